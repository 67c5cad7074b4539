"""Continuous motion: MoveVelocity, and MC_Jog (continuous modes at the manual velocities or the
block's, inching by a distance, inching modulo to the next multiple of the distance).

A velocity job reaches its velocity and keeps it (steady; a buffered successor starts then, as
PLCopen starts a buffered command after MC_MoveVelocity's InVelocity). Towards an enabled
software limit the NC stops it exactly at the limit and then raises 0x4462/0x4463 (the commanded
motion could not continue).
"""
from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any, Mapping

import numpy as np

from nc_schema import E_CmdTypeNewTargPosAndVelo as NPV
from nc_schema import E_JogMode, ErrorCodes, MC_Direction, NcError

from ..planning import Dynamics, Plan, StartState, plan_position, plan_velocity
from ..profile import stopping_distance
from .base import ALL_MODES, Job, JobKind
from .position import PositionKind, _switch_reached, change_or_arm, npv_request

if TYPE_CHECKING:
    from ..context import CoreContext

_POS = int(MC_Direction.MC_Positive_Direction)
_NEG = int(MC_Direction.MC_Negative_Direction)
_CUR = int(MC_Direction.MC_Current_Direction)
_EPS_V = 1e-9
#: Job.phase of a velocity job that is being stopped at a software limit
LIMIT_MAX, LIMIT_MIN = 1, -1


def direction_sense(d: int) -> float:
    """+1/-1 for MC_Positive_Direction/MC_Negative_Direction.

    Raises:
        NcError: 0x4B05 for any other direction (continuous motion needs one).
    """
    if d == _POS:
        return 1.0
    if d == _NEG:
        return -1.0
    raise NcError(ErrorCodes.MC_COMMAND_NOT_PERMITTED,
                  f"Direction {d}: continuous motion needs MC_Positive_Direction (1) or MC_Negative_Direction (3)")


def current_sense(core: CoreContext, i: int, followed: Job | None) -> float:
    """MC_Current_Direction of MC_MoveVelocity (TcMC 3.3 / 6.2): +1/-1, the direction of the current
    set velocity, fixed when the command is accepted. Decisions where the manual is silent: the set
    velocity is the axis's total one (a running superposition included: the direction the axis
    moves in); a command buffered behind ``followed`` takes the direction ``followed`` travels in
    (its velocity, end velocity, or the way to its target), as MC_MoveModulo does.

    Raises:
        NcError: 0x4B05 no direction: the axis is at rest (or the job it follows has none).
    """
    v = float(core.axes.set_velo[i])
    if followed is not None:
        start = followed.data.get("start")
        if followed.velocity:
            v = followed.velocity
        elif followed.end_velocity:
            v = followed.end_velocity
        elif followed.target is not None and followed.data.get("loop") is not None:
            v = followed.target - followed.data["loop"]  # (a loop movement ends on its return leg)
        elif followed.target is not None and start is not None and followed.target != start:
            v = followed.target - start
    if abs(v) <= _EPS_V:
        raise NcError(ErrorCodes.MC_COMMAND_NOT_PERMITTED,
                      "MC_Current_Direction: the axis is at rest, there is no current direction")
    return 1.0 if v > 0 else -1.0


