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
  (MC_Reset); meanwhile the NC does not enable that drive again). Judged by the cycle the statusword answers
  (``TxImage.rx_cycle``, stamped by the link): once a statusword answering outputs sent after the NC's last
  controlword other than Enable operation (0x000F) shows Operation enabled, any later statusword that does not is
  the drive's own doing -- however soon after the enable, whatever the link's latency. A statusword answering
  older outputs may still show the drive obeying the Shutdown of a short MC_Power off/on: not a drop. A drive whose
  state machine runs in a slower task than its PDOs shows Operation enabled for a cycle or two after the Shutdown's
  stamp: ``reaction_margin`` (per backend, ``[drives.<name>] reaction_margin``: 0 for the simulated drives, whose
  statusword shows the outputs it answers, cia402-sim and nc-drive-sim; 2 for CANopen) more cycles are required
  (a drop in those first cycles after an enable is then seen as a drive that did not come up, not as a drop). A link
  that cannot stamp (``rx_cycle`` empty) is taken to answer ``max_age + 1`` cycles late.
* ``io_valid``: the inputs are at most ``max_age`` NC cycles old; stale inputs keep the last valid ActVelo/ActAcc.
* ``reset(rows)``: a fault reset edge (0x0000 then 0x0080) for these axes; the request is kept through Fault
  reaction active and dropped once the drive is out of Fault, or ``max_age + 4`` cycles in Fault (a
  refused reset is not repeated: the next MC_Reset asks again). While it is pending the drive's Fault is not
  shown as ``device_error`` (the statusword shows Fault a while longer over a link with latency; one MC_Reset
  suffices), but the axis is not ``ready``; a refused reset shows 0x4650 again after at most ``max_age + 4``
  cycles.
* Torque: ActTorque [%] = 0x6077 / 10 (per mille -> %), its derivative per cycle; SetTorque, its derivative and
  TorqueOffset from the NC's own model of the axis (:class:`..mechanics.Mechanics` with the axis's Sim*
  parameters: the feed-forward torque of the set-point, plus PLCTONC.ExtTorque), as CiA 402 has no torque
  demand in the cyclic process data the NC maps. A drive that does not follow shows SetTorque and TorqueOffset 0;
  its ActTorque is what it reports (a drive braking itself after a fault shows its braking torque); invalid I/O
  data show 0 in every field (as SimDrive).
* Homing: the NC's own homing (MC_Home: cam search, sync pulse search) with the drive's touch probe latched on
  the encoder's index pulse (0x60B8 = enabled, continuous, source zero impulse, positive edge; 0x60B9 bit 7
  toggles with each new latch; 0x60BA the latched position), not the drive's homing mode 6: MC_Home keeps its
  behaviour (its parameters, cam, directions, the NC's position set) on every backend and the drive stays in
  CSP. The probe is armed all the time (a drive latches in hardware at no cost to the NC); ``latch_sync_pulse``
  reports a latch that arrived in the cycle just stepped, at or beyond the previous cycle's position in the
  direction of travel less ``max_age`` cycles' travel (a late latch from before the search was armed, e.g. still
  on the cam, is not taken; one within that window is).
* Touch probe (MC_TouchProbe, input 1 of the NC): the drive's touch probe 2 (0x60B8 bits 8-13, source "touch
  probe 2 input", first-event mode, rising bit 12 or falling bit 13; 0x60B9 bits 8-10; positions 0x60BC / 0x60BD),
  because probe 1 is the index-pulse latch of homing, armed all the time. The NC enables probe 2 while
  MC_TouchProbe is armed (the cycle after the core first asks :meth:`Cia402Drive.latch_probe`) and takes the
  latch once the inputs show it enabled with the stored bit of the requested edge. Each session starts from a
  disabled probe the NC has seen disabled in the inputs (so a stored bit of an earlier session, still in flight
  on a link with latency, is never taken); after a latch (also one the core rejects outside its window) and on a
  change of edge or a new arming (``arm_probe``: MC_TouchProbe executed again, also with the same edge) the NC
  disables it, waits to see it disabled and enables it again. So edges in the arming cycle and for about two
  cycles plus twice the link's latency after a latch or a re-arming are missed (a real drive's arming takes its
  time too). The position is exact (the drive interpolates); the fraction within the cycle is taken from the
  latched position between the previous and the current actual position (1 where the axis stood). The input's
  level is 0x60B9 bit 14 (user defined). Simulated inputs: :meth:`Cia402SimDrive.set_probe_signal` and the sensor
  pattern (SimProbePeriod) of the device.
