"""Discrete motion to a target: MoveAbsolute, MoveRelative, MoveAdditive, MoveModulo,
MoveAbsoluteOrRestart, and the continuous moves MoveContinuousAbsolute/Relative that pass their
target with an end velocity and keep it.

Targets (NC positions) are fixed when the job is accepted: a relative, additive or modulo target
of a job that waits behind another refers to that job's target (PLCopen: the target of the
previous command), of an immediate job to the set position when it takes effect (MoveAdditive:
to the target of the discrete motion it aborts).

Amendments (NewPos, NewPosAndVelo): a new target and/or velocity, at once, at a switching
position (the set position passes ActivationPos in the direction of travel), or "reach the new
velocity at ActivationPos" (the change starts the braking/accelerating distance before it).

Loop movement (MC_AxisPara 1033 AxisEnLoopingDistance, 1034 AxisLoopingDistance; TwinCAT's 'Loop' and
'Loop distance (+/-)', ADS axis 0x13/0x14). Beckhoff documents the parameters (TcMC 6.1, the NC ADS table) and
their range errors (0x4323, 0x4328: https://infosys.beckhoff.com/content/1033/tc3ncerrcode/513133323.html) but
not the motion; this NC's decisions: the sign of AxisLoopingDistance is the side the target is approached
from (> 0: from above). A positioning that ends at rest (no blending or end velocity) and would reach its
target from the other side goes on to the loop point (target + AxisLoopingDistance), stops there and
returns to the target (one command: Busy/Active throughout, Done at the target). The loop is decided when
the positioning is planned for its command (start, NewPos/NewPosAndVelo), from the set position then; a
parameter written while it runs acts from the next positioning. The loop point must lie inside the enabled
software limits (0x4222) and the return needs the feed enable of its direction (0x4223): otherwise the
command is refused. A blending successor commanded on the way out starts after the return, as Buffered
(the way out has no blending point). The loop point moves with MC_SetActualPositionOnTheFly / SetPosition
(:meth:`PositionKind.shift`). Override 0 on the way out holds the axis there; a raise goes on to the loop
point.

Override type (MC_AxisPara 1039 AxisOverrideType; TwinCAT's 'Velocity Override Type', Setpoint Generator:
https://infosys.beckhoff.com/content/1033/tc3_system/3396207115.html): 4 original (iterated, the default and
how this NC behaved): the override scales the commanded Velocity and every change re-plans; 3 reduced
(iterated): it scales the peak velocity of the command's profile at 100 % (a short move commanded at 1000 u/s
that peaks at 700 u/s runs at 350 u/s at 50 %; type 4 at 500 u/s, and at 80 % still at its 700 u/s); 1 reduced and
2 original (instantaneous): as 3 and 4, but an override raise whose new plan cannot reach the new level (its
peak stays below it: the remaining way is too short) is not applied, the running profile stays (TwinCAT NC
Master Axes, https://infosys.beckhoff.com/content/1033/tcncptp/3449220235.html: "'Override on x%' causes a
new runtime table to be calculated and activated ... In case of failure, the function is not called again
automatically"; only that
raise: a later ChangeDynParam, blending or NewPosAndVelo plans as always). The reduced reference is taken
when the positioning is planned for its command (start, new target or velocity, the return of a loop); a
type written while a positioning runs acts from its next override change (a reduced type from the next
positioning). Endless motions (MoveVelocity, a continuous move past its target) reach their velocity, so
reduced and original are the same there.
"""
from __future__ import annotations

import math
from dataclasses import replace
from typing import TYPE_CHECKING, Any, Callable, Mapping

import numpy as np

from nc_schema import E_CmdTypeNewTargPosAndVelo as NPV
from nc_schema import ErrorCodes, MC_Direction, NcError

from ..checks import running_jerk
from ..planning import Dynamics, Plan, StartState, plan_position, plan_velocity
from ..probe import modulo_position
from ..profile import velocity_extrema
from .base import ALL_MODES, Job, JobKind

if TYPE_CHECKING:
    from ..context import CoreContext

_POS = int(MC_Direction.MC_Positive_Direction)
_SHORT = int(MC_Direction.MC_Shortest_Way)
_NEG = int(MC_Direction.MC_Negative_Direction)
_CURRENT = int(MC_Direction.MC_Current_Direction)
_EPS_V = 1e-9  # [u/s] a set velocity above this is a motion (as the engine's)


