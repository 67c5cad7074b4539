"""Stops: MC_Stop (locks), MC_Halt (a normal discrete motion to rest), MC_OrientedStop (to the next
reachable modulo position), and the NC's own ramps without a CmdNo (after an error; after a
buffered job that could not start).

MC_Stop (TcMC 3.15, https://infosys.beckhoff.com/content/1033/tcplclibmc/10988428555.html):
accepted in every state. Deceleration [u/s^2] and Jerk [u/s^3] 0 mean "from the move command":
the *effective* values of the job it stops (that job's inputs, or the axis defaults AxisDec /
AxisJerk where the job's were 0, as :func:`stopped_dynamics` reads them from the job). A job
without dynamics of its own (a coupling, the external set-point generator) and an axis without
a job: AxisDec/AxisJerk. MC_Halt does the same; a buffered MC_Halt takes them from the job it
follows. 3.15's exceptions hold: a stop is never weaker than a stop already running, its jerk
never lets an accelerating axis overshoot its velocity nor a braking one reverse, and weaker
dynamics that would pass the target (or an enabled software limit) are not used.

Decisions where the manual is silent or unclear:

* "A non zero value will only be accepted if a Jerk value is passed as well": a **lone non-zero
  Deceleration or Jerk is used**, with the stopped job's effective other value (ignoring it loses
  what was asked; refusing it would be an MC_Stop that does not stop).
* A negative (or out of range) Deceleration / Jerk is refused with 0x4230 / 0x422E and changes
  nothing, as for MC_Halt and every move (bad input gets its code; the block shows Error).

On an axis at rest it ends DONE in its first cycle (and locks).
"""
from __future__ import annotations

from typing import TYPE_CHECKING, Any, Mapping

from nc_schema import CmdState, ErrorCodes, NcError

from ..planning import Dynamics, Plan, StartState, hold, plan_position, plan_velocity
from ..profile import velocity_extrema
from .base import ALL_MODES, Job, JobKind
from .position import modulo_beyond_stop

if TYPE_CHECKING:
    from ..context import CoreContext

_EPS_V = 1e-9
#: check_target's software-limit refusals: for MC_OrientedStop fault conditions (TcMC 3.16), the
#: standard stop, then ERROR with the code: the target beyond the limit (0x4222), the axis already
#: beyond it and moving further out (0x4460 / 0x4461, e.g. after MC_SetActualPositionOnTheFly)
_LIMIT_FAULTS = frozenset({int(ErrorCodes.NC_TARGET_POSITION_NOT_ALLOWED), int(ErrorCodes.NC_SOFT_LIMIT_MIN_START),
                           int(ErrorCodes.NC_SOFT_LIMIT_MAX_START)})


def stopped_dynamics(core: CoreContext, i: int, followed: Job | None, dec: float, jerk: float) -> tuple[float, float]:
    """Deceleration [u/s^2] and jerk [u/s^3] of a stop: the non-zero inputs ``dec``/``jerk``, 0 =
    the effective value of ``followed`` (the job it stops, or that a buffered MC_Halt follows: its
    ``dyn`` holds its inputs with the axis defaults filled in). ``followed`` None, without
    dynamics, or driven by a set-point stage (coupling, external generator): AxisDec/AxisJerk.

    Raises:
        NcError: 0x4230 / 0x422E a negative or out of range value (:func:`..checks.command_dynamics`).
    """
    d = core.dynamics(i, {"Deceleration": dec, "Jerk": jerk}, None)  # (the range checks)
    ref = followed.dyn if followed is not None and followed.kind.source is None else None
    if ref is None:
        return d.deceleration, d.jerk
    return (dec or ref.deceleration), (jerk or ref.jerk)


