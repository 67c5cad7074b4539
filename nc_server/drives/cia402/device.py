"""Simulated CiA 402 drives: the device side of the process data, stepped at the device's own cycle.

``Cia402Device(n, cycle_time)`` holds ``n`` drives as columns: the power state machine
(:func:`.statemachine.device_next`), cyclic synchronous position (mode 8: the position controller is the
first-order lag of ``SimTimeConstant``, as ``SimDrive`` had it) and cyclic synchronous velocity (mode 9: the
same lag on the velocity), the quick stop and fault reaction ramps, the mechanical model
(:class:`..mechanics.Mechanics` -> 0x6077 in per mille) and a touch probe on the encoder's index pulses.
Used by ``cia402-sim`` (in process), the simulated CANopen slaves and ``nc-drive-sim``. All positions are
increments (float: no quantisation), velocities inc/s.

Decisions (where CiA 402 leaves the device free):

* Power up: the device's self test is done at construction: it starts in Switch on disabled (transitions 0, 1).
* Quick stop deceleration (0x6085) and the fault reaction's deceleration: the axis's ``AxisDec`` (converted to
  inc/s^2 through AxisEncoderScalingFactor). Quick stop option code 6: the drive stops and stays in Quick stop
  active. Fault reaction: the same ramp, then Fault (transition 14) once the motor stands.
* Outside Operation enabled, Quick stop active and Fault reaction active the motor holds (a brake: velocity 0).
* Faults (:meth:`Cia402Device.inject_fault`): a *transient* fault (default, e.g. 0x2310 overcurrent: the
  cause is gone once the drive has stopped) is acknowledged by a fault reset; a *persistent* one
  (``persistent=True``, e.g. a hardware error) blocks the fault reset until :meth:`Cia402Device.clear_fault`.
  0x603F keeps the code of the fault until the reset succeeds (then 0).
* Lost communication: ``timeout`` seconds without outputs (``step(None)``) is a fault with code 0x8130 (CiA 301
  "life guard error / heartbeat error"): the drive stops on its quick-stop ramp and keeps its position; the
  cause is gone as soon as outputs arrive again (then a fault reset acknowledges it).
* Touch probe (0x60B8 / 0x60B9 / 0x60BA): probe 1 with trigger source "zero impulse" (bits 2-3 = 01) latches the
  encoder's index pulses at SimSyncPulseOffset + k * SimSyncPulseSpacing (axis units as the encoder reports them,
  like ``SimDrive``) into 0x60BA, whatever the direction of travel (bit 4 must be set). Within a device cycle the
  motor moves linearly, so the latch is the exact pulse (the last one passed in the cycle). 0x60B9: bit 0 probe 1
  enabled, bit 1 a position stored, bit 7 toggles with each new latch (continuous mode, bit 1 of 0x60B8; in
  single mode only the first pulse after enabling is latched). Source "input 1" is not simulated.
* Touch probe 2 (0x60B8 bits 8-15, 0x60B9 bits 8-15, 0x60BC / 0x60BD): source "touch probe 2 input" (bits
  10-11 = 00), the input MC_TouchProbe latches (probe 1 stays on the index pulse for homing, armed all the time).
  The input is simulated as ``SimDrive`` does it: a sensor pattern of the drive position (SimProbePeriod,
  SimProbeOffset, SimProbeWidth in axis units, evaluated through the device's encoder chain) or, on an axis
  without one, levels commanded with :meth:`Cia402Device.set_probe_signal` at an offset into the next device
  cycle. Bit 12 (rising) / bit 13 (falling) latch the position of the first such edge of the cycle, interpolated
  (the motor moves linearly within a cycle), into 0x60BC / 0x60BD and set 0x60B9 bit 9 / bit 10; in first-event
  mode (bit 9 of 0x60B8 clear) once per enabling (enabling clears bits 9 and 10 of 0x60B9), in continuous mode
  every cycle with an edge. 0x60B9 bit 8: probe 2 enabled; bit 14 (user defined): the input's level at the end
  of the cycle (the NC's StateDWord3.TouchProbe1InputState).

It may import: numpy, nc_server.core.params, nc_server.drives.
"""
from __future__ import annotations

import math
import threading

import numpy as np

