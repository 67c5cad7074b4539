"""Touch probe (MC_TouchProbe, TcMC 4.21 / 6.3): the checks of a trigger definition and of the window.

Pure functions of their arguments (no NC core state), used by the NC's touch probe cycle: the drive's
latch (``DriveABC.latch_probe``) reports positions, these decide whether one is accepted.
"""
from __future__ import annotations

import math
from numbers import Integral

from nc_schema import ENUMS, ErrorCodes, NcError

#: E_TouchProbe / E_SignalEdge values (schema/enums.json)
TOUCH_PROBE_1: int = ENUMS["E_TouchProbe"]["values"]["TouchProbe1"]
PLC_EVENT: int = ENUMS["E_TouchProbe"]["values"]["PlcEvent"]
RISING_EDGE: int = ENUMS["E_SignalEdge"]["values"]["RisingEdge"]
FALLING_EDGE: int = ENUMS["E_SignalEdge"]["values"]["FallingEdge"]


def modulo_position(pos: float, period: float) -> float:
    """``pos`` in the modulo range [0, period) [u] (also for negative positions).

    Raises:
        ValueError: period <= 0 or not finite.
    """
    if not (period > 0 and math.isfinite(period)):
        raise ValueError(f"modulo period must be > 0 and finite, got {period}")
    p = pos % period
    return 0.0 if p >= period else p  # -1e-20 % 360 rounds up to 360.0


def in_window(pos: float, first: float, last: float, modulo: bool, period: float) -> bool:
    """Whether a recorded position lies in the MC_TouchProbe window (WindowOnly), boundaries included.

    Absolute (``modulo`` False, TriggerInput.ModuloPositions FALSE): the one window
    first <= pos <= last [u]; first > last is an empty window (nothing is inside: TcMC shows a
    wrapping window only for modulo positions). ``period`` is not used.

    Modulo: the window repeats every ``period`` [u]; with p = pos mod period in [0, period):
    first <= last: first <= p <= last (TcMC figure A); first > last: p >= first or p <= last, the
    window wraps through 0 (figure B). ``first`` and ``last`` are compared as given, i.e. modulo
    values in [0, period) as TcMC expects them (a last >= period covers the rest of the cycle).

    A NaN position is never inside.

    Raises:
        ValueError: modulo with period <= 0 or not finite.
    """
    if not modulo:
        return first <= pos <= last
    p = modulo_position(pos, period)
    if first <= last:
        return first <= p <= last
    return p >= first or p <= last


def check_trigger_input(encoder_id: int, touch_probe: int, edge: int) -> None:
    """Check an MC_InputRef trigger definition the NC's latch can serve.

    Args:
        encoder_id: MC_InputRef.EncoderID, 1..255.
        touch_probe: MC_InputRef.TouchProbe (E_TouchProbe): only TouchProbe1 (1). TouchProbe2..4 are
            "not supported at present" in TcMC; PlcEvent (10) is cycle-time dependent and evaluated by
            the PLC function block itself, so it never reaches the NC.
        edge: MC_InputRef.Edge (E_SignalEdge): 0 = rising, 1 = falling.

    Raises:
        NcError: 0x4B0B (MC_TRIGGER_INPUT_INVALID) naming the offending field.
    """
    def bad(message: str) -> NcError:
        return NcError(ErrorCodes.MC_TRIGGER_INPUT_INVALID, message)

    if not _is_int(encoder_id) or not 1 <= encoder_id <= 255:
        raise bad(f"TriggerInput.EncoderID must be 1..255, got {encoder_id!r}")
    if not _is_int(touch_probe) or touch_probe != TOUCH_PROBE_1:
        if _is_int(touch_probe) and touch_probe == PLC_EVENT:
            raise bad("TriggerInput.TouchProbe PlcEvent (10) is evaluated by the PLC function block, not by the NC")
        raise bad(f"TriggerInput.TouchProbe must be TouchProbe1 (1), got {touch_probe!r}"
                  " (TouchProbe2..4 are not supported)")
    if not _is_int(edge) or edge not in (RISING_EDGE, FALLING_EDGE):
        raise bad(f"TriggerInput.Edge must be RisingEdge (0) or FallingEdge (1), got {edge!r}")


def _is_int(value: object) -> bool:
    """An integer (also numpy's), but not a bool: True is no EncoderID."""
    return isinstance(value, Integral) and not isinstance(value, bool)
