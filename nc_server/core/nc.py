"""NcCore: the pure, cycle-stepped NC (no zenoh, no threads, no clock reads).

A test (or the server) drives it cycle by cycle::

    core = NcCore([AxisConfig(1, "X")], cycle_time=0.001)
    core.set_plctonc(0, enabled_record)
    reply = core.execute(parse_request(...), axis_id=1)
    core.step()
    core.nctoplc[0]["SetPos"]

Cycle order: inputs (PLCTONC) -> enable/override handling -> set-points for all
axes (vectorized profile evaluation) -> job ends -> soft-limit approach of
continuous moves -> feed enables -> drive -> monitoring -> NCTOPLC.
"""
from __future__ import annotations

import logging
from typing import Any, Sequence

import numpy as np

from nc_schema import (
    NCTOPLC_DTYPE, PLCTONC_DTYPE, AxisState, CmdState, ControlDWord, ErrorCodes, NcError, StateDWord, make_reply,
    motion_state_array,
)

from ..drives.base import DriveABC
from ..drives.sim import SimDrive
from .axes import JOB_HALT, JOB_NONE, JOB_POSITION, JOB_STOP, JOB_VELOCITY, RAMP_NONE, AxisTable
from .commands import CommandsMixin, fault_ramp
from .monitoring import monitor
from .params import STATUS_PARAMS, AxisConfig, AxisParams, ConfigError, param_name
from .profile import Limits, Planner, PlanningError, evaluate, stopping_distance

_log = logging.getLogger(__name__)
#: Cycles of set-points evaluated at once (NcCore(lookahead=...)); events refresh only the changed
#: axes. Deeper buffers lower the mean cost but make every LOOKAHEAD-th cycle heavier; measured here
#: (bench/nc_cycle.py) 16 suits up to ~64 axes and 4 beyond. None: chosen by axis count.
LOOKAHEAD: int | None = None
_EPS_V = 1e-9
_EN = int(ControlDWord.Enable)
_FP = int(ControlDWord.FeedEnablePlus)
_FM = int(ControlDWord.FeedEnableMinus)

# StateDWord bits
_B = {name: np.uint32(int(getattr(StateDWord, name))) for name in (
    "Operational", "Homed", "NotMoving", "InPositionArea", "InTargetPosition", "HasBeenStopped", "HasJob",
    "PositiveDirection", "NegativeDirection", "ConstantVelocity", "ContinuousMotion", "ControlLoopClosed",
    "PTPmode", "SoftLimitMinExceeded", "SoftLimitMaxExceeded", "MotionCommandsLocked", "Error")}


def _setpoint_luts() -> tuple[np.ndarray, np.ndarray]:
    """AxisState and set-point StateDWord bits for a packed flag byte of an axis following a profile.

    Flag bits: 0 hold (job waits at override 0), 1 constant acceleration (a == 0), 2 accelerating
    (a*v > 0), 3 decelerating (a*v < 0), 4 v > 0, 5 v < 0, 6 steady job (job and not holding).
    """
    states = np.zeros(128, dtype=np.uint32)
    dwords = np.zeros(128, dtype=np.uint32)
    for k in range(128):
        hold, const, accel, decel, pos, neg, steady = ((k >> b) & 1 for b in range(7))
        if hold:
            st = AxisState.OVERRIDE_ZERO
        elif const:
            st = AxisState.PHASE_VELOCONST
        elif accel:
            st = AxisState.PHASE_ACCPOS
        elif decel:
            st = AxisState.PHASE_ACCNEG
        else:
            st = AxisState.RUNNING
        states[k] = int(st)
        moving = pos or neg
        dw = 0 if moving else int(_B["NotMoving"])
        dw |= int(_B["PositiveDirection"]) if pos else 0
        dw |= int(_B["NegativeDirection"]) if neg else 0
        dw |= int(_B["ConstantVelocity"]) if steady and moving and const else 0
        dwords[k] = dw
    return states, dwords


_SP_STATE_LUT, _SP_DWORD_LUT = _setpoint_luts()