from ...core.params import AxisParams
from ..encoder import EncoderChain
from ..mechanics import Mechanics
from ..npcount import count_nonzero
from ..probe_pattern import check_probe_signal, first_pattern_edge, pattern_level, signal_edges
from . import statemachine as sm
from .image import RxImage, TxImage
from .objects import Mode, State

#: 0x603F of a drive whose outputs stopped arriving (CiA 301: life guard error / heartbeat error)
COMM_ERROR_CODE = 0x8130
#: 0x603F of ``set_device_error``-style hardware errors (CiA 301: device hardware)
HARDWARE_ERROR_CODE = 0x5000

_OE, _QSA, _FRA, _FLT = int(State.OPERATION_ENABLED), int(State.QUICK_STOP_ACTIVE), \
    int(State.FAULT_REACTION_ACTIVE), int(State.FAULT)
_CSV = int(Mode.CSV)
# 0x60B8 / 0x60B9 bits
PROBE_ENABLE, PROBE_CONTINUOUS, PROBE_SOURCE_INDEX, PROBE_POSITIVE = 0x01, 0x02, 0x04, 0x10
PROBE_STATUS_ENABLED, PROBE_STATUS_STORED, PROBE_STATUS_TOGGLE = 0x01, 0x02, 0x80
#: the probe function the NC uses for the sync pulse: enabled, continuous, source index pulse, positive edge
PROBE_SYNC_PULSE = PROBE_ENABLE | PROBE_CONTINUOUS | PROBE_SOURCE_INDEX | PROBE_POSITIVE
# probe 2 (the touch probe input of MC_TouchProbe): 0x60B8 bits 8-13, 0x60B9 bits 8-10 and 14
TP2_ENABLE, TP2_CONTINUOUS, TP2_SOURCE, TP2_POSITIVE, TP2_NEGATIVE = 0x0100, 0x0200, 0x0C00, 0x1000, 0x2000
TP2_STATUS_ENABLED, TP2_STATUS_POS_STORED, TP2_STATUS_NEG_STORED, TP2_STATUS_INPUT = 0x0100, 0x0200, 0x0400, 0x4000
_TP2_BITS = np.uint16(0xFF00)
# (0-d arrays of the bits a latch sets: an operation with a Python int converts it on every call)
_STORED, _TOGGLE = np.array(PROBE_STATUS_STORED, dtype=np.uint16), np.array(PROBE_STATUS_TOGGLE, dtype=np.uint16)


