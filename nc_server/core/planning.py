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

from .profile import N_SEGMENTS, integrate_segment, peak_velocity, velocity_extrema


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

    A velocity reduction (issue 17): where the axis heads for the target faster than the velocity
    limit ``max(dyn.velocity, |end_velocity|)`` [u/s], or its acceleration will carry it past that
    limit, the plan first makes the fastest jerk-limited velocity change to the limit ending at
    a = 0 (:func:`velocity_change`, closed form, the shape of ruckig's velocity interface) and then
    ruckig's position profile from that state. So the limit is reached from above, without the
    undershoot of ruckig's brake pre-profile (which ends the brake with a != 0 and dips by
    about a^2 / (2 * jerk) below the limit: 750 u/s instead of 1000 at AxisAcc 5000, AxisJerk 50000
    from 2000 u/s). Decisions where the manual is silent:

    * too little way to reach the lower velocity and still stop at the target: one even deceleration
      (the lowest constant deceleration that ends at the target) through it to the target, never
      down and up again;
    * already braking harder than the limit allows (v - a^2 / (2 * jerk) below it): the least dip
      the jerk allows, back up to the limit with a = 0;
    * a full brake that passes the target: past it and back, as before.

    Raises:
        PlanningError: ruckig failed.
    """
    if target != start.p:
        sense = math.copysign(1.0, target - start.p)
    else:
        sense = math.copysign(1.0, start.v or end_velocity or 1.0)
    if start.v * sense > 0 and end_velocity * sense >= 0:
        vlim = max(dyn.velocity, abs(end_velocity))
        s, acc = start.v * sense, start.a * sense
        if s + max(acc, 0.0) ** 2 / (2 * dyn.jerk) > vlim * (1 + 1e-9):
            reduced = _plan_reduction(start, target, dyn, end_velocity, sense, vlim)
            if reduced is not None:
                return reduced
    return _plan_position(start, target, dyn, end_velocity, sense)


def _plan_position(start: StartState, target: float, dyn: Dynamics, end_velocity: float, sense: float) -> Plan:
    """ruckig's position profile (with its brake pre-profile where the start exceeds the limits)."""
    _set_position_target(target, end_velocity)
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


def _set_position_target(target: float, end_velocity: float) -> None:
    _inp.control_interface = ControlInterface.Position
    _inp.target_position = [target]
    _inp.target_velocity = [end_velocity]
    _inp.target_acceleration = [0.0]


def _plan_reduction(start: StartState, target: float, dyn: Dynamics, end_velocity: float, sense: float,
                    vlim: float) -> Plan | None:
    """:func:`plan_position` for an axis faster than ``vlim`` (in the direction ``sense``): the
    velocity change to ``sense * vlim`` ending at a = 0, then ruckig's one-way position profile;
    with too little way for that, one even deceleration to the target. None: not even a full brake
    stops at the target (the caller plans past it and back)."""
    # in the direction of travel, slowing down is the deceleration, speeding up the acceleration
    change = velocity_change(start.v * sense, start.a * sense, vlim, dyn.acceleration, dyn.deceleration, dyn.jerk)
    p, v, a = 0.0, start.v * sense, start.a * sense
    rows: list[tuple[float, float, float, float, float]] = []  # (duration, p, v, a, j) in the sense frame
    for dur, jk in change:
        rows.append((dur, p, v, a, jk))
        p, v, a = integrate_segment(dur, p, v, a, jk)
    p1 = start.p + sense * p
    if (target - p1) * sense >= 0:
        _set_position_target(target, end_velocity)
        try:
            # exactly at the limit with a = 0: no brake pre-profile in ruckig's plan
            main = _plan(StartState(p1, sense * vlim, 0.0), dyn, sense, one_way=True)
        except PlanningError:
            main = None
        if main is not None:
            first = [[t, start.p + sense * rp, sense * rv, sense * ra, sense * rj]
                     for t, (_, rp, rv, ra, rj) in zip(_starts(change), rows)]
            joined = _joined(first, sum(d for d, _ in change), main.seg, main.duration, main.end)
            if joined is not None:
                return joined
    return _plan_even_deceleration(start, target, dyn, end_velocity, sense)


