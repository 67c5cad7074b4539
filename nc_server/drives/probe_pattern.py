"""The simulated touch probe sensor pattern: one rule for ``SimDrive`` and the CiA 402 device (``Cia402Device``).

A sensor pattern of the drive position (SimProbePeriod > 0): the input is TRUE while
``((position - SimProbeOffset) mod SimProbePeriod) < SimProbeWidth`` (marks on a conveyor). Within a cycle the
drive moves linearly, so an edge is found at its exact position.

It may import: numpy.
"""
from __future__ import annotations

import numpy as np


def pattern_level(pos: np.ndarray, period: np.ndarray, offset: np.ndarray, width: np.ndarray) -> np.ndarray:
    """The input level at ``pos`` (all arrays of one length, period > 0)."""
    phase = np.mod(pos - offset, period)
    return (phase < width) | (width >= period)  # (np.mod may round up to period itself)


def first_pattern_edge(falling: np.ndarray, a: np.ndarray, b: np.ndarray, period: np.ndarray,
                       offset: np.ndarray, width: np.ndarray) -> np.ndarray:
    """The first pattern edge of the requested kind passed moving from a to b (a != b), NaN if none.

    The TRUE windows are [s, s + width) with s = offset + n * period. Moving positive the input rises at s and
    falls at s + width; moving negative it rises at s + width (the window is entered from above) and falls at s.
    An edge at x is passed if a < x <= b moving positive and b < x <= a moving negative, which matches the
    half-open windows :func:`pattern_level` evaluates: an edge reached exactly at the end of one cycle is
    reported then (fraction 1), not again in the next. Only 0 < width < period has edges (the caller selects).
    """
    neg = b < a
    base = offset + np.where(falling != neg, width, 0.0)
    n = np.floor((a - base) / period)
    x = base + np.where(neg, n, n + 1.0) * period  # the first such boundary beyond a in the direction of travel
    # rounding of the division may pick the neighbouring boundary: enforce a < x <= a + period (positive),
    # a - period < x <= a (negative)
    up = ~neg
    x = np.where(up & (x <= a), x + period, x)
    x = np.where(up & (x - period > a), x - period, x)
    x = np.where(neg & (x > a), x - period, x)
    x = np.where(neg & (x + period <= a), x + period, x)
    return np.where(np.where(neg, x > b, x <= b), x, np.nan)


def check_probe_signal(index: int, pattern_period: float, offset: float, cycle_time: float) -> float:
    """Check a simulated probe signal change (``set_probe_signal``) of axis ``index``; the offset [s] as a float.

    Raises:
        NotImplementedError: the axis has a sensor pattern (SimProbePeriod > 0), which alone decides its input.
        ValueError: offset outside 0 <= offset < cycle_time [s].
    """
    if pattern_period > 0:
        raise NotImplementedError(f"axis index {index}: its simulated probe input follows the SimProbePeriod sensor "
                                  "pattern")
    offset = float(offset)
    if not 0.0 <= offset < cycle_time:  # (NaN fails too)
        raise ValueError(f"probe signal offset must be in 0 <= offset < {cycle_time:g} s, got {offset:g}")
    return offset


def signal_edges(pending: dict[int, list[tuple[float, bool]]], level: np.ndarray,
                 cycle_time: float) -> dict[int, list[tuple[float, bool]]]:
    """The edges of the simulated probe signal changes of one cycle (``set_probe_signal``): per axis index, in
    time order, (fraction of the cycle, new level); a change to the level the input already has is no edge.
    ``level`` (the inputs' levels, bool per axis) is updated to the level at the cycle's end."""
    edges: dict[int, list[tuple[float, bool]]] = {}
    for i, events in pending.items():
        now, changes = bool(level[i]), []
        for offset, new in sorted(events):  # (the offsets of one axis are distinct)
            if new != now:
                changes.append((offset / cycle_time, new))
                now = new
        level[i] = now
        if changes:
            edges[i] = changes
    return edges
