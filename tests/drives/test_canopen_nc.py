"""The NC core on CANopen drives: CanopenDrive (from_config, simulated slaves in the process, python-can's virtual
bus) under an NcCore stepped cycle by cycle. Each step waits until the slaves answered its SYNC (the test's
pacing; the NC cycle itself never waits): power up, moves in CSP and CSV, MC_Home with the drive's probe latch,
a drive fault and its reset, a slave that stops answering, and the backend's options."""
from __future__ import annotations

import time
import uuid
from importlib.metadata import entry_points
from pathlib import Path
from typing import Any, Iterator

import numpy as np
import pytest

import nc_server.core  # noqa: F401  (first: nc_server.drives imports the core, which imports drives.base)
from nc_schema import ControlDWord, ErrorCodes as E, MC_AxisStates as S, StateDWord
from nc_server.core import AxisConfig, AxisParams, NcCore
from nc_server.core.params import ConfigError
from nc_server.drives.base import DriveContext
from nc_server.drives.canopen.drive import CanopenDrive
from nc_server.drives.canopen.link import CanopenStartError
from nc_server.drives.cia402.objects import State
from znc_testing.nc_core import ALL_ENABLES, cmd, power, state
from znc_testing.until import step_until

DT = 0.001
SCALE = 0.0001  # mm/inc: positions travel as INT32 increments
DYN = dict(Velocity=100.0, Acceleration=1000.0, Deceleration=1000.0, Jerk=10000.0)


class Rig:
    """An NcCore on ``CanopenDrive`` with in-process simulated slaves on a channel of its own."""

    def __init__(self, axis_options: list[dict[str, Any]], options: dict[str, Any] | None = None,
                 **params: Any) -> None:
        p = dict(AxisEncoderScalingFactor=SCALE)
        p.update(params)
        self.params = [AxisParams(**p) for _ in axis_options]
        # (heartbeat_timeout 1 s, not 0.35: a loaded machine must not lose the healthy node's heartbeat)
        opts = {"simulate_slaves": True, "channel": f"test-{uuid.uuid4().hex[:10]}", "heartbeat_timeout": 1.0,
                **(options or {})}
        drive = CanopenDrive.from_config(self.params, DT, axis_options, DriveContext(options=opts))
        assert isinstance(drive, CanopenDrive)
        self.drive = drive
        self.core = NcCore([AxisConfig(i + 1, f"A{i + 1}", q) for i, q in enumerate(self.params)], DT, drive=drive)
        self.wait: bool | list[int] = True  # wait for every node's answer to each SYNC (a list: these axes')

    def step(self) -> None:
        self.core.step()
        if self.wait is not False:
            rows = None if self.wait is True else self.wait
            assert self.drive.link.wait_answered(5.0, rows), "the slaves did not answer a SYNC"
        else:
            time.sleep(DT)

    def until(self, pred: Any, max_cycles: int = 10_000) -> int:
        return step_until(self.step, pred, max_cycles)

    def until_time(self, pred: Any, seconds: float = 30.0) -> None:
        """Step until ``pred()``, for a wall-clock event (a heartbeat timeout): a deadline, not a cycle count."""
        deadline = time.monotonic() + seconds
        while not pred():
            assert time.monotonic() < deadline, f"condition not reached within {seconds} s"
            self.step()

    def close(self) -> None:
        self.drive.close()


@pytest.fixture
def rig() -> Iterator[Rig]:
    r = Rig([{"node_id": 2}, {"node_id": 3, "mode": "csv"}])
    yield r
    r.close()


def _powered(r: Rig) -> None:
    for i in range(len(r.params)):
        power(r.core, i)
    r.until(lambda: all(state(r.core, i) == S.MC_AXISSTATE_STANDSTILL for i in range(len(r.params)))
            and bool(r.drive.following.all()))


def test_the_entry_point_is_the_backend() -> None:
    (ep,) = [e for e in entry_points(group="zenoh_nc.drives") if e.name == "canopen"]
    assert ep.load() is CanopenDrive


