"""Motion function blocks: MC_MoveAbsolute, MC_MoveRelative, MC_MoveAdditive, MC_MoveModulo,
MC_MoveVelocity, MC_MoveContinuousAbsolute, MC_MoveContinuousRelative, MC_MoveAbsoluteOrRestart,
MC_Halt, MC_Stop, MC_OrientedStop (TcMC manual 3.1-3.6, 3.15, 3.16; Tc2_MC2 for BufferMode,
MC_MoveAdditive, MC_MoveContinuous*, InEndVelocity and the outputs Busy/Active).

Following a command: the NC's reply carries ``CmdNo`` (the axis's number for this command) and
``cycle`` (the NC cycle in which it took effect). The block only evaluates snapshots whose NC
cycle (``Axis.Status.NcCycleCounter``) is >= that cycle; until then it is Busy (not Active).

**With job records** (``AXIS_REF.NcJobs``, NCJOBS_AXIS_REF, ``AxisId`` != 0; schema/README.md
"Commands and their fate") the block looks for *its own* CmdNo:

* ``BufferedCmdNo``: waiting behind the active job -> Busy, not Active;
* ``ActiveCmdNo``: ACTIVE -> Busy and Active (axis Error bit -> Error with NcToPlc.ErrorCode);
  DONE (the axis is idle after it) -> the Done rule below; ABORTED -> CommandAborted; ERROR ->
  Error;
* in ``Ended`` (not the active one): DONE -> Done at once (a buffered or blended successor took
  over: the axis moves on, there is no target window to wait for); ABORTED -> CommandAborted;
  ERROR -> Error with that entry's ``ErrorId`` (0x4B62 when it is 0);
* none of them and older than ``NewestCmdNo`` -> CommandAborted (pushed out of the four
  ``Ended`` entries by a burst of newer commands); not older -> Error 0x4B60.

An ERROR's ErrorID is the ``Ended`` entry's ErrorId, else NcToPlc.ErrorCode, else 0x4B62.

**Without job records** (a frame without them: ``NcJobs`` all zeros) the older rule applies,
from NcToPlc alone:

* ``NcToPlc.CmdNo`` newer than ours (``nc_schema.cmdno_newer``) -> CommandAborted, whoever
  sent the newer command (a buffered successor cannot be told from an aborting one here);
* same CmdNo: axis Error bit -> Error with the axis ErrorCode; CmdState ACTIVE -> Busy and
  Active; DONE -> the Done rule below; ABORTED -> CommandAborted; ERROR -> Error with
  NcToPlc.ErrorCode (0x4B00 if the NC already cleared it);
* CmdNo older than ours: StateDWord.CmdBuffered set -> waiting (Busy, not Active); else
  Error 0x4B60 (the command never became active: the NC lost it).

In both modes: stale data -> Error 0x4B0F; an NC restart while following
(``AXIS_REF.nc_epoch`` changed) -> Error 0x4B0F, the new NC instance knows nothing of the
command.

Done (TcMC appendix 7.1), from the OpModeDWord monitoring bits the NC publishes: the command
ended DONE (HasJob fell) and

* OpModeTargetPosMonitoring set: InTargetPosition (zenoh-nc: also when position range
  monitoring is off - the manual lists only the three other combinations);
* only OpModePosAreaMonitoring: InPositionArea;
* neither: nothing more.

If the window is not reached 6 s after the logical end (first frame with DONE): Error
0x4B07. Active stays TRUE while waiting for the window (the command is still the axis's
latest). MC_Halt, MC_Stop and MC_OrientedStop are Done at the logical standstill (DONE, no
window: their end position is not a target the program chose).

BufferMode (Tc2_MC2 MC_BufferMode, wire values 0 Aborting, 1 Buffered, 18 BlendingLow,
19 BlendingPrevious, 20 BlendingNext, 21 BlendingHigh): the block passes the integer through;
the NC checks it (0x4B64 for another value, 0x4292 when a command already waits). zenoh-nc
choice: a BufferMode that is not an integer (BOOL, REAL, text) or does not fit the wire's
32-bit INT is refused by the block itself with 0x4B64, and nothing is sent.

MC_MoveVelocity: InVelocity when the frame shows our command ACTIVE with ConstantVelocity;
as in Tc2_MC2 the block is then finished ("no further monitoring takes place"): Busy and
Active fall, InVelocity follows the Done output rules. A velocity job that ended DONE because
a buffered successor took over counts as InVelocity.

MC_Stop (PLCopen exception): Done once the stop ramp ended (CmdState DONE), but Busy and
Active stay TRUE while Execute stays TRUE - the axis is locked (MotionCommandsLocked; other
moves get 0x42EF from the NC). On Execute falling the block sends ``StopRelease`` (once the
axis stands still: if Execute falls during the ramp, Done is shown for one cycle at the end
of the ramp and the release follows immediately). A second MC_Stop (newer CmdNo) makes the
first one CommandAborted; then only the newer one releases the lock.
"""
from __future__ import annotations

