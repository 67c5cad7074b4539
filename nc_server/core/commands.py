"""Axis commands: start checks with the TwinCAT error codes, and their effect.

Every check runs before anything is changed: a rejected command leaves the axis,
its running job and its parameters exactly as they were.

Choices where the manual is silent (documented here, see also schema/README.md):

* An axis in ErrorStop rejects motion commands with 0x4B01 ("axis cannot be
  started"), the text naming the axis error. MC_Stop is accepted in every state.
* MC_Reset clears the error and the MC_Stop lock and makes the set position the
  actual position. If a fault or MC_Stop ramp still runs, the ramp goes on as a
  numbered stop job: the axis shows Stopping until it stands, then StandStill (never
  StandStill while moving). A moving axis without an error is left alone.
* Stopping an accelerating axis never uses a softer jerk than its running profile
  (TcMC 3.15); a move whose new dynamics would overshoot both the new and the running
  velocity is refused with 0x423A.
* Acceleration/Deceleration/Jerk = 0 select the axis defaults (AxisAcc, AxisDec,
  AxisJerk); negative values are rejected (0x422F/0x4230/0x422E).
* MC_Stop: Deceleration and Jerk count only together (TcMC 3.15); a lone one is
  ignored (the axis defaults are used: a stop is never refused); a second MC_Stop
  during a stop ramp never makes the ramp weaker.
* MoveVelocity towards an enabled software limit: the NC stops the axis exactly
  at the limit and then raises 0x4462/0x4463 (the commanded motion could not
  continue).
"""
from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import numpy as np

from nc_schema import CmdState, ErrorCodes, MC_Direction, NcError, error_name, next_cmdno

from .axes import JOB_HALT, JOB_NONE, JOB_POSITION, JOB_STOP, JOB_VELOCITY, RAMP_FAULT, RAMP_NONE
from .profile import Limits, PlanningError, peak_velocity

if TYPE_CHECKING:
    from .nc import NcCore

#: largest |position| the NC accepts as a target (ruckig's numeric range)
MAX_POSITION = 1e9


def modulo_target(set_pos: float, target: float, period: float, tolerance: float, direction: int,
                  current_velo: float = 0.0) -> float:
    """Absolute end position of a modulo start (TcMC manual 3.5, tables included).

    Args:
        set_pos: current set position [u] (modulo starts refer to the set position).
        target: modulo target [u], >= 0; >= period adds full turns (not for the shortest way).
        period: modulo period (AxisEncoderModuloValue) [u].
        tolerance: modulo tolerance window (AxisModuloToleranceWindow) [u].
        direction: MC_Direction value.
        current_velo: current set velocity, for MC_Current_Direction.

    Raises:
        NcError: 0x4282 invalid modulo target, 0x4B04 invalid direction.
    """
    if direction not in (1, 2, 3, 4):
        raise NcError(ErrorCodes.MC_INVALID_MODE, f"Direction {direction} is not an MC_Direction")
    if not 0.0 <= target < MAX_POSITION:
        raise NcError(ErrorCodes.NC_MODULO_TARGET_INVALID, f"modulo target {target} must be >= 0")
    if direction == int(MC_Direction.MC_Current_Direction):
        direction = 3 if current_velo < 0 else 1
    base = math.floor(set_pos / period) * period
    if direction == int(MC_Direction.MC_Shortest_Way):
        if target >= period:
            raise NcError(ErrorCodes.NC_MODULO_TARGET_INVALID,
                          f"modulo target {target} must be < {period} for MC_Shortest_Way")
        diff = (base + target) - set_pos
        diff = (diff + period / 2) % period - period / 2
        return set_pos + diff
    turns = math.floor(target / period)
    rest = target - turns * period
    end = base + rest
    if direction == int(MC_Direction.MC_Positive_Direction):
        if end < set_pos - tolerance:
            end += period
        return end + turns * period
    if end > set_pos + tolerance:
        end -= period
    return end - turns * period


