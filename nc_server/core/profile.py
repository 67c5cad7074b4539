"""Jerk-limited set-point profiles as constant-jerk segment rows, evaluated for all axes at once.

A profile (planned once per command by :mod:`.planning`) is a row of constant-jerk segments
(ruckig's brake pre-profile, its 7 phases, an optional post-profile, then a tail that keeps the
final velocity). Each NC cycle evaluates every axis's row with a handful of numpy operations --
no per-axis Python loop, no per-axis ruckig call in the cycle.
"""
from __future__ import annotations

import math

import numpy as np

#: segments per axis: brake (2) + main (7) + post (2) + tail (1) + a sentinel that never starts
N_SEGMENTS = 13


def integrate_segment(t: float, p: float, v: float, a: float, j: float) -> tuple[float, float, float]:
    """(p, v, a) after ``t`` seconds of constant jerk ``j`` from (p, v, a)."""
    return p + t * (v + t * (a / 2 + t * j / 6)), v + t * (a + t * j / 2), a + t * j


def evaluate(seg: np.ndarray, t: np.ndarray, rows: np.ndarray | None) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Evaluate the segment rows ``rows`` (None: all) at their times ``t`` (vectorized).

    Args:
        seg: (5, N, N_SEGMENTS) table of all axes: t0, p, v, a, j.
        t: time since the profile start [s], one per selected row.
        rows: indices of the axes to evaluate, or None for all axes.

    Returns:
        position, velocity, acceleration, jerk arrays.
    """
    t0_all = seg[0] if rows is None else seg[0, rows]
    # the segment in force is the one before the first that starts later (the sentinel never starts)
    k = np.argmax(t0_all > t[:, None], axis=1) - 1
    np.maximum(k, 0, out=k)
    flat = (np.arange(len(t)) if rows is None else rows) * N_SEGMENTS + k
    t0, p0, v0, a0, j = seg.reshape(5, -1)[:, flat]  # one gather for all five columns
    tau = t - t0
    pos = p0 + tau * (v0 + tau * (a0 * 0.5 + tau * j * (1.0 / 6.0)))
    velo = v0 + tau * (a0 + tau * j * 0.5)
    acc = a0 + tau * j
    return pos, velo, acc, j


def evaluate_block(seg: np.ndarray, t: np.ndarray, rows: np.ndarray | slice, base: np.ndarray,
                   out: np.ndarray) -> None:
    """Evaluate the segment rows ``rows`` at a block of times each, into ``out`` (the profile stage's refill).

    The same arithmetic as :func:`evaluate` (bit for bit), shaped for many samples per row: the
    segment search compares each row's segment starts once against all its sample times.

    Args:
        seg: (5, N, N_SEGMENTS) table of all axes: t0, p, v, a, j.
        t: (m, ncol) times since the profile start [s] (> 0), one row per selected axis.
        rows: the m selected axis rows (an index array or a slice).
        base: ``rows * N_SEGMENTS`` as an (m, 1) array (the row offsets into the flat table).
        out: (4, m, ncol) array receiving position, velocity, acceleration, jerk.
    """
    # the segment in force is the one before the first that starts later: with t0[0] = 0 <= t that
    # is the first of t0[1:] that starts later (the sentinel never starts) -- evaluate()'s k exactly
    k = np.argmax(seg[0, rows, 1:][:, None, :] > t[:, :, None], axis=2)
    k += base
    t0, p0, v0, a0, j = seg.reshape(5, -1)[:, k]  # one gather for all five columns, (m, ncol) each
    tau = t - t0
    tj = tau * j
    pos, velo, acc, jerk = out
    np.multiply(tj, 1.0 / 6.0, out=pos)  # p0 + tau * (v0 + tau * (a0 * 0.5 + tau * j * (1 / 6)))
    pos += a0 * 0.5
    pos *= tau
    pos += v0
    pos *= tau
    pos += p0
    np.multiply(tj, 0.5, out=velo)  # v0 + tau * (a0 + tau * j * 0.5)
    velo += a0
    velo *= tau
    velo += v0
    np.add(a0, tj, out=acc)
    jerk[...] = j


def velocity_extrema(seg: np.ndarray) -> tuple[float, float]:
    """(lowest, highest) signed velocity of one axis's segment row (5, N_SEGMENTS) over the whole profile.

    Plain Python: 13 segments are cheaper to walk than to hand to numpy.
    """
    t0, _, v, a, j = seg.tolist()
    lo = hi = v[0]
    for k in range(N_SEGMENTS):
        if t0[k] == math.inf:
            break
        lo, hi = min(lo, v[k]), max(hi, v[k])
        jk = j[k]
        if jk:
            tau = -a[k] / jk  # velocity extremum inside the segment where a + j*tau = 0
            end = t0[k + 1] if k + 1 < N_SEGMENTS else math.inf
            if 0 < tau < end - t0[k]:
                ve = v[k] - a[k] * a[k] / (2 * jk)
                lo, hi = min(lo, ve), max(hi, ve)
    return lo, hi


def peak_velocity(seg: np.ndarray) -> float:
    """Largest |velocity| of one axis's segment row (5, N_SEGMENTS) over the whole profile."""
    lo, hi = velocity_extrema(seg)
    return max(abs(lo), abs(hi))


def stopping_distance(velo: np.ndarray, acc: np.ndarray, dec: np.ndarray, jerk: np.ndarray) -> np.ndarray:
    """Upper bound of the distance a jerk-limited stop from (velo, acc) needs (>= 0).

    Vectorized; used to stop continuous motion at a software limit in time.
    """
    v = np.abs(velo)
    a = np.where(velo >= 0, acc, -acc)  # acceleration in the direction of travel
    a_pos = np.maximum(a, 0.0)
    # 1) bring a speeding-up acceleration to zero
    t1 = a_pos / jerk
    v1 = v + a_pos * a_pos / (2 * jerk)
    d1 = v1 * t1
    # 2) trapezoidal/triangular jerk-limited stop from v1 at zero acceleration
    full = v1 >= dec * dec / jerk
    d2 = np.where(full, 0.5 * v1 * (v1 / dec + dec / jerk), v1 * np.sqrt(np.maximum(v1, 0) / jerk))
    d: np.ndarray = d1 + d2
    return d
