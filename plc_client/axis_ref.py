"""AXIS_REF: the PLC's view of one NC axis (TwinCAT 3 Tc2_MC2 structure).

An :class:`AXIS_REF` holds

* ``NcToPlc``: a **read-only** snapshot (:class:`~plc_client.records.NCTOPLC_AXIS_REF`) of the
  axis's record in the newest NC status frame, renewed at the start of a PLC cycle when a frame
  arrived since the last snapshot (and when the data turns stale), so every function block in one
  cycle sees the same data; every member is an attribute with a plain Python value
  (``X.NcToPlc.SetPos``, ``X.NcToPlc.StateDWord``). While no frame arrived the snapshot is left as it
  is (it would hold the same bytes: a saving, not a rule to rely on), so a program that assigns its
  own record to ``X.NcToPlc`` keeps it until the next frame (or until the data turns stale), and the
  blocks judge that record;
* ``PlcToNc``: a **writable** record (:class:`~plc_client.records.PLCTONC_AXIS_REF`) that the
  runtime publishes at the end of every PLC cycle for the axes it controls
  (``Override`` starts at 1000000 = 100 %; ``X.PlcToNc.Override = 500000``);
* ``Status``: :class:`ST_AxisStatus`, refreshed from the frame with every new snapshot (what
  ``MC_ReadStatus`` / ``Axis.ReadStatus()`` do in TwinCAT; not from a record the program assigned),
  plus ``NcCycleCounter`` (the NC cycle that produced the snapshot), ``CycleCounter`` (the PLC
  cycle, counted every cycle) and ``Valid`` (False while the data is stale or missing).

Binding: ``AXIS_REF(nc="nc1", axis_id=1)`` names the axis; it is bound to a PLC task
(:class:`plc_client.task.PlcTask`) when the program is loaded (``plc-run`` binds every AXIS_REF
the program file declares: :func:`plc_client.cli.load_program`; embedding: ``PlcRuntime(...,
axes=[...])``), when it is created inside a running PLC cycle (to the task running it),
explicitly (``task.axis(...)`` / ``task.register(ax)``) or implicitly the first time a function
block is called with it inside a running PLC cycle. A bound axis's NcToPlc and Status are
kept up to date every cycle (as above), whether or not a block uses it; a bound AXIS_REF stays bound for the task's
life, so create each once (at load or on first use), not anew every cycle.

Staleness (zenoh-nc choice; Tc2_MC2 raises 0x4B0F when its NC cycle counter stops):
if the NC cycle of an axis's snapshot has not advanced for ``stale_cycles`` PLC cycles,
or no frame has arrived yet, ``Status.Valid`` is False and function blocks report
0x4B0F (MC_NO_NC_CYCLE_UPDATE) instead of acting on old data. A new NC instance token
(another id) or a frame whose NC cycle is *lower* than the previous one means the NC restarted
(:class:`nc_schema.NcInstance`; its liveliness token going and coming back is no restart, only an
unreachable NC meanwhile: see
:meth:`plc_client.task.PlcTask.nc_token_gone`): the task increments ``nc_epoch`` once so that
blocks following a command of the old NC instance stop following it (0x4B0F).
"""
from __future__ import annotations

import contextlib
import weakref
from typing import TYPE_CHECKING, Any, Iterator

import numpy as np

from nc_schema import NCTOPLC_DTYPE, MC_AxisStates, StateDWord, motion_state

from .records import _NC_INDEX, NCTOPLC_AXIS_REF, NO_JOBS, PLCTONC_AXIS_REF, NcJobsValues, pick_struct

if TYPE_CHECKING:  # pragma: no cover
    from .task import PlcTask

_S = {name: int(getattr(StateDWord, name)) for name in StateDWord.__members__}