def test_power_up_and_moves_in_csp_and_csv(rig: Rig) -> None:
    d, core = rig.drive, rig.core
    assert d.simulated and not d.following.any()
    assert all(int(s) in (State.SWITCH_ON_DISABLED, State.READY_TO_SWITCH_ON) for s in d.state)
    _powered(rig)
    assert [int(s) for s in d.state] == [State.OPERATION_ENABLED] * 2
    for i in range(2):
        sd = int(core.nctoplc[i]["StateDWord"])
        assert sd & StateDWord.Operational and sd & StateDWord.ControlLoopClosed and not sd & StateDWord.Error
    assert cmd(core, "MoveAbsolute", 1, Position=12.3456, **DYN)["error"] == 0
    assert cmd(core, "MoveAbsolute", 2, Position=-7.5, **DYN)["error"] == 0
    rig.until(lambda: all(state(core, i) == S.MC_AXISSTATE_STANDSTILL for i in range(2)) and core.cycle > 60)
    rig.until(lambda: abs(float(core.nctoplc[0]["ActPos"]) - 12.3456) < 2 * SCALE
              and abs(float(core.nctoplc[1]["ActPos"]) + 7.5) < 1e-3)  # CSV: the velocity lag settles
    # the motors (the slaves' devices, read over SDO in increments) are where the NC says
    assert rig.drive.slaves is not None
    inc = [n.sdo[0x6064].raw for n in rig.drive.slaves.nodes]
    assert inc[0] == round(12.3456 / SCALE) and abs(inc[1] * SCALE + 7.5) < 1e-3
    assert all(int(r["ErrorCode"]) == 0 for r in core.nctoplc)


def test_home_with_the_drives_probe_latch() -> None:
    """MC_Home (no cam recipe, TcMC 3.14): the NC's homing, the sync pulse latched by the drive's touch probe."""
    r = Rig([{"node_id": 4}], AxisCalibrationVelocityBackward=20.0, SimSyncPulseOffset=0.25)
    try:
        core = r.core
        _powered(r)
        power(core, ctrl=ALL_ENABLES | int(ControlDWord.HomingSensor))
        r.step()
        assert cmd(core, "Home", Position=100.0)["error"] == 0
        r.until(lambda: int(core.nctoplc[0]["HomingState"]) >= 4)
        power(core)
        r.until(lambda: int(core.nctoplc[0]["HomingState"]) == 0
                and state(core) == S.MC_AXISSTATE_STANDSTILL and core.nctoplc[0]["StateDWord"] & StateDWord.Homed)
        for _ in range(5):
            r.step()
        act = float(core.nctoplc[0]["ActPos"])
        assert 100.0 < act < 101.0 and int(core.nctoplc[0]["ErrorCode"]) == 0
        # exact, not cycle-quantised: the pulse at 0.25 mm (old frame) is now 100 mm, to an increment or two
        assert r.drive.slaves is not None
        motor = r.drive.slaves.nodes[0].sdo[0x6064].raw * SCALE
        assert act == pytest.approx(100.0 + motor - 0.25, abs=2 * SCALE)
    finally:
        r.close()