def modulo_target(set_pos: float, target: float, period: float, tolerance: float, direction: int,
                  current_velo: float = 0.0) -> float:
    """Absolute end position of a modulo start (TcMC manual 3.5, tables included).

    Args:
        set_pos: current set position [u] (modulo starts refer to the set position).
        target: modulo target [u], >= 0; >= period adds full turns (not for the shortest way).
        period: modulo period (AxisEncoderModuloValue) [u].
        tolerance: modulo tolerance window (AxisModuloToleranceWindow) [u].
        direction: MC_Direction value.
        current_velo: current set velocity, for MC_Current_Direction.

    Rounding (a choice; 3.5 reasons in exact degrees): Position within 16 LSBs of a whole number of periods
    is that many turns (0.3 at a period of 0.1 is 3 turns, though 0.3 / 0.1 < 3 in floats); a set position
    within 16 LSBs of max(|set position|, Position, period) of the target's modulo value is identical to it
    (no motion); beyond that the window is the configured one alone.

    Raises:
        NcError: 0x4282 invalid modulo target, 0x4B04 invalid direction.
    """
    if direction not in (_POS, _SHORT, _NEG, _CURRENT):
        raise NcError(ErrorCodes.MC_INVALID_MODE, f"Direction {direction} is not an MC_Direction")
    if not 0.0 <= target < 1e9:
        raise NcError(ErrorCodes.NC_MODULO_TARGET_INVALID, f"modulo target {target} must be >= 0")
    if direction == _CURRENT:
        direction = _NEG if current_velo < -1e-9 else _POS  # (at rest within rounding: positive)
    base = math.floor(set_pos / period) * period
    if direction == _SHORT:
        if target >= period:
            raise NcError(ErrorCodes.NC_MODULO_TARGET_INVALID,
                          f"modulo target {target} must be < {period} for MC_Shortest_Way")
        diff = (base + target) - set_pos
        diff = (diff + period / 2) % period - period / 2
        return set_pos + diff
    turns = math.floor(target / period)
    rest = target - turns * period
    # floor(target / period) may round a whole number of periods down (0.3 / 0.1 = 2.999...): a rest of
    # period - tiny is the next whole turn with rest ~0, not a turn less. (A rest tiny below 0, the
    # quotient rounded up, is that turn with rest ~0 as it is.) The rest errs by an LSB of the target.
    tiny = 16.0 * math.ulp(max(target, period))
    if rest >= period - tiny:
        rest -= period
        turns += 1
    elif rest < -tiny:
        rest += period
        turns -= 1
    end = base + rest
    # "No motion occurs if target position and starting position are identical" (TcMC 3.5): a set position
    # with the target's modulo value reached by another sum of floats (-1080 + 54.4 + 360 is not -720 + 54.4)
    # is identical. A margin of a few LSBs of the magnitudes involved (these sums err by 0.3-2 LSBs) keeps
    # such rounding from being a full turn and hides no window: with window 0 a set position clearly past
    # the target ("slightly more than 90 deg", 3.5) makes a full turn.
    tolerance += 16.0 * math.ulp(max(abs(set_pos), target, period))
    # the first position with the modulo value ``rest`` at or beyond the window's far side (set position
    # -/+ tolerance): the window is around the set position, so it may reach into the neighbouring period
    # (set position 359.5, window 1: a target of 0 is 0.5 ahead, not 359.5 behind)
    if direction == _POS:
        if end < set_pos - tolerance:
            end += period
        elif end - period >= set_pos - tolerance:
            end -= period
        return end + turns * period
    if end > set_pos + tolerance:
        end -= period
    elif end + period <= set_pos + tolerance:
        end += period
    return end - turns * period


def modulo_beyond_stop(core: CoreContext, i: int, start: StartState, position: float, dyn: Dynamics,
                       running_jerk: float | None = None) -> tuple[float, float, Plan]:
    """Where a moving axis (``start``, |v| > 0) can come to rest at the modulo value ``position`` [u, in
    [0, period)] without turning back: (end position, direction of travel there +-1, the plan to rest from
    ``start`` with the deceleration and jerk of ``dyn``). MC_OrientedStop (with its stop dynamics) and
    MC_MoveModulo started during motion (with its own dynamics) end there.

    The end is the first position with that modulo value, in the direction of travel, at or beyond the
    point where the plan to rest ends. Where that plan turns (a hard braking whose acceleration the jerk
    cannot bring to 0 before the velocity crosses 0: the motion is committed to the turn), the direction
    of travel is the one after the turn, and the end lies at or beyond the plan's end in that direction
    (no second reversal back to a position the axis left). ``running_jerk``: the jerk of the motion
    running now; given, a turn counts only where that jerk could not avoid it either (MC_MoveModulo with
    a weaker Jerk than the running motion's: the turn is its own dynamics' doing, not committed; the end
    is then the first position at or beyond the plan's farthest point in the current direction, and the
    plan to it turns, which the start's checks refuse, 0x4289). None: every turn of the plan counts
    (MC_OrientedStop: its dynamics are the running motion's, never weaker).

    Raises:
        NcError: 0x427E no plan to rest from ``start`` with ``dyn``.
    """
    rest = core.plan(plan_velocity, start, 0.0, dyn)
    sense = 1.0 if start.v > 0 else -1.0
    natural = rest.end.p
    if _turns(rest, sense):
        a_ahead = start.a * sense
        committed = running_jerk is None or (
            a_ahead < 0 and a_ahead * a_ahead / (2 * running_jerk) - abs(start.v) > 1e-9 * (1.0 + abs(start.v)))
        if committed:
            sense = -sense
        else:
            natural = rest.p_max if sense > 0 else rest.p_min
    period = core.params[i].AxisEncoderModuloValue
    k = (natural - position) / period
    # (a rounding margin: a rest point on a position with that modulo value is that position)
    return position + (math.ceil(k - 1e-12) if sense > 0 else math.floor(k + 1e-12)) * period, sense, rest