import numbers
from typing import Any, ClassVar

import numpy as np

from nc_schema import NCJOBS_DTYPE, CmdState, ErrorCodes, MC_Direction, OpModeDWord, StateDWord, cmdno_newer

from ..records import NCTOPLC_AXIS_REF, NcJobsValues, pick_struct
from .base import ExecuteBlock

_ERR = int(StateDWord.Error)
_HASJOB = int(StateDWord.HasJob)
_CONSTV = int(StateDWord.ConstantVelocity)
_CONTM = int(StateDWord.ContinuousMotion)
_CMDBUF = int(StateDWord.CmdBuffered)
_INTARGET = int(StateDWord.InTargetPosition)
_INAREA = int(StateDWord.InPositionArea)
_TGT_MON = int(OpModeDWord.OpModeTargetPosMonitoring)
_AREA_MON = int(OpModeDWord.OpModePosAreaMonitoring)

#: the NCJOBS members _follow / _follow_job read every cycle, picked from the record's bytes (no full unpack)
_JOBS_AXIS_ID = pick_struct(NCJOBS_DTYPE, "AxisId").unpack
_JOBS_HEAD = pick_struct(NCJOBS_DTYPE, "ActiveCmdNo", "ActiveState", "BufferedCmdNo").unpack
_ACTIVE, _DONE_S, _ABORTED, _ERROR = (int(CmdState.ACTIVE), int(CmdState.DONE), int(CmdState.ABORTED),
                                      int(CmdState.ERROR))

#: TcMC appendix 7.1: the window must be reached within this time after the logical end [s].
DONE_WINDOW_TIMEOUT = 6.0

#: range of the wire's INT (protocol.json); a BufferMode outside it cannot be sent
_INT_MIN, _INT_MAX = -(2**31), 2**31 - 1


def _wire_int(v: Any) -> int | None:
    """``v`` as an INT for the wire, or None if it is not an integer that fits."""
    if isinstance(v, (bool, np.bool_)) or not isinstance(v, numbers.Integral):
        return None
    i = int(v)
    return i if _INT_MIN <= i <= _INT_MAX else None


