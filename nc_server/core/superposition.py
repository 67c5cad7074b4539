"""Superimposed motion (TcMC MC_MoveSuperImposed / MC_MoveSuperImposedExt) as a pure planning function.

A superposition adds an offset profile to an axis that already moves with the process velocity
of a reference (conveyor, master). The NC works in the time domain: ``Length`` and the process
velocity give a time window T, and the offset profile is a jerk-limited move of ``Distance``
that fits in it:

* VELOREDUCTION (modes 1, 2): the move takes exactly T (ruckig's ``minimum_duration``), so its
  velocity is as low as the window allows (at most ``VelocityDiff``).
* LENGTHREDUCTION (modes 3, 4): the time-optimal move at ``VelocityDiff``, used as is if it fits.
* ADDITIVE (1, 3): ``Length`` is the reference's travel, T = |Length| / |v|; the axis travels
  Length + Distance. LIMITED (2, 4): ``Length`` is the axis's own travel, |v| T + D = |Length|
  (D counted in the direction of travel), T = (|Length| - D) / |v|.
* The process velocity v is VelocityProcess, which TcMC requires to be non-zero ("absolute value
  > 0", 3.9/3.10): there is always a finite window. Decision for a standing axis (``standing``:
  its basic motion has no velocity, so LIMITEDMOTION's "the axis's own travel" holds no process
  travel): every mode uses T = |Length| / |VelocityProcess|, and ActualLength of a LIMITED mode is
  the axis's own travel, |Distance applied|.

If even the fastest move of the full Distance does not fit, the largest distance that fits is
applied and the result is flagged incomplete (the NC reports 0x4243). The offset profile uses the
segment table of :mod:`.planning` (a :class:`~.planning.Plan`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from . import planning
from .planning import Dynamics, Plan, StartState, plan_position, plan_velocity

#: E_SuperpositionMode
MODE_VELO_ADDITIVE, MODE_VELO_LIMITED, MODE_LENGTH_ADDITIVE, MODE_LENGTH_LIMITED = 1, 2, 3, 4
_MODES = (MODE_VELO_ADDITIVE, MODE_VELO_LIMITED, MODE_LENGTH_ADDITIVE, MODE_LENGTH_LIMITED)

#: bisection steps for the largest distance that fits (2^-40 of the requested distance)
_BISECT = 40


@dataclass(frozen=True, slots=True)
class SuperPlan:
    """A planned superposition.

    Attributes:
        plan: the superimposed offset profile: starts at ``start`` (p = offset so far, v, a), ends
            at rest at ``start.p + distance``.
        distance: ActualDistance, signed like the requested Distance [u] (see
            :func:`plan_superposition` for the one case where it is not).
        velocity_diff: ActualVelocityDiff: peak |v| of the offset profile [u/s].
        length: ActualLength: travel during the superposition [u] (ADDITIVE: the reference's,
            LIMITED: the axis's own).
        window: the time window T the mode allowed for the applied distance [s].
        incomplete: the full Distance did not fit (the NC reports 0x4243); the most that fits was
            applied.
    """

    plan: Plan
    distance: float
    velocity_diff: float
    length: float
    window: float
    incomplete: bool


def plan_superposition(mode: int, distance: float, velocity_diff: float, dyn_acc: float, dyn_dec: float,
                       jerk: float, v_process: float, length: float,
                       start: StartState = StartState(0.0), standing: bool = False) -> SuperPlan:
    """Plan a superimposed move of ``distance`` on top of a motion at ``v_process``.

    Args:
        mode: E_SuperpositionMode (1..4, the ``MODE_*`` constants).
        distance: Distance to superimpose (signed, != 0) [u].
        velocity_diff: VelocityDiff, the largest |velocity| of the offset profile (sign ignored) [u/s].
        dyn_acc, dyn_dec: acceleration / deceleration of the offset profile, towards its goal
            (speeding up / slowing down, as in :func:`.planning.plan_position`) [u/s^2].
        jerk: jerk limit [u/s^3].
        v_process: mean process velocity of the reference (signed, != 0: VelocityProcess; its sign
            is the direction of travel) [u/s].
        length: Length (sign ignored, != 0) [u]; its meaning depends on ``mode``.
        start: the offset profile's current state (a running superposition re-triggered: its
            offset, velocity and acceleration now; the window starts now).
        standing: the axis's basic motion stands: the window is |Length| / |v_process| in every
            mode (see the module docstring).

    When the full distance does not fit, the largest distance that fits (bisection, with the
    fastest move's duration against the window) is applied. In LIMITED modes the window shrinks
    as the distance grows, so a Distance beyond Length only gets what fits with the axis travelling
    at most |Length|. A re-triggered superposition whose motion cannot even be stopped within the
    window gets the fastest stop: then ``distance`` is where that stop ends (possibly past or
    against the requested Distance).

    Raises:
        ValueError: unknown mode, distance 0 or not finite, |velocity_diff| or |length| not > 0,
            dyn_acc, dyn_dec or jerk not > 0, |v_process| not > 0 or not finite.
        PlanningError: ruckig failed.
    """
    _check(mode, distance, velocity_diff, dyn_acc, dyn_dec, jerk, v_process, length)
    dyn = Dynamics(abs(velocity_diff), dyn_acc, dyn_dec, jerk)
    speed = abs(v_process)
    s = -1.0 if v_process < 0 else 1.0  # direction of travel
    limited = mode in (MODE_VELO_LIMITED, MODE_LENGTH_LIMITED)
    travels = limited and not standing  # the axis's own travel includes the process's

    def window(d: float) -> float:
        return (abs(length) - d * s) / speed if travels else abs(length) / speed

    def fastest(d: float) -> Plan | None:
        """The time-optimal move of ``d``, None if it does not fit in its window."""
        p = _move(start, d, dyn)
        return p if p.duration <= window(d) else None

    applied, best = distance, fastest(distance)
    if best is None:
        # the largest fraction of the distance that fits; the bracket's low end must fit: 0 (no
        # further offset) or, for a re-triggered motion, where its fastest stop ends
        stop = plan_velocity(start, 0.0, dyn) if (start.v or start.a) else None
        lo, lo_plan = 0.0, fastest(0.0)
        if stop is not None:
            f = (stop.end.p - start.p) / distance
            if 0.0 < f < 1.0 and (p := fastest(f * distance)) is not None:
                lo, lo_plan = f, p
        if lo_plan is None:
            # nothing fits: a running superposition is stopped as fast as it can be (at rest: stays)
            if stop is None:
                plan = _move(start, 0.0, dyn)
            else:  # a stop is one way; ruckig's velocity-interface extrema are unreliable (p_min 0 seen)
                plan = _at_rest(stop, stop.end.p)
                plan = Plan(plan.seg, plan.duration, min(start.p, plan.end.p), max(start.p, plan.end.p), plan.end)
            d = plan.end.p - start.p
            return _result(plan, d, max(window(d), 0.0), speed, s, limited, standing=standing)
        hi = 1.0
        for _ in range(_BISECT):
            mid = 0.5 * (lo + hi)
            if (p := fastest(mid * distance)) is not None:
                lo, lo_plan = mid, p
            else:
                hi = mid
        applied, best = lo * distance, lo_plan
    win = window(applied)
    if mode in (MODE_VELO_ADDITIVE, MODE_VELO_LIMITED) and math.isfinite(win) and best.duration < win:
        # use the whole window: ruckig stretches the move to exactly T at the lowest velocity
        best = _move(start, applied, dyn, win)
    return _result(best, applied, win, speed, s, limited, applied != distance, standing)


def _result(plan: Plan, applied: float, win: float, speed: float, s: float, limited: bool,
            incomplete: bool = True, standing: bool = False) -> SuperPlan:
    if limited:
        # the axis's own travel: the reference's plus the offset (standing axis: the offset)
        length = speed * plan.duration + applied * s if not standing else abs(applied)
    else:
        length = speed * plan.duration
    return SuperPlan(plan, applied, plan.peak_velocity, length, win, incomplete)


def _move(start: StartState, d: float, dyn: Dynamics, duration: float | None = None) -> Plan:
    """plan_position to ``start.p + d``, taking at least ``duration`` [s] (None: time-optimal).

    planning keeps one ruckig input for all plans; its minimum_duration is reset at once so that
    no other plan inherits the window.
    """
    planning._inp.minimum_duration = duration
    try:
        return _at_rest(plan_position(start, start.p + d, dyn), start.p + d)
    finally:
        planning._inp.minimum_duration = None


def _at_rest(plan: Plan, goal: float) -> Plan:
    """``plan`` with its tail exactly at rest at ``goal`` [u].

    ruckig's integrated end leaves ~1e-14 u/s in the tail, which holds for ever: the offset would
    drift for as long as the axis moves on.
    """
    seg = plan.seg.copy()
    k = int(np.count_nonzero(np.isfinite(seg[0]))) - 1  # the tail: the last segment that starts
    seg[1:, k] = (goal, 0.0, 0.0, 0.0)
    seg.flags.writeable = False
    return Plan(seg, plan.duration, min(plan.p_min, goal), max(plan.p_max, goal), StartState(goal))


def _check(mode: int, distance: float, velocity_diff: float, dyn_acc: float, dyn_dec: float, jerk: float,
           v_process: float, length: float) -> None:
    if mode not in _MODES:
        raise ValueError(f"unknown superposition mode {mode!r} (E_SuperpositionMode 1..4)")
    if not math.isfinite(distance) or distance == 0:
        raise ValueError(f"Distance must be finite and != 0, got {distance!r}")
    if not abs(velocity_diff) > 0 or not math.isfinite(velocity_diff):
        raise ValueError(f"|VelocityDiff| must be finite and > 0, got {velocity_diff!r}")
    if not abs(length) > 0 or not math.isfinite(length):
        raise ValueError(f"|Length| must be finite and > 0, got {length!r}")
    for name, value in (("Acceleration", dyn_acc), ("Deceleration", dyn_dec), ("Jerk", jerk)):
        if not value > 0 or not math.isfinite(value):
            raise ValueError(f"{name} must be finite and > 0, got {value!r}")
    if not abs(v_process) > 0 or not math.isfinite(v_process):
        raise ValueError(f"|VelocityProcess| must be finite and > 0, got {v_process!r}")