def test_drive_fault_and_reset(rig: Rig) -> None:
    core, d = rig.core, rig.drive
    _powered(rig)
    assert cmd(core, "MoveVelocity", 1, Velocity=50.0, Acceleration=1000.0, Deceleration=1000.0,
               Jerk=10000.0)["error"] == 0
    rig.until(lambda: float(core.nctoplc[0]["ActVelo"]) > 49.0)
    assert d.slaves is not None
    d.slaves.inject_fault(0, 0x2310)
    rig.until(lambda: int(core.nctoplc[0]["ErrorCode"]) != 0)
    assert int(core.nctoplc[0]["ErrorCode"]) == E.NC_DRIVE_NOT_READY == 0x4650
    assert int(d.error_code[0]) == 0x2310 and d.device_error[0] and not d.following[0]
    # the drive stops itself on its fault reaction ramp, then is in Fault, the motor standing; the NC runs no ramp
    # of its own: its set-point follows the actual position
    rig.until(lambda: int(d.state[0]) == State.FAULT)
    for _ in range(3):
        rig.step()
    r0 = core.nctoplc[0]
    assert abs(float(r0["ActVelo"])) < 1e-6
    assert abs(float(r0["SetPos"]) - float(r0["ActPos"])) < 2 * SCALE and float(r0["SetVelo"]) == 0.0
    assert d.link.emcy_code[0] == 0x2310  # the EMCY came too
    assert int(core.nctoplc[1]["ErrorCode"]) == 0  # the other axis is untouched
    assert cmd(core, "Reset", 1)["error"] == 0  # MC_Reset: the NC's fault reset edge in the controlword
    # the drive's statusword shows the reset a bus cycle or more later: the NC does not raise 0x4650 again meanwhile
    seen = []
    rig.until(lambda: seen.append(int(core.nctoplc[0]["ErrorCode"])) is None and int(d.error_code[0]) == 0
              and int(d.state[0]) != State.FAULT, max_cycles=2000)
    assert set(seen) == {0}  # one MC_Reset suffices
    for _ in range(10):
        rig.step()
    assert int(core.nctoplc[0]["ErrorCode"]) == 0
    power(core, 0, ctrl=0)
    rig.step()
    power(core, 0)
    rig.until(lambda: state(core, 0) == S.MC_AXISSTATE_STANDSTILL and bool(d.following[0]))
    target = float(core.nctoplc[0]["ActPos"]) + 5.0
    assert cmd(core, "MoveAbsolute", 1, Position=target, **DYN)["error"] == 0
    rig.until(lambda: abs(float(core.nctoplc[0]["ActPos"]) - target) < 2 * SCALE)
    assert int(core.nctoplc[0]["ErrorCode"]) == 0


def test_a_slave_that_stops_answering(rig: Rig) -> None:
    core, d = rig.core, rig.drive
    _powered(rig)
    assert d.slaves is not None
    d.slaves.silence(1)
    rig.wait = [0]  # its TPDOs will not come: paced on the healthy node (whose inputs stay fresh)
    n = rig.until(lambda: int(core.nctoplc[1]["ErrorCode"]) != 0, max_cycles=5000)
    assert n >= d.max_age  # the inputs aged first (ErrorPropagationDelayed), then the axis error
    assert int(core.nctoplc[1]["ErrorCode"]) == E.NC_DRIVE_IO_DATA_INVALID == 0x4655  # the ages come first
    assert not d.io_valid[1] and int(core.nctoplc[1]["StateDWord"]) & StateDWord.IoDataInvalid
    # the heartbeat consumer then reports the node lost
    rig.until_time(lambda: bool(d.comm_error[1]))
    assert int(core.nctoplc[0]["ErrorCode"]) == 0 and d.io_valid[0]  # the other node is fine


def test_a_missing_node_at_start_is_a_bounded_error() -> None:
    from nc_server.drives.canopen.slave import SimulatedSlaves
    ch = f"test-{uuid.uuid4().hex[:10]}"
    params = [AxisParams(), AxisParams()]
    slaves = SimulatedSlaves([2], params[:1], DT, channel=ch)
    try:
        t0 = time.monotonic()
        with pytest.raises(CanopenStartError, match="node 9 does not answer"):
            CanopenDrive.from_config(params, DT, [{"node_id": 2}, {"node_id": 9}],
                                     DriveContext(options={"channel": ch, "sdo_timeout": 0.1}))
        assert time.monotonic() - t0 < 10.0
    finally:
        slaves.close()


