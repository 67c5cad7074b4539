"""The profile stage: the set-points of the axes that follow a plan of their own (``axes.traj_on``).

It evaluates every running plan (constant-jerk segments) ``lookahead`` cycles ahead, a staggered
group of axes per cycle; the stages after it (:mod:`.`) read the set-points it produced.
"""
from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any, Iterable

import numpy as np

from nc_schema import AxisState, StateDWord

from ..profile import N_SEGMENTS

if TYPE_CHECKING:
    from ..context import CoreContext

_EPS_V = 1e-9


def _setpoint_luts() -> tuple[np.ndarray, np.ndarray]:
    """AxisState and set-point StateDWord bits for a packed flag byte of an axis following a profile.

    Flag bits: 0 hold (job waits at override 0), 1 constant acceleration (a == 0), 2 accelerating
    (a*v > 0), 3 decelerating (a*v < 0), 4 v > 0, 5 v < 0, 6 steady job (job and not holding).
    """
    states = np.zeros(128, dtype=np.uint32)
    dwords = np.zeros(128, dtype=np.uint32)
    for k in range(128):
        hold, const, accel, decel, pos, neg, steady = ((k >> b) & 1 for b in range(7))
        if hold:
            st = AxisState.OVERRIDE_ZERO
        elif const:
            st = AxisState.PHASE_VELOCONST
        elif accel:
            st = AxisState.PHASE_ACCPOS
        elif decel:
            st = AxisState.PHASE_ACCNEG
        else:
            st = AxisState.RUNNING
        states[k] = int(st)
        moving = pos or neg
        dw = 0 if moving else int(StateDWord.NotMoving)
        dw |= int(StateDWord.PositiveDirection) if pos else 0
        dw |= int(StateDWord.NegativeDirection) if neg else 0
        dw |= int(StateDWord.ConstantVelocity) if steady and moving and const else 0
        dwords[k] = dw
    return states, dwords


SP_STATE_LUT, SP_DWORD_LUT = _setpoint_luts()
#: both by flag byte: [StateDWord bits, AxisState]
_SP_WORDS = np.stack([SP_DWORD_LUT, SP_STATE_LUT])
#: packs the 8 bool bytes of a flag row (viewed as one little-endian uint64) into its flag byte:
#: byte b (0/1) lands on bit 56 + b, no two partial products overlap or carry
_PACK = np.uint64(0x0102040810204080)
_SHIFT = np.uint64(56)
#: class boundaries for np.searchsorted(side="right"), the same tests as the flag bits:
#: velocity 0: v < -eps, 1: neither, 2: v > eps; acceleration 1: |a| < 1e-9 (constant);
#: a*v 0: < 0, 1: == 0, 2: > 0
_V_EDGES = np.array([-_EPS_V, np.nextafter(_EPS_V, np.inf)])
#: set-point StateDWord bits by velocity class + 3 x (constant velocity: |a| < 1e-9, only when moving)
_NM, _PD, _ND, _CV = (np.uint32(int(f)) for f in (StateDWord.NotMoving, StateDWord.PositiveDirection,
                                                  StateDWord.NegativeDirection, StateDWord.ConstantVelocity))
_MOTION_DW = np.array([_ND, _NM, _PD, _ND | _CV, _NM, _PD | _CV], dtype=np.uint32)


def motion_dwords(v: np.ndarray, acc: np.ndarray | None = None) -> np.ndarray:
    """Set-point StateDWord bits of the stages that write set-points directly: NotMoving (|v| <= eps)
    or the direction of ``v``, and with ``acc`` ConstantVelocity where a moving axis has |acc| < 1e-9
    (the velocity classes of the profile stage)."""
    code = np.searchsorted(_V_EDGES, v, "right")
    if acc is not None:
        code += 3 * (np.abs(acc) < 1e-9)
    return _MOTION_DW[code]
_A_EDGES = np.array([np.nextafter(-1e-9, np.inf), 1e-9])
_AV_EDGES = np.array([0.0, np.nextafter(0.0, np.inf)])
#: small blocks: fewer calls (searchsorted classes + one table) beat the flag bytes + packing
_SMALL_BLOCK = 256