class VelocityKind(JobKind):
    """MC_MoveVelocity (TcMC 3.3). Direction: MC_Positive_Direction, MC_Negative_Direction,
    MC_Current_Direction (:func:`current_sense`; at rest 0x4B05). MC_Shortest_Way is refused with
    0x4B05 (decision: an endless move has no target to be short to)."""

    name = "MoveVelocity"
    commands = ("MoveVelocity",)
    buffer_modes = ALL_MODES

    def accept(self, core: CoreContext, i: int, req: Mapping[str, Any], prev: Job | None) -> Job:
        v = req["Velocity"]
        core.check_velocity(i, v)
        d = req["Direction"]
        if d == _CUR:
            queued = prev is not None and req.get("BufferMode", 0) != 0
            sense = current_sense(core, i, prev if queued else None)
        else:
            sense = direction_sense(d)
        return Job(self, dict(req), dyn=core.dynamics(i, req, v), velocity=sense * v, continuous=True)

    def activate(self, core: CoreContext, i: int, job: Job, start: StartState) -> Plan:
        return activate_velocity(core, i, job, start)

    def replan(self, core: CoreContext, i: int, job: Job, start: StartState, override: float) -> Plan | None:
        if job.phase:
            return None  # stopping at a limit: the stop does not follow the override
        return core.plan(plan_velocity, start, job.velocity * override, job.dyn)

    def on_end(self, core: CoreContext, i: int, job: Job) -> str:
        return end_velocity(core, i, job)

    def successor_may_start(self, core: CoreContext, i: int, job: Job) -> bool:
        return bool(job.data.get("steady")) and not job.held

    def wants_watch(self, job: Job) -> bool:
        return "switch" in job.data or (bool(job.data.get("limits")) and not job.phase)

    def watch(self, core: CoreContext, rows: np.ndarray) -> None:
        queues = core.queues
        switch = np.array([("switch" in queues[i].active.data) for i in rows.tolist()], dtype=bool)
        if switch.any():
            _switch_reached(core, rows[switch])
        # (a row whose switch just made it a positioning is no velocity job any more)
        rest = [i for i in rows.tolist() if (j := queues[i].active) is not None and j.kind is self
                and j.data.get("limits") and not j.phase]
        if rest:  # stop exactly at an enabled software limit
            limit_approach(core, np.array(rest, dtype=np.intp))

    def amend(self, core: CoreContext, i: int, job: Job, req: Mapping[str, Any]) -> Plan | None:
        return amend_velocity(core, i, job, req)

    def apply_change(self, core: CoreContext, i: int, job: Job, base: int, new_pos: float, new_velo: float) -> Plan:
        """A switching-position change reached (:func:`.position._switch_reached`)."""
        return apply_velocity_change(core, i, job, base, new_pos, new_velo)


_TO_POSITION = PositionKind("MoveAbsolute")  # what an endless move becomes with a new target


def amend_velocity(core: CoreContext, i: int, job: Job, req: Mapping[str, Any]) -> Plan | None:
    """MC_NewPos / MC_NewPosAndVelo on an endless move (TcMC 3.7/3.8: "an axis in motion"):
    CHANGE_VELO gives it a new velocity (same direction); NewPos, CHANGE_POS and CHANGE_POSANDVELO
    turn it into a positioning to NewPos (same CmdNo, then Done there). The switching-position
    modes 9, 10, 11 (the same at ActivationPos) and 14 (NewVelo reached at ActivationPos) are armed
    as on a positioning and applied when the set position passes ActivationPos in the job's direction
    of travel (:func:`.position.arm_switch`: an ActivationPos already passed is refused with 0x427F).
    The values are checked when it is armed (0x4221 velocity, 0x4222 target), and once more when it
    is applied (a failure then is an axis error with that code, as on a positioning)."""
    mode, new_pos, new_velo, at = npv_request(req)
    if job.phase:
        raise NcError(ErrorCodes.MC_COMMAND_NOT_PERMITTED, "the axis is being stopped at a software limit")
    return change_or_arm(core, i, job, mode, new_pos, new_velo, at, apply_velocity_change)


def apply_velocity_change(core: CoreContext, i: int, job: Job, base: int, new_pos: float, new_velo: float) -> Plan:
    """The change of an endless move (now, or at its switching position): ``base`` CHANGE_VELO a new
    velocity [u/s] in the same direction; with CHANGE_POS a positioning to ``new_pos`` [u] (at
    ``new_velo`` with CHANGE_POSANDVELO), the same CmdNo."""
    assert job.dyn is not None
    if base == int(NPV.CHANGE_VELO):
        core.check_velocity(i, new_velo)
        sense = 1.0 if job.velocity > 0 else -1.0
        dyn = job.dyn.with_(velocity=float(new_velo))
        start = core.start_state(i)
        plan = core.plan(plan_velocity, start, sense * new_velo * core.override(i), dyn)
        core.check_reversal(i, plan, start, sense)
        core.check_overshoot(i, plan, new_velo * core.override(i))
        job.velocity, job.dyn = sense * float(new_velo), dyn
        job.data["steady"] = False
        return plan
    trial = job.trial()
    trial.kind, trial.continuous, trial.velocity = _TO_POSITION, False, 0.0
    trial.data.pop("switch", None)
    if base & int(NPV.CHANGE_VELO):
        core.check_velocity(i, new_velo)
    core.check_target(i, core.nc_set_pos(i), new_pos)
    plan = _TO_POSITION.apply_change(core, i, trial, base, new_pos, new_velo)
    for name in ("kind", "target", "dyn", "end_velocity", "continuous", "velocity", "data"):
        setattr(job, name, getattr(trial, name))
    return plan