class CommandsMixin:
    """The command handlers of :class:`~nc_server.core.nc.NcCore`."""

    # -- helpers -----------------------------------------------------------------------------
    def _dynamics(self: NcCore, i: int, req: dict[str, Any], velocity: float | None) -> Limits:
        a = self.axes
        acc = req.get("Acceleration", 0.0) or 0.0
        dec = req.get("Deceleration", 0.0) or 0.0
        jerk = req.get("Jerk", 0.0) or 0.0
        if acc < 0:
            raise NcError(ErrorCodes.NC_ACCELERATION_NOT_ALLOWED, f"Acceleration {acc} < 0")
        if dec < 0:
            raise NcError(ErrorCodes.NC_DECELERATION_NOT_ALLOWED, f"Deceleration {dec} < 0")
        if jerk < 0:
            raise NcError(ErrorCodes.NC_JERK_NOT_ALLOWED, f"Jerk {jerk} < 0")
        # outside these ranges ruckig's numerics fail; say which value instead of 'internal error'
        for name, x, lo, hi, code in (("Acceleration", acc, 1e-6, 1e10, ErrorCodes.NC_ACCELERATION_NOT_ALLOWED),
                                      ("Deceleration", dec, 1e-6, 1e10, ErrorCodes.NC_DECELERATION_NOT_ALLOWED),
                                      ("Jerk", jerk, 1e-6, 1e12, ErrorCodes.NC_JERK_NOT_ALLOWED)):
            if x and not lo <= x <= hi:
                raise NcError(code, f"{name} {x:g} outside {lo:g}..{hi:g}")
        v = a.vmax[i] if velocity is None else velocity
        return Limits(v, acc or a.acc[i], dec or a.dec[i], jerk or a.jerk[i])

    def _check_velocity(self: NcCore, i: int, v: float) -> None:
        if not v >= 1e-9 or v > self.axes.vmax[i] * (1 + 1e-12):
            raise NcError(ErrorCodes.NC_VELOCITY_NOT_ALLOWED,
                          f"Velocity {v} must be > 0 and <= AxisVeloMax {self.axes.vmax[i]}")

    def _check_startable(self: NcCore, i: int, req: dict[str, Any]) -> None:
        a = self.axes
        if a.error[i]:
            raise NcError(ErrorCodes.MC_AXIS_CANNOT_BE_STARTED,
                          f"axis {int(a.ids[i])} is in ErrorStop ({error_name(int(a.error[i]))} 0x{int(a.error[i]):04X}); MC_Reset first")
        if a.locked[i]:
            raise NcError(ErrorCodes.NC_AXIS_LOCKED_BY_STOP, "MC_Stop is active; release it (Execute FALSE) or MC_Reset")
        if not self._enabled_input(i):
            raise NcError(ErrorCodes.NC_NO_ENABLE, "controller enable is off (MC_Power)")
        if not self.drive.ready[i]:
            raise NcError(ErrorCodes.NC_DRIVE_NOT_READY_AT_START, "drive not ready")
        if req.get("BufferMode", 0) != 0:
            raise NcError(ErrorCodes.MC_BUFFERMODE_NOT_SUPPORTED,
                          f"BufferMode {req.get('BufferMode')}: only MC_Aborting (0) is supported")

    def _check_feed(self: NcCore, i: int, sense: float) -> None:
        plus, minus = self._feed_input(i)
        if sense > 0 and not plus:
            raise NcError(ErrorCodes.NC_NO_ENABLE, "feed enable plus is off (MC_Power.Enable_Positive)")
        if sense < 0 and not minus:
            raise NcError(ErrorCodes.NC_NO_ENABLE, "feed enable minus is off (MC_Power.Enable_Negative)")

    def _check_limits(self: NcCore, i: int, start: float, target: float, lo: float, hi: float) -> None:
        a = self.axes
        if a.en_max[i] and target > a.max_lim[i]:
            if start > a.max_lim[i] and target >= start:
                raise NcError(ErrorCodes.NC_SOFT_LIMIT_MAX_START, f"axis at {start} is beyond AxisMaxSoftPosLimit {a.max_lim[i]}")
            raise NcError(ErrorCodes.NC_TARGET_POSITION_NOT_ALLOWED, f"target {target} > AxisMaxSoftPosLimit {a.max_lim[i]}")
        if a.en_min[i] and target < a.min_lim[i]:
            if start < a.min_lim[i] and target <= start:
                raise NcError(ErrorCodes.NC_SOFT_LIMIT_MIN_START, f"axis at {start} is beyond AxisMinSoftPosLimit {a.min_lim[i]}")
            raise NcError(ErrorCodes.NC_TARGET_POSITION_NOT_ALLOWED, f"target {target} < AxisMinSoftPosLimit {a.min_lim[i]}")
        # the path may overshoot when the axis is moving (ruckig ignores position limits)
        if a.en_max[i] and hi > max(a.max_lim[i], start) + 1e-9:
            raise NcError(ErrorCodes.NC_TARGET_POSITION_NOT_ALLOWED, f"the move would overshoot AxisMaxSoftPosLimit ({hi:.6g})")
        if a.en_min[i] and lo < min(a.min_lim[i], start) - 1e-9:
            raise NcError(ErrorCodes.NC_TARGET_POSITION_NOT_ALLOWED, f"the move would overshoot AxisMinSoftPosLimit ({lo:.6g})")

    def _check_overshoot(self: NcCore, i: int, seg: np.ndarray, v_new: float) -> None:
        """Refuse (0x423A) a new profile that would exceed both the new and the running command's
        velocity, or AxisVeloMax: it happens when weaker dynamics meet an accelerating axis."""
        a = self.axes
        running = a.cmd_velo[i] * a.override[i] if a.traj_on[i] else 0.0
        cap = min(max(v_new, running, abs(a.set_velo[i])), a.vmax[i])
        peak = peak_velocity(seg)
        if peak > cap * (1 + 1e-6) + 1e-9:
            raise NcError(ErrorCodes.NC_VELOCITY_OVERFLOW,
                          f"the new dynamics would overshoot to {peak:.6g} u/s (limit {cap:.6g}); use a higher Jerk")

    def _start_job(self: NcCore, i: int, kind: int, seg: np.ndarray, duration: float, lim: Limits) -> int:
        """Make the planned profile the axis's job; returns its CmdNo."""
        a = self.axes
        self._end_job(i, CmdState.ABORTED)
        a.set_segments(i, seg, duration)
        a.job[i] = kind
        a.ramp[i] = RAMP_NONE
        a.hold_zero[i] = False
        a.limit_stop[i] = 0
        a.cmd_velo[i], a.cmd_acc[i], a.cmd_dec[i], a.cmd_jerk[i] = lim.velocity, lim.acceleration, lim.deceleration, lim.jerk
        if kind != JOB_STOP:
            a.hold_enable[i] = False  # only a fault's (or a later MC_Stop's) stop ramp holds the drive
        a.cmd_no[i] = next_cmdno(int(a.cmd_no[i]))
        a.cmd_state[i] = int(CmdState.ACTIVE)
        a.stopped[i] = kind == JOB_STOP
        a.since_end[i] = -1.0
        a.window_timer[i] = 0.0
        a.in_target[i] = a.in_area[i] = False
        return int(a.cmd_no[i])

    def _end_job(self: NcCore, i: int, state: CmdState) -> None:
        a = self.axes
        if a.job[i] != JOB_NONE and a.cmd_state[i] == int(CmdState.ACTIVE):
            a.cmd_state[i] = int(state)
        a.job[i] = JOB_NONE

    def _plan_position(self: NcCore, i: int, target: float, lim: Limits) -> tuple[np.ndarray, float, float, float]:
        a = self.axes
        v = lim.velocity * a.override[i]
        if v <= 0:  # override 0: start as a hold, the job waits for override
            seg, dur = self.planner.velocity(a.set_pos[i], a.set_velo[i], a.set_acc[i], 0.0, lim)
            return seg, dur, min(a.set_pos[i], target), max(a.set_pos[i], target)
        return self.planner.position(a.set_pos[i], a.set_velo[i], a.set_acc[i], target,
                                     Limits(v, lim.acceleration, lim.deceleration, lim.jerk))

    # -- commands ----------------------------------------------------------------------------
    def _cmd_position(self: NcCore, i: int, req: dict[str, Any]) -> dict[str, Any]:
        a = self.axes
        self._check_startable(i, req)
        v = req["Velocity"]
        self._check_velocity(i, v)
        lim = self._dynamics(i, req, v)
        start = float(a.set_pos[i])
        cmd = req["cmd"]
        if cmd == "MoveAbsolute":
            target = req["Position"]
        elif cmd == "MoveRelative":
            target = start + req["Distance"]
        else:  # MoveModulo
            period = self.params[i].AxisEncoderModuloValue
            target = modulo_target(start, req["Position"], period, self.params[i].AxisModuloToleranceWindow,
                                   req["Direction"], float(a.set_velo[i]))
        if not abs(target) < MAX_POSITION:
            raise NcError(ErrorCodes.NC_TARGET_POSITION_NOT_ALLOWED, f"target {target} outside +/-{MAX_POSITION:g}")
        self._check_feed(i, target - start if target != start else 0.0)
        try:
            seg, dur, lo, hi = self._plan_position(i, target, lim)
        except PlanningError as exc:
            raise NcError(ErrorCodes.NC_INTERNAL, f"set-point generation failed: {exc}") from None
        self._check_limits(i, start, target, lo, hi)
        self._check_overshoot(i, seg, lim.velocity * a.override[i])
        no = self._start_job(i, JOB_POSITION, seg, dur, lim)
        a.goal_pos[i] = target
        a.target_pos[i] = target
        a.hold_zero[i] = a.override[i] <= 0
        return {"cmd_no": no}

    def _cmd_velocity(self: NcCore, i: int, req: dict[str, Any]) -> dict[str, Any]:
        a = self.axes
        self._check_startable(i, req)
        v = req["Velocity"]
        self._check_velocity(i, v)
        d = req["Direction"]
        if d == int(MC_Direction.MC_Positive_Direction):
            sense = 1.0
        elif d == int(MC_Direction.MC_Negative_Direction):
            sense = -1.0
        else:
            raise NcError(ErrorCodes.MC_COMMAND_NOT_PERMITTED,
                          f"Direction {d}: continuous motion needs MC_Positive_Direction (1) or MC_Negative_Direction (3)")
        self._check_feed(i, sense)
        start = float(a.set_pos[i])
        if sense > 0 and a.en_max[i] and start >= a.max_lim[i]:
            raise NcError(ErrorCodes.NC_SOFT_LIMIT_MAX_START, f"axis at {start} is at/beyond AxisMaxSoftPosLimit {a.max_lim[i]}")
        if sense < 0 and a.en_min[i] and start <= a.min_lim[i]:
            raise NcError(ErrorCodes.NC_SOFT_LIMIT_MIN_START, f"axis at {start} is at/beyond AxisMinSoftPosLimit {a.min_lim[i]}")
        lim = self._dynamics(i, req, v)
        try:
            seg, dur = self.planner.velocity(start, a.set_velo[i], a.set_acc[i], sense * v * a.override[i], lim)
        except PlanningError as exc:
            raise NcError(ErrorCodes.NC_INTERNAL, f"set-point generation failed: {exc}") from None
        self._check_overshoot(i, seg, v * a.override[i])
        no = self._start_job(i, JOB_VELOCITY, seg, dur, lim)
        a.goal_velo[i] = sense * v
        a.target_pos[i] = start
        a.hold_zero[i] = a.override[i] <= 0
        return {"cmd_no": no}

    def _stop_limits(self: NcCore, i: int, req: dict[str, Any], kind: int) -> Limits:
        dec, jerk = req.get("Deceleration", 0.0), req.get("Jerk", 0.0)
        if kind == JOB_STOP and (dec > 0) != (jerk > 0):
            # TcMC 3.15: a non-zero value "will only be accepted" together with the other; a stop
            # must never be refused, so such a value is ignored and the axis defaults are used
            dec = jerk = 0.0
        lim = self._dynamics(i, {"Deceleration": dec, "Jerk": jerk}, None)
        a = self.axes
        if a.job[i] == JOB_STOP or a.ramp[i] == RAMP_FAULT:
            # never make a running stop weaker
            lim.deceleration = max(lim.deceleration, a.cmd_dec[i])
            lim.jerk = max(lim.jerk, a.cmd_jerk[i])
        lim.acceleration = max(lim.acceleration, lim.deceleration)
        lim.jerk = safe_stop_jerk(a, i, lim.jerk)
        return lim

    def _cmd_stop(self: NcCore, i: int, req: dict[str, Any], kind: int = JOB_STOP) -> dict[str, Any]:
        a = self.axes
        if kind == JOB_HALT:
            self._check_startable(i, req)
        lim = self._stop_limits(i, req, kind)
        try:
            seg, dur = self.planner.velocity(a.set_pos[i], a.set_velo[i], a.set_acc[i], 0.0, lim)
        except PlanningError as exc:
            raise NcError(ErrorCodes.NC_INTERNAL, f"set-point generation failed: {exc}") from None
        moving = bool(a.traj_on[i])
        no = self._start_job(i, kind, seg, dur, lim)
        if not moving:  # already standing: the stop is complete at once
            a.clear_profile(i)
            a.job[i] = JOB_NONE
            a.cmd_state[i] = int(CmdState.DONE)
        a.target_pos[i] = self.profile_end(i)
        if kind == JOB_STOP:
            a.locked[i] = True
        return {"cmd_no": no}

    def _cmd_stop_release(self: NcCore, i: int, req: dict[str, Any]) -> dict[str, Any]:
        self.axes.locked[i] = False
        return {}

    def _cmd_reset(self: NcCore, i: int, req: dict[str, Any]) -> dict[str, Any]:
        a = self.axes
        if a.traj_on[i]:
            if a.error[i] or a.locked[i]:
                # still braking: clear the error/lock now, but the ramp goes on as a numbered stop
                # job, so the axis shows Stopping (HasJob + HasBeenStopped) until it stands
                a.error[i] = 0
                a.locked[i] = False
                a.lag_timer[i] = 0.0
                if a.job[i] != JOB_STOP:
                    a.job[i] = JOB_STOP
                    a.ramp[i] = RAMP_NONE
                    a.stopped[i] = True
                    a.cmd_no[i] = next_cmdno(int(a.cmd_no[i]))
                    a.cmd_state[i] = int(CmdState.ACTIVE)
                    a.changed.append(i)
            return {}  # a moving axis without an error: nothing to reset
        a.error[i] = 0
        a.locked[i] = False
        a.stopped[i] = False
        a.lag_timer[i] = 0.0
        a.ramp[i] = RAMP_NONE
        a.hold_enable[i] = False
        # TwinCAT: after a reset the set position is the actual position
        a.set_pos[i] = self.drive.act_pos[i]
        a.target_pos[i] = a.set_pos[i]
        return {}

    def _cmd_set_override(self: NcCore, i: int, req: dict[str, Any]) -> dict[str, Any]:
        ov = req["Override"]
        if not 0.0 <= ov <= 100.0:
            raise NcError(ErrorCodes.MC_PARAMETER_NOT_CORRECT, f"Override {ov} % outside 0..100")
        self.plctonc["Override"][i] = round(ov * 10000.0)
        self._in_dirty = True
        return {}

    def _cmd_read_parameter(self: NcCore, i: int, req: dict[str, Any]) -> dict[str, Any]:
        return {"value": self.read_parameter(i, req["ParameterNumber"])}

    def _cmd_write_parameter(self: NcCore, i: int, req: dict[str, Any]) -> dict[str, Any]:
        self.write_parameter(i, req["ParameterNumber"], req["Value"])
        return {}

    # -- entry point -------------------------------------------------------------------------
    _HANDLERS: dict[str, str] = {
        "MoveAbsolute": "_cmd_position", "MoveRelative": "_cmd_position", "MoveModulo": "_cmd_position",
        "MoveVelocity": "_cmd_velocity", "Stop": "_cmd_stop", "StopRelease": "_cmd_stop_release",
        "Reset": "_cmd_reset", "SetOverride": "_cmd_set_override",
        "ReadParameter": "_cmd_read_parameter", "WriteParameter": "_cmd_write_parameter",
    }

    def _dispatch(self: NcCore, i: int, req: dict[str, Any]) -> dict[str, Any]:
        cmd = req["cmd"]
        if cmd == "Halt":
            return self._cmd_stop(i, req, JOB_HALT)
        name = self._HANDLERS.get(cmd)
        if name is None:
            raise NcError(ErrorCodes.ADSERR_DEVICE_SRVNOTSUPP, f"{cmd} is not an axis command of the NC core")
        return getattr(self, name)(i, req)


