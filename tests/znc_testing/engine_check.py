"""A per-cycle checker for the motion engine: step an NcCore and check every cycle's set-points and
job records against the limits and the contract, independently of the engine's own planning.

Per cycle (from consecutive NCTOPLC samples of one axis):

* |SetVelo| <= the velocity limit, |SetAcc| <= max(acc, dec), |SetJerk| <= jerk (+ a small eps);
* no set-point jump: SetPos advances by the trapezoid of the two SetVelo samples (exact up to
  jerk * dt^3 / 12 for a constant-jerk motion), SetVelo by at most acc * dt, SetAcc by at most jerk * dt
  (a declared shift, e.g. MC_SetActualPositionOnTheFly, is allowed once);
* velocity floors (:meth:`Trace.floor`, derived by :meth:`Trace.learn` from commands and override
  changes): a transition to a lower velocity reaches it from above -- once the set velocity, in the
  direction of travel, is below the floor it never rises again while the job runs (it may brake on to
  its target, or through 0 and back: past the target and back), except by float noise;
* NCJOBS agrees with NCTOPLC: ActiveCmdNo/ActiveState == CmdNo/CmdState, CmdBuffered <=> a waiting job,
  a waiting job has the newest number, HasJob <=> the shown job is ACTIVE, the Ended fates are final
  (a number once ended keeps its fate), CmdNo never goes back.
"""
from __future__ import annotations

import math
from typing import Any, Callable

import numpy as np

from nc_schema import NCJOBS_DTYPE, NCTOPLC_DTYPE, CmdState, StateDWord
from nc_server.core import NcCore
from znc_testing.nc_core import cmd as _cmd
from znc_testing.until import step_until

_ENDED = {int(CmdState.DONE), int(CmdState.ABORTED), int(CmdState.ERROR)}
_ACTIVE, _ERROR = int(CmdState.ACTIVE), int(CmdState.ERROR)
_LOOP, _BUF, _HASJOB = int(StateDWord.ControlLoopClosed), int(StateDWord.CmdBuffered), int(StateDWord.HasJob)
_JOB_BITS = _BUF | _HASJOB
#: commands whose Velocity input is a position job's or a velocity job's travel velocity at 100 % override
_VELOCITY_CMDS = {"MoveAbsolute", "MoveRelative", "MoveAdditive", "MoveModulo", "MoveContinuousAbsolute",
                  "MoveContinuousRelative", "MoveAbsoluteOrRestart", "MoveVelocity"}
_CHANGE_VELO = 2  # E_CmdTypeNewTargPosAndVelo bit: a new velocity
_REACH_VELO_AT_POS = 14
_F = NCTOPLC_DTYPE.names
_P, _V, _A, _J, _AP, _SD, _NO, _ST = (_F.index(n) for n in (
    "SetPos", "SetVelo", "SetAcc", "SetJerk", "ActPos", "StateDWord", "CmdNo", "CmdState"))
assert NCJOBS_DTYPE.names[1:8] == ("ActiveCmdNo", "ActiveState", "BufferedCmdNo", "BufferedMode", "NewestCmdNo",
                                   "Flags", "Ended")