def _stop_plan(core: CoreContext, i: int, job: Job, start: StartState) -> Plan:
    assert job.dyn is not None
    if not core.axes.traj_on[i] and abs(start.v) <= _EPS_V:
        return hold(start.p)  # standing: the stop is complete in its first cycle
    plan = core.plan(plan_velocity, start, 0.0, job.dyn)
    running = core.queues[i].active
    if not core.stop_within(i, plan, running):
        # TcMC 3.15: weaker dynamics are not used if the target (or a soft limit) would be
        # passed: stop with the running motion's (or the axis's) dynamics instead
        a = core.axes
        ref = running.dyn if running is not None and running.dyn is not None else None
        dec = max(job.dyn.deceleration, ref.deceleration if ref else 0.0, float(a.dec[i]))
        jerk = max(job.dyn.jerk, ref.jerk if ref else 0.0, float(a.jerk[i]))
        job.dyn = core.stop_dynamics(i, dec, jerk, running)
        plan = core.plan(plan_velocity, start, 0.0, job.dyn)
    return plan


class StopKind(JobKind):
    name = "Stop"
    commands = ("Stop",)
    is_stop = True
    braking = True
    locks = True
    feed_checked = False
    follows_override = False
    always_allowed = True

    def accept(self, core: CoreContext, i: int, req: Mapping[str, Any], prev: Job | None) -> Job:
        # the job it stops: whatever runs (also an NC ramp; stop_dynamics keeps the stronger one)
        dec, jerk = stopped_dynamics(core, i, core.queues[i].active, req.get("Deceleration", 0.0), req.get("Jerk", 0.0))
        return Job(self, dict(req), dyn=core.stop_dynamics(i, dec, jerk))

    def activate(self, core: CoreContext, i: int, job: Job, start: StartState) -> Plan:
        return _stop_plan(core, i, job, start)

    def from_ramp(self, ramp: Job | None, cmd_no: int) -> Job:
        """MC_Reset during an NC stop ramp: the ramp goes on as a numbered MC_Stop job (the axis shows
        Stopping until it stands, never StandStill while moving)."""
        job = Job(self, {}, dyn=ramp.dyn if ramp is not None else None, cmd_no=cmd_no)
        job.state = int(CmdState.ACTIVE)
        return job

    def on_end(self, core: CoreContext, i: int, job: Job) -> str:
        if job.data.get("release"):  # Execute fell during the ramp: unlock now that it stands
            core.axes.locked[i] = False
        return "done"


class HaltKind(JobKind):
    """MC_Halt: a discrete motion to rest (no lock; Done at standstill; may be buffered). Deceleration
    and Jerk as MC_Stop's (the module docstring): 0 = the stopped job's effective value (a buffered
    MC_Halt: of the job it follows), a lone value used, a negative one refused."""

    name = "Halt"
    commands = ("Halt",)
    buffer_modes = ALL_MODES
    feed_checked = False
    follows_override = False
    braking = True

    def accept(self, core: CoreContext, i: int, req: Mapping[str, Any], prev: Job | None) -> Job:
        # 0 = the effective value of the job it stops (Aborting) or follows (buffered: ``prev``)
        followed = prev if req.get("BufferMode", 0) != 0 and prev is not None else core.queues[i].active
        dec, jerk = stopped_dynamics(core, i, followed, req.get("Deceleration", 0.0), req.get("Jerk", 0.0))
        return Job(self, dict(req), dyn=Dynamics(float(core.axes.vmax[i]), max(float(core.axes.acc[i]), dec), dec, jerk))

    def activate(self, core: CoreContext, i: int, job: Job, start: StartState) -> Plan:
        assert job.dyn is not None
        job.dyn = core.stop_dynamics(i, job.dyn.deceleration, job.dyn.jerk)
        return _stop_plan(core, i, job, start)