def activate_velocity(core: CoreContext, i: int, job: Job, start: StartState) -> Plan:
    a = core.axes
    sense = 1.0 if job.velocity > 0 else -1.0
    core.check_feed(i, sense)
    if sense > 0 and a.en_max[i] and start.p >= a.max_lim[i]:
        raise NcError(ErrorCodes.NC_SOFT_LIMIT_MAX_START, f"axis at {start.p} is at/beyond AxisMaxSoftPosLimit {a.max_lim[i]}")
    if sense < 0 and a.en_min[i] and start.p <= a.min_lim[i]:
        raise NcError(ErrorCodes.NC_SOFT_LIMIT_MIN_START, f"axis at {start.p} is at/beyond AxisMinSoftPosLimit {a.min_lim[i]}")
    ov = core.override(i)
    if start.v * sense > 0 and (a.en_max[i] if sense > 0 else a.en_min[i]):
        # with these dynamics the axis must still be able to stop before the limit
        assert job.dyn is not None
        need = float(stopping_distance(np.array([start.v]), np.array([start.a]), np.array([job.dyn.deceleration]),
                                       np.array([job.dyn.jerk]))[0])
        room = (a.max_lim[i] - start.p) if sense > 0 else (start.p - a.min_lim[i])
        if need > room:
            raise NcError(ErrorCodes.NC_TARGET_POSITION_NOT_ALLOWED,
                          f"with Deceleration {job.dyn.deceleration:g} the axis could not stop before the software limit")
    plan = core.plan(plan_velocity, start, job.velocity * ov, job.dyn)
    core.check_reversal(i, plan, start, sense)
    core.check_overshoot(i, plan, abs(job.velocity) * ov)
    job.held = ov <= 0
    job.phase = 0
    job.data["steady"] = False
    job.data["limits"] = bool(a.en_max[i] or a.en_min[i])
    return plan


def end_velocity(core: CoreContext, i: int, job: Job) -> str:
    if job.phase:  # stopped exactly at the limit: the commanded motion could not continue
        code = ErrorCodes.NC_SOFT_LIMIT_MAX_POSITIONING if job.phase == LIMIT_MAX else ErrorCodes.NC_SOFT_LIMIT_MIN_POSITIONING
        core.clear_profile(i)
        core.fault(i, code)
        return "continue"
    job.data["steady"] = True
    return "steady"


def limit_approach(core: CoreContext, rows: np.ndarray) -> None:
    """Stop continuous moves exactly at an enabled software limit (vectorized check)."""
    a = core.axes
    v = a.set_velo[rows]
    dec = np.empty(rows.size)
    jerk = np.empty(rows.size)
    for n, i in enumerate(rows.tolist()):
        d = core.queues[i].active.dyn
        dec[n], jerk[n] = d.deceleration, d.jerk
    d = stopping_distance(v, a.set_acc[rows], dec, jerk) + 2 * np.abs(v) * core.cycle_time
    pos = a.set_pos[rows]
    hit = (a.en_max[rows] & (v > 0) & (pos + d >= a.max_lim[rows])) | (a.en_min[rows] & (v < 0) & (pos - d <= a.min_lim[rows]))
    for i in rows[hit].tolist():
        job = core.queues[i].active
        assert job is not None and job.dyn is not None
        vi = float(a.set_velo[i])
        target = float(a.max_lim[i] if vi > 0 else a.min_lim[i])
        dyn = job.dyn.with_(velocity=max(abs(vi), job.dyn.velocity * core.override(i), 1e-9))
        try:
            plan = plan_position(core.start_state(i), target, dyn)
        except Exception:
            core.fault(i, ErrorCodes.NC_SOFT_LIMIT_MAX_POSITIONING if vi > 0 else ErrorCodes.NC_SOFT_LIMIT_MIN_POSITIONING)
            continue
        job.phase = LIMIT_MAX if vi > 0 else LIMIT_MIN
        core.set_plan(i, plan)
        a.target_pos[i] = target