def _joined(first: list[list[float]], t_shift: float, m: np.ndarray, duration: float, end: StartState) -> Plan | None:
    """A plan of the segment rows ``first`` ([t, p, v, a, j] each, from t = 0) followed by the segment table ``m``
    (5, N_SEGMENTS) shifted by ``t_shift`` [s], whose own ``duration`` [s] ends in ``end``. None: no room for
    the sentinel row."""
    used = int(np.count_nonzero(np.isfinite(m[0])))
    if len(first) + used >= N_SEGMENTS:
        return None
    cols = first + [[m[0, k] + t_shift, m[1, k], m[2, k], m[3, k], m[4, k]] for k in range(used)]
    cols += [[math.inf, 0.0, 0.0, 0.0, 0.0]] * (N_SEGMENTS - len(cols))
    seg = np.array(cols).T
    seg.flags.writeable = False
    return _make_plan(seg, t_shift + duration, end)


def _starts(change: list[tuple[float, float]]) -> list[float]:
    t, out = 0.0, []
    for dur, _ in change:
        out.append(t)
        t += dur
    return out


def _plan_even_deceleration(start: StartState, target: float, dyn: Dynamics, end_velocity: float,
                            sense: float) -> Plan | None:
    """Too little way to reach the lower velocity and still arrive at the target as asked: brake at
    once, at the lowest constant deceleration [u/s^2] that ends at the target with ``end_velocity``
    (closed form for a start at a = 0; ruckig plans it from the real state, cruising a little first
    where the real state brakes shorter). None: a full brake passes the target."""
    s, acc = start.v * sense, start.a * sense
    peak = s + max(acc, 0.0) ** 2 / (2 * dyn.jerk)
    ve = abs(end_velocity)
    d = (target - start.p) * sense
    dv = s - ve
    m = 0.5 * (s + ve)  # the mean velocity of a jerk-limited change at a = 0 at both ends
    q = d / m if m > 0 else math.inf
    disc = q * q - 4 * dv / dyn.jerk
    tries = []
    if dv > 0 and disc >= 0:
        # d = m * (dv / D + D / J): the root with D <= sqrt(dv * J) (the gentler trapezoid)
        dec = 0.5 * dyn.jerk * (q - math.sqrt(disc))
        if 0 < dec < dyn.deceleration:
            tries.append(dyn.with_(velocity=peak * (1 + 1e-9), deceleration=dec))
    tries.append(dyn.with_(velocity=peak * (1 + 1e-9)))  # the full brake (cruising first)
    for dd in tries:
        _set_position_target(target, end_velocity)
        try:
            plan = _plan(start, dd, sense, one_way=True)
        except PlanningError:
            continue
        lo, hi = velocity_extrema(plan.seg)
        if (lo if sense > 0 else -hi) >= -1e-9:  # never turns back
            return plan
    return None


def velocity_change(v0: float, a0: float, v1: float, acc: float, dec: float, jerk: float) -> list[tuple[float, float]]:
    """The time-optimal jerk-limited change from velocity ``v0`` [u/s] with acceleration ``a0``
    [u/s^2] to ``v1`` with a = 0, as (duration [s], jerk [u/s^3]) segments (at most 3, none of zero
    duration): the shape of ruckig's velocity interface, in closed form. Speeding up is limited by
    ``acc``, slowing down by ``dec``, both [u/s^2]; a start acceleration beyond its limit is brought
    back to it first. A start that cannot avoid passing ``v1`` (v0 + a0 * |a0| / (2 * jerk) beyond it)
    goes the other way: the least overshoot (or dip) the jerk allows, then back with a = 0."""
    v_stop = v0 + a0 * abs(a0) / (2 * jerk)  # where bringing a to 0 at once ends
    if v_stop > v1:  # slowing down: mirror into speeding up
        return [(d, -j) for d, j in _speed_up(-v0, -a0, -v1, dec, jerk)]
    return _speed_up(v0, a0, v1, acc, jerk)


