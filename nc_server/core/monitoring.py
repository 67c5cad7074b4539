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

from nc_schema import ErrorCodes

from .axes import JOB_NONE, AxisTable


def monitor(a: AxisTable, act_pos: np.ndarray, dt: float,
            watch: tuple[np.ndarray, np.ndarray, bool]) -> list[tuple[int, int]]:
    """Update the monitoring state; return the new faults as (row, error code).

    Args:
        watch: (lag monitoring active, logical standstill, any soft limit enabled), per axis
            where arrays; derived by NcCore on events.
    """
    lag_on, standstill, limits = watch
    faults: list[tuple[int, int]] = []
    over = lag_on & (np.abs(a.set_pos - act_pos) > a.lag_max)
    a.lag_timer += dt
    a.lag_timer *= over  # reset where the lag is inside the window
    for i in (over & (a.lag_timer > a.lag_filter)).nonzero()[0]:
        if not a.error[i]:
            faults.append((int(i), ErrorCodes.NC_POSITION_LAG))

    if limits:
        moving = ~standstill & a.enabled
        beyond_max = a.en_max & moving & (act_pos > a.max_lim + a.lag_max) & (a.set_velo > 0)
        beyond_min = a.en_min & moving & (act_pos < a.min_lim - a.lag_max) & (a.set_velo < 0)
        for i in beyond_max.nonzero()[0]:
            if not a.error[i]:
                faults.append((int(i), ErrorCodes.NC_SOFT_LIMIT_MAX_POSITIONING))
        for i in beyond_min.nonzero()[0]:
            if not a.error[i]:
                faults.append((int(i), ErrorCodes.NC_SOFT_LIMIT_MIN_POSITIONING))

    dist = np.abs(act_pos - a.target_pos)
    inside = standstill & a.target_en & (dist <= a.target_win)
    a.window_timer += dt
    a.window_timer *= inside
    a.in_target = inside & (a.window_timer >= a.target_time - 1e-12)
    a.in_area = standstill & a.range_en & (dist <= a.range_win)

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