class JogKind(JobKind):
    """MC_Jog's NC side. Modes (E_JogMode): STANDARD_SLOW/FAST: continuous at AxisVeloManSlow /
    AxisVeloManFast with the axis dynamics (the block's values are ignored); CONTINOUS: continuous
    with the block's Velocity and dynamics; INCHING: relative by Position (> 0) in Direction;
    INCHING_MODULO (Tc2_MC2): relative, the end rounded to the next multiple of Position in the
    direction of travel (from a multiple: exactly Position). Continuous jogs run until a Halt
    (the block sends it when the key is released) or any other command.

    Inching with Position 0 (zenoh-nc decision; the manual says only "relative distance"): the axis's jog
    increment of the direction, AxisJogIncrementForward / AxisJogIncrementBackward (MC_AxisPara 1013/1014,
    TwinCAT's inching distances), is the distance; an increment of 0 then refuses the jog with 0x4B06, as a
    Position <= 0 is. An inching jog is a positioning: it loops as any (AxisEnLoopingDistance) and follows
    AxisOverrideType."""

    name = "Jog"
    commands = ("Jog",)

    def __init__(self) -> None:
        self._pos = PositionKind("Jog")

    def accept(self, core: CoreContext, i: int, req: Mapping[str, Any], prev: Job | None) -> Job:
        mode = req["Mode"]
        sense = direction_sense(req["Direction"])
        p = core.params[i]
        if mode in (int(E_JogMode.MC_JOGMODE_STANDARD_SLOW), int(E_JogMode.MC_JOGMODE_STANDARD_FAST)):
            v = p.AxisVeloManSlow if mode == int(E_JogMode.MC_JOGMODE_STANDARD_SLOW) else p.AxisVeloManFast
            v = min(v, float(core.axes.vmax[i]))
            return Job(self, dict(req), dyn=core.dynamics(i, {}, v), velocity=sense * v, continuous=True,
                       data={"via": "velocity"})
        if mode not in (int(E_JogMode.MC_JOGMODE_CONTINOUS), int(E_JogMode.MC_JOGMODE_INCHING),
                        int(E_JogMode.MC_JOGMODE_INCHING_MODULO)):
            raise NcError(ErrorCodes.MC_INVALID_MODE, f"Mode {mode} is not an E_JogMode")
        v = req["Velocity"]
        core.check_velocity(i, v)
        dyn = core.dynamics(i, req, v)
        if mode == int(E_JogMode.MC_JOGMODE_CONTINOUS):
            return Job(self, dict(req), dyn=dyn, velocity=sense * v, continuous=True, data={"via": "velocity"})
        step = req["Position"]
        if step == 0:  # the axis's jog increment of this direction (taken when the jog is accepted)
            name = "AxisJogIncrementForward" if sense > 0 else "AxisJogIncrementBackward"
            step = getattr(p, name)
            if not step > 0:
                raise NcError(ErrorCodes.MC_PARAMETER_NOT_CORRECT, f"Position 0 and {name} is 0: no inching distance")
        if not step > 0:
            raise NcError(ErrorCodes.MC_PARAMETER_NOT_CORRECT, f"inching distance Position {step} must be > 0")
        start = core.nc_set_pos(i)
        if mode == int(E_JogMode.MC_JOGMODE_INCHING):
            target = start + sense * step
        else:
            k = start / step
            target = (math.floor(k + 1e-9) + 1) * step if sense > 0 else (math.ceil(k - 1e-9) - 1) * step
        return Job(self, dict(req), dyn=dyn, target=target, data={"via": "position"})

    def activate(self, core: CoreContext, i: int, job: Job, start: StartState) -> Plan:
        if job.data["via"] == "velocity":
            return activate_velocity(core, i, job, start)
        return self._pos.activate(core, i, job, start)

    def replan(self, core: CoreContext, i: int, job: Job, start: StartState, override: float) -> Plan | None:
        if job.data["via"] == "velocity":
            return None if job.phase else core.plan(plan_velocity, start, job.velocity * override, job.dyn)
        return self._pos.replan(core, i, job, start, override)

    def override_replan(self, core: CoreContext, i: int, job: Job, start: StartState, old: float,
                        new: float) -> Plan | None:
        if job.data["via"] == "velocity":
            return self.replan(core, i, job, start, new)
        return self._pos.override_replan(core, i, job, start, old, new)  # (inching: AxisOverrideType)

    def goal(self, job: Job) -> float | None:
        return self._pos.goal(job) if job.data["via"] == "position" else job.target

    def shift(self, job: Job, diff: float) -> None:
        if job.data["via"] == "position":
            self._pos.shift(job, diff)  # (a loop point moves with the axis)
        else:
            super().shift(job, diff)

    def on_end(self, core: CoreContext, i: int, job: Job) -> str:
        if job.data["via"] == "velocity":
            return end_velocity(core, i, job)
        return self._pos.on_end(core, i, job)

    def wants_watch(self, job: Job) -> bool:
        return job.data["via"] == "velocity" and bool(job.data.get("limits")) and not job.phase

    def watch(self, core: CoreContext, rows: np.ndarray) -> None:
        limit_approach(core, rows)

    def blend_point(self, job: Job) -> tuple[float, float, float] | None:
        return None


def kinds() -> list[JobKind]:
    return [VelocityKind(), JogKind()]


__all__ = ["VelocityKind", "JogKind", "kinds", "direction_sense", "Dynamics"]