class Trace:
    """Steps ``core`` and checks axis row ``i`` in every cycle; keeps the samples.

    Args:
        vmax, amax, jerk: the limits (default: AxisVeloMax, max(AxisAcc, AxisDec), AxisJerk of the axis,
            read when the trace starts).
        check_jumps: check the velocity/acceleration steps (off for tests that change the dynamics).
        before_step: called before every step (e.g. a cam simulated from the last sample's ActPos).
        shift_ok: ``shift_ok(prev, sample)`` true where the position may be set (SetPos and ActPos jump
            by the same amount: PosDiff stays continuous), e.g. at the end of homing.
        floors: check velocity floors, learnt (:meth:`learn`) from every command the core executes for
            this axis and from every change of the axis's applied override.
    """

    def __init__(self, core: NcCore, i: int = 0, vmax: float | None = None, amax: float | None = None,
                 jerk: float | None = None, check_jumps: bool = True,
                 before_step: Callable[[], Any] | None = None,
                 shift_ok: Callable[[np.void, np.void], Any] | None = None, floors: bool = True) -> None:
        p = core.params[i]
        self.core, self.i = core, i
        self.vmax = p.AxisVeloMax if vmax is None else vmax
        self.amax = max(p.AxisAcc, p.AxisDec) if amax is None else amax
        self.jerk = p.AxisJerk if jerk is None else jerk
        self.check_jumps = check_jumps
        self.before_step = before_step
        self.shift_ok = shift_ok
        self.dt = core.cycle_time
        self.rows: list[np.void] = []    # NCTOPLC samples, one per cycle
        self.jobs: list[np.void] = []    # NCJOBS samples
        self.cycles: list[int] = []
        self.fates: dict[int, tuple[int, int]] = {}
        self._shift = 0.0
        self._job_key: tuple[Any, ...] | None = None
        self._prev = core.nctoplc[i].copy()
        self._prev_jobs = core.ncjobs[i].copy()
        # velocity floors by CmdNo: [floor u/s, jerk u/s^3, armed: (direction, effective floor) or None,
        # lowest velocity since it went below the floor or None]
        self._floors: dict[int, list[Any]] = {}
        self._learned: dict[int, tuple[float, float]] = {}  # CmdNo -> (velocity at 100 %, jerk)
        self._override = float(core.override(i))
        self.floors = floors
        if floors:
            _learn_from(core, self)

    # -- velocity floors -------------------------------------------------------------------------
    def floor(self, v: float, cmd_no: int, jerk: float | None = None) -> None:
        """Check from now on that job ``cmd_no`` reaches the velocity ``v`` [u/s, > 0] from above.

        Armed at the first sample that shows ``cmd_no`` ACTIVE, from the sample before it (the state
        the job's plan starts from): only when that state is faster than ``v`` or its acceleration will
        carry it past ``v`` (a reduction). Already braking harder than ``v`` allows (|v0| - a0^2 / (2 *
        jerk) below it, ``jerk`` [u/s^3] the job's, default the trace's): the floor is that least dip.
        Armed, the set velocity in the direction of travel may go below the floor only for good (the
        brake to the target, past it and back): rising again while positive fails. A later call for the
        same job replaces the floor; ``v`` <= 0 removes it."""
        if v <= 0:
            self._floors.pop(cmd_no, None)
            return
        self._floors[cmd_no] = [float(v), float(jerk or self.jerk), None, None]

    def learn(self, name: str, args: dict[str, Any], reply: dict[str, Any] | None = None) -> None:
        """Derive the velocity floors from a command ``name`` with ``args`` and its ``reply`` (refused:
        nothing), or from an override change (``name`` "Override", ``args`` {"Override": 0..1}).

        A move with a Velocity: its Velocity x override for its CmdNo (a buffered one when it starts);
        MC_NewPosAndVelo with a new velocity (modes with CHANGE_VELO, REACH_VELO_AT_POS): NewVelo x
        override for the job; MC_ChangeDynParam: the job's floor again with its new Jerk; an override
        change: every learned job's velocity x the new override. A new target behind the axis (its way
        turns back) removes the job's floor."""
        if name == "Override":
            self._override = float(args["Override"])
            for no, (v100, jerk) in self._learned.items():
                self.floor(v100 * self._override, no, jerk)
            return
        if reply is not None and reply.get("error"):
            return
        jerk = float(args.get("Jerk") or self.core.params[self.i].AxisJerk)
        no = int(reply["CmdNo"]) if reply is not None and "CmdNo" in reply else int(self.core.nctoplc[self.i]["CmdNo"])
        v100: float | None = None
        if name in _VELOCITY_CMDS and args.get("Velocity"):
            v100 = abs(float(args["Velocity"]))
        elif name == "NewPosAndVelo":
            mode = int(args.get("Mode", 0))
            if mode & _CHANGE_VELO or mode == _REACH_VELO_AT_POS:
                v100 = float(args["NewVelo"])
            elif no in self._learned:
                v100, jerk = self._learned[no]
        elif name == "ChangeDynParam" and no in self._learned:
            v100 = self._learned[no][0]
        elif name == "NewPos" and no in self._learned:
            v100, jerk = self._learned[no]
        if v100 is None:
            return
        if name in ("NewPos", "NewPosAndVelo") and "NewPos" in args:
            r = self.core.nctoplc[self.i]
            if (float(args["NewPos"]) - float(r["SetPos"])) * float(r["SetVelo"]) < 0:
                self._floors.pop(no, None)  # the way turns back: no reduction in the direction of travel
                self._learned.pop(no, None)
                return
        self._learned[no] = (v100, jerk)
        self.floor(v100 * self._override, no, jerk)

    def cmd(self, name: str, **args: Any) -> dict[str, Any]:
        """Send command ``name`` to this trace's axis (its floors learnt)."""
        reply = _cmd(self.core, name, int(self.core.axis_ids[self.i]), **args)
        if not self.floors:
            self.learn(name, args, reply)
        return reply

    def _check_floor(self, p: tuple[Any, ...], r: tuple[Any, ...], c: int) -> None:
        no = r[_NO]
        for k in [k for k, f in self._floors.items() if f[2] is not None and k != no]:
            del self._floors[k]  # armed for a job that no longer runs
        f = self._floors.get(no)
        if f is None or r[_ST] != _ACTIVE:
            return
        v_floor, jerk, armed, low = f
        tol = 1e-7 * v_floor + 1e-9
        if armed is None:
            v0, a0 = p[_V], p[_A]
            d = 1.0 if v0 > 0 else -1.0 if v0 < 0 else 0.0
            s, acc = v0 * d, a0 * d
            if not d or s + max(acc, 0.0) ** 2 / (2 * jerk) <= v_floor + tol:
                del self._floors[no]  # not a reduction: nothing to check
                return
            least = s - min(acc, 0.0) ** 2 / (2 * jerk)  # already braking: the least dip the jerk allows
            armed = f[2] = (d, min(v_floor, least))
        d, eff = armed
        s = r[_V] * d
        if low is None:
            if s < eff - tol:
                f[3] = s
            return
        assert not (s > 0 and s > low + tol), (
            f"cycle {c}: SetVelo rose again to {s} after dipping to {low} below the floor {eff} (CmdNo {no})")
        f[3] = min(low, s)

    # -- driving ---------------------------------------------------------------------------------
    def shift(self, diff: float) -> None:
        """The next sample's SetPos may jump by ``diff`` (a declared position shift)."""
        self._shift += diff

    def step(self, n: int = 1) -> np.void:
        for _ in range(n):
            if self.before_step is not None:
                self.before_step()
            self.core.step()
            self._take()
        return self.rows[-1]

    def take(self) -> np.void:
        """Check and keep the current sample without stepping: several traces of one core (one per
        axis, e.g. a master and its slaves) -- the caller steps the core, each trace takes its row."""
        self._take()
        return self.rows[-1]

    def until(self, pred: Callable[[np.void], Any], max_cycles: int = 20_000) -> int:
        """Step until ``pred(sample)``; returns the number of steps."""
        return step_until(self.step, lambda: pred(self.rows[-1]), max_cycles)

    def settle(self, max_cycles: int = 20_000) -> int:
        """Step until the axis has no job and no set velocity."""
        return self.until(lambda r: not r["StateDWord"] & StateDWord.HasJob and r["SetVelo"] == 0.0
                          and not self.core.axes.traj_on[self.i], max_cycles)

    # -- the samples -----------------------------------------------------------------------------
    def col(self, name: str) -> np.ndarray:
        return np.array([float(r[name]) for r in self.rows])

    def job_col(self, name: str) -> np.ndarray:
        return np.array([int(j[name]) for j in self.jobs])

    def first(self, pred: Callable[[np.void, np.void], Any]) -> int:
        """Index of the first sample (row, jobs) for which ``pred`` is true."""
        return next(k for k, (r, j) in enumerate(zip(self.rows, self.jobs)) if pred(r, j))

    def fate(self, cmd_no: int) -> tuple[int, int] | None:
        """(CmdState, ErrorId) of an ended job as the records showed it."""
        return self.fates.get(cmd_no)

    # -- the checks ------------------------------------------------------------------------------
    def _take(self) -> None:
        if self.floors:
            ov = float(self.core.override(self.i))
            if ov != self._override:  # the override applied in this step: the floors from its start
                self.learn("Override", {"Override": ov})
        r = self.core.nctoplc[self.i].copy()
        j = self.core.ncjobs[self.i].copy()
        self._check(self._prev, r, j)
        self.rows.append(r)
        self.jobs.append(j)
        self.cycles.append(self.core.cycle)
        self._prev, self._prev_jobs = r, j

    def _check(self, p: np.void, r: np.void, j: np.void) -> None:
        dt, c = self.dt, self.core.cycle
        pt, rt = p.item(), r.item()
        v, a, jk = rt[_V], rt[_A], rt[_J]
        # eps: rounding of the planner (relative 1e-6), never a real excess
        assert abs(v) <= self.vmax * (1 + 1e-9) + 1e-9, f"cycle {c}: |SetVelo| {v} > {self.vmax}"
        assert abs(a) <= self.amax * (1 + 1e-6) + 1e-6, f"cycle {c}: |SetAcc| {a} > {self.amax}"
        assert abs(jk) <= self.jerk * (1 + 1e-6) + 1e-6, f"cycle {c}: |SetJerk| {jk} > {self.jerk}"
        if self._floors:
            self._check_floor(pt, rt, c)
        sd, psd = rt[_SD], pt[_SD]
        enabled = bool(sd & _LOOP) and bool(psd & _LOOP)
        if enabled and self.shift_ok is not None and self.shift_ok(p, r):
            jump = rt[_AP] - pt[_AP] - (rt[_P] - pt[_P])
            assert abs(jump) <= self.vmax * dt * 2, f"cycle {c}: a position set with a lag jump {jump}"
            self._shift = rt[_P] - pt[_P] - 0.5 * (pt[_V] + v) * dt
        if enabled:
            dp = rt[_P] - pt[_P] - self._shift
            expect = 0.5 * (pt[_V] + v) * dt
            tol = self.jerk * dt ** 3 / 6 + 1e-9 * max(1.0, abs(rt[_P]))
            assert abs(dp - expect) <= tol, (
                f"cycle {c}: SetPos jump: moved {dp}, the velocities say {expect} (tol {tol})")
            if self.check_jumps:
                dv = v - pt[_V]
                assert abs(dv) <= self.amax * dt * (1 + 1e-6) + 1e-9, f"cycle {c}: SetVelo jump {dv}"
                da = a - pt[_A]
                assert abs(da) <= self.jerk * dt * (1 + 1e-6) + 1e-6, f"cycle {c}: SetAcc jump {da}"
        self._shift = 0.0
        # job records against NCTOPLC (only when something of them changed)
        key = (j.tobytes(), rt[_NO], rt[_ST], sd & _JOB_BITS)
        if key == self._job_key:
            return
        self._job_key = key
        jt = j.item()
        no_r, st_r = rt[_NO], rt[_ST]
        active, active_st, buffered, mode, newest = jt[1], jt[2], jt[3], jt[4], jt[5]
        assert active == no_r and active_st == st_r, (
            f"cycle {c}: NCJOBS active {active}/{active_st} != NCTOPLC {no_r}/{st_r}")
        assert bool(buffered) == bool(sd & _BUF), f"cycle {c}: CmdBuffered vs BufferedCmdNo {buffered}"
        if buffered:
            assert buffered == newest, f"cycle {c}: the waiting job {buffered} is not the newest"
            assert buffered != active
        else:
            assert mode == 0
        if sd & _HASJOB:
            assert st_r == _ACTIVE, f"cycle {c}: HasJob but CmdState {st_r}"
        if st_r == _ACTIVE:
            assert sd & _HASJOB, f"cycle {c}: CmdState ACTIVE without HasJob"
        old = pt[_NO]
        if old and no_r != old:
            assert 0 < (no_r - old) % 65536 < 32768, f"cycle {c}: CmdNo went back {old} -> {no_r}"
        seen = set()
        for no, st, err in jt[7].tolist():
            if not no:
                continue
            assert no not in seen, f"cycle {c}: {no} twice in Ended"
            seen.add(no)
            assert st in _ENDED, f"cycle {c}: Ended {no} with state {st}"
            assert err == 0 or st == _ERROR
            assert no != buffered, f"cycle {c}: {no} both ended and waiting"
            if no in self.fates:
                assert self.fates[no] == (st, err), f"cycle {c}: the fate of {no} changed {self.fates[no]} -> {(st, err)}"
            self.fates[no] = (st, err)


