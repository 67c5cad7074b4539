"""Blocks that amend the axis's active command instead of starting one: MC_NewPos (TcMC 3.7),
MC_NewPosAndVelo (3.8) and MC_ChangeDynParam (4.20).

The NC gives an amendment no CmdNo of its own: ``NewPos``, ``NewPosAndVelo`` and
``ChangeDynParam`` change the active job (NCJOBS.Flags.Amended, StateDWord.NewTargetPos) and
reply with *its* CmdNo; an axis without a moving job to amend refuses them with 0x4B03. The
block that started the job goes on following it and ends Done at the new target.

Choices where the manuals are silent (zenoh-nc):

* Outputs: the manual's (Done, CommandAborted, Error, ErrorID; MC_ChangeDynParam: Done, Error,
  ErrorID) plus Busy (Tc2_MC2; TRUE from the Execute edge until the block has a result).
  MC_ChangeDynParam also gets CommandAborted. None of them has Active: an amendment never
  controls the axis, the block that started the job does.
* The general output rules hold (inputs latched at the Execute edge, results held while Execute
  stays TRUE, one cycle if it fell earlier, a rising edge while Busy ignored) except where a
  block says otherwise.
* Input values that are not finite numbers are refused locally with 0x4B06, nothing is sent.
"""
from __future__ import annotations

from typing import Any, ClassVar

from nc_schema import E_CmdTypeNewTargPosAndVelo, ErrorCodes, StateDWord

from .base import ExecuteBlock
from .motion import MotionBlock, _wire_int

_HASJOB = int(StateDWord.HasJob)
_CONSTV = int(StateDWord.ConstantVelocity)
_CONTM = int(StateDWord.ContinuousMotion)


class _AmendBlock(ExecuteBlock):
    """Send an amendment; Done when the NC accepted it ("if the command was issued successfully")."""

    CMD: ClassVar[str] = ""
    _REALS: ClassVar[tuple[str, ...]] = ()
    _OUTPUTS = {"Done": False, "Busy": False, "CommandAborted": False, "Error": False, "ErrorID": 0}

    def _args(self) -> dict[str, Any] | None:
        return {k: float(getattr(self, k)) for k in self._REALS}

    def _start(self) -> None:
        if not self._check_inputs(self._REALS, buffer_mode=False):
            return
        args = self._args()
        if args is None:
            return
        self._send(self.CMD, **args)

    def _progress(self) -> None:
        if self._await_reply() is not None:
            self._finish("Done")


class MC_NewPos(_AmendBlock):
    """A new target position for the axis's running discrete motion (TcMC 3.7).

    Inputs: Execute, NewPos [u] (greater or smaller than the old target).
    Outputs: Done, Busy, CommandAborted, Error, ErrorID.

    Done (manual: "if the command was issued successfully") as soon as the NC's reply accepted
    it; the amended job keeps its CmdNo, so the block that started it (MC_MoveAbsolute, ...)
    ends Done at the new target. Error with the NC's code otherwise (0x4B03: no moving position
    command to amend). CommandAborted ("if the task is interrupted") is never set by this
    implementation: the amendment takes effect in the cycle of the reply, so there is nothing
    left to interrupt once it was accepted (zenoh-nc choice).
    """

    CMD = "NewPos"
    _INPUTS = {"Execute": False, "NewPos": 0.0}
    NewPos: float
    _REALS = ("NewPos",)


class MC_NewPosAndVelo(_AmendBlock):
    """A new target position and/or velocity for the axis's running motion (TcMC 3.8).

    Inputs: Execute, Mode (E_CmdTypeNewTargPosAndVelo: CHANGE_POS 1, CHANGE_VELO 2,
    CHANGE_POSANDVELO 3, *_AT_SWITCHPOS 9/10/11 at ActivationPos, REACH_VELO_AT_POS 14),
    NewPos [u], NewVelo [u/s], ActivationPos [u].
    Outputs: Done, Busy, CommandAborted, Error, ErrorID.

    Done as soon as the NC accepted it (manual: "if the command was issued successfully"; also
    for the switching-position modes, whose change happens later at ActivationPos - the block
    does not wait for it). The switching-position modes work on positionings and on
    MC_MoveVelocity (the change applies when the set position passes ActivationPos in the
    direction of travel); an ActivationPos already passed is refused by the NC with 0x427F. Mode defaults to CHANGE_POSANDVELO (3), as protocol.json does
    (zenoh-nc choice: the manual gives no default). A Mode that is not an integer is refused
    locally with 0x4B06; which integers are valid is the NC's decision. CommandAborted is never
    set (see MC_NewPos).
    """

    CMD = "NewPosAndVelo"
    _INPUTS = {"Execute": False, "Mode": int(E_CmdTypeNewTargPosAndVelo.CHANGE_POSANDVELO), "NewPos": 0.0,
               "NewVelo": 0.0, "ActivationPos": 0.0}
    Mode: int
    NewPos: float
    NewVelo: float
    ActivationPos: float
    _REALS = ("NewPos", "NewVelo", "ActivationPos")

    def _args(self) -> dict[str, Any] | None:
        mode = _wire_int(self.Mode)
        if mode is None:
            self._finish("Error", ErrorCodes.MC_PARAMETER_NOT_CORRECT)
            return None
        reals = super()._args()
        assert reals is not None  # (_AmendBlock's are always there)
        return {"Mode": mode, **reals}


class MC_ChangeDynParam(MotionBlock):
    """New acceleration, deceleration and jerk for the active positioning (TcMC 4.20).

    Inputs: Execute, Acceleration [u/s^2], Deceleration [u/s^2], Jerk [u/s^3] (>= 0; 0 = the
    axis default). Outputs: Done, Busy, CommandAborted, Error, ErrorID (Busy and
    CommandAborted added; no Active, see the module docstring).

    The NC refuses a change it cannot make safely (0x427F target would be passed, 0x425D a
    harder stop already runs, 0x423A velocity would be exceeded, 0x4289 direction would
    reverse) and keeps the dynamics; the block shows that Error.

    Done: as the manual says, "when the axis is at its destination and all monitoring
    activities (such as destination position monitoring) are positive" - not on the reply
    alone (MC_NewPos/MC_NewPosAndVelo's "issued successfully" is not this block's text). The
    reply names the amended job (its CmdNo) and the block follows that job like the move block
    that started it: Done by the Done rule of appendix 7.1 when it ends (at once if a
    buffered successor took over), CommandAborted if it is aborted, Error if it ends with an
    error. zenoh-nc choice for a job in continuous motion (MC_MoveVelocity, MC_MoveContinuous*
    after the target), which has no destination: Done once the frame shows it at constant
    velocity (the new dynamics have done their work).

    "The block can be re-triggered during the movement": a rising edge of Execute while Busy
    sends the new inputs at once and follows that request's reply instead (no CommandAborted
    for the earlier one).
    """

    CMD = "ChangeDynParam"
    _UNDO_ON_LOSS = False  # it amends another block's job
    _INPUTS = {"Execute": False, "Acceleration": 0.0, "Deceleration": 0.0, "Jerk": 0.0}
    _OUTPUTS = {"Done": False, "Busy": False, "CommandAborted": False, "Error": False, "ErrorID": 0}
    Acceleration: float
    Deceleration: float
    Jerk: float
    _REALS = ("Acceleration", "Deceleration", "Jerk")
    _RETRIGGER = True

    def _on_active(self, sdw: int) -> None:
        if sdw & _CONTM and sdw & _CONSTV and sdw & _HASJOB:
            self._finish("Done")