class OrientedStopKind(JobKind):
    """MC_OrientedStop (TcMC 3.16): stop at the next position with modulo value Position that can
    be reached with the running motion's deceleration (Deceleration/Jerk inputs are not supported,
    as in TwinCAT). Position outside [0, period): 0x4281. An axis at rest: 0x4B03 (nothing to stop;
    use MC_MoveModulo). A target beyond an enabled software limit: TcMC 3.16 "for all fault
    conditions, the axis is stopped safely, but it may subsequently not be at the required oriented
    position": the command is accepted, the axis makes the standard stop (to its natural standstill)
    and the job ends ERROR 0x4222 there (the block's Error must be analysed); likewise an axis that is
    already beyond the limit and moves further out (0x4460 / 0x4461). A job waiting behind it
    then never starts: it ends ABORTED (errors clear the queue, ``JobEngine.finish``). The refusals above
    (bad Position, axis at rest) change nothing: a parameter error is refused before any motion
    (zenoh-nc choice; the manual's examples of fault conditions are run-time ones)."""

    name = "OrientedStop"
    commands = ("OrientedStop",)
    braking = True
    feed_checked = False
    follows_override = False

    def accept(self, core: CoreContext, i: int, req: Mapping[str, Any], prev: Job | None) -> Job:
        period = core.params[i].AxisEncoderModuloValue
        pos = req["Position"]
        if not 0.0 <= pos < period:
            raise NcError(ErrorCodes.NC_ORIENTED_STOP_NOT_ALLOWED, f"Position {pos} outside [0, {period})")
        return Job(self, dict(req))

    def activate(self, core: CoreContext, i: int, job: Job, start: StartState) -> Plan:
        if abs(start.v) <= _EPS_V:
            raise NcError(ErrorCodes.MC_AXIS_NOT_MOVING, "the axis is not moving: use MC_MoveModulo to position it")
        # the running motion's effective dynamics (a coupling, external set-points: AxisDec/AxisJerk)
        dec, jerk = stopped_dynamics(core, i, core.queues[i].active, 0.0, 0.0)
        sd = core.stop_dynamics(i, dec, jerk)
        target, sense, rest = modulo_beyond_stop(core, i, start, float(job.args["Position"]), sd)
        v_max = abs(start.v)
        if sense * start.v < 0:
            # the braking turns the axis already: it reaches the speed of the turn anyway, and goes on to
            # the target with it (not at the start's speed, which may be all but 0 just before the turn),
            # or with the start's speed where that is higher, but never faster than the running motion
            # (its velocity at the override): |start.v| is a speed in the old direction
            lo, hi = velocity_extrema(rest.seg)
            active = core.queues[i].active
            running = (active.dyn.velocity * float(core.axes.override[i])
                       if active is not None and active.dyn is not None and not active.kind.braking else v_max)
            v_max = max(-lo if sense < 0 else hi, min(v_max, running))
        dyn = Dynamics(v_max, sd.acceleration, sd.deceleration, sd.jerk)
        plan = core.plan(plan_position, start, target, dyn)
        try:
            core.check_target(i, start.p, target, plan)
        except NcError as err:
            if err.code not in _LIMIT_FAULTS:
                raise
            # TcMC 3.16: the axis is stopped safely all the same (the standard stop), the job ends with the error
            stop = core.plan(plan_velocity, start, 0.0, sd)
            job.target, job.dyn = stop.end.p, dyn
            job.data["end_error"] = int(err.code)
            return stop
        job.target, job.dyn = target, dyn
        return plan

    def on_end(self, core: CoreContext, i: int, job: Job) -> str:
        code = int(job.data.get("end_error", 0))
        if not code:
            return "done"
        core.axes.target_pos[i] = core.axes.set_pos[i]
        core.finish(i, job, CmdState.ERROR, code)
        return "continue"


class RampKind(JobKind):
    """The NC's own stop ramps (CmdNo 0: nobody's command)."""

    feed_checked = False
    follows_override = False
    always_allowed = True
    internal = True
    braking = True

    def __init__(self, name: str, holds_enable: bool) -> None:
        self.name = name
        self.holds_enable = holds_enable
        self.is_stop = True


STOP = StopKind()
#: after an axis error: AxisDec/AxisJerk, the drive stays enabled until standstill
FAULT_RAMP = RampKind("FaultRamp", holds_enable=True)
#: after a buffered job that could not start: the running job's dynamics
HALT_RAMP = RampKind("HaltRamp", holds_enable=False)


def kinds() -> list[JobKind]:
    return [STOP, HaltKind(), OrientedStopKind()]