class MotionBlock(ExecuteBlock):
    """A motion command followed through the job records or (CmdNo, CmdState); see the module docstring."""

    CMD: ClassVar[str] = ""
    _REALS: ClassVar[tuple[str, ...]] = ()
    #: "window": appendix 7.1 Done; "standstill": DONE and HasJob fell; "velocity": InVelocity
    _END: ClassVar[str] = "window"
    #: a rising edge of Execute while Busy sends a new command (MC_MoveAbsoluteOrRestart,
    #: MC_ChangeDynParam) instead of being ignored
    _RETRIGGER: ClassVar[bool] = False
    #: the task stops the command if the block gave up on lost data and the NC still runs it
    #: (False for stops and amendments: nothing to undo)
    _UNDO_ON_LOSS: ClassVar[bool] = True

    def __init__(self, timeout: float | None = None) -> None:
        super().__init__(timeout)
        self._cmdno = 0
        self._cmd_cycle = 0
        self._done_since: float | None = None

    def _args(self) -> dict[str, Any] | None:
        """The command's arguments: the latched real inputs, Direction and BufferMode where the
        block has them. None (the block finished with Error) if BufferMode cannot be sent."""
        a: dict[str, Any] = {k: float(getattr(self, k)) for k in self._REALS}
        # (getattr: only the blocks whose _INPUTS have them have these attributes)
        if "Direction" in self._INPUTS:
            a["Direction"] = _int_or_invalid(getattr(self, "Direction"))
        if "BufferMode" in self._INPUTS:
            bm = _wire_int(getattr(self, "BufferMode"))
            if bm is None:
                self._finish("Error", ErrorCodes.MC_BUFFERMODE_NOT_SUPPORTED)
                return None
            a["BufferMode"] = bm
        return a

    #: the class keeps MotionBlock._progress (set when the class is defined: a ``_progress`` assigned to the class
    #: later is not seen): the busy path of ``_cycle`` may call ``_follow``
    _PLAIN_PROGRESS: ClassVar[bool] = True

    #: the class keeps MotionBlock's _on_state and _set_active (set when the class is defined): _follow_job may
    #: take an ACTIVE command without an axis error inline
    _PLAIN_STATE: ClassVar[bool] = True
    #: the class keeps MotionBlock._on_active (which does nothing): the inline path skips its call
    _PLAIN_ON_ACTIVE: ClassVar[bool] = True
    #: "Active" is one of the class's outputs (what _set_active tests, once per class)
    _HAS_ACTIVE: ClassVar[bool] = True

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        cls._PLAIN_PROGRESS = cls._progress is MotionBlock._progress
        cls._PLAIN_STATE = cls._on_state is MotionBlock._on_state and cls._set_active is MotionBlock._set_active
        cls._PLAIN_ON_ACTIVE = cls._on_active is MotionBlock._on_active
        cls._HAS_ACTIVE = "Active" in cls._OUTPUTS

    def _cycle(self) -> None:
        if self.Busy and self._prev_execute and self._cmdno and self._PLAIN_PROGRESS and self.Execute:
            # (every cycle of a move: Busy, Execute held, the command accepted; ExecuteBlock._cycle would only
            # call _progress, and that only _follow)
            self._follow()
            return
        if self._RETRIGGER and self.Busy and self.Execute and not self._prev_execute:
            self._prev_execute = True
            self._restart()
            return
        ExecuteBlock._cycle(self)  # (super()'s, without building the super object every cycle)

    def _restart(self) -> None:
        """A rising edge while Busy (``_RETRIGGER`` blocks): send a new command, follow its CmdNo.

        The earlier request is dropped without being abandoned: a reply to it that is still on
        its way is then neither followed nor treated as a late acceptance (which would make the
        task halt the axis if that command were still active). Active stays as it is until the
        new command's frames show it.
        """
        self._pending = None
        self._start()

    def _start(self) -> None:
        self._cmdno, self._cmd_cycle, self._done_since = 0, 0, None
        if not self._check_inputs(self._REALS, buffer_mode=False):
            return
        args = self._args()
        if args is None:
            return
        self._send(self.CMD, **args)

    def _progress(self) -> None:
        if not self._cmdno:
            got = self._accepted()
            if got is None:
                return
            self._cmdno, self._cmd_cycle, _ = got
        self._follow()


    def _on_axis_lost(self, ax: Any, task: Any) -> None:
        if self._UNDO_ON_LOSS and self._cmdno:
            task.lost_command(ax, self._cmdno, self.CMD, max(self._cmd_cycle, ax.Status.NcCycleCounter))

    def _set_active(self, active: bool) -> None:
        if "Active" in self._OUTPUTS:
            self.Active = active

    def _follow(self) -> None:
        ax = self.Axis
        # (_lost_axis's usual answer, False, without its call; then AXIS_REF.shows_cycle inline)
        if (ax is None or ax._task is None or ax.missing or not ax.Status.Valid or ax.nc_epoch != self._epoch) \
                and self._lost_axis():
            return
        assert ax is not None
        if not (ax._has_data and ax.Status.NcCycleCounter >= self._cmd_cycle):
            return  # the frame does not show the command's effect yet
        jobs = ax._jobs  # (plain values: the few members read here picked from its bytes, not unpacked)
        if _JOBS_AXIS_ID(jobs._raw)[0]:  # (jobs.AxisId without unpacking the record)
            self._follow_job(ax.NcToPlc, jobs)
        else:
            self._follow_cmdno(ax.NcToPlc)

    def _follow_job(self, rec: NCTOPLC_AXIS_REF, jobs: NcJobsValues) -> None:
        """The table of schema/README.md: find our CmdNo in the axis's job records."""
        me = self._cmdno
        active_no, state, buffered_no = _JOBS_HEAD(jobs._raw)  # (those members without unpacking the record)
        if buffered_no == me:
            self._set_active(False)  # waiting behind the active job
            return
        if active_no == me:
            if state == _ACTIVE and self._PLAIN_STATE:
                # (every cycle of a running move: what _on_state does for ACTIVE without an axis error, without
                # its calls; an axis error takes the path below)
                sdw = rec._sdw  # (its StateDWord, without unpacking the record)
                if not sdw & _ERR:
                    if self._HAS_ACTIVE:
                        self.Active = True
                    if not self._PLAIN_ON_ACTIVE:
                        self._on_active(sdw)
                    return
            if state in (_ACTIVE, _DONE_S, _ABORTED, _ERROR):
                # the error code matters only for ERROR or an axis error (_on_state): looked up only then
                err = (self._ended_error(jobs, me, rec) if state == _ERROR or rec.StateDWord & _ERR
                       else ErrorCodes.MC_BUFFERED_CMD_ERROR)
                self._on_state(state, rec, err)
            else:
                self._set_active(False)  # BUFFERED/NONE under the active number: not started yet
            return
        for cmdno, state, error_id in jobs.Ended:
            if cmdno != me:
                continue
            if state == _DONE_S:
                self._done_now()
            elif state == _ABORTED:
                self._finish("CommandAborted")
            elif state == _ERROR:
                self._finish("Error", error_id or ErrorCodes.MC_BUFFERED_CMD_ERROR)
            return  # (an Ended entry that is not ended cannot happen; keep waiting)
        if cmdno_newer(jobs.NewestCmdNo, me):
            self._finish("CommandAborted")  # pushed out of the record by newer commands
        else:
            self._finish("Error", ErrorCodes.MC_CMD_NOT_ACTIVE)

    @staticmethod
    def _ended_error(jobs: NcJobsValues, me: int, rec: NCTOPLC_AXIS_REF) -> int:
        for cmdno, _, error_id in jobs.Ended:
            if cmdno == me and error_id:
                return error_id
        return rec.ErrorCode or ErrorCodes.MC_BUFFERED_CMD_ERROR

    def _follow_cmdno(self, rec: NCTOPLC_AXIS_REF) -> None:
        """No job records: follow NcToPlc (CmdNo, CmdState) alone."""
        cmdno, state, sdw = rec.CmdNo, rec.CmdState, rec.StateDWord
        if cmdno != self._cmdno:
            if cmdno_newer(cmdno, self._cmdno):
                self._finish("CommandAborted")
            elif sdw & _CMDBUF:
                self._set_active(False)  # ours is (presumably) the one waiting
            else:
                self._finish("Error", ErrorCodes.MC_CMD_NOT_ACTIVE)
            return
        self._on_state(state, rec, rec.ErrorCode or ErrorCodes.MC_AXIS_STOPPED)

    def _on_state(self, state: int, rec: NCTOPLC_AXIS_REF, error_code: int) -> None:
        """Our command is the axis's active (or last) one, in ``state``; ``error_code`` is used only for
        ERROR or an axis error."""
        sdw = rec.StateDWord
        if state == _ERROR:
            self._finish("Error", error_code)
        elif sdw & _ERR:
            self._finish("Error", rec.ErrorCode or error_code)
        elif state == _ABORTED:
            self._finish("CommandAborted")
        elif state == _ACTIVE:
            self._set_active(True)
            self._on_active(sdw)
        elif state == _DONE_S:
            self._set_active(True)
            self._on_done(rec, sdw)
        # CmdState NONE with our CmdNo cannot happen; keep waiting (the timeout is the reply's)

    def _on_active(self, sdw: int) -> None:
        pass

    def _done_now(self) -> None:
        """Our job ended DONE and a successor took over: finished without a window to wait for."""
        self._finish(self._DONE)

    def _on_done(self, rec: Any, sdw: int) -> None:
        if self._END != "window":
            if not sdw & _HASJOB:
                self._finish(self._DONE)
            return
        opmode = rec.OpModeDWord
        if sdw & _HASJOB:
            ok = False
        elif opmode & _TGT_MON:
            ok = bool(sdw & _INTARGET)
        elif opmode & _AREA_MON:
            ok = bool(sdw & _INAREA)
        else:
            ok = True
        if ok:
            self._finish(self._DONE)
            return
        ax = self.Axis
        assert ax is not None and ax._task is not None  # (_follow: bound, valid data)
        now = ax._task.now
        if self._done_since is None:
            self._done_since = now
        elif now - self._done_since >= DONE_WINDOW_TIMEOUT:
            self._finish("Error", ErrorCodes.MC_TIMEOUT_AXIS_FB)


