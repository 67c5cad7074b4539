"""NcCore: the pure, cycle-stepped NC (no zenoh, no threads, no clock reads).

A test (or the server) drives it cycle by cycle::

    core = NcCore([AxisConfig(1, "X")], cycle_time=0.001)
    core.set_plctonc(0, enabled_record)
    reply = core.execute(parse_request(...), axis_id=1)
    core.step()
    core.nctoplc[0]["SetPos"]

The motion engine: every motion command becomes a job (:mod:`.jobs`) in the axis's queue; the
active job's plan (:mod:`.planning`) is evaluated by the set-point stages (:mod:`.stages`).

Cycle order (``NcCore.pipeline``, :mod:`.pipeline`; the set-point stages: :mod:`.stages`): inputs (PLCTONC: enables, override) -> the
profile stage -> plan ends (jobs end, buffered jobs take over) -> the external set-point
generator -> superposition and coupling, level by level (masters before slaves) -> limits of
slaves and superpositions -> job watches and limits (soft-limit approach, switching positions,
homing, feed enables) -> drive -> touch probe latches -> monitoring -> NCTOPLC and job records.

Positions: the NC's positions (set, actual, targets) are what the PLC sees. ``axes.offset`` is the
difference NC - drive position at the drive boundary (MC_SetActualPosition), and ``axes.origin``
the shift of a running plan since it was planned (MC_SetActualPositionOnTheFly): no absolute value
is rewritten when the position is set.

Seams: job kinds and set-point stages see the NC through :class:`.context.CoreContext`; the job
lifecycle is :mod:`.engine`, the pure checks :mod:`.checks`, the output records :mod:`.packing`,
the cycle :mod:`.pipeline`. NcCore is the front: execute, step, PLCTONC in, parameters.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Any, Callable, Iterable, Mapping, Sequence, cast

import numpy as np

from nc_schema import (
    NCJOBS_DTYPE, NCTOPLC_DTYPE, PLCTONC_DTYPE, ST_AXIS_PARAMETER_SET, CmdState, ControlDWord, E_NcDriveType,
    COMMAND_SPECS, E_NcEncoderType, ErrorCodes, NcError, OpModeDWord, StateDWord, make_reply, next_cmdno,
)

from ..drives.base import DriveABC
from ..drives.sim import SimDrive
from . import checks
from .axes import AxisTable
from .checks import MAX_POSITION
from .commands import CORE_HANDLERS, core_command
from .drive_monitor import DriveMonitor
from .corrections import Corrections
from .engine import KINDS_LIST, JobEngine
from .jobs import KINDS, Job, JobKind, JobQueue
from .jobs.stop import STOP
from .packing import JobRecords, NctoplcPacker
from .pipeline import Pipeline, Stage, default_pipeline, run_pipeline
from .params import AxisConfig, AxisParams, ConfigError, param_entry
from .planning import Dynamics, Plan, PlanningError, StartState, plan_velocity
from .remote import MasterSample, RemoteMasters
from .profile import evaluate
from .stages import CouplingStage, ExternalStage, ProbeStage, ProfileStage, SuperpositionStage

_log = logging.getLogger(__name__)
#: Cycles of set-points evaluated ahead (NcCore(lookahead=...)); the refills are staggered over the
#: cycles (stages.ProfileStage), events refresh only the changed axes. None: 16.
LOOKAHEAD: int | None = None
_EPS_V = 1e-9
_EN = int(ControlDWord.Enable)
_FP = int(ControlDWord.FeedEnablePlus)
_FM = int(ControlDWord.FeedEnableMinus)
_CAM = int(ControlDWord.HomingSensor)
_OVERRIDE_MAX = 1_000_000


_NOT_MOVING = np.uint32(int(StateDWord.NotMoving))
_LOOP = np.uint32(int(StateDWord.ControlLoopClosed))
_OPERATIONAL = np.uint32(int(StateDWord.Operational))

_PROTECTED = np.uint32(int(StateDWord.Protected))
_PTP = np.uint32(int(StateDWord.PTPmode))
_COMPENSATING = np.uint32(int(StateDWord.Compensating))
_EXT_ENABLED = np.uint32(int(StateDWord.ExtSetPointGenEnabled))
_LATCH_VALID = np.uint32(int(StateDWord.ExternalLatchValid))

#: commands whose engine path ends with the sync of their row (JobEngine.motion, JobEngine.amend): the job
#: kinds (the registry's, filled when .jobs was imported) and the contract's amendments (the registry
#: refuses an amendment registered other than as ``how="amendment"``, whose handler must end in
#: JobEngine.amend). A read-class command must change no record: execute syncs nothing after it.
_ENGINE_SYNCED = frozenset(KINDS) | frozenset(n for n, s in COMMAND_SPECS.items() if s.amends)
#: the read class (schema/protocol.json): they change nothing, so no row is synced after them
_READS = frozenset(n for n, s in COMMAND_SPECS.items() if s.cls == "read")

@dataclass(eq=False, slots=True)
class Prepared:
    """A motion command prepared for activation at the start of cycle :attr:`cycle` (TwinCAT's SVB:
    :meth:`NcCore.prepare`); :meth:`NcCore.activate` starts it there (SAF) if its prediction still holds.

    Attributes:
        i: the axis row.
        job: the accepted record (numbered when it begins).
        plan: its plan from the row's set-point state at the start of ``cycle`` (None: a job of a set-point stage).
        cycle: the step in which it takes effect (``core.cycle + 1`` when it was prepared).
        rows: (row, :attr:`NcCore.row_version`) of every row the preparation read: the axis, a gearing's master.
        inputs: the axis's applied PLCTONC ControlDWord and Override when it was prepared (the checks and the
            plan's scale depend on them).
        reply: the reply it gets when it is activated as predicted (cycle, CmdNo).
    """

    i: int
    job: Job
    plan: Plan | None
    cycle: int
    rows: tuple[tuple[int, int], ...]
    inputs: tuple[int, int]
    reply: dict[str, Any]


def default_drive(params: Sequence[AxisParams], cycle_time: float) -> DriveABC:
    """The drives an NcCore builds when given none: simulated CiA 402 drives (``cia402-sim``, issue 20; the
    first-order lag and encoder chain of ``sim`` behind the CiA 402 layer: docs/drives.md "The default simulated
    drive"); the server's default is ``[nc] drive`` (nc_server/server/config.py, default.toml)."""
    from ..drives.cia402.sim import Cia402SimDrive  # (here: the drives package imports the core)
    return Cia402SimDrive(params, cycle_time)


class NcCore:
    """All axes of one NC, stepped one fixed cycle at a time.

    Args:
        axes: the configured axes (ids must be unique).
        cycle_time: NC cycle time [s] (> 0).
        drive: the drives of all axes; default: :func:`default_drive`.

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
            lookahead = 16
        self.configs = list(axes)
        self.params: list[AxisParams] = [c.params for c in axes]
        self.axes = AxisTable(ids, self.params)
        self.axis_ids = self.axes.ids
        self._index = {int(a): i for i, a in enumerate(ids)}
        self.drive = drive if drive is not None else default_drive(self.params, self.cycle_time)
        #: position correction, backlash, dead time between the set-point and the drive (corrections.py)
        self.corrections = Corrections(self.axes, self.params, self.cycle_time)
        #: the set position the controller compares with ActPos (PosDiff, lag): SetPos, or with a dead
        #: time the delayed one (set by the drive stage)
        self.pos_ref: np.ndarray = self.axes.set_pos
        self.queues = [JobQueue() for _ in ids]
        #: per row, bumped by every change of its job records (the engine's sync): a preparation made before
        #: a change is stale (:meth:`activate`)
        self.row_version = [0] * len(ids)
        #: 1 for an axis with a command in preparation (a server's commands in steps, :meth:`set_preparing`)
        self.preparing = np.zeros(len(ids), dtype=np.uint8)
        self.cycle = 0
        self.nc_time_ns = 0
        n = len(ids)
        self.plctonc = np.zeros(n, dtype=PLCTONC_DTYPE)
        self.plctonc[:] = self.default_plctonc()
        self.plctonc_arrived = np.zeros(n, dtype=bool)  # a PLCTONC was handed in since the last cycle
        self.ncjobs = np.zeros(n, dtype=NCJOBS_DTYPE)
        self.ncjobs["AxisId"] = self.axis_ids
        self.records = JobRecords(self.ncjobs, ids)
        self.engine = JobEngine(self)
        self._not_moving = np.array([_NOT_MOVING, 0], dtype=np.uint32)  # by |set velocity| > eps
        self._loop_ok = np.array([_LOOP | _OPERATIONAL, _LOOP], dtype=np.uint32)  # by error
        self.profile = ProfileStage(self, max(1, int(lookahead)))
        self.external = ExternalStage(n, self.cycle_time)
        self.superposition = SuperpositionStage(n, self.cycle_time)
        self.coupling = CouplingStage(n, self.cycle_time)
        self.probe = ProbeStage(n)
        self._slot_dw = np.zeros(n, dtype=np.uint32)  # StateDWord bits of the stages (event-driven)
        # the set-point StateDWord bits and AxisState, one array (the profile stage copies both at once)
        self.sp_words = np.zeros((2, n), dtype=np.uint32)
        self.sp_dw, self.axis_state = self.sp_words
        self.on_rows = np.zeros(0, dtype=np.intp)
        self.all_on = False
        self.has_origin = False
        self._has_offset = False
        self._off_rows = np.arange(n)
        self.watch_rows: list[tuple[JobKind, np.ndarray]] = []
        #: OpModeSimulationAxis on the axes whose drive is simulated (a DriveGroup may mix backends)
        self._opmode_sim = self.drive.simulated_axes.astype(np.uint32) * np.uint32(int(OpModeDWord.OpModeSimulationAxis))
        self.nctoplc = np.zeros(n, dtype=NCTOPLC_DTYPE)
        self.nctoplc["AxisId"] = self.axis_ids
        self.nctoplc["OpModeDWord"] = self.axes.opmode
        self._packer = NctoplcPacker(self.nctoplc)
        self._dt_ns = int(round(self.cycle_time * 1e9))
        self.act_pos = self.drive.act_pos.copy()
        self.prev_act_pos = self.act_pos.copy()
        self.drive_monitor = DriveMonitor(n)
        #: called as hook(row, jump [u]) when an axis's actual position moved without motion (an encoder
        #: parameter changed what the drive reports): what keeps a history of positions restarts there
        self.position_jump_hooks: list[Callable[[int, float], None]] = []
        self.position_jump_hooks.append(self.corrections.restart_history)  # (the dead-time history)
        self._in_dirty = True
        #: counts the changes of ``plctonc`` (set_plctonc, set_plctonc_many, inputs_changed: a direct write must
        #: call inputs_changed to be applied); the frame ring copies PLCTONC into a slot only when it changed
        self.plctonc_version = 0
        self.state_dirty = True  # derived state and records to recompute before their next use
        self.refine_plans = False  # True only while a command runs (execute, prepare): CoreContext
        self.profile_idle = np.zeros(0, dtype=np.intp)
        self.plan_ended = self.profile_idle  # the profile stage's rows whose plan ended this cycle
        self._pipeline = Pipeline(default_pipeline())
        self.stage_last_ns = [0] * len(self.pipeline)
        self.stage_max_ns = [0] * len(self.pipeline)
        self._apply_inputs()
        self._derive_state()
        self.fill_nctoplc()

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
        r["Override"] = _OVERRIDE_MAX
        return cast(np.void, r[()])  # (numpy's stubs type a 0-d array's [()] as an array)

    def set_plctonc(self, index: int, record: np.void | bytes | bytearray) -> None:
        """Apply a PLCTONC to axis row ``index`` from the next step.

        Raises:
            ValueError: a bytes record that is not 128 bytes.
        """
        if isinstance(record, (bytes, bytearray, memoryview)):
            if len(record) != PLCTONC_DTYPE.itemsize:
                raise ValueError(f"PLCTONC is {PLCTONC_DTYPE.itemsize} bytes, got {len(record)}")
            record = np.frombuffer(record, dtype=PLCTONC_DTYPE, count=1)[0]
        self.plctonc_arrived[index] = True  # (a PLC frame: the external generator's feed, also unchanged)
        if self.plctonc[index].tobytes() != np.asarray(record, dtype=PLCTONC_DTYPE).tobytes():
            self.plctonc[index] = record
            self._in_dirty = True
            self.plctonc_version += 1

    def configure_remote(self, own_nc: str, masters: Sequence[tuple[str, int]], max_age: float = 0.05) -> None:
        """The masters on other NCs this NC's slaves may follow (``[remote] masters``), this NC's name (refused as
        a MasterNc) and the largest age [s] of a master's newest sample a slave still follows (configuration; a
        coupled slave's master stays where it is)."""
        if not 0 < max_age <= 10.0:
            raise ConfigError("remote.max_age", f"must be in (0, 10] s, got {max_age}")
        self.coupling.sources = RemoteMasters(own_nc, masters, int(round(max_age * 1e9)))

    def set_remote_samples(self, samples: Iterable[MasterSample]) -> None:
        """The remote masters' samples that arrived since the last step (coupling across NCs): the cycle's one
        input from other NCs, used from the next step; samples of masters not configured, older than the newest
        one or not finite are ignored (counted in ``coupling.sources.ignored``)."""
        self.coupling.sources.feed(samples)

    def inputs_changed(self) -> None:
        """The applied PLCTONC changed (e.g. SetOverride): decoded again at the next step."""
        self._in_dirty = True
        self.plctonc_version += 1

    def set_plctonc_many(self, index: np.ndarray, records: np.ndarray) -> None:
        """Apply PLCTONC records to several axis rows at once (vectorized :meth:`set_plctonc`)."""
        new = np.ascontiguousarray(records, dtype=PLCTONC_DTYPE).view(np.uint8).reshape(-1, PLCTONC_DTYPE.itemsize)
        self.plctonc_arrived[index] = True
        # through byte views: indexing a structured array of 22 fields copies field by field (~10x slower)
        rows = self.plctonc.view(np.uint8).reshape(len(self.plctonc), PLCTONC_DTYPE.itemsize)
        if not np.array_equal(rows[index], new):
            rows[index] = new
            self._in_dirty = True
            self.plctonc_version += 1

    def _refused(self, rid: Any, cmd: Any, exc: Exception, cycle: int) -> dict[str, Any]:
        """The reply to a command that raised: an :class:`NcError`'s code and text, anything else (a bug)
        logged with its traceback and answered NC_INTERNAL; the rows it touched are synced first."""
        self._sync_refused()
        if isinstance(exc, NcError):
            return make_reply(rid, cmd, exc.code, str(exc), cycle)
        _log.error("command %r failed", cmd, exc_info=exc)
        return make_reply(rid, cmd, ErrorCodes.NC_INTERNAL, f"internal error: {exc.__class__.__name__}: {exc}", cycle)

    def _sync_refused(self) -> None:
        """After a refused or failed command: the rows its hooks touched before it raised are synced too
        (records stay true; the next step would otherwise drop them unsynced). Never raises."""
        try:
            self.engine.sync_touched()
            self.engine.flush_slots()
        except Exception:  # (the reply is an error already; the cycle must go on)
            _log.exception("syncing after a refused command failed")

    def execute(self, request: dict[str, Any], axis_id: int | None) -> dict[str, Any]:
        """Run one parsed request (``nc_schema.parse_request``) against an axis.

        Returns a reply map; never raises for bad input. The command takes effect
        in the next :meth:`step`, whose cycle number the reply carries.
        """
        cycle = self.cycle + 1
        rid, cmd = request.get("id"), request.get("cmd")
        self.state_dirty = True
        self.engine.touched.clear()
        try:
            if axis_id is None:
                raise NcError(ErrorCodes.ADSERR_DEVICE_SRVNOTSUPP, f"{cmd} needs an axis key (nc/<nc>/axis/<id>/cmd/<class>/<client>)")
            i = self.index(axis_id)
            self.refine_plans = True  # (the command path, between cycles: CoreContext.refine_plans)
            try:
                out = self._dispatch(i, request)
            finally:
                self.refine_plans = False
        except Exception as exc:  # NcError: its code; a bug must cost one command, never the NC cycle
            return self._refused(rid, cmd, exc, cycle)
        # the engine's rule: records true after every command. Row i is synced unless its engine path
        # ended with that sync or the command only reads; then the other rows its hooks changed.
        engine = self.engine
        if cmd not in _READS:
            if cmd not in _ENGINE_SYNCED:
                engine.sync(i)
            if engine.touched:
                engine.sync_touched({i: len(engine.touched)})  # (row i: synced after its last change)
        elif engine.touched:
            engine.sync_touched()
        engine.flush_slots()
        return make_reply(rid, cmd, 0, "", cycle, cmd_no=out.get("cmd_no"), value=out.get("value"))

    def prepare(self, request: dict[str, Any], axis_id: int | None) -> Prepared | dict[str, Any]:
        """Prepare one parsed request for activation at the start of the next step (TwinCAT's SVB): a
        motion command that starts now is checked and planned from the state the next step starts from,
        changing nothing; :meth:`activate` starts it (SAF). Any other command (and a motion command
        queued behind the running job) runs now, as :meth:`execute`: its reply is returned.

        Returns:
            a :class:`Prepared`, or the reply map (a refusal: the TwinCAT code; never raises for bad input).
        """
        cmd = request.get("cmd")
        kind = KINDS.get(cmd) if isinstance(cmd, str) else None
        if kind is None or axis_id is None:
            return self.execute(request, axis_id)
        cycle = self.cycle + 1
        rid = request.get("id")
        self.engine.touched.clear()
        try:
            i = self.index(axis_id)
            self.refine_plans = True  # (the command path, between cycles: CoreContext.refine_plans)
            try:
                got = self.engine.prepare(i, kind, request)
            finally:
                self.refine_plans = False
        except Exception as exc:  # NcError: its code; a bug must cost one command, never the NC cycle
            return self._refused(rid, cmd, exc, cycle)
        if got is None:  # queued behind the running job: one step, now
            return self.execute(request, axis_id)
        job, plan = got
        rows: tuple[tuple[int, int], ...] = ((i, self.row_version[i]),)
        master = job.data.get("master")
        if master is not None and 0 <= int(master) != i:  # (-1: a master on another NC, no row here)
            rows += ((int(master), self.row_version[int(master)]),)
        # (begin numbers it so: the queue is verified unchanged when it is activated)
        cmd_no = job.cmd_no if (job.numbered or job.kind.internal) else next_cmdno(self.queues[i].newest)
        return Prepared(i, job, plan, cycle, rows, self._inputs_of(i), make_reply(rid, cmd, 0, "", cycle, cmd_no=cmd_no))

    def set_preparing(self, axis_id: int, on: bool) -> None:
        """Whether a command on ``axis_id`` is in preparation (TwinCAT's SVB: from its request's handling to its
        activation or refusal): NCTOPLC.SvbEntries counts it in the frames made meanwhile. Unknown ids: ignored."""
        i = self._index.get(axis_id)
        if i is not None and bool(self.preparing[i]) != on:
            self.preparing[i] = on
            self.state_dirty = True

    def _inputs_of(self, i: int) -> tuple[int, int]:
        return int(self.plctonc["ControlDWord"][i]), int(self.plctonc["Override"][i])

    def holds(self, p: Prepared) -> bool:
        """Whether ``p``'s prediction holds now: the step about to run is its cycle, and no row it read and
        no input of its axis changed since it was prepared."""
        return (self.cycle + 1 == p.cycle and all(self.row_version[r] == v for r, v in p.rows)
                and self._inputs_of(p.i) == p.inputs)

    def activate(self, p: Prepared) -> dict[str, Any] | None:
        """Start a prepared command before the step of its cycle (TwinCAT's SAF: the plan row swapped in, the
        running job aborted, the records synced): between the previous step and that cycle's PLCTONC
        (the server: in the gap of its plan, or at that cycle's start). Returns its reply (``cycle`` = the step in which it
        takes effect), or None when its prediction no longer holds (:meth:`holds`): nothing changed;
        prepare it again or refuse it, never activate it stale."""
        if not self.holds(p):
            return None
        i, job = p.i, p.job
        rid, cmd = p.reply.get("id"), p.reply.get("cmd")
        self.state_dirty = True
        engine = self.engine
        engine.touched.clear()
        try:
            engine.begin(i, job, p.plan)
        except Exception as exc:  # NcError: its code; a bug must cost one command, never the NC cycle
            return self._refused(rid, cmd, exc, p.cycle)
        if engine.touched:
            engine.sync_touched({i: len(engine.touched)})
        engine.flush_slots()
        if job.cmd_no != p.reply.get("CmdNo"):  # (never expected: the queue was verified unchanged)
            return make_reply(rid, cmd, 0, "", p.cycle, cmd_no=job.cmd_no)
        return p.reply

    def fault(self, i: int, code: int) -> None:
        """Raise axis error ``code`` now and stop the axis with its deceleration.

        The first error sticks (like TwinCAT); the running job ends ERROR, a waiting one ABORTED;
        the drive stays enabled until the stop ramp ends, whatever the PLCTONC says.
        """
        self.engine.fault(i, code)

    @property
    def moving(self) -> np.ndarray:
        """Axes with a job or a non-zero set velocity."""
        moving: np.ndarray = self.axes.has_job | (np.abs(self.axes.set_velo) > _EPS_V) | self.axes.traj_on
        return moving

    @property
    def stopping(self) -> np.ndarray:
        """Axes whose running motion is a stop (MC_Stop or a stop ramp of the NC)."""
        out = np.zeros(self.axes.n, dtype=bool)
        for i, q in enumerate(self.queues):
            out[i] = q.active is not None and q.active.kind.is_stop
        return out

    def commanders(self, i: int) -> set[str]:
        """The clients whose motion runs or waits on axis row ``i``: the running and the buffered
        numbered job (stops excepted: they stop anyway) and a running superposition ("" =
        anonymous). The server stops these motions when their client is lost."""
        q, sp = self.queues[i], self.superposition
        out = {j.client for j in (q.active, q.waiting) if j is not None and j.numbered and not j.kind.is_stop}
        if sp.on[i] and sp.state[i] == int(CmdState.ACTIVE):
            out.add(sp.client[i])
        return out

    def info(self) -> dict[str, Any]:
        return {"cycle_time": self.cycle_time,
                "axes": [{"AxisId": c.AxisId, "Name": c.Name, "Modulo": c.params.Modulo,
                          "ModuloFactor": c.params.AxisEncoderModuloValue} for c in self.configs]}

    def read_parameter(self, i: int, number: int) -> float | bool:
        """Value of MC_AxisPara ``number`` for axis row ``i`` (the parameter table ``nc_schema.PARAMETERS``):
        a bool for BOOL parameters, else a float.

        Raises:
            NcError: 0x703 a number TcMC does not define.
        """
        e = param_entry(number)
        if e.source == "status":
            return self._status_param(i, e.status or "")
        if e.source == "fixed":
            return bool(e.fixed) if e.is_bool else float(e.fixed)
        v = getattr(self.params[i], e.store or "")
        return bool(v) if e.is_bool else float(v)

    def write_parameter(self, i: int, number: int, value: float | bool) -> None:
        """Write MC_AxisPara ``number`` (validated; a rejected value changes nothing). It takes effect at once:
        commands run between two cycles, so the next cycle is the first one with the new value.

        Raises:
            NcError: 0x703 unknown number, 0x704 read-only (status), 0x4251 another value than the fixed
                one of a parameter without meaning here, 0x70B invalid value (type or range), 0x4220 a
                parameter written only at standstill while the axis moves, 0x4B42 one written only while
                disabled while the controller is enabled, the parameter's own TwinCAT code for a bad value where
                the table gives one (``ParamEntry.code``: AxisLoopingDistance 0x4328, AxisOverrideType 0x430D,
                ...), 0x4221/0x422F/0x4222 a value that would break the running motion (see
                :meth:`_check_running`).
        """
        e = param_entry(number)
        if e.source == "status":
            raise NcError(ErrorCodes.ADSERR_DEVICE_INVALIDACCESS, f"parameter {number} ({e.name}) is read-only")
        if e.is_bool and not isinstance(value, bool):
            if value not in (0.0, 1.0):
                raise NcError(e.code or ErrorCodes.ADSERR_DEVICE_INVALIDPARM,
                              f"{e.name} is boolean: 0/1 or true/false, got {value}")
            value = bool(value)
        if e.source == "fixed":
            same = (bool(value) == bool(e.fixed)) if e.is_bool else (
                not isinstance(value, bool) and float(value) == float(e.fixed))
            if not same:
                raise NcError(ErrorCodes.NC_FUNCTION_NOT_SUPPORTED,
                              f"{e.name} has no meaning for this NC: its value is fixed at {e.fixed!r}")
            return
        name = e.store or ""
        if not e.is_bool and isinstance(value, bool):
            raise NcError(ErrorCodes.ADSERR_DEVICE_INVALIDPARM, f"{e.name} is a number, got {value!r}")
        if e.when == "standstill" and self._moves(i):
            raise NcError(ErrorCodes.NC_GROUP_NOT_READY, f"{e.name} can only be written at standstill")
        if e.when == "disabled" and self.axes.enabled[i]:
            raise NcError(ErrorCodes.MC_AXIS_IS_ENABLED, f"{e.name} can only be written while the controller is disabled")
        try:
            new = self.params[i].with_value(name, value)
        except ConfigError as exc:  # (the parameter's own TwinCAT code where the table gives one)
            raise NcError(exc.code or ErrorCodes.ADSERR_DEVICE_INVALIDPARM, f"{exc.key}: {exc.message}") from None
        if self._moves(i):
            self._check_running(i, new)
        self.params[i] = new
        self.configs[i].params = new
        self.axes.load_params(i, new)
        before = float(self.drive.act_pos[i])
        self.drive.configure(i, new)
        self.corrections.configure(i, new)
        self.coupling.invalidate()  # (its copies of the limits)
        self.state_dirty = True
        jump = float(self.drive.act_pos[i]) - before
        if jump:
            self.position_jumped(i, jump)

    def position_jumped(self, i: int, jump: float) -> None:
        """Axis row ``i``'s actual position moved by ``jump`` [u] without motion (the drive reports it
        otherwise now: an encoder parameter). The NC's copies follow at once (the set position of a disabled
        axis follows its actual position), then every hook of :attr:`position_jump_hooks` is called."""
        a = self.axes
        self.act_pos = self.drive.act_pos + a.offset  # (a new array: the drive's may have changed in place)
        self.prev_act_pos = self.prev_act_pos.copy()  # (a latch compares the last two: no motion)
        self.prev_act_pos[i] += jump
        if not a.enabled[i]:
            a.set_pos[i] = a.target_pos[i] = self.act_pos[i]
        self.state_dirty = True
        for hook in self.position_jump_hooks:
            hook(i, jump)

    def _moves(self, i: int) -> bool:
        """Whether axis row ``i`` moves or is driven: a job, a plan, a set velocity, a coupling, a
        superposition or the external set-point generator."""
        a = self.axes
        return bool(a.has_job[i] or a.traj_on[i] or abs(a.set_velo[i]) > _EPS_V or self.queues[i].active is not None
                    or self.coupling.slave[i] or self.superposition.on[i] or self.external.on[i])

    def _check_running(self, i: int, new: AxisParams) -> None:
        """Refuse parameters the running motion would violate (:func:`.checks.check_running`)."""
        checks.check_running(self.axes, i, self.queues[i].active, self.params[i], new)

    def parameter_set(self, i: int) -> dict[str, Any]:
        """ST_AxisParameterSet of axis row ``i`` as a map of its members (MC_ReadParameterSet; the table's
        ``structs.ST_AxisParameterSet`` says where each value comes from)."""
        c, p = self.configs[i], self.params[i]
        stepper = bool(p.SimStepper) and bool(self.drive.simulated_axes[i])
        enc = E_NcEncoderType.NcEncoderType_KL2531_Stepper if stepper else E_NcEncoderType.NcEncoderType_Simulation
        drv = E_NcDriveType.NcDriveType_KL2531_Stepper if stepper else E_NcDriveType.NcDriveType_undefined
        core = {"AxisId": c.AxisId, "Name": c.Name, "CycleTime": self.cycle_time, "EncoderId": c.AxisId,
                "ControllerId": c.AxisId, "DriveId": c.AxisId, "EncoderType": int(enc), "DriveType": int(drv),
                "Kv": (1.0 / p.SimTimeConstant) if p.SimTimeConstant > 0 else 0.0}
        out: dict[str, Any] = {}
        for f in ST_AXIS_PARAMETER_SET.fields:
            src, _, arg = f.value.partition(":")
            if src == "param":
                v: Any = getattr(p, arg)
            elif src == "core":
                v = core[arg]
            else:
                v = arg
            if f.type == "LREAL":
                out[f.name] = float(v)
            elif f.type.startswith("STRING") or f.type == "T_AmsNetId":
                out[f.name] = str(v)
            else:
                out[f.name] = int(float(v)) if not isinstance(v, bool) else int(v)
        return out

    # -- helpers for the job kinds -----------------------------------------------------------
    def start_state(self, i: int, total: bool = False) -> StartState:
        """The set-point state a new plan starts from (NC position): that of the basic motion, without
        a running superposition (``total``: with it, for a plan that replaces both, e.g. a stop)."""
        a = self.axes
        p, v, acc = float(a.set_pos[i]), float(a.set_velo[i]), float(a.set_acc[i])
        if not total and self.superposition.on[i]:
            sp, sv, sa, _ = self.superposition.applied[:, i]
            p, v, acc = p - float(sp), v - float(sv), acc - float(sa)
        return StartState(p, v, acc)

    def nc_set_pos(self, i: int) -> float:
        return float(self.axes.set_pos[i])

    def override(self, i: int) -> float:
        return float(self.axes.override[i])

    def dynamics(self, i: int, req: Mapping[str, Any], velocity: float | None) -> Dynamics:
        """The dynamics of a command (:func:`.checks.command_dynamics`)."""
        return checks.command_dynamics(self.axes, i, req, velocity)

    def check_velocity(self, i: int, v: float) -> None:
        """Raises NcError 0x4221 unless 0 < v <= AxisVeloMax."""
        checks.check_velocity(float(self.axes.vmax[i]), v)

    def check_startable(self, i: int) -> None:
        """The axis accepts motion commands: no error, no MC_Stop lock, enabled, drive ready."""
        checks.check_startable(self.axes, i, int(self.plctonc["ControlDWord"][i]), bool(self.drive.ready[i]))

    def check_feed(self, i: int, sense: float) -> None:
        """Raises NcError 0x4223 if the feed enable of direction ``sense`` is off."""
        checks.check_feed(int(self.plctonc["ControlDWord"][i]), sense)

    def check_target(self, i: int, start: float, target: float, plan: Plan | None = None) -> None:
        """Software limits for a move from ``start`` to ``target`` (:func:`.checks.check_target`)."""
        checks.check_target(self.axes, i, start, target, plan)

    def check_overshoot(self, i: int, plan: Plan, v_new: float) -> None:
        """Refuse (0x423A) a plan beyond the new and the running velocity (:func:`.checks.check_overshoot`)."""
        checks.check_overshoot(self.axes, i, self.queues[i].active, plan, v_new)

    def check_reversal(self, i: int, plan: Plan, start: StartState, sense: float, target: float | None = None,
                       running: Job | None = None) -> None:
        """Refuse (0x4289) a plan that turns back on its way unless the motion running now (``running``,
        default the active job) turns the axis already (:func:`.checks.check_reversal`)."""
        job = self.queues[i].active if running is None else running
        checks.check_reversal(plan, start, sense, target, checks.running_jerk(self.axes, i, job))

    def plan(self, fn: Callable[..., Plan], *args: Any) -> Plan:
        """Call a planning function; ruckig failures become NcError 0x427E (the motion cannot be
        realized from this state with these dynamics; the command is refused, nothing changes)."""
        try:
            return fn(*args)
        except PlanningError as exc:
            raise NcError(ErrorCodes.NC_MOTION_NOT_REALIZED,
                          f"this motion cannot be planned from the current state with these dynamics ({exc})") from None

    def stop_dynamics(self, i: int, dec: float = 0.0, jerk: float = 0.0, running: Job | None = None) -> Dynamics:
        """Dynamics of a stop (0 = axis defaults), never weaker than a stop already running, and with
        a jerk that cannot speed an accelerating axis up beyond its running motion (TcMC 3.15).

        Args:
            running: the motion being stopped (default: the axis's running job).
        """
        a = self.axes
        job = running if running is not None else self.queues[i].active
        d = self.dynamics(i, {"Deceleration": dec, "Jerk": jerk}, None)
        dec_, jerk_ = d.deceleration, d.jerk
        if job is not None and job.kind.braking and job.dyn is not None:
            # TcMC 3.15: a stop with more rigorous dynamics already runs (MC_Stop, MC_Halt, a ramp)
            dec_, jerk_ = max(dec_, job.dyn.deceleration), max(jerk_, job.dyn.jerk)
        v0, a0 = float(a.set_velo[i]), float(a.set_acc[i])
        if a.traj_on[i] and v0 * a0 > 0 and job is not None and job.dyn is not None:
            # accelerating: the velocity must not exceed the running motion's (acceleration
            # reduces too slowly with a weaker jerk)
            jerk_ = max(jerk_, job.dyn.jerk)
            cap = max(job.dyn.velocity * a.override[i], abs(v0))
            if cap > abs(v0):  # (not beyond the jerk of the axis or of the running motion)
                jerk_ = max(jerk_, min(a0 * a0 / (2 * (cap - abs(v0))), max(jerk_, float(a.jerk[i]))))
        elif a.traj_on[i] and v0 * a0 < 0:
            # braking: the direction must not reverse (the negative acceleration must reach 0
            # before the velocity does), so never below the braking that already runs
            dec_ = max(dec_, abs(a0))
            if job is not None and job.dyn is not None:
                jerk_ = max(jerk_, job.dyn.jerk)
            # ... but never beyond the jerk of the axis or of the running motion: a motion on its own
            # braking curve needs exactly its jerk (no margin beyond rounding); one that cannot stop
            # without turning even with its own jerk was turning anyway (a reversal under way)
            cap = max(jerk_, float(a.jerk[i]))
            jerk_ = max(jerk_, min(a0 * a0 / (2 * abs(v0)) * (1 + 1e-9), cap))
        return Dynamics(float(a.vmax[i]), max(d.acceleration, dec_), dec_, jerk_)

    def stop_within(self, i: int, plan: Plan, running: Job | None) -> bool:
        """The stop ``plan`` ends before the running job's target (on the way out of a loop movement: its
        loop point, where that motion heads) and an enabled soft limit (TcMC 3.15: weaker stop dynamics
        are not used if the target would be exceeded)."""
        a = self.axes
        end = plan.end.p
        v0 = float(a.set_velo[i])
        goal = running.kind.goal(running) if running is not None else None  # (a loop movement: its loop point)
        if running is not None and goal is not None and not running.continuous and v0:
            if (end - goal) * v0 > 1e-9:
                return False
        if a.en_max[i] and v0 > 0 and end > max(float(a.max_lim[i]), float(a.set_pos[i])) + 1e-9:
            return False
        if a.en_min[i] and v0 < 0 and end < min(float(a.min_lim[i]), float(a.set_pos[i])) - 1e-9:
            return False
        return True

    def continue_plan(self, i: int, plan: Plan) -> None:
        """At the end of row ``i``'s plan: follow ``plan``, which starts from that plan's exact end
        state (:meth:`plan_end_state`), as if it had begun there. This cycle's set-point (not sent
        yet) is re-evaluated on it, so the composed motion is sampled exactly (jerk-limited, no
        lateness of up to a cycle)."""
        a = self.axes
        _, elapsed = self.plan_end_state(i)
        self.set_plan(i, plan, elapsed)
        p, v, acc, j = evaluate(a.seg, np.array([elapsed]), np.array([i]))
        a.set_pos[i], a.set_velo[i], a.set_acc[i], a.set_jerk[i] = float(p[0]), float(v[0]), float(acc[0]), float(j[0])

    def plan_end_state(self, i: int) -> tuple[StartState, float]:
        """The exact end state of row ``i``'s current plan and the time since it (>= 0; the plan's
        end is noticed in the first cycle at or after it)."""
        a = self.axes
        p, v, acc, _ = evaluate(a.seg, np.array([a.traj_dur[i]]), np.array([i]))
        return StartState(float(p[0] + a.origin[i]), float(v[0]), float(acc[0])), max(float(a.traj_t[i] - a.traj_dur[i]), 0.0)

    def profile_end(self, i: int) -> float:
        """Position where axis row ``i``'s current plan ends [u]."""
        a = self.axes
        if not a.traj_on[i]:
            return float(a.set_pos[i])
        p, _, _, _ = evaluate(a.seg, np.array([a.traj_dur[i]]), np.array([i]))
        return float(p[0] + a.origin[i])

    def cam(self, rows: np.ndarray) -> np.ndarray:
        """The reference cam (PLCTONC ControlDWord.HomingSensor) of ``rows``."""
        cam: np.ndarray = (self.plctonc["ControlDWord"][rows] & _CAM) != 0
        return cam

    def shift_position(self, i: int, diff: float) -> None:
        """Shift the NC positions of row ``i`` by ``diff`` [u]: the drive offset takes it, the set
        position and the running plan (through ``origin``), the job targets and the other positions
        the jobs keep (:meth:`JobKind.shift`) move with it."""
        a, q = self.axes, self.queues[i]
        self.coupling.shift(i, diff)
        if self.external.on[i]:
            self.external.fold(i, diff)
        a.offset[i] += diff
        a.set_pos[i] += diff
        self.corrections.shift(i, diff)
        a.target_pos[i] += diff
        if a.traj_on[i]:
            a.origin[i] += diff
            a.changed.append(i)
        for job in (q.active, q.waiting):
            if job is not None:
                if job.target is not None:
                    job.target += diff
                job.kind.shift(job, diff)
        self.act_pos = self.act_pos.copy()
        self.act_pos[i] += diff
        self.prev_act_pos = self.prev_act_pos.copy()  # (a latch compares the last two)
        self.prev_act_pos[i] += diff
        self._has_offset = True  # from this cycle's drive step on
        self.has_origin = bool(a.origin.any())
        self.state_dirty = True

    # -- the queue ----------------------------------------------------------------------------
    def set_plan(self, i: int, plan: Plan, elapsed: float = 0.0) -> None:
        """Follow ``plan`` on row ``i`` from the next cycle (the running job keeps going).

        Args:
            elapsed: the time [s] of the plan already gone by at this cycle's set-point (a plan that
                continues the previous one from its exact end, which lies up to a cycle back).
        """
        a = self.axes
        a.seg[:, i, :] = plan.seg
        a.traj_t[i] = elapsed
        a.traj_dur[i] = plan.duration
        a.traj_on[i] = True
        if a.origin[i]:
            a.origin[i] = 0.0
        a.changed.append(i)
        self.engine.touched.append(i)  # (a hook's change: the engine syncs the row after it)
        self.state_dirty = True

    def clear_profile(self, i: int, keep_velocity: bool = False) -> None:
        """Stop the set-point generator (the axis holds its set position; ``keep_velocity``: a
        set-point stage takes the row over from its state)."""
        a = self.axes
        a.changed.append(i)
        self.engine.touched.append(i)
        if a.origin[i]:
            a.origin[i] = 0.0  # (set_pos already includes the origin)
        a.traj_on[i] = False
        if not keep_velocity:
            a.set_velo[i] = 0.0
            a.set_acc[i] = 0.0
            a.set_jerk[i] = 0.0
        self.state_dirty = True

    def fold_offset(self, i: int, offset: float) -> None:
        """A finished superposition's ``offset`` becomes part of row ``i``'s basic motion (whatever
        drives it: plan origin, coupling, fed positions; a standing axis holds it already)."""
        if not offset:
            return
        a = self.axes
        if self.coupling.is_slave(i):
            self.coupling.fold(i, offset)
        elif self.external.on[i]:
            self.external.fold(i, offset)
        elif a.traj_on[i]:
            a.origin[i] += offset
            a.changed.append(i)
            self.has_origin = True
        job = self.queues[i].active
        if job is not None and job.target is not None:
            job.target += offset
            a.target_pos[i] = job.target
        elif not a.traj_on[i]:
            a.target_pos[i] = a.set_pos[i]
        self.state_dirty = True

    def begin(self, i: int, job: Job, plan: Plan | None, abort_waiting: bool = True) -> None:
        """Make ``job`` the running job with ``plan`` (:meth:`.engine.JobEngine.begin`)."""
        self.engine.begin(i, job, plan, abort_waiting)

    def finish(self, i: int, job: Job, state: CmdState = CmdState.DONE, error_id: int = 0) -> None:
        """End the running ``job``; a waiting job takes over (or the generator stops)."""
        self.engine.finish(i, job, state, error_id)

    def start_ramp(self, i: int, kind: JobKind, running: Job | None) -> None:
        """An internal stop ramp (no CmdNo) of ``kind`` (FAULT_RAMP, HALT_RAMP) braking ``running``."""
        self.engine.start_ramp(i, kind, running)

    def touch(self, i: int) -> None:
        """Row ``i``'s job changed (phase, flags): the engine brings its records up to date when the
        running hook returns."""
        self.engine.touched.append(i)

    def jobs_written(self) -> None:
        """Columns of ``ncjobs`` were written directly (not through the engine's sync): counted in
        ``records.version``, so the next frame carries them."""
        self.records.version += 1

    # -- step ---------------------------------------------------------------------------------
    def step(self, nc_time_ns: int | None = None) -> None:
        """Run one NC cycle of ``cycle_time`` seconds: the stages of :attr:`pipeline`, in order.

        Args:
            nc_time_ns: the NC time of this cycle [ns]; default: previous + cycle_time.
        """
        self.cycle += 1
        self.nc_time_ns = int(nc_time_ns) if nc_time_ns is not None else self.nc_time_ns + self._dt_ns
        run_pipeline(self, self._pipeline)

    @property
    def pipeline(self) -> list[Stage]:
        """The cycle's stages in order (:class:`.pipeline.Stage`); step() runs them, the stats show
        their times. A list: a stage inserted, replaced or removed runs from the next step on."""
        return self._pipeline

    @pipeline.setter
    def pipeline(self, stages: list[Stage]) -> None:
        self._pipeline = Pipeline(stages)

    @property
    def inputs_pending(self) -> bool:
        """A PLCTONC changed since the last step: the next step's inputs stage applies it (an unchanged
        frame leaves this False: nothing to re-derive)."""
        return self._in_dirty

    def stage_times(self) -> list[dict[str, Any]]:
        """Per stage of the pipeline, in order: name, last and largest time [us] (the stats' ``stages``)."""
        return [{"name": st.name, "last_us": round(last / 1000.0, 1), "max_us": round(peak / 1000.0, 1)}
                for st, last, peak in zip(self.pipeline, self.stage_last_ns, self.stage_max_ns)]

    # -- the stages' work (pipeline) ---------------------------------------------------------
    def take_inputs(self) -> None:
        """The cycle's inputs: the PLCTONC applied (on changes), the state derived (on events),
        disabled axes' set positions following their actual positions, superimposed offsets off."""
        if self._in_dirty:
            self._apply_inputs()
        if self.state_dirty:
            self._derive_state()
        if self.engine.touched:  # (touched outside a hook: synced there already)
            self.engine.touched.clear()
        if self._off_rows.size:  # disabled axes: the set position follows the actual position
            self.axes.set_pos[self._off_rows] = self.act_pos[self._off_rows]
        d = self.drive
        if d.faulty:  # enabled axes whose drive does not follow (switching on, or stopped itself after a fault)
            a = self.axes
            idle = np.flatnonzero(a.enabled & ~d.following)
            if idle.size:  # no ramp runs on them: the set-point is where the motor is, nothing jumps later
                a.set_pos[idle] = self.act_pos[idle]
                a.set_velo[idle] = 0.0
                a.set_acc[idle] = 0.0
        sup = self.superposition
        if sup.active:
            sup.unapply(self)  # (the stages produce the basic motion; the offsets are added after it)

    def check_feeds(self) -> None:
        """Moving axes with the feed enable of their direction missing: an axis error."""
        feed = self._feed_rows  # moving axes with a feed enable missing in some direction
        if feed.size:
            plus, minus = self._feed_plus[feed], self._feed_minus[feed]
            v = self.axes.set_velo[feed]
            for i in feed[~plus & (v > _EPS_V)]:
                self.fault(int(i), ErrorCodes.NC_AXIS_FEED_ENABLE_PLUS)
            for i in feed[~minus & (v < -_EPS_V)]:
                self.fault(int(i), ErrorCodes.NC_AXIS_FEED_ENABLE_MINUS)

    def step_drive(self) -> None:
        """The drive steps to this cycle's set-points (NC positions less the offset)."""
        a = self.axes
        self.prev_act_pos, prev = self.act_pos, self.act_pos
        ref = a.set_pos
        if self.corrections.active:  # (position correction, backlash, dead time: corrections.py)
            ref = self.corrections.step(self)
            self._has_offset = True
        self.pos_ref = ref
        if self._has_offset:
            self.drive.step(a.enabled, ref - a.offset, a.set_velo, a.set_acc)
            self.act_pos = self.drive.act_pos + a.offset
        else:
            self.drive.step(a.enabled, a.set_pos, a.set_velo, a.set_acc)
            self.act_pos = self.drive.act_pos
        del prev
        ds = self.drive.terminal_status()
        if ds is not None and not np.array_equal(self.records.drive_status, ds):
            self.records.drive_status[:] = ds
            self.records.version += 1  # (only on a change: the frame ring copies NCJOBS when it counts one)

    def derive_state(self) -> None:
        """Recompute what only changes on events (commands, inputs, faults, job ends)."""
        self._derive_state()

    def fill_nctoplc(self) -> None:
        """This cycle's NCTOPLC values (:class:`.packing.NctoplcPacker`)."""
        self._packer.fill(self, self._event_dw, self._loop_dw)

    # -- internals ---------------------------------------------------------------------------
    def _apply_inputs(self) -> None:
        """Decode the applied PLCTONC (only when it changed): enables, feed, override."""
        a = self.axes
        self._in_dirty = False
        ctrl = self.plctonc["ControlDWord"]
        self.corrections.take_input(self.plctonc["PositionCorrection"])
        self._enable_in = (ctrl & _EN) != 0
        self._feed_plus = (ctrl & _FP) != 0
        self._feed_minus = (ctrl & _FM) != 0
        self.drive.set_torque_offset(self.plctonc["ExtTorque"])  # (TorqueOffset; the drive judges the value)
        raw = self.plctonc["Override"]
        too_high = (raw > _OVERRIDE_MAX).nonzero()[0]
        for i in too_high.tolist():
            # TwinCAT: 0x4238 'velocity override not allowed (> 100 %)' -- an axis error, never a
            # silent clamp; the axis goes on with at most 100 % while it stops
            if not a.error[i]:
                _log.warning("axis %d: PLCTONC Override %d > 100 %%", int(a.ids[i]), int(raw[i]))
                self.fault(i, ErrorCodes.NC_OVERRIDE_NOT_ALLOWED)
        ov = np.minimum(raw, _OVERRIDE_MAX) / float(_OVERRIDE_MAX)
        changed = (ov != a.override).nonzero()[0]
        old_ov = a.override
        a.override = ov
        for i in changed.tolist():
            job = self.queues[i].active
            if job is not None and job.numbered and job.kind.follows_override and a.traj_on[i]:
                held = ov[i] <= 0
                try:  # (the kind applies AxisOverrideType: an instantaneous type may keep the running plan)
                    plan = job.kind.override_replan(self, i, job, self.start_state(i), float(old_ov[i]), float(ov[i]))
                except NcError:
                    # not plannable at this override from here (e.g. a tiny override while fast):
                    # the job waits at rest as at override 0 and is re-planned on the next change
                    try:
                        plan = plan_velocity(self.start_state(i), 0.0, job.dyn or self.stop_dynamics(i))
                    except PlanningError:
                        plan = None
                    held = True
                if plan is not None:
                    self.set_plan(i, plan)
                    job.held = held
                    self.engine.sync(i)
        self.state_dirty = True

    def _derive_state(self) -> None:
        """Recompute what only changes on events (commands, inputs, faults, job ends)."""
        self.state_dirty = False
        a, out = self.axes, self.nctoplc
        # PLCopen 'Enable FALSE -> Disabled': the job is aborted, an MC_Stop lock goes with it;
        # only a fault's stop ramp keeps the drive enabled until it ends
        enabled = self._enable_in | (a.hold_enable & a.traj_on)
        flips = (enabled != a.enabled).nonzero()[0]
        if flips.size:
            for i in flips.tolist():
                if enabled[i]:  # controller activation: set position := actual position
                    a.set_pos[i] = a.target_pos[i] = self.act_pos[i]
                    self.corrections.restart_history(i)
                else:
                    q = self.queues[i]
                    if q.waiting is not None:
                        q.end(q.waiting, CmdState.ABORTED)
                    if q.active is not None:
                        q.end(q.active, CmdState.ABORTED)
                    a.locked[i] = False
                    self.superposition.abort(self, i)
                    self.clear_profile(i)
                    self.engine.sync(i)
                    self.engine.release_slaves(i)
            a.enabled = enabled
            self._off_rows = (~enabled).nonzero()[0]
            self.state_dirty = False
        self.on_rows = a.traj_on.nonzero()[0]
        self.all_on = self.on_rows.size == a.n
        if a.changed:  # the axes whose profile changed are evaluated afresh at the next profile run
            self.profile.refresh(self, a.changed)
            a.changed.clear()
        job = a.has_job
        watch = a.watch_kind
        self.watch_rows = []
        watched = watch >= 0
        if np.count_nonzero(watched):  # (np.count_nonzero: far cheaper than ndarray.any here)
            for k in np.unique(watch[watched]).tolist():
                self.watch_rows.append((KINDS_LIST[k], (watch == k).nonzero()[0]))
        self._feed_rows = ((a.driving | self.superposition.on) & ~(self._feed_plus & self._feed_minus)).nonzero()[0]
        standstill = ~(a.traj_on | job)
        standstill &= enabled
        self.monitor_watch = (a.lag_en & enabled, standstill, bool(np.count_nonzero(a.en_max) or np.count_nonzero(a.en_min)),
                       bool(np.count_nonzero(standstill)))
        cpl, sup, ext, pr = self.coupling, self.superposition, self.external, self.probe
        slaves = cpl.slave
        staged = slaves | ext.on | sup.on  # rows a set-point stage writes every cycle
        if not self.all_on:  # axes without a profile: AxisState INACTIVE, NotMoving unless a set velocity remains
            idle = ~(a.traj_on | staged)
            self.sp_dw[idle] = self._not_moving[(np.abs(a.set_velo[idle]) > _EPS_V).view(np.uint8)]
            self.axis_state[idle] = 0
        err = a.error != 0
        # a new array at every derive (edited in place only here, before the packer reads it): NctoplcPacker.fill
        # skips StateDWord while this and _loop_dw are the same objects as at its last fill
        self._event_dw = a.event_dwords(err)
        if np.count_nonzero(staged) or np.count_nonzero(pr.valid):
            # a slave is in protected mode and no PTP axis; Compensating, ExtSetPointGenEnabled,
            # ExternalLatchValid from their stages
            self._event_dw &= ~(slaves * _PTP)
            self._event_dw |= (slaves * _PROTECTED) | (sup.on * _COMPENSATING) | (ext.on * _EXT_ENABLED) | (pr.valid * _LATCH_VALID)
        out["CoupleState"] = cpl.couple_state
        out["TouchProbeState"] = pr.touch_state()
        out["TouchProbeCounter"] = pr.counter
        # ControlLoopClosed always, Operational only without an error (both need enable, drive ready and following)
        self._loop_dw = self._loop_ok[err.view(np.uint8)]
        self._has_offset = bool(np.count_nonzero(a.offset))
        self.has_origin = bool(np.count_nonzero(a.origin))
        out["ErrorCode"] = a.error
        out["SafEntries"] = job  # (1 while a job runs; SvbEntries 1 while a command waits behind it)
        out["SvbEntries"] = a.buffered + self.preparing  # (waiting behind the job, or being prepared)
        out["OpModeDWord"] = a.opmode | self._opmode_sim
        out["CmdNo"] = a.cmd_no
        out["CmdState"] = a.cmd_state
        out["TargetPos"] = a.target_pos
        out["HomingState"] = a.homing_state

    def _status_param(self, i: int, what: str) -> float:
        """A read-only parameter from the live axis state (the table entry's ``status``)."""
        a, r = self.axes, self.nctoplc[i]
        if what in ("SetPos", "ActVelo", "SetVelo"):
            return float(r[what])
        if what == "AxisId":
            return float(a.ids[i])
        if what == "TargetPos":
            return float(a.target_pos[i])
        if what == "RefVelo":
            return float(self.params[i].AxisVeloMax)
        if what == "UnitInterpretation":
            return float(4 if self.params[i].Modulo else 0)  # bit 2 = modulo
        job = self.queues[i].active
        positioning = job is not None and job.numbered and job.target is not None and bool(a.traj_on[i])
        if what == "RemainingTime":
            return float(max(a.traj_dur[i] - a.traj_t[i], 0.0)) if positioning else 0.0
        if what == "RemainingDistance":  # (the ignore: positioning means job and its target are not None)
            return float(abs(job.target - a.set_pos[i])) if positioning else 0.0  # type: ignore[union-attr]
        raise AssertionError(f"params.json: unknown status {what!r}")  # a contract bug, not input

    # -- commands ----------------------------------------------------------------------------
    def _dispatch(self, i: int, req: dict[str, Any]) -> dict[str, Any]:
        # the command registry's handler (.commands): a job kind, an amendment or a function
        handler = CORE_HANDLERS.get(req["cmd"])
        if handler is None:
            raise NcError(ErrorCodes.ADSERR_DEVICE_SRVNOTSUPP, f"{req['cmd']} is not an axis command of the NC core")
        return handler(self, i, req)



@core_command("NewPos", "NewPosAndVelo", "ChangeDynParam", how="amendment")
def _cmd_amend(core: NcCore, i: int, req: dict[str, Any]) -> dict[str, Any]:
    """NewPos, NewPosAndVelo, ChangeDynParam: the running job changes (the engine's amend; its kind decides how)."""
    return core.engine.amend(i, req)


@core_command("StopRelease")
def _cmd_stop_release(core: NcCore, i: int, req: dict[str, Any]) -> dict[str, Any]:
    """MC_Stop Execute fell: unlock -- but not during the stop ramp (PLCopen: Stopping until the axis
    stands and Execute is FALSE); then the lock goes when the ramp ends."""
    job = core.queues[i].active
    if job is not None and job.kind.locks and core.axes.traj_on[i]:
        job.data["release"] = True
        return {}
    core.axes.locked[i] = False
    core.state_dirty = True
    return {}


@core_command("Reset")
def _cmd_reset(core: NcCore, i: int, req: dict[str, Any]) -> dict[str, Any]:
    """MC_Reset. On an axis still braking after an error (its NC stop ramp), the ramp goes on as a
    numbered stop job: that job's number is in the reply (``cmd_no``), so every CmdNo the NC hands
    out is one accepted command's (this reset's); otherwise the reply has none."""
    a, q = core.axes, core.queues[i]
    core.probe.disarm_on_reset(i)
    core.drive.reset(np.array([i]))  # the drive's fault reset (CiA 402: a rising edge of controlword bit 7)
    if core.coupling.is_slave(i) or core.external.on[i]:
        return {}  # a stage drives it (no error: an error ends the coupling/generator): nothing to reset
    if a.traj_on[i] or core.superposition.on[i]:
        if a.error[i] or a.locked[i]:
            # still braking: clear the error/lock now, but the ramp goes on as a numbered stop
            # job, so the axis shows Stopping (HasJob + HasBeenStopped) until it stands
            a.error[i] = 0
            a.locked[i] = False
            a.lag_timer[i] = 0.0
            ramp = q.active
            if ramp is None or not ramp.numbered:
                job = STOP.from_ramp(ramp, next_cmdno(q.newest))
                q.newest = job.cmd_no
                q.active = q.shown = job
                a.stopped[i] = True
                return {"cmd_no": job.cmd_no}
        return {}  # a moving axis without an error: nothing to reset
    a.error[i] = 0
    a.locked[i] = False
    a.stopped[i] = False
    a.lag_timer[i] = 0.0
    # TwinCAT: after a reset the set position is the actual position
    a.set_pos[i] = core.act_pos[i]
    a.target_pos[i] = a.set_pos[i]
    core.corrections.restart_history(i)
    return {}


@core_command("SetOverride")
def _cmd_set_override(core: NcCore, i: int, req: dict[str, Any]) -> dict[str, Any]:
    ov = req["Override"]
    if not 0.0 <= ov <= 100.0:
        raise NcError(ErrorCodes.MC_PARAMETER_NOT_CORRECT, f"Override {ov} % outside 0..100")
    core.plctonc["Override"][i] = round(ov * 10000.0)
    core.inputs_changed()
    return {}


@core_command("ReadParameter")
def _cmd_read_parameter(core: NcCore, i: int, req: dict[str, Any]) -> dict[str, Any]:
    return {"value": core.read_parameter(i, req["ParameterNumber"])}


@core_command("WriteParameter")
def _cmd_write_parameter(core: NcCore, i: int, req: dict[str, Any]) -> dict[str, Any]:
    core.write_parameter(i, req["ParameterNumber"], req["Value"])
    return {}


@core_command("SetActualPosition")
def _cmd_set_actual_position(core: NcCore, i: int, req: dict[str, Any]) -> dict[str, Any]:
    """MC_SetActualPosition: at standstill only (0x4B01 while moving: that is
    MC_SetActualPositionOnTheFly's job); actual and set position take the new value."""
    a = core.axes
    if a.traj_on[i] or a.has_job[i] or core.superposition.on[i]:
        raise NcError(ErrorCodes.MC_AXIS_CANNOT_BE_STARTED, "the axis is moving: use MC_SetActualPositionOnTheFly")
    pos = req["Position"]
    if not abs(pos) < MAX_POSITION:
        raise NcError(ErrorCodes.MC_PARAMETER_NOT_CORRECT, f"Position {pos} outside +/-{MAX_POSITION:g}")
    core.shift_position(i, pos - float(core.act_pos[i]))
    return {}


@core_command("SetActualPositionOnTheFly")
def _cmd_set_actual_position_otf(core: NcCore, i: int, req: dict[str, Any]) -> dict[str, Any]:
    """MC_SetActualPositionOnTheFly: shift by ActualPosition - PreviousPosition, also while moving;
    the running move covers the same distance (its target shifts with it)."""
    diff = req["ActualPosition"] - req["PreviousPosition"]
    if not abs(diff) < MAX_POSITION:
        raise NcError(ErrorCodes.MC_PARAMETER_NOT_CORRECT, f"shift {diff} outside +/-{MAX_POSITION:g}")
    core.shift_position(i, diff)
    job = core.queues[i].running_numbered
    if job is not None:
        job.amended = True
        return {"cmd_no": job.cmd_no}
    return {}


@core_command("SetReferenceFlag")
def _cmd_set_reference_flag(core: NcCore, i: int, req: dict[str, Any]) -> dict[str, Any]:
    core.axes.homed[i] = bool(req["ReferenceFlag"])
    core.state_dirty = True
    return {}


@core_command("ReadParameterSet")
def _cmd_read_parameter_set(core: NcCore, i: int, req: dict[str, Any]) -> dict[str, Any]:
    """MC_ReadParameterSet: the whole ST_AxisParameterSet as a map of its members."""
    return {"value": core.parameter_set(i)}


@core_command("ReadAxisComponents")
def _cmd_read_axis_components(core: NcCore, i: int, req: dict[str, Any]) -> dict[str, Any]:
    """MC_ReadAxisComponents: ST_AxisComponents (one encoder, controller and drive per axis, with its id)."""
    ident = int(core.axis_ids[i])
    ids = [ident] + [0] * 8
    return {"value": {"EncoderIDs": ids, "ControllerIDs": list(ids), "DriveIDs": list(ids)}}


@core_command("SetExternalError")
def _cmd_set_external_error(core: NcCore, i: int, req: dict[str, Any]) -> dict[str, Any]:
    """Set an external axis error (TwinCAT ADS axis function 0x19; MC_PowerStepper): the axis stops with
    its deceleration as for any axis error (the first error sticks); Unreference also clears Homed.

    Raises:
        NcError: 0x4B06 ErrorCode not in 1..0x7FFFFFFF.
    """
    code = int(req["ErrorCode"])
    if code <= 0:
        raise NcError(ErrorCodes.MC_PARAMETER_NOT_CORRECT, f"ErrorCode must be > 0, got {code}")
    _log.warning("axis %d: external error 0x%X%s set by %s", int(core.axis_ids[i]), code,
                 " (axis unreferenced)" if req.get("Unreference") else "", req.get("client") or "an anonymous client")
    core.fault(i, code)
    if req.get("Unreference"):
        core.axes.homed[i] = False
    core.state_dirty = True
    return {}


@core_command("SimStall")
def _cmd_sim_stall(core: NcCore, i: int, req: dict[str, Any]) -> dict[str, Any]:
    """SimStall: a simulated stepper (SimStepper) stalls / stops stalling (see SimDrive.set_stall).

    Raises:
        NcError: 0x4251 not a simulated stepper axis.
    """
    try:
        core.drive.set_stall(i, bool(req["Stall"]))
    except (NotImplementedError, AttributeError) as exc:
        raise NcError(ErrorCodes.NC_FUNCTION_NOT_SUPPORTED, str(exc) or "the drive cannot stall on demand") from None
    return {}


@core_command("SimTerminalError")
def _cmd_sim_terminal_error(core: NcCore, i: int, req: dict[str, Any]) -> dict[str, Any]:
    """SimTerminalError: the error bits of a simulated stepper terminal's status word (KL_Status2).

    Raises:
        NcError: 0x4251 not a simulated stepper axis; 0x4B06 StatusWord outside 0..65535.
    """
    word = int(req["StatusWord"])
    if not 0 <= word <= 0xFFFF:
        raise NcError(ErrorCodes.MC_PARAMETER_NOT_CORRECT, f"StatusWord must be in 0..65535, got {word}")
    try:
        core.drive.set_terminal_error(i, word)
    except (NotImplementedError, AttributeError) as exc:
        raise NcError(ErrorCodes.NC_FUNCTION_NOT_SUPPORTED, str(exc) or "the drive has no simulated terminal") from None
    return {}
