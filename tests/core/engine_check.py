"""A per-cycle checker for the motion engine: step an NcCore and check every cycle's set-points and
job records against the limits and the contract, independently of the engine's own planning.

Per cycle (from consecutive NCTOPLC samples of one axis):

* |SetVelo| <= the velocity limit, |SetAcc| <= max(acc, dec), |SetJerk| <= jerk (+ a small eps);
* no set-point jump: SetPos advances by the trapezoid of the two SetVelo samples (exact up to
  jerk * dt^3 / 12 for a constant-jerk motion), SetVelo by at most acc * dt, SetAcc by at most jerk * dt
  (a declared shift, e.g. MC_SetActualPositionOnTheFly, is allowed once);
* NCJOBS agrees with NCTOPLC: ActiveCmdNo/ActiveState == CmdNo/CmdState, CmdBuffered <=> a waiting job,
  a waiting job has the newest number, HasJob <=> the shown job is ACTIVE, the Ended fates are final
  (a number once ended keeps its fate), CmdNo never goes back.
"""
from __future__ import annotations

import math
from typing import Any, Callable

import numpy as np

from nc_schema import CmdState, StateDWord
from nc_server.core import NcCore

_ENDED = {int(CmdState.DONE), int(CmdState.ABORTED), int(CmdState.ERROR)}


class Trace:
    """Steps ``core`` and checks axis row ``i`` in every cycle; keeps the samples.

    Args:
        vmax, amax, jerk: the limits (default: AxisVeloMax, max(AxisAcc, AxisDec), AxisJerk of the axis,
            read when the trace starts).
        check_jumps: check the velocity/acceleration steps (off for tests that change the dynamics).
        before_step: called before every step (e.g. a cam simulated from the last sample's ActPos).
        shift_ok: ``shift_ok(prev, sample)`` true where the position may be set (SetPos and ActPos jump
            by the same amount: PosDiff stays continuous), e.g. at the end of homing.
    """

    def __init__(self, core: NcCore, i: int = 0, vmax: float | None = None, amax: float | None = None,
                 jerk: float | None = None, check_jumps: bool = True,
                 before_step: Callable[[], Any] | None = None,
                 shift_ok: Callable[[np.void, np.void], Any] | None = None) -> None:
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
        self._prev = core.nctoplc[i].copy()
        self._prev_jobs = core.ncjobs[i].copy()

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

    def until(self, pred: Callable[[np.void], Any], max_cycles: int = 20_000) -> int:
        """Step until ``pred(sample)``; returns the number of steps."""
        for k in range(1, max_cycles + 1):
            if pred(self.step()):
                return k
        raise AssertionError(f"condition not reached within {max_cycles} cycles")

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
        r = self.core.nctoplc[self.i].copy()
        j = self.core.ncjobs[self.i].copy()
        self._check(self._prev, r, j)
        self.rows.append(r)
        self.jobs.append(j)
        self.cycles.append(self.core.cycle)
        self._prev, self._prev_jobs = r, j

    def _check(self, p: np.void, r: np.void, j: np.void) -> None:
        dt, c = self.dt, self.core.cycle
        v, a, jk = float(r["SetVelo"]), float(r["SetAcc"]), float(r["SetJerk"])
        assert abs(v) <= self.vmax * (1 + 1e-9) + 1e-9, f"cycle {c}: |SetVelo| {v} > {self.vmax}"
        assert abs(a) <= self.amax * (1 + 1e-9) + 1e-6, f"cycle {c}: |SetAcc| {a} > {self.amax}"
        assert abs(jk) <= self.jerk * (1 + 1e-9) + 1e-6, f"cycle {c}: |SetJerk| {jk} > {self.jerk}"
        enabled = bool(r["StateDWord"] & StateDWord.ControlLoopClosed) and bool(p["StateDWord"] & StateDWord.ControlLoopClosed)
        if enabled and self.shift_ok is not None and self.shift_ok(p, r):
            jump = float(r["ActPos"]) - float(p["ActPos"]) - (float(r["SetPos"]) - float(p["SetPos"]))
            assert abs(jump) <= self.vmax * dt * 2, f"cycle {c}: a position set with a lag jump {jump}"
            self._shift = float(r["SetPos"]) - float(p["SetPos"]) - 0.5 * (float(p["SetVelo"]) + v) * dt
        if enabled:
            dp = float(r["SetPos"]) - float(p["SetPos"]) - self._shift
            expect = 0.5 * (float(p["SetVelo"]) + v) * dt
            tol = self.jerk * dt ** 3 / 6 + 1e-9 * max(1.0, abs(float(r["SetPos"])))
            assert abs(dp - expect) <= tol, (
                f"cycle {c}: SetPos jump: moved {dp}, the velocities say {expect} (tol {tol})")
            if self.check_jumps:
                dv = v - float(p["SetVelo"])
                assert abs(dv) <= self.amax * dt * (1 + 1e-6) + 1e-9, f"cycle {c}: SetVelo jump {dv}"
                da = a - float(p["SetAcc"])
                assert abs(da) <= self.jerk * dt * (1 + 1e-6) + 1e-6, f"cycle {c}: SetAcc jump {da}"
        self._shift = 0.0
        # job records against NCTOPLC
        sd = int(r["StateDWord"])
        assert int(j["ActiveCmdNo"]) == int(r["CmdNo"]) and int(j["ActiveState"]) == int(r["CmdState"]), (
            f"cycle {c}: NCJOBS active {int(j['ActiveCmdNo'])}/{int(j['ActiveState'])} != "
            f"NCTOPLC {int(r['CmdNo'])}/{int(r['CmdState'])}")
        buffered = int(j["BufferedCmdNo"])
        assert bool(buffered) == bool(sd & StateDWord.CmdBuffered), f"cycle {c}: CmdBuffered vs BufferedCmdNo {buffered}"
        if buffered:
            assert buffered == int(j["NewestCmdNo"]), f"cycle {c}: the waiting job {buffered} is not the newest"
            assert buffered != int(j["ActiveCmdNo"])
        else:
            assert int(j["BufferedMode"]) == 0
        if sd & StateDWord.HasJob:
            assert int(r["CmdState"]) == int(CmdState.ACTIVE), f"cycle {c}: HasJob but CmdState {int(r['CmdState'])}"
        if int(r["CmdState"]) == int(CmdState.ACTIVE):
            assert sd & StateDWord.HasJob, f"cycle {c}: CmdState ACTIVE without HasJob"
        old = int(p["CmdNo"])
        new = int(r["CmdNo"])
        if old and new != old:
            assert 0 < (new - old) % 65536 < 32768, f"cycle {c}: CmdNo went back {old} -> {new}"
        seen = set()
        for e in j["Ended"]:
            no, st, err = int(e["CmdNo"]), int(e["CmdState"]), int(e["ErrorId"])
            if not no:
                continue
            assert no not in seen, f"cycle {c}: {no} twice in Ended"
            seen.add(no)
            assert st in _ENDED, f"cycle {c}: Ended {no} with state {st}"
            assert err == 0 or st == int(CmdState.ERROR)
            assert no != buffered, f"cycle {c}: {no} both ended and waiting"
            if no in self.fates:
                assert self.fates[no] == (st, err), f"cycle {c}: the fate of {no} changed {self.fates[no]} -> {(st, err)}"
            self.fates[no] = (st, err)


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