def _class_codes() -> tuple[np.ndarray, np.ndarray]:
    """Flag bytes by (row bits, velocity class, acceleration class, a*v class), and the row bits'
    flag bits. Row bits (``AxisTable.sp_row``): 1 the job holds at override 0, 2 a job runs and
    does not hold."""
    codes = np.zeros((4, 3, 3, 3), dtype=np.uint8)
    for rp in range(4):
        for sv in range(3):
            for sa in range(3):
                for sav in range(3):
                    codes[rp, sv, sa, sav] = ((rp & 1) | (sa == 1) << 1 | (sav == 2) << 2 | (sav == 0) << 3
                                              | (sv == 2) << 4 | (sv == 0) << 5 | (rp >> 1) << 6)
    row_bits = np.array([0, 1, 64, 65], dtype=np.uint64)
    return codes, row_bits


_CLASS_CODES, _ROW_BITS = _class_codes()


#: Staggering: up to this many axes, one group of a quarter of them is refilled every 4th cycle (blocks of
#: up to 1024 samples with a lookahead of 16: cheaper per sample, and 3 of 4 cycles refill nothing);
#: above, one group every cycle (a block per cycle of about as many samples as there are axes).
#: Measured with bench/nc_cycle.py (docs/ARCHITECTURE.md, "How the core keeps a cycle cheap"), before the
#: steady groups: they skip the refills of steady motion whatever the grouping, so the choice now only
#: matters for motion that is not steady.
PERIOD_4_UP_TO = 256


def default_groups(n: int, lookahead: int) -> int:
    """Refill groups for ``n`` axes: ``lookahead // 4`` up to PERIOD_4_UP_TO axes, else ``lookahead``."""
    if n <= PERIOD_4_UP_TO and lookahead % 4 == 0:
        return lookahead // 4
    return lookahead


#: up to this many evenly spaced runs of rows follow a plan: the stage copies their set-points slice by slice,
#: else under a mask of all rows
_MAX_RUNS = 4


def _runs(rows: np.ndarray, most: int) -> list[slice] | None:
    """Ascending ``rows`` as at most ``most`` slices of evenly spaced rows (the same rows, in order); None: more."""
    m = rows.size
    if not m:
        return []
    d = np.diff(rows)
    changes = np.flatnonzero(d[1:] != d[:-1]) + 1  # where the spacing changes (indices into d)
    if changes.size > 2 * most:
        return None
    ends = changes.tolist() + [m - 1]
    out: list[slice] = []
    i = 0
    while i < m:
        if i == m - 1:
            j, step = i, 1
        else:
            step = int(d[i])
            j = next(e for e in ends if e > i)  # (the run's last row: the spacing changes after it)
        out.append(slice(int(rows[i]), int(rows[j]) + 1, step))
        if len(out) > most:
            return None
        i = j + 1
    return out


