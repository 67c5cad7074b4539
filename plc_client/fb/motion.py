"""Motion function blocks: MC_MoveAbsolute, MC_MoveRelative, MC_MoveModulo, MC_MoveVelocity,
MC_Halt, MC_Stop (TcMC manual 3.1-3.4, 3.15; Tc2_MC2 outputs Busy/Active added).

Following a command through the cyclic interface: the NC's reply carries ``CmdNo`` (the
number the axis shows in NcToPlc.CmdNo while this command is its active one) and ``cycle``
(the NC cycle in which it took effect). The block only evaluates snapshots whose NC cycle
(``Axis.Status.NcCycleCounter``) is >= that cycle; until then it is Busy (not Active). Then:

* ``NcToPlc.CmdNo`` newer than ours (``nc_schema.cmdno_newer``) -> CommandAborted, whoever
  sent the newer command;
* same CmdNo: axis Error bit -> Error with the axis ErrorCode; CmdState ACTIVE -> Busy and
  Active; DONE -> the Done rule below; ABORTED -> CommandAborted; ERROR -> Error with
  NcToPlc.ErrorCode (0x4B00 if the NC already cleared it);
* CmdNo older than ours on a frame that should show it -> Error 0x4B60 (the command
  never became active: the NC lost it);
* stale data -> Error 0x4B0F; an NC restart while following (``AXIS_REF.nc_epoch``
  changed) -> Error 0x4B0F, the new NC instance knows nothing of the command.

Done (TcMC appendix 7.1), from the OpModeDWord monitoring bits the NC publishes:
CmdState DONE (HasJob fell) and

* OpModeTargetPosMonitoring set: InTargetPosition (zenoh-nc: also when position range
  monitoring is off - the manual lists only the three other combinations);
* only OpModePosAreaMonitoring: InPositionArea;
* neither: nothing more.

If the window is not reached 6 s after the logical end (first frame with DONE): Error
0x4B07. Active stays TRUE while waiting for the window (the command is still the axis's
latest). MC_Halt and MC_Stop are Done at the logical standstill (CmdState DONE, no window:
their end position is not a target the program chose).

MC_MoveVelocity: InVelocity when the frame shows our command ACTIVE with ConstantVelocity;
as in Tc2_MC2 the block is then finished ("no further monitoring takes place"): Busy and
Active fall, InVelocity follows the Done output rules.

MC_Stop (PLCopen exception): Done once the stop ramp ended (CmdState DONE), but Busy and
Active stay TRUE while Execute stays TRUE - the axis is locked (MotionCommandsLocked; other
moves get 0x42EF from the NC). On Execute falling the block sends ``StopRelease`` (once the
axis stands still: if Execute falls during the ramp, Done is shown for one cycle at the end
of the ramp and the release follows immediately). A second MC_Stop (newer CmdNo) makes the
first one CommandAborted; then only the newer one releases the lock.
"""
from __future__ import annotations

from typing import Any, ClassVar

from nc_schema import CmdState, ErrorCodes, MC_Direction, OpModeDWord, StateDWord, cmdno_newer

from .base import ExecuteBlock

_ERR = int(StateDWord.Error)
_HASJOB = int(StateDWord.HasJob)
_CONSTV = int(StateDWord.ConstantVelocity)
_INTARGET = int(StateDWord.InTargetPosition)
_INAREA = int(StateDWord.InPositionArea)
_TGT_MON = int(OpModeDWord.OpModeTargetPosMonitoring)
_AREA_MON = int(OpModeDWord.OpModePosAreaMonitoring)

#: TcMC appendix 7.1: the window must be reached within this time after the logical end [s].
DONE_WINDOW_TIMEOUT = 6.0


