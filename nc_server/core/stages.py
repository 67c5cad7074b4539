"""Set-point stages: what produces each axis's set-points in a cycle, in an explicit order.

The NC cycle runs ``NcCore.stages`` in order; each stage owns some axes' set-points for that
cycle and may read any axis's set-point that an earlier stage produced in the same cycle (the
coupling stage of the next issue reads its masters' set-points). Stages are vectorized over the
axes they own; their cost does not depend on how many job kinds exist.

1. :class:`ProfileStage` -- the profile generator: evaluates every running plan (constant-jerk
   segments) for its axes ``lookahead`` cycles ahead, a staggered group of axes per cycle.
2. (coupling, superposition, external set-points: next issue)
3. job watches and limits (``NcCore._stage_jobs``): soft-limit approach of continuous moves,
   switching positions, homing cams/latches, feed enables.
4. the drive, monitoring, NCTOPLC (``NcCore.step``).
"""
from __future__ import annotations

from typing import TYPE_CHECKING, Iterable

import numpy as np

from nc_schema import AxisState, StateDWord

from .profile import N_SEGMENTS, evaluate_block

if TYPE_CHECKING:
    from .nc import NcCore

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
#: packs the 8 bool bytes of a flag row (viewed as one little-endian uint64) into its flag byte:
#: byte b (0/1) lands on bit 56 + b, no two partial products overlap or carry
_PACK = np.uint64(0x0102040810204080)
_SHIFT = np.uint64(56)