class PositionKind(JobKind):
    """Move to a target and end there at rest (or with the blending velocity of its successor)."""

    buffer_modes = ALL_MODES
    commands = ("MoveAbsolute",)

    def __init__(self, name: str) -> None:
        self.name = name
        self.commands = (name,)

    # -- accept / activate -------------------------------------------------------------------
    def target_of(self, core: CoreContext, i: int, req: Mapping[str, Any], base: float, prev: Job | None) -> float:
        return float(req["Position"])

    def accept(self, core: CoreContext, i: int, req: Mapping[str, Any], prev: Job | None) -> Job:
        v = req["Velocity"]
        core.check_velocity(i, v)
        dyn = core.dynamics(i, req, v)
        queued = prev is not None and req.get("BufferMode", 0) != 0
        base = prev.kind.next_base(prev, core, i) if queued and prev is not None else None
        data: dict[str, Any] = {}
        if base is None:
            base = core.nc_set_pos(i)
            if queued:  # behind a job without a target: relative to where this one starts
                data["from_start"] = True
        target = self.target_of(core, i, req, base, prev)
        if not abs(target) < 1e9:
            raise NcError(ErrorCodes.NC_TARGET_POSITION_NOT_ALLOWED, f"target {target} outside +/-1e9")
        return Job(self, dict(req), dyn=dyn, target=target, end_velocity=self.end_velocity_of(core, i, req, target, base),
                   data=data)

    def end_velocity_of(self, core: CoreContext, i: int, req: Mapping[str, Any], target: float, base: float) -> float:
        return 0.0

    def start_target(self, core: CoreContext, i: int, job: Job, start: StartState) -> None:
        """Fix the parts of the target that depend on the state the job starts from (``start``, at its
        activation): a job queued behind one without a target refers to the set position there."""
        if job.data.get("from_start"):
            job.target = self.target_of(core, i, job.args, start.p, None)
            job.end_velocity = self.end_velocity_of(core, i, job.args, job.target, start.p)

    def activate(self, core: CoreContext, i: int, job: Job, start: StartState) -> Plan:
        assert job.target is not None and job.dyn is not None
        self.start_target(core, i, job, start)
        assert job.target is not None
        sense = job.target - start.p
        core.check_feed(i, sense if sense else job.end_velocity)
        self.prepare(core, i, job, start)  # loop point, reduced velocity (AxisEnLoopingDistance, AxisOverrideType)
        plan = self._plan(core, i, job, start, core.override(i))
        core.check_target(i, start.p, job.target, plan)
        if sense:
            core.check_reversal(i, plan, start, 1.0 if sense > 0 else -1.0, job.target)
        core.check_overshoot(i, plan, max(job.dyn.velocity, abs(job.end_velocity)) * core.override(i))
        job.held = core.override(i) <= 0
        job.data["start"] = start.p
        return plan

    def wants_watch(self, job: Job) -> bool:
        return "switch" in job.data

    def watch(self, core: CoreContext, rows: np.ndarray) -> None:
        _switch_reached(core, rows)

    def _plan(self, core: CoreContext, i: int, job: Job, start: StartState, ov: float) -> Plan:
        """The plan to the target from ``start`` at override ``ov``. ``job.end_velocity`` (blending,
        EndVelocity) is the velocity at the target at 100 % and scales with the override like the
        travel velocity. An end velocity above the travel velocity (BlendingNext/High towards a faster
        successor, an EndVelocity above Velocity) is reached by speeding up just before the target:
        the plan runs to the point where that ramp starts and :meth:`on_end` plans the ramp
        (``job.data["ramp"]``). Where the remaining distance is too short the end velocity is lowered
        (never passing the target); the job keeps the requested one for later replans."""
        assert job.target is not None and job.dyn is not None
        job.data.pop("ramp", None)
        if ov <= 0:  # override 0: start as a hold, the job waits for override
            return core.plan(plan_velocity, start, 0.0, job.dyn)
        dyn = self._travel_dyn(core, i, job, ov)
        loop = job.data.get("loop")
        if loop is not None:  # the way out of a loop movement: to the loop point, at rest
            return self._plan_to_target(core, replace(job, target=loop, end_velocity=0.0), start, dyn, 0.0)
        ve = job.end_velocity * ov
        if abs(ve) > dyn.velocity:
            sense = 1.0 if ve > 0 else -1.0
            v_c = sense * dyn.velocity
            d_ramp = abs(core.plan(plan_velocity, StartState(0.0, v_c), ve, dyn).end.p)
            switch = job.target - sense * d_ramp
            if (switch - start.p) * sense > 0:
                plan = core.plan(plan_position, start, switch, dyn, v_c)
                beyond = plan.p_max - switch if sense > 0 else switch - plan.p_min
                if beyond <= 1e-9 and not (start.v * sense >= 0 and _turns(plan, sense)):
                    job.data["ramp"] = ve
                    return plan
            elif start.v * sense > 0:
                # within the ramp already (e.g. a new velocity or dynamics while speeding up to it):
                # go on speeding up if that ends at the target (ruckig would pass it and come back)
                plan = core.plan(plan_velocity, start, ve, dyn)
                if abs(plan.end.p - job.target) <= 1e-6 * max(1.0, abs(ve)):
                    return plan
        return self._plan_to_target(core, job, start, dyn, ve)

    @staticmethod
    def _plan_to_target(core: CoreContext, job: Job, start: StartState, dyn: Dynamics, ve: float) -> Plan:
        """The first acceptable of: the plan with the end velocity ``ve``; the same without ruckig's
        brake pre-profile (a travel velocity below the current one: an override cut or a slower new
        velocity close to the target, where braking first to the new velocity leaves too little way and
        ruckig turns back); lower end velocities (halved; on the command path, ``core.refine_plans``, then
        the highest that fits searched between the last two: 8 bisections); at rest. Acceptable: heading
        for the target it never turns back on the way, and (with an end velocity) it does not pass the
        target. In the cycle the first halved one that fits is taken: a plan made on the command path and
        re-planned there (an override change) may pass the target more slowly than it could."""
        target = job.target
        assert target is not None
        sense = 1.0 if target > start.p else (-1.0 if target < start.p else (1.0 if ve >= 0 else -1.0))

        def acceptable(plan: Plan, v_end: float) -> bool:
            if start.v * sense >= 0 and _turns(plan, sense):
                return False
            beyond = (plan.p_max - target) if sense > 0 else (target - plan.p_min)
            return not v_end or job.continuous or beyond <= 1e-9

        dyns = [dyn]
        a_ahead = max(start.a * sense, 0.0)
        v_peak = abs(start.v) + a_ahead * a_ahead / (2 * dyn.jerk) if start.v * sense > 0 else 0.0
        if v_peak > max(dyn.velocity, abs(ve)):
            dyns.append(dyn.with_(velocity=v_peak * (1 + 1e-9)))
        ends = [ve] + ([ve * 0.5 ** k for k in range(1, 9)] + [0.0] if ve and not job.continuous else [])
        fallback = None
        for k, v_end in enumerate(ends):
            for d in dyns:
                plan = core.plan(plan_position, start, target, d, v_end)
                if acceptable(plan, v_end):
                    if k and v_end and core.refine_plans:
                        # halving overshot the highest end velocity that fits: search between this one
                        # and the previous (Tc2_MC2 MC_BufferMode: blending "as best as possible").
                        # Only on the command path: in the cycle (an override change, a buffered job
                        # taking over) the search would multiply the step's cost on many axes
                        lo, hi = v_end, ends[k - 1]
                        for _ in range(8):
                            mid = 0.5 * (lo + hi)
                            try:
                                trial = core.plan(plan_position, start, target, d, mid)
                            except NcError:
                                hi = mid
                                continue
                            if acceptable(trial, mid):
                                lo, plan = mid, trial
                            else:
                                hi = mid
                    return plan
                if d is dyn and not v_end:
                    fallback = plan
        # nothing better: to rest with the given dynamics, as planned (e.g. a target within the
        # braking distance: past it and back)
        return fallback if fallback is not None else core.plan(plan_position, start, target, dyn, 0.0)

    def replan(self, core: CoreContext, i: int, job: Job, start: StartState, override: float) -> Plan | None:
        job.data.pop("ov_kept", None)  # (a new plan runs at ``override``: no kept raise any more)
        if job.continuous:  # past the target: a velocity job now
            return core.plan(plan_velocity, start, job.end_velocity * override, job.dyn)
        return self._plan(core, i, job, start, override)

    def on_end(self, core: CoreContext, i: int, job: Job) -> str:
        if job.held:
            return "steady"  # override 0: waiting, not the end
        if self.loop_back(core, i, job):
            return "continue"
        if self.start_ramp(core, i, job):
            return "continue"
        if job.end_velocity and not core.queues[i].waiting:
            return "steady"
        return "done"

    def start_ramp(self, core: CoreContext, i: int, job: Job) -> bool:
        """At the end of the first part of a plan that speeds up to its end velocity just before the
        target (:meth:`_plan`): plan the ramp, which ends at the target."""
        ve = job.data.pop("ramp", None)
        if ve is None:
            return False
        assert job.dyn is not None
        # from the first part's exact end (up to a cycle back), so that the ramp ends at the target
        end, _ = core.plan_end_state(i)
        core.continue_plan(i, core.plan(plan_velocity, end, ve, job.dyn.scaled(core.override(i))))
        return True

    def shift(self, job: Job, diff: float) -> None:
        super().shift(job, diff)
        if "loop" in job.data:  # the loop point moves with the axis (as the target)
            job.data["loop"] += diff
        if "switch" in job.data:  # the switching position and a new target move with the axis
            mode, at, new_pos, new_velo = job.data["switch"]
            job.data["switch"] = (mode, at + diff, new_pos + diff, new_velo)

    def blend_point(self, job: Job) -> tuple[float, float, float] | None:
        if job.target is None or job.dyn is None or job.continuous or "loop" in job.data:
            return None  # (on the way out of a loop a blending successor waits for the return: as Buffered)
        start = job.data.get("start", job.target)
        sense = 1.0 if job.target >= start else -1.0
        return job.target, sense, job.dyn.velocity

    # -- amendments ----------------------------------------------------------------------------
    def amend(self, core: CoreContext, i: int, job: Job, req: Mapping[str, Any]) -> Plan | None:
        return change_or_arm(core, i, job, *npv_request(req), self.apply_change)

    def apply_change(self, core: CoreContext, i: int, job: Job, base: int, new_pos: float, new_velo: float) -> Plan:
        """A new target and/or velocity from the current set-point state (the job keeps its CmdNo)."""
        start = core.start_state(i)
        trial = Job(job.kind, job.args, dyn=job.dyn, target=job.target, end_velocity=job.end_velocity,
                    data=dict(job.data))
        if base & int(NPV.CHANGE_POS):
            trial.target = float(new_pos)
            trial.end_velocity = self.end_velocity_after_change(job, trial.target, start.p)
        if base & int(NPV.CHANGE_VELO):
            assert trial.dyn is not None
            trial.dyn = trial.dyn.with_(velocity=float(new_velo))
        if trial.target is None:
            trial.target = start.p
        self.prepare(core, i, trial, start)  # a new profile: the loop and the reduced velocity decided again
        plan = self._plan(core, i, trial, start, core.override(i))
        core.check_target(i, start.p, trial.target, plan)
        sense = trial.target - start.p
        core.check_feed(i, sense)
        # the checks of a start (:meth:`activate`), before anything of the job changes
        if sense:
            core.check_reversal(i, plan, start, 1.0 if sense > 0 else -1.0, trial.target)
        assert trial.dyn is not None
        core.check_overshoot(i, plan, max(trial.dyn.velocity, abs(trial.end_velocity)) * core.override(i))
        job.target, job.dyn, job.end_velocity = trial.target, trial.dyn, trial.end_velocity
        job.data = trial.data  # with the plan's own state (the ramp to the end velocity)
        job.continuous = False
        job.data["start"] = start.p
        return plan

    def end_velocity_after_change(self, job: Job, target: float, p: float) -> float:
        """The end velocity after a new target: at rest (a blending successor blends again)."""
        return 0.0

    # -- loop movement and override type (module docstring) ----------------------------------------
    def prepare(self, core: CoreContext, i: int, job: Job, start: StartState) -> None:
        """Decide what the parameters make of the positioning planned now from ``start``: its loop point
        (``job.data["loop"]``) and, for a reduced override type, the peak velocity of its profile at 100 %
        (``job.data["v_red"]``).

        Raises:
            NcError: 0x4222 (0x4460/0x4461) the loop point beyond an enabled software limit, 0x4223 no feed
                enable for the return.
        """
        assert job.target is not None and job.dyn is not None
        job.data.pop("loop", None)
        job.data.pop("v_red", None)
        p = core.params[i]
        dist = p.AxisLoopingDistance
        sense = job.target - start.p
        if p.AxisEnLoopingDistance and dist and not job.end_velocity and not job.continuous and sense * dist > 0:
            loop = job.target + dist  # reached from the other side: on to the loop point, then back
            core.check_target(i, start.p, loop)
            core.check_feed(i, -sense)
            job.data["loop"] = loop
        if p.AxisOverrideType in (1.0, 3.0):
            job.data["v_red"] = min(self._plan(core, i, job, start, 1.0).peak_velocity, job.dyn.velocity)

    def _travel_dyn(self, core: CoreContext, i: int, job: Job, ov: float) -> Dynamics:
        """The job's dynamics at override ``ov`` (> 0): the velocity is ``ov`` x the commanded one (original
        types), x the peak of its profile at 100 % (reduced types, below 100 %)."""
        assert job.dyn is not None
        dyn = job.dyn.scaled(ov)
        v_red = job.data.get("v_red")
        if v_red is not None and ov < 1.0 and core.params[i].AxisOverrideType in (1.0, 3.0):
            dyn = dyn.with_(velocity=min(dyn.velocity, ov * v_red))
        return dyn

    def override_replan(self, core: CoreContext, i: int, job: Job, start: StartState, old: float,
                        new: float) -> Plan | None:
        """The plan after an override change. Types 1 and 2 (instantaneous): a raise whose new plan's peak
        stays below the new level is not achievable: None, the running plan stays (the job unchanged)."""
        kept = job.data.get("ov_kept", old)  # (the level the running plan was made for, after a kept raise)
        if job.continuous or job.held or not 0.0 < kept < new or core.params[i].AxisOverrideType not in (1.0, 2.0):
            job.data.pop("ov_kept", None)
            return self.replan(core, i, job, start, new)
        trial = job.trial()  # (planning notes its ramp in data: adopted only with the plan)
        plan = self.replan(core, i, trial, start, new)
        if plan is not None and plan.peak_velocity < self._travel_dyn(core, i, trial, new).velocity * (1 - 1e-9):
            job.data["ov_kept"] = kept
            return None
        job.data = trial.data
        job.data.pop("ov_kept", None)
        return plan

    def goal(self, job: Job) -> float | None:
        return job.data.get("loop", job.target)

    def loop_back(self, core: CoreContext, i: int, job: Job) -> bool:
        """At the end of the way out of a loop movement (at rest at the loop point): plan the return to the
        target. False: the job has no loop (pending)."""
        if job.data.pop("loop", None) is None:
            return False
        end, _ = core.plan_end_state(i)
        job.data["start"] = end.p  # (the return's direction: blending, MC_Current_Direction)
        if "v_red" in job.data:
            assert job.dyn is not None
            job.data["v_red"] = min(self._plan(core, i, job, end, 1.0).peak_velocity, job.dyn.velocity)
        core.continue_plan(i, self._plan(core, i, job, end, core.override(i)))
        return True