@pytest.mark.parametrize("axis,options,key,text", [
    ({"node_id": 2, "speed": 1}, {}, "axis[0].Drive.speed", "unknown option"),
    ({}, {}, "axis[0].Drive.node_id", "required"),
    ({"node_id": 128}, {}, "axis[0].Drive.node_id", "1..127"),
    ({"node_id": True}, {}, "axis[0].Drive.node_id", "1..127"),
    ({"node_id": 2, "mode": "pp"}, {}, "axis[0].Drive.mode", "csp"),
    ({"node_id": 2, "eds": "/no/such.eds"}, {}, "axis[0].Drive.eds", "no such EDS"),
    ({"node_id": 2}, {"bus": "x"}, "drives.canopen.bus", "unknown option"),
    ({"node_id": 2}, {"interface": "socketcan", "simulate_slaves": True}, "drives.canopen.simulate_slaves",
     "virtual"),
    ({"node_id": 2}, {"simulate_slaves": "yes"}, "drives.canopen.simulate_slaves", "true or false"),
    ({"node_id": 2}, {"bitrate": 0}, "drives.canopen.bitrate", "integer"),
    ({"node_id": 2}, {"sdo_timeout": -1}, "drives.canopen.sdo_timeout", "positive"),
    ({"node_id": 2}, {"sdo_timeout": 1e9}, "drives.canopen.sdo_timeout", "at most 60"),
    ({"node_id": 2}, {"start_timeout": 60.5}, "drives.canopen.start_timeout", "at most 60"),
    ({"node_id": 2}, {"heartbeat_period": 65.6}, "drives.canopen.heartbeat_period", "UNSIGNED16"),
    ({"node_id": 2}, {"heartbeat_period": 0.0005}, "drives.canopen.heartbeat_period", "0.001"),
    ({"node_id": 2}, {"heartbeat_period": 0.2, "heartbeat_timeout": 0.1}, "drives.canopen.heartbeat_timeout",
     "longer"),
    ({"node_id": 2}, {"max_age": -1}, "drives.canopen.max_age", "integer >= 0"),
    ({"node_id": 2, "mode": "csv", "kv": 0}, {}, "axis[0].Drive.kv", "> 0"),
    ({"node_id": 2}, {"channel": ""}, "drives.canopen.channel", "non-empty"),
    ({"node_id": 2}, {"monitoring": "lifeguard"}, "drives.canopen.monitoring", "node_guarding"),
])
def test_bad_options_are_config_errors(axis: dict[str, Any], options: dict[str, Any], key: str, text: str) -> None:
    with pytest.raises(ConfigError, match=text) as e:
        CanopenDrive.from_config([AxisParams()], DT, [axis], DriveContext(options=options))
    assert e.value.key == key


@pytest.mark.parametrize("text,error", [("hello world\n", "not a readable EDS"),
                                        ("[FileInfo]\nFileName=x\n", "lacks the objects 0x603F, 0x6040"),
                                        ("[DeviceInfo]\nProductName=x\n", "lacks the objects 0x603F, 0x6040")])
@pytest.mark.parametrize("simulate", [True, False])
def test_a_file_that_is_no_drive_eds_is_a_config_error(tmp_path: Path, text: str, error: str,
                                                       simulate: bool) -> None:
    eds = tmp_path / "not.eds"
    eds.write_text(text)
    with pytest.raises(ConfigError, match=error) as e:
        CanopenDrive.from_config([AxisParams()], DT, [{"node_id": 2, "eds": str(eds)}],
                                 DriveContext(options={"simulate_slaves": simulate,
                                                       "channel": f"test-{uuid.uuid4().hex[:10]}"}))
    assert e.value.key == "axis[0].Drive.eds"
    assert str(eds) in str(e.value)


def test_duplicate_node_ids_and_an_unrepresentable_cycle() -> None:
    with pytest.raises(ConfigError, match="already axis") as e:
        CanopenDrive.from_config([AxisParams()] * 2, DT, [{"node_id": 2}, {"node_id": 2}], DriveContext())
    assert e.value.key == "axis[1].Drive.node_id"
    with pytest.raises(ConfigError, match="0x60C2"):
        CanopenDrive.from_config([AxisParams()], 0.2561, [{"node_id": 2}], DriveContext())


