"""Jobs: the records of accepted motion commands, the per-axis queue, and the job-kind interface.

A **job** is one accepted motion command (or an internal motion of the NC, e.g. the stop ramp after
an error, which has CmdNo 0). Its lifecycle: BUFFERED (waiting behind the active job) -> ACTIVE
(the set-point generator executes its plan; it may be *amended*: new target, velocity, dynamics)
-> DONE / ABORTED / ERROR. Accepting and activating are separate steps: :meth:`JobKind.accept`
checks the arguments and makes the record, :meth:`JobKind.activate` checks the axis state and
plans from a frozen start state. Each kind (position, velocity, stop, homing, ...) is a small
unit in its own module; the NC core knows kinds only through this interface.

Queue depth: one job can wait behind the active one (TwinCAT has one command buffer per axis);
a further buffered command is refused with 0x4292.
"""
from __future__ import annotations

import collections
import math
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any, ClassVar, Mapping

import numpy as np

from nc_schema import CmdState, ErrorCodes, MC_BufferMode, NcError

from ..planning import Dynamics, Plan, StartState
from ..profile import stopping_distance

if TYPE_CHECKING:
    from ..context import CoreContext

ABORTING = int(MC_BufferMode.MC_Aborting)
BUFFERED = int(MC_BufferMode.MC_Buffered)
BLENDING = frozenset({int(MC_BufferMode.MC_BlendingLow), int(MC_BufferMode.MC_BlendingPrevious),
                      int(MC_BufferMode.MC_BlendingNext), int(MC_BufferMode.MC_BlendingHigh)})
ALL_MODES = frozenset({ABORTING, BUFFERED}) | BLENDING
#: ended jobs kept per axis for the wire (NCJOBS_AXIS_REF.Ended)
ENDED_KEPT = 4


@dataclass(eq=False, slots=True)
class Job:
    """One motion command (``cmd_no`` > 0) or an internal motion of the NC (``cmd_no`` == 0).

    Positions are NC positions [u]; ``target`` of a waiting job is fixed when it is accepted
    (relative/additive/modulo targets refer to the target of the job it follows).
    """

    kind: JobKind
    args: Mapping[str, Any]
    client: str = ""
    cmd_no: int = 0
    buffer_mode: int = ABORTING
    state: int = int(CmdState.NONE)
    error_id: int = 0
    dyn: Dynamics | None = None       # the motion's dynamics (override replans, stops, blending)
    target: float | None = None       # NC position where a discrete motion ends
    velocity: float = 0.0             # signed velocity at 100 % override (velocity phases)
    end_velocity: float = 0.0         # signed velocity at the target (blending, continuous moves)
    held: bool = False                # waiting at override 0 (AxisState OVERRIDE_ZERO)
    amended: bool = False             # NewPos/NewPosAndVelo/ChangeDynParam changed it (NewTargetPos)
    continuous: bool = False          # ContinuousMotion: endless (velocity) or past its target at EndVelocity
    phase: int = 0                    # kind-specific phase (homing state, limit stop, ...)
    data: dict[str, Any] = field(default_factory=dict)

    @property
    def numbered(self) -> bool:
        return self.cmd_no != 0

    def trial(self) -> Job:
        """A copy to activate or re-plan on approval: the record itself changes only when the NC
        adopts the result (a check, a refusal or a dry run leaves it as it was)."""
        return replace(self, data=dict(self.data))

    def __repr__(self) -> str:
        return f"Job({self.kind.name} #{self.cmd_no} {CmdState(self.state).name})"