#: ST_AxisStatus boolean members taken directly from one StateDWord bit.
_BIT_FIELDS: dict[str, str] = {
    "Operational": "Operational", "ControlLoopClosed": "ControlLoopClosed", "HasJob": "HasJob",
    "HasBeenStopped": "HasBeenStopped", "NewTargetPosition": "NewTargetPos", "InPositionArea": "InPositionArea",
    "InTargetPosition": "InTargetPosition", "ProtectedMode": "Protected", "Homed": "Homed",
    "HomingBusy": "HomingBusy", "MotionCommandsLocked": "MotionCommandsLocked",
    "SoftLimitMinExceeded": "SoftLimitMinExceeded", "SoftLimitMaxExceeded": "SoftLimitMaxExceeded",
    "PositiveDirection": "PositiveDirection", "NegativeDirection": "NegativeDirection", "NotMoving": "NotMoving",
    "Compensating": "Compensating", "ExtSetPointGenEnabled": "ExtSetPointGenEnabled",
    "PhasingActive": "PhasingActive", "ExternalLatchValid": "ExternalLatchValid",
    "CamDataQueued": "CamDataQueued", "CamTableQueued": "CamTableQueued", "CamScalingPending": "CamScalingPending",
    "CmdBuffered": "CmdBuffered", "PTPmode": "PTPmode", "DriveDeviceError": "DriveDeviceError",
    "IoDataInvalid": "IoDataInvalid", "ErrorPropagationDelayed": "ErrorPropagationDelayed",
    "DriveLimitActive": "IsDriveLimitActive", "ConstantVelocity": "ConstantVelocity",
}

#: PLCopen state -> the ST_AxisStatus flag that is TRUE in it.
_STATE_FLAGS: dict[int, str] = {
    int(MC_AxisStates.MC_AXISSTATE_ERRORSTOP): "ErrorStop",
    int(MC_AxisStates.MC_AXISSTATE_DISABLED): "Disabled",
    int(MC_AxisStates.MC_AXISSTATE_STOPPING): "Stopping",
    int(MC_AxisStates.MC_AXISSTATE_STANDSTILL): "StandStill",
    int(MC_AxisStates.MC_AXISSTATE_DISCRETEMOTION): "DiscreteMotion",
    int(MC_AxisStates.MC_AXISSTATE_CONTINOUSMOTION): "ContinuousMotion",
    int(MC_AxisStates.MC_AXISSTATE_SYNCHRONIZEDMOTION): "SynchronizedMotion",
    int(MC_AxisStates.MC_AXISSTATE_HOMING): "Homing",
}

#: where ST_AxisStatus.update finds its members in an unpacked NCTOPLC record (scalars)
_I_SDW, _I_CS, _I_ERR, _I_ACC, _I_VEL = (_NC_INDEX[n][0] for n in
                                         ("StateDWord", "CoupleState", "ErrorCode", "SetAcc", "SetVelo"))

#: the NCTOPLC members a snapshot reads every cycle (the Status refresh, and StateDWord for the blocks: ``_sdw``),
#: without unpacking the other ~55 values (NcToPlc unpacks them at its first read, if any)
_NC_PICK = pick_struct(NCTOPLC_DTYPE, "StateDWord", "ErrorCode", "CoupleState", "SetVelo", "SetAcc").unpack
_new = object.__new__

#: |SetAcc| below this [u/s^2] counts as "not accelerating" (numerical noise of the profile).
_ACC_EPS = 1e-9


#: (StateDWord, CoupleState) -> the ST_AxisStatus members derived from them alone (a few states per axis
#: recur every cycle: computing ~40 members each time cost ~20 us per axis and PLC cycle)
_FLAGS: dict[tuple[int, int], dict[str, Any]] = {}
_FLAGS_MAX = 4096


def _flags(s: int, cs: int) -> dict[str, Any]:
    state = motion_state(s, cs)
    d: dict[str, Any] = {"MotionState": state, "Error": bool(s & _S["Error"]), "Coupled": cs != 0}
    for value, flag in _STATE_FLAGS.items():
        d[flag] = value == state
    for name, bit in _BIT_FIELDS.items():
        d[name] = bool(s & _S[bit])
    d["Moving"] = d["PositiveDirection"] or d["NegativeDirection"]
    if len(_FLAGS) >= _FLAGS_MAX:
        _FLAGS.clear()
    _FLAGS[(s, cs)] = d
    return d