* Modes: CSP (0x6060 = 8) by default: 0x607A is the set position, 0x60FF the set velocity as feed forward, the
  drive closes the position loop. CSV (9, per axis ``mode = "csv"``): the NC closes the position loop,
  0x60FF = SetVelo + kv * (SetPos - ActPos) (per axis ``kv`` [1/s], default 100), 0x607A is sent as in CSP.
* The drive's own error code (0x603F, ``error_code``) is shown in the NC's stats (``drive_errors``, and with the
  link's figures in ``drive_link``, CANopen's last EMCY code too) and by nc-status (next to the axis error and on
  the axis's drive line), not in NCTOPLC: none of the 256 bytes fits. ErrorCode is the NC's axis error
  (0x4650/0x4651/0x4655 for drive errors, which PLC programs compare); ``_reserved2`` is TwinCAT's hidden member;
  UserData is TwinCAT's "configurable axis state parameter", whose choices are the NC's own axis states (e.g.
  the master's motion state), not a drive object -- taking it over would change what a TwinCAT PLC program
  configured there reads; the rest are TwinCAT's fields with their own meaning.
* Disabling the controller sends Shutdown: the drive goes to Ready to switch on (no torque; its brake holds);
  enabling from there is one cycle (0x000F: transitions 3 + 4).

It may import: numpy, nc_server.core.params, nc_server.drives.
"""
from __future__ import annotations

from typing import Any, Mapping, Sequence

import numpy as np

from ...core.params import AxisParams, ConfigError
from ..base import DriveABC
from ..encoder import EncoderChain
from ..mechanics import Mechanics
from ..npcount import count_nonzero
from . import statemachine as sm
from .device import (PROBE_STATUS_TOGGLE, PROBE_SYNC_PULSE, TP2_ENABLE, TP2_NEGATIVE, TP2_POSITIVE,
                     TP2_STATUS_ENABLED, TP2_STATUS_INPUT, TP2_STATUS_NEG_STORED, TP2_STATUS_POS_STORED)
from .image import ProcessDataLink, RxImage, TxImage
from .objects import Mode, State

_OE, _FRA = int(State.OPERATION_ENABLED), int(State.FAULT_REACTION_ACTIVE)
_ENABLE_OPERATION = 0x000F
# (0-d arrays of the status bits tested each cycle: an operation with a Python int converts it on every call; the
# same bits of any integer status word. And ``x.astype(bool)`` for ``x != 0``: the same, without the 0 to convert)
_TOGGLE, _TP2_INPUT = np.array(PROBE_STATUS_TOGGLE, dtype=np.uint16), np.array(TP2_STATUS_INPUT, dtype=np.uint16)
#: the NC's position loop gain in CSV [1/s] unless an axis sets ``kv``
DEFAULT_KV = 100.0


def axis_options(opts: Mapping[str, Any], where: str) -> tuple[Mode, float, dict[str, Any]]:
    """The CiA 402 options of one axis's ``Drive`` table: ``mode`` ("csp" or "csv", default "csp") and ``kv``
    (CSV's position loop gain [1/s], default :data:`DEFAULT_KV`); returns (mode, kv, the other options) for the
    backend to judge.

    Raises:
        ConfigError: a bad ``mode`` or ``kv`` (``where``: the key path, e.g. ``axis[0].Drive``).
    """
    rest = dict(opts)
    raw = rest.pop("mode", "csp")
    mode = {"csp": Mode.CSP, "csv": Mode.CSV}.get(str(raw).lower()) if isinstance(raw, str) else None
    if mode is None:
        raise ConfigError(f"{where}.mode", f"must be \"csp\" or \"csv\", got {raw!r}")
    kv = rest.pop("kv", DEFAULT_KV)
    if isinstance(kv, bool) or not isinstance(kv, (int, float)) or not (np.isfinite(kv) and kv > 0):
        raise ConfigError(f"{where}.kv", f"must be a number > 0 [1/s], got {kv!r}")
    return mode, float(kv), rest


def link_options(opts: Mapping[str, Any], where: str = "drives") -> tuple[int, dict[str, Any]]:
    """``max_age`` (inputs older than this many NC cycles are invalid I/O data; default 3) of a backend's
    ``[drives.<name>]`` table; returns (max_age, the other options).

    Raises:
        ConfigError: ``max_age`` not an integer >= 0.
    """
    rest = dict(opts)
    max_age = rest.pop("max_age", 3)
    if isinstance(max_age, bool) or not isinstance(max_age, int) or max_age < 0:
        raise ConfigError(f"{where}.max_age", f"must be an integer >= 0 [NC cycles], got {max_age!r}")
    return max_age, rest


#: the largest ``reaction_margin`` [NC cycles]
MAX_REACTION_MARGIN = 1000


def reaction_margin_option(opts: Mapping[str, Any], where: str, default: int) -> tuple[int, dict[str, Any]]:
    """``reaction_margin`` of a backend's ``[drives.<name>]`` table (NC cycles a drive's state machine may react
    after the outputs its statusword's stamp names, see :class:`Cia402Drive`; ``default`` the backend's); returns
    (margin, the other options).

    Raises:
        ConfigError: not an integer 0..MAX_REACTION_MARGIN.
    """
    rest = dict(opts)
    m = rest.pop("reaction_margin", default)
    if isinstance(m, bool) or not isinstance(m, int) or not 0 <= m <= MAX_REACTION_MARGIN:
        raise ConfigError(f"{where}.reaction_margin",
                          f"must be an integer 0..{MAX_REACTION_MARGIN} [NC cycles], got {m!r}")
    return m, rest


def _immutable(a: np.ndarray) -> bool:
    """``a`` cannot change: read-only and the owner of its data (no writeable base behind it)."""
    return not a.flags.writeable and a.base is None


class Cia402Drive(DriveABC):
    """CiA 402 drives behind a process data link (one column per axis).

    Attributes:
        link: the fieldbus.
        state: the drives' power states as last decoded (int8 :class:`.objects.State`).
        controlword: the controlwords sent last.
        tx: the inputs of the last cycle.
        encoder: the encoder chains (increments <-> axis units).
        max_age: inputs older than this [NC cycles] are invalid I/O data.
        reaction_margin: NC cycles the drive's state machine may react after the outputs its statusword answers
            (by the link's stamp): Operation enabled is confirmed only by a statusword answering outputs more than
            this many cycles after the last controlword other than 0x000F.
    """

    def __init__(self, params: Sequence[AxisParams], cycle_time: float, link: ProcessDataLink, *,
                 simulated: bool = False, max_age: int = 3, mode: Mode | Sequence[Mode] = Mode.CSP,
                 kv: float | Sequence[float] = DEFAULT_KV, reaction_margin: int = 0) -> None:
        """
        Args:
            params: the axes' parameters (the encoder chain, the torque model).
            cycle_time: the NC cycle [s].
            link: the process data link of these axes (one column per axis, in order).
            simulated: OpModeDWord.OpModeSimulationAxis.
            max_age: inputs older than this [NC cycles] are invalid I/O data (0x4655 three cycles later).
            mode: per axis (or for all) CSP (the default) or CSV.
            kv: per axis (or for all) the NC's position loop gain in CSV [1/s] (target velocity = SetVelo +
                kv * (SetPos - ActPos)); unused in CSP, where the drive closes the position loop.
            reaction_margin: see the class (0: the drive's statusword shows the effect of the outputs it answers;
                a real drive whose state machine runs in a slower task than its PDOs needs a cycle or two).

        Raises:
            ValueError: a mode other than CSP/CSV, kv <= 0, max_age < 0, reaction_margin < 0.
        """
        super().__init__(params, cycle_time)
        n = len(params)
        modes = [mode] * n if isinstance(mode, (int, Mode)) else list(mode)
        kvs = [kv] * n if isinstance(kv, (int, float)) else list(kv)
        if len(modes) != n or len(kvs) != n:
            raise ValueError(f"mode and kv need one value per axis ({n})")
        if any(int(m) not in (Mode.CSP, Mode.CSV) for m in modes):
            raise ValueError(f"mode must be CSP (8) or CSV (9), got {modes}")
        if not all(float(k) > 0 and np.isfinite(float(k)) for k in kvs):
            raise ValueError(f"kv must be > 0 [1/s], got {kvs}")
        if int(max_age) < 0:
            raise ValueError(f"max_age must be >= 0 cycles, got {max_age}")
        if int(reaction_margin) < 0:
            raise ValueError(f"reaction_margin must be >= 0 cycles, got {reaction_margin}")
        self.reaction_margin = int(reaction_margin)
        self.simulated = simulated
        self.link = link
        self.max_age = int(max_age)
        self.encoder = EncoderChain(n)
        self.mechanics = Mechanics(n, cycle_time)
        self.state = np.full(n, int(State.NOT_READY_TO_SWITCH_ON), dtype=np.int8)
        self.controlword = np.zeros(n, dtype=np.uint16)
        self._mode = np.array([int(m) for m in modes], dtype=np.int8)
        self._csv = self._mode == int(Mode.CSV)
        self._any_csv = bool(self._csv.any())
        self._kv = np.array([float(k) for k in kvs])
        self._probe_fn = np.full(n, PROBE_SYNC_PULSE, dtype=np.uint16)
        self._reset_left = np.zeros(n, dtype=np.int64)
        self._dropped = np.zeros(n, dtype=bool)
        self._lost = np.zeros(n, dtype=bool)  # lost (not alive) while enabled: not enabled again before a reset
        self._last_off = np.full(n, -(1 << 30), dtype=np.int64)  # the cycle of the last controlword not 0x000F
        # Operation enabled shown by a statusword answering a 0x000F sent after the last other controlword: leaving
        # it from now on is the drive's own doing (cleared by the next controlword other than 0x000F)
        self._confirmed = np.zeros(n, dtype=bool)
        self._probe_new = np.zeros(n, dtype=bool)
        self._last_probe_status = np.zeros(n, dtype=np.uint16)
        self._no_probe = np.zeros(n, dtype=bool)
        self._pi_key = b""  # (probe_input: the input bits of the probe status words of its last array)
        #: the age and alive arrays of inputs last found all fresh and alive, and max_age then (immutable arrays:
        #: the same ones again need no look)
        self._fresh: tuple[np.ndarray | None, np.ndarray | None, int] = (None, None, 0)
        self._pi = self._no_probe
        self._probe_new_any = False
        # touch probe 2 (MC_TouchProbe): the probe 2 bits sent, those the core asked for, session bookkeeping
        self._tp_code = np.zeros(n, dtype=np.uint16)
        self._tp_req = np.zeros(n, dtype=np.uint16)
        self._tp_req_cycle = -1  # the cycle whose latch_probe call set _tp_req
        self._tp_clean = np.zeros(n, dtype=bool)  # probe 2 seen disabled since the NC last sent it off
        self._tp_used = np.zeros(n, dtype=bool)  # a latch was taken: disable before the next one counts
        self._tp_rearm = np.zeros(n, dtype=bool)  # a new arming (arm_probe): disable before a latch counts
        self._tp_watch = True  # some probe 2 sent, used or not seen disabled yet (else nothing to do per cycle)
        self._any_dropped = False
        self._any_reset = False
        self._act_live = False  # ActTorque (0x6077) was not 0 in the last cycle, or its derivative
        self._act_shown = np.zeros(n)  # the ActTorque shown last [%]
        # (0-d arrays of the cycle's scalars: an operation with a Python float converts it on every call, one with a
        # 0-d float64 array does not -- the same IEEE operation, bit for bit)
        self._dt0, self._inv_dt0 = np.array(self.cycle_time), np.array(self.mechanics.inv_dt)
        self._cycle = 0
        # the key (states, enables) of the last controlwords computed without a reset, those (never written: sent
        # again while the key holds) and whether one of them is not Enable operation
        self._cw_key = b""
        self._cw = np.zeros(0, dtype=np.uint16)
        self._cw_off = True
        # the steady cycle's statuswords (bytes), their states, following and confirmed masks and the enables
        self._st_key = b""
        self._st_state = np.zeros(0, dtype=np.int8)
        self._st_following: np.ndarray | None = None
        self._st_conf: np.ndarray | None = None
        self._st_want = b""
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
        self._any_reset = True
        self._dropped[rows] = False
        self._lost[rows] = False
        self._any_dropped = bool(self._dropped.any() or self._lost.any())

    def resync(self, latched: np.ndarray | None = None) -> None:
        """A takeover (:meth:`..base.DriveABC.resync`): the drives' power state, position and error code from the
        link's newest inputs (:meth:`.image.ProcessDataLink.peek`; nothing is sent). A drive in Operation enabled is
        taken as confirmed (the other NC enabled it: leaving it from now on is the drive's own doing), its target the
        NC's set-point from the first step on; one that is not is walked up by the controlword of its real state.
        This drive's cycle count continues after the newest cycle the drives answer (the other NC's numbering), so
        the stamps of the outputs it sends are newer than every stamp the drives showed before."""
        tx = self.link.peek()
        if tx is None:
            return
        n = len(self.state)
        rc = tx.rx_cycle
        if len(rc) == n and n:
            self._cycle = max(self._cycle, int(rc.max()))
        state = sm.decode(tx.statusword)
        alive = tx.alive if len(tx.alive) == n else np.ones(n, dtype=bool)
        valid = tx.age <= self.max_age
        following = (state == _OE) & alive
        fault_state = state >= _FRA
        c = self.encoder
        self._pos_inc = np.where(valid, tx.position_actual, self._pos_inc)
        self.act_pos = np.where(valid, c.positions(tx.position_actual), self.act_pos)
        self.act_velo = np.where(valid, tx.velocity_actual * c.scaling * c.sign, self.act_velo)
        self.act_acc = np.zeros(n)
        self.tx, self.state, self.following = tx, state, following
        self._confirmed = following.copy()
        self._lost = np.zeros(n, dtype=bool)
        keep = np.zeros(n, dtype=bool) if latched is None else np.asarray(latched, dtype=bool)
        self._dropped = keep & ~following & ~fault_state
        self._any_dropped = bool(self._dropped.any())
        self._reset_left = np.zeros(n, dtype=np.int64)
        self._any_reset = False
        self._last_probe_status = tx.probe_status
        self._probe_new = self._no_probe
        self._probe_new_any = False
        self.io_valid, self.comm_error = valid, ~alive
        self.device_error = fault_state | self._dropped
        self.ready = ~fault_state & alive
        self.error_code, self.input_age = tx.error_code, tx.age
        self.faulty = True  # (the first step evaluates everything)

    # -- the cycle ------------------------------------------------------------------------------------------

    def step(self, enabled: np.ndarray, set_pos: np.ndarray, set_velo: np.ndarray, set_acc: np.ndarray) -> None:
        en = np.asarray(enabled, dtype=bool)
        c = self.encoder
        target = c.increments_at(set_pos)
        if count_nonzero(self.following) < len(target):  # not following: the target is where the motor is
            target = np.where(self.following, target, self._pos_inc)
        velo = c.inc_velocities(set_velo)
        if self._tp_watch or self._tp_req_cycle == self._cycle:
            self._probe_outputs()
        if self._any_csv:  # the NC closes the position loop: feed forward + kv * the position error [inc/s]
            velo = np.where(self._csv & self.following, velo + self._kv * (target - self._pos_inc), velo)
        self._exchange(en, target, velo)
        self._torque(set_velo, set_acc)

    def _exchange(self, want: np.ndarray, target: np.ndarray | None, target_velo: np.ndarray) -> None:
        up = want
        if self._any_dropped:  # a drive that dropped out or was lost is not enabled again before a fault reset
            up = want & ~(self._dropped | self._lost)
        if self._any_reset:
            cw = sm.nc_controlword(self.state, up, self._reset_left > 0, self.controlword)
            # (the time limit runs once the drive is in Fault: its fault reaction (braking) may take long)
            self._reset_left = np.where(self.state == _FRA, self._reset_left, np.maximum(self._reset_left - 1, 0))
        else:  # (a function of the states and the enables alone: the steady cycle reuses the last controlwords)
            key = self.state.tobytes() + up.tobytes()  # (``want``, ``up``: bool arrays)
            if key != self._cw_key:
                cw = sm.nc_controlword(self.state, up)
                self._cw_key, self._cw, self._cw_off = key, cw, bool(count_nonzero(cw != _ENABLE_OPERATION))
            cw = self._cw
        self._cycle += 1
        if cw is not self._cw or self._cw_off:
            off = cw != _ENABLE_OPERATION
            if count_nonzero(off):
                self._last_off = np.where(off, self._cycle, self._last_off)
                self._confirmed = self._confirmed & ~off
        rx = RxImage(cw, self._mode, self._pos_inc if target is None else target, target_velo, self._probe_fn,
                     self._cycle)
        self.controlword = cw
        tx = self.link.exchange(rx)
        self.tx = tx
        skey = tx.statusword.tobytes()
        # the steady cycle (see _remember_steady): the statuswords of the last cycle again, nothing confirmed or
        # decoded anew since -> the same states, the same following mask, nothing pending
        known = skey == self._st_key and self._confirmed is self._st_conf and self.following is self._st_following
        if known:
            state = self._st_state.copy()  # (a copy: ``state`` is handed out)
            following = self.following
            pending_n = 0
        else:
            state = sm.decode(tx.statusword)
            following = state == _OE
            pending = following & ~self._confirmed
            pending_n = int(count_nonzero(pending))
            if pending_n:  # (the steady state: every following axis confirmed, nothing to do)
                # (strictly after: a statusword stamped with the Shutdown's own cycle may not show it yet)
                self._confirmed = self._confirmed | (pending & (self._answered(tx) - self.reaction_margin > self._last_off))
        self.state = state
        c = self.encoder
        new_pos = c.positions(tx.position_actual)
        new_velo = c.velocities(tx.velocity_actual)
        new_acc = np.subtract(new_velo, self.act_velo)  # ((new_velo - act_velo) / dt: one new array)
        new_acc /= self._dt0
        n = len(state)
        age, alive = tx.age, tx.alive
        if age is self._fresh[0] and alive is self._fresh[1] and self.max_age == self._fresh[2]:
            degraded: Any = 0  # (the same immutable arrays found fresh and alive before)
        else:
            degraded = count_nonzero(age > self.max_age) or count_nonzero(alive) < n
            if not degraded and _immutable(age) and _immutable(alive):
                self._fresh = (age, alive, self.max_age)
        if degraded or self.faulty:  # (the steady state skips all of this)
            valid = tx.age <= self.max_age
            alive = tx.alive
            if not valid.all():  # stale inputs: the last valid values stay
                new_pos = np.where(valid, new_pos, self.act_pos)
                new_velo = np.where(valid, new_velo, self.act_velo)
                new_acc = np.where(valid, new_acc, self.act_acc)
                self._pos_inc = np.where(valid, tx.position_actual, self._pos_inc)
            else:
                self._pos_inc = tx.position_actual
            following = following & alive
            lost = want & self.following & ~alive
            if count_nonzero(lost):  # (it may come back rebooted, in Switch on disabled: never re-enabled unasked)
                self._lost = self._lost | lost
                self._any_dropped = True
            fault_state = state >= _FRA
            dropped = self._dropped
            if self._any_dropped or count_nonzero(self.following & ~following):
                dropped = want & alive & ~following & (dropped | (self.following & self._confirmed))  # (silent: 0x4651)
                self._dropped = dropped
                self._any_dropped = bool(dropped.any() or self._lost.any())
            self.io_valid = valid
            self.comm_error = ~alive
            # a fault reset on its way: the statusword shows Fault a cycle or more (latency); the NC has cleared
            # 0x4650 and must not raise it again meanwhile (the axis stays not ready: ``ready`` is the real state)
            shown = fault_state & ~(self._reset_left > 0) if self._any_reset else fault_state
            self.device_error = shown | dropped
            self.ready = ~fault_state & alive & (~want | following)
            self.faulty = bool(degraded or self.device_error.any() or count_nonzero(want & ~following)
                               or self._any_reset)
        else:
            self._pos_inc = tx.position_actual
            wkey = want.tobytes()
            if known and wkey == self._st_want and not self._any_reset:
                pass  # (the states, the following mask and the enables of a cycle that found no change: none)
            elif count_nonzero(self.following & ~following) or count_nonzero(state >= _FRA) \
                    or count_nonzero(want & ~following) or self._any_reset:  # a change (then the full evaluation)
                fault_state = state >= _FRA
                dropped = want & ~following & self.following & self._confirmed
                self._dropped = dropped
                self._any_dropped = bool(dropped.any() or self._lost.any())
                shown = fault_state & ~(self._reset_left > 0) if self._any_reset else fault_state
                self.device_error = shown | dropped
                self.ready = ~fault_state & (~want | following)
                self.faulty = bool(self.device_error.any() or count_nonzero(want & ~following)
                                   or self._any_reset)
            elif not pending_n:
                # no change, nothing pending: while the statuswords, this following mask, the confirmed mask and
                # the enables stay, the next cycles find the same (no drive in Fault (reaction), every enabled one
                # following, every following one confirmed)
                self._st_key, self._st_state, self._st_following = skey, state.copy(), following
                self._st_conf, self._st_want = self._confirmed, wkey
        self.following = following
        self.act_pos, self.act_velo, self.act_acc = new_pos, new_velo, new_acc
        self.error_code = tx.error_code
        self.input_age = tx.age
        if self._any_reset:
            self._reset_left = np.where(state >= _FRA, self._reset_left, 0)  # (kept through the fault reaction)
            self._any_reset = bool(self._reset_left.any())
        ps = tx.probe_status
        if self._tp_watch:
            off = (self._tp_code == 0) & ((ps & TP2_STATUS_ENABLED) == 0) & (tx.age <= self.max_age)
            self._tp_clean = self._tp_clean | off
            self._tp_watch = bool(self._tp_code.any() or self._tp_used.any() or not self._tp_clean.all())
        if ps is not self._last_probe_status:
            self._probe_new = ((ps ^ self._last_probe_status) & _TOGGLE).astype(bool)  # (!= 0 of integers)
            self._last_probe_status = ps
        elif self._probe_new_any:
            self._probe_new = self._no_probe
        self._probe_new_any = bool(count_nonzero(self._probe_new))  # (far cheaper than ndarray.any)

    def _answered(self, tx: TxImage) -> np.ndarray:
        """Per axis the NC cycle whose outputs the statusword in ``tx`` answers: the link's stamp; a stamp from the
        future (e.g. the echo of another NC's cycle count after a standby takeover) counts as none (0); a link
        without stamps: the worst case, ``max_age + 1`` cycles before the inputs arrived."""
        rc = tx.rx_cycle
        if len(rc) == len(tx.statusword):
            return np.where(rc <= self._cycle, rc, 0)
        return self._cycle - tx.age - (self.max_age + 1)

    def _torque(self, set_velo: np.ndarray, set_acc: np.ndarray) -> None:
        m = self.mechanics
        delivering = self.following if not self.faulty else self.following & self.io_valid
        m.step_set(delivering, set_velo, set_acc)  # (ActTorque and its derivative: the drive's, below)
        act = self.tx.torque_actual
        if self.faulty:  # invalid I/O data: no torque shown (the motor gets no set-points)
            act = np.where(self.io_valid, act, 0.0)
        live = bool(count_nonzero(act))
        # ActTorque is the drive's (also while it brakes itself, the model resting), and so is its fall to 0
        if live or self._act_live or not m.resting:
            a = act * 0.1  # (a Python float: a link's float32 torque stays float32 here, as it did)
            f = m.fields
            f2 = f[2]
            np.subtract(a, self._act_shown, f2)
            f2 *= self._inv_dt0
            f[1] = a
            self._act_shown = a
            self._act_live = live or bool(count_nonzero(f2))  # (one more cycle: the derivative to 0)

    def encoder_count(self, index: int) -> float:
        """The hardware counter of axis ``index``'s encoder as the NC's chain reads it: increments & mask [inc]."""
        return self.encoder.hardware_count(index, float(self.act_pos[index]))

    # -- torque, homing -------------------------------------------------------------------------------------

    def set_torque_offset(self, values: np.ndarray) -> None:
        """PLCTONC.ExtTorque [%]: shown as TorqueOffset and in SetTorque (:meth:`.mechanics.Mechanics.set_offset`)."""
        self.mechanics.set_offset(np.asarray(values, dtype=float))

    def torque_fields(self) -> np.ndarray | None:
        """SetTorque from the NC's model, ActTorque from 0x6077 (see the module docstring); None while resting."""
        return None if self.mechanics.resting and not self._act_live else self.mechanics.fields

    def latch_sync_pulse(self, rows: np.ndarray, prev_pos: np.ndarray) -> np.ndarray:
        """The index pulse the drive's touch probe latched in the cycle just stepped [u] (NaN: none).

        Only a latch at or beyond ``prev_pos`` in the direction of travel counts, less a window of ``max_age``
        cycles' travel (inputs that came late carry a latch from a few cycles back): the probe is armed all the
        time, and a latch from before homing armed its search (still on the cam) must not be taken."""
        rows = np.asarray(rows, dtype=np.intp)
        new = self._probe_new[rows]
        if not new.any():
            return np.full(len(rows), np.nan)
        pos = self.encoder.positions(self.tx.probe_position[rows], rows)
        step = self.act_pos[rows] - np.asarray(prev_pos, dtype=float)
        ahead = (pos - prev_pos) * np.sign(step) >= -np.abs(step) * self.max_age
        return np.where(new & ahead, pos, np.nan)

    # -- touch probe (MC_TouchProbe) -------------------------------------------------------------------------

    def _probe_outputs(self) -> None:
        """Probe 2's bits of 0x60B8 for this cycle (see the module docstring): off where the core no longer asks, a
        latch was taken or the edge changed; on (first event, the requested edge) where it asks and the probe has
        been seen disabled."""
        req = self._tp_req if self._tp_req_cycle == self._cycle else np.zeros_like(self._tp_code)
        code = self._tp_code
        off = self._tp_used | self._tp_rearm | ((code != 0) & (code != req))
        new = np.where(off, 0, code)
        self._tp_clean = self._tp_clean & ~(off & (code != 0))
        self._tp_used = np.zeros_like(self._tp_used)
        self._tp_rearm = np.zeros_like(self._tp_rearm)
        start = (new == 0) & (req != 0) & self._tp_clean & ~off
        new = np.where(start, req, new).astype(np.uint16)
        if not np.array_equal(new, code):
            self._tp_code = new
            self._probe_fn = (np.uint16(PROBE_SYNC_PULSE) | new).astype(np.uint16)  # (a new array: the drive compares)
        self._tp_watch = True  # (the inputs decide: see _exchange)

    def probe_input(self) -> np.ndarray:
        """Touch probe input 1 of the NC per axis: the drive's probe 2 input (0x60B9 bit 14). While those bits of the
        probe status words stay (compared by their bytes; the other bits change with each index pulse latched),
        the array of the last call again (read-only): the NC's packer then skips writing StateDWord3."""
        bits = self.tx.probe_status & _TP2_INPUT
        key = bits.tobytes()
        if key != self._pi_key:
            pi = bits.astype(bool)  # (!= 0 of integers)
            pi.flags.writeable = False
            self._pi_key, self._pi = key, pi
        return self._pi

    def arm_probe(self, rows: np.ndarray) -> None:
        """A new MC_TouchProbe on these rows: the session of probe 2 ends (disabled next cycle, seen disabled in
        the inputs, enabled again), so a latch stored for the arming before, still in flight, is not taken."""
        self._tp_rearm[np.asarray(rows, dtype=np.intp)] = True
        self._tp_watch = True

    def latch_probe(self, rows: np.ndarray, falling: np.ndarray,
                    prev_pos: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The latch of probe 2 in this session, where the inputs show one (module docstring); asks for probe 2
        on these rows from the next cycle."""
        rows = np.asarray(rows, dtype=np.intp)
        falling = np.asarray(falling, dtype=bool)
        code = np.where(falling, TP2_ENABLE | TP2_NEGATIVE, TP2_ENABLE | TP2_POSITIVE).astype(np.uint16)
        req = np.zeros_like(self._tp_code)
        req[rows] = code
        self._tp_req, self._tp_req_cycle = req, self._cycle
        self._tp_watch = True
        m = len(rows)
        tx = self.tx
        ps = tx.probe_status[rows]
        stored = (ps & np.where(falling, TP2_STATUS_NEG_STORED, TP2_STATUS_POS_STORED)) != 0
        found = ((self._tp_code[rows] == code) & self._tp_clean[rows] & ((ps & TP2_STATUS_ENABLED) != 0) & stored
                 & (tx.age[rows] <= self.max_age) & ~self._tp_rearm[rows])
        if not found.any():
            return found, np.full(m, np.nan), np.full(m, np.nan)
        raw = np.where(falling, tx.probe2_neg[rows], tx.probe2_pos[rows])
        pos = np.where(found, self.encoder.positions(raw, rows), np.nan)
        self._tp_used[rows[found]] = True
        a = np.asarray(prev_pos, dtype=float)
        d = self.act_pos[rows] - a
        with np.errstate(divide="ignore", invalid="ignore"):
            frac = np.where(d != 0, np.clip((pos - a) / np.where(d != 0, d, 1.0), 0.0, 1.0), 1.0)
        return found, pos, np.where(found, frac, np.nan)

    def link_figures(self) -> dict[int, dict[str, Any]]:
        """The link's figures per axis (:meth:`.image.ProcessDataLink.figures`) with the drive's own error code
        ``error_code`` (0x603F of the inputs used last; 0: none): where a user reads the link (stats ``drive_link``,
        nc-status's drive line). A link without figures (in process) gives ``{"link": "local", "error_code": ..}``
        for the axes whose drive reports an error only."""
        codes = self.error_code.tolist()  # (the cycle replaces the array, it does not write into it)
        figures = self.link.figures()
        if not figures:
            return {i: {"link": "local", "error_code": int(c)} for i, c in enumerate(codes) if c}
        return {i: {**f, "error_code": int(codes[i])} if i < len(codes) else f for i, f in enumerate(figures)}

    def close(self) -> None:
        self.link.close()
