"""The coupling stage: set-points of coupled slaves from their masters' (linear gearing, TcMC 3.17-3.21).

A slave at gear ratio ``r`` follows ``SetPos = s_base + r * (master SetPos - m_base)``: the ratio
times the master's travel since the coupling (or since the last ratio change of MC_GearInDyn),
exact in floating point for a fixed ratio; velocity, acceleration and jerk are ``r`` times the
master's. Chains (a slave that is the master of another) are evaluated level by level, masters
before slaves, in the same cycle: no lag per link. Each level is one vector operation.

Coupling happens with the slave at standstill (TcMC). When the master moves at that moment the
slave first synchronizes (AxisState SLAVE_SYNCHRONIZING): it reaches ``r`` times the master's
velocity and acceleration with its own AxisAcc/AxisDec/AxisJerk (ruckig, velocity interface, one
cycle at a time), then locks in position (SLAVE_SYNCHRON; MC_GearIn InGear). TcMC only couples
standing masters ("flying saw" is a separate product); synchronizing instead of jumping to the
master's velocity is this NC's choice, so that no coupling can ever command a velocity step.

MC_GearInDyn: the ratio follows PLCTONC.GearRatio1 of the slave every cycle, changing by at most
``Acceleration / master AxisVeloMax`` per second (TcMC 3.19: "the maximum acceleration will be
reached when the master is moving at its maximum velocity"). A non-finite GearRatio1 or one
beyond +/-MAX_RATIO is ignored (the last ratio stays) and counted in ``ignored_ratios``.

A master on another NC (MC_GearIn with MasterNc, :mod:`..remote`): the slave's row has ``remote`` = the
index of that master in ``sources`` (its ``master`` stays -1). Such slaves are evaluated before the levels,
from the master's newest sample extrapolated to this cycle's NcTimeNs; their own slaves follow them in the
levels as usual. A master whose samples stop (older than ``sources.max_age_ns``) faults the slave with
0x42A0 (it stops on its own ramp from where it was going); the phase error is measured as later samples
cover each cycle and shown in the job record (PhaseError, PhaseErrorMax, PhaseBound, MasterAgeUs) and the
stats (:meth:`CouplingStage.remote_stats`).

Which axes are coupled follows the jobs: a slave is coupled exactly while its running job is a
coupling job (``JobEngine.sync`` releases the row when another job takes over), so every way a
coupling can end (MC_GearOut, a motion command with AxisAllowMotionCmdToSlave, MC_Stop, an error,
Enable FALSE) goes through one place.
"""
from __future__ import annotations

import collections
import math
from typing import TYPE_CHECKING, Any, Callable

import numpy as np
from ruckig import ControlInterface, InputParameter, OutputParameter, Result, Ruckig

from nc_schema import AxisState, CoupleState, ErrorCodes

from ..remote import HISTORY, RemoteMasters
from .profile import motion_dwords

if TYPE_CHECKING:
    from ..context import CoreContext

#: largest |gear ratio| accepted
MAX_RATIO = 1e6
_EPS_V = 1e-9
SYNCHRONIZING = int(AxisState.SLAVE_SYNCHRONIZING)
SYNCHRON = int(AxisState.SLAVE_SYNCHRON)
#: one level's copies (CouplingStage._levels): rows, masters, ratio, s_base, m_base, any dyn, any synchronizing,
#: AxisState, rows and masters as indices (a slice where they are evenly spaced: basic indexing), the level's memo
_Level = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, bool, bool, np.ndarray,
               "np.ndarray | slice", "np.ndarray | slice", "_Memo"]


def _as_index(rows: np.ndarray) -> np.ndarray | slice:
    """``rows`` (ascending or not) as a slice where they are evenly spaced and ascending (a view instead of a
    gather, a strided copy instead of a scatter: the same elements), else the array itself."""
    if rows.size == 1:
        return slice(int(rows[0]), int(rows[0]) + 1)
    if rows.size > 1:
        step = int(rows[1] - rows[0])
        if step > 0 and np.array_equal(np.diff(rows), np.full(rows.size - 1, step)):
            return slice(int(rows[0]), int(rows[-1]) + 1, step)
    return rows


