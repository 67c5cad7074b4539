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
"""
from __future__ import annotations

import numpy as np

from nc_schema import ErrorCodes, StateDWord

from .axes import AxisTable


_IN_AREA = np.uint32(int(StateDWord.InPositionArea))
_IN_TARGET = np.uint32(int(StateDWord.InTargetPosition))
_SOFT_MIN = np.uint32(int(StateDWord.SoftLimitMinExceeded))
_SOFT_MAX = np.uint32(int(StateDWord.SoftLimitMaxExceeded))


def monitor(a: AxisTable, act_pos: np.ndarray, dt: float,
            watch: tuple[np.ndarray, np.ndarray, bool, bool]) -> list[tuple[int, int]]:
    """Update the monitoring state and ``a.mon_dw`` (its StateDWord bits); return new faults (row, code).

    Args:
        watch: (lag monitoring active, logical standstill, any soft limit enabled, any axis standing),
            derived by NcCore on events.
    """
    lag_on, standstill, limits, any_standing = watch
    faults: list[tuple[int, int]] = []
    over = np.abs(a.set_pos - act_pos) > a.lag_max
    over &= lag_on
    a.lag_timer += dt
    a.lag_timer *= over  # reset where the lag is inside the window
    for i in (a.lag_timer > a.lag_filter).nonzero()[0]:
        if not a.error[i]:
            faults.append((int(i), ErrorCodes.NC_POSITION_LAG))

    mon = a.mon_dw
    mon[:] = 0
    if limits:
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
        dist = np.abs(act_pos - a.target_pos)
        inside = standstill & a.target_en & (dist <= a.target_win)
        a.window_timer += dt
        a.window_timer *= inside
        a.in_target = inside & (a.window_timer >= a.target_time - 1e-12)
        a.in_area = standstill & a.range_en & (dist <= a.range_win)
        mon |= a.in_area * _IN_AREA
        mon |= a.in_target * _IN_TARGET
    elif np.count_nonzero(a.in_target) or np.count_nonzero(a.in_area):  # (far cheaper than ndarray.any)
        a.in_target[:] = False
        a.in_area[:] = False
        a.window_timer[:] = 0.0

    watching = (a.since_end >= 0).nonzero()[0]
    if watching.size:
        w = watching
        reached = a.in_target[w]
        a.since_end[w] += dt * standstill[w]
        a.since_end[w[reached]] = -1.0
        late = w[~reached & a.peh_en[w] & a.target_en[w] & (a.since_end[w] > a.peh_time[w])]
        for i in late:
            if not a.error[i]:
                faults.append((int(i), ErrorCodes.NC_AXIS_PEH_TIMEOUT))
            a.since_end[i] = -1.0
    return faults