def _speed_up(v0: float, a0: float, v1: float, amax: float, jerk: float) -> list[tuple[float, float]]:
    """:func:`velocity_change` where v0 + a0 * |a0| / (2 * jerk) <= v1: up to the peak acceleration,
    hold it, back to 0."""
    ap = math.sqrt(max(0.5 * a0 * a0 + jerk * (v1 - v0), 0.0))  # triangular: (2 ap^2 - a0^2) / (2 J) = dv
    hold = 0.0
    if ap > amax:
        ap = amax
        dv1 = (ap + a0) * 0.5 * abs(ap - a0) / jerk
        hold = max((v1 - v0 - dv1 - ap * ap / (2 * jerk)) / ap, 0.0)
    out = [(abs(ap - a0) / jerk, math.copysign(jerk, ap - a0)), (hold, 0.0), (ap / jerk, -jerk)]
    return [(d, j) for d, j in out if d > 0]


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
    acc, dec = dyn.acceleration, dyn.deceleration
    reversing = start.v * sense < 0
    if sense >= 0:
        hi, lo = (min(acc, dec) if reversing else acc), dec
    else:
        hi, lo = dec, (min(acc, dec) if reversing else acc)
    _inp.max_acceleration = [hi]
    _inp.min_acceleration = [-lo]
    _inp.max_jerk = [dyn.jerk]
    try:
        traj = _run()
    except PlanningError as exc:
        if one_way:  # not possible one way with these dynamics: the caller plans it two ways
            raise
        # an acceleration beyond the limit on its side: brought to it first, the plan within the limits
        # after that (the widened retry would brake at up to 1.01 |a0|, beyond both limits)
        reduced = _plan_from_limit(start, dyn.jerk, hi, lo)
        if reduced is not None:
            return reduced
        retried = _retry(start.a, hi, lo, max(acc, dec))
        if retried is None:
            _inp.current_acceleration = [start.a]
            raise exc
        traj = retried
    seg, end = _segments(traj)
    return _make_plan(seg, float(traj.duration), end)


def _nudged(a: float) -> list[float]:
    """Accelerations within rounding of ``a`` [u/s^2]: ruckig 0.19 fails ("error in step 1") on some
    states that lie exactly on a profile's braking curve (a stop from them ends exactly on a target)."""
    return [a * (1 + n) + n for n in (1e-12, -1e-12, 1e-9, -1e-9)]


def _attempt(hi: float, lo: float, a: float) -> Trajectory | None:
    """ruckig with :func:`_plan`'s input but the limits ``hi``/``lo`` [u/s^2] and the current
    acceleration ``a``; None where it fails."""
    _inp.max_acceleration, _inp.min_acceleration = [hi], [-lo]
    _inp.current_acceleration = [a]
    try:
        return _run()
    except PlanningError:
        return None


def _retry(a0: float, hi: float, lo: float, widest: float) -> Trajectory | None:
    """ruckig 0.19 fails ("error in step 1") on some valid inputs; retries of :func:`_plan`'s
    input (limits ``hi``/``lo`` [u/s^2], current acceleration ``a0``) after :func:`_plan_from_limit`,
    the first that plans wins (the same input, the same plan). None: none plans.

    1. Both limits widened to ``max(widest, 1.01 |a0|)`` (``widest`` = max(Acceleration,
       Deceleration)): new dynamics may be below the current acceleration and ruckig's brake
       pre-profile, which must first reduce it, fails on some such states. This goes past the
       command's limits on purpose: such a plan may brake at up to that widened limit (beyond the
       Deceleration where Acceleration > Deceleration or |a0| > both) rather than refuse a
       legitimate command 0x427E.
    2. The limits as given, the acceleration nudged within rounding (:func:`_nudged`).

    The order is the one before :func:`_plan_from_limit` existed: what planned then plans the same,
    except a start beyond the limit on its side that :func:`_plan_from_limit` plans (within the
    limits now, where 1. went past them).
    """
    wide = max(widest, abs(a0) * 1.01)
    for (hi_try, lo_try), a in [((wide, wide), a0)] + [((hi, lo), a) for a in _nudged(a0)]:
        traj = _attempt(hi_try, lo_try, a)
        if traj is not None:
            return traj
    return None