class _Memo:
    """What a fixed-ratio level computed from its slaves' velocities and accelerations (both pure functions of
    their bytes): their set-point StateDWord bits and whether they are within the limits, kept while the values
    repeat (a master at constant velocity gives its slaves the same values every cycle)."""

    __slots__ = ("key", "dwords", "within")

    def __init__(self) -> None:
        self.key = b""  # the bytes of (SetVelo, SetAcc) of the level's slaves
        self.dwords: np.ndarray | None = None  # motion_dwords of them
        self.within = False  # no slave beyond its limits at them (found so; False: not known)

    def dwords_of(self, sv: np.ndarray) -> np.ndarray:
        """motion_dwords of the level's set-points ``sv`` (4, rows) of this cycle (first call of the cycle)."""
        key = sv[1:3].tobytes()
        if key != self.key or self.dwords is None:
            self.key, self.dwords, self.within = key, motion_dwords(sv[1], sv[2]), False
        return self.dwords

    def is_within(self, sv: np.ndarray, lim: np.ndarray) -> bool:
        """No slave of ``sv`` (as given to :meth:`dwords_of` this cycle) beyond its limits ``lim`` (2, rows)."""
        if not self.within:
            self.within = not np.count_nonzero(np.abs(sv[1:3]) > lim)
        return self.within