_DYN = {"Acceleration": 0.0, "Deceleration": 0.0, "Jerk": 0.0}
_BM = {"BufferMode": int(0)}


class MC_MoveAbsolute(MotionBlock):
    """Absolute positioning (TcMC 3.1; BufferMode and Busy/Active from Tc2_MC2).

    Inputs: Execute, Position [u], Velocity [u/s] (> 0), Acceleration [u/s^2], Deceleration
    [u/s^2], Jerk [u/s^3] (>= 0; 0 = axis default), BufferMode (MC_BufferMode, checked by the NC).
    Outputs: Done, Busy, Active, CommandAborted, Error, ErrorID.
    """

    CMD = "MoveAbsolute"
    _INPUTS = {"Execute": False, "Position": 0.0, "Velocity": 0.0, **_DYN, **_BM}
    Position: float
    Velocity: float
    Acceleration: float
    Deceleration: float
    Jerk: float
    BufferMode: int
    _REALS = ("Position", "Velocity", "Acceleration", "Deceleration", "Jerk")


class MC_MoveRelative(MotionBlock):
    """Relative positioning by Distance [u] (TcMC 3.2): from the set position when it takes
    effect (Buffered/Blending: from the previous command's target, as the NC defines it)."""

    CMD = "MoveRelative"
    _INPUTS = {"Execute": False, "Distance": 0.0, "Velocity": 0.0, **_DYN, **_BM}
    Distance: float
    Velocity: float
    Acceleration: float
    Deceleration: float
    Jerk: float
    BufferMode: int
    _REALS = ("Distance", "Velocity", "Acceleration", "Deceleration", "Jerk")


