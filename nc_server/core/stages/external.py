"""The external set-point stage: set-points fed by the PLC through PLCTONC (TcMC 4.16-4.18).

The PLC cycle is slower than the NC's (10 ms against 1 ms): a fed set-point (ExtSetPos,
ExtSetVelo, ExtSetAcc) is applied in the NC cycle its PLCTONC arrives in, exactly, and the NC
cycles until the next feed continue it with the fed velocity and acceleration
(``p = ExtSetPos + ExtSetVelo * t + ExtSetAcc * t^2 / 2``, ``t`` = time since the feed): exact for
a generator whose acceleration is constant between its samples, and a jerk-limited one's
deviation is of order jerk * (PLC cycle)^3 / 6. A feed is "new" when any of the three values
changed. ExtSetDirection is informational (the direction bits come from the velocity).

No jump: after MC_ExtSetPointGenEnable the axis holds its set position until a fed position lies
within AxisVeloMax x 1.5 cycles of it (MC_ExtSetPointGenEnable feeds the current SetPos first);
from then a fed set-point that would jump further in one cycle, or a fed velocity above
AxisVeloMax, is an axis error 0x4359 (set velocity not allowed) and the axis brakes on its ramp.
A PLC that stops feeding is the watchdog's case: its PLCTONC times out (0x8F02), the axis stops.
"""
from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from nc_schema import AxisState, StateDWord

if TYPE_CHECKING:
    from ..nc import NcCore

_EPS_V = 1e-9
_NOT_MOVING = np.uint32(int(StateDWord.NotMoving))
_POS = np.uint32(int(StateDWord.PositiveDirection))
_NEG = np.uint32(int(StateDWord.NegativeDirection))
_RUNNING = np.uint32(int(AxisState.RUNNING))


class ExternalStage:
    """Axes whose set-points the PLC feeds. Columns: ``on`` (enabled), ``following`` (a fed
    set-point matched: the feed is applied), ``fed`` (the last feed: p, v, a), ``tau`` (s since it),
    ``offset`` (superimposed distances folded into the fed positions)."""

    name = "external"

    def __init__(self, n: int, cycle_time: float) -> None:
        self.dt = cycle_time
        self.on = np.zeros(n, dtype=bool)
        self.following = np.zeros(n, dtype=bool)
        self.fed = np.full((3, n), np.nan)
        self.tau = np.zeros(n)
        self.offset = np.zeros(n)
        self.rows = np.zeros(0, dtype=np.intp)
        self.changed = False  # following flags changed: NcCore refreshes the job records

    @property
    def active(self) -> bool:
        return bool(self.rows.size)

    def enable(self, core: NcCore, i: int) -> None:
        self.on[i] = True
        self.following[i] = False
        self.fed[:, i] = np.nan  # whatever PLCTONC holds counts as a new feed
        self.offset[i] = 0.0
        self.rows = self.on.nonzero()[0]
        self.changed = True

    def release(self, i: int) -> None:
        if not self.on[i]:
            return
        self.on[i] = self.following[i] = False
        self.rows = self.on.nonzero()[0]
        self.changed = True

    def fold(self, i: int, diff: float) -> None:
        self.offset[i] += diff

    def run(self, core: NcCore) -> list[int]:
        """Set-points of the enabled axes for this cycle. Returns the rows whose feed jumps or is
        too fast (the NC faults them with 0x4359)."""
        rows = self.rows
        a, S = core.axes, core.axes.S
        pc = core.plctonc[rows]
        feed = np.stack((pc["ExtSetPos"], pc["ExtSetVelo"], pc["ExtSetAcc"]))
        new = (feed != self.fed[:, rows]).any(axis=0)
        self.fed[:, rows[new]] = feed[:, new]
        tau = self.tau[rows]
        tau[new] = 0.0
        tau[~new] += self.dt
        self.tau[rows] = tau
        f = self.fed[:, rows]
        p = f[0] + f[1] * tau + 0.5 * f[2] * tau * tau + self.offset[rows]
        v = f[1] + f[2] * tau
        prev = S[0, rows]
        reach = a.vmax[rows] * self.dt * 1.5 + 1e-9
        step = np.abs(p - prev)
        ok = np.isfinite(p) & np.isfinite(v)
        follow = self.following[rows]
        starts = ~follow & ok & (step <= reach)
        if starts.any():
            self.following[rows[starts]] = True
            self.changed = True
            follow = follow | starts
        bad = follow & (~ok | (step > reach) | (np.abs(v) > a.vmax[rows] * (1 + 1e-6) + _EPS_V))
        apply = follow & ~bad
        if bad.any():  # the fault ramp starts next cycle: this one continues with the last velocity
            rb = rows[bad]
            S[0, rb] += S[1, rb] * self.dt
        r = rows[apply]
        S[0, r], S[1, r], S[2, r], S[3, r] = p[apply], v[apply], f[2][apply], 0.0
        held = rows[~follow]
        S[1:, held] = 0.0  # waiting for a matching feed: the axis holds
        vv = S[1, rows]
        core.sp_dw[rows] = np.where(np.abs(vv) > _EPS_V, np.where(vv > 0, _POS, _NEG), _NOT_MOVING)
        core.axis_state[rows] = np.where(np.abs(vv) > _EPS_V, _RUNNING, np.uint32(0))
        return rows[bad].tolist()