class ProfileStage:
    """The profile generator: set-points of the axes that follow a plan (``axes.traj_on``).

    Set-points (and their StateDWord bits and AxisState) are evaluated ``lookahead`` cycles ahead.
    Buffer column ``c % lookahead`` (``buf[:, c % lookahead]``, one contiguous row per set-point)
    holds the set-points of the stage's cycle ``c`` for every row, so a cycle copies one column. The
    refills are staggered: row ``r`` belongs to group ``r % groups``; every ``lookahead // groups``
    cycles one group is refilled for the next ``lookahead`` cycles (``groups == lookahead``: one
    group every cycle, each cycle about the same work; ``groups == 1``: all rows every
    ``lookahead``-th cycle). A row whose plan (or job flags) changed (:meth:`refresh`) is evaluated
    for the next ``lookahead`` cycles at the next run, in the same evaluation as that cycle's group.

    Steady groups: when every row of a group stays in a segment without jerk and acceleration for a
    whole window, and no row of the group changed since its last refill, the group needs no refills
    until a row could reach its next segment: its velocity, acceleration, jerk and words are the
    segment's constants, in every column of the buffer already, and its positions are computed every
    cycle for all steady rows at once from the plan time (``p0 + v0 * (traj_t - t0)``: the arithmetic
    of the full evaluation for such a segment, bit for bit; three calls per cycle instead of a refill).
    A changed row leaves at once (its new plan is evaluated); the other rows of its group, and a group
    whose time is up, at the group's next refill.

    Plan times advance by repeated addition of the cycle time, exactly as ``axes.traj_t``; a sample
    is therefore the same whenever it is evaluated: set-points do not depend on the lookahead or on
    the refill pattern (bit for bit the set-points of ``lookahead=1``).

    Args:
        steady: use steady groups (False: every refill evaluates in full, the reference).
    """

    name = "profile"

    def __init__(self, core: CoreContext, lookahead: int, groups: int | None = None, steady: bool = True) -> None:
        n = core.axes.n
        L = lookahead
        self.n = n
        self.lookahead = L
        self.dt = core.cycle_time
        self.steady = steady
        self.buf = np.zeros((4, L, n))        # set-points, column = stage cycle % lookahead
        self.buf_words = np.zeros((2, L, n), dtype=np.uint32)  # their StateDWord bits and AxisState
        self.c = 0  # stage cycles run: the next run produces the set-points of stage cycle c
        self.pending: set[int] = set()  # rows to evaluate at the next run (plans changed)
        self.refills = 0  # runs that evaluated rows (groups or pending)
        self.refill_rows = 0  # rows evaluated by the last run
        self.steady_refills = 0  # refills a steady group did not need
        # the segment table as evaluated: axes.seg's t0, p, v, a, j and a/2 (copied when a plan changes)
        self.seg = np.zeros((6, n, N_SEGMENTS))
        self.seg[0] = np.inf
        self._seg_flat = self.seg.reshape(6, -1)
        self._row_base = np.arange(n) * N_SEGMENTS  # each row's offset into the flat table
        # plan times of a window: row 0 the time before it (traj_t), then one cycle time each (never written);
        # accumulated into _t_out (the additions the cycle makes)
        self._t_in = np.full((L + 1, n), self.dt)
        self._t_out = np.empty((L + 1, n))
        self._times1 = np.full(L, self.dt)
        self._res = np.empty((4, L, n))
        self._flag_bytes = np.zeros((L, n, 8), dtype=bool)
        self._on_key: np.ndarray | None = None
        self._on_groups: list[np.ndarray] = []
        self._on_seen = np.zeros(0, dtype=np.intp)  # the rows following a plan the steady groups were made for
        self._on_mask = np.zeros(n, dtype=bool)  # and as a mask
        self._on_mask4 = np.zeros((4, n), dtype=bool)  # and that 4 times (rows)
        self._on_runs: list[slice] | None = None  # and as a few evenly spaced runs (None: more than _MAX_RUNS)
        self._ends_from = 0.0  # the stage cycle from which running plans may end (looked for every cycle)
        # steady rows: their positions come from p0 + v0 * (traj_t - t0) every cycle
        self._st_mask = np.zeros(n, dtype=bool)
        self._st_t0, self._st_v0, self._st_p0 = np.zeros(n), np.zeros(n), np.zeros(n)
        self._st_tau = np.empty(n)
        self.n_steady = 0  # rows in _st_mask
        self._ends_dirty = True  # plans changed: _ends_from is found again
        self.set_groups(default_groups(n, L) if groups is None else groups)

    def set_groups(self, groups: int) -> None:
        """Refill in ``groups`` staggered groups (a divisor of ``lookahead``; 1 = unstaggered).

        Raises:
            ValueError: not a divisor of the lookahead.
        """
        if groups < 1 or self.lookahead % groups:
            raise ValueError(f"groups {groups} must divide the lookahead {self.lookahead}")
        self.groups = groups
        self.period = self.lookahead // groups
        n = self.n
        self._all_groups = [np.arange(g, n, groups) for g in range(groups)]
        self._bases = [self._row_base[g::groups] for g in range(groups)]
        self._on_key = None
        self._until = [-math.inf] * groups  # a steady group's last refill cycle it can skip
        self._g_steady = [0] * groups  # its rows in _st_mask
        self._busy = [False] * groups  # a row of the group changed since the group's last refill
        self._st_mask[:] = False  # (every row is evaluated afresh below)
        self.n_steady = 0
        self.pending = set(range(n))  # every row from the next run on (whatever ran before)

    def run(self, core: CoreContext) -> np.ndarray:
        """Advance one cycle; returns the rows whose plan ended in this cycle."""
        a = core.axes
        on = core.on_rows
        if not on.size:
            self.pending.clear()  # (nothing runs: rows that start later are refreshed then)
            if self.n_steady:
                self._st_mask[:] = False
                self.n_steady = 0
                self._g_steady = [0] * self.groups
                self._until = [-math.inf] * self.groups
            return on
        if on is not self._on_seen:
            self._rows_changed(on)
        c = self.c
        self.c = c + 1
        L = self.lookahead
        col = c % L
        rows: np.ndarray | slice | None = None  # the rows to evaluate (basic indexing where possible)
        base: np.ndarray | None = None  # and their offsets into the flat segment table, (m,)
        group = -1
        if self.pending:
            self._drop_steady()
            self._ends_dirty = True
        if c % self.period == 0:
            group = (c // self.period) % self.groups
            if core.all_on:
                if self._all_groups[group].size:
                    rows, base = slice(group, None, self.groups), self._bases[group]
            else:
                idx = self._group_rows(on, group)
                if idx.size:
                    rows, base = idx, self._row_base[idx]
            if rows is not None and c <= self._until[group]:
                rows = base = None  # steady: nothing to refill (its positions come every cycle)
                self.steady_refills += 1
            elif self._g_steady[group]:
                self._leave_steady(group, rows)  # (its rows are evaluated in full below)
        group_rows = rows
        if self.pending:
            rows, base = self._take_pending(a, rows, base, group)
        if rows is not None:
            if type(rows) is slice and rows.step is None:  # one row (a command)
                self._eval_row(core, rows, base, col)  # type: ignore[arg-type]  # (base is set with rows)
            else:
                steady = -1  # (the group alone, not changed since its last refill: it may be steady)
                if rows is group_rows and self.steady:
                    if self._busy[group]:
                        self._busy[group] = False
                    else:
                        steady = group
                self._eval(core, rows, base, col, steady)  # type: ignore[arg-type]  # (base is set with rows)
        dt = self.dt
        if core.all_on:
            a.traj_t += dt
            a.S[:] = self.buf[:, col]
            core.sp_words[:] = self.buf_words[:, col]  # (sp_dw, axis_state)
            if self.n_steady:
                self._steady_positions(core)
            if self._ends_dirty:
                self._next_ends(c, np.min(a.traj_dur - a.traj_t))
            if c < self._ends_from:
                return _NO_ROWS
            ended: np.ndarray = (a.traj_t >= a.traj_dur).nonzero()[0]
        else:
            mask = self._on_mask  # (the rows of ``on``: whole rows under a mask cost less than gathers)
            runs = self._on_runs
            if runs is not None:  # (a few runs of rows, e.g. a coupling's masters: slices cost less than the masks)
                traj_t, S, sp_words, buf, buf_words = a.traj_t, a.S, core.sp_words, self.buf, self.buf_words
                for sl in runs:
                    t = traj_t[sl]
                    np.add(t, dt, out=t)
                    S[:, sl] = buf[:, col, sl]
                    sp_words[:, sl] = buf_words[:, col, sl]
            else:
                np.add(a.traj_t, dt, out=a.traj_t, where=mask)
                mask4 = self._on_mask4
                np.copyto(a.S, self.buf[:, col], where=mask4)
                np.copyto(core.sp_words, self.buf_words[:, col], where=mask4[:2])
            if self.n_steady:
                self._steady_positions(core)
            if self._ends_dirty:
                self._next_ends(c, np.min(a.traj_dur - a.traj_t, where=mask, initial=np.inf))
            if c < self._ends_from:
                return _NO_ROWS
            over = a.traj_t >= a.traj_dur
            over &= mask
            ended = over.nonzero()[0]
        if ended.size:
            self._ends_dirty = True  # (their jobs end or go on steady: the next end is another)
        return ended

    def refresh(self, core: CoreContext, rows: Iterable[int]) -> None:
        """Rows whose plan (or whose job's hold/HasJob) changed: evaluated afresh at the next run."""
        self.pending.update(rows)

    def _rows_changed(self, on: np.ndarray) -> None:
        """``core.on_rows`` is a new array: if other rows follow a plan now, the groups are other row sets
        (no steady group stays)."""
        self._ends_dirty = True
        if not np.array_equal(on, self._on_seen):
            self._until = [-math.inf] * self.groups  # (each group leaves steady at its next refill)
            self._on_mask = np.zeros(self.n, dtype=bool)
            self._on_mask[on] = True
            # (as rows of the set-point tables: a mask of their shape costs less than one broadcast every cycle)
            self._on_mask4 = np.repeat(self._on_mask[None, :], 4, axis=0)
            self._on_runs = _runs(on, _MAX_RUNS)
        self._on_seen = on

    def _next_ends(self, c: int, left: float) -> None:
        """The first stage cycle at which a running plan may end, ``left`` [s] of plan time after this
        cycle's (the minimum over the rows that follow a plan): the ends are looked for from then on
        (plan times move on by a cycle time per cycle; a margin for the rounding of the additions)."""
        self._ends_dirty = False
        if left == np.inf:
            self._ends_from = np.inf
        elif left > 0:
            self._ends_from = c + math.floor(left / self.dt * 0.999) - 1
        else:  # (one ends now, or NaN: look every cycle)
            self._ends_from = c

    def _drop_steady(self) -> None:
        """The pending rows are not steady from now on (their plans changed: evaluated afresh), the rest of
        their groups from the groups' next refills."""
        G = self.groups
        until, busy, mask, count = self._until, self._busy, self._st_mask, self._g_steady
        for r in self.pending:
            g = r % G
            until[g] = -math.inf
            busy[g] = True
            if mask[r]:
                mask[r] = False
                count[g] -= 1
                self.n_steady -= 1

    def _leave_steady(self, group: int, rows: np.ndarray | slice | None) -> None:
        """The steady rows of ``group`` (its rows ``rows``) are evaluated in full from this refill on."""
        if rows is not None:
            self._st_mask[rows] = False
        self.n_steady -= self._g_steady[group]
        self._g_steady[group] = 0
        self._until[group] = -math.inf

    def _steady_positions(self, core: CoreContext) -> None:
        """This cycle's positions of the steady rows: ``p0 + v0 * tau`` at their plan time, the arithmetic
        :meth:`_eval` does for a segment without jerk and acceleration and with a velocity, bit for bit."""
        a = core.axes
        tau = self._st_tau
        np.subtract(a.traj_t, self._st_t0, out=tau)
        np.multiply(tau, self._st_v0, out=tau)
        if self.n_steady == self.n and not core.has_origin:
            np.add(tau, self._st_p0, out=a.S[0])
            return
        tau += self._st_p0
        if core.has_origin:
            tau += a.origin
        np.copyto(a.S[0], tau, where=self._st_mask)

    def _take_pending(self, a: Any, rows: np.ndarray | slice | None, base: np.ndarray | None,
                      group: int) -> tuple[np.ndarray | slice | None, np.ndarray | None]:
        """Copy the changed plans of the pending rows that run; add those outside this cycle's group
        to ``rows`` (and ``base``)."""
        traj_on = a.traj_on
        pend = self.pending
        if len(pend) == 1:  # (a command: basic indexing)
            idx: int | np.ndarray = pend.pop()
            if not traj_on[idx]:
                return rows, base
            todo = [idx]
        else:
            todo = sorted(r for r in pend if traj_on[r])
            pend.clear()
            if not todo:
                return rows, base
            idx = np.array(todo, dtype=np.intp)
        seg = self.seg
        seg[:5, idx] = a.seg[:, idx]
        if type(idx) is int:  # a / 2 (exact: what evaluate() computes per sample)
            np.multiply(seg[3, idx], 0.5, out=seg[5, idx])
        else:
            seg[5, idx] = seg[3, idx] * 0.5
        G = self.groups
        extra = [r for r in todo if r % G != group] if rows is not None else todo
        if not extra:
            return rows, base
        if rows is None and len(extra) == 1:  # (a command: basic indexing)
            r = extra[0]
            return slice(r, r + 1), self._row_base[r:r + 1]
        more = np.array(extra, dtype=np.intp)
        if rows is not None:
            more = np.concatenate((self._all_groups[group] if isinstance(rows, slice) else rows, more))
        return more, self._row_base[more]

    def _group_rows(self, on: np.ndarray, group: int) -> np.ndarray:
        """The running rows of ``group`` (cached per ``core.on_rows``, which changes on events only)."""
        if on is not self._on_key:
            self._on_key = on
            g = on % self.groups
            self._on_groups = [on[g == k] for k in range(self.groups)]
        return self._on_groups[group]

    def _eval_row(self, core: CoreContext, rows: slice, base: np.ndarray, col: int) -> None:
        """:meth:`_eval` for one row ``rows = slice(r, r + 1)``: when one segment serves all its
        samples (the common case), with that segment's coefficients as scalars (fewer calls; the
        same operations on the same values, bit for bit)."""
        r = rows.start
        a = core.axes
        L = self.lookahead
        seg = self.seg
        t = self._times1.copy()
        t[0] += a.traj_t[r]
        np.add.accumulate(t, out=t)
        starts = seg[0, r].tolist()
        tf, tl = float(t[0]), float(t[-1])
        k = 0
        for j in range(N_SEGMENTS - 1):
            if starts[j + 1] > tf:
                k = j
                break
        if not tl < starts[k + 1]:  # it reaches the next segment in the window
            self._eval(core, rows, base, col, -1)
            return
        self.refills += 1
        self.refill_rows = 1
        t0, p0, v0, a0, j, ah = seg[:, r, k].tolist()
        tau = np.subtract(t, t0, out=t)
        tj = tau * j
        res = self._res[:, :, 0]
        pv = res[:2]
        np.multiply(tj, _SIXTH_HALF[:, :, 0], out=pv)
        pv[0] += ah
        pv[1] += a0
        pv *= tau
        pv += v0
        pos = res[0]
        pos *= tau
        pos += p0
        np.add(a0, tj, out=res[2])
        res[3] = j
        if core.has_origin:
            pos += a.origin[r]
        v, acc = res[1], res[2]
        code = _CLASS_CODES[a.sp_row[r], np.searchsorted(_V_EDGES, v, "right"),
                            np.searchsorted(_A_EDGES, acc, "right"), np.searchsorted(_AV_EDGES, acc * v, "right")]
        words = _SP_WORDS[:, code]
        buf, bw = self.buf, self.buf_words
        if col:
            n1 = L - col
            buf[:, col:, r] = res[:, :n1]
            buf[:, :col, r] = res[:, n1:]
            bw[:, col:, r] = words[:, :n1]
            bw[:, :col, r] = words[:, n1:]
        else:
            buf[:, :, r] = res
            bw[:, :, r] = words

    def _eval(self, core: CoreContext, rows: np.ndarray | slice, base: np.ndarray, col: int, group: int) -> None:
        """Evaluate ``rows`` (offsets ``base`` into the flat segment table, (m,)) for the stage
        cycles from this one on, into columns col, col+1, ... (mod L); samples as (L, m) blocks.

        The arithmetic of :func:`.profile.evaluate`, bit for bit, arranged for blocks of samples.
        ``group`` >= 0: ``rows`` are that group's; make it steady if it is.
        """
        a = core.axes
        L = self.lookahead
        m = base.shape[0]
        self.refills += 1
        self.refill_rows = m
        seg = self.seg
        # plan times of the next L cycles: traj_t + dt, + dt, ... (the additions the cycle makes)
        t_in = self._t_in[:, :m]
        t_in[0] = a.traj_t[rows]
        t = self._t_out[:, :m]
        np.add.accumulate(t_in, axis=0, out=t)
        t = t[1:]
        # the segment in force is the one before the first that starts later: with t0[0] = 0 < t,
        # the first of t0[1:] that starts later (the sentinel never starts) -- evaluate()'s k
        starts = seg[0, rows, 1:]
        if m * L <= _SMALL_BLOCK:
            k = np.argmax(starts > t[:, :, None], axis=2)
            k += base
            k1: np.ndarray | None = k[0] if group >= 0 and np.array_equal(k[0], k[-1]) else None
        else:  # the first sample's segment; only rows reaching their next segment in the window look again
            k = np.argmax(starts > t[0][:, None], axis=1)
            k += base
            cross = (t[-1] >= self._seg_flat[0, k + 1]).nonzero()[0]
            k1 = k
            if cross.size:
                k1 = None
                k = np.repeat(k[None, :], L, axis=0)
                kc = np.argmax(starts[cross] > t[:, cross, None], axis=2)
                kc += base[cross]
                k[:, cross] = kc
        t0, p0, v0, a0, j, ah = self._seg_flat.take(k, axis=1)  # one gather, (L, m) or (m,) each (C order)
        if group >= 0 and k1 is not None:
            self._make_steady(group, rows, k1, t[-1])
        tau = np.subtract(t, t0, out=t)
        tj = tau * j
        res = self._res[:, :, :m]
        pv = res[:2]
        # position p0 + tau * (v0 + tau * (a0 / 2 + tau * j / 6)), velocity v0 + tau * (a0 + tau * j / 2)
        np.multiply(tj, _SIXTH_HALF, out=pv)
        pv[0] += ah
        pv[1] += a0
        pv *= tau
        pv += v0
        pos = res[0]
        pos *= tau
        pos += p0
        np.add(a0, tj, out=res[2])
        res[3] = j  # (broadcast when one segment serves all of a row's samples)
        if core.has_origin:
            pos += a.origin[rows]
        # set-point bits and AxisState: one flag byte per sample (two table lookups when copied)
        v, acc = res[1], res[2]
        rp = a.sp_row[rows]
        if m * L <= _SMALL_BLOCK:
            code = _CLASS_CODES[rp, np.searchsorted(_V_EDGES, v, "right"),
                                np.searchsorted(_A_EDGES, acc, "right"), np.searchsorted(_AV_EDGES, acc * v, "right")]
        else:
            flags = self._flag_bytes[:, :m]
            np.less(np.abs(acc), 1e-9, out=flags[:, :, 1])
            av = acc * v
            np.greater(av, 0, out=flags[:, :, 2])
            np.less(av, 0, out=flags[:, :, 3])
            np.greater(v, _EPS_V, out=flags[:, :, 4])
            np.less(v, -_EPS_V, out=flags[:, :, 5])
            code = flags.view(np.uint64)[:, :, 0] * _PACK
            code >>= _SHIFT
            code |= _ROW_BITS[rp]
        # columns col.. L-1 take the first samples, 0 .. col-1 the rest
        words = _SP_WORDS[:, code]
        buf, bw = self.buf, self.buf_words
        if col:
            n1 = L - col
            buf[:, col:, rows] = res[:, :n1]
            buf[:, :col, rows] = res[:, n1:]
            bw[:, col:, rows] = words[:, :n1]
            bw[:, :col, rows] = words[:, n1:]
        else:
            buf[:, :, rows] = res
            bw[:, :, rows] = words

    def _make_steady(self, group: int, rows: np.ndarray | slice, k: np.ndarray, t_last: np.ndarray) -> None:
        """The group's rows ``rows`` stay in segments ``k`` (flat indices, (m,)) for the window ending at plan
        times ``t_last``: steady if none of them has jerk or acceleration and each has a velocity."""
        sf = self._seg_flat
        if np.count_nonzero(sf[4, k]) or np.count_nonzero(sf[3, k]) or np.count_nonzero(sf[2, k]) < k.size:
            return
        left = float(np.min(sf[0, k + 1] - t_last))  # until the first row reaches its next segment [s]
        c = self.c - 1  # (this refill's stage cycle)
        if left == np.inf:
            until = np.inf
        elif left > 0:  # the window's last sample moves on by a cycle time per cycle: with a margin for the
            until = c + math.floor(left / self.dt * 0.999) - 2  # rounding of the repeated additions
        else:
            return
        self._until[group] = float(until)
        self._st_mask[rows] = True
        self._st_t0[rows], self._st_v0[rows], self._st_p0[rows] = sf[0, k], sf[2, k], sf[1, k]
        self._g_steady[group] = k.size
        self.n_steady += k.size


_SIXTH_HALF = np.array([1.0 / 6.0, 0.5]).reshape(2, 1, 1)
_NO_ROWS = np.zeros(0, dtype=np.intp)