class ST_AxisStatus:
    """Tc2_MC2 ST_AxisStatus: the axis state as plain attributes.

    All members are False/0 until the first valid snapshot. ``MotionState`` is an
    ``MC_AxisStates`` value computed by :func:`nc_schema.motion_state`; the PLCopen
    flags (``ErrorStop`` ... ``Homing``) are derived from it, so exactly one is TRUE
    while ``Valid``. ``Accelerating``/``Decelerating`` compare the signs of SetAcc and
    SetVelo (|velocity| growing / shrinking); ``Moving`` is PositiveDirection or
    NegativeDirection.
    """

    _FIELDS: tuple[str, ...] = (
        "UpdateTaskIndex", "UpdateCycleTime", "CycleCounter", "NcCycleCounter", "MotionState", "Error", "ErrorId",
        "ErrorStop", "Disabled", "Stopping", "StandStill", "DiscreteMotion", "ContinuousMotion",
        "SynchronizedMotion", "Homing", "Accelerating", "Decelerating", "Moving", "Coupled", "Valid",
        *_BIT_FIELDS,
    )
    # the members __init__ sets from _STATE_FLAGS and _BIT_FIELDS, declared for the type checker
    # (tests/plc/test_declarations.py checks that none is missing)
    ErrorStop: bool
    Disabled: bool
    Stopping: bool
    StandStill: bool
    DiscreteMotion: bool
    ContinuousMotion: bool
    SynchronizedMotion: bool
    Homing: bool
    Operational: bool
    ControlLoopClosed: bool
    HasJob: bool
    HasBeenStopped: bool
    NewTargetPosition: bool
    InPositionArea: bool
    InTargetPosition: bool
    ProtectedMode: bool
    Homed: bool
    HomingBusy: bool
    MotionCommandsLocked: bool
    SoftLimitMinExceeded: bool
    SoftLimitMaxExceeded: bool
    PositiveDirection: bool
    NegativeDirection: bool
    NotMoving: bool
    Compensating: bool
    ExtSetPointGenEnabled: bool
    PhasingActive: bool
    ExternalLatchValid: bool
    CamDataQueued: bool
    CamTableQueued: bool
    CamScalingPending: bool
    CmdBuffered: bool
    PTPmode: bool
    DriveDeviceError: bool
    IoDataInvalid: bool
    ErrorPropagationDelayed: bool
    DriveLimitActive: bool
    ConstantVelocity: bool

    def __init__(self) -> None:
        self.UpdateTaskIndex: int = 0
        self.UpdateCycleTime: float = 0.0
        self.CycleCounter: int = 0
        self.NcCycleCounter: int = 0
        self.MotionState: MC_AxisStates = MC_AxisStates.MC_AXISSTATE_UNDEFINED
        self.Error: bool = False
        self.ErrorId: int = 0
        self.Accelerating: bool = False
        self.Decelerating: bool = False
        self.Moving: bool = False
        self.Coupled: bool = False
        self.Valid: bool = False
        for flag in _STATE_FLAGS.values():
            setattr(self, flag, False)
        for name in _BIT_FIELDS:
            setattr(self, name, False)

    def update(self, rec: NCTOPLC_AXIS_REF, nc_cycle: int, plc_cycle: int, cycle_time: float, valid: bool) -> None:
        """Refresh every member from one NCTOPLC record (what MC_ReadStatus does)."""
        v = rec._v or rec._unpack()  # (one look at the unpacked values instead of five properties)
        s = v[_I_SDW]
        cs = v[_I_CS]
        self.CycleCounter = plc_cycle
        self.NcCycleCounter = nc_cycle
        self.UpdateCycleTime = cycle_time
        self.Valid = valid
        flags = _FLAGS.get((s, cs))
        if flags is None:
            flags = _flags(s, cs)
        self.__dict__.update(flags)
        self.ErrorId = v[_I_ERR]
        acc, vel = v[_I_ACC], v[_I_VEL]
        if abs(acc) <= _ACC_EPS:
            self.Accelerating = self.Decelerating = False
        elif vel == 0.0:
            # starting from rest: any acceleration increases |v|
            self.Accelerating, self.Decelerating = True, False
        else:
            self.Accelerating = (acc > 0) == (vel > 0)
            self.Decelerating = not self.Accelerating

    def copy(self) -> ST_AxisStatus:
        """An independent copy (MC_ReadStatus output)."""
        c = object.__new__(ST_AxisStatus)  # (every member is in __dict__: no __init__ needed)
        c.__dict__.update(self.__dict__)
        return c

    def as_dict(self) -> dict[str, Any]:
        return dict(self.__dict__)

    def __repr__(self) -> str:
        flags = [n for n in ("Valid", "Error", "HasJob", "ControlLoopClosed", "InTargetPosition") if getattr(self, n)]
        return f"ST_AxisStatus({self.MotionState.name}, nc_cycle={self.NcCycleCounter}, {'|'.join(flags)})"