def _plan_from_limit(start: StartState, jerk: float, hi: float, lo: float) -> Plan | None:
    """The first fallback, before :func:`_retry`, for a start acceleration beyond the limit on its side (an
    axis accelerating at AxisAcc re-targeted behind it, AxisDec < AxisAcc: ruckig's brake
    pre-profile fails on some such states): first the acceleration brought to that limit at full
    ``jerk`` [u/s^3] (closed form), then ruckig from there with the unchanged limits ``hi``/``lo``
    [u/s^2] (nudges allowed), so the plan stays within them after that first segment. None: the
    start is within the limits, ruckig fails from there too, or no room for the extra segment."""
    a0 = start.a
    lim = hi if a0 > 0 else -lo
    if abs(a0) <= abs(lim):
        return None
    jk = -math.copysign(jerk, a0)
    t_red = (abs(a0) - abs(lim)) / jerk
    p1, v1, _ = integrate_segment(t_red, start.p, start.v, a0, jk)
    _inp.current_position, _inp.current_velocity = [p1], [v1]
    try:
        for a in [lim] + [x for x in _nudged(lim) if abs(x) < abs(lim)]:  # (inwards: within the limits)
            traj = _attempt(hi, lo, a)
            if traj is not None:
                break
        else:
            return None
    finally:
        _inp.current_position, _inp.current_velocity = [start.p], [start.v]
    m, end = _segments(traj)
    return _joined([[0.0, start.p, start.v, a0, jk]], t_red, m, float(traj.duration), end)


def _make_plan(seg: np.ndarray, duration: float, end: StartState) -> Plan:
    p_min, p_max = position_extrema(seg, duration)
    return Plan(seg, duration, p_min, p_max, end)


def position_extrema(seg: np.ndarray, duration: float) -> tuple[float, float]:
    """(lowest, highest) position [u] of a segment row (5, N_SEGMENTS) from 0 to ``duration`` [s].

    From the plan's own segments: ruckig's ``position_extrema`` keeps the target of an earlier
    position calculation in velocity plans and leaves out the brake pre-profile (a MoveAbsolute at
    override 0 was refused 0x4222 because of another axis's target). Plain Python (at most 12
    segments): the ends of each segment and where its velocity crosses 0 inside it.
    """
    t0, p, v, a, j = seg.tolist()
    lo = hi = p[0]
    for k in range(N_SEGMENTS):
        start = t0[k]
        if not start < duration:
            break
        end = t0[k + 1] if k + 1 < N_SEGMENTS else math.inf
        dur = min(end, duration) - start
        pk, vk, ak, jk = p[k], v[k], a[k], j[k]
        # the roots of v + a t + j t^2 / 2 inside (0, dur)
        if jk:
            disc = ak * ak - 2 * jk * vk
            roots = [] if disc < 0 else [(-ak + sq) / jk for sq in (math.sqrt(disc), -math.sqrt(disc))]
        else:
            roots = [-vk / ak] if ak else []
        for t in roots + [dur]:
            if 0 < t <= dur:
                x = integrate_segment(t, pk, vk, ak, jk)[0]
                lo, hi = min(lo, x), max(hi, x)
    return lo, hi


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
