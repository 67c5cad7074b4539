"""Second review's findings: the NC cycle never raises, and an axis in error never keeps moving.

* a legal tiny override on a fast axis whose job cannot be re-planned at it: the job waits at rest
  (as at override 0) instead of step() raising;
* axis dynamics the planner cannot take are refused as parameters (0x70B), and the NC's own stop
  ramp clamps what it uses, so a fault always brakes.
"""
from __future__ import annotations

import math

import pytest

from nc_schema import ErrorCodes, MC_AxisPara
from znc_testing.nc_core import cmd, power, powered, run_until


@pytest.mark.parametrize("override", [1, 2, 5, 10, 20, 100])
def test_tiny_override_on_a_fast_axis_never_raises(override: int) -> None:
    core = powered(1, AxisVeloMax=1000.0, AxisAcc=5000.0, AxisDec=5000.0, AxisJerk=50000.0)
    cmd(core, "MoveVelocity", Velocity=600.0, Direction=1)
    run_until(core, lambda: math.isclose(float(core.nctoplc[0]["SetVelo"]), 600.0), 5000)
    assert cmd(core, "MoveRelative", Distance=30.0, Velocity=1.0)["error"] == 0
    power(core, 0, override=override)
    for _ in range(3000):
        core.step()  # must not raise
    r = core.nctoplc[0]
    assert int(r["ErrorCode"]) == 0
    power(core, 0, override=1_000_000)
    run_until(core, lambda: int(core.nctoplc[0]["CmdState"]) == 2, 200_000)


@pytest.mark.parametrize("number,value", [(int(MC_AxisPara.MaxJerk), 1e13), (int(MC_AxisPara.MaxDecelerationAppl), 1e-7),
                                          (int(MC_AxisPara.AxisJerk), 5e-324), (int(MC_AxisPara.AxisAcc), 1e11)])
def test_unplannable_axis_dynamics_are_refused(number: int, value: float) -> None:
    core = powered(1)
    assert cmd(core, "WriteParameter", ParameterNumber=number, Value=value)["error"] == ErrorCodes.ADSERR_DEVICE_INVALIDPARM


def test_a_fault_always_brakes() -> None:
    core = powered(1)
    cmd(core, "MoveVelocity", Velocity=100.0, Direction=1)
    run_until(core, lambda: math.isclose(float(core.nctoplc[0]["SetVelo"]), 100.0), 5000)
    power(core, 0, ctrl=1 | 4)  # feed enable plus withdrawn while moving positive
    run_until(core, lambda: int(core.nctoplc[0]["ErrorCode"]) == ErrorCodes.NC_AXIS_FEED_ENABLE_PLUS, 100)
    run_until(core, lambda: float(core.nctoplc[0]["SetVelo"]) == 0.0, 5000)
