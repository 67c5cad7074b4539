"""The NC's drives over CiA 402: :class:`Cia402Drive`, a ``DriveABC`` on top of any :class:`.image.ProcessDataLink`.

Per NC cycle (a few vector operations for all axes):

1. the controlword from :func:`.statemachine.nc_controlword` (the last decoded state, the controller enable,
   pending fault resets);
2. the targets: 0x607A = the encoder chain's inverse of the set position [inc] (0x60FF the set velocity
   [inc/s], CSP's velocity feed forward / CSV's target) -- while the drive is not in Operation enabled the
   target is its actual position, so nothing jumps when it is enabled;
3. ``link.exchange`` -> the newest inputs; ActPos through the encoder chain from 0x6064, ActVelo from 0x606C,
   ActAcc their difference per cycle;
4. the drive state the NC monitors (``following``, ``device_error``, ``comm_error``, ``io_valid``, ``ready``,
   ``error_code``).

Decisions:

* ``ready``: not in Fault / Fault reaction active and alive; on an enabled axis only once Operation enabled
  (a start during power up is refused with 0x4225, as for a drive that is not ready).
* ``device_error``: Fault or Fault reaction active, or the drive left Operation enabled while the NC wanted it
  enabled (e.g. its safe torque off: latched until the NC disables the axis or a fault reset is requested
  (MC_Reset); meanwhile the NC does not enable that drive again).
* ``io_valid``: the inputs are at most ``max_age`` NC cycles old; stale inputs keep the last valid ActVelo/ActAcc.
* ``reset(rows)``: a fault reset edge (0x0000 then 0x0080) for these axes; the request is dropped once the
  drive is out of Fault, or ``max_age + 4`` cycles after it was made (a refused reset is not repeated: the next
  MC_Reset asks again).
* Torque: ActTorque [%] = 0x6077 / 10 (per mille -> %), its derivative per cycle; SetTorque, its derivative and
  TorqueOffset from the NC's own model of the axis (:class:`..mechanics.Mechanics` with the axis's Sim*
  parameters: the feed-forward torque of the set-point, plus PLCTONC.ExtTorque), as CiA 402 has no torque
  demand in the cyclic process data the NC maps.
* Homing: the NC's own homing (MC_Home: cam search, sync pulse search) with the drive's touch probe latched on
  the encoder's index pulse (0x60B8 = enabled, continuous, source zero impulse, positive edge; 0x60B9 bit 7
  toggles with each new latch; 0x60BA the latched position), not the drive's homing mode 6: MC_Home keeps its
  behaviour (its parameters, cam, directions, the NC's position set) on every backend and the drive stays in
  CSP. The probe is armed all the time (a drive latches in hardware at no cost to the NC); ``latch_sync_pulse``
  reports a latch that arrived in the cycle just stepped.

It may import: numpy, nc_server.core.params, nc_server.drives.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np

from ...core.params import AxisParams
from ..base import DriveABC
from ..encoder import EncoderChain
from ..mechanics import Mechanics
from . import statemachine as sm
from .device import PROBE_STATUS_TOGGLE, PROBE_SYNC_PULSE
from .image import ProcessDataLink, RxImage, TxImage
from .objects import Mode, State

_OE, _FRA, _FLT = int(State.OPERATION_ENABLED), int(State.FAULT_REACTION_ACTIVE), int(State.FAULT)


class Cia402Drive(DriveABC):
    """CiA 402 drives behind a process data link (one column per axis).

    Attributes:
        link: the fieldbus.
        state: the drives' power states as last decoded (int8 :class:`.objects.State`).
        controlword: the controlwords sent last.
        tx: the inputs of the last cycle.
        encoder: the encoder chains (increments <-> axis units).
        max_age: inputs older than this [NC cycles] are invalid I/O data.
    """

    def __init__(self, params: Sequence[AxisParams], cycle_time: float, link: ProcessDataLink, *,
                 simulated: bool = False, max_age: int = 3, mode: Mode = Mode.CSP) -> None:
        super().__init__(params, cycle_time)
        n = len(params)
        self.simulated = simulated
        self.link = link
        self.max_age = int(max_age)
        self.encoder = EncoderChain(n)
        self.mechanics = Mechanics(n, cycle_time)
        self.state = np.full(n, int(State.NOT_READY_TO_SWITCH_ON), dtype=np.int8)
        self.controlword = np.zeros(n, dtype=np.uint16)
        self._mode = np.full(n, int(mode), dtype=np.int8)
        self._probe_fn = np.full(n, PROBE_SYNC_PULSE, dtype=np.uint16)
        self._reset_left = np.zeros(n, dtype=np.int64)
        self._dropped = np.zeros(n, dtype=bool)
        self._probe_new = np.zeros(n, dtype=bool)
        self._last_probe_status = np.zeros(n, dtype=np.uint16)
        self._cycle = 0
        self.following = np.zeros(n, dtype=bool)
        self.tx = TxImage.zeros(n)
        self._pos_inc = np.zeros(n)
        for i, p in enumerate(params):
            self.configure(i, p)
        self._exchange(np.zeros(n, dtype=bool), None, np.zeros(n))  # read the drives' positions and states

    def configure(self, index: int, params: AxisParams) -> None:
        """The encoder chain (a parameter change moves the reported position, not the motor) and the torque model."""
        self.mechanics.configure(index, params)
        pos = float(self.act_pos[index])
        new = self.encoder.configure(index, params, pos)
        if new != pos:
            self.act_pos = self.act_pos.copy()  # (the NC may hold this array: it compares before and after)
            self.act_pos[index] = new

    def reset(self, rows: np.ndarray) -> None:
        """A fault reset edge for these axes (MC_Reset)."""
        rows = np.asarray(rows, dtype=np.intp)
        self._reset_left[rows] = self.max_age + 4
        self._dropped[rows] = False

    # -- the cycle ------------------------------------------------------------------------------------------

    def step(self, enabled: np.ndarray, set_pos: np.ndarray, set_velo: np.ndarray, set_acc: np.ndarray) -> None:
        en = np.asarray(enabled, dtype=bool)
        c = self.encoder
        target = (set_pos - c.offset) / c.scaling * c.sign - c.base
        if np.count_nonzero(self.following) < len(target):  # not following: the target is where the motor is
            target = np.where(self.following, target, self._pos_inc)
        self._exchange(en, target, set_velo / c.scaling * c.sign)
        self._torque(set_velo, set_acc)

    def _exchange(self, want: np.ndarray, target: np.ndarray | None, target_velo: np.ndarray) -> None:
        en = want
        if self._dropped.any():  # a drive that dropped out is not enabled again before a fault reset
            en = en & ~self._dropped
        if self._reset_left.any():
            requested = self._reset_left > 0
            cw = sm.nc_controlword(self.state, en, requested, self.controlword)
            self._reset_left = np.maximum(self._reset_left - 1, 0)
        else:
            cw = sm.nc_controlword(self.state, en)
        self._cycle += 1
        rx = RxImage(cw, self._mode, self._pos_inc if target is None else target, target_velo, self._probe_fn,
                     self._cycle)
        self.controlword = cw
        tx = self.link.exchange(rx)
        self.tx = tx
        state = sm.decode(tx.statusword)
        self.state = state
        follows = state == _OE
        alive = tx.alive
        c = self.encoder
        valid = tx.age <= self.max_age
        all_valid = bool(valid.all())
        new_pos = c.sign * (tx.position_actual + c.base) * c.scaling + c.offset
        new_velo = tx.velocity_actual * c.scaling * c.sign
        if not all_valid:  # stale inputs: the last valid values stay
            new_pos = np.where(valid, new_pos, self.act_pos)
            new_velo = np.where(valid, new_velo, self.act_velo)
        new_acc = (new_velo - self.act_velo) / self.cycle_time
        if not all_valid:
            new_acc = np.where(valid, new_acc, self.act_acc)
        self._pos_inc = np.where(valid, tx.position_actual, self._pos_inc) if not all_valid else tx.position_actual
        self.act_pos, self.act_velo, self.act_acc = new_pos, new_velo, new_acc
        self.io_valid = valid
        if alive.all():
            following = follows
            self.comm_error = np.zeros(len(follows), dtype=bool)
        else:
            following = follows & alive
            self.comm_error = ~alive
        fault_state = (state == _FRA) | (state == _FLT)
        dropped = self._dropped
        if dropped.any() or np.count_nonzero(self.following & ~following):
            dropped = want & ~following & (dropped | self.following)
            self._dropped = dropped
        self.following = following
        self.device_error = fault_state | dropped
        self.ready = ~fault_state & alive & (~want | following)
        self.error_code = tx.error_code
        self.faulty = bool(not all_valid or self.device_error.any() or not alive.all()
                           or np.count_nonzero(want & ~following))
        if self._reset_left.any():
            self._reset_left = np.where(fault_state, self._reset_left, 0)
        self._probe_new = ((tx.probe_status ^ self._last_probe_status) & PROBE_STATUS_TOGGLE) != 0
        self._last_probe_status = tx.probe_status

    def _torque(self, set_velo: np.ndarray, set_acc: np.ndarray) -> None:
        m = self.mechanics
        shown = m.fields[1].copy()
        m.step(self.following, set_velo, set_acc, self.act_velo, self.act_acc)
        if not m.resting:
            act = self.tx.torque_actual * 0.1
            m.fields[2] = (act - shown) * m.inv_dt
            m.fields[1] = act

    # -- torque, homing -------------------------------------------------------------------------------------

    def set_torque_offset(self, values: np.ndarray) -> None:
        """PLCTONC.ExtTorque [%]: shown as TorqueOffset and in SetTorque (:meth:`.mechanics.Mechanics.set_offset`)."""
        self.mechanics.set_offset(np.asarray(values, dtype=float))

    def torque_fields(self) -> np.ndarray | None:
        """SetTorque from the NC's model, ActTorque from 0x6077 (see the module docstring); None while resting."""
        return None if self.mechanics.resting else self.mechanics.fields

    def latch_sync_pulse(self, rows: np.ndarray, prev_pos: np.ndarray) -> np.ndarray:
        """The index pulse the drive's touch probe latched in the cycle just stepped [u] (NaN: none)."""
        rows = np.asarray(rows, dtype=np.intp)
        c = self.encoder
        pos = c.sign[rows] * (self.tx.probe_position[rows] + c.base[rows]) * c.scaling[rows] + c.offset[rows]
        return np.where(self._probe_new[rows], pos, np.nan)

    def close(self) -> None:
        self.link.close()
