"""The NC's parameters by the table (schema/params.json): every MC_AxisPara number readable, writes where
allowed and when allowed, never breaking a running motion; ReadParameterSet, ReadAxisComponents,
SetExternalError and the simulated stepper (SimStepper, SimStall, SimTerminalError)."""
from __future__ import annotations

import pytest

from nc_schema import PARAMETERS, E_NcDriveType, E_NcEncoderType, ErrorCodes as E, OpModeDWord, StateDWord
from nc_schema import encode_parameter_set
from nc_server.core.params import AxisParams, param_number
from znc_testing.nc_core import cmd, make_core, power, powered, run_until, snapshot


def _valid_value(e, current):
    """A value different from ``current`` inside the entry's range (a bool: its negation)."""
    if e.is_bool:
        return not current
    if e.name == "AxisEncoderEncoderMask":  # 2^k - 1: one bit less
        return float((int(current) + 1) // 2 - 1)
    v = current * 1.5 if current else 1.0
    if e.max is not None and v > e.max:
        v = current / 2.0
    return float(v)


def test_every_number_is_readable_with_its_type():
    core = powered(AxisEnMinSoftPosLimit=True)
    for e in PARAMETERS:
        r = cmd(core, "ReadParameter", ParameterNumber=e.number)
        assert r["error"] == 0, (e.name, r)
        assert isinstance(r["Value"], bool) == e.is_bool, (e.name, r["Value"])
    assert cmd(core, "ReadParameter", ParameterNumber=1000)["Value"] == 1.0
    assert cmd(core, "ReadParameter", ParameterNumber=1015)["Value"] is True
    assert cmd(core, "ReadParameter", ParameterNumber=1043)["Value"] == 4294967295.0  # encoder mask: 32 bits
    assert cmd(core, "ReadParameter", ParameterNumber=1039)["Value"] == 4.0  # override type


def test_every_writable_number_round_trips_and_its_aliases_follow():
    core = make_core()  # disabled: the 'disabled' parameters may be written too
    for e in PARAMETERS:
        if not e.writable:
            continue
        before = cmd(core, "ReadParameter", ParameterNumber=e.number)["Value"]
        value = _valid_value(e, before)
        r = cmd(core, "WriteParameter", ParameterNumber=e.number, Value=value)
        if e.store in ("AxisMinSoftPosLimit", "AxisMaxSoftPosLimit"):
            assert r["error"] == 0, r  # (the limits are disabled here: no ordering rule)
        assert r["error"] == 0, (e.name, r)
        for other in PARAMETERS.stores()[e.store]:
            assert cmd(core, "ReadParameter", ParameterNumber=other.number)["Value"] == value, (e.name, other.name)
        assert getattr(core.params[0], e.store) == value


@pytest.mark.parametrize("number, value, code", [
    (4711, 1.0, E.ADSERR_DEVICE_INVALIDOFFSET),
    (17, 1.0, E.ADSERR_DEVICE_INVALIDOFFSET),
    (1, 1.0, E.ADSERR_DEVICE_INVALIDACCESS),          # CommandedPosition: status
    (1000, 7.0, E.ADSERR_DEVICE_INVALIDACCESS),       # AxisId
    (2001, 0.0, E.ADSERR_DEVICE_INVALIDACCESS),
    (1038, 100.0, E.ADSERR_DEVICE_INVALIDACCESS),     # AxisRefVeloOnRefOutput: status
    (1039, 5.0, E.NC_AXIS_OVERRIDE_TYPE_NOT_ALLOWED),  # override type: 1..4
    (1003, 0.0, E.ADSERR_DEVICE_INVALIDPARM),         # below the table's min
    (1003, 2e9, E.ADSERR_DEVICE_INVALIDPARM),         # above its max
    (1006, 1e13, E.ADSERR_DEVICE_INVALIDPARM),
    (1016, 2e9, E.ADSERR_DEVICE_INVALIDPARM),
    (1021, -1.0, E.ADSERR_DEVICE_INVALIDPARM),
    (1003, True, E.ADSERR_DEVICE_INVALIDPARM),        # a BOOL for an LREAL
    (1019, 0.5, E.ADSERR_DEVICE_INVALIDPARM),         # neither 0 nor 1 for a BOOL
])
def test_refused_writes_change_nothing(number, value, code):
    core = powered()
    before = snapshot(core)
    r = cmd(core, "WriteParameter", ParameterNumber=number, Value=value)
    assert r["error"] == code, r
    assert snapshot(core) == before


def test_fixed_value_written_back_is_accepted():
    core = powered()
    before = snapshot(core)
    for number, value in ((1035, False), (1036, 0.0), (1039, 4.0), (1033, 0.0)):
        assert cmd(core, "WriteParameter", ParameterNumber=number, Value=value)["error"] == 0
    assert snapshot(core) == before


def test_a_write_takes_effect_at_the_next_cycle_boundary():
    core = powered()
    bit = int(OpModeDWord.OpModePosAreaMonitoring)
    assert int(core.nctoplc[0]["OpModeDWord"]) & bit
    r = cmd(core, "WriteParameter", ParameterNumber=1022, Value=False)
    assert r["error"] == 0 and r["cycle"] == core.cycle + 1
    assert int(core.nctoplc[0]["OpModeDWord"]) & bit, "the cycle already output is not rewritten"
    core.step()
    assert core.cycle == r["cycle"] and not int(core.nctoplc[0]["OpModeDWord"]) & bit


@pytest.fixture
def moving():
    core = powered(AxisEnMinSoftPosLimit=True, AxisMinSoftPosLimit=-100.0, AxisEnMaxSoftPosLimit=True,
                   AxisMaxSoftPosLimit=200.0, AxisVeloMax=500.0, AxisModuloToleranceWindow=0.0)
    assert cmd(core, "MoveAbsolute", Position=100.0, Velocity=50.0)["error"] == 0
    for _ in range(300):
        core.step()
    assert abs(float(core.nctoplc[0]["SetVelo"])) > 0
    return core


@pytest.mark.parametrize("number, value, code", [
    (1044, 100.0, E.NC_GROUP_NOT_READY),              # modulo factor: at standstill only
    (1003, 40.0, E.NC_VELOCITY_NOT_ALLOWED),          # below the running 50 u/s
    (9, 40.0, E.NC_VELOCITY_NOT_ALLOWED),             # (its PLCopen number)
    (1018, 90.0, E.NC_TARGET_POSITION_NOT_ALLOWED),   # the target 100 would lie beyond
    (1016, 50.0, E.NC_TARGET_POSITION_NOT_ALLOWED),   # the set position (about 14) would lie below
    (1040, 2.0, E.MC_AXIS_IS_ENABLED),                # encoder scaling: only while disabled
    (1041, 1.0, E.MC_AXIS_IS_ENABLED),
])
def test_writes_that_would_break_the_running_motion_are_refused(moving, number, value, code):
    before = [vars(p) for p in moving.params]
    r = cmd(moving, "WriteParameter", ParameterNumber=number, Value=value)
    assert r["error"] == code, r
    assert [vars(p) for p in moving.params] == before
    run_until(moving, lambda: int(moving.nctoplc[0]["StateDWord"]) & int(StateDWord.InTargetPosition) != 0)
    assert abs(float(moving.nctoplc[0]["ActPos"]) - 100.0) < 0.05 and not moving.nctoplc[0]["ErrorCode"]


def test_harmless_writes_while_moving_are_taken(moving):
    for number, value in ((1003, 60.0), (1004, 4000.0), (1018, 150.0), (1001, 5.0), (1025, 0.05), (1019, False)):
        assert cmd(moving, "WriteParameter", ParameterNumber=number, Value=value)["error"] == 0, number
    run_until(moving, lambda: int(moving.nctoplc[0]["StateDWord"]) & int(StateDWord.InTargetPosition) != 0)
    assert abs(float(moving.nctoplc[0]["ActPos"]) - 100.0) < 0.06 and not moving.nctoplc[0]["ErrorCode"]
    # at rest the refused ones go through
    for number, value in ((1044, 100.0), (1003, 40.0), (1018, 90.0)):
        assert cmd(moving, "WriteParameter", ParameterNumber=number, Value=value)["error"] == 0, number


def test_disabled_only_parameters_once_disabled():
    core = powered()
    assert cmd(core, "WriteParameter", ParameterNumber=1040, Value=2.0)["error"] == E.MC_AXIS_IS_ENABLED
    power(core, ctrl=0)
    core.step()
    assert cmd(core, "WriteParameter", ParameterNumber=1040, Value=2.0)["error"] == 0
    assert cmd(core, "ReadParameter", ParameterNumber=1040)["Value"] == 2.0


def test_read_parameter_set():
    core = powered(AxisVeloMax=321.0, AxisEnMinSoftPosLimit=True, AxisMinSoftPosLimit=-5.0, SimTimeConstant=0.004)
    r = cmd(core, "ReadParameterSet")
    assert r["error"] == 0
    ps = r["Value"]
    assert ps["AxisId"] == 1 and ps["sAxisName"] == "A1" and ps["fAxisCycleTime"] == 0.001
    assert ps["fVeloMaximum"] == 321.0 and ps["bEncEnableSoftEndMinControl"] == 1 and ps["fEncSoftEndMin"] == -5.0
    assert ps["nEncType"] == E_NcEncoderType.NcEncoderType_Simulation and ps["nDriveType"] == 0
    assert ps["fCtrlPosKp"] == pytest.approx(250.0) and ps["nEncMaxIncrement"] == 0xFFFFFFFF
    assert len(encode_parameter_set(ps)) == 1024
    # it follows writes
    assert cmd(core, "WriteParameter", ParameterNumber=1003, Value=123.0)["error"] == 0
    assert cmd(core, "ReadParameterSet")["Value"]["fVeloMaximum"] == 123.0


def test_read_axis_components():
    core = make_core(n=3)
    r = cmd(core, "ReadAxisComponents", axis=3)
    assert r["Value"] == {"EncoderIDs": [3] + [0] * 8, "ControllerIDs": [3] + [0] * 8, "DriveIDs": [3] + [0] * 8}
    assert cmd(core, "ReadAxisComponents", axis=9)["error"] == E.NC_AXIS_ID_NOT_ALLOWED


def test_set_external_error():
    core = powered(Homed=True)
    assert cmd(core, "SetExternalError", ErrorCode=0)["error"] == E.MC_PARAMETER_NOT_CORRECT
    assert cmd(core, "SetExternalError", ErrorCode=0x4636)["error"] == 0
    core.step()
    r = core.nctoplc[0]
    assert r["ErrorCode"] == 0x4636 and int(r["StateDWord"]) & int(StateDWord.Homed)
    assert cmd(core, "SetExternalError", ErrorCode=0x4630, Unreference=True)["error"] == 0
    core.step()
    assert r["ErrorCode"] == 0x4636, "the first error sticks"
    assert not int(core.nctoplc[0]["StateDWord"]) & int(StateDWord.Homed)
    assert cmd(core, "Reset")["error"] == 0
    core.step()
    assert core.nctoplc[0]["ErrorCode"] == 0


def _stepper_core(**kw):
    p = dict(SimStepper=True, AxisEnPositionLagMonitoring=False, SimTimeConstant=0.01)
    p.update(kw)
    return _two(p)


def _two(p):
    from nc_server.core import AxisConfig, NcCore
    core = NcCore([AxisConfig(1, "S", AxisParams(**p)), AxisConfig(2, "Servo")], 0.001)
    power(core, 0)
    power(core, 1)
    core.step()
    return core


def _ds(core, i=0):
    return int(core.ncjobs["DriveStatus"][i])


def test_sim_stepper_terminal_status_and_stall():
    core = _stepper_core()
    core.step()
    assert _ds(core) == (1 << 31) | 0x01 | 0x10  # present, Ready, Idle
    assert _ds(core, 1) == 0  # a servo axis has no terminal
    ps = cmd(core, "ReadParameterSet")["Value"]
    assert ps["nEncType"] == E_NcEncoderType.NcEncoderType_KL2531_Stepper
    assert ps["nDriveType"] == E_NcDriveType.NcDriveType_KL2531_Stepper
    assert cmd(core, "SimStall", axis=2, Stall=True)["error"] == E.NC_FUNCTION_NOT_SUPPORTED
    # a motor at rest cannot stall: latched in at once
    assert cmd(core, "SimStall", Stall=True)["error"] == 0
    core.step()
    assert (_ds(core) >> 1) & 7 == 0
    assert cmd(core, "MoveVelocity", Velocity=20.0, Direction=1)["error"] == 0
    for _ in range(200):
        core.step()
    assert cmd(core, "SimStall", Stall=True)["error"] == 0
    core.step()
    held = float(core.nctoplc[0]["ActPos"])
    for _ in range(100):
        core.step()
    r = core.nctoplc[0]
    assert float(r["ActPos"]) == held and float(r["PosDiff"]) > 1.5  # the set-point runs away
    assert (_ds(core) >> 1) & 7 == 7 and not _ds(core) & 0x10  # LoadAngle 7, not idle
    assert cmd(core, "Halt")["error"] == 0
    run_until(core, lambda: abs(float(core.nctoplc[0]["SetVelo"])) == 0.0)
    run_until(core, lambda: abs(float(core.nctoplc[0]["PosDiff"])) < 1e-3)  # latched in, caught up
    assert (_ds(core) >> 1) & 7 == 0 and not core.nctoplc[0]["ErrorCode"]


def test_sim_terminal_error_bits():
    core = _stepper_core()
    assert cmd(core, "SimTerminalError", StatusWord=70000)["error"] == E.MC_PARAMETER_NOT_CORRECT
    assert cmd(core, "SimTerminalError", axis=2, StatusWord=8)["error"] == E.NC_FUNCTION_NOT_SUPPORTED
    assert cmd(core, "SimTerminalError", StatusWord=1 << 3)["error"] == 0
    core.step()
    ds = _ds(core)
    assert (ds >> 8) & 0xFFFF == 8 and ds & 0x40 and not ds & 0x01  # Error, not Ready
    assert cmd(core, "SimTerminalError", StatusWord=0)["error"] == 0
    core.step()
    assert _ds(core) & 0x41 == 0x01


def test_acceleration_limits_below_the_set_acceleration_are_refused():
    core = powered()
    assert cmd(core, "MoveVelocity", Velocity=100.0, Direction=1)["error"] == 0
    for _ in range(5):  # still accelerating (jerk-limited): |SetAcc| = 250 u/s^2 after 5 ms
        core.step()
    acc = abs(float(core.nctoplc[0]["SetAcc"]))
    assert 100.0 < acc < 5000.0
    assert cmd(core, "WriteParameter", ParameterNumber=1004, Value=100.0)["error"] == 0  # AxisDec still 5000
    r = cmd(core, "WriteParameter", ParameterNumber=1005, Value=100.0)
    assert r["error"] == E.NC_ACCELERATION_NOT_ALLOWED, r
    assert core.params[0].AxisDec == 5000.0


def test_param_number_prefers_the_beckhoff_number():
    assert param_number("AxisVeloMax") == 1003
    assert param_number("AxisMaxSoftPosLimit") == 1018
    assert param_number("AxisMaxVelocity") == 1007  # (its own writable entry)
    assert param_number("SimTimeConstant") is None and param_number("AxisId") is None
