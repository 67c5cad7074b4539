"""Per-cycle monitoring of all axes at once (vectorized).

* Position lag (0x4550): |SetPos - ActPos| > AxisMaxPosLagValue for longer than
  AxisMaxPosLagFilterTime, while the controller is enabled.
* Software limits while positioning (0x4462/0x4463): the actual position beyond an
  enabled limit by more than AxisMaxPosLagValue (TwinCAT widens the limit by the
  lag window for servo axes) while the axis is moving.
* InTargetPosition: at logical standstill (no job), |ActPos - TargetPos| <=
  AxisTargetPositionWindow continuously for AxisTargetPositionMonitoringTime.
* InPositionArea: at logical standstill, |ActPos - TargetPos| <= AxisPositionRangeWindow.
* PEH time (0x435C): with AxisEnInTargetTimeout, the target window not reached
  within AxisInTargetTimeout after the logical end of a positioning job.
* Motion monitoring (0x435D): with AxisEnMotionMonitoring, while the set velocity is not 0, the
  override above 0 and the controller enabled, the actual position must move by
  AxisMotionMonitoringWindow within AxisMotionMonitoringTime (a blocked axis or a dead encoder).
  Beckhoff's text of 0x435D: "actual position changed too little within the monitoring time"; its
  hydraulics library's check of the same error: "whether the axis has traveled at least a MinDistance
  within Filter" (https://infosys.beckhoff.com/content/1033/tcplclibhydraulics30/1599777931.html).
  Decisions (the manual is silent): a window starts where the axis is when the watch begins and again
  each time it moved by the window (in either direction); standing axes, override 0 and disabled
  axes are not watched (a held job is not a blocked axis); reaching the target window in time stays
  the PEH check (0x435C).

The lag is measured against ``ref`` (the set position the controller uses: with a dead time,
:mod:`.corrections`' delayed one).
"""
from __future__ import annotations

import numpy as np

from nc_schema import ErrorCodes, StateDWord

from .axes import AxisTable
from .npcount import count_nonzero


_IN_AREA = np.uint32(int(StateDWord.InPositionArea))
_IN_TARGET = np.uint32(int(StateDWord.InTargetPosition))
_SOFT_MIN = np.uint32(int(StateDWord.SoftLimitMinExceeded))
_SOFT_MAX = np.uint32(int(StateDWord.SoftLimitMaxExceeded))
_EPS_V = 1e-9
_NO_ROWS = np.zeros(0, dtype=np.intp)


def monitor(a: AxisTable, act_pos: np.ndarray, dt: float,
            watch: tuple[np.ndarray, np.ndarray, bool, bool], ref: np.ndarray | None = None) -> list[tuple[int, int]]:
    """Update the monitoring state and ``a.mon_dw`` (its StateDWord bits); return new faults (row, code).

    Args:
        watch: (lag monitoring active, logical standstill, any soft limit enabled, any axis standing),
            derived by NcCore on events.
        ref: the set position the lag is measured from (default: SetPos).
    """
    lag_on, standstill, limits, any_standing = watch
    faults: list[tuple[int, int]] = []
    if count_nonzero(lag_on):
        lag = np.subtract(a.set_pos if ref is None else ref, act_pos)  # |SetPos - ActPos| > AxisMaxPosLagValue
        np.abs(lag, out=lag)
        over = np.greater(lag, a.lag_max)
        over &= lag_on
        a.lag_timer += dt
        a.lag_timer *= over  # reset where the lag is inside the window
        a.lag_clear = False
        for i in (a.lag_timer > a.lag_filter).nonzero()[0]:
            if not a.error[i]:
                faults.append((int(i), ErrorCodes.NC_POSITION_LAG))
    elif not a.lag_clear:  # (no axis watched: the timers as the full check leaves them; then known 0)
        if count_nonzero(a.lag_timer):
            a.lag_timer[:] = 0.0
        a.lag_clear = True

    mon = a.mon_dw
    if not a.mon_clear:
        mon[:] = 0
        a.mon_clear = True
    if limits:
        a.mon_clear = False
        min_ex = a.en_min & (act_pos < a.min_lim)
        max_ex = a.en_max & (act_pos > a.max_lim)
        mon |= min_ex * _SOFT_MIN
        mon |= max_ex * _SOFT_MAX
        moving = ~standstill & a.enabled
        beyond_max = max_ex & moving & (act_pos > a.max_lim + a.lag_max) & (a.set_velo > 0)
        beyond_min = min_ex & moving & (act_pos < a.min_lim - a.lag_max) & (a.set_velo < 0)
        for i in beyond_max.nonzero()[0]:
            if not a.error[i]:
                faults.append((int(i), ErrorCodes.NC_SOFT_LIMIT_MAX_POSITIONING))
        for i in beyond_min.nonzero()[0]:
            if not a.error[i]:
                faults.append((int(i), ErrorCodes.NC_SOFT_LIMIT_MIN_POSITIONING))

    if any_standing:  # the windows only apply at logical standstill
        a.mon_clear = False
        dist = np.abs(act_pos - a.target_pos)
        inside = standstill & a.target_en & (dist <= a.target_win)
        a.window_timer += dt
        a.window_timer *= inside
        a.in_target = inside & (a.window_timer >= a.target_time - 1e-12)
        a.in_area = standstill & a.range_en & (dist <= a.range_win)
        mon |= a.in_area * _IN_AREA
        mon |= a.in_target * _IN_TARGET
        a.windows_clear = False
    elif not a.windows_clear:  # (then known False until some axis stands again)
        if count_nonzero(a.in_target) or count_nonzero(a.in_area):  # (far cheaper than ndarray.any)
            a.in_target[:] = False
            a.in_area[:] = False
            a.window_timer[:] = 0.0
        a.windows_clear = True

    watching = (a.since_end >= 0).nonzero()[0] if a.end_watch else _NO_ROWS
    if not watching.size:
        a.end_watch = False
    else:
        w = watching
        reached = a.in_target[w]
        a.since_end[w] += dt * standstill[w]
        a.since_end[w[reached]] = -1.0
        late = w[~reached & a.peh_en[w] & a.target_en[w] & (a.since_end[w] > a.peh_time[w])]
        for i in late:
            if not a.error[i]:
                faults.append((int(i), ErrorCodes.NC_AXIS_PEH_TIMEOUT))
            a.since_end[i] = -1.0
    if a.mm_rows.size:
        faults += _motion(a, act_pos, dt)
    return faults


def _motion(a: AxisTable, act_pos: np.ndarray, dt: float) -> list[tuple[int, int]]:
    """Motion monitoring of the axes that have it on (module docstring): 0x435D where the actual
    position moved less than the window within the time while the axis should move."""
    r = a.mm_rows
    p = act_pos[r]
    anchor = a.mm_anchor[r]
    watched = a.enabled[r] & (np.abs(a.set_velo[r]) > _EPS_V) & (a.override[r] > 0)
    restart = np.abs(p - anchor) >= a.mm_win[r]  # (a NaN anchor: False)
    restart |= ~watched
    restart |= np.isnan(anchor)
    a.mm_anchor[r] = np.where(restart, p, anchor)
    timer = np.where(restart, 0.0, a.mm_timer[r] + dt)
    a.mm_timer[r] = timer
    out: list[tuple[int, int]] = []
    for k in np.flatnonzero(timer >= a.mm_time[r] - 1e-12).tolist():
        i = int(r[k])
        a.mm_timer[i] = 0.0
        a.mm_anchor[i] = act_pos[i]
        if not a.error[i]:
            out.append((i, int(ErrorCodes.NC_AXIS_MOTION_MONITORING)))
    return out
