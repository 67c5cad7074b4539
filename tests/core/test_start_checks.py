"""Every start check returns its TwinCAT code and changes nothing."""
import pytest

from nc_schema import ControlDWord, ErrorCodes as E
from znc_testing.nc_core import cmd, make_core, power, powered, run_until, snapshot


@pytest.fixture
def moving_core():
    core = make_core(AxisEnMinSoftPosLimit=True, AxisMinSoftPosLimit=-100.0,
                     AxisEnMaxSoftPosLimit=True, AxisMaxSoftPosLimit=100.0, AxisVeloMax=500.0)
    power(core)
    core.step()
    cmd(core, "MoveAbsolute", Position=50.0, Velocity=20.0)
    for _ in range(100):
        core.step()
    return core


@pytest.mark.parametrize("name,args,code", [
    ("MoveAbsolute", dict(Position=10.0, Velocity=0.0), E.NC_VELOCITY_NOT_ALLOWED),
    ("MoveAbsolute", dict(Position=10.0, Velocity=-5.0), E.NC_VELOCITY_NOT_ALLOWED),
    ("MoveAbsolute", dict(Position=10.0, Velocity=501.0), E.NC_VELOCITY_NOT_ALLOWED),
    ("MoveAbsolute", dict(Position=101.0, Velocity=10.0), E.NC_TARGET_POSITION_NOT_ALLOWED),
    ("MoveAbsolute", dict(Position=-100.5, Velocity=10.0), E.NC_TARGET_POSITION_NOT_ALLOWED),
    ("MoveAbsolute", dict(Position=1e300, Velocity=10.0), E.NC_TARGET_POSITION_NOT_ALLOWED),
    ("MoveRelative", dict(Distance=120.0, Velocity=10.0), E.NC_TARGET_POSITION_NOT_ALLOWED),
    ("MoveAbsolute", dict(Position=10.0, Velocity=10.0, Acceleration=-1.0), E.NC_ACCELERATION_NOT_ALLOWED),
    ("MoveAbsolute", dict(Position=10.0, Velocity=10.0, Deceleration=-1.0), E.NC_DECELERATION_NOT_ALLOWED),
    ("MoveAbsolute", dict(Position=10.0, Velocity=10.0, Jerk=-1.0), E.NC_JERK_NOT_ALLOWED),
    ("MoveAbsolute", dict(Position=10.0, Velocity=10.0, BufferMode=7), E.MC_BUFFERMODE_NOT_SUPPORTED),
    ("MoveVelocity", dict(Velocity=10.0, Direction=2), E.MC_COMMAND_NOT_PERMITTED),
    ("MoveVelocity", dict(Velocity=10.0, Direction=99), E.MC_COMMAND_NOT_PERMITTED),
    ("MoveVelocity", dict(Velocity=1000.0, Direction=1), E.NC_VELOCITY_NOT_ALLOWED),
    ("MoveModulo", dict(Position=400.0, Velocity=10.0, Direction=2), E.NC_MODULO_TARGET_INVALID),
    ("MoveModulo", dict(Position=-1.0, Velocity=10.0, Direction=1), E.NC_MODULO_TARGET_INVALID),
    ("MoveModulo", dict(Position=10.0, Velocity=10.0, Direction=7), E.MC_INVALID_MODE),
    ("MoveAbsolute", dict(Position=10.0, Velocity=10.0, Jerk=1e-9), E.NC_JERK_NOT_ALLOWED),
    ("MoveAbsolute", dict(Position=10.0, Velocity=10.0, Jerk=1e300), E.NC_JERK_NOT_ALLOWED),
    ("MoveAbsolute", dict(Position=10.0, Velocity=1e-12), E.NC_VELOCITY_NOT_ALLOWED),
    ("Stop", dict(Deceleration=1e11, Jerk=1e13), E.NC_DECELERATION_NOT_ALLOWED),
    ("SetOverride", dict(Override=101.0), E.MC_PARAMETER_NOT_CORRECT),
    ("SetOverride", dict(Override=-0.1), E.MC_PARAMETER_NOT_CORRECT),
    ("ReadParameter", dict(ParameterNumber=4711), E.ADSERR_DEVICE_INVALIDOFFSET),
    ("WriteParameter", dict(ParameterNumber=1003, Value=-1.0), E.ADSERR_DEVICE_INVALIDPARM),
    ("WriteParameter", dict(ParameterNumber=1015, Value=0.5), E.ADSERR_DEVICE_INVALIDPARM),
    ("WriteParameter", dict(ParameterNumber=1003, Value=True), E.ADSERR_DEVICE_INVALIDPARM),
    ("WriteParameter", dict(ParameterNumber=2000, Value=1.0), E.ADSERR_DEVICE_INVALIDACCESS),
    ("WriteParameter", dict(ParameterNumber=1016, Value=200.0), E.ADSERR_DEVICE_INVALIDPARM),  # min >= max
])
def test_rejected_command_has_code_and_changes_nothing(moving_core, name, args, code):
    core = moving_core
    before = snapshot(core)
    rep = cmd(core, name, **args)
    assert rep["error"] == code, rep
    assert rep["text"] and "CmdNo" not in rep
    assert snapshot(core) == before
    # the running job goes on to its target
    run_until(core, lambda: core.nctoplc[0]["SetPos"] == 50.0, 20_000)
    assert core.nctoplc[0]["CmdNo"] == 1