class RelativeKind(PositionKind):
    def target_of(self, core: CoreContext, i: int, req: Mapping[str, Any], base: float, prev: Job | None) -> float:
        return base + float(req["Distance"])


class AdditiveKind(PositionKind):
    """MC_MoveAdditive: the distance is added to the target of the discrete motion it follows or
    aborts; at rest or in continuous motion, to the set position (PLCopen Part 1)."""

    def target_of(self, core: CoreContext, i: int, req: Mapping[str, Any], base: float, prev: Job | None) -> float:
        if prev is not None and prev.target is not None and not prev.continuous and not prev.kind.is_stop:
            return prev.target + float(req["Distance"])
        return base + float(req["Distance"])


class ModuloKind(PositionKind):
    """MC_MoveModulo (TcMC 3.4, 3.5).

    From standstill, and queued behind a job with a target (Buffered: at rest there), the TcMC 3.5 rules
    (:func:`modulo_target`): Direction, the modulo tolerance window, Position >= period adds full turns
    (not with MC_Shortest_Way: 0x4282). MC_Current_Direction: the direction of the current motion -- of
    a job queued behind another, the direction that job travels in (a blend then passes its target
    moving on). A queued target refers to the previous job's target (PLCopen) and is fixed when accepted.

    Started during motion (|set velocity| > 1e-9 u/s when it takes over: Aborting a motion, or queued
    behind a job without a target such as MC_MoveVelocity): TcMC 3.4/3.5 speak only of starts from
    standstill. Moving is the NC's own notion (the set velocity is not 0, as TwinCAT's logical
    standstill), not a threshold of its own: a start in the last cycles of a stop counts as moving (e.g.
    in a MC_Halt's last cycle, at 0.02 u/s with 1e-5 u to go: a Direction against it costs a turn);
    to get the standstill rule, start it after standstill or buffered (MC_Buffered) behind the stop.
    This NC follows Beckhoff's later libraries (Tc2_MC2 MC_MoveModulo: "If an axis is already in
    motion ... The direction of movement cannot be reversed by MC_MoveModulo, i.e. the target can only
    be reached in the current direction. The user is not able to specify the number of additional
    turns. The system automatically calculates how the axis can be moved to the target position on the
    shortest possible path."): the end position is the first position with the modulo value of
    Position (Position mod period: Position >= period adds no turns) in the current direction of motion
    at or beyond the point where the axis can come to rest with the move's own Deceleration and Jerk
    (0 = AxisDec/AxisJerk) (:func:`modulo_beyond_stop`, as MC_OrientedStop). Where that way to rest
    turns (a braking motion, e.g. a reversing positioning just before its velocity crosses 0, whose
    acceleration the running motion's jerk cannot bring to 0 in time: the axis is committed to the turn),
    the current direction is the one after the turn and the end lies at or beyond the rest point in it
    (the axis turns once, as it must, and not back again). A turn that only the move's own weaker Jerk
    causes is not committed: refused, 0x4289 (as any start). Decisions: the current
    direction wins over every Direction, an explicit opposite one and MC_Shortest_Way included (turning
    back may be shorter, but reverses the motion); Direction and Position are still checked as at
    standstill (0x4B04, 0x4282 also for Position >= period with MC_Shortest_Way), so a command is valid
    or not whatever the axis does. The modulo tolerance window plays no role (it is for a set position
    after a reset, at rest). The end position is computed at the activation, from the state the job
    starts from (:meth:`start_target`; a command that starts now is prepared from its activation cycle's
    state and prepared again where that no longer holds). A software limit before it: 0x4222, refused as
    every move.

    Blending modes: the predecessor passes its target with a velocity from which this job can come to
    rest within its distance from where it takes over, at the cycle boundary after that target
    (``JobKind.blend_velocity``), so the queued target stays (extra turns included) and the axis does not
    turn. Only where the axis moves when the job takes over and that
    target lies before its rest point (e.g. behind MC_MoveContinuousAbsolute, which moves on past its
    target) the moving rule replaces it.
    """

    def target_of(self, core: CoreContext, i: int, req: Mapping[str, Any], base: float, prev: Job | None) -> float:
        p = core.params[i]
        if prev is not None and req.get("BufferMode", 0) != 0:  # queued behind prev
            start = prev.data.get("start", prev.target)
            velo = prev.velocity or (prev.target - start if prev.target is not None and start is not None else 0.0)
        else:
            velo = float(core.axes.set_velo[i])
        return modulo_target(base, float(req["Position"]), p.AxisEncoderModuloValue, p.AxisModuloToleranceWindow,
                             int(req["Direction"]), velo)

    def accept(self, core: CoreContext, i: int, req: Mapping[str, Any], prev: Job | None) -> Job:
        job = super().accept(core, i, req, prev)
        if prev is not None and req.get("BufferMode", 0) != 0 and not job.data.get("from_start"):
            job.data["queued"] = True  # the target refers to prev's target
        return job

    def start_target(self, core: CoreContext, i: int, job: Job, start: StartState) -> None:
        super().start_target(core, i, job, start)
        if abs(start.v) <= _EPS_V:
            return  # from standstill: as accepted
        assert job.target is not None and job.dyn is not None
        period = core.params[i].AxisEncoderModuloValue
        position = modulo_position(float(job.args["Position"]), period)
        jerk = running_jerk(core.axes, i, core.queues[i].active)  # (the running motion's, as the reversal check's)
        end, sense, _ = modulo_beyond_stop(core, i, start, position, job.dyn, jerk)
        if job.data.get("queued") and (job.target - end) * sense > -period / 2:
            return  # the queued target lies at or beyond the rest point: it stays (module docstring)
        job.target = end


