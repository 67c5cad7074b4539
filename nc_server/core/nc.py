"""NcCore: the pure, cycle-stepped NC (no zenoh, no threads, no clock reads).

A test (or the server) drives it cycle by cycle::

    core = NcCore([AxisConfig(1, "X")], cycle_time=0.001)
    core.set_plctonc(0, enabled_record)
    reply = core.execute(parse_request(...), axis_id=1)
    core.step()
    core.nctoplc[0]["SetPos"]

The motion engine: every motion command becomes a job (:mod:`.jobs`) in the axis's queue; the
active job's plan (:mod:`.planning`) is evaluated by the set-point stages (:mod:`.stages`).

Cycle order (``NcCore.STAGES``, :mod:`.stages`): inputs (PLCTONC: enables, override) -> the
profile stage -> plan ends (jobs end, buffered jobs take over) -> the external set-point
generator -> superposition and coupling, level by level (masters before slaves) -> limits of
slaves and superpositions -> job watches and limits (soft-limit approach, switching positions,
homing, feed enables) -> drive -> touch probe latches -> monitoring -> NCTOPLC and job records.

Positions: the NC's positions (set, actual, targets) are what the PLC sees. ``axes.offset`` is the
difference NC - drive position at the drive boundary (MC_SetActualPosition), and ``axes.origin``
the shift of a running plan since it was planned (MC_SetActualPositionOnTheFly): no absolute value
is rewritten when the position is set.
"""
from __future__ import annotations

import logging
import struct
from typing import Any, Mapping, Sequence

import numpy as np

from nc_schema import (
    NCJOBS_DTYPE, NCTOPLC_DTYPE, PLCTONC_DTYPE, ST_AXIS_PARAMETER_SET, CmdState, ControlDWord, E_NcDriveType,
    E_NcEncoderType, ErrorCodes, NcError, OpModeDWord, StateDWord, error_name, make_reply, next_cmdno,
)

from ..drives.base import DriveABC
from ..drives.sim import SimDrive
from .axes import AxisTable
from .jobs import KINDS, Job, JobQueue
from .jobs.base import ABORTING, BLENDING, ENDED_KEPT
from .jobs.stop import FAULT_RAMP, HALT_RAMP, STOP
from .monitoring import monitor
from .params import AxisConfig, AxisParams, ConfigError, param_entry
from .planning import Dynamics, Plan, PlanningError, StartState, plan_velocity
from .profile import evaluate, peak_velocity, stopping_distance, velocity_extrema
from .jobs.external import ext_disable
from .jobs.gearing import gear_out
from .stages import CouplingStage, ExternalStage, ProbeStage, ProfileStage, SuperpositionStage
from .stages.probe import cmd_abort_trigger, cmd_sim_probe_signal, cmd_touch_probe
from .stages.superposition import cmd_abort_superposition, cmd_move_superimposed

_log = logging.getLogger(__name__)
#: Cycles of set-points evaluated ahead (NcCore(lookahead=...)); the refills are staggered over the
#: cycles (stages.ProfileStage), events refresh only the changed axes. None: 16.
LOOKAHEAD: int | None = None
#: largest |position| the NC accepts as a target (ruckig's numeric range)
MAX_POSITION = 1e9
_EPS_V = 1e-9
_EN = int(ControlDWord.Enable)
_FP = int(ControlDWord.FeedEnablePlus)
_FM = int(ControlDWord.FeedEnableMinus)
_CAM = int(ControlDWord.HomingSensor)
_OVERRIDE_MAX = 1_000_000


_NOT_MOVING = np.uint32(int(StateDWord.NotMoving))
_LOOP = np.uint32(int(StateDWord.ControlLoopClosed))
_OPERATIONAL = np.uint32(int(StateDWord.Operational))

#: the queue part of an NCJOBS_AXIS_REF record: AxisId, ActiveCmdNo, ActiveState, BufferedCmdNo, BufferedMode,
#: NewestCmdNo, Flags, then ENDED_KEPT x (CmdNo, CmdState, ErrorId)
_NCJOBS_RECORD = struct.Struct("<IHHHHHH" + "HHI" * ENDED_KEPT)
#: its slots part: MasterId, SyncFlags, GearRatio, SuperCmdNo, SuperState, SuperErrorId, SuperDistance,
#: SuperVelocityDiff, SuperLength, ProbeCmdNo, ProbeState, ProbeCounter, RecordedPosition, RecordedTimeNs,
#: ProbeErrorId, DriveStatus
_NCJOBS_SLOTS = struct.Struct("<IIdHHIdddHHIdQII")
_NCJOBS_SIZE = NCJOBS_DTYPE.itemsize
assert _NCJOBS_RECORD.size + _NCJOBS_SLOTS.size == _NCJOBS_SIZE and NCJOBS_DTYPE.names == (
    "AxisId", "ActiveCmdNo", "ActiveState", "BufferedCmdNo", "BufferedMode", "NewestCmdNo", "Flags", "Ended",
    "MasterId", "SyncFlags", "GearRatio", "SuperCmdNo", "SuperState", "SuperErrorId", "SuperDistance",
    "SuperVelocityDiff", "SuperLength", "ProbeCmdNo", "ProbeState", "ProbeCounter", "RecordedPosition",
    "RecordedTimeNs", "ProbeErrorId", "DriveStatus")
_SYNC_EXT_ENABLED, _SYNC_EXT_FOLLOWING, _SYNC_DYN, _SYNC_SYNCHRON = 1, 2, 4, 8
_PROTECTED = np.uint32(int(StateDWord.Protected))
_PTP = np.uint32(int(StateDWord.PTPmode))
_COMPENSATING = np.uint32(int(StateDWord.Compensating))
_EXT_ENABLED = np.uint32(int(StateDWord.ExtSetPointGenEnabled))
_LATCH_VALID = np.uint32(int(StateDWord.ExternalLatchValid))
_NO_ENDED = [0, 0, 0] * ENDED_KEPT

#: commands that change the running job instead of starting one
AMENDMENTS = frozenset({"NewPos", "NewPosAndVelo", "ChangeDynParam"})


