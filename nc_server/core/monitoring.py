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


def monitor(a: AxisTable, act_pos: np.ndarray, dt: float) -> list[tuple[int, int]]:
    """Update the monitoring state; return the new faults as (row, error code)."""
    faults: list[tuple[int, int]] = []
    ok = a.error == 0
    lag = np.abs(a.set_pos - act_pos)
    over = a.lag_en & a.enabled & (lag > a.lag_max)
    a.lag_timer = np.where(over, a.lag_timer + dt, 0.0)
    for i in np.flatnonzero(ok & over & (a.lag_timer > a.lag_filter)):
        faults.append((int(i), ErrorCodes.NC_POSITION_LAG))

    moving = a.traj_on | (a.job != JOB_NONE)
    beyond_max = a.en_max & moving & (act_pos > a.max_lim + a.lag_max) & (a.set_velo > 0)
    beyond_min = a.en_min & moving & (act_pos < a.min_lim - a.lag_max) & (a.set_velo < 0)
    for i in np.flatnonzero(ok & beyond_max):
        faults.append((int(i), ErrorCodes.NC_SOFT_LIMIT_MAX_POSITIONING))
    for i in np.flatnonzero(ok & beyond_min):
        faults.append((int(i), ErrorCodes.NC_SOFT_LIMIT_MIN_POSITIONING))

    standstill = (a.job == JOB_NONE) & ~a.traj_on & a.enabled
    dist = np.abs(act_pos - a.target_pos)
    inside = standstill & a.target_en & (dist <= a.target_win)
    a.window_timer = np.where(inside, a.window_timer + dt, 0.0)
    a.in_target = inside & (a.window_timer >= a.target_time - 1e-12)
    a.in_area = standstill & a.range_en & (dist <= a.range_win)

    watching = a.since_end >= 0
    a.since_end = np.where(watching & ~a.in_target & standstill, a.since_end + dt, np.where(a.in_target, -1.0, a.since_end))
    late = ok & watching & a.peh_en & a.target_en & ~a.in_target & (a.since_end > a.peh_time)
    for i in np.flatnonzero(late):
        faults.append((int(i), ErrorCodes.NC_AXIS_PEH_TIMEOUT))
        a.since_end[i] = -1.0
    return faults