class MC_MoveAdditive(MotionBlock):
    """Relative positioning from the last commanded target, reached or not (Tc2_MC2 MC_MoveAdditive).

    Inputs: Execute, Distance [u], Velocity [u/s] (> 0), Acceleration, Deceleration, Jerk
    (0 = axis default), BufferMode. Outputs: Done, Busy, Active, CommandAborted, Error, ErrorID.
    Which target the Distance is added to is the NC's (protocol.json MoveAdditive: the target of
    the command it follows, on an axis at rest or in continuous motion the set position); the
    block only follows the command.
    """

    CMD = "MoveAdditive"
    _INPUTS = {"Execute": False, "Distance": 0.0, "Velocity": 0.0, **_DYN, **_BM}
    Distance: float
    Velocity: float
    Acceleration: float
    Deceleration: float
    Jerk: float
    BufferMode: int
    _REALS = ("Distance", "Velocity", "Acceleration", "Deceleration", "Jerk")


class MC_MoveModulo(MotionBlock):
    """Modulo positioning (TcMC 3.4): Position [u] in the modulo period, Direction (MC_Direction), BufferMode."""

    CMD = "MoveModulo"
    _INPUTS = {"Execute": False, "Position": 0.0, "Velocity": 0.0, **_DYN,
               "Direction": int(MC_Direction.MC_Positive_Direction), **_BM}
    Position: float
    Velocity: float
    Acceleration: float
    Deceleration: float
    Jerk: float
    Direction: int
    BufferMode: int
    _REALS = ("Position", "Velocity", "Acceleration", "Deceleration", "Jerk")