class CouplingStage:
    """The master/slave table of one NC and the per-cycle evaluation of its slaves.

    Columns (one entry per axis row): ``master`` (row of the master, -1 = not a slave), ``ratio``
    (applied), ``ratio_cmd`` (MC_GearInDyn: the ratio asked for), ``rate`` (MC_GearInDyn: the
    largest ratio change per second), ``dyn``, ``s_base``/``m_base`` (slave and master position
    where the current ratio took effect), ``state`` (AxisState of the slave: 12 or 13).
    """

    name = "coupling"

    def __init__(self, n: int, cycle_time: float) -> None:
        self.n = n
        self.dt = cycle_time
        self.master = np.full(n, -1, dtype=np.intp)
        self.ratio = np.zeros(n)
        self.ratio_cmd = np.zeros(n)
        self.rate = np.zeros(n)
        self.dyn = np.zeros(n, dtype=bool)
        self.s_base = np.zeros(n)
        self.m_base = np.zeros(n)
        self.m_last = np.zeros(n)  # the master's set position the slave followed last cycle
        self.state = np.zeros(n, dtype=np.uint32)
        #: coupling across NCs: the master's index in ``sources`` (-1: none); ``slave``: master >= 0 or remote >= 0
        self.remote = np.full(n, -1, dtype=np.intp)
        self.slave = np.zeros(n, dtype=bool)
        self.sources = RemoteMasters()
        self.remote_rows: list[int] = []
        #: per remote slave row: (slave NcTimeNs, master position extrapolated, NcTimeNs of the sample used)
        self.pending: dict[int, collections.deque[tuple[int, float, int]]] = {}
        self.phase = np.zeros((3, n))  # newest phase error, largest |phase error|, its bound [u]
        self.age_us = np.zeros(n, dtype=np.int64)
        self.measured = np.zeros(n, dtype=np.int64)
        self.within = np.zeros(n, dtype=np.int64)
        self.sq_sum = np.zeros(n)
        self.live = np.zeros(n, dtype=bool)  # MC_GearInDyn: GearRatio1 is the block's
        self.gr_seen = np.full(n, math.nan)
        self.couple_state = np.zeros(n, dtype=np.uint32)  # NCTOPLC.CoupleState
        self.levels: list[tuple[np.ndarray, np.ndarray]] = []  # (slave rows, their master rows) per depth
        self.slaves = np.zeros(0, dtype=np.intp)
        self.ignored_ratios = 0
        self.changed: list[int] = []  # slaves whose job record changed in a cycle (a synchronization locked)
        self._cache: tuple[list[_Level], np.ndarray, np.ndarray] | None = None
        self._scratch(cycle_time)

    def _scratch(self, cycle_time: float) -> None:
        """ruckig's objects for a synchronizing slave: filled anew for every cycle (no state between cycles)."""
        self._otg = Ruckig(1, cycle_time)
        self._inp = InputParameter(1)
        self._out = OutputParameter(1)
        self._inp.control_interface = ControlInterface.Velocity

    def __getstate__(self) -> dict[str, Any]:
        """Pickled without ruckig's scratch objects (they do not pickle; a standby's snapshot: docs/standby.md)."""
        return {k: v for k, v in self.__dict__.items() if k not in ("_otg", "_inp", "_out")}

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)
        self._scratch(self.dt)

    # -- the table ----------------------------------------------------------------------------
    @property
    def active(self) -> bool:
        return bool(self.slaves.size)

    def is_slave(self, i: int) -> bool:
        return bool(self.slave[i])

    def remote_master_id(self, k: int) -> int:
        """The AxisId (on its NC) of remote master ``k``."""
        return self.sources.sources[k][1]

    def closes_cycle(self, slave: int, master: int) -> bool:
        """Coupling ``slave`` to ``master`` would make an axis its own master (directly or through a chain)."""
        m = master
        for _ in range(self.n + 1):
            if m == slave:
                return True
            if m < 0:
                return False
            m = int(self.master[m])
        return True

    def couple(self, core: CoreContext, i: int, m: int, ratio: float, dyn: bool = False, rate: float = 0.0,
               gear_ratio1: float = math.nan) -> None:
        """Make row ``i`` a slave of row ``m`` from this cycle's set-points on (the caller checked
        that it may: slave standing, no cycle). A moving master: synchronize first.

        Args:
            gear_ratio1: MC_GearInDyn: PLCTONC.GearRatio1 as the command found it. The ratio follows
                GearRatio1 only once it equals ``ratio`` or changed from this value (the block's
                PLCTONC frame may arrive after the command: an older GearRatio1 is not its ratio).
        """
        a = core.axes
        if dyn and self.master[i] == m:  # MC_GearInDyn again: the coupling goes on from its applied ratio
            self.ratio_cmd[i] = ratio
            self.dyn[i], self.rate[i] = True, rate
            self.live[i] = False
            self.gr_seen[i] = gear_ratio1
            self._cache = None
            return
        self.master[i] = m
        self.ratio[i] = self.ratio_cmd[i] = ratio
        self.dyn[i] = dyn
        self.rate[i] = rate
        self.live[i] = not dyn
        self.gr_seen[i] = gear_ratio1
        self._start(i, float(a.set_pos[m]), float(a.set_velo[m]), float(a.set_acc[m]), float(a.set_pos[i]))

    def _start(self, i: int, mp: float, mv: float, ma: float, sp: float) -> None:
        moving = abs(mv) > _EPS_V or abs(ma) > 1e-9
        self.state[i] = SYNCHRONIZING if moving else SYNCHRON
        self.s_base[i] = sp
        self.m_base[i] = self.m_last[i] = mp
        self._rebuild()

    def couple_remote(self, core: CoreContext, i: int, k: int, ratio: float) -> None:
        """Make row ``i`` a slave of remote master ``k`` (``sources``) at a fixed ratio from this cycle on (the
        caller checked that it may: slave standing, master fresh)."""
        st = self.sources.state(k, core.nc_time_ns + int(round(self.dt * 1e9)))
        assert st is not None  # (checked fresh)
        self.remote[i] = k
        self.ratio[i] = self.ratio_cmd[i] = ratio
        self.dyn[i], self.rate[i], self.live[i] = False, 0.0, True
        self.pending[i] = collections.deque(maxlen=HISTORY)
        self.phase[:, i] = 0.0
        self.age_us[i] = self.measured[i] = self.within[i] = 0
        self.sq_sum[i] = 0.0
        self._start(i, st[0], st[1], st[2], float(core.axes.set_pos[i]))

    def release(self, i: int) -> None:
        """Row ``i`` is no slave any more; it keeps this cycle's set-point state (the job that took
        over planned from it)."""
        if not self.slave[i]:
            return
        self.master[i] = -1
        self.remote[i] = -1
        self.pending.pop(i, None)
        self.ratio[i] = self.ratio_cmd[i] = 0.0
        self.dyn[i] = False
        self.state[i] = 0
        self._rebuild()

    def shift(self, i: int, diff: float) -> None:
        """The NC positions of row ``i`` moved by ``diff`` (MC_SetActualPosition*): no slave may jump."""
        if self.slave[i]:
            self.s_base[i] += diff
        of = self.master == i
        self.m_base[of] += diff
        self.m_last[of] += diff
        self._cache = None

    def fold(self, i: int, diff: float) -> None:
        """A superimposed distance ``diff`` of slave row ``i`` becomes part of its coupling."""
        self.s_base[i] += diff
        self._cache = None

    def _rebuild(self) -> None:
        n = self.n
        depth = np.zeros(n, dtype=np.intp)
        for i in range(n):  # (couplings change on commands only; a remote master is one level up)
            d, r = 0, i
            while d <= n:
                m = int(self.master[r])
                if m < 0:
                    d += int(self.remote[r] >= 0)
                    break
                d += 1
                r = m
            depth[i] = d
        local = self.master >= 0
        self.levels = []
        for d in range(1, int(depth.max(initial=0)) + 1):
            rows = ((depth == d) & local).nonzero()[0]
            if rows.size:
                self.levels.append((rows, self.master[rows].copy()))
        self.slave = slave = local | (self.remote >= 0)
        self.slaves = slave.nonzero()[0]
        self.remote_rows = (self.remote >= 0).nonzero()[0].tolist()
        is_master = np.zeros(n, dtype=bool)
        is_master[self.master[local]] = True
        cs = np.full(n, int(CoupleState.SINGLE), dtype=np.uint32)
        cs[is_master] = int(CoupleState.MASTER)
        cs[slave] = int(CoupleState.SLAVE)
        cs[slave & is_master] = int(CoupleState.MASTERSLAVE)
        self.couple_state = cs
        self._cache = None

    # -- the cycle ----------------------------------------------------------------------------
    def invalidate(self) -> None:
        """A column changed: the per-level copies are made again at the next run."""
        self._cache = None

    def _levels(self, core: CoreContext) -> tuple[list[_Level], np.ndarray, np.ndarray]:
        """Per level: rows, masters, ratio, s_base, m_base, any dyn, any synchronizing, AxisState;
        and the slaves' velocity and acceleration limits (copies: a cycle gathers less)."""
        if self._cache is None:
            a = core.axes
            lv = []
            for rows, masters in self.levels:
                lv.append((rows, masters, self.ratio[rows], self.s_base[rows], self.m_base[rows],
                           bool(self.dyn[rows].any()), bool((self.state[rows] == SYNCHRONIZING).any()), self.state[rows],
                           _as_index(rows), _as_index(masters), _Memo()))
            s = self.slaves
            lim = np.stack((a.vmax[s], np.maximum(a.acc[s], a.dec[s]))) * (1 + 1e-6)
            lim += np.array([[_EPS_V], [1e-6]])
            self._cache = (lv, s, lim)
        return self._cache

    def run(self, core: CoreContext, after_level: Callable[[CoreContext, np.ndarray], None] | None) -> list[tuple[int, int]]:
        """Set-points of every slave, level by level; ``after_level(core, rows)`` runs after each level
        (the superposition of those rows, before their own slaves read them). Returns (row, code) of
        the slaves beyond their limits, for the NC to fault: 0x4359 AxisVeloMax, 0x422F
        max(AxisAcc, AxisDec)."""
        S = core.axes.S
        levels, s, lim = self._levels(core)
        sv: np.ndarray | None = None  # the slaves' set-points, (4, s.size), if they are still in hand
        memo: _Memo | None = None  # and their level's memo (given sv this cycle)
        lost: list[tuple[int, int]] = []
        if self.remote_rows:
            lost = self._run_remote(core, after_level)
        for rows, masters, r, sb, mb, dyn, syncing, state, rows_ix, masters_ix, level_memo in levels:
            if not (dyn or syncing):  # (fixed ratios, all locked: one gather and one scatter, the same values)
                if type(masters_ix) is slice:  # (C order: S[:, masters] gives F order, slower to compute on)
                    sv = S[:, masters_ix].copy()
                else:
                    sv = S.take(masters, axis=1)
                pos = sv[0]
                pos -= mb
                pos *= r
                pos += sb  # sb + r * (pm - mb)
                sv[1:] *= r
                S[:, rows_ix] = sv
                memo = level_memo
                core.sp_dw[rows_ix] = memo.dwords_of(sv)
                core.axis_state[rows_ix] = state
                if after_level is not None:
                    after_level(core, rows)
                    sv = None
                continue
            sv = None
            pm = S[0, masters]
            if syncing:
                sync = (self.state[rows] == SYNCHRONIZING).nonzero()[0]
                prev = S[:3, rows[sync]].copy()  # their set-point state of the last cycle
            accel = None
            if dyn:
                accel = self._dyn_ratios(core, rows, core.plctonc["GearRatio1"])
                if accel is not None:
                    r, sb, mb = self.ratio[rows], self.s_base[rows], self.m_base[rows]
            if dyn or syncing:
                self.m_last[rows] = pm  # (where a ratio change or a lock re-bases the coupling)
            S[0, rows] = sb + r * (pm - mb)
            S[1:, rows] = r * S[1:, masters]
            if accel is not None:  # ratio changes of this level (MC_GearInDyn)
                S[2, rows] += accel
            if syncing:
                for col, k in enumerate(sync.tolist()):
                    m = int(masters[k])
                    self._synchronize(core, int(rows[k]), float(S[0, m]), float(S[1, m]), float(S[2, m]), prev[:, col])
                state = self.state[rows]
            core.sp_dw[rows] = motion_dwords(S[1, rows], S[2, rows])
            core.axis_state[rows] = state
            if after_level is not None:
                after_level(core, rows)
        # beyond AxisVeloMax: the fault ramp then takes the acceleration down with up to 4 x AxisJerk
        # (JobEngine.start_ramp)
        if sv is not None and len(levels) == 1 and not self.remote_rows:  # (one level: its rows are the slaves, in order)
            assert memo is not None  # (set with sv)
            if memo.is_within(sv, lim):
                return []
        v, acc = S[1, s], S[2, s]
        fast = np.abs(v) > lim[0]
        hard = np.abs(acc) > lim[1]
        if np.count_nonzero(fast) or np.count_nonzero(hard):
            return lost + [(int(i), int(ErrorCodes.NC_AXIS_SET_VELOCITY)) for i in s[fast].tolist()] + [
                (int(i), int(ErrorCodes.NC_ACCELERATION_NOT_ALLOWED)) for i in s[hard & ~fast].tolist()]
        return lost

    def _run_remote(self, core: CoreContext, after_level: Callable[[CoreContext, np.ndarray], None] | None
                    ) -> list[tuple[int, int]]:
        """The slaves of remote masters (before the levels: their own slaves read them there). Returns (row,
        0x42A0) of those whose master's newest sample is older than ``max_age_ns`` (or that much in the future: the
        two NCs' clocks are apart): they go on from their own
        set-point state for this cycle and the NC faults them (their own stop ramp)."""
        a = core.axes
        S = a.S
        src = self.sources
        t = core.nc_time_ns
        lost: list[tuple[int, int]] = []
        rows = self.remote_rows
        dt = self.dt
        for i in rows:
            k = int(self.remote[i])
            st = src.state(k, t)
            if st is None or abs(st[4]) > src.max_age_ns:  # (a sample far in the future: clocks apart, no master)
                p, v, acc = float(S[0, i]), float(S[1, i]), float(S[2, i])
                S[0, i], S[1, i], S[3, i] = p + dt * (v + 0.5 * acc * dt), v + acc * dt, 0.0
                lost.append((i, int(ErrorCodes.NC_CONSEQUENTIAL_ERROR)))
                continue
            mp, mv, ma, mj, age = st
            self.age_us[i] = age // 1000
            r = float(self.ratio[i])
            if self.state[i] == SYNCHRONIZING:
                self._synchronize(core, i, mp, mv, ma, S[:3, i].copy())
                self.m_last[i] = mp
                continue
            S[0, i] = self.s_base[i] + r * (mp - self.m_base[i])
            S[1, i], S[2, i], S[3, i] = r * mv, r * ma, r * mj
            self.m_last[i] = mp
            self.pending[i].append((t, mp, t - age))
        rr = np.asarray(rows, dtype=np.intp)
        core.sp_dw[rr] = motion_dwords(S[1, rr], S[2, rr])
        core.axis_state[rr] = self.state[rr]
        self._measure(core, rows)
        if after_level is not None:
            after_level(core, rr)
        return lost

    def _measure(self, core: CoreContext, rows: list[int]) -> None:
        """The phase error of the cycles the masters' samples now cover (into the job records' phase part)."""
        src = self.sources
        jobs = core.ncjobs
        for i in rows:
            q = self.pending[i]
            k = int(self.remote[i])
            r = abs(float(self.ratio[i]))
            while q:
                t_s, p_est, since = q[0]
                got = src.actual(k, t_s, since)
                if got is None:
                    break
                q.popleft()
                p_true, jmax = got
                err = float(self.ratio[i]) * (p_est - p_true)
                tau = abs(t_s - since) * 1e-9  # (a late slave cycle may have a sample newer than its time)
                bound = r * jmax * tau ** 3 / 6.0
                ph = self.phase
                ph[0, i], ph[2, i] = err, bound
                ph[1, i] = max(ph[1, i], abs(err))
                self.measured[i] += 1
                self.sq_sum[i] += err * err
                if abs(err) <= bound + 1e-9:
                    self.within[i] += 1
            jobs["PhaseError"][i], jobs["PhaseErrorMax"][i], jobs["PhaseBound"][i] = self.phase[:, i]
            jobs["MasterAgeUs"][i] = min(max(int(self.age_us[i]), 0), 0xFFFFFFFF)
        core.jobs_written()

    def remote_stats(self, axis_ids: np.ndarray) -> dict[int, dict[str, object]]:
        """{AxisId: ...} of the slaves of remote masters (the stats' ``remote_couplings``)."""
        out: dict[int, dict[str, object]] = {}
        for i in list(self.remote_rows):
            k = int(self.remote[i])
            if k < 0:
                continue
            n = int(self.measured[i])
            out[int(axis_ids[i])] = {
                "master": self.sources.name(k), "state": int(self.state[i]), "ratio": float(self.ratio[i]),
                "age_us": int(self.age_us[i]), "phase_err": float(self.phase[0, i]),
                "phase_err_max": float(self.phase[1, i]), "phase_bound": float(self.phase[2, i]),
                "measured": n, "within": int(self.within[i]),
                "rms": math.sqrt(float(self.sq_sum[i]) / n) if n else 0.0}
        return out

    def _dyn_ratios(self, core: CoreContext, rows: np.ndarray, gr: np.ndarray) -> np.ndarray | None:
        """MC_GearInDyn rows of a level: the ratio moves towards PLCTONC.GearRatio1 within its rate;
        where it changed, the coupling is re-based at last cycle's positions (so position stays
        continuous) and the ratio change adds ``dr/dt * master velocity`` to the acceleration, which is
        returned per row of ``rows`` (None: no ratio changed)."""
        S = core.axes.S
        d = rows[self.dyn[rows]]
        want = gr[d]
        stale = ~self.live[d]
        if stale.any():
            self.live[d] |= (want == self.ratio_cmd[d]) | (want != self.gr_seen[d])
            d, want = d[self.live[d]], want[self.live[d]]
        ok = np.isfinite(want) & (np.abs(want) <= MAX_RATIO)
        if not ok.all():
            self.ignored_ratios += int(np.count_nonzero(~ok))
        self.ratio_cmd[d[ok]] = want[ok]
        old = self.ratio[d]
        step = self.rate[d] * self.dt
        new = old + np.clip(self.ratio_cmd[d] - old, -step, step)
        moved = new != old
        if not moved.any():
            return None
        dm = d[moved]
        self.s_base[dm] += old[moved] * (self.m_last[dm] - self.m_base[dm])
        self.m_base[dm] = self.m_last[dm]
        self.ratio[dm] = new[moved]
        self._cache = None
        core.ncjobs["GearRatio"][dm] = new[moved]
        core.jobs_written()
        acc = np.zeros(rows.size)
        acc[np.searchsorted(rows, dm)] = (new[moved] - old[moved]) / self.dt * S[1, self.master[dm]]  # (rows ascend)
        return acc

    def _update(self) -> Result:
        try:
            return self._otg.update(self._inp, self._out)
        except Exception:  # (ruckig raises on inputs it cannot take)
            return Result.Error

    def _synchronize(self, core: CoreContext, i: int, mp: float, mv: float, ma: float, prev: np.ndarray) -> None:
        """One cycle of a synchronizing slave: towards ratio x the master's velocity and acceleration
        with the slave's own dynamics; locked in position once it got there."""
        a = core.axes
        r = float(self.ratio[i])
        inp, out = self._inp, self._out
        inp.current_position = [float(prev[0])]
        inp.current_velocity = [float(prev[1])]
        inp.current_acceleration = [float(prev[2])]
        acc_lim = float(max(a.acc[i], a.dec[i]))
        vmax = float(a.vmax[i])
        inp.target_velocity = [max(-vmax, min(vmax, r * mv))]  # (beyond: the limit check faults)
        inp.target_acceleration = [max(-acc_lim, min(acc_lim, r * ma))]
        jerk = float(a.jerk[i])
        inp.max_velocity = [float(a.vmax[i])]
        inp.max_acceleration = [acc_lim]
        inp.max_jerk = [jerk]
        res = self._update()
        if res not in (Result.Working, Result.Finished):
            inp.target_acceleration = [0.0]  # (a target acceleration out of reach from here: aim at 0 first)
            res = self._update()
        dt = self.dt
        if res in (Result.Working, Result.Finished):
            p, v, acc = out.new_position[0], out.new_velocity[0], out.new_acceleration[0]
        else:  # ruckig cannot plan: take the acceleration down with the jerk and try again next cycle
            a0 = float(prev[2])
            acc = a0 - math.copysign(min(abs(a0), jerk * dt), a0)
            v = float(prev[1]) + 0.5 * (a0 + acc) * dt
            p = float(prev[0]) + float(prev[1]) * dt + (a0 / 3.0 + acc / 6.0) * dt * dt
        a.set_pos[i], a.set_velo[i], a.set_acc[i] = p, v, acc
        a.set_jerk[i] = (acc - float(prev[2])) / dt
        # locked only where following the master is no step: velocity within a cycle of acceleration,
        # acceleration within a cycle of jerk of ratio x the master's
        locked = (res == Result.Finished and abs(v - r * mv) <= acc_lim * dt
                  and abs(acc - r * ma) <= jerk * dt)
        if locked:
            self.state[i] = SYNCHRON
            self.s_base[i] = p
            self.m_base[i] = self.m_last[i] = mp
            self.changed.append(i)
            self._cache = None
        if not math.isfinite(p):  # never hand a non-finite set-point on
            a.set_pos[i], a.set_velo[i], a.set_acc[i] = float(prev[0]), 0.0, 0.0