class JobKind:
    """One kind of job: its checks, its plan, its end condition. Subclasses override what they need.

    Class attributes describe how the NC treats a running job of this kind.
    """

    #: its name (name, commands, is_stop, holds_enable: no ClassVars, a kind made for several commands sets
    #: them per instance)
    name: str = ""
    #: request commands this kind accepts (each registered as a job: :func:`..commands.register_kind`)
    commands: tuple[str, ...] = ()
    #: starting its job starts a motion (the contract's ``motion``; the registry checks they agree)
    motion: ClassVar[bool] = True
    #: BufferModes accepted (others: 0x4B64)
    buffer_modes: ClassVar[frozenset[int]] = frozenset({ABORTING})
    #: a stop: sets HasBeenStopped; never made weaker by a later stop
    is_stop: bool = False
    #: locks the axis for motion commands (MC_Stop)
    locks: ClassVar[bool] = False
    #: checked against the feed enables of its direction while it runs
    feed_checked: ClassVar[bool] = True
    #: keeps the drive enabled until it ends, whatever the PLCTONC says (fault ramps)
    holds_enable: bool = False
    #: HomingBusy while it runs
    homing: ClassVar[bool] = False
    #: its plan follows the override (replanned on changes)
    follows_override: ClassVar[bool] = True
    #: has a per-cycle :meth:`watch` (rows of this kind are handed to it every cycle)
    watches: ClassVar[bool] = False
    #: may be started from an axis in ErrorStop / locked (stops)
    always_allowed: ClassVar[bool] = False
    #: brings the axis to rest: a later stop is never weaker than it (TcMC 3.15)
    braking: ClassVar[bool] = False
    #: the NC's own motion (a stop ramp), never numbered
    internal: ClassVar[bool] = False
    #: the set-point stage that drives the axis while this job runs ("coupling", "external"); None:
    #: its plan (the profile stage). The stage holds the row exactly while such a job is active.
    source: ClassVar[str | None] = None

    def accept(self, core: CoreContext, i: int, req: Mapping[str, Any], prev: Job | None) -> Job:
        """Check the arguments and make the record (nothing is changed yet).

        Args:
            prev: the job this one will follow (the active one, or the waiting one it is queued
                behind), or None when it starts from the axis's current state.

        Raises:
            NcError: the TwinCAT code of the first failed check.
        """
        raise NotImplementedError

    def activate(self, core: CoreContext, i: int, job: Job, start: StartState) -> Plan | None:
        """Check the axis state and plan the job from ``start`` (a job of a ``source`` stage: None,
        it has no plan).

        It changes nothing but ``job`` (what the plan needs to know later: phase, held, the start
        of the move, ...). The NC checks a buffered job on ``job.trial()``, a copy, so a check
        never changes the record; the planning itself (``planning``) is a pure function.

        Raises:
            NcError: the job cannot start here.
        """
        raise NotImplementedError

    def on_begin(self, core: CoreContext, i: int, job: Job) -> None:
        """The job became the running one (a job of a ``source`` stage hands the row to it here)."""

    def on_end(self, core: CoreContext, i: int, job: Job) -> str:
        """The plan ended. Returns "done" (the job is finished), "steady" (keep the plan's end
        velocity: the job goes on) or "continue" (the kind started a new plan itself)."""
        return "done"

    def replan(self, core: CoreContext, i: int, job: Job, start: StartState, override: float) -> Plan | None:
        """A new plan after an override change or a new end velocity (blending); None: keep."""
        return None

    def override_replan(self, core: CoreContext, i: int, job: Job, start: StartState, old: float,
                        new: float) -> Plan | None:
        """A new plan after the override changed from ``old`` to ``new`` (0..1); None: keep the running one.
        Default: :meth:`replan` at ``new`` (positionings apply AxisOverrideType here)."""
        return self.replan(core, i, job, start, new)

    def goal(self, job: Job) -> float | None:
        """Where the running plan of ``job`` heads for (NC position): its target; a positioning's loop point on
        the way out of a loop movement. None: no target."""
        return job.target

    def watch(self, core: CoreContext, rows: np.ndarray) -> None:
        """Per-cycle checks of the running jobs of this kind in ``rows`` (after the set-points)."""

    def wants_watch(self, job: Job) -> bool:
        """Hand this job's row to :meth:`watch` every cycle (default: the class's ``watches``)."""
        return self.watches

    def successor_may_start(self, core: CoreContext, i: int, job: Job) -> bool:
        """A buffered job may take over now (e.g. a velocity job at its constant velocity)."""
        return False

    def amend(self, core: CoreContext, i: int, job: Job, req: Mapping[str, Any]) -> Plan | None:
        """Change the running job (NewPos, NewPosAndVelo, ChangeDynParam). Returns the new plan,
        None to keep the current one (the change happens later, e.g. at a switching position).

        Raises:
            NcError: 0x4B05 this kind cannot be amended so.
        """
        raise NcError(ErrorCodes.MC_COMMAND_NOT_PERMITTED, f"a {self.name} command cannot be changed so")

    def change_dynamics(self, core: CoreContext, i: int, job: Job, req: Mapping[str, Any]) -> Plan:
        """MC_ChangeDynParam (TcMC 4.20): new dynamics for the running job, or a refusal that keeps
        the current ones: 0x425D a stop runs, 0x427F the target would be passed, 0x423A the
        velocity would overshoot, 0x4289 the direction would reverse (both only where the new dynamics
        cause it, not the running move's own turn or peak: :func:`.checks.check_reversal`,
        :func:`.checks.check_overshoot`). Generic: re-plans with
        :meth:`replan` on a trial copy and adopts it only when every check passed.

        Raises:
            NcError: the TwinCAT code of the refusal.
        """
        if self.braking:
            raise NcError(ErrorCodes.NC_ESTOP_ALREADY_ACTIVE, "a stop with its own dynamics is running")
        old = job.dyn or core.dynamics(i, {}, None)
        new = core.dynamics(i, req, old.velocity)
        start = core.start_state(i)
        trial = job.trial()
        trial.dyn = new
        plan = self.replan(core, i, trial, start, core.override(i))
        if plan is None:
            raise NcError(ErrorCodes.MC_COMMAND_NOT_PERMITTED, f"a {self.name} command has no dynamics to change")
        goal = self.goal(job)  # (the loop point on the way out of a loop movement)
        if goal is not None:
            sense = 1.0 if goal >= start.p else -1.0
            beyond = plan.p_max - goal if sense > 0 else goal - plan.p_min
            if beyond > 1e-9:
                raise NcError(ErrorCodes.NC_NEW_TARGET_OVERRUN, "the target would be passed with these dynamics")
        else:  # a velocity job (0: no direction of its own, nothing to keep)
            sense = (1.0 if job.velocity > 0 else -1.0) if job.velocity else 0.0
        if sense:
            # the direction would reverse: the check of a start (against the running jerk: a positioning
            # that turns the axis towards its goal already may get new dynamics)
            core.check_reversal(i, plan, start, sense, None, job)
        core.check_overshoot(i, plan, old.velocity * core.override(i))
        job.dyn = new
        job.data = trial.data  # with the plan's own state (the ramp to the end velocity)
        return plan

    def blend_velocity(self, core: CoreContext, i: int, job: Job, nxt: Job) -> float:
        """The velocity [u/s, >= 0, at 100 % override] with which ``job`` passes its target when
        ``nxt`` waits behind it with a Blending BufferMode (PLCopen Part 1: Low = the lower,
        Previous = this job's, High = the higher of both, Next = the waiting job's velocity).
        Opposite directions: 0. Lowered until ``nxt`` can still stop within its own distance from where
        it takes over: the next cycle boundary, up to one cycle's travel (|v| x cycle time) past this
        job's target (else ``nxt`` would overshoot its target and come back, a reversal; a MC_MoveModulo
        started so would count as moving with its rest point beyond its queued target, a full turn more).
        Only called for jobs with a :meth:`blend_point`."""
        bp = self.blend_point(job)
        if bp is None:
            return 0.0
        target, sense, v_prev = bp
        if nxt.target is not None:
            d_next = (nxt.target - target) * sense
            v_next = nxt.dyn.velocity if nxt.dyn is not None else 0.0
        else:
            d_next = math.inf if nxt.velocity * sense > 0 else -1.0
            v_next = abs(nxt.velocity)
        if d_next <= 0:
            return 0.0
        mode = nxt.buffer_mode
        if mode == int(MC_BufferMode.MC_BlendingLow):
            v = min(v_prev, v_next)
        elif mode == int(MC_BufferMode.MC_BlendingPrevious):
            v = v_prev
        elif mode == int(MC_BufferMode.MC_BlendingNext):
            v = v_next
        else:
            v = max(v_prev, v_next)
        v = min(v, float(core.axes.vmax[i]))  # at 100 %: the plan scales it with the override
        if math.isfinite(d_next) and nxt.dyn is not None and v > 0:
            dec, jerk = np.array([nxt.dyn.deceleration]), np.array([nxt.dyn.jerk])
            dt = core.cycle_time
            for _ in range(30):  # the waiting job must be able to stop within its distance
                # (from where it takes over: at the first cycle boundary at or after this job's end, up to
                # one cycle's travel past the target; a margin of 1e-9 relative for the rounding)
                d_stop = float(stopping_distance(np.array([v]), np.zeros(1), dec, jerk)[0])
                if (d_stop + v * dt) * (1 + 1e-9) <= d_next:
                    break
                v *= 0.8
            else:
                v = 0.0
        return v

    def blend_point(self, job: Job) -> tuple[float, float, float] | None:
        """(target, direction of travel +-1, velocity at 100 %) of a job that a blending successor
        can pass through, or None (a successor then waits for its end, as with Buffered)."""
        return None

    def shift(self, job: Job, diff: float) -> None:
        """The NC positions were shifted by ``diff`` (MC_SetActualPositionOnTheFly): move the positions
        the job keeps besides its target (the NC has shifted ``target``)."""
        if job.data.get("start") is not None:
            job.data["start"] += diff

    def next_base(self, job: Job, core: CoreContext, i: int) -> float | None:
        """The position a relative/additive successor refers to (NC position): this job's target;
        None for a job without one (velocity, halt, homing): the successor refers to the set position
        where it starts."""
        return job.target


class JobQueue:
    """The jobs of one axis: the running one, at most one waiting, and the last ended ones."""

    __slots__ = ("active", "waiting", "shown", "ended", "newest")

    def __init__(self) -> None:
        self.active: Job | None = None     # what the set-point generator executes (may be internal)
        self.waiting: Job | None = None    # the buffered job
        self.shown: Job | None = None      # the last numbered job that became active (NCTOPLC.CmdNo)
        self.ended: collections.deque[Job] = collections.deque(maxlen=ENDED_KEPT)
        self.newest = 0                    # the newest CmdNo handed out

    def end(self, job: Job, state: CmdState, error_id: int = 0) -> None:
        """Give ``job`` its fate (once) and forget it as active/waiting."""
        if job.state in (int(CmdState.ACTIVE), int(CmdState.BUFFERED)):
            job.state = int(state)
            job.error_id = int(error_id)
            if job.numbered:
                self.ended.appendleft(job)
        if self.active is job:
            self.active = None
        if self.waiting is job:
            self.waiting = None

    @property
    def running_numbered(self) -> Job | None:
        j = self.active
        return j if j is not None and j.numbered else None
