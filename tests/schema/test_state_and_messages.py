"""The shared PLCopen state mapping, CmdNo arithmetic, request parsing."""
import math

import msgpack
import numpy as np
import pytest

import nc_schema as s
from nc_schema import MC_AxisStates as M, StateDWord as B

CLC = int(B.ControlLoopClosed)
NM = int(B.NotMoving)


@pytest.mark.parametrize("bits,couple,expected", [
    (0, 0, M.MC_AXISSTATE_DISABLED),
    (int(B.Error), 0, M.MC_AXISSTATE_ERRORSTOP),
    (int(B.Error) | CLC | int(B.HasJob), 0, M.MC_AXISSTATE_ERRORSTOP),
    (CLC | NM, 0, M.MC_AXISSTATE_STANDSTILL),
    (CLC, 0, M.MC_AXISSTATE_DISCRETEMOTION),  # moving without a job (a superposition on a standing axis)
    (CLC | int(B.HasBeenStopped), 0, M.MC_AXISSTATE_STOPPING),  # moving on an NC ramp without a CmdNo
    (CLC | int(B.MotionCommandsLocked), 0, M.MC_AXISSTATE_STOPPING),
    (CLC | int(B.HasBeenStopped) | int(B.HasJob), 0, M.MC_AXISSTATE_STOPPING),
    (CLC | NM | int(B.HasBeenStopped), 0, M.MC_AXISSTATE_STANDSTILL),
    (CLC | int(B.HomingBusy) | int(B.HasJob), 0, M.MC_AXISSTATE_HOMING),
    (CLC | int(B.HasJob), 3, M.MC_AXISSTATE_SYNCHRONIZEDMOTION),
    (CLC | int(B.HasJob) | int(B.ContinuousMotion), 0, M.MC_AXISSTATE_CONTINOUSMOTION),
    (CLC | int(B.HasJob), 0, M.MC_AXISSTATE_DISCRETEMOTION),
])
def test_motion_state_mapping_scalar_and_vector_agree(bits, couple, expected):
    assert s.motion_state(bits, couple) == expected
    assert s.motion_state_array(np.array([bits], np.uint32), np.array([couple]))[0] == int(expected)


def test_cmdno_serial_arithmetic():
    assert s.cmdno_newer(2, 1) and not s.cmdno_newer(1, 2) and not s.cmdno_newer(5, 5)
    assert s.cmdno_newer(1, 65535) and s.cmdno_newer(3, 65000)
    assert s.next_cmdno(65535) == 1 and s.next_cmdno(0) == 1


def test_parse_request_fills_defaults():
    r = s.parse_request(s.make_request("MoveVelocity", 7, "plc-1", Velocity=5))
    assert r == {"id": 7, "client": "plc-1", "cmd": "MoveVelocity", "Velocity": 5.0, "Acceleration": 0.0,
                 "Deceleration": 0.0, "Jerk": 0.0, "Direction": 1, "BufferMode": 0}


@pytest.mark.parametrize("payload,code", [
    (b"\xc1garbage", 0x706),
    (msgpack.packb([1, 2]), 0x706),
    (msgpack.packb({"cmd": "Reset"}), 0x706),
    (msgpack.packb({"id": True, "cmd": "Reset"}), 0x706),
    (msgpack.packb({"id": 1, "cmd": "Explode"}), 0x701),
    (msgpack.packb({"id": 1, "cmd": 5}), 0x706),
    (msgpack.packb({"id": 1, "cmd": "MoveAbsolute", "Velocity": 1.0}), 0x706),
    (msgpack.packb({"id": 1, "cmd": "MoveAbsolute", "Position": math.nan, "Velocity": 1.0}), 0x706),
    (msgpack.packb({"id": 1, "cmd": "MoveAbsolute", "Position": "1", "Velocity": 1.0}), 0x706),
    (msgpack.packb({"id": 1, "cmd": "MoveAbsolute", "Position": 1.0, "Velocity": math.inf}), 0x706),
    (msgpack.packb({"id": 1, "cmd": "MoveVelocity", "Velocity": 1.0, "Direction": 1.5}), 0x706),
    (msgpack.packb({"id": 1, "cmd": "Reset", "Bogus": 1}), 0x706),
    (msgpack.packb({"id": 1, "cmd": "Reset", "client": "bad client!"}), 0x706),
    (msgpack.packb({"id": "x" * 200, "cmd": "Reset"}), 0x706),
])
def test_parse_request_rejects_bad_input_with_codes(payload, code):
    with pytest.raises(s.NcError) as ei:
        s.parse_request(payload)
    assert ei.value.code == code and str(ei.value)


