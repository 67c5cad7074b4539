"""MC_Jog: moving an axis with manual keys (TcMC manual 3.13; Tc2_MC2 MC_Jog: outputs Busy and
Active, mode MC_JOGMODE_INCHING_MODULO).

Inputs: JogForward, JogBackwards (BOOL keys), Mode (``nc_schema.E_JogMode``), Position [u]
(inching distance), Velocity [u/s], Acceleration [u/s^2], Deceleration [u/s^2], Jerk [u/s^3]
(0 = axis default). Outputs: Done, Busy, Active, CommandAborted, Error, ErrorID.

What the block sends (wire contract, ``schema/protocol.json``):

* a rising edge of a key while the block is not Busy sends ``Jog`` {Mode, Direction, ...}:
  JogForward -> MC_Positive_Direction (1), JogBackwards -> MC_Negative_Direction (3); on
  simultaneous edges JogForward wins (manual). Edges while Busy are ignored - of both keys
  (mutual locking) - and are not remembered: a key already held when the block becomes free
  again needs a new press;
* the mode decides which inputs go with it: MC_JOGMODE_STANDARD_SLOW/FAST send only Mode and
  Direction (the NC uses AxisVeloManSlow/AxisVeloManFast and the axis dynamics; the block's
  Position/Velocity/dynamics are ignored and not checked, as the manual says they need not be
  specified); MC_JOGMODE_CONTINOUS (Tc2_MC2's spelling; ``E_JogMode.MC_JOGMODE_CONTINUOUS`` is the
  same value) sends Velocity and the dynamics (not Position: "no effect");
  MC_JOGMODE_INCHING and MC_JOGMODE_INCHING_MODULO send Position too. The inputs are latched at
  the edge;
* continuous modes (STANDARD_SLOW, STANDARD_FAST, CONTINOUS): when the key that started the
  motion falls, the block sends ``Halt`` and follows that Halt to Done (the logical standstill,
  as MC_Halt). The Halt is sent once the Jog is the axis's active command (Active), never
  before its acceptance, so it cannot overtake the Jog; if the Jog was refused there is nothing
  to stop. The Halt uses the jog's latched Deceleration and Jerk in MC_JOGMODE_CONTINOUS (0 =
  axis defaults, like the jog itself) and the axis defaults in the STANDARD modes ("standard
  dynamics");
* inching modes (INCHING, INCHING_MODULO): the NC moves by Position (INCHING_MODULO: the end is
  rounded to a multiple of Position, Tc2_MC2) and stops by itself; releasing the key changes
  nothing; Done follows the appendix 7.1 rule of the positioning blocks (target window). Position 0
  (the default) moves by the axis's jog increment of the direction, AxisJogIncrementForward /
  AxisJogIncrementBackward (the NC's choice; an increment of 0: 0x4B06).

The command is followed as every motion block follows its own (``MotionBlock``, see
:mod:`plc_client.fb.motion`): Error with the NC's code, CommandAborted when another command
(another block, another client, MC_Stop, ...) takes the axis - also during the block's own
Halt ramp.

Output rules (zenoh-nc choice; the manual only says "Busy ... becomes FALSE when it has
returned to its initial state"): the key that started the command plays the part of
Execute. Done/Error/CommandAborted stay TRUE while that key stays TRUE and are TRUE for
exactly one cycle if it was already released (always so in the continuous modes, where the
release is what ends the motion). Active is TRUE while the Jog is the axis's active command
and during the block's Halt ramp. A result that is still shown is cleared by the next accepted
edge (of either key).

Mode not an E_JogMode value (or not an integer): Error 0x4B04 (MC_INVALID_MODE), nothing sent.
A non-finite Position/Velocity/dynamics value in a mode that uses it: Error 0x4B06. The NC checks
the values themselves (e.g. Velocity <= 0 in CONTINOUS/inching: 0x4221; an inching Position < 0, or Position 0 with a
jog increment of 0: 0x4B06; no enable: 0x4223).
"""
from __future__ import annotations

import numbers
from typing import Any, ClassVar

import numpy as np

from nc_schema import E_JogMode, ErrorCodes, MC_Direction

from .motion import MC_Halt, MotionBlock

_POS = int(MC_Direction.MC_Positive_Direction)
_NEG = int(MC_Direction.MC_Negative_Direction)
_MODES = frozenset(int(m) for m in E_JogMode)
_STANDARD = frozenset({int(E_JogMode.MC_JOGMODE_STANDARD_SLOW), int(E_JogMode.MC_JOGMODE_STANDARD_FAST)})
_CONTINUOUS = _STANDARD | {int(E_JogMode.MC_JOGMODE_CONTINOUS)}
_INCHING = frozenset({int(E_JogMode.MC_JOGMODE_INCHING), int(E_JogMode.MC_JOGMODE_INCHING_MODULO)})
_DYN = ("Acceleration", "Deceleration", "Jerk")