def test_an_existing_eds_is_accepted_by_the_options(tmp_path: Path) -> None:
    from nc_server.drives.canopen.link import SIM_EDS
    eds = tmp_path / "servo.eds"
    eds.write_text(Path(SIM_EDS).read_text())
    r = Rig([{"node_id": 6, "eds": str(eds)}])
    try:
        _powered(r)
        assert np.all(r.drive.following)
    finally:
        r.close()


def test_a_lost_heartbeat_is_a_communication_error(rig: Rig) -> None:
    """The node's PDOs still come, its heartbeat stops (the consumer's loss detection): 0x4651, the drive's state
    unknown, the other axis untouched."""
    core, d = rig.core, rig.drive
    _powered(rig)
    assert d.slaves is not None
    d.slaves.nodes[1].nmt.stop_heartbeat()
    rig.until_time(lambda: int(core.nctoplc[1]["ErrorCode"]) != 0)
    assert int(core.nctoplc[1]["ErrorCode"]) == 0x4651 and d.comm_error[1] and d.io_valid[1]
    assert int(core.nctoplc[0]["ErrorCode"]) == 0


def _usable_after_reset(r: Rig, i: int) -> None:
    """MC_Reset, MC_Power off and on, a move of 5 mm: axis ``i`` works again, its error gone."""
    core, d = r.core, r.drive
    assert cmd(core, "Reset", i + 1)["error"] == 0
    r.until(lambda: int(core.nctoplc[i]["ErrorCode"]) == 0 and not d.device_error[i], max_cycles=3000)
    power(core, i, ctrl=0)
    r.step()
    power(core, i)
    r.until(lambda: state(core, i) == S.MC_AXISSTATE_STANDSTILL and bool(d.following[i]), max_cycles=3000)
    target = float(core.nctoplc[i]["ActPos"]) + 5.0
    assert cmd(core, "MoveAbsolute", i + 1, Position=target, **DYN)["error"] == 0
    r.until(lambda: abs(float(core.nctoplc[i]["ActPos"]) - target) < 1e-3)
    assert int(core.nctoplc[i]["ErrorCode"]) == 0


def test_a_rebooted_node_is_set_up_again(rig: Rig) -> None:
    """A node that reboots (its configuration gone, a boot-up message): the link sets it up again (SDO, NMT start)
    without the cycle waiting; the axis is in error until MC_Reset, then powers up and moves; the position kept."""
    core, d = rig.core, rig.drive
    _powered(rig)
    assert cmd(core, "MoveAbsolute", 2, Position=3.0, **DYN)["error"] == 0
    rig.until(lambda: state(core, 1) == S.MC_AXISSTATE_STANDSTILL and core.cycle > 60)
    rig.until(lambda: abs(float(core.nctoplc[1]["ActPos"]) - 3.0) < 1e-3)
    assert d.slaves is not None
    slave = d.slaves.nodes[1]
    assert slave.sdo[0x6060].raw == 9  # CSV, as the link configured it
    d.slaves.reboot(1)
    assert slave.sdo[0x6060].raw == 8 and slave.sdo[0x1017].raw == 0  # the EDS defaults: the configuration gone
    rig.wait = [0]
    rig.until(lambda: int(core.nctoplc[1]["ErrorCode"]) != 0)
    assert int(core.nctoplc[1]["ErrorCode"]) in (0x4651, 0x4655)  # lost communication / invalid I/O data
    assert int(core.nctoplc[0]["ErrorCode"]) == 0
    rig.until_time(lambda: int(d.link.setups[1]) == 1 and bool(d.link.figures()[1]["alive"]))
    rig.wait = True
    assert d.slaves.nmt_state(1) == "OPERATIONAL"
    assert slave.sdo[0x6060].raw == 9 and slave.sdo[0x1017].raw == 100  # configured again
    assert [slave.sdo[0x1601][k].raw for k in range(3)] == [2, 0x60FF0020, 0x60B80010]
    # the drive back in Switch on disabled (the NC's Shutdown may have taken it on to Ready to switch on)
    rig.until(lambda: int(d.state[1]) in (State.SWITCH_ON_DISABLED, State.READY_TO_SWITCH_ON) and bool(d.io_valid[1]))
    assert int(core.nctoplc[1]["ErrorCode"]) != 0  # still in error: the drive dropped out while enabled
    assert abs(float(core.nctoplc[1]["ActPos"]) - 3.0) < 1e-3  # the motor where it was
    _usable_after_reset(rig, 1)
    f = d.link_figures()[1]
    assert f["setups"] == 1 and f["nmt"] == "OPERATIONAL" and f["monitoring"] == "heartbeat" and f["node_id"] == 3
    assert f["tpdo_late"] > 0 and f["tpdo_missed"] > 0  # its TPDOs were gone meanwhile