#: collectors of :func:`collect_axes` (a program being loaded); weak: a temporary AXIS_REF is not kept
_collectors: list[list[weakref.ref[AXIS_REF]]] = []


@contextlib.contextmanager
def collect_axes() -> Iterator[list[weakref.ref[AXIS_REF]]]:
    """Record every AXIS_REF created inside the ``with`` block (how ``plc-run`` finds the axes a program
    declares while it loads it, wherever it keeps them: module globals, a Program's attributes, lists...)."""
    refs: list[weakref.ref[AXIS_REF]] = []
    _collectors.append(refs)
    try:
        yield refs
    finally:
        _collectors.remove(refs)


class AXIS_REF:
    """Reference to one NC axis: ``AXIS_REF(nc="nc1", axis_id=1)``.

    Attributes:
        nc: NC name (``nc/<nc>/...`` keys).
        axis_id: the axis's AxisId (1..65535).
        NcToPlc: read-only NCTOPLC snapshot of this PLC cycle (:class:`~plc_client.records.NCTOPLC_AXIS_REF`:
            ``X.NcToPlc.SetPos`` ... as plain Python values; ``X.NcToPlc["SetPos"]`` is the same).
        PlcToNc: writable PLCTONC record published for a controlled axis
            (:class:`~plc_client.records.PLCTONC_AXIS_REF`: ``X.PlcToNc.Override = 500000``).
        NcJobs: read-only NCJOBS_AXIS_REF snapshot (zenoh-nc, a numpy record): the axis's command queue
            and the fates of its last ended commands, so a block sees how its own command ended (the
            blocks read the same record as plain values, ``_jobs``: :class:`~plc_client.records.NcJobsValues`).
        Status: :class:`ST_AxisStatus`, refreshed every PLC cycle.
        nc_epoch: incremented once each time the NC is seen to restart (a new instance in the
            frames: its cycle went back).

    Raises:
        ValueError: an invalid NC name or axis id.
    """

    def __init__(self, nc: str = "nc1", axis_id: int = 1, name: str = "") -> None:
        if isinstance(axis_id, bool) or not isinstance(axis_id, int) or not 1 <= axis_id <= 65535:
            raise ValueError(f"axis_id must be an integer 1..65535, got {axis_id!r}")
        if not isinstance(nc, str) or not nc:
            raise ValueError(f"nc must be an NC name, got {nc!r}")
        self.nc = nc
        self.axis_id = axis_id
        self.name = name or f"{nc}/{axis_id}"
        self.NcToPlc = NCTOPLC_AXIS_REF()
        #: this cycle's NCJOBS as plain values (the blocks read these; ``NcJobs`` is its numpy record)
        self._jobs: NcJobsValues = NO_JOBS
        self.PlcToNc = PLCTONC_AXIS_REF()
        self.PlcToNc.Override = 1_000_000
        self._plctonc = self.PlcToNc._arr  # a numpy view of the same bytes (the frame encoders take it)
        self._plctonc_buf = self.PlcToNc._buf  # the same bytes (the task's preallocated PLC frame copies them)
        self.Status = ST_AxisStatus()
        self.nc_epoch = 0
        #: True once frames arrived but this axis id was not in them (-> 0x4012).
        self.missing = False
        #: True while the view frames of its NC do not cover it yet (bound after the client asked for its
        #: view: the NC has not seen the new selection), for at most the task's command_timeout after binding;
        #: a block called on it waits (:meth:`plc_client.fb.base.FunctionBlock.__call__`)
        self.pending = False
        self._pending_until = 0.0  # time.monotonic() when a binding's wait for the view ends
        self._task: PlcTask | None = None
        for refs in _collectors:
            refs.append(weakref.ref(self))
        self._has_data = False
        self._unchanged = 0  # PLC cycles without a newer NC cycle
        #: the task's frame entry this axis's last snapshot was taken from and valid with (None: none such); the
        #: task skips the decoding while no newer frame came (PlcTask._snapshot_all)
        self._src: Any = None
        from .task import current_task  # (task imports this module)
        task = current_task()
        if task is not None:
            # created by the program in a cycle (e.g. on first use): bound at once, as one declared at load
            # is, so its data is valid from this cycle on without a block call (a monitor sees it too)
            task.register(self)

    # -- binding -----------------------------------------------------------------------
    @property
    def task(self) -> PlcTask | None:
        """The PLC task this reference is bound to (None while unbound)."""
        return self._task

    @property
    def controlled(self) -> bool:
        """True once an MC_Power block has been used on this axis (its PLCTONC is published)."""
        return self._task is not None and self._task.is_controlled(self)

    @property
    def NcJobs(self) -> np.void:
        """The read-only NCJOBS_AXIS_REF record of this cycle (numpy; made on first use in a cycle)."""
        return self._jobs.record

    # -- snapshot ----------------------------------------------------------------------
    def _snapshot(self, rec: bytes | None, nc_cycle: int | None, plc_cycle: int, cycle_time: float,
                  stale_cycles: int, jobs: bytes | None = None) -> None:
        """Take this cycle's snapshot (called by the task at the start of each PLC cycle).

        ``rec`` is the bytes of this axis's NCTOPLC record in the newest frame of its NC (None if the
        frame does not contain the axis or no frame was received yet), ``jobs`` those of its NCJOBS
        record (None: the frame has none; the last ones are kept). Bytes, never copied again: the
        task slices them from one copy of the frame's records (immutable, so a snapshot kept by the
        program keeps its values).
        """
        self.pending = False
        self._src = None  # (the task sets it again after a valid snapshot of its frame)
        st = self.Status
        if rec is not None and nc_cycle is not None:
            if self._has_data and nc_cycle == st.NcCycleCounter:
                self._unchanged += 1
            else:
                self._unchanged = 0  # a newer frame (or a restarted NC's: the task bumps nc_epoch)
            # this cycle's copy (NCTOPLC_AXIS_REF._of without its call), unpacked at its first read; the five
            # members the Status refresh needs are read now
            nc = self.NcToPlc = _new(NCTOPLC_AXIS_REF)
            s, err, cs, vel, acc = _NC_PICK(rec)
            nc._raw, nc._v, nc._rec, nc._sdw = rec, None, None, s
            if jobs is not None:
                j = self._jobs = _new(NcJobsValues)
                j._raw, j._v, j._rec = jobs, None, None
            self._has_data = True
            self.missing = False
            if self._unchanged < stale_cycles:  # valid (the usual case): ST_AxisStatus.update inline
                # every valid snapshot sets the ~40 members again (~1 us), as TwinCAT's ReadStatus does: a program's
                # write into Status does not outlive the next snapshot
                flags = _FLAGS.get((s, cs))
                if flags is None:
                    flags = _flags(s, cs)
                st.__dict__.update(flags)
                if abs(acc) <= _ACC_EPS:
                    accel = decel = False
                elif vel == 0.0:
                    accel, decel = True, False  # starting from rest: any acceleration increases |v|
                else:
                    accel = (acc > 0) == (vel > 0)
                    decel = not accel
                st.CycleCounter, st.NcCycleCounter, st.UpdateCycleTime, st.Valid = plc_cycle, nc_cycle, cycle_time, True
                st.ErrorId, st.Accelerating, st.Decelerating = err, accel, decel
                return
        else:
            self._unchanged += 1
            self.missing = nc_cycle is not None  # frames arrive, but without this axis
            nc_cycle = st.NcCycleCounter
        valid = self._has_data and not self.missing and self._unchanged < stale_cycles
        st.update(self.NcToPlc, nc_cycle, plc_cycle, cycle_time, valid)

    @property
    def valid(self) -> bool:
        return self.Status.Valid

    def shows_cycle(self, cycle: int) -> bool:
        """True once this PLC cycle's snapshot comes from a frame of NC cycle ``cycle`` or later, i.e.
        the frame shows what the NC did in that cycle (a command whose reply carried
        ``cycle``: :func:`plc_client.port.reply_cycle`). False without data of the current NC
        instance (after a restart its cycles start again: a block that waits compares ``nc_epoch``)."""
        return self._has_data and self.Status.NcCycleCounter >= cycle

    # -- convenience (TwinCAT-like) ------------------------------------------------------
    def ReadStatus(self) -> ST_AxisStatus:
        """Tc2_MC2 ``Axis.ReadStatus()``: the status is already refreshed every cycle."""
        return self.Status

    @property
    def ActPos(self) -> float:
        return self.NcToPlc.ActPos

    @property
    def ActVelo(self) -> float:
        return self.NcToPlc.ActVelo

    def __repr__(self) -> str:
        return f"AXIS_REF(nc={self.nc!r}, axis_id={self.axis_id})"