class ProfileStage:
    """The profile generator: set-points of the axes that follow a plan (``axes.traj_on``).

    Set-points (and their StateDWord bits and AxisState) are evaluated ``lookahead`` cycles ahead.
    Buffer column ``c % lookahead`` holds the set-points of the stage's cycle ``c`` for every row,
    so a cycle copies one column (basic indexing). The refills are staggered: row ``r`` belongs to
    group ``r % groups``; every ``lookahead // groups`` cycles one group is refilled for the next
    ``lookahead`` cycles (``groups == lookahead``: one group every cycle, each cycle about the same
    work; ``groups == 1``: all rows every ``lookahead``-th cycle). A row whose plan (or job flags)
    changed (:meth:`refresh`) is evaluated for the next ``lookahead`` cycles at the next run, in
    the same evaluation as that cycle's group.

    Plan times advance by repeated addition of the cycle time, exactly as ``axes.traj_t``; a sample
    is therefore the same whenever it is evaluated: set-points do not depend on the lookahead or on
    the refill pattern (bit for bit the set-points of ``lookahead=1``).
    """

    name = "profile"

    def __init__(self, core: NcCore, lookahead: int, groups: int | None = None) -> None:
        n = core.axes.n
        self.n = n
        self.lookahead = lookahead
        self.dt = core.cycle_time
        self.buf = np.zeros((4, n, lookahead))        # set-points, column = stage cycle % lookahead
        self.buf_code = np.zeros((n, lookahead), dtype=np.uint8)  # their flag bytes (SP_*_LUT index)
        self.c = 0  # stage cycles run: the next run produces the set-points of stage cycle c
        self.pending: set[int] = set()  # rows to evaluate at the next run (plans changed)
        self.refills = 0  # runs that evaluated rows (groups or pending)
        self.refill_rows = 0  # rows evaluated by the last run
        self._flags: dict[tuple[int, int], np.ndarray] = {}
        self._on_key: np.ndarray | None = None
        self._on_groups: list[np.ndarray] = []
        self.set_groups(lookahead if groups is None else groups)

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
        self._bases = [(r * N_SEGMENTS)[:, None] for r in self._all_groups]
        self._on_key = None
        self.pending = set(range(n))  # every row from the next run on (whatever ran before)

    def run(self, core: NcCore) -> np.ndarray:
        """Advance one cycle; returns the rows whose plan ended in this cycle."""
        a = core.axes
        on = core.on_rows
        if not on.size:
            self.pending.clear()  # (nothing runs: rows that start later are refreshed then)
            return on
        c = self.c
        self.c = c + 1
        L = self.lookahead
        col = c % L
        rows: np.ndarray | slice | None = None
        group = -1
        if c % self.period == 0:
            group = (c // self.period) % self.groups
            if core.all_on:
                rows = self._all_groups[group]
                if rows.size:
                    rows = slice(group, None, self.groups)
            else:
                rows = self._group_rows(on, group)
        if self.pending:
            traj_on = a.traj_on
            G = self.groups
            extra = [r for r in self.pending if traj_on[r] and r % G != group]
            self.pending.clear()
            if extra:
                extra.sort()
                if rows is None:
                    rows = np.array(extra, dtype=np.intp)
                else:
                    grp = self._all_groups[group] if isinstance(rows, slice) else rows
                    rows = np.concatenate((grp, np.array(extra, dtype=np.intp)))
        if rows is not None:
            self._eval(core, rows, col)
        dt = self.dt
        if core.all_on:
            a.traj_t += dt
            a.S[:] = self.buf[:, :, col]
            code = self.buf_code[:, col]
            np.take(SP_DWORD_LUT, code, out=core.sp_dw)
            np.take(SP_STATE_LUT, code, out=core.axis_state)
            return (a.traj_t >= a.traj_dur).nonzero()[0]
        a.traj_t[on] += dt
        a.S[:, on] = self.buf[:, on, col]
        code = self.buf_code[on, col]
        core.sp_dw[on] = SP_DWORD_LUT[code]
        core.axis_state[on] = SP_STATE_LUT[code]
        return on[a.traj_t[on] >= a.traj_dur[on]]

    def refresh(self, core: NcCore, rows: Iterable[int]) -> None:
        """Rows whose plan (or whose job's hold/HasJob) changed: evaluated afresh at the next run."""
        self.pending.update(rows)

    def _group_rows(self, on: np.ndarray, group: int) -> np.ndarray:
        """The running rows of ``group`` (cached per ``core.on_rows``, which changes on events only)."""
        if on is not self._on_key:
            self._on_key = on
            g = on % self.groups
            self._on_groups = [on[g == k] for k in range(self.groups)]
        return self._on_groups[group]

    def _eval(self, core: NcCore, rows: np.ndarray | slice, col: int) -> None:
        """Evaluate ``rows`` for the stage cycles from this one on, into columns col, col+1, ... (mod L)."""
        a = core.axes
        L = self.lookahead
        if isinstance(rows, slice):
            idx = self._all_groups[rows.start]
            base = self._bases[rows.start]
        else:
            idx = rows
            base = (rows * N_SEGMENTS)[:, None]
        m = idx.size
        if not m:
            return
        self.refills += 1
        self.refill_rows = m
        # plan times of the next L cycles: traj_t + dt, + dt, ... (the additions the cycle makes)
        t = np.empty((m, L))
        t[:, 0] = a.traj_t[rows]
        t[:, 0] += self.dt
        t[:, 1:] = self.dt
        np.add.accumulate(t, axis=1, out=t)
        key = (m, L)
        blk = self._flags.get(key)
        if blk is None:
            blk = self._flags[key] = (np.empty((4, m, L)), np.zeros((m, L, 8), dtype=bool))
        res, flags = blk
        evaluate_block(a.seg, t, rows, base, res)
        if core.has_origin:
            res[0] += a.origin[rows][:, None]
        # set-point bits and AxisState: one flag byte per sample (two table lookups when copied)
        held = a.held[rows]
        v, acc = res[1], res[2]
        flags[:, :, 0] = held[:, None]
        np.less(np.abs(acc), 1e-9, out=flags[:, :, 1])
        av = acc * v
        np.greater(av, 0, out=flags[:, :, 2])
        np.less(av, 0, out=flags[:, :, 3])
        np.greater(v, _EPS_V, out=flags[:, :, 4])
        np.less(v, -_EPS_V, out=flags[:, :, 5])
        flags[:, :, 6] = (a.has_job[rows] > held)[:, None]  # a job and not holding
        code = flags.view(np.uint64)[:, :, 0] * _PACK
        code >>= _SHIFT
        # columns col.. L-1 take the first samples, 0 .. col-1 the rest
        buf, bc = self.buf, self.buf_code
        n1 = L - col
        if col:
            buf[:, rows, col:] = res[:, :, :n1]
            buf[:, rows, :col] = res[:, :, n1:]
            bc[rows, col:] = code[:, :n1]
            bc[rows, :col] = code[:, n1:]
        else:
            buf[:, rows, :] = res
            bc[rows, :] = code