def test_node_guarding_detects_a_lost_node_and_a_reboot() -> None:
    """``monitoring = "node_guarding"``: the master polls, the simulated slaves answer (state + toggle); a silent
    node is lost communication (0x4651); back with its configuration, MC_Reset suffices; after a reboot it is set
    up again."""
    r = Rig([{"node_id": 2}, {"node_id": 3}], options={"monitoring": "node_guarding", "heartbeat_period": 0.05})
    try:
        core, d = r.core, r.drive
        assert d.slaves is not None
        slave = d.slaves.nodes[1]
        assert slave.sdo[0x1017].raw == 0 and slave.sdo[0x100C].raw == 50 and slave.sdo[0x100D].raw == 20
        _powered(r)
        f = d.link_figures()
        assert [x["monitoring"] for x in f.values()] == ["node_guarding"] * 2 and all(x["alive"] for x in f.values())
        assert all(x["heartbeat_age_ms"] is not None and x["nmt"] == "OPERATIONAL" for x in f.values())
        d.slaves.silence(1)
        r.wait = [0]
        r.until_time(lambda: bool(d.comm_error[1]))
        r.until(lambda: int(core.nctoplc[1]["ErrorCode"]) != 0)
        assert int(core.nctoplc[1]["ErrorCode"]) in (0x4651, 0x4655) and int(core.nctoplc[0]["ErrorCode"]) == 0
        assert not d.link_figures()[1]["alive"]
        d.slaves.revive(1)  # back, configuration kept: checked, not set up again
        r.until_time(lambda: not d.comm_error[1])
        r.wait = True
        _usable_after_reset(r, 1)
        assert int(d.link.setups[1]) == 0
        d.slaves.reboot(1)
        r.wait = [0]
        r.until_time(lambda: int(d.link.setups[1]) == 1 and not d.comm_error[1])
        r.wait = True
        assert slave.sdo[0x100C].raw == 50 and d.slaves.nmt_state(1) == "OPERATIONAL"
        _usable_after_reset(r, 1)
        assert int(core.nctoplc[0]["ErrorCode"]) == 0
    finally:
        r.close()


def test_node_guarding_needs_the_guarding_objects(tmp_path: Path) -> None:
    """An EDS without 0x100C / 0x100D: node guarding is a clear start error, naming the node."""
    from nc_server.drives.canopen.link import SIM_EDS
    text = Path(SIM_EDS).read_text()
    for index in ("100C", "100D"):
        text = text.replace(f"[{index}]", f"[{index}-removed]")
    eds = tmp_path / "no_guarding.eds"
    eds.write_text(text)
    with pytest.raises(CanopenStartError, match="node 2: its EDS has no guard time"):
        Rig([{"node_id": 2, "eds": str(eds)}], options={"monitoring": "node_guarding"})