class ContinuousKind(PositionKind):
    """MC_MoveContinuousAbsolute/Relative (Tc2_MC2): reach the target with EndVelocity, then keep
    that velocity as a continuous motion (ContinuousMotion from the target on: the block's
    InEndVelocity) until another command takes over. EndVelocity 0 behaves like a discrete move
    (ends at rest, Done)."""

    def __init__(self, name: str, relative: bool) -> None:
        super().__init__(name)
        self.relative = relative

    def target_of(self, core: CoreContext, i: int, req: Mapping[str, Any], base: float, prev: Job | None) -> float:
        return base + float(req["Distance"]) if self.relative else float(req["Position"])

    def end_velocity_of(self, core: CoreContext, i: int, req: Mapping[str, Any], target: float, base: float) -> float:
        ve = float(req["EndVelocity"])
        if abs(ve) > core.axes.vmax[i] * (1 + 1e-12):
            raise NcError(ErrorCodes.NC_VELOCITY_NOT_ALLOWED, f"EndVelocity {ve} beyond AxisVeloMax {core.axes.vmax[i]}")
        sense = 1.0 if target >= base else -1.0
        return sense * abs(ve)

    def end_velocity_after_change(self, job: Job, target: float, p: float) -> float:
        """A new target is passed with EndVelocity as well (in the direction it lies in)."""
        return math.copysign(abs(job.end_velocity), target - p) if job.end_velocity and target != p else 0.0

    def apply_change(self, core: CoreContext, i: int, job: Job, base: int, new_pos: float, new_velo: float) -> Plan:
        if job.continuous and not base & int(NPV.CHANGE_POS):
            # past the target, endless at EndVelocity: a new velocity is the new endless velocity
            assert job.dyn is not None
            sense = 1.0 if job.end_velocity > 0 else -1.0
            core.check_feed(i, sense)
            start = core.start_state(i)
            plan = core.plan(plan_velocity, start, sense * new_velo * core.override(i), job.dyn)
            core.check_reversal(i, plan, start, sense)
            core.check_overshoot(i, plan, new_velo * core.override(i))
            job.end_velocity = sense * new_velo
            return plan
        return super().apply_change(core, i, job, base, new_pos, new_velo)

    def on_end(self, core: CoreContext, i: int, job: Job) -> str:
        if job.phase:  # stopped exactly at a software limit (as MoveVelocity): 0x4462/0x4463
            from .velocity import end_velocity
            return end_velocity(core, i, job)
        if job.held:
            return "steady"
        if self.loop_back(core, i, job):  # (EndVelocity 0: a positioning that ends at rest may loop)
            return "continue"
        if self.start_ramp(core, i, job):
            return "continue"
        if job.end_velocity:
            job.continuous = True  # past the target: endless at EndVelocity
            return "steady"
        return "done"

    def successor_may_start(self, core: CoreContext, i: int, job: Job) -> bool:
        return job.continuous

    def wants_watch(self, job: Job) -> bool:
        return "switch" in job.data or (bool(job.end_velocity) and job.data.get("limits", False) and not job.phase)

    def watch(self, core: CoreContext, rows: np.ndarray) -> None:
        from .velocity import limit_approach
        switch = np.array([("switch" in core.queues[i].active.data) for i in rows.tolist()], dtype=bool)
        if switch.any():
            _switch_reached(core, rows[switch])
        rest = rows[~switch]
        if rest.size:  # endless beyond the target: stop exactly at an enabled software limit
            limit_approach(core, rest)

    def activate(self, core: CoreContext, i: int, job: Job, start: StartState) -> Plan:
        plan = super().activate(core, i, job, start)
        a = core.axes
        job.data["limits"] = bool(a.en_max[i] or a.en_min[i])
        job.phase = 0
        return plan


