"""The NC's pure checks: start conditions, command values, limits. Each reads the values it is
given and raises the TwinCAT error of the first failed check (``NcError``); none changes anything.

NcCore offers them to the job kinds per axis row (``core.check_target(i, ...)`` & co.,
:class:`~.context.CoreContext`); here they take the axis table and the row.

It may import: nc_schema, .planning, .profile, .params, .jobs.base (types only).
"""
from __future__ import annotations

from typing import TYPE_CHECKING, Any, Mapping

from nc_schema import ControlDWord, ErrorCodes, NcError, error_name

from .planning import Dynamics, Plan, StartState
from .profile import peak_velocity, velocity_extrema

if TYPE_CHECKING:
    from .axes import AxisTable
    from .jobs.base import Job, JobKind
    from .params import AxisParams

#: largest |position| the NC accepts as a target (ruckig's numeric range)
MAX_POSITION = 1e9
_EN = int(ControlDWord.Enable)
_FP = int(ControlDWord.FeedEnablePlus)
_FM = int(ControlDWord.FeedEnableMinus)
_ABORTING = 0  # MC_BufferMode.MC_Aborting


def check_startable(a: AxisTable, i: int, control: int, drive_ready: bool) -> None:
    """The axis accepts motion commands: no error, no MC_Stop lock, enabled (PLCTONC ``control``
    word), drive ready."""
    if a.error[i]:
        raise NcError(ErrorCodes.MC_AXIS_CANNOT_BE_STARTED,
                      f"axis {int(a.ids[i])} is in ErrorStop ({error_name(int(a.error[i]))} 0x{int(a.error[i]):04X}); MC_Reset first")
    if a.locked[i]:
        raise NcError(ErrorCodes.NC_AXIS_LOCKED_BY_STOP, "MC_Stop is active; release it (Execute FALSE) or MC_Reset")
    if not control & _EN:
        raise NcError(ErrorCodes.NC_NO_ENABLE, "controller enable is off (MC_Power)")
    if not drive_ready:
        raise NcError(ErrorCodes.NC_DRIVE_NOT_READY_AT_START, "drive not ready")


def check_feed(control: int, sense: float) -> None:
    """Raises NcError 0x4223 if the feed enable of direction ``sense`` is off in PLCTONC ``control``."""
    if sense > 0 and not control & _FP:
        raise NcError(ErrorCodes.NC_NO_ENABLE, "feed enable plus is off (MC_Power.Enable_Positive)")
    if sense < 0 and not control & _FM:
        raise NcError(ErrorCodes.NC_NO_ENABLE, "feed enable minus is off (MC_Power.Enable_Negative)")


def check_velocity(vmax: float, v: float) -> None:
    """Raises NcError 0x4221 unless 0 < v <= AxisVeloMax."""
    if not v >= 1e-9 or v > vmax * (1 + 1e-12):
        raise NcError(ErrorCodes.NC_VELOCITY_NOT_ALLOWED, f"Velocity {v} must be > 0 and <= AxisVeloMax {vmax}")


def command_dynamics(a: AxisTable, i: int, req: Mapping[str, Any], velocity: float | None) -> Dynamics:
    """The dynamics of a command: its Acceleration/Deceleration/Jerk, 0 = the axis defaults.

    Raises:
        NcError: 0x422F/0x4230/0x422E for negative or unusable values.
    """
    acc = req.get("Acceleration", 0.0) or 0.0
    dec = req.get("Deceleration", 0.0) or 0.0
    jerk = req.get("Jerk", 0.0) or 0.0
    # outside these ranges ruckig's numerics fail; say which value instead of 'internal error'
    for name, x, lo, hi, code in (("Acceleration", acc, 1e-6, 1e10, ErrorCodes.NC_ACCELERATION_NOT_ALLOWED),
                                  ("Deceleration", dec, 1e-6, 1e10, ErrorCodes.NC_DECELERATION_NOT_ALLOWED),
                                  ("Jerk", jerk, 1e-6, 1e12, ErrorCodes.NC_JERK_NOT_ALLOWED)):
        if x < 0:
            raise NcError(code, f"{name} {x} < 0")
        if x and not lo <= x <= hi:
            raise NcError(code, f"{name} {x:g} outside {lo:g}..{hi:g}")
    v = float(a.vmax[i]) if velocity is None else velocity
    return Dynamics(v, acc or float(a.acc[i]), dec or float(a.dec[i]), jerk or float(a.jerk[i]))