def test_unknown_axis():
    core = make_core()
    assert cmd(core, "Reset", axis=9)["error"] == E.NC_AXIS_ID_NOT_ALLOWED


def test_no_enable_and_no_feed_enable():
    core = make_core()
    core.step()
    assert cmd(core, "MoveAbsolute", Position=1.0, Velocity=1.0)["error"] == E.NC_NO_ENABLE
    power(core, ctrl=int(ControlDWord.Enable | ControlDWord.FeedEnableMinus))
    core.step()
    assert cmd(core, "MoveAbsolute", Position=1.0, Velocity=1.0)["error"] == E.NC_NO_ENABLE
    assert cmd(core, "MoveVelocity", Velocity=1.0, Direction=1)["error"] == E.NC_NO_ENABLE
    assert cmd(core, "MoveAbsolute", Position=-1.0, Velocity=1.0)["error"] == 0


def test_error_state_and_locked_state():
    core = powered()
    core.fault(0, E.NC_POSITION_LAG)
    core.step()
    rep = cmd(core, "MoveAbsolute", Position=1.0, Velocity=1.0)
    assert rep["error"] == E.MC_AXIS_CANNOT_BE_STARTED and "0x4550" in rep["text"]
    assert cmd(core, "Reset")["error"] == 0
    core.step()
    assert cmd(core, "Stop")["error"] == 0
    core.step()
    assert cmd(core, "MoveVelocity", Velocity=1.0)["error"] == E.NC_AXIS_LOCKED_BY_STOP
    assert cmd(core, "Halt")["error"] == E.NC_AXIS_LOCKED_BY_STOP


def test_overshoot_of_soft_limit_is_refused():
    """A weaker deceleration while running towards a limit would overshoot it: refused (ruckig ignores limits)."""
    core = powered(AxisEnMaxSoftPosLimit=True, AxisMaxSoftPosLimit=100.0, AxisAcc=500.0, AxisDec=500.0)
    cmd(core, "MoveAbsolute", Position=99.0, Velocity=400.0)
    run_until(core, lambda: core.nctoplc[0]["SetPos"] > 45.0)
    assert core.nctoplc[0]["SetVelo"] > 150.0
    rep = cmd(core, "MoveAbsolute", Position=0.0, Velocity=400.0, Deceleration=50.0)
    assert rep["error"] == E.NC_TARGET_POSITION_NOT_ALLOWED and "overshoot" in rep["text"]
    rep = cmd(core, "MoveAbsolute", Position=0.0, Velocity=400.0)
    assert rep["error"] == 0  # with the axis deceleration the reversal stays inside
    hi = 0.0
    for _ in range(3000):
        core.step()
        hi = max(hi, core.nctoplc[0]["SetPos"])
    assert hi <= 100.0 and core.nctoplc[0]["SetPos"] == 0.0


def test_write_parameter_takes_effect_and_reads_back():
    core = make_core()
    assert cmd(core, "WriteParameter", ParameterNumber=1003, Value=123.0)["error"] == 0
    assert cmd(core, "ReadParameter", ParameterNumber=1003)["Value"] == 123.0
    assert cmd(core, "ReadParameter", ParameterNumber=9)["Value"] == 123.0  # PLCopen MaxVelocityAppl
    assert cmd(core, "WriteParameter", ParameterNumber=1015, Value=1.0)["error"] == 0
    assert cmd(core, "ReadParameter", ParameterNumber=1015)["Value"] is True
    power(core)
    core.step()
    assert cmd(core, "MoveAbsolute", Position=1.0, Velocity=124.0)["error"] == E.NC_VELOCITY_NOT_ALLOWED
