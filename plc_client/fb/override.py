"""MC_OverrideFilter (TcMC manual 4.19): a raw override value (e.g. the digits of an analog input terminal)
turned into a filtered override in the PLCTONC scale (0..1000000) and in percent.

Rules (the manual's, with zenoh-nc's choices where it is silent):

* the raw value is limited to [LowerOverrideThreshold, UpperOverrideThreshold] and mapped linearly onto
  0..100 %, in OverrideSteps steps (200: 0.5 %); the step is the nearest one (round half up), so the upper
  threshold gives 100 % and the lower one 0 %;
* after each change of the output a new value is taken only after OverrideRecoveryTime (TIME: seconds, or a
  ``datetime.timedelta``; default 150 ms), measured on the PLC task's clock (``time.monotonic()`` outside a
  task); 0 % and 100 % are taken at once ("for safety reasons"); the first call takes its value at once;
* MC_ERROR_PARAMETER_NOT_CORRECT (0x4B06, MC_PARAMETER_NOT_CORRECT) for OverrideSteps <= 1 or
  LowerOverrideThreshold >= UpperOverrideThreshold (the two cases of the manual), and for inputs that are
  not integers (OverrideValueRaw, the thresholds, OverrideSteps) or a negative/invalid OverrideRecoveryTime:
  Error with ErrorId while the parameters are wrong; the outputs keep the last valid filtered value (a
  program bug must not make the axis jump); correct parameters clear the error.

Outputs have TcMC's names: OverrideValueFiltered (DWORD), OverridePercentFiltered (LREAL), Error, ErrorId
(this block spells it ``ErrorId``; ``ErrorID`` reads the same value). The block has no axis: wire
OverrideValueFiltered into ``Axis.PlcToNc["Override"]`` or OverridePercentFiltered into MC_Power.Override.
"""
from __future__ import annotations

import datetime
import math
import numbers
import time
from typing import Any, ClassVar, Self

import numpy as np

from nc_schema import ErrorCodes

from ..task import current_task
from .base import FunctionBlock

#: PLCTONC Override of 100 %
OVERRIDE_FULL = 1_000_000


def _int(v: Any) -> int | None:
    if isinstance(v, (bool, np.bool_)) or not isinstance(v, numbers.Integral):
        return None
    return int(v)


class MC_OverrideFilter(FunctionBlock):
    """Filter a raw override value (TcMC 4.19; see the module docstring).

    Inputs: OverrideValueRaw (DINT), LowerOverrideThreshold (DINT, 0), UpperOverrideThreshold (DINT, 32767),
    OverrideSteps (UDINT, 200), OverrideRecoveryTime (TIME [s], 0.15).
    Outputs: OverrideValueFiltered (DWORD 0..1000000), OverridePercentFiltered (LREAL 0..100 %), Error, ErrorId.
    """

    _INPUTS: ClassVar[dict[str, Any]] = {"OverrideValueRaw": 0, "LowerOverrideThreshold": 0,
                                         "UpperOverrideThreshold": 32767, "OverrideSteps": 200,
                                         "OverrideRecoveryTime": 0.15}
    _OUTPUTS: ClassVar[dict[str, Any]] = {"OverrideValueFiltered": 0, "OverridePercentFiltered": 0.0,
                                          "Error": False, "ErrorId": 0}
    OverrideValueRaw: int
    LowerOverrideThreshold: int
    UpperOverrideThreshold: int
    OverrideSteps: int
    OverrideRecoveryTime: float | datetime.timedelta
    OverrideValueFiltered: int
    OverridePercentFiltered: float
    Error: bool
    ErrorId: int

    def __init__(self) -> None:
        super().__init__()
        self._changed_at: float | None = None  # when the output last changed (None: never)

    @property
    def ErrorID(self) -> int:
        """The same as ErrorId (the spelling of the other blocks)."""
        return int(self.ErrorId)

    def __call__(self, Axis: Any = None, **inputs: Any) -> Self:
        """Call with the inputs, in any case (no Axis: the block computes only; an Axis passed is ignored)."""
        self._set_inputs(inputs)
        self._cycle()
        return self

    @staticmethod
    def _now() -> float:
        t = current_task()
        return t.now if t is not None else time.monotonic()

    def _recovery(self) -> float | None:
        v = self.OverrideRecoveryTime
        if isinstance(v, datetime.timedelta):
            v = v.total_seconds()
        if isinstance(v, (bool, np.bool_)) or not isinstance(v, numbers.Real) or not math.isfinite(v) or v < 0:
            return None
        return float(v)

    def filtered(self) -> int | None:
        """The filtered value (0..1000000) for the current inputs, ignoring the recovery time; None when the
        parameters are not correct."""
        raw, lo, hi, steps = (_int(self.OverrideValueRaw), _int(self.LowerOverrideThreshold),
                              _int(self.UpperOverrideThreshold), _int(self.OverrideSteps))
        if raw is None or lo is None or hi is None or steps is None or steps <= 1 or lo >= hi:
            return None
        raw = min(max(raw, lo), hi)
        k = (2 * (raw - lo) * steps + (hi - lo)) // (2 * (hi - lo))  # nearest step, exact integer arithmetic
        return (k * OVERRIDE_FULL + steps // 2) // steps

    def _cycle(self) -> None:
        value, recovery = self.filtered(), self._recovery()
        if value is None or recovery is None:
            self.Error, self.ErrorId = True, int(ErrorCodes.MC_PARAMETER_NOT_CORRECT)
            return
        self.Error, self.ErrorId = False, 0
        if value == self.OverrideValueFiltered and self._changed_at is not None:
            return
        now = self._now()
        changed_at = self._changed_at
        if value in (0, OVERRIDE_FULL) or changed_at is None or now - changed_at >= recovery:
            self.OverrideValueFiltered = int(value)
            self.OverridePercentFiltered = value / 10000.0
            self._changed_at = now