def safe_stop_jerk(a: Any, i: int, jerk: float) -> float:
    """A stop's jerk, raised so that stopping an accelerating axis cannot speed it up beyond
    what the running profile would have reached (TcMC 3.15: weaker dynamics are not used then)."""
    v0, a0 = a.set_velo[i], a.set_acc[i]
    if a.traj_on[i] and v0 * a0 > 0:
        jerk = max(jerk, a.cmd_jerk[i])
        cap = max(a.cmd_velo[i] * a.override[i], abs(v0))
        if cap > abs(v0):
            jerk = max(jerk, a0 * a0 / (2 * (cap - abs(v0))))
    return float(jerk)


def fault_ramp(core: NcCore, i: int) -> None:
    """Stop axis ``i`` after an error with AxisDec/AxisJerk (never weaker than a running stop)."""
    a = core.axes
    if not a.traj_on[i] and abs(a.set_velo[i]) == 0.0:
        return
    lim = Limits(a.vmax[i], max(a.acc[i], a.dec[i]), a.dec[i], a.jerk[i])
    if a.job[i] == JOB_STOP:
        lim.deceleration = max(lim.deceleration, a.cmd_dec[i])
        lim.jerk = max(lim.jerk, a.cmd_jerk[i])
    lim.jerk = safe_stop_jerk(a, i, lim.jerk)
    try:
        seg, dur = core.planner.velocity(a.set_pos[i], a.set_velo[i], a.set_acc[i], 0.0, lim)
    except PlanningError:
        a.clear_profile(i)  # cannot plan: stop the set-point at once
        return
    a.set_segments(i, seg, dur)
    a.cmd_dec[i], a.cmd_jerk[i] = lim.deceleration, lim.jerk
    a.ramp[i] = RAMP_FAULT
    a.hold_zero[i] = False
