"""The job engine: the lifecycle of the jobs in the axes' queues (begin, finish, advance, blend,
amend, the NC's own stop ramps, plan ends, the per-cycle watches) and the records that mirror them.

It owns the rule that keeps the records true: after every hook of a job kind (accept/activate,
on_begin, on_end, amend, change_dynamics, watch) the engine brings the axis columns and the
NCJOBS record of the row up to date (:meth:`JobEngine.sync`); kinds never sync. A vectorized
``watch(rows)`` is synced for the rows it changed: those handed to the context's mutators
(``set_plan``, ``clear_profile``, ``continue_plan``, ``touch``) while it ran.

It may import: nc_schema, .jobs, .planning, .packing, .checks; it reaches the NC only through
:class:`~.context.CoreContext` plus the few NcCore members named in :class:`EngineHost`.
"""
from __future__ import annotations

import logging
from typing import TYPE_CHECKING, Any, Callable, Iterable

import numpy as np

from nc_schema import CmdState, ErrorCodes, NcError, next_cmdno

from .checks import check_source
from .jobs import KINDS, Job, JobKind
from .jobs.base import ABORTING, BLENDING
from .jobs.stop import FAULT_RAMP, HALT_RAMP
from .planning import Plan, PlanningError, StartState, plan_velocity

if TYPE_CHECKING:
    from .nc import NcCore

_log = logging.getLogger(__name__)
_EPS_V = 1e-9
#: the kinds by number (``axes.watch_kind``: the kind whose watch a row's job wants, -1 none)
KINDS_LIST: list[JobKind] = sorted({k for k in KINDS.values()}, key=lambda k: k.name)
KINDS_INDEX = {k.name: n for n, k in enumerate(KINDS_LIST)}


#: what :func:`guarded` returns after a bug
FAILED: Any = object()


def on_bug(what: str, rows: Iterable[int], fault: Callable[[int, int], None]) -> None:
    """The one fault guard's rule (called while an exception is handled): a bug must stop the axes
    ``rows`` (0x4000 NC_INTERNAL), never the NC cycle or the command loop."""
    _log.exception("%s failed", what)
    for i in list(rows):
        fault(int(i), ErrorCodes.NC_INTERNAL)


# (call, rows: called without arguments; typed "..." because the callers' lambdas bind loop variables as defaults)
def guarded(what: str, call: Callable[..., Any], rows: Callable[..., Iterable[int]], fault: Callable[[int, int], None],
            passthrough: tuple[type[BaseException], ...] = ()) -> Any:
    """``call()`` under the fault guard (:func:`on_bug`; exceptions in ``passthrough`` are no bugs
    and propagate). Returns what ``call`` returned, or :data:`FAILED` after a bug."""
    try:
        return call()
    except passthrough:
        raise
    except Exception:
        on_bug(what, rows(), fault)
        return FAILED


def _buffered(checked: tuple[int, Job | None, str]) -> bool:
    """A motion command with these (BufferMode, running numbered job, client) waits behind the running job."""
    mode, running, _ = checked
    return mode != ABORTING and running is not None and running.state == int(CmdState.ACTIVE)


