"""Jerk-limited set-point profiles: planned by ruckig, evaluated for all axes at once.

ruckig computes a time-optimal third-order profile when a command arrives (a few
microseconds, once). The profile is stored as a row of constant-jerk segments
(ruckig's brake pre-profile, its 7 phases, an optional post-profile, then a tail
that keeps the final velocity). Each NC cycle then evaluates every axis's row
with a handful of numpy operations -- no per-axis Python loop, no per-axis
ruckig call in the cycle.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from ruckig import ControlInterface, InputParameter, Result, Ruckig, RuckigError, Trajectory

#: segments per axis: brake (2) + main (7) + post (2) + tail (1) + a sentinel that never starts
N_SEGMENTS = 13


class PlanningError(Exception):
    """ruckig could not plan the requested motion."""


@dataclass
class Limits:
    """Dynamic limits of one move (all > 0): [u/s], [u/s^2], [u/s^3]."""

    velocity: float
    acceleration: float
    deceleration: float
    jerk: float


class Planner:
    """Plans one axis at a time into a segment row (reuses its ruckig objects)."""

    def __init__(self) -> None:
        self._otg = Ruckig(1)
        self._inp = InputParameter(1)
        self._traj = Trajectory(1)

    def _calc(self, p0: float, v0: float, a0: float, lim: Limits, sense: float) -> Trajectory:
        inp = self._inp
        inp.current_position = [p0]
        inp.current_velocity = [v0]
        inp.current_acceleration = [a0]
        inp.max_velocity = [lim.velocity]
        # Directional limits: towards the goal ('sense') 'acceleration' speeds up and 'deceleration'
        # slows down. A reversal first brakes the current motion and then speeds up the other way
        # with the same sign of acceleration, so that side gets the smaller of the two.
        up, down = lim.acceleration, lim.deceleration
        reversing = v0 * sense < 0
        if sense >= 0:
            hi, lo = (min(up, down) if reversing else up), down
        else:
            hi, lo = down, (min(up, down) if reversing else up)
        inp.max_acceleration = [hi]
        inp.min_acceleration = [-lo]
        inp.max_jerk = [lim.jerk]
        try:
            return self._run()
        except PlanningError:
            # A new command may lower the limits below the current acceleration; ruckig can
            # fail on such states, so retry with limits widened to cover it.
            wide = max(lim.acceleration, lim.deceleration, abs(a0) * 1.01)
            inp.max_acceleration = [wide]
            inp.min_acceleration = [-wide]
            return self._run()

    def _run(self) -> Trajectory:
        try:
            res = self._otg.calculate(self._inp, self._traj)
        except RuckigError as exc:
            raise PlanningError(str(exc).strip().splitlines()[0]) from None
        if res not in (Result.Working, Result.Finished):
            raise PlanningError(f"ruckig result {res}")
        return self._traj

    def position(self, p0: float, v0: float, a0: float, target: float, lim: Limits) -> tuple[np.ndarray, float, float, float]:
        """Plan a move to ``target`` ending at rest.

        Returns:
            (segments (5, N_SEGMENTS): t0, p, v, a, j), duration [s], min and max position on the way.

        Raises:
            PlanningError: ruckig failed.
        """
        inp = self._inp
        inp.control_interface = ControlInterface.Position
        inp.target_position = [target]
        inp.target_velocity = [0.0]
        inp.target_acceleration = [0.0]
        traj = self._calc(p0, v0, a0, lim, math.copysign(1.0, target - p0) if target != p0 else math.copysign(1.0, v0 or 1.0))
        ext = traj.position_extrema[0]
        return _segments(traj), traj.duration, ext.min, ext.max

    def velocity(self, p0: float, v0: float, a0: float, target_velo: float, lim: Limits) -> tuple[np.ndarray, float]:
        """Plan a change to ``target_velo``, which is then held.

        Returns:
            (segments, duration of the change [s]).

        Raises:
            PlanningError: ruckig failed.
        """
        inp = self._inp
        inp.control_interface = ControlInterface.Velocity
        inp.target_velocity = [target_velo]
        inp.target_acceleration = [0.0]
        sense = target_velo if target_velo != 0 else v0  # a stop brakes the current motion
        traj = self._calc(p0, v0, a0, lim, math.copysign(1.0, sense) if sense else 1.0)
        return _segments(traj), traj.duration


def _segments(traj: Trajectory) -> np.ndarray:
    """Flatten a 1-DoF ruckig trajectory into constant-jerk segments, shape (5, N_SEGMENTS)."""
    prof = traj.profiles[0][0]
    rows: list[tuple[float, float, float, float, float]] = []  # (duration, p, v, a, j)
    b = prof.brake
    if b.duration > 0:
        bt, bp, bv, ba, bj = b.t, b.p, b.v, b.a, b.j
        rows += [(bt[k], bp[k], bv[k], ba[k], bj[k]) for k in range(2)]
    pt, pp, pv, pa, pj = prof.t, prof.p, prof.v, prof.a, prof.j
    rows += [(pt[k], pp[k], pv[k], pa[k], pj[k]) for k in range(7)]
    acc = prof.accel
    if acc.duration > 0:
        at, ap, av, aa, aj = acc.t, acc.p, acc.v, acc.a, acc.j
        rows += [(at[k], ap[k], av[k], aa[k], aj[k]) for k in range(2)]
        tail = _integrate(at[1], ap[1], av[1], aa[1], aj[1])  # the end of the post-profile
    else:
        tail = (pp[7], pv[7], pa[7])
    cols: list[list[float]] = []
    t = 0.0
    for dur, p, v, a, j in rows:
        cols.append([t, p, v, a, j])
        t += dur
    cols.append([traj.duration, tail[0], tail[1], tail[2], 0.0])  # tail: hold the final velocity
    cols += [[math.inf, 0.0, 0.0, 0.0, 0.0]] * (N_SEGMENTS - len(cols))  # unused: never start
    return np.array(cols).T


def _integrate(t: float, p: float, v: float, a: float, j: float) -> tuple[float, float, float]:
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


def peak_velocity(seg: np.ndarray) -> float:
    """Largest |velocity| of one axis's segment row (5, N_SEGMENTS) over the whole profile.

    Plain Python: 13 segments are cheaper to walk than to hand to numpy.
    """
    t0, _, v, a, j = seg.tolist()
    peak = 0.0
    for k in range(N_SEGMENTS):
        if t0[k] == math.inf:
            break
        peak = max(peak, abs(v[k]))
        jk = j[k]
        if jk:
            tau = -a[k] / jk  # velocity extremum inside the segment where a + j*tau = 0
            end = t0[k + 1] if k + 1 < N_SEGMENTS else math.inf
            if 0 < tau < end - t0[k]:
                peak = max(peak, abs(v[k] - a[k] * a[k] / (2 * jk)))
    return peak


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
    return d1 + d2