class MotionBlock(ExecuteBlock):
    """A motion command followed through (CmdNo, CmdState); see the module docstring."""

    CMD: ClassVar[str] = ""
    _REALS: ClassVar[tuple[str, ...]] = ()
    #: "window": appendix 7.1 Done; "standstill": CmdState DONE; "velocity": InVelocity
    _END: ClassVar[str] = "window"

    def __init__(self, timeout: float | None = None) -> None:
        super().__init__(timeout)
        self._cmdno = 0
        self._cmd_cycle = 0
        self._done_since: float | None = None

    def _args(self) -> dict[str, Any]:
        """The command's arguments: the latched real inputs, and Direction where the block has one."""
        a: dict[str, Any] = {k: float(getattr(self, k)) for k in self._REALS}
        if "Direction" in self._INPUTS:
            a["Direction"] = _int_or_invalid(self.Direction)  # type: ignore[attr-defined]
        return a

    def _start(self) -> None:
        self._cmdno, self._cmd_cycle, self._done_since = 0, 0, None
        if not self._check_inputs(self._REALS, buffer_mode="BufferMode" in self._INPUTS):
            return
        self._send(self.CMD, **self._args())

    def _progress(self) -> None:
        if not self._cmdno:
            if self._lost_axis():
                return
            reply = self._await_reply()
            if reply is None:
                return
            cmdno = int(reply.get("CmdNo", 0))
            if not cmdno:
                self._finish("Error", ErrorCodes.MC_CMD_NUMBER_ZERO)
                return
            self._cmdno, self._cmd_cycle = cmdno, int(reply.get("cycle", 0))
            self._pending = None
        self._follow()

    def _lost_axis(self) -> bool:
        """Finish with Error if the axis data is stale/missing or the NC restarted."""
        ax = self.Axis
        code = self._axis_problem()
        if not code and ax is not None and ax.nc_epoch != self._epoch:
            code = ErrorCodes.MC_NO_NC_CYCLE_UPDATE
        if code:
            self._finish("Error", code)
            return True
        return False

    def _follow(self) -> None:
        if self._lost_axis():
            return
        ax = self.Axis
        assert ax is not None
        if ax.Status.NcCycleCounter < self._cmd_cycle:
            return  # the frame does not show the command's effect yet
        rec = ax.NcToPlc
        cmdno, state, sdw = int(rec["CmdNo"]), int(rec["CmdState"]), int(rec["StateDWord"])
        if cmdno != self._cmdno:
            if cmdno_newer(cmdno, self._cmdno):
                self._finish("CommandAborted")
            else:
                self._finish("Error", ErrorCodes.MC_CMD_NOT_ACTIVE)
            return
        if sdw & _ERR or state == CmdState.ERROR:
            self._finish("Error", int(rec["ErrorCode"]) or ErrorCodes.MC_AXIS_STOPPED)
        elif state == CmdState.ABORTED:
            self._finish("CommandAborted")
        elif state == CmdState.ACTIVE:
            self.Active = True
            self._on_active(sdw)
        elif state == CmdState.DONE:
            self.Active = True
            self._on_done(rec, sdw)
        # CmdState NONE with our CmdNo cannot happen; keep waiting (the timeout is the reply's)

    def _on_active(self, sdw: int) -> None:
        pass

    def _on_done(self, rec: Any, sdw: int) -> None:
        if self._END != "window":
            if not sdw & _HASJOB:
                self._finish(self._DONE)
            return
        opmode = int(rec["OpModeDWord"])
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
        now = self.Axis._task.now  # type: ignore[union-attr]
        if self._done_since is None:
            self._done_since = now
        elif now - self._done_since >= DONE_WINDOW_TIMEOUT:
            self._finish("Error", ErrorCodes.MC_TIMEOUT_AXIS_FB)


_DYN = {"Acceleration": 0.0, "Deceleration": 0.0, "Jerk": 0.0}


