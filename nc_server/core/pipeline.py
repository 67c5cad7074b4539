"""The NC cycle as a pipeline: the stages one :meth:`NcCore.step` runs, in order (``NcCore.pipeline``,
readable at run time like LinuxCNC's ``addf`` order), with one fault guard and per-stage timing.

Every stage has one signature, ``run(core) -> None`` (:class:`Stage`); what one stage hands the next
lives on the core (e.g. ``core.plan_ended``). A stage says which axes a bug in it stops
(:meth:`Stage.rows_at_fault`): those get axis error 0x4000 and the cycle goes on; None: the bug is
not the axes' (inputs, drive, output) and leaves the step as before (the server counts it).

It may import: numpy, nc_schema, .engine (the guard), .planning, .profile, .monitoring; it reaches
the NC through :class:`~.context.CoreContext` and the NcCore members of :class:`~.context.CycleHost`.
"""
from __future__ import annotations

import logging
from time import perf_counter_ns
from typing import TYPE_CHECKING, Any, Callable, Iterable, Protocol

import numpy as np

from nc_schema import ErrorCodes

from .engine import on_bug
from .monitoring import monitor
from .planning import PlanningError, StartState, plan_velocity
from .profile import stopping_distance

if TYPE_CHECKING:
    from .nc import NcCore

_log = logging.getLogger(__name__)
_EPS_V = 1e-9


class Stage(Protocol):
    """One stage of the NC cycle."""

    #: its name in ``NcCore.pipeline`` and in the stats (``stages``)
    name: str

    def run(self, core: NcCore) -> None:
        """This cycle's work of the stage (cheap when it has nothing to do)."""

    def rows_at_fault(self, core: NcCore) -> np.ndarray | None:
        """The axes a bug in :meth:`run` stops (0x4000); None: the bug leaves the step."""


class _Stage:
    name = ""

    def bind(self, core: NcCore) -> Callable[[NcCore], None]:
        """What :func:`run_pipeline` calls with ``core`` every cycle, looked up once: :meth:`run`; a
        stage that only forwards to a method of the core gives that method's function (a call less)."""
        return self.run

    def run(self, core: NcCore) -> None:
        raise NotImplementedError

    def rows_at_fault(self, core: NcCore) -> np.ndarray | None:
        return None

    def __repr__(self) -> str:
        return f"<stage {self.name}>"


class Inputs(_Stage):
    """PLCTONC in (enables, feed, override: on changes), the state derived on events, disabled axes'
    set positions following their actual positions, the superimposed offsets taken off (the stages
    produce the basic motion; the offsets are added after it)."""

    name = "inputs"

    def run(self, core: NcCore) -> None:
        core.take_inputs()

    def bind(self, core: NcCore) -> Callable[[NcCore], None]:
        return type(core).take_inputs


class Profile(_Stage):
    """Every running plan's set-points (:class:`~.stages.ProfileStage`); the rows whose plan ended
    go to :class:`PlanEnds` (``core.plan_ended``)."""

    name = "profile"

    def run(self, core: NcCore) -> None:
        if core.on_rows.size:
            core.plan_ended = core.profile.run(core)


class PlanEnds(_Stage):
    """Jobs end, buffered jobs take over (the job engine, a guard per job)."""

    name = "plan ends"

    def run(self, core: NcCore) -> None:
        ended = core.plan_ended
        if ended.size:
            core.plan_ended = core.profile_idle
            core.engine.plan_ends(ended)


class SetPoints(_Stage):
    """The external set-points, the superpositions and the couplings (level by level), then the
    limits of the axes they drive: a violation is an axis error and a controlled stop."""

    name = "set-points"

    def run(self, core: NcCore) -> None:
        sup, cpl, ext = core.superposition, core.coupling, core.external
        if not (ext.active or sup.active or cpl.active):
            return
        over: list[tuple[int, int]] = []
        if ext.active:
            over += ext.run(core)
        if sup.active:
            sup.evaluate()
            sup.apply(core, sup.rows[~cpl.slave[sup.rows]])  # (the slaves' after their coupling)
        if cpl.active:
            over += cpl.run(core, sup.apply if sup.active else None)  # (no closure built every cycle)
        if sup.active:
            over += sup.limits(core)
            sup.ended(core)
        over += stage_soft_limits(core)
        core.engine.flush_slots()
        for i, code in over:
            if not core.axes.error[i]:
                _log.warning("axis %d: set-point beyond its limits (0x%X): stopped", int(core.axis_ids[i]), int(code))
            core.fault(i, code)

    def rows_at_fault(self, core: NcCore) -> np.ndarray | None:
        cpl, sup, ext = core.coupling, core.superposition, core.external
        return (cpl.slave | ext.on | sup.on).nonzero()[0]