def _learn_from(core: NcCore, tr: Trace) -> None:
    """Let ``tr`` learn its floors from every request ``core.execute`` runs for its axis (one wrapper
    per core, shared by its traces)."""
    execute = core.execute
    traces: list[Trace] | None = getattr(execute, "traces", None)
    if traces is None:
        traces = []

        def learning(request: dict[str, Any], axis_id: int | None) -> dict[str, Any]:
            reply: dict[str, Any] = execute(request, axis_id)
            for t in traces:
                if axis_id is not None and int(t.core.axis_ids[t.i]) == axis_id:
                    t.learn(str(request.get("cmd")), request, reply)
            return reply

        learning.traces = traces  # type: ignore[attr-defined]
        core.execute = learning  # type: ignore[method-assign]
    traces.append(tr)


def velocity_at(tr: Trace, pos: float) -> float:
    """|SetVelo| where SetPos passes ``pos`` (linear between the two samples around it)."""
    p, v = tr.col("SetPos"), np.abs(tr.col("SetVelo"))
    for k in range(1, len(p)):
        if (p[k - 1] - pos) * (p[k] - pos) <= 0 and p[k] != p[k - 1]:
            w = (pos - p[k - 1]) / (p[k] - p[k - 1])
            return float(v[k - 1] + w * (v[k] - v[k - 1]))
    raise AssertionError(f"SetPos never passes {pos}")


def ruckig_duration(p0: float, p1: float, v: float, acc: float, dec: float, jerk: float,
                    v0: float = 0.0, v1: float = 0.0) -> float:
    """Duration of the time-optimal jerk-limited move p0 -> p1 (an independent reference: ruckig called
    here directly, not through the engine's planning)."""
    from ruckig import InputParameter, Result, Ruckig, Trajectory

    otg, inp, traj = Ruckig(1), InputParameter(1), Trajectory(1)
    inp.current_position, inp.current_velocity, inp.current_acceleration = [p0], [v0], [0.0]
    inp.target_position, inp.target_velocity, inp.target_acceleration = [p1], [v1], [0.0]
    inp.max_velocity = [v]
    up, down = (acc, dec) if p1 >= p0 else (dec, acc)
    inp.max_acceleration, inp.min_acceleration, inp.max_jerk = [up], [-down], [jerk]
    assert otg.calculate(inp, traj) in (Result.Working, Result.Finished)
    return float(traj.duration)


def cycles_for(duration: float, dt: float) -> int:
    """Steps a plan of ``duration`` takes: its end is the step whose time reaches it."""
    return math.ceil(duration / dt - 1e-6)
