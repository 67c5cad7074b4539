"""MC_OverrideFilter (TcMC 4.19): thresholds, steps, the recovery time (on the task's virtual clock: 10 ms
cycles), 0 % / 100 % at once, and the MC_ERROR_PARAMETER_NOT_CORRECT cases."""
from __future__ import annotations

import datetime

import pytest

from nc_schema import ErrorCodes as E
from plc_client import MC_OverrideFilter
from znc_testing.plc_rig import ScriptNc


def run(nc: ScriptNc, fb: MC_OverrideFilter, st: dict, n: int = 1) -> None:
    if not nc.calls:
        nc.calls.append(lambda: fb(**st))
    nc.cycle_once(n)


@pytest.mark.parametrize("raw, lo, hi, steps, value", [
    (0, 0, 32767, 200, 0),
    (32767, 0, 32767, 200, 1_000_000),
    (-500, 0, 32767, 200, 0),                 # below the lower threshold: 0 %
    (40000, 0, 32767, 200, 1_000_000),         # above the upper one: 100 %
    (16384, 0, 32767, 200, 500_000),           # half way: step 100 of 200
    (16384 + 82, 0, 32767, 200, 505_000),      # the nearest 0.5 % step (a step is 163.8 digits)
    (16384 + 81, 0, 32767, 200, 500_000),
    (150, 100, 200, 10, 500_000),              # thresholds inside the range
    (125, 100, 200, 4, 250_000),
    (2, 0, 3, 3, 666_667),                     # 2/3 rounded to the counts
])
def test_mapping(raw, lo, hi, steps, value) -> None:
    fb = MC_OverrideFilter()
    fb(OverrideValueRaw=raw, LowerOverrideThreshold=lo, UpperOverrideThreshold=hi, OverrideSteps=steps)
    assert not fb.Error and fb.ErrorId == 0 and fb.ErrorID == 0
    assert fb.OverrideValueFiltered == value and fb.OverridePercentFiltered == value / 10000.0


def test_recovery_time_and_immediate_limits(nc: ScriptNc) -> None:
    fb = MC_OverrideFilter()
    st = {"OverrideValueRaw": 16384}
    run(nc, fb, st)
    assert fb.OverrideValueFiltered == 500_000  # the first value at once
    st["OverrideValueRaw"] = 19661  # 60 %
    seen = []
    nc.calls.append(lambda: seen.append(fb.OverrideValueFiltered))
    nc.cycle_once(20)
    first = seen.index(600_000)
    assert 14 <= first <= 15, seen  # after 150 ms (15 cycles of 10 ms, counted from the previous change)
    st["OverrideValueRaw"] = 0  # 0 %: at once
    nc.cycle_once()
    assert fb.OverrideValueFiltered == 0
    st["OverrideValueRaw"] = 32767  # 100 %: at once, even right after a change
    nc.cycle_once()
    assert fb.OverrideValueFiltered == 1_000_000 and fb.OverridePercentFiltered == 100.0
    st["OverrideValueRaw"] = 6553  # 20 %: waits again
    nc.cycle_once()
    assert fb.OverrideValueFiltered == 1_000_000


def test_recovery_time_as_timedelta_and_zero(nc: ScriptNc) -> None:
    fb = MC_OverrideFilter()
    st = {"OverrideValueRaw": 16384, "OverrideRecoveryTime": datetime.timedelta(0)}
    run(nc, fb, st)
    st["OverrideValueRaw"] = 19661
    nc.cycle_once()
    assert fb.OverrideValueFiltered == 600_000


@pytest.mark.parametrize("inputs", [
    {"OverrideSteps": 1}, {"OverrideSteps": 0}, {"OverrideSteps": -5},
    {"LowerOverrideThreshold": 100, "UpperOverrideThreshold": 100},
    {"LowerOverrideThreshold": 200, "UpperOverrideThreshold": 100},
    {"OverrideValueRaw": 1.5}, {"OverrideSteps": True}, {"OverrideRecoveryTime": -0.1},
    {"OverrideRecoveryTime": "150ms"},
])
def test_parameter_not_correct_keeps_the_last_value(inputs) -> None:
    fb = MC_OverrideFilter()
    fb(OverrideValueRaw=8192, OverrideRecoveryTime=0.0)
    assert fb.OverrideValueFiltered == 250_000
    fb(**{"OverrideValueRaw": 32767, **inputs})
    assert fb.Error and fb.ErrorId == E.MC_PARAMETER_NOT_CORRECT == 0x4B06 and fb.ErrorID == 0x4B06
    assert fb.OverrideValueFiltered == 250_000, "the outputs keep the last valid value"
    fb(OverrideValueRaw=32767, OverrideSteps=200, LowerOverrideThreshold=0, UpperOverrideThreshold=32767,
       OverrideRecoveryTime=0.0)
    assert not fb.Error and fb.ErrorId == 0 and fb.OverrideValueFiltered == 1_000_000


def test_no_axis_and_unknown_input() -> None:
    fb = MC_OverrideFilter()
    assert fb(OverrideValueRaw=0) is fb
    with pytest.raises(TypeError):
        fb(Override=5)
