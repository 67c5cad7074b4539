"""External set-point generator: MC_ExtSetPointGenEnable, MC_ExtSetPointGenDisable (blocks) and
MC_ExtSetPointGenFeed (a function) (TcMC manual 4.16-4.18).

While the external set-point generator of an axis is enabled, the NC takes the axis's set-points
from its cyclic interface, the PLCTONC fields ExtSetPos, ExtSetVelo, ExtSetAcc and
ExtSetDirection (TcMC: fExtSetPos, fExtSetVelo, fExtSetAcc, nExtSetDirection). Those fields
reach the NC only in the PLCTONC frame of the client that holds the axis: **the program feeding
the set-points must be the one running the axis's MC_Power** (``AXIS_REF.controlled``). The
blocks write into ``Axis.PlcToNc``; the task publishes it at the end of the cycle.

MC_ExtSetPointGenEnable, at the rising edge of Execute, first writes ExtSetPos := the axis's
current NCTOPLC SetPos and ExtSetVelo := ExtSetAcc := ExtSetDirection := 0, then sends
``ExtSetPointGenEnable`` {Position, PositionType}: the first set-point the NC takes from the
interface is where the axis already is (no jump, even if the program feeds its first value a
cycle later). On an axis whose generator is already enabled (StateDWord ExtSetPointGenEnabled) it
writes nothing: the values there are the PLC generator's feed (the NC answers the command: its
0x4B08 refusal of a second enable is zenoh-nc's choice). Position is the target of the NC's
target position monitoring (InTargetPosition), not a motion target; PositionType is E_TargPosType (1 absolute, 2 relative, 5 modulo).

Both blocks: Done once the NC accepted the command and a frame of the reply's cycle (or a later
one) arrived, so ``Enabled`` already shows the new state in the cycle Done comes; Error with
the NC's code (e.g. 0x4B01: enabling while a command moves the axis), 0x4B0F for stale data.
Outputs: TcMC's Done, Error, ErrorID, Enabled, plus Busy (as the other Execute blocks: TRUE from
the edge until the result; the output rules need it). **Enabled** is StateDWord
ExtSetPointGenEnabled of the axis in every cycle, independent of Execute (FALSE while the axis
data is not valid). Input checks, nothing written or sent on failure: Position not a finite
number -> 0x4B06; PositionType not one of 1, 2, 5 -> 0x4B04.

MC_ExtSetPointGenFeed(Position, Velocity, Acceleration, Direction, AxisRefOut) copies the values
into AxisRefOut's ExtSetPos, ExtSetVelo, ExtSetAcc, ExtSetDirection at once and returns FALSE
(TcMC: the result is unused). AxisRefOut is the axis's PLCTONC record (``ax.PlcToNc``, TcMC's
PLCTONC_AXLESTRUCT) or the AXIS_REF itself. zenoh-nc choice: a set of values with a member that
is not a finite number (or a Direction that is not -1, 0 or 1) is not written at all - the
interface keeps the last consistent set-point, so a NaN never reaches the NC (which would stop
the axis with 0x4359) - and the function still returns FALSE.
"""
from __future__ import annotations

import numpy as np

from nc_schema import E_TargPosType, ErrorCodes, PLCTONC_DTYPE, StateDWord

from ..axis_ref import AXIS_REF
from ..records import PLCTONC_AXIS_REF
from .base import ExecuteBlock, FunctionBlock
from .coupling import _integer_in


_EXT = int(StateDWord.ExtSetPointGenEnabled)
_POS_TYPES = frozenset(int(m) for m in E_TargPosType)


class _ExtSetPointBlock(ExecuteBlock):
    """Done once the command's frame is shown; ``Enabled`` every cycle (see the module docstring)."""

    _OUTPUTS = {"Done": False, "Busy": False, "Error": False, "ErrorID": 0, "Enabled": False}
    Enabled: bool

    def _cycle(self) -> None:
        super()._cycle()
        ax = self.Axis
        self._task()  # bind the axis, so Enabled shows its state before any Execute
        self.Enabled = bool(ax is not None and ax.Status.Valid and int(ax.NcToPlc["StateDWord"]) & _EXT)

    def _progress(self) -> None:
        if self._reply_shown():
            self._finish("Done")