class RestartKind(PositionKind):
    """MC_MoveAbsoluteOrRestart: on a moving axis the new target and velocity take over with the
    running motion's dynamics (TcMC 3.6: Acceleration/Deceleration/Jerk only count from rest)."""

    buffer_modes = frozenset({0})

    def accept(self, core: CoreContext, i: int, req: Mapping[str, Any], prev: Job | None) -> Job:
        job = super().accept(core, i, req, prev)
        running = core.queues[i].running_numbered
        if running is not None and running.dyn is not None and core.axes.traj_on[i] and not running.kind.is_stop:
            assert job.dyn is not None
            job.dyn = Dynamics(job.dyn.velocity, running.dyn.acceleration, running.dyn.deceleration, running.dyn.jerk)
        return job


def _turns(plan: Plan, sense: float) -> bool:
    """The plan's velocity changes to the other direction somewhere (before or after the target)."""
    lo, hi = velocity_extrema(plan.seg)
    return lo < -1e-9 if sense > 0 else hi > 1e-9


def travel_sense(core: CoreContext, i: int, job: Job) -> float:
    """The direction of travel (+1/-1) of row ``i``'s running ``job``: of the set velocity, and where
    that is 0 (all but standing, e.g. at override 0) the direction the job heads in (its target, or
    a velocity job's velocity)."""
    v = float(core.axes.set_velo[i])
    if abs(v) > 1e-9:
        return 1.0 if v > 0 else -1.0
    if job.target is None:
        return -1.0 if job.velocity < 0 else 1.0
    return 1.0 if job.target >= float(core.axes.set_pos[i]) else -1.0