class NcCore:
    """All axes of one NC, stepped one fixed cycle at a time.

    Args:
        axes: the configured axes (ids must be unique).
        cycle_time: NC cycle time [s] (> 0).
        drive: the drives of all axes; default: a :class:`SimDrive`.

    Raises:
        ConfigError: duplicate axis ids, no axes, bad cycle time.
    """

    #: the stages of one cycle, in order (see the module docstring)
    STAGES = ("inputs", "profile", "plan ends", "external", "superposition + coupling", "slave limits", "jobs",
              "drive", "probe", "monitoring", "output")

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
        self.drive = drive if drive is not None else SimDrive(self.params, self.cycle_time)
        self.queues = [JobQueue() for _ in ids]
        self.cycle = 0
        self.nc_time_ns = 0
        n = len(ids)
        self.plctonc = np.zeros(n, dtype=PLCTONC_DTYPE)
        self.plctonc[:] = self.default_plctonc()
        self.plctonc_arrived = np.zeros(n, dtype=bool)  # a PLCTONC was handed in since the last cycle
        self.ncjobs = np.zeros(n, dtype=NCJOBS_DTYPE)
        self.ncjobs["AxisId"] = self.axis_ids
        self._jobs_bytes = memoryview(self.ncjobs.view(np.uint8))  # _sync writes packed records into it
        self._drive_status = self.ncjobs["DriveStatus"]  # (a view: a simulated stepper terminal's status)
        self._axis_id_list = [int(x) for x in ids]
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
        self._watch_rows: list[tuple[Any, np.ndarray]] = []
        self._opmode_sim = np.uint32(int(OpModeDWord.OpModeSimulationAxis) if self.drive.simulated else 0)
        self.nctoplc = np.zeros(n, dtype=NCTOPLC_DTYPE)
        self.nctoplc["AxisId"] = self.axis_ids
        self.nctoplc["OpModeDWord"] = self.axes.opmode
        # views of the NCTOPLC fields the cycle writes (a field lookup per write costs more than the copy)
        self._out = {name: self.nctoplc[name] for name in NCTOPLC_DTYPE.names}
        f8 = NCTOPLC_DTYPE.fields
        assert f8["SetVelo"][1] == f8["SetPos"][1] + 8 and f8["SetAcc"][1] == f8["SetPos"][1] + 16
        self._out_sp = np.ndarray((n, 3), np.float64, self.nctoplc, f8["SetPos"][1], (NCTOPLC_DTYPE.itemsize, 8))
        self._dt_ns = int(round(self.cycle_time * 1e9))
        self.act_pos = self.drive.act_pos.copy()
        self.prev_act_pos = self.act_pos.copy()
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
        r["Override"] = _OVERRIDE_MAX
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
        self.plctonc_arrived[index] = True  # (a PLC frame: the external generator's feed, also unchanged)
        if self.plctonc[index].tobytes() != np.asarray(record, dtype=PLCTONC_DTYPE).tobytes():
            self.plctonc[index] = record
            self._in_dirty = True

    def set_plctonc_many(self, index: np.ndarray, records: np.ndarray) -> None:
        """Apply PLCTONC records to several axis rows at once (vectorized :meth:`set_plctonc`)."""
        new = np.ascontiguousarray(records, dtype=PLCTONC_DTYPE).view(np.uint8).reshape(-1, PLCTONC_DTYPE.itemsize)
        self.plctonc_arrived[index] = True
        # through byte views: indexing a structured array of 22 fields copies field by field (~10x slower)
        rows = self.plctonc.view(np.uint8).reshape(len(self.plctonc), PLCTONC_DTYPE.itemsize)
        if not np.array_equal(rows[index], new):
            rows[index] = new
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
                raise NcError(ErrorCodes.ADSERR_DEVICE_SRVNOTSUPP, f"{cmd} needs an axis key (nc/<nc>/axis/<id>/cmd/<class>/<client>)")
            i = self.index(axis_id)
            out = self._dispatch(i, request)
        except NcError as err:
            return make_reply(rid, cmd, err.code, str(err), cycle)
        except Exception as exc:  # a bug must cost one command, never the NC cycle
            _log.exception("command %r failed", cmd)
            return make_reply(rid, cmd, ErrorCodes.NC_INTERNAL, f"internal error: {exc.__class__.__name__}: {exc}", cycle)
        self._flush_slots()
        return make_reply(rid, cmd, 0, "", cycle, cmd_no=out.get("cmd_no"), value=out.get("value"))

    def fault(self, i: int, code: int) -> None:
        """Raise axis error ``code`` now and stop the axis with its deceleration.

        The first error sticks (like TwinCAT); the running job ends ERROR, a waiting one ABORTED;
        the drive stays enabled until the stop ramp ends, whatever the PLCTONC says.
        """
        a, q = self.axes, self.queues[i]
        if a.error[i]:
            return
        self._state_dirty = True
        a.error[i] = code
        self.superposition.abort(self, i)  # the ramp brakes the total motion
        running = q.active
        if q.waiting is not None:
            q.end(q.waiting, CmdState.ABORTED)
        if running is not None:
            q.end(running, CmdState.ERROR, code)
        moving = bool(a.traj_on[i]) or abs(a.set_velo[i]) > 0
        if moving and a.enabled[i]:
            try:
                self._start_ramp(i, FAULT_RAMP, running)
            except Exception:  # never leave an axis in error moving
                _log.exception("axis %d: fault ramp failed; the set-point stops at once", int(a.ids[i]))
                self.clear_profile(i)
        else:
            self.clear_profile(i)
        self._sync(i)

    @property
    def moving(self) -> np.ndarray:
        """Axes with a job or a non-zero set velocity."""
        return self.axes.has_job | (np.abs(self.axes.set_velo) > _EPS_V) | self.axes.traj_on

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
                disabled while the controller is enabled, 0x4221/0x422F/0x4222 a value that would
                break the running motion (see :meth:`_check_running`).
        """
        e = param_entry(number)
        if e.source == "status":
            raise NcError(ErrorCodes.ADSERR_DEVICE_INVALIDACCESS, f"parameter {number} ({e.name}) is read-only")
        if e.is_bool and not isinstance(value, bool):
            if value not in (0.0, 1.0):
                raise NcError(ErrorCodes.ADSERR_DEVICE_INVALIDPARM, f"{e.name} is boolean: 0/1 or true/false, got {value}")
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
        except ConfigError as exc:
            raise NcError(ErrorCodes.ADSERR_DEVICE_INVALIDPARM, f"{exc.key}: {exc.message}") from None
        if self._moves(i):
            self._check_running(i, new)
        self.params[i] = new
        self.configs[i].params = new
        self.axes.load_params(i, new)
        self.drive.configure(i, new)
        self.coupling.invalidate()  # (its copies of the limits)
        self._state_dirty = True

    def _moves(self, i: int) -> bool:
        """Whether axis row ``i`` moves or is driven: a job, a plan, a set velocity, a coupling, a
        superposition or the external set-point generator."""
        a = self.axes
        return bool(a.has_job[i] or a.traj_on[i] or abs(a.set_velo[i]) > _EPS_V or self.queues[i].active is not None
                    or self.coupling.master[i] >= 0 or self.superposition.on[i] or self.external.on[i])

    def _check_running(self, i: int, new: AxisParams) -> None:
        """Refuse parameters that the motion running now would violate (the write would break it):

        * AxisVeloMax below the running command's velocity or the set velocity: 0x4221;
        * AxisAcc and AxisDec both below the set acceleration (coupled slaves, superpositions and the
          external generator are checked against them every cycle): 0x422F;
        * a software limit (enabled) that the running command's target or the set position lies beyond:
          0x4222.

        Raises:
            NcError: as above.
        """
        a, p = self.axes, self.params[i]
        job = self.queues[i].active
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

    def parameter_set(self, i: int) -> dict[str, Any]:
        """ST_AxisParameterSet of axis row ``i`` as a map of its members (MC_ReadParameterSet; the table's
        ``structs.ST_AxisParameterSet`` says where each value comes from)."""
        c, p = self.configs[i], self.params[i]
        stepper = bool(p.SimStepper) and self.drive.simulated
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
        """The dynamics of a command: its Acceleration/Deceleration/Jerk, 0 = the axis defaults.

        Raises:
            NcError: 0x422F/0x4230/0x422E for negative or unusable values.
        """
        a = self.axes
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

    def check_velocity(self, i: int, v: float) -> None:
        """Raises NcError 0x4221 unless 0 < v <= AxisVeloMax."""
        if not v >= 1e-9 or v > self.axes.vmax[i] * (1 + 1e-12):
            raise NcError(ErrorCodes.NC_VELOCITY_NOT_ALLOWED,
                          f"Velocity {v} must be > 0 and <= AxisVeloMax {self.axes.vmax[i]}")

    def check_startable(self, i: int) -> None:
        """The axis accepts motion commands: no error, no MC_Stop lock, enabled, drive ready."""
        a = self.axes
        if a.error[i]:
            raise NcError(ErrorCodes.MC_AXIS_CANNOT_BE_STARTED,
                          f"axis {int(a.ids[i])} is in ErrorStop ({error_name(int(a.error[i]))} 0x{int(a.error[i]):04X}); MC_Reset first")
        if a.locked[i]:
            raise NcError(ErrorCodes.NC_AXIS_LOCKED_BY_STOP, "MC_Stop is active; release it (Execute FALSE) or MC_Reset")
        if not int(self.plctonc["ControlDWord"][i]) & _EN:
            raise NcError(ErrorCodes.NC_NO_ENABLE, "controller enable is off (MC_Power)")
        if not self.drive.ready[i]:
            raise NcError(ErrorCodes.NC_DRIVE_NOT_READY_AT_START, "drive not ready")

    def check_feed(self, i: int, sense: float) -> None:
        """Raises NcError 0x4223 if the feed enable of direction ``sense`` is off."""
        c = int(self.plctonc["ControlDWord"][i])
        if sense > 0 and not c & _FP:
            raise NcError(ErrorCodes.NC_NO_ENABLE, "feed enable plus is off (MC_Power.Enable_Positive)")
        if sense < 0 and not c & _FM:
            raise NcError(ErrorCodes.NC_NO_ENABLE, "feed enable minus is off (MC_Power.Enable_Negative)")

    def check_target(self, i: int, start: float, target: float, plan: Plan | None = None) -> None:
        """Software limits for a move from ``start`` to ``target`` (and the plan's extrema).

        Raises:
            NcError: 0x4222 target beyond a limit (or the path would overshoot it), 0x4460/0x4461
                when the axis already stands beyond the limit and the move goes further.
        """
        a = self.axes
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

    def check_overshoot(self, i: int, plan: Plan, v_new: float) -> None:
        """Refuse (0x423A) a plan that would exceed both the new and the running motion's velocity,
        or AxisVeloMax: it happens when weaker dynamics meet an accelerating axis."""
        a, job = self.axes, self.queues[i].active
        # (a stop's "velocity" is AxisVeloMax, not a velocity it runs at)
        moving_job = job is not None and job.dyn is not None and a.traj_on[i] and not job.kind.braking
        running = job.dyn.velocity * a.override[i] if moving_job else 0.0  # type: ignore[union-attr]
        cap = min(max(v_new, running, abs(a.set_velo[i])), a.vmax[i])
        peak = peak_velocity(plan.seg)
        if peak > cap * (1 + 1e-6) + 1e-9:
            raise NcError(ErrorCodes.NC_VELOCITY_OVERFLOW,
                          f"the new dynamics would overshoot to {peak:.6g} u/s (limit {cap:.6g}); use a higher Jerk")

    def check_reversal(self, plan: Plan, start: StartState, sense: float, target: float | None = None) -> None:
        """Refuse (0x4289) a plan that turns back on its way although the axis already heads that way
        (``sense``): it happens when weaker dynamics (a lower jerk) meet a braking axis, whose
        deceleration can then not be reduced in time. A plan that passes its ``target`` first and
        comes back (a target within the braking distance) is not such a turn."""
        if start.v * sense <= 0:
            return
        lo, hi = velocity_extrema(plan.seg)
        if not (lo < -1e-9 if sense > 0 else hi > 1e-9):
            return
        if target is not None and ((plan.p_max - target) if sense > 0 else (target - plan.p_min)) > 1e-9:
            return
        raise NcError(ErrorCodes.NC_ILLEGAL_REVERSAL,
                      "with these dynamics the braking axis would turn back on its way; use a higher Jerk")

    def plan(self, fn: Any, *args: Any) -> Plan:
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
        """The stop ``plan`` ends before the running job's target and an enabled soft limit
        (TcMC 3.15: weaker stop dynamics are not used if the target would be exceeded)."""
        a = self.axes
        end = plan.end.p
        v0 = float(a.set_velo[i])
        if running is not None and running.target is not None and not running.continuous and v0:
            if (end - running.target) * v0 > 1e-9:
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
        return (self.plctonc["ControlDWord"][rows] & _CAM) != 0

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
        self._state_dirty = True

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
        self._state_dirty = True

    def clear_profile(self, i: int, keep_velocity: bool = False) -> None:
        """Stop the set-point generator (the axis holds its set position; ``keep_velocity``: a
        set-point stage takes the row over from its state)."""
        a = self.axes
        a.changed.append(i)
        if a.origin[i]:
            a.origin[i] = 0.0  # (set_pos already includes the origin)
        a.traj_on[i] = False
        if not keep_velocity:
            a.set_velo[i] = 0.0
            a.set_acc[i] = 0.0
            a.set_jerk[i] = 0.0
        self._state_dirty = True

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
        self._state_dirty = True

    def begin(self, i: int, job: Job, plan: Plan | None, abort_waiting: bool = True) -> None:
        """Make ``job`` the running job with ``plan``: the running one ends ABORTED (and, unless
        ``abort_waiting`` is False, the waiting one too). Numbers the job if it has no number.
        ``plan`` None: a job of a set-point stage (``JobKind.source``), which takes the row."""
        a, q = self.axes, self.queues[i]
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
            self.superposition.abort(self, i)  # (planned from the total state)
        if plan is None:
            self.clear_profile(i, keep_velocity=True)
            a.target_pos[i] = job.target if job.target is not None else a.set_pos[i]
        else:
            self.set_plan(i, plan)
            a.target_pos[i] = job.target if job.target is not None else plan.end.p
        a.since_end[i] = -1.0
        a.window_timer[i] = 0.0
        a.in_target[i] = a.in_area[i] = False
        self._sync(i)
        job.kind.on_begin(self, i, job)
        self._sync(i)

    def _start_ramp(self, i: int, kind: Any, running: Job | None) -> None:
        """An internal stop ramp (no CmdNo) after an error or a job that could not take over."""
        a = self.axes
        if kind is FAULT_RAMP or running is None or running.dyn is None:
            dec, jerk = float(a.dec[i]), float(a.jerk[i])
        else:
            dec, jerk = running.dyn.deceleration, running.dyn.jerk
        # the NC's own ramp is never refused: values the planner cannot take are clamped into range
        d = self.stop_dynamics(i, min(max(dec, 1e-6), 1e10), min(max(jerk, 1e-6), 1e12), running)
        start = self.start_state(i, total=True)
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
            self.clear_profile(i)  # cannot plan: stop the set-point at once (never keep moving)
            return
        self.begin(i, Job(kind, {}, dyn=d), plan, abort_waiting=False)

    def _sync(self, i: int) -> None:
        """Mirror row ``i``'s queue into the columns and its job record (on events only); a stage
        that drives the row without its job running any more lets it go."""
        a, q = self.axes, self.queues[i]
        j = q.active
        source = j.kind.source if j is not None else None
        if source != "coupling" and self.coupling.is_slave(i):
            self.coupling.release(i)
        if source != "external" and self.external.on[i]:
            self.external.release(i)
        numbered = j is not None and j.numbered
        held = j is not None and j.held
        row_bits = 1 if held else (2 if numbered else 0)
        if a.sp_row[i] != row_bits:
            a.sp_row[i] = row_bits
            if a.traj_on[i]:
                a.changed.append(i)  # the buffered set-point bits depend on them (the profile stage)
        homing = numbered and j.kind.homing  # type: ignore[union-attr]
        amended = numbered and j.amended  # type: ignore[union-attr]
        w = q.waiting
        a.has_job[i] = numbered
        a.continuous[i] = numbered and j.continuous  # type: ignore[union-attr]
        a.homing[i] = homing
        a.amended[i] = amended
        a.buffered[i] = w is not None
        a.hold_enable[i] = j is not None and j.kind.holds_enable
        a.driving[i] = numbered and j.kind.feed_checked and not held  # type: ignore[union-attr]
        a.held[i] = held
        a.watch_kind[i] = KINDS_INDEX.get(j.kind.name, -1) if (j is not None and j.kind.wants_watch(j)) else -1
        a.homing_state[i] = j.phase if homing else 0  # type: ignore[union-attr]
        shown = q.shown
        cmd_no, cmd_state = (shown.cmd_no, shown.state) if shown is not None else (0, 0)
        a.cmd_no[i] = cmd_no
        a.cmd_state[i] = cmd_state
        # the NCJOBS record in one write of its packed bytes (field by field through np.void cost ~6 us)
        ended = [x for e in q.ended for x in (e.cmd_no, e.state, e.error_id)]
        ended += _NO_ENDED[len(ended):]
        o = i * _NCJOBS_SIZE
        self._jobs_bytes[o:o + _NCJOBS_RECORD.size] = _NCJOBS_RECORD.pack(
            self._axis_id_list[i], cmd_no, cmd_state, w.cmd_no if w is not None else 0,
            w.buffer_mode if w is not None else 0, q.newest, 1 if amended else 0, *ended)
        self._sync_slots(i)

    def _sync_slots(self, i: int) -> None:
        """The coupling, superposition and touch probe part of row ``i``'s job record (on events)."""
        c, sp, pr, ex = self.coupling, self.superposition, self.probe, self.external
        m = int(c.master[i])
        flags = ((_SYNC_EXT_ENABLED if ex.on[i] else 0) | (_SYNC_EXT_FOLLOWING if ex.following[i] else 0)
                 | (_SYNC_DYN if c.dyn[i] else 0) | (_SYNC_SYNCHRON if m >= 0 and c.state[i] == 13 else 0))
        o = i * _NCJOBS_SIZE + _NCJOBS_RECORD.size
        self._jobs_bytes[o:o + _NCJOBS_SLOTS.size] = _NCJOBS_SLOTS.pack(
            self._axis_id_list[m] if m >= 0 else 0, flags, float(c.ratio[i]) if m >= 0 else 0.0,
            int(sp.cmd_no[i]), int(sp.state[i]), int(sp.error[i]), *(float(x) for x in sp.actual[:, i]),
            int(pr.cmd_no[i]), int(pr.state[i]), int(pr.counter[i]), float(pr.recorded[i]), int(pr.recorded_ns[i]), int(pr.error[i]),
            int(self._drive_status[i]))
        self._state_dirty = True

    def finish(self, i: int, job: Job, state: CmdState = CmdState.DONE, error_id: int = 0) -> None:
        """End the running ``job``; a waiting job takes over (or the generator stops)."""
        q = self.queues[i]
        q.end(job, state, error_id)
        if q.waiting is not None:
            self._advance(i)
        else:
            self.clear_profile(i)
        self._sync(i)

    def _advance(self, i: int) -> None:
        """The waiting job takes over from the current set-point state (its exact cycle)."""
        q = self.queues[i]
        nxt = q.waiting
        assert nxt is not None
        prev = q.active
        if prev is not None:
            q.end(prev, CmdState.DONE)
        try:
            plan = nxt.kind.activate(self, i, nxt, self.start_state(i, total=nxt.kind.braking))
        except NcError as err:
            # it can no longer start: it ends ERROR with that check's code, the axis stops
            q.end(nxt, CmdState.ERROR, err.code)
            _log.info("axis %d: buffered command %d could not start: %s", int(self.axis_ids[i]), nxt.cmd_no, err)
            if abs(self.axes.set_velo[i]) > _EPS_V:
                self._start_ramp(i, HALT_RAMP, prev)
            else:
                self.clear_profile(i)
            self._sync(i)
            return
        self.begin(i, nxt, plan, abort_waiting=False)

    def blend(self, i: int) -> None:
        """Re-plan the running job so that it passes its target with the blending velocity of the
        waiting job's BufferMode (the rules: ``JobKind.blend_velocity``). A running job without a
        target (velocity, stop): no blending, the waiting job starts at the end as with Buffered.
        The plan lowers the velocity where the job could not reach it without passing its target."""
        q = self.queues[i]
        prev, nxt = q.active, q.waiting
        if prev is None or nxt is None or nxt.buffer_mode not in BLENDING:
            return
        bp = prev.kind.blend_point(prev)
        if bp is None:
            return
        _, sense, _ = bp
        v = prev.kind.blend_velocity(self, i, prev, nxt)
        ov = float(self.axes.override[i])
        prev.end_velocity = sense * v
        try:
            plan = prev.kind.replan(self, i, prev, self.start_state(i), ov)
        except NcError:
            # ruckig could not blend from this state: the running plan stays (it ends at rest, the
            # waiting job starts there, as Buffered) -- "blending as well as possible"
            prev.end_velocity = 0.0
            plan = None
        if plan is not None:
            self.set_plan(i, plan)
        self._sync(i)

    # -- step ---------------------------------------------------------------------------------
    def step(self, nc_time_ns: int | None = None) -> None:
        """Run one NC cycle of ``cycle_time`` seconds.

        Args:
            nc_time_ns: the NC time of this cycle [ns]; default: previous + cycle_time.
        """
        a = self.axes
        self.cycle += 1
        self.nc_time_ns = int(nc_time_ns) if nc_time_ns is not None else self.nc_time_ns + self._dt_ns
        # inputs
        if self._in_dirty:
            self._apply_inputs()
        if self._state_dirty:
            self._derive_state()
        if self._off_rows.size:  # disabled axes: the set position follows the actual position
            a.set_pos[self._off_rows] = self.act_pos[self._off_rows]
        sup, cpl, ext = self.superposition, self.coupling, self.external
        if sup.active:
            sup.unapply(self)  # (the stages produce the basic motion; the offsets are added after it)
        # set-point stages, then the ends of plans (jobs end, buffered jobs take over)
        if self.on_rows.size:
            ended = self.profile.run(self)
            if ended.size:
                self._plan_ends(ended)
        if ext.active or sup.active or cpl.active:
            try:
                self._stage_sync()
            except Exception:  # a bug must stop the axes of these stages, never the NC cycle
                _log.exception("set-point stages failed")
                staged = (cpl.master >= 0) | ext.on | sup.on
                for i in staged.nonzero()[0].tolist():
                    self.fault(int(i), ErrorCodes.NC_INTERNAL)
        # job watches and limits
        if self._watch_rows:
            for kind, rows in self._watch_rows:
                if self._state_dirty:  # jobs ended or changed this cycle: only rows still watched
                    rows = self._still_watched(kind, rows)
                    if not rows.size:
                        continue
                try:
                    kind.watch(self, rows)
                except Exception:  # a bug must stop its axes, never the NC cycle
                    _log.exception("job watch of %s failed", kind.name)
                    for i in rows.tolist():
                        self.fault(int(i), ErrorCodes.NC_INTERNAL)
        feed = self._feed_rows  # moving axes with a feed enable missing in some direction
        if feed.size:
            plus, minus = self._feed_plus[feed], self._feed_minus[feed]
            v = a.set_velo[feed]
            for i in feed[~plus & (v > _EPS_V)]:
                self.fault(int(i), ErrorCodes.NC_AXIS_FEED_ENABLE_PLUS)
            for i in feed[~minus & (v < -_EPS_V)]:
                self.fault(int(i), ErrorCodes.NC_AXIS_FEED_ENABLE_MINUS)
        # drive
        self.prev_act_pos, prev = self.act_pos, self.act_pos
        if self._has_offset:
            self.drive.step(a.enabled, a.set_pos - a.offset, a.set_velo, a.set_acc)
            self.act_pos = self.drive.act_pos + a.offset
        else:
            self.drive.step(a.enabled, a.set_pos, a.set_velo, a.set_acc)
            self.act_pos = self.drive.act_pos
        del prev
        ds = self.drive.terminal_status()
        if ds is not None:
            self._drive_status[:] = ds
        if self.probe.active:
            self.probe.run(self)
            self._flush_slots()
        if self._state_dirty:  # a job ended this cycle: monitor it as standing already
            self._derive_state()
        # monitoring: new faults stop their axes from the next cycle
        watch = self._watch
        if self.external.active:  # an enabled external generator: its target window counts when it stands
            r = self.external.rows
            st = watch[1].copy()
            st[r] = (np.abs(a.set_velo[r]) <= _EPS_V) & a.enabled[r]
            watch = (watch[0], st, watch[2], True)
        for i, code in monitor(a, self.act_pos, self.cycle_time, watch):
            self.fault(i, code)
        if self._state_dirty:
            self._derive_state()
        self._fill_nctoplc()

    def _release_slaves(self, m: int) -> None:
        """Master row ``m`` lost its enable: its set position now follows its actual position, which
        a slave cannot follow without a jump. Its slaves are decoupled (the coupling jobs end ABORTED)
        and brake on their own ramps (their own slaves follow them)."""
        for s in (self.coupling.master == m).nonzero()[0].tolist():
            q = self.queues[s]
            job = q.active
            if job is None or job.kind.source != "coupling":
                continue
            q.end(job, CmdState.ABORTED)
            self.superposition.abort(self, s)
            self._start_ramp(s, HALT_RAMP, None)
            self._sync(s)

    def _stage_soft_limits(self) -> list[tuple[int, int]]:
        """Slaves and superpositions (not on a positioning move: checked when commanded) towards an
        enabled software limit (external set-points: ExternalStage.run judges their feeds): an axis
        error (0x4463/0x4462) in the first cycle in which the stop the fault ramp makes from this
        cycle's state (AxisDec, AxisJerk) would end beyond the limit (a plan's own jobs brake for the
        limit themselves). A bound of the stop distance picks the candidates, an exact plan decides,
        so a motion that ends exactly at the limit is no fault; the price of deciding on this cycle's
        state is that a real violation is noticed up to one cycle late (the stop then ends beyond the
        limit by what the stop's end moved in that cycle, a fraction of the distance per cycle)."""
        if not self._watch[2]:  # (no software limit enabled on any axis: derived on events)
            return []
        a = self.axes
        sup = self.superposition.on.copy()
        for i in np.flatnonzero(sup).tolist():
            job = self.queues[i].running_numbered
            if job is not None and job.target is not None and not job.continuous:
                sup[i] = False  # (positioning + offset: checked against the limits when commanded)
        rows = np.flatnonzero((self.coupling.master >= 0) | sup)  # (external rows: ExternalStage.run)
        rows = rows[a.en_max[rows] | a.en_min[rows]]
        if not rows.size:
            return []
        p, v, acc = a.set_pos[rows], a.set_velo[rows], a.set_acc[rows]
        bound = p + np.sign(v) * stopping_distance(v, acc, a.dec[rows], a.jerk[rows])
        cand = (a.en_max[rows] & (v > 0) & (bound > a.max_lim[rows])) | (a.en_min[rows] & (v < 0) & (bound < a.min_lim[rows]))
        out: list[tuple[int, int]] = []
        for k in np.flatnonzero(cand).tolist():
            i = int(rows[k])
            d = self.stop_dynamics(i, float(a.dec[i]), float(a.jerk[i]))  # (the fault ramp's)
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

    def _apply_superposition(self, rows: np.ndarray) -> None:
        self.superposition.apply(self, rows)

    def _flush_slots(self) -> None:
        """Job records of the rows whose stage slot changed (a superposition, a touch probe, a
        synchronization locked, an external feed matched)."""
        for st in (self.superposition, self.probe, self.coupling, self.external):
            if st.changed:
                for i in set(st.changed):
                    self._sync(i)  # (NewestCmdNo, HasJob, and the slots)
                st.changed.clear()

    def _stage_sync(self) -> None:
        """The external set-points, the superpositions and the couplings (level by level), then the
        limits of the axes they drive: a violation is an axis error and a controlled stop."""
        sup, cpl, ext = self.superposition, self.coupling, self.external
        over: list[tuple[int, int]] = []
        if ext.active:
            over += ext.run(self)
        if sup.active:
            sup.evaluate()
            sup.apply(self, sup.rows[cpl.master[sup.rows] < 0])  # (the slaves' after their coupling)
        if cpl.active:
            over += cpl.run(self, self._apply_superposition if sup.active else None)
        if sup.active:
            over += sup.limits(self)
            sup.ended(self)
        over += self._stage_soft_limits()
        self._flush_slots()
        for i, code in over:
            if not self.axes.error[i]:
                _log.warning("axis %d: set-point beyond its limits (0x%X): stopped", int(self.axis_ids[i]), int(code))
            self.fault(i, code)

    def _still_watched(self, kind: Any, rows: np.ndarray) -> np.ndarray:
        """The rows of ``rows`` whose running job is still one of ``kind`` that wants its watch."""
        keep = [i for i in rows.tolist()
                if (j := self.queues[i].active) is not None and j.kind is kind and j.kind.wants_watch(j)]
        return np.array(keep, dtype=np.intp)

    def _plan_ends(self, rows: np.ndarray) -> None:
        a = self.axes
        for i in rows.tolist():
            q = self.queues[i]
            job = q.active
            if job is None:
                self.clear_profile(i)
                continue
            try:
                res = job.kind.on_end(self, i, job)
            except NcError as err:  # its next phase cannot be planned: the job ends with that error
                self.fault(i, err.code)
                continue
            except Exception:  # a bug must stop its axis, never the NC cycle
                _log.exception("end of %s failed", job.kind.name)
                self.fault(i, ErrorCodes.NC_INTERNAL)
                continue
            if res == "steady":
                a.traj_dur[i] = np.inf  # keep the end velocity: not an end
                if q.waiting is not None and job.kind.successor_may_start(self, i, job):
                    self._advance(i)
                self._sync(i)
            elif res == "done":
                if q.waiting is None and job.target is not None and job.end_velocity == 0.0 and not job.kind.is_stop:
                    a.set_pos[i] = job.target  # exact end
                    a.target_pos[i] = job.target
                    a.since_end[i] = 0.0
                elif q.waiting is None:
                    a.target_pos[i] = a.set_pos[i]
                self.finish(i, job)
            self._state_dirty = True

    # -- internals ---------------------------------------------------------------------------
    def _apply_inputs(self) -> None:
        """Decode the applied PLCTONC (only when it changed): enables, feed, override."""
        a = self.axes
        self._in_dirty = False
        ctrl = self.plctonc["ControlDWord"]
        self._enable_in = (ctrl & _EN) != 0
        self._feed_plus = (ctrl & _FP) != 0
        self._feed_minus = (ctrl & _FM) != 0
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
        a.override = ov
        for i in changed.tolist():
            job = self.queues[i].active
            if job is not None and job.numbered and job.kind.follows_override and a.traj_on[i]:
                held = ov[i] <= 0
                try:
                    plan = job.kind.replan(self, i, job, self.start_state(i), float(ov[i]))
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
                    self._sync(i)
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
                    a.set_pos[i] = a.target_pos[i] = self.act_pos[i]
                else:
                    q = self.queues[i]
                    if q.waiting is not None:
                        q.end(q.waiting, CmdState.ABORTED)
                    if q.active is not None:
                        q.end(q.active, CmdState.ABORTED)
                    a.locked[i] = False
                    self.superposition.abort(self, i)
                    self.clear_profile(i)
                    self._sync(i)
                    self._release_slaves(i)
            a.enabled = enabled
            self._off_rows = (~enabled).nonzero()[0]
            self._state_dirty = False
        self.on_rows = a.traj_on.nonzero()[0]
        self.all_on = self.on_rows.size == a.n
        if a.changed:  # the axes whose profile changed are evaluated afresh at the next profile run
            self.profile.refresh(self, a.changed)
            a.changed.clear()
        job = a.has_job
        watch = a.watch_kind
        self._watch_rows = []
        watched = watch >= 0
        if np.count_nonzero(watched):  # (np.count_nonzero: far cheaper than ndarray.any here)
            for k in np.unique(watch[watched]).tolist():
                self._watch_rows.append((KINDS_LIST[k], (watch == k).nonzero()[0]))
        self._feed_rows = ((a.driving | self.superposition.on) & ~(self._feed_plus & self._feed_minus)).nonzero()[0]
        standstill = ~(a.traj_on | job)
        standstill &= enabled
        self._watch = (a.lag_en & enabled, standstill, bool(np.count_nonzero(a.en_max) or np.count_nonzero(a.en_min)),
                       bool(np.count_nonzero(standstill)))
        cpl, sup, ext, pr = self.coupling, self.superposition, self.external, self.probe
        slaves = cpl.master >= 0
        staged = slaves | ext.on | sup.on  # rows a set-point stage writes every cycle
        if not self.all_on:  # axes without a profile: AxisState INACTIVE, NotMoving unless a set velocity remains
            idle = ~(a.traj_on | staged)
            self.sp_dw[idle] = self._not_moving[(np.abs(a.set_velo[idle]) > _EPS_V).view(np.uint8)]
            self.axis_state[idle] = 0
        err = a.error != 0
        self._event_dw = a.event_dwords(err)
        if np.count_nonzero(staged) or np.count_nonzero(pr.valid):
            # a slave is in protected mode and no PTP axis; Compensating, ExtSetPointGenEnabled,
            # ExternalLatchValid from their stages
            self._event_dw &= ~(slaves * _PTP)
            self._event_dw |= (slaves * _PROTECTED) | (sup.on * _COMPENSATING) | (ext.on * _EXT_ENABLED) | (pr.valid * _LATCH_VALID)
        out["CoupleState"] = cpl.couple_state
        out["TouchProbeState"] = pr.touch_state()
        out["TouchProbeCounter"] = pr.counter
        # ControlLoopClosed always, Operational only without an error (both need enable + drive ready)
        self._loop_dw = self._loop_ok[err.view(np.uint8)]
        self._has_offset = bool(np.count_nonzero(a.offset))
        self.has_origin = bool(np.count_nonzero(a.origin))
        out["ErrorCode"] = a.error
        out["SafEntries"] = job
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
        if what == "RemainingDistance":
            return float(abs(job.target - a.set_pos[i])) if positioning else 0.0  # type: ignore[union-attr,operator]
        raise AssertionError(f"params.json: unknown status {what!r}")  # a contract bug, not input

    def _fill_nctoplc(self) -> None:
        a, d, o = self.axes, self.drive, self._out
        act = self.act_pos
        sd = self._event_dw | self.sp_dw
        sd |= a.mon_dw
        sd |= (a.enabled & d.ready) * self._loop_dw
        o["StateDWord"][...] = sd
        o["AxisState"][...] = self.axis_state
        period = a.modulo_factor
        o["ActPos"][...] = act
        np.divmod(act, period, out=(o["ModuloActTurns"], o["ModuloActPos"]), casting="unsafe")  # // and %
        o["ActVelo"][...] = d.act_velo
        o["ActAcc"][...] = d.act_acc
        np.subtract(a.set_pos, act, out=o["PosDiff"])
        self._out_sp[...] = a.S[:3].T  # SetPos, SetVelo, SetAcc: adjacent fields, one copy
        o["SetJerk"][...] = a.set_jerk
        if np.count_nonzero(a.continuous):
            cont = a.continuous
            a.target_pos[cont] = a.set_pos[cont]  # endless motion: the target moves with the axis
            o["TargetPos"][...] = a.target_pos
        np.divmod(a.set_pos, period, out=(o["ModuloSetTurns"], o["ModuloSetPos"]), casting="unsafe")
        o["ActPosWithoutPosCorrection"][...] = act
        o["StateDWord3"][...] = self.drive.probe_input()  # bit 0: TouchProbe1InputState
        o["DcTimeStamp"][...] = self.nc_time_ns & 0xFFFFFFFF

    # -- commands ----------------------------------------------------------------------------
    def _dispatch(self, i: int, req: dict[str, Any]) -> dict[str, Any]:
        cmd = req["cmd"]
        kind = KINDS.get(cmd)
        if kind is not None:
            return self._motion(i, kind, req)
        if cmd in AMENDMENTS:
            return self._amend(i, req)
        handler = _ADMIN.get(cmd)
        if handler is None:
            raise NcError(ErrorCodes.ADSERR_DEVICE_SRVNOTSUPP, f"{cmd} is not an axis command of the NC core")
        return handler(self, i, req)

    def _motion(self, i: int, kind: Any, req: dict[str, Any]) -> dict[str, Any]:
        q = self.queues[i]
        mode = req.get("BufferMode", ABORTING)
        if mode not in kind.buffer_modes:
            raise NcError(ErrorCodes.MC_BUFFERMODE_NOT_SUPPORTED, f"{req['cmd']}: BufferMode {mode} is not supported")
        if not kind.always_allowed:
            self.check_startable(i)
        self._check_source(i, kind, mode)
        running = q.running_numbered
        if (running is not None and running.kind.homing and mode == ABORTING and not kind.always_allowed
                and running.state == int(CmdState.ACTIVE)):
            raise NcError(ErrorCodes.MC_AXIS_CANNOT_BE_STARTED, "the axis is homing (PLCopen: Homing accepts only MC_Stop)")
        client = str(req.get("client") or "")
        if mode != ABORTING and running is not None and running.state == int(CmdState.ACTIVE):
            if q.waiting is not None:
                raise NcError(ErrorCodes.NC_COMMAND_BUFFER_FULL,
                              f"command {q.waiting.cmd_no} is already waiting (one buffered command per axis)")
            job = kind.accept(self, i, req, running)
            job.client, job.buffer_mode = client, mode
            # validate from where it will start: the running job's target (at rest or passing it)
            base = running.kind.next_base(running, self, i)
            if base is None:  # no target to refer to: checked from here, fixed where it starts
                base = self.nc_set_pos(i)
            kind.activate(self, i, job.trial(), StartState(base))  # a check only: the record stays as accepted
            job.cmd_no = q.newest = next_cmdno(q.newest)
            job.state = int(CmdState.BUFFERED)
            q.waiting = job
            self._sync(i)
            if mode in BLENDING:
                self.blend(i)
            if running.kind.successor_may_start(self, i, running):
                self._advance(i)
                self._sync(i)
            return {"cmd_no": job.cmd_no}
        job = kind.accept(self, i, req, running)
        job.client, job.buffer_mode = client, mode
        # a stop brakes the total motion (a running superposition included)
        plan = kind.activate(self, i, job, self.start_state(i, total=kind.braking))
        self.begin(i, job, plan)
        return {"cmd_no": job.cmd_no}

    def _check_source(self, i: int, kind: Any, mode: int) -> None:
        """Motion commands to an axis a coupling or the external generator drives (TcMC / Tc2_MC2):
        refused unless its parameter allows them (then only Aborting: the command decouples /
        disables and takes over); MC_Stop always takes over; a second coupling is refused."""
        job = self.queues[i].active
        source = job.kind.source if job is not None else None
        if source is None or kind.always_allowed:
            return
        p = self.params[i]
        if kind.source == "coupling" and source == "coupling":
            return  # (the coupling kind decides: GearInDyn may take its own coupling over)
        if source == "coupling" and not p.AxisAllowMotionCmdToSlave:
            raise NcError(ErrorCodes.NC_SLAVE_COMMAND_NOT_ALLOWED,
                          f"axis {int(self.axis_ids[i])} is a coupled slave (AxisAllowMotionCmdToSlave is off)")
        if source == "external" and not p.AxisAllowMotionCmdToExtSetAxis:
            raise NcError(ErrorCodes.MC_AXIS_PROTECTED,
                          f"axis {int(self.axis_ids[i])} follows the external set-point generator "
                          "(AxisAllowMotionCmdToExtSetAxis is off; MC_ExtSetPointGenDisable first)")
        if mode != ABORTING:
            raise NcError(ErrorCodes.MC_BUFFERMODE_NOT_SUPPORTED, "a command to a coupled/external axis can only be Aborting")

    def _amend(self, i: int, req: dict[str, Any]) -> dict[str, Any]:
        q, a = self.queues[i], self.axes
        job = q.running_numbered
        if job is None or not (a.traj_on[i] or abs(a.set_velo[i]) > _EPS_V):
            raise NcError(ErrorCodes.MC_AXIS_NOT_MOVING, f"{req['cmd']}: the axis has no moving command to change")
        if req["cmd"] == "ChangeDynParam":
            plan = job.kind.change_dynamics(self, i, job, req)
        else:
            plan = job.kind.amend(self, i, job, req)
        job.amended = True
        if plan is not None:
            self.set_plan(i, plan)
            if job.target is not None:
                a.target_pos[i] = job.target
        if q.waiting is not None and q.waiting.buffer_mode in BLENDING:
            self.blend(i)
        self._sync(i)
        return {"cmd_no": job.cmd_no}


def _cmd_stop_release(core: NcCore, i: int, req: dict[str, Any]) -> dict[str, Any]:
    """MC_Stop Execute fell: unlock -- but not during the stop ramp (PLCopen: Stopping until the axis
    stands and Execute is FALSE); then the lock goes when the ramp ends."""
    job = core.queues[i].active
    if job is not None and job.kind.locks and core.axes.traj_on[i]:
        job.data["release"] = True
        return {}
    core.axes.locked[i] = False
    core._state_dirty = True
    return {}


def _cmd_reset(core: NcCore, i: int, req: dict[str, Any]) -> dict[str, Any]:
    a, q = core.axes, core.queues[i]
    core.probe.disarm_on_reset(i)
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
            core._sync(i)
        return {}  # a moving axis without an error: nothing to reset
    a.error[i] = 0
    a.locked[i] = False
    a.stopped[i] = False
    a.lag_timer[i] = 0.0
    # TwinCAT: after a reset the set position is the actual position
    a.set_pos[i] = core.act_pos[i]
    a.target_pos[i] = a.set_pos[i]
    core._sync(i)
    return {}


def _cmd_set_override(core: NcCore, i: int, req: dict[str, Any]) -> dict[str, Any]:
    ov = req["Override"]
    if not 0.0 <= ov <= 100.0:
        raise NcError(ErrorCodes.MC_PARAMETER_NOT_CORRECT, f"Override {ov} % outside 0..100")
    core.plctonc["Override"][i] = round(ov * 10000.0)
    core._in_dirty = True
    return {}


def _cmd_read_parameter(core: NcCore, i: int, req: dict[str, Any]) -> dict[str, Any]:
    return {"value": core.read_parameter(i, req["ParameterNumber"])}


def _cmd_write_parameter(core: NcCore, i: int, req: dict[str, Any]) -> dict[str, Any]:
    core.write_parameter(i, req["ParameterNumber"], req["Value"])
    return {}


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
        core._sync(i)
        return {"cmd_no": job.cmd_no}
    return {}


def _cmd_set_reference_flag(core: NcCore, i: int, req: dict[str, Any]) -> dict[str, Any]:
    core.axes.homed[i] = bool(req["ReferenceFlag"])
    core._state_dirty = True
    return {}


def _cmd_read_parameter_set(core: NcCore, i: int, req: dict[str, Any]) -> dict[str, Any]:
    """MC_ReadParameterSet: the whole ST_AxisParameterSet as a map of its members."""
    return {"value": core.parameter_set(i)}


def _cmd_read_axis_components(core: NcCore, i: int, req: dict[str, Any]) -> dict[str, Any]:
    """MC_ReadAxisComponents: ST_AxisComponents (one encoder, controller and drive per axis, with its id)."""
    ident = int(core.axis_ids[i])
    ids = [ident] + [0] * 8
    return {"value": {"EncoderIDs": ids, "ControllerIDs": list(ids), "DriveIDs": list(ids)}}


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
    core._state_dirty = True
    return {}


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


_ADMIN = {
    "ReadParameterSet": _cmd_read_parameter_set, "ReadAxisComponents": _cmd_read_axis_components,
    "SetExternalError": _cmd_set_external_error, "SimStall": _cmd_sim_stall, "SimTerminalError": _cmd_sim_terminal_error,
    "Reset": _cmd_reset, "StopRelease": _cmd_stop_release, "SetOverride": _cmd_set_override,
    "ReadParameter": _cmd_read_parameter, "WriteParameter": _cmd_write_parameter,
    "SetActualPosition": _cmd_set_actual_position, "SetActualPositionOnTheFly": _cmd_set_actual_position_otf,
    "SetReferenceFlag": _cmd_set_reference_flag,
    "GearOut": gear_out, "GearOutExt": gear_out, "ExtSetPointGenDisable": ext_disable,
    "MoveSuperImposed": cmd_move_superimposed, "AbortSuperposition": cmd_abort_superposition,
    "TouchProbe": cmd_touch_probe, "AbortTrigger": cmd_abort_trigger, "SimProbeSignal": cmd_sim_probe_signal,
}
KINDS_LIST = sorted({k for k in KINDS.values()}, key=lambda k: k.name)
KINDS_INDEX = {k.name: n for n, k in enumerate(KINDS_LIST)}