class MC_ExtSetPointGenEnable(_ExtSetPointBlock):
    """Switch the axis to the external set-point generator (TcMC 4.16).

    Inputs: Execute, Position [u] (target position monitoring), PositionType (E_TargPosType,
    default POS_ABSOLUTE). Outputs: Done, Busy, Error, ErrorID, Enabled. VAR_IN_OUT: Axis.
    """

    _INPUTS = {"Execute": False, "Position": 0.0, "PositionType": 1}
    Position: float
    PositionType: int

    def _start(self) -> None:
        self._cycle_no = 0
        if not self._is_real(self.Position):
            self._finish("Error", ErrorCodes.MC_PARAMETER_NOT_CORRECT)
            return
        pt = _integer_in(self.PositionType, min(_POS_TYPES), max(_POS_TYPES))
        if pt is None or pt not in _POS_TYPES:
            self._finish("Error", ErrorCodes.MC_INVALID_MODE)
            return
        ax = self._usable_axis()
        if ax is None:
            return
        # the first set-point the NC takes is where the axis is: no jump. Not on an axis whose generator is
        # already enabled: the PLC's generator feeds it, and a seed at velocity 0 would be a velocity step
        # of a moving axis (0x4359)
        if not int(ax.NcToPlc["StateDWord"]) & _EXT:
            out = ax.PlcToNc
            out["ExtSetPos"] = float(ax.NcToPlc["SetPos"])
            out["ExtSetVelo"] = 0.0
            out["ExtSetAcc"] = 0.0
            out["ExtSetDirection"] = 0
        self._send("ExtSetPointGenEnable", Position=float(self.Position), PositionType=pt)


class MC_ExtSetPointGenDisable(_ExtSetPointBlock):
    """Switch the axis back to the NC's own set-point generator (TcMC 4.17).

    Inputs: Execute. Outputs: Done, Busy, Error, ErrorID, Enabled. VAR_IN_OUT: Axis. A moving
    axis brakes from its set-point state (the NC's Halt ramp).
    """

    def _start(self) -> None:
        self._cycle_no = 0
        self._send("ExtSetPointGenDisable")


def MC_ExtSetPointGenFeed(Position: float, Velocity: float, Acceleration: float, Direction: int,
                          AxisRefOut: PLCTONC_AXIS_REF | np.void | AXIS_REF) -> bool:
    """Feed one external set-point into the axis's PLCTONC interface (TcMC 4.18); returns FALSE.

    Args:
        Position: set position [u].
        Velocity: set velocity [u/s].
        Acceleration: set acceleration [u/s^2].
        Direction: -1 negative, 0 standstill, 1 positive.
        AxisRefOut: the axis's PLCTONC record (``ax.PlcToNc``) or its AXIS_REF.

    Values that are not finite numbers, or a Direction other than -1/0/1, leave the interface
    unchanged (see the module docstring).

    Raises:
        TypeError: AxisRefOut is neither a PLCTONC record nor an AXIS_REF (a program bug).
    """
    out = AxisRefOut.PlcToNc if isinstance(AxisRefOut, AXIS_REF) else AxisRefOut
    if not isinstance(out, PLCTONC_AXIS_REF) and not (isinstance(out, np.void) and out.dtype == PLCTONC_DTYPE):
        raise TypeError(f"MC_ExtSetPointGenFeed: AxisRefOut must be an AXIS_REF or its PlcToNc record, "
                        f"got {type(AxisRefOut).__name__}")
    real = FunctionBlock._is_real
    direction = _integer_in(Direction, -1, 1)
    if real(Position) and real(Velocity) and real(Acceleration) and direction is not None:
        out["ExtSetPos"] = float(Position)
        out["ExtSetVelo"] = float(Velocity)
        out["ExtSetAcc"] = float(Acceleration)
        out["ExtSetDirection"] = direction
    return False
