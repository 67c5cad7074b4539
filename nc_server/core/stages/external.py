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
acceleration and ramps within AxisAcc stays inside, at any PLC/NC cycle ratio up to a feed interval
of MAX_FEED_INTERVAL, 50 ms.) The fed acceleration carries the set-point between feeds until the
velocity reaches 0 or AxisVeloMax. An enabled software limit: a fed position beyond it that moves
further out, or a velocity that even amax could not stop before it, is 0x4463/0x4462.
A PLC that stops feeding is the watchdog's case: its PLCTONC times out (0x8F02), the axis stops.
"""
from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from nc_schema import AxisState, ErrorCodes

from .profile import motion_dwords

if TYPE_CHECKING:
    from ..context import CoreContext

_EPS_V = 1e-9
_RUNNING = np.uint32(int(AxisState.RUNNING))
#: feeds farther apart are judged as this far apart [s]: the allowances grow with the feed interval,
#: and a PLC that paused must not earn a jump by it (PLC cycles up to 50 ms feed within the rules)
MAX_FEED_INTERVAL = 0.05


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
        self.changed: list[int] = []  # rows whose following flag changed (their job records)

    @property
    def active(self) -> bool:
        return bool(self.rows.size)

    def enable(self, core: CoreContext, i: int) -> None:
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

    def run(self, core: CoreContext) -> list[tuple[int, int]]:
        """Set-points of the enabled axes for this cycle. Returns (row, code) of the feeds the NC
        faults: 0x4359 a jump, a velocity step or a velocity above AxisVeloMax, 0x422F an
        acceleration above max(AxisAcc, AxisDec), 0x4463/0x4462 a software limit."""
        rows = self.rows
        a, S = core.axes, core.axes.S
        dt = self.dt
        pc = core.plctonc[rows]
        feed = np.stack((pc["ExtSetPos"], pc["ExtSetVelo"], pc["ExtSetAcc"]))
        # a feed is a PLCTONC frame (also one that repeats the values: the generator stands), or a
        # change of the values by other means
        new = core.plctonc_arrived[rows] | (feed != self.fed[:, rows]).any(axis=0)
        core.plctonc_arrived[rows] = False
        a_prev = np.where(np.isfinite(self.fed[2, rows]), self.fed[2, rows], 0.0)
        self.fed[:, rows[new]] = feed[:, new]
        tau = self.tau[rows]
        # the time a new feed may have taken from the previous one: as measured here, or as the previous
        # feed took (frames bunch on their way), plus a cycle of arrival jitter; between feeds a cycle
        since = tau + dt
        span = np.minimum(np.where(new, np.maximum(since, self.last_span[rows]) + dt, dt), MAX_FEED_INTERVAL)
        self.last_span[rows[new]] = since[new]
        tau[new] = 0.0
        tau[~new] += dt
        self.tau[rows] = tau
        f = self.fed[:, rows]
        vmax = a.vmax[rows]
        amax = np.maximum(a.acc[rows], a.dec[rows])
        # extrapolation with the fed acceleration until the velocity reaches 0 or AxisVeloMax, then on
        # at that velocity (a generator that stops or reaches its speed between two feeds)
        P, V, A = f
        with np.errstate(divide="ignore", invalid="ignore"):
            t_lim = np.where(A * V < 0, -V / A, np.where(A != 0, (np.sign(A) * vmax - V) / A, np.inf))
        ta = np.clip(np.minimum(tau, np.where(np.isfinite(t_lim), t_lim, np.inf)), 0.0, None)
        p = P + V * tau + A * ta * (tau - 0.5 * ta) + self.offset[rows]
        v = V + A * ta
        acc_now = np.where(tau < t_lim, A, 0.0)
        prev_p, prev_v = S[0, rows], S[1, rows]
        ok = np.isfinite(p) & np.isfinite(v) & np.isfinite(A)
        follow = self.following[rows]
        dev = np.abs(p - (prev_p + 0.5 * (prev_v + v) * dt))
        scale = np.maximum(np.abs(p), 1.0)
        # (to start with: a feed within one cycle of its own velocity of the standing axis)
        starts = ~follow & ok & (np.abs(p - prev_p) <= np.abs(v) * dt + 1e-9 * scale)
        if starts.any():
            self.following[rows[starts]] = True
            self.changed += rows[starts].tolist()
            follow = follow | starts
        # what the axis's acceleration (and a reversal of the fed one) can make of the feed interval,
        # plus two cycles of arrival jitter at the velocity
        a_env = amax + np.abs(a_prev)
        pos_tol = 0.5 * a_env * span * span + 2.0 * np.abs(v) * dt + 1e-9 * scale
        jump = follow & (~ok | (dev > pos_tol) | (np.abs(v - prev_v) > a_env * span * (1 + 1e-6) + 1e-9)
                         | (np.abs(V) > vmax * (1 + 1e-6) + _EPS_V))
        hard = follow & ok & ~jump & (np.abs(A) > amax * (1 + 1e-6) + 1e-6)
        # software limits: beyond one and moving further out, or unable to stop before it even at
        # amax (the generator is responsible for its braking; the NC catches what cannot end well)
        # (the generator may have been braking at amax since its last feed, and the extrapolation of a
        # feed without acceleration may lie a amax T^2 / 2 beyond it: judged with both)
        t_feed = np.minimum(np.where(new, span, tau + dt), MAX_FEED_INTERVAL)
        slack = amax * t_feed
        v_eff = np.maximum(np.abs(v) - slack, 0.0)
        ext_tol = 0.5 * a_env * t_feed * t_feed + 1e-6 * scale
        stop_end = p + np.sign(v) * v_eff * v_eff / (2.0 * amax)
        out_max = a.en_max[rows] & (((p > a.max_lim[rows] + ext_tol) & (p > prev_p))
                                    | ((v > 0) & (stop_end > a.max_lim[rows] + ext_tol)))
        out_min = a.en_min[rows] & (((p < a.min_lim[rows] - ext_tol) & (p < prev_p))
                                    | ((v < 0) & (stop_end < a.min_lim[rows] - ext_tol)))
        limit = follow & ok & ~jump & ~hard & (out_max | out_min)
        bad = jump | hard | limit
        apply = follow & ~bad
        if bad.any():  # the fault ramp starts next cycle: this one continues with the last velocity
            rb = rows[bad]
            S[0, rb] += S[1, rb] * dt
        r = rows[apply]
        S[0, r], S[1, r], S[2, r], S[3, r] = p[apply], v[apply], acc_now[apply], 0.0
        held = rows[~follow]
        S[1:, held] = 0.0  # waiting for a matching feed: the axis holds
        vv = S[1, rows]
        core.sp_dw[rows] = motion_dwords(vv)
        core.axis_state[rows] = np.where(np.abs(vv) > _EPS_V, _RUNNING, np.uint32(0))
        if not bad.any():
            return []
        return ([(int(i), int(ErrorCodes.NC_AXIS_SET_VELOCITY)) for i in rows[jump].tolist()]
                + [(int(i), int(ErrorCodes.NC_ACCELERATION_NOT_ALLOWED)) for i in rows[hard].tolist()]
                + [(int(i), int(ErrorCodes.NC_SOFT_LIMIT_MAX_POSITIONING if out_max[k] else ErrorCodes.NC_SOFT_LIMIT_MIN_POSITIONING))
                   for k, i in zip(np.flatnonzero(limit).tolist(), rows[limit].tolist())])