def check_target(a: AxisTable, i: int, start: float, target: float, plan: Plan | None = None) -> None:
    """Software limits for a move from ``start`` to ``target`` (and the plan's extrema).

    Raises:
        NcError: 0x4222 target beyond a limit (or the path would overshoot it), 0x4460/0x4461
            when the axis already stands beyond the limit and the move goes further.
    """
    if not abs(target) < MAX_POSITION:
        raise NcError(ErrorCodes.NC_TARGET_POSITION_NOT_ALLOWED, f"target {target} outside +/-{MAX_POSITION:g}")
    if a.en_max[i] and target > a.max_lim[i]:
        if start > a.max_lim[i] and target >= start:
            raise NcError(ErrorCodes.NC_SOFT_LIMIT_MAX_START, f"axis at {start} is beyond AxisMaxSoftPosLimit {a.max_lim[i]}")
        raise NcError(ErrorCodes.NC_TARGET_POSITION_NOT_ALLOWED, f"target {target} > AxisMaxSoftPosLimit {a.max_lim[i]}")
    if a.en_min[i] and target < a.min_lim[i]:
        if start < a.min_lim[i] and target <= start:
            raise NcError(ErrorCodes.NC_SOFT_LIMIT_MIN_START, f"axis at {start} is beyond AxisMinSoftPosLimit {a.min_lim[i]}")
        raise NcError(ErrorCodes.NC_TARGET_POSITION_NOT_ALLOWED, f"target {target} < AxisMinSoftPosLimit {a.min_lim[i]}")
    if plan is None:
        return
    # the path may overshoot when the axis is moving (ruckig ignores position limits)
    if a.en_max[i] and plan.p_max > max(a.max_lim[i], start) + 1e-9:
        raise NcError(ErrorCodes.NC_TARGET_POSITION_NOT_ALLOWED, f"the move would overshoot AxisMaxSoftPosLimit ({plan.p_max:.6g})")
    if a.en_min[i] and plan.p_min < min(a.min_lim[i], start) - 1e-9:
        raise NcError(ErrorCodes.NC_TARGET_POSITION_NOT_ALLOWED, f"the move would overshoot AxisMinSoftPosLimit ({plan.p_min:.6g})")


def running_jerk(a: AxisTable, i: int, job: Job | None) -> float:
    """The jerk [u/s^3] of the motion that runs now: of the running ``job``'s dynamics (trajectory
    mode), else AxisJerk (a coupling or the external generator drives the axis)."""
    if job is not None and job.dyn is not None and a.traj_on[i]:
        return float(job.dyn.jerk)
    return float(a.jerk[i])


def _committed_peak(v: float, acc: float, jerk: float) -> float:
    """|v| + the velocity the axis still gains in its direction of travel before an acceleration
    ``acc`` along it is brought to 0 with ``jerk``: the least peak any plan with that jerk has."""
    a_ahead = acc if v >= 0 else -acc
    return abs(v) + (a_ahead * a_ahead / (2 * jerk) if a_ahead > 0 else 0.0)


def check_overshoot(a: AxisTable, i: int, job: Job | None, plan: Plan, v_new: float) -> None:
    """Refuse (0x423A) a plan that would exceed both the new and the running motion's (``job``)
    velocity, or AxisVeloMax: it happens when weaker dynamics meet an accelerating axis (TcMC 4.20:
    "the velocity would exceed the parameterised travel speed due to weaker dynamic parameters").

    Not refused: a peak the running motion's jerk could not avoid either (an axis still speeding up
    after an override cut or a lower new velocity; the running motion overshoots the same way);
    refusing it would keep that very motion."""
    # (a stop's "velocity" is AxisVeloMax, not a velocity it runs at)
    dyn = job.dyn if job is not None and a.traj_on[i] and not job.kind.braking else None  # (of a moving job)
    running = dyn.velocity * a.override[i] if dyn is not None else 0.0
    cap = min(max(v_new, running, abs(a.set_velo[i])), a.vmax[i])
    peak = peak_velocity(plan.seg)
    if peak <= cap * (1 + 1e-6) + 1e-9:
        return
    committed = _committed_peak(float(plan.seg[2, 0]), float(plan.seg[3, 0]), running_jerk(a, i, job))
    if peak <= committed * (1 + 1e-6) + 1e-9:
        return
    raise NcError(ErrorCodes.NC_VELOCITY_OVERFLOW,
                  f"the new dynamics would overshoot to {peak:.6g} u/s (limit {cap:.6g}); use a higher Jerk")