def npv_request(req: Mapping[str, Any]) -> tuple[int, float, float, float]:
    """(Mode, NewPos [u], NewVelo [u/s], ActivationPos [u]) of an MC_NewPos / MC_NewPosAndVelo request
    (MC_NewPos: CHANGE_POS).

    Raises:
        NcError: MC_INVALID_MODE, Mode is not an E_CmdTypeNewTargPosAndVelo.
    """
    if req["cmd"] == "NewPos":
        return int(NPV.CHANGE_POS), req["NewPos"], 0.0, 0.0
    mode = req["Mode"]
    if mode not in {int(m) for m in NPV}:
        raise NcError(ErrorCodes.MC_INVALID_MODE, f"Mode {mode} is not an E_CmdTypeNewTargPosAndVelo")
    return mode, req["NewPos"], req["NewVelo"], req["ActivationPos"]


def change_or_arm(core: CoreContext, i: int, job: Job, mode: int, new_pos: float, new_velo: float, at: float,
                  apply: Callable[[CoreContext, int, Job, int, float, float], Plan]) -> Plan | None:
    """An amendment of the running ``job`` (any kind with an ``apply_change``): the new values checked
    (0x4221 velocity, 0x4222 target), then ``apply(core, i, job, base, new_pos, new_velo)`` now
    (modes 1, 2, 3) or armed for its switching position (9, 10, 11, 14: :func:`arm_switch`, None)."""
    base = mode & 3 if mode != int(NPV.REACH_VELO_AT_POS) else int(NPV.CHANGE_VELO)
    if base & int(NPV.CHANGE_VELO):
        core.check_velocity(i, new_velo)
    if base & int(NPV.CHANGE_POS):
        core.check_target(i, core.nc_set_pos(i), new_pos)
    if mode in (int(NPV.CHANGE_POS), int(NPV.CHANGE_VELO), int(NPV.CHANGE_POSANDVELO)):
        return apply(core, i, job, base, new_pos, new_velo)
    arm_switch(core, i, job, mode, at, new_pos, new_velo)  # applied by the kind's watch
    return None