def _jog_mode(v: Any) -> int | None:
    """An E_JogMode value as int, None if ``v`` is none (a bool or a non-integer is none)."""
    if isinstance(v, (bool, np.bool_)) or not isinstance(v, numbers.Integral):
        return None
    return int(v) if int(v) in _MODES else None


class MC_Jog(MotionBlock):
    """Jog an axis with two keys (TcMC 3.13 / Tc2_MC2); see the module docstring.

    Inputs: JogForward, JogBackwards, Mode (E_JogMode, default MC_JOGMODE_STANDARD_SLOW),
    Position [u], Velocity [u/s], Acceleration, Deceleration, Jerk.
    Outputs: Done, Busy, Active, CommandAborted, Error, ErrorID.
    """

    CMD = "Jog"
    _INPUTS: ClassVar[dict[str, Any]] = {
        "JogForward": False, "JogBackwards": False, "Mode": int(E_JogMode.MC_JOGMODE_STANDARD_SLOW),
        "Position": 0.0, "Velocity": 0.0, "Acceleration": 0.0, "Deceleration": 0.0, "Jerk": 0.0,
    }
    JogForward: bool
    JogBackwards: bool
    Mode: int
    Position: float
    Velocity: float
    Acceleration: float
    Deceleration: float
    Jerk: float

    def __init__(self, timeout: float | None = None) -> None:
        super().__init__(timeout)
        #: internal: the level of the key that started the current (or last) command
        self.Execute = False
        self._prev_fw = False
        self._prev_bw = False
        self._dir = 0
        self._mode = int(E_JogMode.MC_JOGMODE_STANDARD_SLOW)
        self._halt: MC_Halt | None = None
        self._halt_wanted = False
        self._halt_args: dict[str, float] = {}

    # -- what MotionBlock sends and how it ends ------------------------------------------
    # [override]: properties where MotionBlock has class constants (the latched jog mode decides)
    @property
    def _REALS(self) -> tuple[str, ...]:  # type: ignore[override]
        if self._mode in _STANDARD:
            return ()
        if self._mode in _INCHING:
            return ("Position", "Velocity", *_DYN)
        return ("Velocity", *_DYN)

    @property
    def _END(self) -> str:  # type: ignore[override]
        # inching: a positioning, Done by the target window; continuous: ends with our Halt
        return "window" if self._mode in _INCHING else "standstill"

    def _args(self) -> dict[str, Any]:
        a: dict[str, Any] = {"Mode": self._mode, "Direction": self._dir}
        a.update({k: float(getattr(self, k)) for k in self._REALS})
        return a

    # -- the cycle -----------------------------------------------------------------------
    def _cycle(self) -> None:
        fw, bw = bool(self.JogForward), bool(self.JogBackwards)
        rise_f, rise_b = fw and not self._prev_fw, bw and not self._prev_bw
        self._prev_fw, self._prev_bw = fw, bw
        if not self.Busy and (rise_f or rise_b):
            self._dir = _POS if rise_f else _NEG  # JogForward has priority
            self._prev_execute = False            # the edge starts the command below
        self.Execute = fw if self._dir == _POS else bw if self._dir == _NEG else False
        super()._cycle()

    def _start(self) -> None:
        self._halt, self._halt_wanted, self._halt_args = None, False, {}
        mode = _jog_mode(self.Mode)
        if mode is None:
            self._finish("Error", ErrorCodes.MC_INVALID_MODE)
            return
        self._mode = mode
        if mode == int(E_JogMode.MC_JOGMODE_CONTINOUS):
            self._halt_args = {"Deceleration": self.Deceleration, "Jerk": self.Jerk}
        super()._start()

    def _on_execute_fell(self) -> None:
        if self._mode in _CONTINUOUS:
            self._halt_wanted = True

    def _progress(self) -> None:
        if self._halt is not None:
            self._follow_halt()
            return
        super()._progress()
        if self.Busy and self._halt_wanted and self.Active:
            self._halt = MC_Halt(self.timeout)
            self._follow_halt()

    def _follow_halt(self) -> None:
        h = self._halt
        assert h is not None
        h(Axis=self.Axis, Execute=True, **self._halt_args)
        if h.Done:
            self._finish("Done")
        elif h.Error:
            self._finish("Error", h.ErrorID)
        elif h.CommandAborted:
            self._finish("CommandAborted")
        else:
            self.Active = True  # our Halt ramp: the axis is still this block's
