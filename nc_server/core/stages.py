"""Set-point stages: what produces each axis's set-points in a cycle, in an explicit order.

The NC cycle runs ``NcCore.stages`` in order; each stage owns some axes' set-points for that
cycle and may read any axis's set-point that an earlier stage produced in the same cycle (the
coupling stage of the next issue reads its masters' set-points). Stages are vectorized over the
axes they own; their cost does not depend on how many job kinds exist.

1. :class:`ProfileStage` -- the profile generator: evaluates every running plan (constant-jerk
   segments) for its axes, 16 (or 4) cycles ahead at once.
2. (coupling, superposition, external set-points: next issue)
3. job watches and limits (``NcCore._stage_jobs``): soft-limit approach of continuous moves,
   switching positions, homing cams/latches, feed enables.
4. the drive, monitoring, NCTOPLC (``NcCore.step``).
"""
from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from nc_schema import AxisState, StateDWord

from .profile import evaluate

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


class ProfileStage:
    """The profile generator: set-points of the axes that follow a plan (``axes.traj_on``).

    Set-points (and their StateDWord bits and AxisState) are evaluated ``lookahead`` cycles ahead
    for all axes at once; when a plan changes only that axis is re-evaluated (:meth:`refresh`).
    Every ``lookahead``-th cycle refills all running rows at once (not staggered: see the note).
    """

    name = "profile"

    def __init__(self, core: NcCore, lookahead: int) -> None:
        n = core.axes.n
        self.lookahead = lookahead
        self.buf = np.zeros((4, n, lookahead))        # set-points of the next `lookahead` cycles
        self.buf_dw = np.zeros((n, lookahead), dtype=np.uint32)  # their StateDWord bits
        self.buf_st = np.zeros((n, lookahead), dtype=np.uint32)  # their AxisState
        self.k = lookahead
        self.t_ahead = core.cycle_time * np.arange(1, lookahead + 1)
        self._flags: dict[tuple[int, int], np.ndarray] = {}
        self.refills = 0

    def run(self, core: NcCore) -> np.ndarray:
        """Advance one cycle; returns the rows whose plan ended in this cycle."""
        a = core.axes
        on = core.on_rows
        if not on.size:
            return on
        dt = core.cycle_time
        if self.k >= self.lookahead:
            self.k = 0
            self.refills += 1
            self._eval_into(core, on)
        k = self.k
        self.k = k + 1
        if core.all_on:
            a.traj_t += dt
            a.S[:] = self.buf[:, :, k]
            core.sp_dw[:] = self.buf_dw[:, k]
            core.axis_state[:] = self.buf_st[:, k]
            return (a.traj_t >= a.traj_dur).nonzero()[0]
        a.traj_t[on] += dt
        a.S[:, on] = self.buf[:, on, k]
        core.sp_dw[on] = self.buf_dw[on, k]
        core.axis_state[on] = self.buf_st[on, k]
        return on[a.traj_t[on] >= a.traj_dur[on]]

    def refresh(self, core: NcCore, rows: np.ndarray) -> None:
        """Re-evaluate the rest of the buffer for ``rows`` (their plans changed)."""
        if rows.size and self.k < self.lookahead:
            self._eval_into(core, rows)

    def _eval_into(self, core: NcCore, rows: np.ndarray) -> None:
        a = core.axes
        k0 = self.k
        ncol = self.lookahead - k0
        m = rows.size
        t = (a.traj_t[rows][:, None] + self.t_ahead[:ncol]).ravel()
        p, v, acc, j = evaluate(a.seg, t, np.repeat(rows, ncol))
        if core.has_origin:
            p = p + np.repeat(a.origin[rows], ncol)
        # one row (a command) or all rows: basic indexing, much cheaper than fancy indexing
        sel: int | slice | np.ndarray = int(rows[0]) if m == 1 else (slice(None) if m == a.n else rows)
        shape = (ncol,) if m == 1 else (m, ncol)
        buf = self.buf
        for r, x in enumerate((p, v, acc, j)):
            buf[r, sel, k0:] = x.reshape(shape)
        # set-point bits and AxisState: one packed flag byte per sample, two table lookups
        flags = self._flags.get((m, ncol))
        if flags is None:
            flags = self._flags[(m, ncol)] = np.zeros((m, ncol, 8), dtype=bool)
        flags[:, :, 0] = a.held[rows][:, None]
        flags[:, :, 1] = (np.abs(acc) < 1e-9).reshape(m, ncol)
        av = (acc * v).reshape(m, ncol)
        flags[:, :, 2] = av > 0
        flags[:, :, 3] = av < 0
        v = v.reshape(m, ncol)
        flags[:, :, 4] = v > _EPS_V
        flags[:, :, 5] = v < -_EPS_V
        flags[:, :, 6] = (a.has_job[rows] & ~a.held[rows])[:, None]
        code = np.packbits(flags, axis=2, bitorder="little")[:, :, 0]
        self.buf_dw[sel, k0:] = SP_DWORD_LUT[code].reshape(shape)
        self.buf_st[sel, k0:] = SP_STATE_LUT[code].reshape(shape)
