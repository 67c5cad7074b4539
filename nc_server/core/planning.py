"""Planning as a pure function: a frozen start state and a target in, a frozen plan out.

ruckig computes a time-optimal jerk-limited profile once per command (a few microseconds); the
plan stores it as constant-jerk segments (``profile.N_SEGMENTS`` per axis) that the profile stage
evaluates for all axes at once. Nothing here keeps state between calls that could change a
result: the ruckig objects are reused only to avoid allocations.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from ruckig import ControlInterface, InputParameter, Result, Ruckig, RuckigError, Trajectory

from .profile import N_SEGMENTS, integrate_segment, peak_velocity


class PlanningError(Exception):
    """ruckig could not plan the requested motion."""


@dataclass(frozen=True, slots=True)
class StartState:
    """Where a plan starts: set position [u], velocity [u/s], acceleration [u/s^2]."""

    p: float
    v: float = 0.0
    a: float = 0.0


@dataclass(frozen=True, slots=True)
class Dynamics:
    """Limits of one motion (all > 0): velocity [u/s], acceleration and deceleration [u/s^2] (towards
    the goal: speeding up / slowing down), jerk [u/s^3]."""

    velocity: float
    acceleration: float
    deceleration: float
    jerk: float

    def scaled(self, override: float) -> Dynamics:
        """The same dynamics with the velocity scaled by an override 0..1 (accelerations stay)."""
        return Dynamics(self.velocity * override, self.acceleration, self.deceleration, self.jerk)

    def with_(self, **kw: float) -> Dynamics:
        return Dynamics(**{**{k: getattr(self, k) for k in ("velocity", "acceleration", "deceleration", "jerk")}, **kw})


@dataclass(frozen=True, slots=True)
class Plan:
    """A planned profile.

    Attributes:
        seg: (5, N_SEGMENTS) read-only table t0, p, v, a, j (the last used segment holds the end
            velocity for ever).
        duration: time to the end state [s].
        p_min, p_max: position extrema on the way [u].
        end: the state at ``duration``.
    """

    seg: np.ndarray
    duration: float
    p_min: float
    p_max: float
    end: StartState

    @property
    def peak_velocity(self) -> float:
        return peak_velocity(self.seg)


_otg = Ruckig(1)
_inp = InputParameter(1)
_traj = Trajectory(1)


def plan_position(start: StartState, target: float, dyn: Dynamics, end_velocity: float = 0.0) -> Plan:
    """Plan a move to ``target``, arriving with ``end_velocity`` (signed; 0 = at rest) and zero
    acceleration; the plan then keeps ``end_velocity``.

    Raises:
        PlanningError: ruckig failed.
    """
    _inp.control_interface = ControlInterface.Position
    _inp.target_position = [target]
    _inp.target_velocity = [end_velocity]
    _inp.target_acceleration = [0.0]
    if target != start.p:
        sense = math.copysign(1.0, target - start.p)
    else:
        sense = math.copysign(1.0, start.v or end_velocity or 1.0)
    if start.v * sense >= 0 and end_velocity * sense >= 0:
        # heading for the target (or at rest): one way only. With symmetric velocity limits ruckig's
        # brake pre-profile (the axis faster than the new velocity) may undershoot into the other
        # direction and come back. Where one way is impossible (a target within the braking
        # distance: past it and back) the symmetric limits are the answer.
        try:
            return _plan(start, dyn, sense, one_way=True)
        except PlanningError:
            pass
    return _plan(start, dyn, sense)


def plan_velocity(start: StartState, velocity: float, dyn: Dynamics) -> Plan:
    """Plan a change to ``velocity`` (signed), which the plan then keeps (0: a stop).

    Raises:
        PlanningError: ruckig failed.
    """
    _inp.control_interface = ControlInterface.Velocity
    _inp.target_velocity = [velocity]
    _inp.target_acceleration = [0.0]
    sense = velocity if velocity != 0 else start.v  # a stop brakes the current motion
    return _plan(start, dyn, math.copysign(1.0, sense) if sense else 1.0)


def hold(p: float) -> Plan:
    """A plan that stands at ``p``."""
    cols = [[0.0, p, 0.0, 0.0, 0.0]] + [[math.inf, 0.0, 0.0, 0.0, 0.0]] * (N_SEGMENTS - 1)
    seg = np.array(cols).T
    seg.flags.writeable = False
    return Plan(seg, 0.0, p, p, StartState(p))


def _plan(start: StartState, dyn: Dynamics, sense: float, one_way: bool = False) -> Plan:
    _inp.current_position = [start.p]
    _inp.current_velocity = [start.v]
    _inp.current_acceleration = [start.a]
    vmax = max(dyn.velocity, abs(_inp.target_velocity[0]), 1e-12)
    if abs(start.v) <= vmax * (1 + 1e-9):
        # a velocity at the limit within rounding is at the limit: no brake pre-profile for it
        # (ruckig brakes first and plans a different motion for 1 ulp above the limit)
        vmax = max(vmax, abs(start.v))
    if not one_way:
        _inp.max_velocity, _inp.min_velocity = [vmax], [-vmax]
    elif sense > 0:
        _inp.max_velocity, _inp.min_velocity = [vmax], [0.0]
    else:
        _inp.max_velocity, _inp.min_velocity = [0.0], [-vmax]
    # Directional limits: towards the goal ('sense') 'acceleration' speeds up and 'deceleration'
    # slows down. A reversal first brakes the current motion and then speeds up the other way
    # with the same sign of acceleration, so that side gets the smaller of the two.
    up, down = dyn.acceleration, dyn.deceleration
    reversing = start.v * sense < 0
    if sense >= 0:
        hi, lo = (min(up, down) if reversing else up), down
    else:
        hi, lo = down, (min(up, down) if reversing else up)
    _inp.max_acceleration = [hi]
    _inp.min_acceleration = [-lo]
    _inp.max_jerk = [dyn.jerk]
    try:
        traj = _run()
    except PlanningError:
        if one_way:  # not possible one way with these dynamics: the caller plans it two ways
            raise
        # new dynamics may be below the current acceleration; ruckig can fail on such states,
        # so retry with limits widened to cover it
        wide = max(up, down, abs(start.a) * 1.01)
        _inp.max_acceleration = [wide]
        _inp.min_acceleration = [-wide]
        try:
            traj = _run()
        except PlanningError:
            # ruckig 0.19 fails ("error in step 1") on some states that lie exactly on a profile's
            # braking curve (a stop from them ends exactly on a target): a nudge of the acceleration
            # within rounding plans them
            _inp.max_acceleration, _inp.min_acceleration = [hi], [-lo]
            for nudge in (1e-12, -1e-12, 1e-9, -1e-9):
                _inp.current_acceleration = [start.a * (1 + nudge) + nudge]
                try:
                    traj = _run()
                    break
                except PlanningError:
                    continue
            else:
                _inp.current_acceleration = [start.a]
                raise
    seg, end = _segments(traj)
    ext = traj.position_extrema[0]
    return Plan(seg, float(traj.duration), float(ext.min), float(ext.max), end)


def _run() -> Trajectory:
    try:
        res = _otg.calculate(_inp, _traj)
    except RuckigError as exc:
        raise PlanningError(str(exc).strip().splitlines()[0]) from None
    if res not in (Result.Working, Result.Finished):
        raise PlanningError(f"ruckig result {res}")
    return _traj


def _segments(traj: Trajectory) -> tuple[np.ndarray, StartState]:
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
    post = acc.duration > 0
    if post:
        at, ap, av, aa, aj = acc.t, acc.p, acc.v, acc.a, acc.j
        rows += [(at[k], ap[k], av[k], aa[k], aj[k]) for k in range(2)]
    # Phases of zero duration are left out: ruckig reuses its profile objects, and an unused phase
    # of the brake/post profiles keeps the values of an earlier calculation (a velocity of another
    # motion, which the velocity checks would see; it made their answers depend on history).
    rows = [r for r in rows if r[0] > 0]
    if post and rows:
        tail = integrate_segment(*rows[-1])  # the end of the post-profile
    else:
        tail = (pp[7], pv[7], pa[7])
    cols: list[list[float]] = []
    t = 0.0
    for dur, p, v, a, j in rows:
        cols.append([t, p, v, a, j])
        t += dur
    cols.append([traj.duration, tail[0], tail[1], 0.0, 0.0])  # tail: hold the final velocity
    cols += [[math.inf, 0.0, 0.0, 0.0, 0.0]] * (N_SEGMENTS - len(cols))  # unused: never start
    seg = np.array(cols).T
    seg.flags.writeable = False
    return seg, StartState(float(tail[0]), float(tail[1]), 0.0)


def position_at(plan: Plan, t: float) -> tuple[float, float, float]:
    """(p, v, a) of ``plan`` at time ``t`` (plain Python, for planning decisions)."""
    t0, p, v, a, j = plan.seg.tolist()
    k = 0
    while k + 1 < N_SEGMENTS and t0[k + 1] <= t:
        k += 1
    return integrate_segment(t - t0[k], p[k], v[k], a[k], j[k])


def time_at_position(plan: Plan, x: float) -> float | None:
    """First time the plan passes ``x`` (bisection on the monotone stretch), None if never."""
    lo_t, hi_t = 0.0, plan.duration
    p0 = position_at(plan, 0.0)[0]
    p1 = plan.end.p
    if (x - p0) * (x - p1) > 0:
        return None
    sense = 1.0 if p1 >= p0 else -1.0
    for _ in range(60):
        mid = 0.5 * (lo_t + hi_t)
        if (position_at(plan, mid)[0] - x) * sense < 0:
            lo_t = mid
        else:
            hi_t = mid
    return hi_t