class Jobs(_Stage):
    """The running jobs' watches and limits (soft-limit approach, switching positions, homing; a
    guard per kind), then the feed enables of the moving axes."""

    name = "jobs"

    def run(self, core: NcCore) -> None:
        if core.watch_rows:
            core.engine.watches(core.watch_rows)
        core.check_feeds()


class Drive(_Stage):
    """The drive steps to this cycle's set-points; the actual positions come back."""

    name = "drive"

    def run(self, core: NcCore) -> None:
        core.step_drive()

    def bind(self, core: NcCore) -> Callable[[NcCore], None]:
        return type(core).step_drive


class Probe(_Stage):
    """Touch probe latches of the drive step just made (:class:`~.stages.ProbeStage`)."""

    name = "probe"

    def run(self, core: NcCore) -> None:
        if core.probe.active:
            core.probe.run(core)
            core.engine.flush_slots()


class Monitoring(_Stage):
    """Position lag, target windows, software limits, the drive's I/O and device state: new faults stop their
    axes from the next cycle."""

    name = "monitoring"

    def run(self, core: NcCore) -> None:
        if core.state_dirty:  # a job ended this cycle: monitor it as standing already
            core.derive_state()
        a = core.axes
        watch = core.monitor_watch
        if core.external.active:  # an enabled external generator: its target window counts when it stands
            r = core.external.rows
            st = watch[1].copy()
            st[r] = (np.abs(a.set_velo[r]) <= _EPS_V) & a.enabled[r]
            watch = (watch[0], st, watch[2], True)
        for i, code in monitor(a, core.act_pos, core.cycle_time, watch, core.pos_ref):
            core.fault(i, code)
        dm = core.drive_monitor
        if dm.active or core.drive.faulty:  # the drive's I/O and device state (.drive_monitor)
            for i, code in dm.run(core.drive, a.enabled, a.error):
                core.fault(i, code)
            if dm.active:
                a.mon_dw |= dm.dw
                a.mon_clear = False
        if core.state_dirty:
            core.derive_state()


class Output(_Stage):
    """NCTOPLC: this cycle's values packed into the records (the job records are packed on events)."""

    name = "output"

    def run(self, core: NcCore) -> None:
        core.fill_nctoplc()

    def bind(self, core: NcCore) -> Callable[[NcCore], None]:
        return type(core).fill_nctoplc


def default_pipeline() -> list[Stage]:
    """The NC cycle's stages, in order."""
    return [Inputs(), Profile(), PlanEnds(), SetPoints(), Jobs(), Drive(), Probe(), Monitoring(), Output()]


def _changes(name: str) -> Callable[..., Any]:
    base = getattr(list, name)

    def method(self: Pipeline, *args: Any, **kwargs: Any) -> Any:
        self.calls = None
        return base(self, *args, **kwargs)
    method.__name__ = name
    return method


class Pipeline(list["Stage"]):
    """``NcCore.pipeline``: one core's stages in order, a list like any other (read, insert, replace).
    :func:`run_pipeline` calls what the stages bound once (``calls``, :meth:`_Stage.bind`; a stage
    without ``bind``: its ``run``); any change of the list drops them, to be bound anew at the next
    cycle."""

    def __init__(self, stages: Iterable[Stage] = ()) -> None:
        super().__init__(stages)
        self.calls: tuple[Callable[[NcCore], None], ...] | None = None

    def bind(self, core: NcCore) -> tuple[Callable[[NcCore], None], ...]:
        """The stages' calls for ``core`` (kept until the list changes); the timing lists of the
        core grown to the stages."""
        self.calls = tuple(stage.bind(core) if hasattr(stage, "bind") else stage.run for stage in self)
        for times in (core.stage_last_ns, core.stage_max_ns):
            times += [0] * (len(self) - len(times))
        return self.calls