def _int_or_invalid(v: Any) -> int:
    """An MC_Direction as int; anything else becomes 0 (the NC rejects it with its code)."""
    try:
        return int(v) if not isinstance(v, (bool, float)) else 0
    except (TypeError, ValueError):
        return 0


class MC_MoveVelocity(MotionBlock):
    """Endless motion at Velocity [u/s] (> 0) in Direction (TcMC 3.3), BufferMode (Tc2_MC2).

    Direction (MC_Direction): MC_Positive_Direction, MC_Negative_Direction, or
    MC_Current_Direction: the direction of the axis's set velocity when the NC accepts the command
    (a running superposition included; buffered: the direction of the job it follows); at rest
    the NC refuses it with 0x4B05, as MC_Shortest_Way (an endless move has no target to be short
    to). The block sends the value; the NC decides.

    Outputs: InVelocity (instead of Done), Busy, Active, CommandAborted, Error, ErrorID.
    InVelocity: the NC shows this command active with ConstantVelocity; the block is then
    finished (Tc2_MC2: no further monitoring).
    """

    CMD = "MoveVelocity"
    _INPUTS = {"Execute": False, "Velocity": 0.0, **_DYN,
               "Direction": int(MC_Direction.MC_Positive_Direction), **_BM}
    _OUTPUTS = {"InVelocity": False, "Busy": False, "Active": False, "CommandAborted": False,
                "Error": False, "ErrorID": 0}
    Velocity: float
    Acceleration: float
    Deceleration: float
    Jerk: float
    Direction: int
    BufferMode: int
    InVelocity: bool
    _DONE = "InVelocity"
    _REALS = ("Velocity", "Acceleration", "Deceleration", "Jerk")
    _END = "velocity"

    def _on_active(self, sdw: int) -> None:
        if sdw & _CONSTV and sdw & _HASJOB:
            self._finish("InVelocity")

    def _on_done(self, rec: Any, sdw: int) -> None:
        # a velocity command only ends by being aborted or taken over; DONE with the axis idle
        # after it would mean it stopped by itself
        self._finish("CommandAborted")


class _MoveContinuous(MotionBlock):
    """MC_MoveContinuousAbsolute/Relative (Tc2_MC2): reach the target with EndVelocity and keep it.

    InEndVelocity (instead of Done): the NC shows this command active with ConstantVelocity and
    a non-zero set velocity, and the set position is at or past the job's target
    (``NcToPlc.TargetPos``) in the direction the axis now moves: the target was passed and the
    axis goes on at its end velocity. zenoh-nc choice: the contract has no bit for "target
    passed", so the block compares SetPos with TargetPos (the NC's target of the active job,
    which also follows MC_NewPos amendments) rather than with its own Position input; the
    magnitude of SetVelo is not compared with EndVelocity (the override scales it).

    After InEndVelocity the block is finished, as Tc2_MC2 documents ("once the target position
    has been reached, the function of the function block is terminated and the axis is no
    longer monitored"): Busy and Active fall, InEndVelocity follows the Done output rules, and
    a later command on the axis (which ends this continuous motion) makes no CommandAborted.
    (PLCopen Part 1 keeps its blocks Busy after InEndVelocity until the motion is aborted;
    we follow Tc2_MC2, as MC_MoveVelocity does for InVelocity.) The command itself stays the
    axis's (continuous) motion until the next command.

    EndVelocity 0: the axis stops at the target and the job ends DONE; then InEndVelocity
    follows the Done rule of appendix 7.1 (target window). A job that ended DONE because a
    buffered/blended successor took over counts as InEndVelocity at once.
    """

    _OUTPUTS = {"InEndVelocity": False, "Busy": False, "Active": False, "CommandAborted": False,
                "Error": False, "ErrorID": 0}
    InEndVelocity: bool
    _DONE = "InEndVelocity"

    def _on_active(self, sdw: int) -> None:
        if not (sdw & _CONSTV and sdw & _HASJOB):
            return
        assert self.Axis is not None  # (_follow checked it)
        rec = self.Axis.NcToPlc
        v = float(rec["SetVelo"])
        if v != 0.0 and (float(rec["SetPos"]) - float(rec["TargetPos"])) * v >= 0.0:
            self._finish("InEndVelocity")


