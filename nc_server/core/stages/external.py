"""The external set-point stage: set-points fed by the PLC through PLCTONC (TcMC 4.16-4.18).

The PLC cycle is slower than the NC's (10 ms against 1 ms): a fed set-point (ExtSetPos,
ExtSetVelo, ExtSetAcc) is applied in the NC cycle its PLCTONC arrives in, exactly, and the NC
cycles until the next feed continue it with the fed velocity and acceleration
(``p = ExtSetPos + ExtSetVelo * t + ExtSetAcc * t^2 / 2``, ``t`` = time since the feed): exact for
a generator whose acceleration is constant between its samples, and a jerk-limited one's
deviation is of order jerk * (PLC cycle)^3 / 6. A feed is "new" when any of the three values
changed. ExtSetDirection is informational (the direction bits come from the velocity).

No jump: after MC_ExtSetPointGenEnable the axis holds its set position until a fed set-point
matches where the axis is, within one cycle of the fed velocity (MC_ExtSetPointGenEnable feeds the
current SetPos with velocity 0 first). From then, with T the time since the previous feed (the
longer of the last two feed intervals plus a cycle of arrival jitter; a cycle between feeds) and
amax = max(AxisAcc, AxisDec): a set-point farther than amax T^2 / 2 from where
the axis gets to at the mean of the last and the new velocity, a velocity step beyond amax T or a
fed velocity above AxisVeloMax is an axis error 0x4359 (set velocity not allowed), a fed
acceleration above amax 0x422F; the axis then brakes on its ramp. (A generator that feeds no
acceleration and ramps within AxisAcc stays inside, at any PLC/NC cycle ratio.)
A PLC that stops feeding is the watchdog's case: its PLCTONC times out (0x8F02), the axis stops.
"""
from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from nc_schema import AxisState, ErrorCodes, StateDWord

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
        self.last_span = np.zeros(n)  # the time between the last two feeds [s]
        self.offset = np.zeros(n)
        self.rows = np.zeros(0, dtype=np.intp)
        self.changed_rows: list[int] = []  # rows whose following flag changed (their job records)

    @property
    def active(self) -> bool:
        return bool(self.rows.size)

    def enable(self, core: NcCore, i: int) -> None:
        self.on[i] = True
        self.following[i] = False
        self.fed[:, i] = np.nan  # whatever PLCTONC holds counts as a new feed
        self.tau[i] = self.last_span[i] = 0.0
        self.offset[i] = 0.0
        self.rows = self.on.nonzero()[0]

    def release(self, i: int) -> None:
        if not self.on[i]:
            return
        self.on[i] = self.following[i] = False
        self.rows = self.on.nonzero()[0]

    def fold(self, i: int, diff: float) -> None:
        self.offset[i] += diff

    def run(self, core: NcCore) -> list[tuple[int, int]]:
        """Set-points of the enabled axes for this cycle. Returns (row, code) of the feeds the NC
        faults: 0x4359 a jump or a velocity above AxisVeloMax, 0x422F an acceleration above
        max(AxisAcc, AxisDec)."""
        rows = self.rows
        a, S = core.axes, core.axes.S
        dt = self.dt
        pc = core.plctonc[rows]
        feed = np.stack((pc["ExtSetPos"], pc["ExtSetVelo"], pc["ExtSetAcc"]))
        new = (feed != self.fed[:, rows]).any(axis=0)
        self.fed[:, rows[new]] = feed[:, new]
        tau = self.tau[rows]
        # the time a new feed may have taken from the previous one: as measured here, or as the previous
        # feed took (frames bunch on their way), plus a cycle of arrival jitter; between feeds a cycle
        since = tau + dt
        span = np.where(new, np.maximum(since, self.last_span[rows]) + dt, dt)
        self.last_span[rows[new]] = since[new]
        tau[new] = 0.0
        tau[~new] += dt
        self.tau[rows] = tau
        f = self.fed[:, rows]
        p = f[0] + f[1] * tau + 0.5 * f[2] * tau * tau + self.offset[rows]
        v = f[1] + f[2] * tau
        prev_p, prev_v = S[0, rows], S[1, rows]
        ok = np.isfinite(p) & np.isfinite(v) & np.isfinite(f[2])
        follow = self.following[rows]
        # where the axis gets to in this cycle at the mean of both velocities, and how far a feed may be
        # from it: what the axis's acceleration can make of the time T since the previous feed
        # (a amax T^2 / 2 in position, amax T in velocity: a generator that feeds no acceleration and
        # ramps at AxisAcc stays inside; a jump or a velocity step does not)
        dev = np.abs(p - (prev_p + 0.5 * (prev_v + v) * dt))
        scale = np.maximum(np.abs(p), 1.0)
        # (to start with: a feed within one cycle of its own velocity of the standing axis)
        starts = ~follow & ok & (np.abs(p - prev_p) <= np.abs(v) * dt + 1e-9 * scale)
        if starts.any():
            self.following[rows[starts]] = True
            self.changed_rows += rows[starts].tolist()
            follow = follow | starts
        vmax = a.vmax[rows]
        amax = np.maximum(a.acc[rows], a.dec[rows])
        jump = follow & (~ok | (dev > 0.5 * amax * span * span + 1e-9 * scale)
                         | (np.abs(v - prev_v) > amax * span * (1 + 1e-6) + 1e-9)
                         | (np.abs(v) > vmax * (1 + 1e-6) + _EPS_V))
        hard = follow & ok & ~jump & (np.abs(f[2]) > amax * (1 + 1e-6) + 1e-6)
        bad = jump | hard
        apply = follow & ~bad
        if bad.any():  # the fault ramp starts next cycle: this one continues with the last velocity
            rb = rows[bad]
            S[0, rb] += S[1, rb] * dt
        r = rows[apply]
        S[0, r], S[1, r], S[2, r], S[3, r] = p[apply], v[apply], f[2][apply], 0.0
        held = rows[~follow]
        S[1:, held] = 0.0  # waiting for a matching feed: the axis holds
        vv = S[1, rows]
        core.sp_dw[rows] = np.where(np.abs(vv) > _EPS_V, np.where(vv > 0, _POS, _NEG), _NOT_MOVING)
        core.axis_state[rows] = np.where(np.abs(vv) > _EPS_V, _RUNNING, np.uint32(0))
        if not bad.any():
            return []
        return ([(int(i), int(ErrorCodes.NC_AXIS_SET_VELOCITY)) for i in rows[jump].tolist()]
                + [(int(i), int(ErrorCodes.NC_ACCELERATION_NOT_ALLOWED)) for i in rows[hard].tolist()])
