"""The parameters that act (issue 17) through the PLC blocks against a real NcCore (Rig): the position
correction a PLC writes into PLCTONC shows in NCTOPLC, MC_WriteParameter gets TwinCAT's own code for a
bad value, and a dead time written with MC_WriteParameter keeps PosDiff at the drive's lag."""
from __future__ import annotations

import pytest

from nc_schema import ErrorCodes as E
from plc_client import MC_MoveVelocity, MC_WriteBoolParameter, MC_WriteParameter
from znc_testing.plc_rig import Rig, powered


def test_the_plcs_position_correction_reaches_actpos(rig: Rig) -> None:
    ax, _, calls = powered(rig)
    wb = MC_WriteBoolParameter()
    calls["body"] = lambda p: wb(Axis=ax, Enable=True, ParameterNumber=1046, Value=True)
    rig.run_until(lambda: wb.Done, 10)
    assert not wb.Error and rig.core.params[0].AxisEnActPosCorrection

    def body(p: object) -> None:
        ax.PlcToNc.PositionCorrection = 1.25
    calls["body"] = body
    rig.run(20)
    r = ax.NcToPlc
    assert r["ActPos"] - r["ActPosWithoutPosCorrection"] == pytest.approx(1.25)
    assert r["ActPos"] == pytest.approx(r["SetPos"], abs=1e-6)  # the drive took the correction up


@pytest.mark.parametrize("number, value, code", [
    (1032, 0.5, E.NC_AXIS_DEAD_TIME_NOT_ALLOWED), (1047, -1.0, E.NC_ENCODER_POS_CORRECTION_FILTER_TIME_NOT_ALLOWED),
    (1031, 0.0, E.NC_AXIS_MOTION_MONITORING_TIME_NOT_ALLOWED), (1030, -0.5, E.NC_AXIS_MOTION_MONITORING_WINDOW_NOT_ALLOWED),
])
def test_write_parameter_gets_the_twincat_code(rig: Rig, number: int, value: float, code: int) -> None:
    ax, _, calls = powered(rig)
    wp = MC_WriteParameter()
    calls["body"] = lambda p: wp(Axis=ax, Enable=True, ParameterNumber=number, Value=value)
    rig.run_until(lambda: wp.Error or wp.Done, 10)
    assert wp.Error and wp.ErrorID == code
    assert rig.core.read_parameter(0, number) != value


def test_a_dead_time_written_by_the_plc(rig: Rig) -> None:
    ax, _, calls = powered(rig)
    wp, mv = MC_WriteParameter(), MC_MoveVelocity()
    calls["body"] = lambda p: wp(Axis=ax, Enable=True, ParameterNumber=1032, Value=0.02)
    rig.run_until(lambda: wp.Done, 10)
    assert not wp.Error and rig.core.corrections.delay[0] == 20
    calls["body"] = lambda p: mv(Axis=ax, Execute=True, Velocity=200.0, Direction=1)
    rig.run_until(lambda: mv.InVelocity, 100)
    rig.run(5)
    r = ax.NcToPlc
    assert r["SetPos"] - r["ActPos"] > 200.0 * 0.02 * 0.9  # the actual position is 20 ms behind ...
    assert abs(float(r["PosDiff"])) < 0.2  # ... which PosDiff does not show as a lag
    assert r["ErrorCode"] == 0