class MC_MoveContinuousAbsolute(_MoveContinuous):
    __doc__ = (
        """Move to Position [u] and go on with EndVelocity [u/s] (Tc2_MC2 MC_MoveContinuousAbsolute).

    Inputs: Execute, Position, Velocity (> 0), EndVelocity (signed, > 0 in the direction of
    travel), Acceleration, Deceleration, Jerk (0 = axis default), BufferMode.
    Outputs: InEndVelocity, Busy, Active, CommandAborted, Error, ErrorID.
    """ + (_MoveContinuous.__doc__ or ""))

    CMD = "MoveContinuousAbsolute"
    _INPUTS = {"Execute": False, "Position": 0.0, "Velocity": 0.0, "EndVelocity": 0.0, **_DYN, **_BM}
    Position: float
    Velocity: float
    EndVelocity: float
    Acceleration: float
    Deceleration: float
    Jerk: float
    BufferMode: int
    _REALS = ("Position", "Velocity", "EndVelocity", "Acceleration", "Deceleration", "Jerk")


class MC_MoveContinuousRelative(_MoveContinuous):
    __doc__ = (
        """Move by Distance [u] and go on with EndVelocity [u/s] (Tc2_MC2 MC_MoveContinuousRelative).

    Inputs: Execute, Distance, Velocity (> 0), EndVelocity (signed, > 0 in the direction of
    travel), Acceleration, Deceleration, Jerk (0 = axis default), BufferMode.
    Outputs: InEndVelocity, Busy, Active, CommandAborted, Error, ErrorID.
    """ + (_MoveContinuous.__doc__ or ""))

    CMD = "MoveContinuousRelative"
    _INPUTS = {"Execute": False, "Distance": 0.0, "Velocity": 0.0, "EndVelocity": 0.0, **_DYN, **_BM}
    Distance: float
    Velocity: float
    EndVelocity: float
    Acceleration: float
    Deceleration: float
    Jerk: float
    BufferMode: int
    _REALS = ("Distance", "Velocity", "EndVelocity", "Acceleration", "Deceleration", "Jerk")


class MC_MoveAbsoluteOrRestart(MotionBlock):
    """Absolute positioning that can be re-triggered while the axis moves (TcMC 3.6).

    Inputs: Execute, Position [u], Velocity [u/s] (> 0), Acceleration, Deceleration, Jerk
    (0 = axis default; the NC uses them only for a start from standstill, a restart keeps the
    running command's dynamics). No BufferMode (neither the manual nor the contract has one).
    Outputs: Done, Busy, Active, CommandAborted, Error, ErrorID (Busy, Active: Tc2_MC2).

    Unlike the general rule, a rising edge of Execute while Busy is not ignored: the block
    latches the inputs again, sends a new ``MoveAbsoluteOrRestart`` (the NC gives it a new
    CmdNo) and follows that one. Its own earlier command is not reported as CommandAborted (the
    block simply stops following it); Active stays TRUE across the restart. If the NC refuses the
    restart, the block shows that Error while the earlier command goes on unfollowed (zenoh-nc
    choice). A rising edge when the block is not Busy starts as MC_MoveAbsolute does.
    """

    CMD = "MoveAbsoluteOrRestart"
    _INPUTS = {"Execute": False, "Position": 0.0, "Velocity": 0.0, **_DYN}
    Position: float
    Velocity: float
    Acceleration: float
    Deceleration: float
    Jerk: float
    _REALS = ("Position", "Velocity", "Acceleration", "Deceleration", "Jerk")
    _RETRIGGER = True


class MC_Halt(MotionBlock):
    """Controlled stop as a normal motion command (no lock; Tc2_MC2 MC_Halt).

    Inputs: Execute, Deceleration [u/s^2], Jerk [u/s^3] (as MC_Stop's: 0 = the effective value of
    the job it stops; buffered: of the job it follows; a lone value used; negative: 0x4230 /
    0x422E), BufferMode.
    Outputs: Done, Busy, Active, CommandAborted, Error, ErrorID. Done at the logical standstill.
    """

    CMD = "Halt"
    _UNDO_ON_LOSS = False  # a stop: nothing to undo
    _INPUTS = {"Execute": False, "Deceleration": 0.0, "Jerk": 0.0, **_BM}
    Deceleration: float
    Jerk: float
    BufferMode: int
    _REALS = ("Deceleration", "Jerk")
    _END = "standstill"