class NcCore(CommandsMixin):
    """All axes of one NC, stepped one fixed cycle at a time.

    Args:
        axes: the configured axes (ids must be unique).
        cycle_time: NC cycle time [s] (> 0).
        drive: the drives of all axes; default: a :class:`SimDrive`.

    Raises:
        ConfigError: duplicate axis ids, no axes, bad cycle time.
    """

    def __init__(self, axes: Sequence[AxisConfig], cycle_time: float = 0.001, drive: DriveABC | None = None,
                 lookahead: int | None = LOOKAHEAD) -> None:
        if not axes:
            raise ConfigError("axis", "at least one axis is needed")
        ids = [c.AxisId for c in axes]
        if len(set(ids)) != len(ids):
            raise ConfigError("axis.AxisId", f"duplicate axis ids in {ids}")
        if not 0 < cycle_time <= 1.0:
            raise ConfigError("cycle_time", f"must be in (0, 1] s, got {cycle_time}")
        self.cycle_time = float(cycle_time)
        if lookahead is None:
            lookahead = 16 if len(axes) <= 64 else 4
        self._lookahead = max(1, int(lookahead))
        self.configs = list(axes)
        self.params: list[AxisParams] = [c.params for c in axes]
        self.axes = AxisTable(ids, self.params)
        self.axis_ids = self.axes.ids
        self._index = {int(a): i for i, a in enumerate(ids)}
        self.drive = drive if drive is not None else SimDrive(self.params, self.cycle_time)
        self.planner = Planner()
        self.cycle = 0
        self.nc_time_ns = 0
        n = len(ids)
        self.plctonc = np.zeros(n, dtype=PLCTONC_DTYPE)
        self.plctonc[:] = self.default_plctonc()
        self._bits = np.zeros((n, 32), dtype=bool)  # event-driven StateDWord bits, packed in _derive_state
        self._bits[:, 25] = True  # PTPmode: every axis is a PTP axis
        self._buf = np.zeros((4, n, self._lookahead))        # set-points of the next self._lookahead cycles
        self._buf_dw = np.zeros((n, self._lookahead), dtype=np.uint32)  # their StateDWord bits
        self._buf_st = np.zeros((n, self._lookahead), dtype=np.uint32)  # their AxisState
        self._buf_k = self._lookahead
        self._lookahead_t = self.cycle_time * np.arange(1, self._lookahead + 1)
        self._sp_dw = np.zeros(n, dtype=np.uint32)
        self._off_rows = np.arange(n)
        self._flags: dict[tuple[int, int], np.ndarray] = {}  # scratch for _eval_into, by shape
        self._axis_state = np.zeros(n, dtype=np.uint32)
        self._opmode_sim = np.uint32(1 << 8) if self.drive.simulated else np.uint32(0)
        self.nctoplc = np.zeros(n, dtype=NCTOPLC_DTYPE)
        self.nctoplc["AxisId"] = self.axis_ids
        self.nctoplc["OpModeDWord"] = self.axes.opmode
        self._dt_ns = int(round(self.cycle_time * 1e9))
        self._in_dirty = True
        self._state_dirty = True
        self._apply_inputs()
        self._derive_state()
        self._fill_nctoplc()

    # -- public API --------------------------------------------------------------------------
    def index(self, axis_id: int) -> int:
        """Row of ``axis_id``.

        Raises:
            NcError: 0x4012 unknown axis.
        """
        try:
            return self._index[int(axis_id)]
        except (KeyError, TypeError, ValueError):
            raise NcError(ErrorCodes.NC_AXIS_ID_NOT_ALLOWED, f"no axis {axis_id!r} on this NC") from None

    @staticmethod
    def default_plctonc() -> np.void:
        """The PLCTONC applied when no client controls an axis: all enables off, override 100 %."""
        r = np.zeros((), dtype=PLCTONC_DTYPE)
        r["Override"] = 1_000_000
        return r[()]

    def set_plctonc(self, index: int, record: np.void | bytes | bytearray) -> None:
        """Apply a PLCTONC to axis row ``index`` from the next step.

        Raises:
            ValueError: a bytes record that is not 128 bytes.
        """
        if isinstance(record, (bytes, bytearray, memoryview)):
            if len(record) != PLCTONC_DTYPE.itemsize:
                raise ValueError(f"PLCTONC is {PLCTONC_DTYPE.itemsize} bytes, got {len(record)}")
            record = np.frombuffer(record, dtype=PLCTONC_DTYPE, count=1)[0]
        if self.plctonc[index].tobytes() != np.asarray(record, dtype=PLCTONC_DTYPE).tobytes():
            self.plctonc[index] = record
            self._in_dirty = True

    def set_plctonc_many(self, index: np.ndarray, records: np.ndarray) -> None:
        """Apply PLCTONC records to several axis rows at once (vectorized :meth:`set_plctonc`).

        Args:
            index: axis rows (int array).
            records: PLCTONC_DTYPE array of the same length.
        """
        new = np.ascontiguousarray(records, dtype=PLCTONC_DTYPE)
        old = self.plctonc[index]
        if old.tobytes() != new.tobytes():
            self.plctonc[index] = new
            self._in_dirty = True

    def execute(self, request: dict[str, Any], axis_id: int | None) -> dict[str, Any]:
        """Run one parsed request (``nc_schema.parse_request``) against an axis.

        Returns a reply map; never raises for bad input. The command takes effect
        in the next :meth:`step`, whose cycle number the reply carries.
        """
        cycle = self.cycle + 1
        rid, cmd = request.get("id"), request.get("cmd")
        self._state_dirty = True
        try:
            if axis_id is None:
                raise NcError(ErrorCodes.ADSERR_DEVICE_SRVNOTSUPP, f"{cmd} needs an axis key (nc/<nc>/axis/<id>/cmd)")
            i = self.index(axis_id)
            out = self._dispatch(i, request)
        except NcError as err:
            return make_reply(rid, cmd, err.code, str(err), cycle)
        except Exception as exc:  # a bug must cost one command, never the NC cycle
            _log.exception("command %r failed", cmd)
            return make_reply(rid, cmd, ErrorCodes.NC_INTERNAL, f"internal error: {exc.__class__.__name__}: {exc}", cycle)
        return make_reply(rid, cmd, 0, "", cycle, cmd_no=out.get("cmd_no"), value=out.get("value"))

    def fault(self, index: int, code: int) -> None:
        """Raise axis error ``code`` now and stop the axis with its deceleration.

        The first error sticks (like TwinCAT); the drive stays enabled until the
        stop ramp ends, whatever the PLCTONC says.
        """
        a = self.axes
        if a.error[index]:
            return
        self._state_dirty = True
        a.error[index] = code
        self._end_job(index, CmdState.ERROR)
        moving = bool(a.traj_on[index]) or abs(a.set_velo[index]) > 0
        if moving:
            fault_ramp(self, index)
            a.hold_enable[index] = bool(a.enabled[index])
        a.limit_stop[index] = 0

    @property
    def moving(self) -> np.ndarray:
        """Axes with a job or a non-zero set velocity."""
        return (self.axes.job != JOB_NONE) | (np.abs(self.axes.set_velo) > _EPS_V)

    def info(self) -> dict[str, Any]:
        return {"cycle_time": self.cycle_time,
                "axes": [{"AxisId": c.AxisId, "Name": c.Name, "Modulo": c.params.Modulo,
                          "ModuloFactor": c.params.AxisEncoderModuloValue} for c in self.configs]}

    def read_parameter(self, i: int, number: int) -> float | bool:
        """Value of MC_AxisPara ``number`` for axis row ``i``.

        Raises:
            NcError: 0x703 unknown parameter number.
        """
        if number in STATUS_PARAMS:
            return self._status_param(i, number)
        return getattr(self.params[i], param_name(number))

    def write_parameter(self, i: int, number: int, value: float | bool) -> None:
        """Write MC_AxisPara ``number``; validated, a rejected value changes nothing.

        Raises:
            NcError: 0x704 read-only, 0x703 unknown, 0x70B invalid value.
        """
        if number in STATUS_PARAMS:
            raise NcError(ErrorCodes.ADSERR_DEVICE_INVALIDACCESS, f"parameter {number} is read-only")
        name = param_name(number)
        if AxisParams.kind(name) == "bool" and not isinstance(value, bool):
            if value not in (0.0, 1.0):
                raise NcError(ErrorCodes.ADSERR_DEVICE_INVALIDPARM, f"{name} is boolean: 0/1 or true/false, got {value}")
            value = bool(value)
        try:
            new = self.params[i].with_value(name, value)
        except ConfigError as exc:
            raise NcError(ErrorCodes.ADSERR_DEVICE_INVALIDPARM, str(exc)) from None
        self.params[i] = new
        self.configs[i].params = new
        self.axes.load_params(i, new)
        self.drive.configure(i, new)
        self._state_dirty = True

    def step(self, nc_time_ns: int | None = None) -> None:
        """Run one NC cycle of ``cycle_time`` seconds.

        Args:
            nc_time_ns: the NC time of this cycle [ns]; default: previous + cycle_time.
        """
        a = self.axes
        dt = self.cycle_time
        self.cycle += 1
        self.nc_time_ns = int(nc_time_ns) if nc_time_ns is not None else self.nc_time_ns + self._dt_ns
        if self._in_dirty:
            self._apply_inputs()
        if self._state_dirty:
            self._derive_state()
        if self._off_rows.size:  # disabled axes: the set position follows the actual position
            a.set_pos[self._off_rows] = self.drive.act_pos[self._off_rows]

        # -- set-points: one column of the lookahead buffer (refilled every self._lookahead cycles or on events)
        on = self._on_rows
        if on.size:
            if self._buf_k >= self._lookahead:
                self._fill_buffer()
            k = self._buf_k
            self._buf_k = k + 1
            if self._all_on:
                a.traj_t += dt
                a.S[:] = self._buf[:, :, k]
                self._sp_dw[:] = self._buf_dw[:, k]
                self._axis_state[:] = self._buf_st[:, k]
                finished = (a.traj_t >= a.traj_dur).nonzero()[0]
            else:
                a.traj_t[on] += dt
                a.S[:, on] = self._buf[:, on, k]
                self._sp_dw[on] = self._buf_dw[on, k]
                self._axis_state[on] = self._buf_st[on, k]
                finished = on[a.traj_t[on] >= a.traj_dur[on]]
            if finished.size:
                self._profile_ends(finished)
            vel = self._vel_rows
            if vel.size:
                a.target_pos[vel] = a.set_pos[vel]
            cont = self._limit_rows  # continuous moves approaching an enabled software limit
            if cont.size:
                d = stopping_distance(a.set_velo[cont], a.set_acc[cont], a.cmd_dec[cont], a.cmd_jerk[cont])
                d += 2 * np.abs(a.set_velo[cont]) * dt
                hit = (a.en_max[cont] & (a.set_velo[cont] > 0) & (a.set_pos[cont] + d >= a.max_lim[cont])) | (
                    a.en_min[cont] & (a.set_velo[cont] < 0) & (a.set_pos[cont] - d <= a.min_lim[cont]))
                for i in cont[hit]:
                    self._stop_at_limit(int(i))
            feed = self._feed_rows  # moving axes with a feed enable missing in some direction
            if feed.size:
                plus, minus = self._feed_plus[feed], self._feed_minus[feed]
                v = a.set_velo[feed]
                for i in feed[~plus & (v > _EPS_V)]:
                    self.fault(int(i), ErrorCodes.NC_AXIS_FEED_ENABLE_PLUS)
                for i in feed[~minus & (v < -_EPS_V)]:
                    self.fault(int(i), ErrorCodes.NC_AXIS_FEED_ENABLE_MINUS)

        self.drive.step(a.enabled, a.set_pos, a.set_velo, a.set_acc)
        if self._state_dirty:  # a job ended this cycle: monitor it as standing already
            self._derive_state()

        # monitoring: new faults stop their axes from the next cycle
        for i, code in monitor(a, self.drive.act_pos, dt, self._watch):
            self.fault(i, code)
        if self._state_dirty:
            self._derive_state()
        self._fill_nctoplc()

    def _fill_buffer(self) -> None:
        """Evaluate the next self._lookahead cycles of every profile at once (and their set-point bits)."""
        self._buf_k = 0
        self._eval_into(self._on_rows)

    def _eval_into(self, rows: np.ndarray) -> None:
        """(Re)compute the buffer columns from ``_buf_k`` on for ``rows`` (their profiles changed)."""
        a = self.axes
        k0 = self._buf_k
        ncol = self._lookahead - k0
        m = rows.size
        t = (a.traj_t[rows][:, None] + self._lookahead_t[:ncol]).ravel()
        p, v, acc, j = evaluate(a.seg, t, np.repeat(rows, ncol))
        # one row (a command) or all rows: basic indexing, much cheaper than fancy indexing
        sel: int | slice | np.ndarray = int(rows[0]) if m == 1 else (slice(None) if m == a.n else rows)
        shape = (ncol,) if m == 1 else (m, ncol)
        buf = self._buf
        for r, x in enumerate((p, v, acc, j)):
            buf[r, sel, k0:] = x.reshape(shape)
        # set-point bits and AxisState: one packed flag byte per sample, two table lookups
        flags = self._flags.get((m, ncol))
        if flags is None:
            flags = self._flags[(m, ncol)] = np.zeros((m, ncol, 8), dtype=bool)
        flags[:, :, 0] = self._hold[rows][:, None]
        flags[:, :, 1] = (np.abs(acc) < 1e-9).reshape(m, ncol)
        av = (acc * v).reshape(m, ncol)
        flags[:, :, 2] = av > 0
        flags[:, :, 3] = av < 0
        v = v.reshape(m, ncol)
        flags[:, :, 4] = v > _EPS_V
        flags[:, :, 5] = v < -_EPS_V
        flags[:, :, 6] = (self._job[rows] & ~a.hold_zero[rows])[:, None]
        code = np.packbits(flags, axis=2, bitorder="little")[:, :, 0]
        self._buf_dw[sel, k0:] = _SP_DWORD_LUT[code].reshape(shape)
        self._buf_st[sel, k0:] = _SP_STATE_LUT[code].reshape(shape)

    # -- internals ---------------------------------------------------------------------------
    def _apply_inputs(self) -> None:
        """Decode the applied PLCTONC (only when it changed): enables, feed, override."""
        a = self.axes
        self._in_dirty = False
        ctrl = self.plctonc["ControlDWord"]
        self._enable_in = (ctrl & _EN) != 0
        self._feed_plus = (ctrl & _FP) != 0
        self._feed_minus = (ctrl & _FM) != 0
        ov = np.minimum(self.plctonc["Override"], 1_000_000) / 1_000_000.0
        changed = (ov != a.override).nonzero()[0]
        a.override = ov
        for i in changed:
            if a.traj_on[i] and a.job[i] in (JOB_POSITION, JOB_VELOCITY) and a.ramp[i] == RAMP_NONE and not a.limit_stop[i]:
                self._replan_override(int(i))
        self._state_dirty = True

    def _derive_state(self) -> None:
        """Recompute what only changes on events (commands, inputs, faults, job ends)."""
        self._state_dirty = False
        a, out = self.axes, self.nctoplc
        # PLCopen 'Enable FALSE -> Disabled': the job is aborted, an MC_Stop lock goes with it;
        # only a fault's stop ramp keeps the drive enabled until it ends
        enabled = self._enable_in | (a.hold_enable & a.traj_on)
        flips = (enabled != a.enabled).nonzero()[0]
        if flips.size:
            for i in flips.tolist():
                if enabled[i]:  # controller activation: set position := actual position
                    a.set_pos[i] = a.target_pos[i] = self.drive.act_pos[i]
                else:
                    self._end_job(i, CmdState.ABORTED)
                    a.ramp[i] = RAMP_NONE
                    a.locked[i] = False
                    a.hold_enable[i] = False
                    a.clear_profile(i)
            a.enabled = enabled
            self._off_rows = (~enabled).nonzero()[0]
        job = a.job != JOB_NONE
        self._job = job
        self._hold = job & a.hold_zero
        self._on_rows = a.traj_on.nonzero()[0]
        self._all_on = self._on_rows.size == a.n
        if a.changed:  # re-evaluate the rest of the buffer for the axes whose profile changed
            rows = np.array(sorted(set(a.changed)), dtype=np.intp)
            a.changed.clear()
            rows = rows[a.traj_on[rows]]
            if rows.size and self._buf_k < self._lookahead:
                self._eval_into(rows)
        velocity_job = a.job == JOB_VELOCITY
        self._vel_rows = velocity_job.nonzero()[0]
        self._limit_rows = (velocity_job & (a.limit_stop == 0) & (a.en_max | a.en_min)).nonzero()[0]
        driving = job & (a.job != JOB_STOP) & (a.job != JOB_HALT)
        self._feed_rows = (driving & ~(self._feed_plus & self._feed_minus)).nonzero()[0]
        standstill = ~(a.traj_on | job) & enabled
        self._watch = a.lag_en & enabled, standstill, bool((a.en_max | a.en_min).any()), bool(standstill.any())
        # axes without a profile: AxisState INACTIVE, NotMoving unless a set velocity remains
        idle = ~a.traj_on
        self._sp_dw[idle] = np.where(np.abs(a.set_velo[idle]) > _EPS_V, np.uint32(0), _B["NotMoving"])
        self._axis_state[idle] = 0
        err = a.error != 0
        ev = self._bits
        ev[:, 1] = a.homed                          # Homed
        ev[:, 7] = a.stopped                        # HasBeenStopped
        ev[:, 8] = job                              # HasJob
        ev[:, 19] = velocity_job                    # ContinuousMotion
        ev[:, 29] = a.locked                        # MotionCommandsLocked
        ev[:, 31] = err                             # Error
        self._event_dw = np.packbits(ev, axis=1, bitorder="little").view(np.uint32)[:, 0].copy()
        # ControlLoopClosed always, Operational only without an error (both need enable + drive ready)
        self._loop_dw = np.where(err, _B["ControlLoopClosed"], _B["ControlLoopClosed"] | _B["Operational"])
        out["ErrorCode"] = a.error
        out["SafEntries"] = job
        out["OpModeDWord"] = a.opmode | self._opmode_sim
        out["CmdNo"] = a.cmd_no
        out["CmdState"] = a.cmd_state
        out["TargetPos"] = a.target_pos

    def _enabled_input(self, i: int) -> bool:
        return bool(int(self.plctonc["ControlDWord"][i]) & _EN)

    def _feed_input(self, i: int) -> tuple[bool, bool]:
        c = int(self.plctonc["ControlDWord"][i])
        return bool(c & _FP), bool(c & _FM)

    def _profile_ends(self, rows: np.ndarray) -> None:
        a = self.axes
        for i in rows:
            i = int(i)
            job = int(a.job[i])
            if a.hold_zero[i] or job == JOB_VELOCITY and a.limit_stop[i] == 0:
                a.traj_dur[i] = np.inf  # steady tail (constant velocity / override-0 hold): not an end
                continue
            self._state_dirty = True
            if a.limit_stop[i]:
                code = ErrorCodes.NC_SOFT_LIMIT_MAX_POSITIONING if a.limit_stop[i] > 0 else ErrorCodes.NC_SOFT_LIMIT_MIN_POSITIONING
                a.limit_stop[i] = 0
                a.clear_profile(i)
                self.fault(i, code)
                continue
            if job == JOB_POSITION:
                a.set_pos[i] = a.goal_pos[i]  # exact end
                a.since_end[i] = 0.0
            a.clear_profile(i)
            if job != JOB_NONE:
                a.cmd_state[i] = int(CmdState.DONE)
                a.job[i] = JOB_NONE
            a.ramp[i] = RAMP_NONE
            a.hold_enable[i] = False  # standstill: the PLCTONC enables apply again
            a.target_pos[i] = a.set_pos[i] if job != JOB_POSITION else a.goal_pos[i]

    def _replan_override(self, i: int) -> None:
        a = self.axes
        lim = Limits(a.cmd_velo[i], a.cmd_acc[i], a.cmd_dec[i], a.cmd_jerk[i])
        ov = a.override[i]
        try:
            if a.job[i] == JOB_POSITION and ov > 0:
                seg, dur, _, _ = self.planner.position(a.set_pos[i], a.set_velo[i], a.set_acc[i], a.goal_pos[i],
                                                       Limits(lim.velocity * ov, lim.acceleration, lim.deceleration, lim.jerk))
            else:
                seg, dur = self.planner.velocity(a.set_pos[i], a.set_velo[i], a.set_acc[i],
                                                 a.goal_velo[i] * ov if a.job[i] == JOB_VELOCITY else 0.0, lim)
        except PlanningError:
            return  # keep the current profile
        a.set_segments(i, seg, dur)
        self._state_dirty = True
        a.hold_zero[i] = ov <= 0

    def _stop_at_limit(self, i: int) -> None:
        a = self.axes
        v = a.set_velo[i]
        target = a.max_lim[i] if v > 0 else a.min_lim[i]
        lim = Limits(max(abs(v), a.cmd_velo[i] * a.override[i], 1e-9), a.cmd_acc[i], a.cmd_dec[i], a.cmd_jerk[i])
        try:
            seg, dur, _, _ = self.planner.position(a.set_pos[i], v, a.set_acc[i], target, lim)
        except PlanningError:
            self.fault(i, ErrorCodes.NC_SOFT_LIMIT_MAX_POSITIONING if v > 0 else ErrorCodes.NC_SOFT_LIMIT_MIN_POSITIONING)
            return
        a.set_segments(i, seg, dur)
        self._state_dirty = True
        a.limit_stop[i] = 1 if v > 0 else -1
        a.target_pos[i] = target

    def profile_end(self, i: int) -> float:
        """Position where axis row ``i``'s current profile ends [u]."""
        a = self.axes
        if not a.traj_on[i]:
            return float(a.set_pos[i])
        p, _, _, _ = evaluate(a.seg, np.array([a.traj_dur[i]]), np.array([i]))
        return float(p[0])

    def _status_param(self, i: int, number: int) -> float:
        a, r = self.axes, self.nctoplc[i]
        names = {1: "SetPos", 10: "ActVelo", 11: "SetVelo"}
        if number in names:
            return float(r[names[number]])
        if number == 1000:
            return float(a.ids[i])
        if number == 2000:
            return float(a.target_pos[i])
        if number == 2001:
            return float(max(a.traj_dur[i] - a.traj_t[i], 0.0)) if a.job[i] == JOB_POSITION else 0.0
        if number == 2002:
            return float(abs(a.goal_pos[i] - a.set_pos[i])) if a.job[i] == JOB_POSITION else 0.0
        return float(4 if self.params[i].Modulo else 0)  # AxisUnitInterpretation: bit 2 = modulo

    def _fill_nctoplc(self) -> None:
        a, d, out = self.axes, self.drive, self.nctoplc
        act = d.act_pos
        sd = self._event_dw | self._sp_dw | a.mon_dw
        sd |= (a.enabled & d.ready) * self._loop_dw
        out["StateDWord"] = sd
        out["AxisState"] = self._axis_state
        period = a.modulo_factor
        out["ActPos"] = act
        out["ModuloActPos"] = act % period
        out["ModuloActTurns"] = act // period
        out["ActVelo"] = d.act_velo
        out["ActAcc"] = d.act_acc
        out["PosDiff"] = a.set_pos - act
        out["SetPos"] = a.set_pos
        out["SetVelo"] = a.set_velo
        out["SetAcc"] = a.set_acc
        out["SetJerk"] = a.set_jerk
        if self._vel_rows.size:
            out["TargetPos"] = a.target_pos
        out["ModuloSetPos"] = a.set_pos % period
        out["ModuloSetTurns"] = a.set_pos // period
        out["ActPosWithoutPosCorrection"] = act
        out["DcTimeStamp"] = self.nc_time_ns & 0xFFFFFFFF

    def motion_states(self) -> np.ndarray:
        """PLCopen state of every axis (the shared mapping, nc_schema.motion_state_array)."""
        return motion_state_array(self.nctoplc["StateDWord"], self.nctoplc["CoupleState"])