for _name in ("__setitem__", "__delitem__", "__iadd__", "__imul__", "append", "extend", "insert", "pop", "remove",
              "clear", "sort", "reverse"):  # (every change in place)
    setattr(Pipeline, _name, _changes(_name))
del _name


def run_pipeline(core: NcCore, stages: Pipeline) -> None:
    """Run the pipeline ``stages`` (``core.pipeline``) once: each stage under the one fault guard, its
    time kept (``core.stage_last_ns`` / ``core.stage_max_ns``, by position in the pipeline; one clock
    read per stage boundary, the end of one stage is the start of the next)."""
    calls = stages.calls or stages.bind(core)
    last, peak = core.stage_last_ns, core.stage_max_ns
    k = 0
    t = perf_counter_ns()
    for call in calls:
        try:  # (free in CPython >= 3.11 while nothing is raised)
            call(core)
        except Exception:
            stage = stages[k]
            rows = stage.rows_at_fault(core)
            if rows is None:
                raise
            on_bug(f"stage {stage.name}", rows.tolist(), core.fault)
        now = perf_counter_ns()
        dt = last[k] = now - t
        if dt > peak[k]:
            peak[k] = dt
        t = now
        k += 1


def stage_soft_limits(core: NcCore) -> list[tuple[int, int]]:
    """Slaves and superpositions (not on a positioning move: checked when commanded) towards an
    enabled software limit (external set-points: ExternalStage.run judges their feeds): an axis
    error (0x4463/0x4462) in the first cycle in which the stop the fault ramp makes from this
    cycle's state (AxisDec, AxisJerk) would end beyond the limit (a plan's own jobs brake for the
    limit themselves). A bound of the stop distance picks the candidates, an exact plan decides,
    so a motion that ends exactly at the limit is no fault; the price of deciding on this cycle's
    state is that a real violation is noticed up to one cycle late (the stop then ends beyond the
    limit by what the stop's end moved in that cycle, a fraction of the distance per cycle)."""
    if not core.monitor_watch[2]:  # (no software limit enabled on any axis: derived on events)
        return []
    a = core.axes
    sup = core.superposition.on.copy()
    for i in np.flatnonzero(sup).tolist():
        job = core.queues[i].running_numbered
        if job is not None and job.target is not None and not job.continuous:
            sup[i] = False  # (positioning + offset: checked against the limits when commanded)
    rows = np.flatnonzero(core.coupling.slave | sup)  # (external rows: ExternalStage.run)
    rows = rows[a.en_max[rows] | a.en_min[rows]]
    if not rows.size:
        return []
    p, v, acc = a.set_pos[rows], a.set_velo[rows], a.set_acc[rows]
    bound = p + np.sign(v) * stopping_distance(v, acc, a.dec[rows], a.jerk[rows])
    cand = (a.en_max[rows] & (v > 0) & (bound > a.max_lim[rows])) | (a.en_min[rows] & (v < 0) & (bound < a.min_lim[rows]))
    out: list[tuple[int, int]] = []
    for k in np.flatnonzero(cand).tolist():
        i = int(rows[k])
        d = core.stop_dynamics(i, float(a.dec[i]), float(a.jerk[i]))  # (the fault ramp's)
        try:
            end = plan_velocity(StartState(float(p[k]), float(v[k]), float(acc[k])), 0.0, d).end.p
        except PlanningError:
            end = float(bound[k])
        tol = 1e-6 * max(1.0, abs(end))
        if v[k] > 0 and a.en_max[i] and end > a.max_lim[i] + tol:
            out.append((i, int(ErrorCodes.NC_SOFT_LIMIT_MAX_POSITIONING)))
        elif v[k] < 0 and a.en_min[i] and end < a.min_lim[i] - tol:
            out.append((i, int(ErrorCodes.NC_SOFT_LIMIT_MIN_POSITIONING)))
    return out