def test_keys():
    k = s.Keys("nc1")
    assert k.axis_nctoplc(3) == "nc/nc1/axis/3/nctoplc" and k.frame == "nc/nc1/frame" and k.claims == "nc/nc1/claims"
    assert k.axis_cmd(12, "op", "plc1") == "nc/nc1/axis/12/cmd/op/plc1" and k.cmd("read", "cli") == "nc/nc1/cmd/read/cli"
    assert k.command_key("WriteParameter", 2, "e") == "nc/nc1/axis/2/cmd/eng/e"
    assert k.command_key("MoveAbsolute", 2, "p") == "nc/nc1/axis/2/cmd/op/p"
    assert k.command_key("Info", None, "o") == "nc/nc1/cmd/read/o"
    assert k.command_key("NoSuchCommand", 1, "o") == "nc/nc1/axis/1/cmd/op/o"  # the NC answers 0x701
    assert k.parse_cmd_key("nc/nc1/axis/12/cmd/op/plc1") == (12, "op", "plc1")
    assert k.parse_cmd_key("nc/nc1/axis/0/cmd/read/x") == (0, "read", "x")
    assert k.parse_cmd_key("nc/nc1/cmd/eng/e.1-_") == (None, "eng", "e.1-_")
    for bad in ("nc/nc1/axis/x/cmd/op/a", "nc/nc1/axis/01/cmd/op/a", "nc/nc1/axis/12/cmd", "nc/nc1/cmd",
                "nc/nc1/cmd/root/a", "nc/nc1/cmd/op/a b", "nc/nc1/cmd/op/" + "a" * 65, "nc/nc2/cmd/op/a",
                "nc/nc1/axis/1234567890/cmd/op/a", "nc/nc1/cmd/op/a/b", "nc/nc1/**"):
        with pytest.raises(s.NcError) as ei:
            k.parse_cmd_key(bad)
        assert ei.value.code == 0x4012, bad
    for bad_args in (("admin", "a"), ("op", "a b"), ("op", "")):
        with pytest.raises(ValueError):
            k.cmd(*bad_args)
    with pytest.raises(ValueError):
        k.axis_cmd(-1, "op", "a")
    with pytest.raises(ValueError):
        s.Keys("bad name")


def test_every_command_has_a_class():
    assert s.PROTOCOL["version"] == 5
    assert set(s.CLASSES) == {"read", "op", "eng"} == set(s.PROTOCOL["classes"]) - {"doc"}
    assert {n for n, c in s.COMMANDS.items() if c["class"] == "read"} == {
        "Info", "ReadParameter", "ReadParameterSet", "ReadAxisComponents"}
    assert {n for n, c in s.COMMANDS.items() if c["class"] == "eng"} == {
        "WriteParameter", "SetActualPosition", "SetActualPositionOnTheFly", "SetReferenceFlag"}
    assert all(c["class"] in s.CLASSES for c in s.COMMANDS.values())
    for role, classes in s.ROLE_CLASSES.items():
        assert all(role in s.PROTOCOL["classes"][c]["roles"] for c in classes)


def test_parse_error_keeps_id_and_known_command():
    with pytest.raises(s.NcError) as ei:
        s.parse_request(msgpack.packb({"id": 7, "cmd": "MoveAbsolute", "Position": "x", "Velocity": 1.0}))
    assert ei.value.request_id == 7 and ei.value.cmd == "MoveAbsolute"
    with pytest.raises(s.NcError) as ei:
        s.parse_request(msgpack.packb({"id": 8, "cmd": "Explode"}))
    assert ei.value.cmd is None  # unknown commands are not echoed back


def test_ids_with_a_trailing_newline_are_refused() -> None:
    import pytest as _pytest

    from nc_schema import Keys, check_client_id
    with _pytest.raises(ValueError):
        check_client_id("plc1\n")
    with _pytest.raises(ValueError):
        Keys("nc1\n")