class JobEngine:
    """The queues' lifecycle for one :class:`~.nc.NcCore` (one per NC; it keeps no state but the
    rows changed during a hook)."""

    def __init__(self, core: NcCore) -> None:
        self.core = core
        self.touched: list[int] = []  # rows a hook changed (synced when it returns)

    # -- records ---------------------------------------------------------------------------------
    def sync(self, i: int) -> None:
        """Mirror row ``i``'s queue into the columns and its job record (on events only); a stage
        that drives the row without its job running any more lets it go."""
        core = self.core
        core.row_version[i] += 1  # (a preparation made before this is stale: NcCore.activate)
        a, q = core.axes, core.queues[i]
        j = q.active
        source = j.kind.source if j is not None else None
        if source != "coupling" and core.coupling.is_slave(i):
            core.coupling.release(i)
        if source != "external" and core.external.on[i]:
            core.external.release(i)
        numbered = j is not None and j.numbered
        held = j is not None and j.held
        row_bits = 1 if held else (2 if numbered else 0)
        if a.sp_row[i] != row_bits:
            a.sp_row[i] = row_bits
            if a.traj_on[i]:
                a.changed.append(i)  # the buffered set-point bits depend on them (the profile stage)
        # (the union-attr ignores: numbered means j is not None)
        homing = numbered and j.kind.homing  # type: ignore[union-attr]
        amended = numbered and j.amended  # type: ignore[union-attr]
        a.has_job[i] = numbered
        a.continuous[i] = numbered and j.continuous  # type: ignore[union-attr]
        a.homing[i] = homing
        a.amended[i] = amended
        a.buffered[i] = q.waiting is not None
        a.hold_enable[i] = j is not None and j.kind.holds_enable
        a.driving[i] = numbered and j.kind.feed_checked and not held  # type: ignore[union-attr]
        a.held[i] = held
        a.watch_kind[i] = KINDS_INDEX.get(j.kind.name, -1) if (j is not None and j.kind.wants_watch(j)) else -1
        a.homing_state[i] = j.phase if homing else 0  # type: ignore[union-attr]
        shown = q.shown
        cmd_no, cmd_state = (shown.cmd_no, shown.state) if shown is not None else (0, 0)
        a.cmd_no[i] = cmd_no
        a.cmd_state[i] = cmd_state
        core.records.pack_queue(i, q, cmd_no, cmd_state, amended)
        self.sync_slots(i)

    def sync_slots(self, i: int) -> None:
        """The coupling, superposition and touch probe part of row ``i``'s job record (on events)."""
        core = self.core
        core.records.pack_slots(i, core.coupling, core.superposition, core.probe, core.external)
        core.state_dirty = True

    def sync_touched(self, synced: dict[int, int] | None = None) -> None:
        """Sync the rows a hook changed (see the module docstring), in the order of their first change.

        Args:
            synced: rows the caller synced since, each with ``len(touched)`` at that sync: a row not
                changed after its sync is not synced again (a sync only mirrors the state).
        """
        rows, self.touched = self.touched, []
        if synced:
            last = {r: k for k, r in enumerate(rows)}  # (a row's last change)
            for i in dict.fromkeys(rows):
                if last[i] >= synced.get(i, -1):
                    self.sync(i)
            return
        for i in dict.fromkeys(rows):
            self.sync(i)

    def flush_slots(self) -> None:
        """Job records of the rows whose stage slot changed (a superposition, a touch probe, a
        synchronization locked, an external feed matched)."""
        core = self.core
        for st in (core.superposition, core.probe, core.coupling, core.external):
            if st.changed:
                for i in set(st.changed):
                    self.sync(i)  # (NewestCmdNo, HasJob, and the slots)
                st.changed.clear()

    # -- commands ----------------------------------------------------------------------------
    def motion(self, i: int, kind: JobKind, req: dict[str, Any]) -> dict[str, Any]:
        """A motion command: accepted, then started now (Aborting) or queued behind the running job."""
        checked = self._motion_checks(i, kind, req)
        if _buffered(checked):
            return self._buffer(i, kind, req, checked)
        job, plan = self._prepare(i, kind, req, checked)
        self.begin(i, job, plan)
        return {"cmd_no": job.cmd_no}

    def prepare(self, i: int, kind: JobKind, req: dict[str, Any]) -> tuple[Job, Plan | None] | None:
        """The preparation of a motion command that starts now (SVB): its checks, its record and its plan
        from the row's current set-point state, changing nothing; :meth:`begin` starts it (the
        activation). None: it would be queued behind the running job (:meth:`motion` does that in one step).

        Raises:
            NcError: the TwinCAT code of the first failed check.
        """
        checked = self._motion_checks(i, kind, req)
        if _buffered(checked):
            return None
        return self._prepare(i, kind, req, checked)

    def _prepare(self, i: int, kind: JobKind, req: dict[str, Any],
                 checked: tuple[int, Job | None, str]) -> tuple[Job, Plan | None]:
        mode, running, client = checked
        job = kind.accept(self.core, i, req, running)
        job.client, job.buffer_mode = client, mode
        # a stop brakes the total motion (a running superposition included)
        plan = kind.activate(self.core, i, job, self.core.start_state(i, total=kind.braking))
        return job, plan

    def _motion_checks(self, i: int, kind: JobKind, req: dict[str, Any]) -> tuple[int, Job | None, str]:
        """The checks every motion command passes first: (BufferMode, the running numbered job, client)."""
        core = self.core
        q = core.queues[i]
        mode = req.get("BufferMode", ABORTING)
        if mode not in kind.buffer_modes:
            raise NcError(ErrorCodes.MC_BUFFERMODE_NOT_SUPPORTED, f"{req['cmd']}: BufferMode {mode} is not supported")
        if not kind.always_allowed:
            core.check_startable(i)
        check_source(q.active, kind, core.params[i], int(core.axis_ids[i]), mode)
        running = q.running_numbered
        if (running is not None and running.kind.homing and mode == ABORTING and not kind.always_allowed
                and running.state == int(CmdState.ACTIVE)):
            raise NcError(ErrorCodes.MC_AXIS_CANNOT_BE_STARTED, "the axis is homing (PLCopen: Homing accepts only MC_Stop)")
        return mode, running, str(req.get("client") or "")

    def _buffer(self, i: int, kind: JobKind, req: dict[str, Any], checked: tuple[int, Job | None, str]) -> dict[str, Any]:
        """A motion command queued behind the running job (a BufferMode other than Aborting): checked from
        where it will start, numbered, BUFFERED; a blending one re-plans the running job."""
        core = self.core
        q = core.queues[i]
        mode, running, client = checked
        if running is not None:
            if q.waiting is not None:
                raise NcError(ErrorCodes.NC_COMMAND_BUFFER_FULL,
                              f"command {q.waiting.cmd_no} is already waiting (one buffered command per axis)")
            job = kind.accept(core, i, req, running)
            job.client, job.buffer_mode = client, mode
            # validate from where it will start: the running job's target (at rest or passing it)
            base = running.kind.next_base(running, core, i)
            if base is None:  # no target to refer to: checked from here, fixed where it starts
                base = core.nc_set_pos(i)
            kind.activate(core, i, job.trial(), StartState(base))  # a check only: the record stays as accepted
            job.cmd_no = q.newest = next_cmdno(q.newest)
            job.state = int(CmdState.BUFFERED)
            q.waiting = job
            self.sync(i)
            if mode in BLENDING:
                self.blend(i)
            if running.kind.successor_may_start(core, i, running):
                self.advance(i)
                self.sync(i)
            return {"cmd_no": job.cmd_no}
        raise AssertionError("_buffer(): only for a command queued behind a running job")

    def amend(self, i: int, req: dict[str, Any]) -> dict[str, Any]:
        """NewPos, NewPosAndVelo, ChangeDynParam: the running job changes (its kind decides how)."""
        core = self.core
        q, a = core.queues[i], core.axes
        job = q.running_numbered
        if job is None or not (a.traj_on[i] or abs(a.set_velo[i]) > _EPS_V):
            raise NcError(ErrorCodes.MC_AXIS_NOT_MOVING, f"{req['cmd']}: the axis has no moving command to change")
        plan: Plan | None
        if req["cmd"] == "ChangeDynParam":
            plan = job.kind.change_dynamics(core, i, job, req)
        else:
            plan = job.kind.amend(core, i, job, req)
        job.amended = True
        if plan is not None:
            core.set_plan(i, plan)
            if job.target is not None:
                a.target_pos[i] = job.target
        if q.waiting is not None and q.waiting.buffer_mode in BLENDING:
            self.blend(i)
        self.sync(i)
        return {"cmd_no": job.cmd_no}

    # -- the lifecycle -----------------------------------------------------------------------
    def begin(self, i: int, job: Job, plan: Plan | None, abort_waiting: bool = True) -> None:
        """Make ``job`` the running job with ``plan``: the running one ends ABORTED (and, unless
        ``abort_waiting`` is False, the waiting one too). Numbers the job if it has no number.
        ``plan`` None: a job of a set-point stage (``JobKind.source``), which takes the row."""
        core = self.core
        a, q = core.axes, core.queues[i]
        if q.active is not None and q.active is not job:
            q.end(q.active, CmdState.ABORTED)
        if abort_waiting and q.waiting is not None and q.waiting is not job:
            q.end(q.waiting, CmdState.ABORTED)
        if q.waiting is job:
            q.waiting = None
        if not job.kind.internal and not job.numbered:
            job.cmd_no = q.newest = next_cmdno(q.newest)
        job.state = int(CmdState.ACTIVE)
        q.active = job
        if job.numbered:
            a.stopped[i] = job.kind.is_stop
            q.shown = job
            if job.kind.locks:
                a.locked[i] = True
        if job.kind.braking:
            core.superposition.abort(core, i)  # (planned from the total state)
        if plan is None:
            core.clear_profile(i, keep_velocity=True)
            a.target_pos[i] = job.target if job.target is not None else a.set_pos[i]
        else:
            core.set_plan(i, plan)
            a.target_pos[i] = job.target if job.target is not None else plan.end.p
        a.since_end[i] = -1.0
        a.window_timer[i] = 0.0
        a.in_target[i] = a.in_area[i] = False
        self.sync(i)
        on_begin = job.kind.on_begin
        if getattr(on_begin, "__func__", None) is not JobKind.on_begin:  # (the default does nothing: no second sync)
            on_begin(core, i, job)
            self.sync(i)

    def start_ramp(self, i: int, kind: JobKind, running: Job | None) -> None:
        """An internal stop ramp (no CmdNo) after an error or a job that could not take over."""
        core = self.core
        a = core.axes
        if kind is FAULT_RAMP or running is None or running.dyn is None:
            dec, jerk = float(a.dec[i]), float(a.jerk[i])
        else:
            dec, jerk = running.dyn.deceleration, running.dyn.jerk
        # the NC's own ramp is never refused: values the planner cannot take are clamped into range
        d = core.stop_dynamics(i, min(max(dec, 1e-6), 1e10), min(max(jerk, 1e-6), 1e12), running)
        start = core.start_state(i, total=True)
        if start.v * start.a > 0:
            # accelerating (a slave, a superposition or a feed beyond AxisVeloMax): take the acceleration
            # down with the jerk that keeps it within AxisVeloMax, up to 4 x AxisJerk (an emergency
            # ramp may jerk harder than a motion; beyond that it overshoots by a^2 / (8 AxisJerk))
            vmax = float(a.vmax[i])
            room = vmax - abs(start.v)
            # (only where its own jerk would overshoot by more than rounding: an axis reaching
            # AxisVeloMax with a residue of acceleration keeps its ramp)
            if start.a * start.a / (2.0 * d.jerk) - room > 1e-9 * max(vmax, 1.0):
                need = start.a * start.a / (2.0 * max(room, 1e-12))
                d = d.with_(jerk=min(need, 4.0 * float(a.jerk[i]), 1e12))
        try:
            plan = plan_velocity(start, 0.0, d)
        except PlanningError:
            _log.error("axis %d: no stop ramp could be planned; the set-point stops at once", int(a.ids[i]))
            core.clear_profile(i)  # cannot plan: stop the set-point at once (never keep moving)
            return
        self.begin(i, Job(kind, {}, dyn=d), plan, abort_waiting=False)

    def fault(self, i: int, code: int) -> None:
        """See :meth:`NcCore.fault`."""
        core = self.core
        a, q = core.axes, core.queues[i]
        if a.error[i]:
            return
        core.state_dirty = True
        a.error[i] = code
        core.superposition.abort(core, i)  # the ramp brakes the total motion
        running = q.active
        if q.waiting is not None:
            q.end(q.waiting, CmdState.ABORTED)
        if running is not None:
            q.end(running, CmdState.ERROR, code)
        moving = bool(a.traj_on[i]) or abs(a.set_velo[i]) > 0
        # a drive that does not follow (a CiA 402 fault: it has stopped itself) gets no ramp: the set-point
        # follows its actual position (NcCore.take_inputs)
        if moving and a.enabled[i] and core.drive.following[i]:
            try:
                self.start_ramp(i, FAULT_RAMP, running)
            except Exception:  # never leave an axis in error moving
                _log.exception("axis %d: fault ramp failed; the set-point stops at once", int(a.ids[i]))
                core.clear_profile(i)
        else:
            core.clear_profile(i)
        self.sync(i)

    def finish(self, i: int, job: Job, state: CmdState = CmdState.DONE, error_id: int = 0) -> None:
        """End the running ``job``; a waiting job takes over (or the generator stops). A job that ends
        ERROR (it could not do its task: MC_OrientedStop beyond a software limit, after its standard
        stop) clears the queue as an axis error does: the waiting job ends ABORTED, it never starts
        (a buffered successor waits for its predecessor's Done)."""
        core = self.core
        q = core.queues[i]
        if state == CmdState.ERROR and q.waiting is not None:
            q.end(q.waiting, CmdState.ABORTED)
        q.end(job, state, error_id)
        if q.waiting is not None:
            self.advance(i)
        else:
            core.clear_profile(i)
        self.sync(i)

    def advance(self, i: int) -> None:
        """The waiting job takes over from the current set-point state (its exact cycle)."""
        core = self.core
        q = core.queues[i]
        nxt = q.waiting
        assert nxt is not None
        prev = q.active
        if prev is not None:
            q.end(prev, CmdState.DONE)
        try:
            plan = nxt.kind.activate(core, i, nxt, core.start_state(i, total=nxt.kind.braking))
        except NcError as err:
            # it can no longer start: it ends ERROR with that check's code, the axis stops
            q.end(nxt, CmdState.ERROR, err.code)
            _log.info("axis %d: buffered command %d could not start: %s", int(core.axis_ids[i]), nxt.cmd_no, err)
            if abs(core.axes.set_velo[i]) > _EPS_V:
                self.start_ramp(i, HALT_RAMP, prev)
            else:
                core.clear_profile(i)
            self.sync(i)
            return
        self.begin(i, nxt, plan, abort_waiting=False)

    def blend(self, i: int) -> None:
        """Re-plan the running job so that it passes its target with the blending velocity of the
        waiting job's BufferMode (the rules: ``JobKind.blend_velocity``). A running job without a
        target (velocity, stop): no blending, the waiting job starts at the end as with Buffered.
        The plan lowers the velocity where the job could not reach it without passing its target."""
        core = self.core
        q = core.queues[i]
        prev, nxt = q.active, q.waiting
        if prev is None or nxt is None or nxt.buffer_mode not in BLENDING:
            return
        bp = prev.kind.blend_point(prev)
        if bp is None:
            return
        _, sense, _ = bp
        v = prev.kind.blend_velocity(core, i, prev, nxt)
        ov = float(core.axes.override[i])
        prev.end_velocity = sense * v
        try:
            plan = prev.kind.replan(core, i, prev, core.start_state(i), ov)
        except NcError:
            # ruckig could not blend from this state: the running plan stays (it ends at rest, the
            # waiting job starts there, as Buffered) -- "blending as well as possible"
            prev.end_velocity = 0.0
            plan = None
        if plan is not None:
            core.set_plan(i, plan)
        self.sync(i)

    def release_slaves(self, m: int) -> None:
        """Master row ``m`` lost its enable: its set position now follows its actual position, which
        a slave cannot follow without a jump. Its slaves are decoupled (the coupling jobs end ABORTED)
        and brake on their own ramps (their own slaves follow them)."""
        core = self.core
        for s in (core.coupling.master == m).nonzero()[0].tolist():
            q = core.queues[s]
            job = q.active
            if job is None or job.kind.source != "coupling":
                continue
            q.end(job, CmdState.ABORTED)
            core.superposition.abort(core, s)
            self.start_ramp(s, HALT_RAMP, None)
            self.sync(s)

    # -- the cycle ---------------------------------------------------------------------------
    def plan_ends(self, rows: np.ndarray) -> None:
        """The rows whose plan ended this cycle: their kind decides (done, steady, continue)."""
        core = self.core
        a = core.axes
        self.touched.clear()  # (rows touched before are synced by whoever touched them)
        synced: dict[int, int] = {}  # rows whose branch below ended with their sync (sync_touched)
        for i in rows.tolist():
            q = core.queues[i]
            job = q.active
            if job is None:
                core.clear_profile(i)
                continue
            try:
                res = guarded(f"end of {job.kind.name}", lambda job=job, i=i: job.kind.on_end(core, i, job),
                              lambda i=i: (i,), core.fault, (NcError,))
            except NcError as err:  # its next phase cannot be planned: the job ends with that error
                core.fault(i, err.code)
                continue
            if res is FAILED:
                continue
            if res == "steady":
                a.traj_dur[i] = np.inf  # keep the end velocity: not an end
                if q.waiting is not None and job.kind.successor_may_start(core, i, job):
                    self.advance(i)
                self.sync(i)
            elif res == "done":
                if q.waiting is None and job.target is not None and job.end_velocity == 0.0 and not job.kind.is_stop:
                    a.set_pos[i] = job.target  # exact end
                    a.target_pos[i] = job.target
                    a.since_end[i] = 0.0
                    a.end_watch = True  # (monitoring looks at since_end from now on)
                elif q.waiting is None:
                    a.target_pos[i] = a.set_pos[i]
                self.finish(i, job)
            else:  # "continue": the kind planned on
                self.sync(i)
            synced[i] = len(self.touched)
            core.state_dirty = True
        if self.touched:
            self.sync_touched(synced)

    def watches(self, watch_rows: list[tuple[JobKind, np.ndarray]]) -> None:
        """The per-cycle watches of the running jobs, kind by kind (rows synced as they changed)."""
        core = self.core
        self.touched.clear()
        for kind, rows in watch_rows:
            if core.state_dirty:  # jobs ended or changed this cycle: only rows still watched
                rows = self.still_watched(kind, rows)
                if not rows.size:
                    continue
            try:  # (the guard of guarded(), inline: no closure and no text built every cycle)
                kind.watch(core, rows)
            except Exception:
                on_bug(f"job watch of {kind.name}", rows.tolist(), core.fault)
            if self.touched:
                self.sync_touched()

    def still_watched(self, kind: JobKind, rows: np.ndarray) -> np.ndarray:
        """The rows of ``rows`` whose running job is still one of ``kind`` that wants its watch."""
        queues = self.core.queues
        keep = [i for i in rows.tolist()
                if (j := queues[i].active) is not None and j.kind is kind and j.kind.wants_watch(j)]
        return np.array(keep, dtype=np.intp)