def check_reversal(plan: Plan, start: StartState, sense: float, target: float | None = None,
                   jerk: float | None = None) -> None:
    """Refuse (0x4289) a plan that turns back on its way although the axis already heads that way
    (``sense``: the direction the command heads in, to its ``target`` or with its velocity).

    Decision (TcMC manual 4.20 MC_ChangeDynParam, the one place that names 0x4289: "If the axis is
    in a braking phase, and the direction of travel would reverse due to weaker dynamic parameters
    (negative acceleration cannot be reduced in time)"; 3.15 MC_Stop: weaker stop dynamics are not
    used in that case; 3.7/3.8 MC_NewPos/MC_NewPosAndVelo: "The new target position can be greater
    or smaller than the old target position"): 0x4289 is the refusal of a turn that the *new
    dynamics* cause. None of this NC's commands has a mode that forbids a reversal as such, so
    these turns are legal and not refused:

    * the axis moves against ``sense`` (a target behind it: MC_MoveAbsolute Aborting, MC_NewPos,
      MC_NewPosAndVelo brake and reverse; a velocity command of the other direction);
    * the plan passes its ``target`` first and comes back (a target within the braking distance);
    * the running motion turns the axis already: its acceleration against the direction of travel
      cannot be brought to 0 with the running ``jerk`` before the velocity crosses 0 (the running
      positioning reverses towards its own target), and the new plan turns no deeper than it must:
      its lowest velocity against ``sense`` is at most the unavoidable a^2 / (2 jerk) - |v|. A new
      command cannot keep the axis from turning that far (any plan with that jerk does); refusing
      it would keep the very reversal it would be refused for. (bench/nc_cycle.py's stress load: 9 %
      of its re-targets were refused so, all of them such states, 24..242 u/s past the point of no
      return; their plans, with the running jerk, turn exactly as deep.)

    What is refused is a turn, or the part of a turn, that the new dynamics cause: the axis heads
    towards ``sense``, and the new plan turns before its target while the running jerk could still
    stop the turn, or turns deeper than the running jerk has to (weaker dynamics: a lower Jerk of
    MC_ChangeDynParam or of a command; a plan that could only be made by turning back). Checked on
    every path that installs a new plan for a moving axis (start, blending successor,
    MC_ChangeDynParam, MC_NewPos/MC_NewPosAndVelo now or at a switching position); a refused command
    changes nothing, except a NewPosAndVelo armed for a switching position: checked when it fires,
    there is no reply to refuse it with, so the axis faults with the code (ErrorStop,
    :func:`.jobs.position._switch_reached`).
    ``jerk`` None: no running motion to compare with (every turn against ``sense`` is refused)."""
    if start.v * sense <= 0:
        return
    lo, hi = velocity_extrema(plan.seg)
    if not (lo < -1e-9 if sense > 0 else hi > 1e-9):
        return
    if target is not None and ((plan.p_max - target) if sense > 0 else (target - plan.p_min)) > 1e-9:
        return
    if jerk is not None:
        a_ahead = start.a * sense
        unavoidable = a_ahead * a_ahead / (2 * jerk) - abs(start.v) if a_ahead < 0 else 0.0
        # (strictly past the point of no return: a stop's last jerk phase ends exactly at v = 0
        # with a^2 / 2j = |v|, and a weaker jerk must not turn that one back)
        if unavoidable > 1e-9 * (1.0 + abs(start.v)):
            # the running motion turns the axis already: exempt as deep as it has to turn, no deeper (a
            # plan with the running jerk dips exactly so far: both from the same start state, excess 0.0
            # over the stress sequence; the tolerance is rounding, as check_overshoot's)
            deepest = -lo if sense > 0 else hi
            if deepest <= unavoidable + 1e-6 * max(abs(lo), abs(hi)) + 1e-9:
                return
    raise NcError(ErrorCodes.NC_ILLEGAL_REVERSAL,
                  "with these dynamics the braking axis would turn back on its way; use a higher Jerk")