def arm_switch(core: CoreContext, i: int, job: Job, mode: int, at: float, new_pos: float, new_velo: float) -> None:
    """Arm a NewPosAndVelo switching-position change (modes 9, 10, 11, 14) on the running ``job``
    of any kind with an ``apply_change`` (positionings, MoveVelocity): the kind's watch applies it
    when the set position passes ``at`` [u] in the direction of travel (:func:`_switch_reached`).

    Decision (TcMC 3.8 is silent): an ActivationPos the set position has already passed in the
    direction of travel is refused with 0x427F "new target position has been /
    would be overrun" (the closest code of TwinCAT's NC list: the switching point lies behind the
    axis) and changes nothing; exactly at ActivationPos counts as not passed (applied at once in the
    next watch). Before, a passed ActivationPos switched at once.

    Raises:
        NcError: 0x427F ActivationPos already passed.
    """
    sense = travel_sense(core, i, job)
    p = float(core.axes.set_pos[i])
    if (p - at) * sense > 0:
        raise NcError(ErrorCodes.NC_NEW_TARGET_OVERRUN,
                      f"ActivationPos {at:g} has already been passed (set position {p:g}, direction {sense:+g})")
    job.data["switch"] = (int(mode), float(at), float(new_pos), float(new_velo))


def _switch_reached(core: CoreContext, rows: np.ndarray) -> None:
    """Apply NewPosAndVelo changes armed at a switching position (the watch of positionings and of
    MoveVelocity: :func:`arm_switch`). The change runs the checks of a start when it fires
    (``apply_change``: 0x4289, 0x423A, ...); the command was acknowledged at arming, so a failed
    check faults the axis with its code (ErrorStop) instead of a refusal."""
    a = core.axes
    for i in rows.tolist():
        job = core.queues[i].active
        if job is None or "switch" not in job.data:
            continue
        mode, at, new_pos, new_velo = job.data["switch"]
        v = float(a.set_velo[i])
        p = float(a.set_pos[i])
        sense = travel_sense(core, i, job)
        if mode == int(NPV.REACH_VELO_AT_POS):
            # start the change so that the new velocity is reached at ActivationPos
            assert job.dyn is not None
            need = core.plan(plan_velocity, StartState(0.0, v, float(a.set_acc[i])), sense * new_velo, job.dyn).end.p
            due = (at - p) * sense <= abs(need) + abs(v) * core.cycle_time
            base = int(NPV.CHANGE_VELO)
        else:
            due = (p - at) * sense >= 0
            base = mode & 3
        if due:
            del job.data["switch"]
            try:
                plan = job.kind.apply_change(core, i, job, base, new_pos, new_velo)
            except NcError as err:
                core.fault(i, err.code)
                continue
            core.set_plan(i, plan)
            if job.target is not None:
                a.target_pos[i] = job.target


def kinds() -> list[JobKind]:
    out: list[JobKind] = [PositionKind("MoveAbsolute"), RelativeKind("MoveRelative"), AdditiveKind("MoveAdditive"),
                          ModuloKind("MoveModulo"), ContinuousKind("MoveContinuousAbsolute", False),
                          ContinuousKind("MoveContinuousRelative", True), RestartKind("MoveAbsoluteOrRestart")]
    return out