class MC_OrientedStop(MotionBlock):
    """Stop at the next reachable position with the modulo value Position (TcMC 3.16).

    Inputs: Execute, Position [u] (0 <= Position < modulo period; otherwise the NC refuses it
    with 0x4281 and the block reports that), Deceleration, Jerk (not supported by TwinCAT
    either: the NC uses the running command's dynamics; they are sent anyway).
    Outputs: Done, Busy (manual), Active, CommandAborted (Tc2_MC2 outputs added), Error,
    ErrorID. A motion command with its own CmdNo: Done once the job ended and the axis stands
    still at the logical end (as MC_Halt; no target window is awaited), CommandAborted if
    another command took over, Error if the NC ended it with an error (e.g. Position beyond an
    enabled software limit: Busy during the standard stop, then Error 0x4222, TcMC 3.16).
    No BufferMode (neither the manual nor the contract has one).
    """

    CMD = "OrientedStop"
    _UNDO_ON_LOSS = False  # a stop: nothing to undo
    _INPUTS = {"Execute": False, "Position": 0.0, "Deceleration": 0.0, "Jerk": 0.0}
    Position: float
    Deceleration: float
    Jerk: float
    _REALS = ("Position", "Deceleration", "Jerk")
    _END = "standstill"


class MC_Stop(MotionBlock):
    """Stop and lock the axis (TcMC 3.15; see the module docstring for the lock rules).

    Inputs: Execute, Deceleration [u/s^2], Jerk [u/s^3]: 0 = the effective value of the job it
    stops (its input, or the axis default where that was 0; a coupling, external set-points or
    no job: AxisDec/AxisJerk). A lone non-zero value is used with the stopped job's other one
    (zenoh-nc decision; TcMC: "only accepted together"); a negative one is refused by the NC
    (0x4230 / 0x422E) and the axis is not locked. The NC keeps TcMC 3.15's exceptions (never
    weaker than a running stop, never past the target).
    Outputs: Done, Busy, Active, CommandAborted, Error, ErrorID.
    """

    CMD = "Stop"
    _UNDO_ON_LOSS = False  # a stop: nothing to undo
    _INPUTS = {"Execute": False, "Deceleration": 0.0, "Jerk": 0.0}
    Deceleration: float
    Jerk: float
    _REALS = ("Deceleration", "Jerk")
    _END = "standstill"

    def __init__(self, timeout: float | None = None) -> None:
        super().__init__(timeout)
        self._release_at_end = False

    def _start(self) -> None:
        self._release_at_end = False
        super()._start()

    def _cycle(self) -> None:
        ex = bool(self.Execute)
        if self.Busy and self.Done:
            # stopped and locked: wait for Execute to fall, watch for a newer command
            self._prev_execute = ex
            if not ex:
                self._release()
                self._reset_outputs()
                return
            self._watch_locked()
            return
        super()._cycle()

    def _on_execute_fell(self) -> None:
        self._release_at_end = True

    def _on_done(self, rec: Any, sdw: int) -> None:
        if sdw & _HASJOB:
            return
        self.Done = True  # Busy and Active stay TRUE: the axis is locked
        self.Active = True
        if self._release_at_end or not self.Execute:
            # Execute already fell: Done for this one cycle, then unlocked
            self._release()
            self.Busy = self.Active = False

    def _watch_locked(self) -> None:
        if self._lost_axis():
            self.Done = False
            return
        ax = self.Axis
        assert ax is not None
        cmdno = int(ax.NcToPlc["CmdNo"])
        if cmdno != self._cmdno and cmdno_newer(cmdno, self._cmdno):
            self.Done = False
            self._finish("CommandAborted")

    def _release(self) -> None:
        ax = self.Axis
        if ax is None or ax._task is None:
            return
        if ax.nc_epoch == self._epoch and int(ax.NcToPlc["CmdNo"]) == self._cmdno:
            ax._task.detach(ax._task.send(ax, "StopRelease"), f"StopRelease of {ax!r}")