class MC_MoveAbsolute(MotionBlock):
    """Absolute positioning (TcMC 3.1).

    Inputs: Execute, Position [u], Velocity [u/s] (> 0), Acceleration [u/s^2], Deceleration
    [u/s^2], Jerk [u/s^3] (>= 0; 0 = axis default), BufferMode (only MC_Aborting = 0).
    Outputs: Done, Busy, Active, CommandAborted, Error, ErrorID.
    """

    CMD = "MoveAbsolute"
    _INPUTS = {"Execute": False, "Position": 0.0, "Velocity": 0.0, **_DYN, "BufferMode": 0}
    _REALS = ("Position", "Velocity", "Acceleration", "Deceleration", "Jerk")


class MC_MoveRelative(MotionBlock):
    """Relative positioning by Distance [u] from the set position when it takes effect (TcMC 3.2)."""

    CMD = "MoveRelative"
    _INPUTS = {"Execute": False, "Distance": 0.0, "Velocity": 0.0, **_DYN, "BufferMode": 0}
    _REALS = ("Distance", "Velocity", "Acceleration", "Deceleration", "Jerk")


class MC_MoveModulo(MotionBlock):
    """Modulo positioning (TcMC 3.4): Position [u] in the modulo period, Direction (MC_Direction)."""

    CMD = "MoveModulo"
    _INPUTS = {"Execute": False, "Position": 0.0, "Velocity": 0.0, **_DYN,
               "Direction": int(MC_Direction.MC_Positive_Direction), "BufferMode": 0}
    _REALS = ("Position", "Velocity", "Acceleration", "Deceleration", "Jerk")


def _int_or_invalid(v: Any) -> int:
    """An MC_Direction as int; anything else becomes 0 (the NC rejects it with its code)."""
    try:
        return int(v) if not isinstance(v, (bool, float)) else 0
    except (TypeError, ValueError):
        return 0


class MC_MoveVelocity(MotionBlock):
    """Endless motion at Velocity [u/s] (> 0) in Direction (TcMC 3.3).

    Outputs: InVelocity (instead of Done), Busy, Active, CommandAborted, Error, ErrorID.
    InVelocity: the NC shows this command active with ConstantVelocity; the block is then
    finished (Tc2_MC2: no further monitoring).
    """

    CMD = "MoveVelocity"
    _INPUTS = {"Execute": False, "Velocity": 0.0, **_DYN,
               "Direction": int(MC_Direction.MC_Positive_Direction), "BufferMode": 0}
    _OUTPUTS = {"InVelocity": False, "Busy": False, "Active": False, "CommandAborted": False,
                "Error": False, "ErrorID": 0}
    _DONE = "InVelocity"
    _REALS = ("Velocity", "Acceleration", "Deceleration", "Jerk")
    _END = "velocity"

    def _on_active(self, sdw: int) -> None:
        if sdw & _CONSTV and sdw & _HASJOB:
            self._finish("InVelocity")

    def _on_done(self, rec: Any, sdw: int) -> None:
        # a velocity command only ends by being aborted; DONE would mean it stopped by itself
        self._finish("CommandAborted")


class MC_Halt(MotionBlock):
    """Controlled stop as a normal motion command (no lock; Tc2_MC2 MC_Halt).

    Inputs: Execute, Deceleration [u/s^2], Jerk [u/s^3] (0 = axis default), BufferMode.
    Done at the logical standstill.
    """

    CMD = "Halt"
    _INPUTS = {"Execute": False, "Deceleration": 0.0, "Jerk": 0.0, "BufferMode": 0}
    _REALS = ("Deceleration", "Jerk")
    _END = "standstill"


class MC_Stop(MotionBlock):
    """Stop and lock the axis (TcMC 3.15; see the module docstring for the lock rules).

    Inputs: Execute, Deceleration [u/s^2], Jerk [u/s^3] (0 = axis default; a non-zero value
    counts only together with the other: a lone one is ignored and the axis defaults apply).
    Outputs: Done, Busy, Active, CommandAborted, Error, ErrorID.
    """

    CMD = "Stop"
    _INPUTS = {"Execute": False, "Deceleration": 0.0, "Jerk": 0.0}
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
