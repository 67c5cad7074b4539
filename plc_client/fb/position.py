"""Position and reference administration: MC_SetActualPosition, MC_SetActualPositionOnTheFly,
MC_SetReferenceFlag (TcMC manual 4.12, 4.13, 4.15), and F_GetVersionTcMC (5.1).

These are not motion commands: the NC answers them without a job of their own (no CmdNo to
follow), so the blocks end with the reply (zenoh-nc choices where the manual only says "Done:
the command was issued successfully"):

* Done: the NC accepted the command (reply error 0) **and** the axis's snapshot is from the NC
  cycle the reply names or a later one, so a program that sees Done also sees the effect in
  ``Axis.NcToPlc`` (the new ActPos, the Homed bit) in the same cycle;
* Error: the NC's code (e.g. 0x4B01 for MC_SetActualPosition on a moving axis), 0x745 without a
  reply within the timeout, 0x4B0F for stale axis data or an NC restart while waiting, 0x4B06
  for an input value that is not a finite number (not a BOOL for ReferenceFlag), nothing sent;
* CommandAborted (MC_SetActualPosition, MC_SetActualPositionOnTheFly: "the task is
  interrupted") is never set: once accepted, nothing can interrupt the command. The output is
  kept for the interface.

Outputs are the TcMC ones (MC_SetActualPosition: Done, CommandAborted, Error, ErrorID;
MC_SetReferenceFlag: Done, Error, ErrorID; MC_SetActualPositionOnTheFly adds Busy); the
Execute edge rules are those of every Execute block (:mod:`plc_client.fb.base`), and the blocks
without a Busy output still carry a ``Busy`` attribute (the state those rules need).

MC_SetActualPositionOnTheFly sends ``SetActualPositionOnTheFly`` {ActualPosition,
PreviousPosition}: the NC shifts actual position, set position and the running command's target
by ActualPosition - PreviousPosition (the move covers the same distance; the block that started
it ends Done at the shifted target). Whether the NC accepts it on an axis at rest is the NC's
answer (the wire contract calls it an amendment of the active job).

F_GetVersionTcMC(nVersionElement) returns the version of this library: the zenoh-nc package
version (``importlib.metadata``), 1 major, 2 minor, 3 revision; 0 for any other element and
for a missing component.
"""
from __future__ import annotations

import functools
import importlib.metadata
import re
from typing import Any, ClassVar

import numpy as np

from nc_schema import ErrorCodes

from .base import ExecuteBlock


class _AcceptedCommand(ExecuteBlock):
    """An Execute block whose command ends with the NC's acceptance (see the module docstring)."""

    CMD: ClassVar[str] = ""

    def __init__(self, timeout: float | None = None) -> None:
        self.Busy = False
        self.Active = False
        super().__init__(timeout)
        self._cycle_no = 0

    def _request(self) -> dict[str, Any] | None:
        """The command's arguments from the latched inputs; None after finishing with Error."""
        raise NotImplementedError  # pragma: no cover

    def _start(self) -> None:
        self._cycle_no = 0
        args = self._request()
        if args is not None:
            self._send(self.CMD, **args)

    def _progress(self) -> None:
        if self._reply_shown():
            self._finish("Done")


class MC_SetActualPosition(_AcceptedCommand):
    """Set the actual position of an axis at standstill (TcMC 4.12).

    Inputs: Execute, Position [u]. Outputs: Done, CommandAborted, Error, ErrorID.
    """

    CMD = "SetActualPosition"
    _INPUTS: ClassVar[dict[str, Any]] = {"Execute": False, "Position": 0.0}
    _OUTPUTS: ClassVar[dict[str, Any]] = {"Done": False, "CommandAborted": False, "Error": False, "ErrorID": 0}
    Position: float

    def _request(self) -> dict[str, Any] | None:
        if not self._check_inputs(("Position",), buffer_mode=False):
            return None
        return {"Position": float(self.Position)}


class MC_SetActualPositionOnTheFly(_AcceptedCommand):
    """Set the actual position while moving (TcMC 4.13): shift by ActualPosition - PreviousPosition.

    Inputs: Execute, ActualPosition [u], PreviousPosition [u].
    Outputs: Done, Busy, CommandAborted, Error, ErrorID.
    """

    CMD = "SetActualPositionOnTheFly"
    _INPUTS: ClassVar[dict[str, Any]] = {"Execute": False, "ActualPosition": 0.0, "PreviousPosition": 0.0}
    _OUTPUTS: ClassVar[dict[str, Any]] = {"Done": False, "Busy": False, "CommandAborted": False, "Error": False,
                                          "ErrorID": 0}
    ActualPosition: float
    PreviousPosition: float

    def _request(self) -> dict[str, Any] | None:
        if not self._check_inputs(("ActualPosition", "PreviousPosition"), buffer_mode=False):
            return None
        return {"ActualPosition": float(self.ActualPosition), "PreviousPosition": float(self.PreviousPosition)}


class MC_SetReferenceFlag(_AcceptedCommand):
    """Set or clear the axis's "is homed" state, StateDWord.Homed (TcMC 4.15).

    Inputs: Execute, ReferenceFlag (BOOL: TRUE = homed). Outputs: Done, Error, ErrorID.
    """

    CMD = "SetReferenceFlag"
    _INPUTS: ClassVar[dict[str, Any]] = {"Execute": False, "ReferenceFlag": False}
    _OUTPUTS: ClassVar[dict[str, Any]] = {"Done": False, "Error": False, "ErrorID": 0}
    ReferenceFlag: bool

    def _request(self) -> dict[str, Any] | None:
        flag = self.ReferenceFlag
        if not isinstance(flag, (bool, np.bool_)):
            self._finish("Error", ErrorCodes.MC_PARAMETER_NOT_CORRECT)
            return None
        return {"ReferenceFlag": bool(flag)}


@functools.lru_cache(maxsize=1)
def _version() -> tuple[int, int, int]:
    try:
        text = importlib.metadata.version("zenoh-nc")
    except importlib.metadata.PackageNotFoundError:
        return (0, 0, 0)
    parts = []
    for piece in text.split(".")[:3]:
        m = re.match(r"\d+", piece)
        parts.append(int(m.group()) if m else 0)
    while len(parts) < 3:
        parts.append(0)
    return (parts[0], parts[1], parts[2])


def F_GetVersionTcMC(nVersionElement: int) -> int:
    """Library version info (TcMC 5.1): 1 major, 2 minor, 3 revision of the zenoh-nc package; else 0."""
    if isinstance(nVersionElement, bool) or nVersionElement not in (1, 2, 3):
        return 0
    return _version()[int(nVersionElement) - 1]