def check_source(active: Job | None, kind: JobKind, p: AxisParams, axis_id: int, mode: int) -> None:
    """Motion commands to an axis a coupling or the external generator drives (TcMC / Tc2_MC2):
    refused unless its parameter allows them (then only Aborting: the command decouples /
    disables and takes over); MC_Stop always takes over; a second coupling is refused."""
    source = active.kind.source if active is not None else None
    if source is None or kind.always_allowed:
        return
    if kind.source == "coupling" and source == "coupling":
        return  # (the coupling kind decides: GearInDyn may take its own coupling over)
    if source == "coupling" and not p.AxisAllowMotionCmdToSlave:
        raise NcError(ErrorCodes.NC_SLAVE_COMMAND_NOT_ALLOWED,
                      f"axis {axis_id} is a coupled slave (AxisAllowMotionCmdToSlave is off)")
    if source == "external" and not p.AxisAllowMotionCmdToExtSetAxis:
        raise NcError(ErrorCodes.MC_AXIS_PROTECTED,
                      f"axis {axis_id} follows the external set-point generator "
                      "(AxisAllowMotionCmdToExtSetAxis is off; MC_ExtSetPointGenDisable first)")
    if mode != _ABORTING:
        raise NcError(ErrorCodes.MC_BUFFERMODE_NOT_SUPPORTED, "a command to a coupled/external axis can only be Aborting")


def check_running(a: AxisTable, i: int, job: Job | None, p: AxisParams, new: AxisParams) -> None:
    """Refuse parameters that the motion running now (``job``) would violate (the write would break it):

    * AxisVeloMax below the running command's velocity or the set velocity: 0x4221;
    * AxisAcc and AxisDec both below the set acceleration (coupled slaves, superpositions and the
      external generator are checked against them every cycle): 0x422F;
    * a software limit (enabled) that the running command's target or the set position lies beyond:
      0x4222.

    Raises:
        NcError: as above.
    """
    v = abs(float(a.set_velo[i]))
    if job is not None and job.dyn is not None and job.numbered:
        v = max(v, abs(job.dyn.velocity))
    if new.AxisVeloMax < p.AxisVeloMax and new.AxisVeloMax < v * (1 - 1e-12):
        raise NcError(ErrorCodes.NC_VELOCITY_NOT_ALLOWED,
                      f"AxisVeloMax {new.AxisVeloMax:g} is below the velocity of the running motion ({v:g})")
    acc = abs(float(a.set_acc[i]))
    if max(new.AxisAcc, new.AxisDec) < max(p.AxisAcc, p.AxisDec) and max(new.AxisAcc, new.AxisDec) < acc:
        raise NcError(ErrorCodes.NC_ACCELERATION_NOT_ALLOWED,
                      f"AxisAcc/AxisDec {max(new.AxisAcc, new.AxisDec):g} below the set acceleration {acc:g}")
    points = [("the set position", float(a.set_pos[i]))]
    if job is not None and job.numbered and job.target is not None:
        points.append(("the target of the running command", float(job.target)))
    for what, x in points:
        if new.AxisEnMaxSoftPosLimit and x > new.AxisMaxSoftPosLimit and not (
                p.AxisEnMaxSoftPosLimit and x > p.AxisMaxSoftPosLimit):
            raise NcError(ErrorCodes.NC_TARGET_POSITION_NOT_ALLOWED,
                          f"{what} {x:g} lies beyond the new maximum software limit {new.AxisMaxSoftPosLimit:g}")
        if new.AxisEnMinSoftPosLimit and x < new.AxisMinSoftPosLimit and not (
                p.AxisEnMinSoftPosLimit and x < p.AxisMinSoftPosLimit):
            raise NcError(ErrorCodes.NC_TARGET_POSITION_NOT_ALLOWED,
                          f"{what} {x:g} lies below the new minimum software limit {new.AxisMinSoftPosLimit:g}")