class Cia402Device:
    """``n`` simulated CiA 402 drives (columns), stepped once per device cycle.

    Attributes:
        cycle_time: the device cycle [s] (set at construction; what it derives is kept).
        timeout: seconds without outputs before the communication fault (None: never).
        state: power state per axis (int8 :class:`.objects.State`).
        position, velocity, acceleration: the motor [inc, inc/s, inc/s^2].
        error_code: 0x603F per axis.
        rx: the outputs in effect (the last that arrived).
        silent: seconds since outputs last arrived.
    """

    def __init__(self, n: int, cycle_time: float, timeout: float | None = None) -> None:
        self.n = int(n)
        self.cycle_time = float(cycle_time)
        self.timeout = timeout
        self.state = np.full(n, int(State.SWITCH_ON_DISABLED), dtype=np.int8)
        self.position = np.zeros(n)
        self._before = self.position  # the position at the start of the last step
        self.velocity = np.zeros(n)
        self.acceleration = np.zeros(n)
        self.error_code = np.zeros(n, dtype=np.uint16)
        self.rx = RxImage.zeros(n)
        self.silent = 0.0
        #: per axis, the motor stands whatever its target (a stalled stepper, ``cia402-sim``'s SimStall); None: none
        self.stalled: np.ndarray | None = None
        self._prev_cw = np.zeros(n, dtype=np.uint16)
        self._prev_tv = np.zeros(n)
        self._alpha = np.ones(n)
        self._dec = np.full(n, 5000.0)       # quick stop / fault reaction deceleration [inc/s^2]
        self._scale = np.ones(n)             # |AxisEncoderScalingFactor| [u/inc] (the mechanics work in u)
        self._unit_scale = True              # every scale is 1
        self._scale_dt = self._scale / self.cycle_time
        # (0-d arrays of the cycle's scalars: an operation with a Python float converts it on every call, one with a
        # 0-d float64 array does not -- the same IEEE operation, bit for bit)
        self._dt0 = np.array(self.cycle_time)
        self._ten = np.array(10.0)
        # the states and the modes of the last _move: their Operation enabled and CSV masks
        self._oe_key = b""
        self._oe = np.zeros(n, dtype=bool)
        self._n_oe = 0
        self._csv_of: np.ndarray | None = None
        self._csv = np.zeros(n, dtype=bool)
        self._any_csv = False
        self._pulse_spacing = np.ones(n)     # [inc]
        self._pulse_offset = np.zeros(n)     # [inc]
        self._event = np.zeros(n, dtype=bool)      # a transient fault waiting for its reaction
        self._event_code = np.zeros(n, dtype=np.uint16)
        self._cause = np.zeros(n, dtype=bool)      # a persistent fault cause
        self._cause_code = np.zeros(n, dtype=np.uint16)
        self._probe_status = np.zeros(n, dtype=np.uint16)
        self._probe_position = np.zeros(n)
        self._prev_probe_fn = np.zeros(n, dtype=np.uint16)
        self._probe_armed = np.zeros(n, dtype=bool)
        self._probe_armed_any = False
        self._probe_continuous = np.zeros(n, dtype=bool)
        self._all_continuous = n == 0  # every probe 1 in continuous mode (a latch never disarms it)
        # probe 2: the input (sensor pattern in axis units, or commanded levels) and its latch
        self._tp2_fn = np.zeros(n, dtype=np.uint16)  # 0x60B8 & 0xFF00 in effect
        self._tp2_on = False  # some probe 2 enabled
        self._tp2_pos = np.zeros(n)  # 0x60BC [inc]
        self._tp2_neg = np.zeros(n)  # 0x60BD [inc]
        self._tp2_period = np.zeros(n)  # SimProbePeriod [u] (0: no pattern)
        self._tp2_offset = np.zeros(n)
        self._tp2_width = np.zeros(n)
        self._tp2_rows = np.zeros(0, dtype=np.intp)  # the axes with a sensor pattern
        self._tp2_level = np.zeros(n, dtype=bool)  # the commanded input of the axes without one
        self._tp2_input = np.zeros(n, dtype=bool)  # the input at the end of the last step
        #: set_probe_signal events for the next step: axis -> [(offset [s], level)] (another thread may add them)
        self._tp2_pending: dict[int, list[tuple[float, bool]]] = {}
        self._tp2_lock = threading.Lock()
        # (the TxImage's arrays are replaced, never written: these are shared by every TxImage)
        self._no_torque = np.zeros(n)
        self._age0 = np.zeros(n, dtype=np.int64)
        self._alive = np.ones(n, dtype=bool)
        self._age0.flags.writeable = self._alive.flags.writeable = False  # (never written: the drive trusts them)
        self._chain = EncoderChain(n)
        self.mechanics = Mechanics(n, cycle_time)
        self._any_fault = False
        # _pulses_passed's work arrays
        self._pp_fa, self._pp_fb, self._pp_k = np.zeros(n), np.zeros(n), np.zeros(n)
        self._pp_c, self._pp_c2 = np.zeros(n, dtype=bool), np.zeros(n, dtype=bool)
        self._pp_kc = np.zeros(n)
        self._pp_plain = True  # every pulse offset +0.0 and spacing 1.0: (x - 0.0) / 1.0 is x, bit for bit
        self._sm_key = b""  # the states and controlwords of the last fault-free transition, its result and its bytes
        self._sm_new = self.state
        self._sm_new_key = b""
        self._sw_key = b""  # the states of the last statuswords published, and those (shared by the TxImages)
        self._sw = np.zeros(0, dtype=np.uint16)
        self.tx = TxImage.zeros(n)
        self._publish()

    def configure(self, i: int, params: AxisParams) -> None:
        """Axis ``i``'s simulation parameters: SimTimeConstant (the lag), AxisDec (the quick-stop ramp), the
        mechanics (Sim*), the index pulses (SimSyncPulseSpacing/Offset) and the encoder scaling they need."""
        self._chain.configure(i, params, self._chain.position(i, float(self.position[i])))
        scale = abs(float(params.AxisEncoderScalingFactor))
        self._scale[i] = scale
        self._unit_scale = bool(np.all(self._scale == 1.0))
        self._scale_dt = self._scale / self.cycle_time  # (s / dt of every step)
        t = float(params.SimTimeConstant)
        self._alpha[i] = 1.0 if t <= 0 else 1.0 - math.exp(-self.cycle_time / t)
        self._dec[i] = float(params.AxisDec) / scale
        self._pulse_spacing[i] = float(getattr(params, "SimSyncPulseSpacing", 1.0)) / scale
        self._pulse_offset[i] = self._chain.increments(i, float(getattr(params, "SimSyncPulseOffset", 0.0)))
        self._pp_plain = (self._pulse_offset.tobytes() == bytes(self._pulse_offset.nbytes)
                          and bool(np.all(self._pulse_spacing == 1.0)))
        self.mechanics.configure(i, params)
        period = float(getattr(params, "SimProbePeriod", 0.0))
        self._tp2_period[i] = period
        self._tp2_offset[i] = float(getattr(params, "SimProbeOffset", 0.0))
        self._tp2_width[i] = float(getattr(params, "SimProbeWidth", 0.0))
        if period > 0:  # the pattern decides the level from now on: commanded signals are dropped
            self._tp2_level[i] = False
            with self._tp2_lock:
                self._tp2_pending.pop(i, None)
        self._tp2_rows = np.flatnonzero(self._tp2_period > 0)
        self._tp2_update_input()

    # -- faults ---------------------------------------------------------------------------------------------

    def inject_fault(self, i: int, code: int, persistent: bool = False) -> None:
        """A fault of axis ``i`` with 0x603F ``code`` (e.g. 0x2310 overcurrent) from the next step: fault
        reaction (the quick-stop ramp), then Fault. ``persistent``: the cause stays until :meth:`clear_fault`
        (a fault reset before that is refused); else a fault reset acknowledges it.

        Raises:
            IndexError: no axis ``i``; ValueError: code outside 1..0xFFFF.
        """
        self._check(i)
        if not 0 < int(code) <= 0xFFFF:
            raise ValueError(f"error code must be in 1..0xFFFF, got {code}")
        if persistent:
            self._cause[i], self._cause_code[i] = True, int(code)
        else:
            self._event[i], self._event_code[i] = True, int(code)
        self._any_fault = True

    def clear_fault(self, i: int) -> None:
        """The persistent fault cause of axis ``i`` has gone (a fault reset may now acknowledge it)."""
        self._check(i)
        self._cause[i] = False
        self._cause_code[i] = 0
        self._any_fault = bool(self._event.any() or self._cause.any())

    def power_cycle(self, i: int) -> None:
        """Drive ``i`` restarts (its electronics rebooted): Switch on disabled, no fault, the motor at rest where it
        is (an absolute encoder: the position is kept), its outputs cleared until new ones arrive.

        Raises:
            IndexError: no axis ``i``.
        """
        self._check(i)

        def put(a: np.ndarray, v: float) -> np.ndarray:  # (a new array: TxImages and callers may hold the old)
            a = a.copy()
            a[i] = v
            return a
        self.state = put(self.state, int(State.SWITCH_ON_DISABLED))
        self.velocity, self.acceleration = put(self.velocity, 0.0), put(self.acceleration, 0.0)
        self.error_code = put(self.error_code, 0)
        self._event[i] = self._cause[i] = False
        self._event_code[i] = self._cause_code[i] = 0
        self._any_fault = bool(self._event.any() or self._cause.any())
        self._prev_cw = put(self._prev_cw, 0)
        rx = self.rx
        self.rx = RxImage(put(rx.controlword, 0), rx.mode.copy(), put(rx.target_position, float(self.position[i])),
                          put(rx.target_velocity, 0.0), put(rx.probe_function, 0), rx.cycle)
        self._probe_status[i] = 0
        self._publish()

    def _check(self, i: int) -> None:
        if not 0 <= int(i) < self.n:
            raise IndexError(f"no axis index {i}")

    # -- the cycle ------------------------------------------------------------------------------------------

    def step(self, rx: RxImage | None, owned: bool = False) -> TxImage:
        """One device cycle with the outputs that arrived (None: none arrived, the last ones stay in effect).

        Args:
            owned: the caller never writes the arrays of ``rx`` after this call (``cia402-sim``'s drive: it makes
                new arrays): the device keeps them instead of copies, and compares the probe function by identity
                once its values were equal (an array written in place after the call would go unseen).

        Returns:
            the inputs of this cycle (a new :class:`TxImage`, age 0, alive; its arrays are not written later).
        """
        dt = self.cycle_time
        if rx is None:
            self.silent += dt
        elif owned:
            self.rx = rx
            self.silent = 0.0
        else:  # (copies: a caller reusing its arrays must not change the last controlword, which edges compare)
            self.rx = RxImage(rx.controlword.copy(), rx.mode.copy(), rx.target_position.copy(),
                              rx.target_velocity.copy(), rx.probe_function.copy(), rx.cycle)
            self.silent = 0.0
        rx = self.rx
        comm_lost = self.timeout is not None and self.silent >= self.timeout
        state = self.state
        cw = rx.controlword
        key = state.tobytes() + cw.tobytes()
        if key == self._sm_key and not (self._any_fault or comm_lost):
            # the steady cycle: the states and controlwords of the last fault-free transition again (its states had no
            # drive in Fault (reaction): none now either), so its result (a copy: see _transition)
            new, new_key = self._sm_new.copy(), self._sm_new_key
        else:
            new, new_key = self._transition(state, cw, key, comm_lost)
        self.state = new
        self._prev_cw = cw
        self._move(new, rx, dt, new_key)
        self._latch(rx)
        if self._tp2_on or self._tp2_pending or len(self._tp2_rows):  # (nothing to do without probe 2 or input)
            self._latch2()
        self._publish(new_key)
        return self.tx

    def _transition(self, state: np.ndarray, cw: np.ndarray, key: bytes, comm_lost: bool) -> tuple[np.ndarray, bytes]:
        """The power states after this cycle's controlwords and faults, and their bytes (the fault codes with them)."""
        faulted = count_nonzero(state >= _FRA)  # some drive in Fault reaction active or Fault
        stopped: np.ndarray | bool = self.velocity == 0.0 if faulted else True
        if self._any_fault or comm_lost:
            fault = self._event | self._cause
            if comm_lost:
                fault = np.ones(self.n, dtype=bool)
            fresh = fault & (state < _FRA)
            if fresh.any():  # the code of the fault that starts the reaction
                code = np.where(self._cause, self._cause_code, self._event_code)
                if comm_lost:
                    code = np.where(self._event | self._cause, code, COMM_ERROR_CODE)
                self.error_code = np.where(fresh, code, self.error_code).astype(np.uint16)
            new = sm.device_next(state, cw, self._prev_cw, fault, stopped)
            self._event &= new < _FRA  # consumed by the reaction
            self._any_fault = bool(self._event.any() or self._cause.any())
        elif faulted:
            new = sm.device_next(state, cw, self._prev_cw, False, stopped)
        else:
            # no drive in Fault reaction active or Fault: the next states are a function of the states and the
            # controlwords alone, so while both stay (the steady cycle: every drive stays in Operation enabled under
            # 0x000F) step takes this result again without the table look-up (a copy each time: what it returns
            # becomes device.state, which a test may write in place; the one kept must stay this result)
            new = sm.device_next(state, cw, self._prev_cw, False, True)
            self._sm_key, self._sm_new, self._sm_new_key = key, new.copy(), new.tobytes()
            return new, self._sm_new_key
        if faulted:
            reset = (state == _FLT) & (new != _FLT)
            if reset.any():
                self.error_code = np.where(reset, 0, self.error_code).astype(np.uint16)
        return new, new.tobytes()

    def _move(self, state: np.ndarray, rx: RxImage, dt: float, key: bytes) -> None:
        """The motor's motion in this cycle (``key``: the bytes of ``state``)."""
        pos, v = self.position, self.velocity
        if key != self._oe_key:  # (the states change on events only)
            self._oe_key, self._oe = key, state == _OE
            self._n_oe = int(count_nonzero(self._oe))
        oe, n_oe = self._oe, self._n_oe
        if rx.mode is not self._csv_of:  # (an owned RxImage's mode is the same array every cycle)
            self._csv_of, self._csv = rx.mode, rx.mode == _CSV
            self._any_csv = bool(count_nonzero(self._csv))
        csv = self._csv
        stopping: np.ndarray | None = None
        if n_oe == self.n and not self._any_csv:  # the steady state: every drive follows its position target
            # (pos + alpha * (target - pos) in one new array: the same operations, + and * commute bit for bit)
            new_pos = np.subtract(rx.target_position, pos)
            new_pos *= self._alpha
            new_pos += pos
        else:
            stopping = (state == _QSA) | (state == _FRA)
            new_pos = pos.copy()
            if n_oe:
                p_csp = pos + self._alpha * (rx.target_position - pos)
                v_csv = v + self._alpha * (rx.target_velocity - v)
                new_pos = np.where(oe, np.where(csv, pos + v_csv * dt, p_csp), new_pos)
            if stopping.any():
                v_stop = np.sign(v) * np.maximum(np.abs(v) - self._dec * dt, 0.0)
                new_pos = np.where(stopping, pos + v_stop * dt, new_pos)
            else:
                stopping = None
        if self.stalled is not None:  # a stalled motor loses its field synchronism: it stands
            new_pos = np.where(self.stalled, pos, new_pos)
        new_v = np.subtract(new_pos, pos)  # ((new_pos - pos) / dt, dt as a 0-d array: one new array)
        new_v /= self._dt0
        if stopping is not None:  # (exactly 0 at the end of the ramp: "stopped")
            new_v = np.where(stopping & (np.abs(new_v) < 1e-12), 0.0, new_v)
        new_a = np.subtract(new_v, v)
        new_a /= self._dt0
        self._before = pos
        self.position, self.velocity, self.acceleration = new_pos, new_v, new_a
        delivering, k = (oe, n_oe) if stopping is None else (oe | stopping, None)
        tv = rx.target_velocity
        s = self._scale
        # (0x6077 shows the mechanics' ActTorque alone: the set-point's row is not computed)
        if self._unit_scale:  # (x * 1.0 is x, bit for bit: the mechanics copy their inputs)
            self.mechanics.step_actual(delivering, new_v, new_a, k)
        else:
            self.mechanics.step_actual(delivering, new_v * s, new_a * s, k)
        self._prev_tv = tv

    def _latch(self, rx: RxImage) -> None:
        fn = rx.probe_function
        if fn is not self._prev_probe_fn:
            if not np.array_equal(fn, self._prev_probe_fn):
                fn2 = np.asarray(fn, dtype=np.uint16) & _TP2_BITS
                if not np.array_equal(fn2, self._tp2_fn):
                    self._tp2_changed(fn2)
                self._probe_changed(fn)
            elif fn.dtype == np.uint16:  # (the same values in another array: compared by identity from now on)
                self._prev_probe_fn = fn
        if self._probe_armed_any:
            hit, x = self._pulses_passed()
            if hit is not None:  # (new arrays: the TxImages given out hold the old ones)
                self._probe_position = np.where(hit, x, self._probe_position)
                st = self._probe_status
                self._probe_status = np.where(hit, (st | _STORED) ^ _TOGGLE, st)
                if not self._all_continuous:  # single mode: latched once
                    self._probe_armed = self._probe_armed & (self._probe_continuous | ~hit)
                    self._probe_armed_any = bool(self._probe_armed.any())

    def _pulses_passed(self) -> tuple[np.ndarray | None, np.ndarray]:
        """The armed axes that passed an index pulse in this step (a mask; None: none) and the pulses [inc] (an
        array of every axis, valid where the mask is; both work arrays, valid until the next call):
        :func:`..encoder.pulse_passed` from the position before the step to the new one, bit for bit, with its work
        arrays kept (the crossing test for all axes; the pulses, for all axes too, only in a step that passed one).
        Its rule: moving up the last pulse index reached is floor(fb) and counts if > fa, moving down ceil(fb) if
        < fa (f = (position - offset) / spacing); floor(fb) > fa can only hold moving up and ceil(fb) < fa only moving
        down, so one test of both needs no direction (none holds when fa == fb or either is NaN)."""
        sp, off = self._pulse_spacing, self._pulse_offset
        k, c, c2 = self._pp_k, self._pp_c, self._pp_c2
        if self._pp_plain:  # (the positions themselves are f, bit for bit)
            fa, fb = self._before, self.position
        else:
            fa, fb = self._pp_fa, self._pp_fb
            np.subtract(self._before, off, out=fa)
            fa /= sp
            np.subtract(self.position, off, out=fb)
            fb /= sp
        kc = self._pp_kc
        np.floor(fb, k)
        np.greater(k, fa, c)
        np.ceil(fb, kc)
        np.less(kc, fa, c2)
        c |= c2
        c &= self._probe_armed
        if not count_nonzero(c):
            return None, kc
        # off + (floor(fb) if fb > fa else ceil(fb)) * spacing for all axes (fewer calls than gathering the rows
        # first; the same operations on each row's values); a NaN pulse is none
        np.greater(fb, fa, c2)
        np.copyto(kc, k, where=c2)
        if self._pp_plain:
            # (x * 1.0 is x; + 0.0 stays: it makes -0.0 +0.0. No NaN pulse: a crossing needs finite fa and fb,
            # and floor/ceil of a finite fb are finite, so c stands as it is)
            np.add(off, kc, kc)
            return c, kc
        kc *= sp
        np.add(off, kc, kc)
        np.equal(kc, kc, c2)
        c &= c2
        return (c if count_nonzero(c) else None), kc

    def _probe_changed(self, fn: np.ndarray) -> None:
        """0x60B8 changed: probe 1 enabled (again) or off, its mode, source and edge."""
        fn = np.asarray(fn, dtype=np.uint16)
        on = (fn & PROBE_ENABLE) != 0
        started = on & ((self._prev_probe_fn & PROBE_ENABLE) == 0)
        status = np.where(on, self._probe_status | PROBE_STATUS_ENABLED, self._probe_status & _TP2_BITS).astype(np.uint16)
        status = np.where(started, status & ~np.uint16(PROBE_STATUS_STORED), status).astype(np.uint16)
        self._probe_status = status
        self._probe_continuous = (fn & PROBE_CONTINUOUS) != 0
        self._all_continuous = count_nonzero(self._probe_continuous) >= self.n
        armed = on & ((fn & 0x0C) == PROBE_SOURCE_INDEX) & ((fn & PROBE_POSITIVE) != 0)
        # single mode: armed until a position is stored (a new enable edge arms it again)
        self._probe_armed = armed & (self._probe_continuous | ((status & PROBE_STATUS_STORED) == 0))
        self._probe_armed_any = bool(self._probe_armed.any())
        self._prev_probe_fn = fn

    # -- touch probe 2: the input MC_TouchProbe latches -------------------------------------------------------

    def _tp2_changed(self, fn2: np.ndarray) -> None:
        """Probe 2's bits of 0x60B8 changed: enabling clears the stored bits (first-event mode starts anew)."""
        on = (fn2 & TP2_ENABLE) != 0
        started = on & ((self._tp2_fn & TP2_ENABLE) == 0)
        st = self._probe_status
        st = np.where(on, st | TP2_STATUS_ENABLED, st & ~np.uint16(TP2_STATUS_ENABLED | TP2_STATUS_POS_STORED
                                                                    | TP2_STATUS_NEG_STORED))
        st = np.where(started, st & ~np.uint16(TP2_STATUS_POS_STORED | TP2_STATUS_NEG_STORED), st)
        self._probe_status = st.astype(np.uint16)
        self._tp2_fn = fn2
        self._tp2_on = bool(on.any())

    def set_probe_signal(self, i: int, level: bool, offset: float) -> None:
        """Command touch probe input 2 of axis ``i`` (without a sensor pattern): ``level`` from ``offset`` s into the
        next device cycle on (several calls before one step: several events; the same offset again replaces it).
        Thread-safe (the device may be stepped by another thread).

        Raises:
            IndexError: no axis ``i``.
            NotImplementedError: the axis has a sensor pattern (SimProbePeriod > 0), which alone decides its input.
            ValueError: offset outside 0 <= offset < cycle_time [s].
        """
        self._check(i)
        i = int(i)
        offset = check_probe_signal(i, float(self._tp2_period[i]), offset, self.cycle_time)
        with self._tp2_lock:
            events = self._tp2_pending.setdefault(i, [])
            events[:] = [e for e in events if e[0] != offset]
            events.append((offset, bool(level)))

    def _tp2_update_input(self) -> None:
        """The input level at the end of the last step (the pattern at the position, else the commanded level)."""
        level = self._tp2_level.copy()
        r = self._tp2_rows
        if len(r):
            u = self._chain.positions(self.position[r], r)
            level[r] = pattern_level(u, self._tp2_period[r], self._tp2_offset[r], self._tp2_width[r])
        self._tp2_input = level
        st = self._probe_status
        new = np.where(level, st | TP2_STATUS_INPUT, st & ~np.uint16(TP2_STATUS_INPUT)).astype(np.uint16)
        if not np.array_equal(new, st):
            self._probe_status = new

    def _latch2(self) -> None:
        """This cycle's edges of input 2 (commanded events, pattern crossings) and probe 2's latch."""
        with self._tp2_lock:
            pending, self._tp2_pending = self._tp2_pending, {}
        edges = signal_edges(pending, self._tp2_level, self.cycle_time)  # axis -> [(fraction, new level)]
        if self._tp2_on:
            fn, st = self._tp2_fn, self._probe_status
            on = ((fn & TP2_ENABLE) != 0) & ((fn & TP2_SOURCE) == 0)
            cont = (fn & TP2_CONTINUOUS) != 0
            want_pos = on & ((fn & TP2_POSITIVE) != 0) & (cont | ((st & TP2_STATUS_POS_STORED) == 0))
            want_neg = on & ((fn & TP2_NEGATIVE) != 0) & (cont | ((st & TP2_STATUS_NEG_STORED) == 0))
            for falling, want in ((False, want_pos), (True, want_neg)):
                rows = np.flatnonzero(want)
                if len(rows):
                    self._tp2_store(rows, falling, edges)
        self._tp2_update_input()

    def _tp2_store(self, rows: np.ndarray, falling: bool, edges: dict[int, list[tuple[float, bool]]]) -> None:
        """Latch the first edge of one kind in this cycle of the armed ``rows`` (0x60BC / 0x60BD, 0x60B9 bit 9 / 10)."""
        a, b = self._before[rows], self.position[rows]
        x = np.full(len(rows), np.nan)  # [inc]
        period, width = self._tp2_period[rows], self._tp2_width[rows]
        k = np.flatnonzero((width > 0) & (width < period) & (a != b))
        if len(k):
            rk = rows[k]
            ua, ub = self._chain.positions(a[k], rk), self._chain.positions(b[k], rk)
            ux = first_pattern_edge(np.full(len(k), falling), ua, ub, period[k], self._tp2_offset[rk], width[k])
            c = self._chain  # the chain's inverse: units -> increments
            x[k] = (ux - c.offset[rk]) / c.scaling[rk] * c.sign[rk] - c.base[rk]
        for j, i in enumerate(rows.tolist()):
            for f, level in edges.get(i, ()):
                if level != falling:  # rising: to True; falling: to False
                    x[j] = a[j] + f * (b[j] - a[j])
                    break
        hit = ~np.isnan(x)
        if not hit.any():
            return
        r, xs = rows[hit], x[hit]
        if falling:
            self._tp2_neg = self._tp2_neg.copy()  # (TxImages given out hold the old array)
            self._tp2_neg[r] = xs
        else:
            self._tp2_pos = self._tp2_pos.copy()
            self._tp2_pos[r] = xs
        st = self._probe_status.copy()
        st[r] |= np.uint16(TP2_STATUS_NEG_STORED if falling else TP2_STATUS_POS_STORED)
        self._probe_status = st

    def _cycle_stamp(self, cycle: int) -> np.ndarray:
        """A new array of ``cycle`` per axis (np.full's values; empty + fill: fewer calls)."""
        out = np.empty(self.n, dtype=np.int64)
        out.fill(cycle)
        return out

    def _publish(self, key: bytes | None = None) -> None:
        """This cycle's inputs (``key``: the bytes of :attr:`state`, where the caller has them)."""
        m = self.mechanics
        torque = self._no_torque if m.resting else m.fields[1] * self._ten
        if key is None:
            key = self.state.tobytes()
        if key != self._sw_key:  # (the statuswords change with the states only: the steady cycle reuses them)
            self._sw_key, self._sw = key, sm.statusword(self.state, follows=True)
        self.tx = TxImage(self._sw, self.rx.mode, self.position, self.velocity,
                          torque, self.error_code, self._probe_status, self._probe_position, self._tp2_pos,
                          self._tp2_neg, self._age0, self._alive,
                          self._cycle_stamp(self.rx.cycle))  # (the outputs these inputs answer)
