"""NcCore cycle by cycle with the ``cia402-sim`` drives (Cia402SimDrive): power up, moves, a drive fault (0x4650,
the drive's own code, no NC ramp, MC_Reset), lost communication (0x4651), stale inputs (0x4655), homing with the
drive's probe latch, and a link with latency (MC_Power's Status only once the drive is in Operation enabled)."""
from __future__ import annotations

from typing import Any

import numpy as np
import pytest

import nc_server.core  # noqa: F401  (first: nc_server.drives imports the core, which imports drives.base)
from nc_schema import ErrorCodes as E, MC_AxisStates as S, StateDWord
from nc_server.core import AxisConfig, AxisParams, NcCore
from nc_server.drives.cia402.device import Cia402Device
from nc_server.drives.cia402.drive import Cia402Drive
from nc_server.drives.cia402.image import ProcessDataLink, RxImage, TxImage
from nc_server.drives.cia402.objects import State
from nc_server.drives.cia402.sim import Cia402SimDrive
from znc_testing.nc_core import cmd, power, run_until, state

DT = 0.001
LOOP, OPERATIONAL, DEVICE = (int(StateDWord.ControlLoopClosed), int(StateDWord.Operational),
                             int(StateDWord.DriveDeviceError))


def _core(n: int = 1, drive: Any = None, **params: Any) -> NcCore:
    p = [AxisParams(**params) for _ in range(n)]
    return NcCore([AxisConfig(i + 1, f"A{i + 1}", p[i]) for i in range(n)], DT,
                  drive=drive if drive is not None else Cia402SimDrive(p, DT))


def _dw(core: NcCore, i: int = 0) -> int:
    return int(core.nctoplc[i]["StateDWord"])


def _err(core: NcCore, i: int = 0) -> int:
    return int(core.nctoplc[i]["ErrorCode"])


def test_power_up_enables_the_drive_and_status_follows_it() -> None:
    core = _core()
    drive = core.drive
    assert isinstance(drive, Cia402SimDrive)
    for _ in range(3):
        core.step()
    assert int(drive.state[0]) == int(State.READY_TO_SWITCH_ON) and not _dw(core) & LOOP
    power(core)
    core.step()
    assert int(drive.state[0]) == int(State.OPERATION_ENABLED)
    assert _dw(core) & LOOP and _dw(core) & OPERATIONAL
    assert state(core) == S.MC_AXISSTATE_STANDSTILL
    power(core, ctrl=0)
    core.step()
    assert int(drive.state[0]) == int(State.READY_TO_SWITCH_ON) and not _dw(core) & LOOP


class DelayedLink(ProcessDataLink):
    """A link with one cycle of latency each way: the outputs reach the device in the next exchange, the inputs
    returned are the device's of the exchange before."""

    def __init__(self, device: Cia402Device) -> None:
        self.device, self.n = device, device.n
        self._rx: RxImage | None = None
        self._tx: TxImage = device.tx

    def exchange(self, rx: RxImage) -> TxImage:
        out = self._tx
        out = TxImage(**{**vars(out), "age": np.ones(self.n, dtype=np.int64)})
        self._tx = self.device.step(self._rx)
        self._rx = rx
        return out


def test_with_latency_status_shows_enabled_only_once_the_drive_is() -> None:
    p = [AxisParams()]
    dev = Cia402Device(1, DT)
    dev.configure(0, p[0])
    drive = Cia402Drive(p, DT, DelayedLink(dev), simulated=True)
    core = _core(drive=drive)
    for _ in range(5):
        core.step()
    assert int(drive.state[0]) == int(State.READY_TO_SWITCH_ON)
    power(core)
    seen = []
    for _ in range(6):
        core.step()
        seen.append((int(drive.state[0]), bool(_dw(core) & LOOP), bool(drive.following[0])))
    assert seen[0] == (int(State.READY_TO_SWITCH_ON), False, False)  # the enable is on its way
    first = next(k for k, s in enumerate(seen) if s[0] == int(State.OPERATION_ENABLED))
    assert all(not s[1] for s in seen[:first]) and all(s[1] for s in seen[first:])
    assert _err(core) == 0
    # a start while the drive switches on is refused as for a drive not ready; once it follows it moves
    assert cmd(core, "MoveAbsolute", Position=10.0, Velocity=100.0)["error"] == 0
    run_until(core, lambda: state(core) == S.MC_AXISSTATE_STANDSTILL and abs(core.nctoplc[0]["ActPos"] - 10.0) < 1e-6,
              20_000)


def test_start_during_switch_on_is_refused_0x4225() -> None:
    p = [AxisParams()]
    dev = Cia402Device(1, DT)
    dev.configure(0, p[0])
    core = _core(drive=Cia402Drive(p, DT, DelayedLink(dev), simulated=True))
    core.step()
    power(core)
    core.step()
    assert cmd(core, "MoveAbsolute", Position=10.0, Velocity=100.0)["error"] == E.NC_DRIVE_NOT_READY_AT_START


@pytest.mark.parametrize("target", [100.0, -37.5])
def test_moves_reach_their_targets(target: float) -> None:
    core = _core(2)
    power(core, 0)
    power(core, 1)
    core.step()
    assert cmd(core, "MoveAbsolute", axis=1, Position=target, Velocity=300.0)["error"] == 0
    assert cmd(core, "MoveVelocity", axis=2, Velocity=50.0, Direction=1)["error"] == 0
    run_until(core, lambda: state(core) == S.MC_AXISSTATE_STANDSTILL, 20_000)
    run_until(core, lambda: abs(core.nctoplc[0]["ActPos"] - target) < 1e-6, 1000)
    assert core.nctoplc[1]["ActVelo"] == pytest.approx(50.0, rel=1e-6)
    assert _err(core, 0) == _err(core, 1) == 0


def _moving(params: dict[str, Any] | None = None) -> NcCore:
    core = _core(**(params or {}))
    power(core)
    core.step()
    cmd(core, "MoveVelocity", Velocity=200.0, Direction=1)
    run_until(core, lambda: abs(core.nctoplc[0]["ActVelo"] - 200.0) < 1e-3, 5000)
    return core


def test_a_drive_fault_is_0x4650_the_drive_stops_itself_and_reset_clears_it() -> None:
    core = _moving(dict(AxisDec=1000.0))
    drive = core.drive
    assert isinstance(drive, Cia402SimDrive)
    drive.inject_fault(0, 0x2310)
    core.step()
    assert _err(core) == E.NC_DRIVE_NOT_READY == 0x4650
    assert int(drive.error_code[0]) == 0x2310
    assert _dw(core) & DEVICE and not _dw(core) & LOOP
    # the drive brakes on its own quick-stop ramp (AxisDec 1000: 0.2 s); the NC runs no ramp, its set-point
    # follows the actual position
    cycles = 0
    while int(drive.state[0]) != int(State.FAULT):
        core.step()
        cycles += 1
        r = core.nctoplc[0]
        assert r["SetVelo"] == 0.0 and not core.axes.traj_on[0]
        assert abs(r["SetPos"] - r["ActPos"]) < 200.0 * DT + 1e-9  # one cycle of motion at most
        assert cycles < 1000
    assert cycles == pytest.approx(200, abs=5)
    for _ in range(5):
        core.step()
    r = core.nctoplc[0]
    assert r["SetPos"] == r["ActPos"] and r["ActVelo"] == 0.0
    assert int(drive.error_code[0]) == 0x2310 and _err(core) == 0x4650
    stood = float(r["ActPos"])
    assert cmd(core, "Reset")["error"] == 0
    run_until(core, lambda: bool(_dw(core) & LOOP), 20)
    assert _err(core) == 0 and int(drive.error_code[0]) == 0 and not _dw(core) & DEVICE
    assert state(core) == S.MC_AXISSTATE_STANDSTILL
    for _ in range(20):
        core.step()
    assert core.nctoplc[0]["ActPos"] == pytest.approx(stood, abs=1e-9)  # nothing jumped
    assert cmd(core, "MoveRelative", Distance=5.0, Velocity=100.0)["error"] == 0
    run_until(core, lambda: abs(core.nctoplc[0]["ActPos"] - (stood + 5.0)) < 1e-6, 10_000)


def test_a_fault_whose_cause_lasts_comes_back_after_reset() -> None:
    core = _moving()
    drive = core.drive
    assert isinstance(drive, Cia402SimDrive)
    drive.set_device_error(0, True)
    run_until(core, lambda: int(drive.state[0]) == int(State.FAULT), 1000)
    assert _err(core) == 0x4650 and int(drive.error_code[0]) == 0x5000
    cmd(core, "Reset")
    for _ in range(drive.max_age + 5):  # the refused reset: 0x4650 again once its request has timed out
        core.step()
    assert _err(core) == 0x4650 and int(drive.state[0]) == int(State.FAULT)
    drive.set_device_error(0, False)
    for _ in range(3):
        core.step()
    assert _err(core) == 0x4650  # the drive still waits for its fault reset
    cmd(core, "Reset")
    run_until(core, lambda: bool(_dw(core) & LOOP), 20)
    assert _err(core) == 0 and int(drive.error_code[0]) == 0


def test_lost_communication_is_0x4651() -> None:
    core = _moving()
    drive = core.drive
    assert isinstance(drive, Cia402SimDrive)
    drive.set_silent(0, True)
    core.step()
    assert _err(core) == E.NC_DRIVE_CYCLIC_COMM_ERROR == 0x4651
    assert not _dw(core) & LOOP
    r = core.nctoplc[0]
    assert r["SetVelo"] == 0.0 and not core.axes.traj_on[0]  # no NC ramp on a drive it cannot reach


def test_lost_communication_on_a_disabled_axis_is_0x4651_too() -> None:
    core = _core()
    core.step()
    core.drive.set_silent(0, True)  # type: ignore[attr-defined]
    core.step()
    assert _err(core) == 0x4651


def test_stale_inputs_are_0x4655_after_three_cycles() -> None:
    core = _moving()
    drive = core.drive
    assert isinstance(drive, Cia402SimDrive)
    drive.set_io_invalid(0, True)
    for k in range(3):
        core.step()
        assert _dw(core) & int(StateDWord.IoDataInvalid) and _err(core) == 0, k
    core.step()
    assert _err(core) == E.NC_DRIVE_IO_DATA_INVALID == 0x4655
    drive.set_io_invalid(0, False)
    run_until(core, lambda: not core.axes.traj_on[0], 10_000)
    cmd(core, "Reset")
    for _ in range(3):
        core.step()
    assert _err(core) == 0


def test_homing_latches_the_index_pulse_through_the_drives_probe() -> None:
    core = _core(AxisCalibrationVelocityForward=100.0, AxisCalibrationVelocityBackward=20.0,
                 SimSyncPulseOffset=0.25, SimSyncPulseSpacing=1.0, AxisEncoderScalingFactor=0.01)
    power(core)
    core.step()
    cam = (-30.0, -10.0)
    from nc_schema import ControlDWord
    from znc_testing.nc_core import ALL_ENABLES

    def cam_input() -> None:
        p = float(core.nctoplc[0]["ActPos"])
        power(core, ctrl=ALL_ENABLES | (int(ControlDWord.HomingSensor) if cam[0] <= p <= cam[1] else 0))

    latched: list[float] = []
    drive = core.drive
    orig = drive.latch_sync_pulse

    def spy(rows: np.ndarray, prev: np.ndarray) -> np.ndarray:
        out = orig(rows, prev)
        latched.extend(float(x) for x in out if not np.isnan(x))
        return out

    drive.latch_sync_pulse = spy  # type: ignore[method-assign]
    assert cmd(core, "Home", Position=500.0)["error"] == 0
    for _ in range(20_000):
        cam_input()
        core.step()
        if int(core.nctoplc[0]["HomingState"]) == 0 and state(core) == S.MC_AXISSTATE_STANDSTILL:
            break
    assert latched == [pytest.approx(-9.75)]  # the first index pulse off the cam, exactly
    assert core.nctoplc[0]["StateDWord"] & int(StateDWord.Homed)
    assert _err(core) == 0


def test_csv_axes_reach_their_targets_through_the_ncs_position_loop() -> None:
    p = [AxisParams(), AxisParams()]
    from nc_server.drives.cia402.objects import Mode
    drive = Cia402SimDrive(p, DT, mode=[Mode.CSV, Mode.CSP], kv=[100.0, 100.0])
    core = _core(2, drive=drive)
    power(core, 0)
    power(core, 1)
    core.step()
    assert list(drive.device.rx.mode) == [9, 8]
    for axis in (1, 2):
        assert cmd(core, "MoveAbsolute", axis=axis, Position=50.0, Velocity=200.0)["error"] == 0
    lag, lag_csp = [], []
    for _ in range(3000):
        core.step()
        lag.append(abs(float(core.nctoplc[0]["PosDiff"])))
        lag_csp.append(abs(float(core.nctoplc[1]["PosDiff"])))
    assert core.nctoplc[0]["ActPos"] == pytest.approx(50.0, abs=1e-6)
    assert core.nctoplc[1]["ActPos"] == pytest.approx(50.0, abs=1e-6)
    # the loop follows the profile within two cycles of motion (CSP: the drive's lag of SimTimeConstant, less)
    assert max(lag_csp) < max(lag) <= 200.0 * 2 * DT and _err(core, 0) == 0


def test_from_config_options_and_their_errors() -> None:
    from nc_server.core.params import ConfigError
    from nc_server.drives.base import DriveContext
    p = [AxisParams(), AxisParams()]
    d = Cia402SimDrive.from_config(p, DT, [{"mode": "csv", "kv": 50}, {}], DriveContext(options={"max_age": 5}))
    assert list(d._mode) == [9, 8] and list(d._kv) == [50.0, 100.0] and d.max_age == 5
    for opts, ctx, key in [
        ([{"mode": "pp"}, {}], {}, "axis[0].Drive.mode"),
        ([{}, {"kv": 0}], {}, "axis[1].Drive.kv"),
        ([{}, {"kv": "fast"}], {}, "axis[1].Drive.kv"),
        ([{"node_id": 3}, {}], {}, "axis[0].Drive"),
        ([{}, {}], {"max_age": -1}, "drives.cia402-sim.max_age"),
        ([{}, {}], {"bus": "x"}, "drives.cia402-sim"),
    ]:
        with pytest.raises(ConfigError) as e:
            Cia402SimDrive.from_config(p, DT, opts, DriveContext(options=ctx))
        assert key in str(e.value), (opts, ctx, str(e.value))


def _delayed(params: dict[str, Any] | None = None) -> tuple[NcCore, Cia402Device, Cia402Drive]:
    p = [AxisParams(**(params or {}))]
    dev = Cia402Device(1, DT)
    dev.configure(0, p[0])
    drive = Cia402Drive(p, DT, DelayedLink(dev), simulated=True)
    core = NcCore([AxisConfig(1, "A1", p[0])], DT, drive=drive)
    power(core)
    run_until(core, lambda: bool(_dw(core) & LOOP), 20)
    return core, dev, drive


@pytest.mark.parametrize("during_reaction", [False, True])
def test_with_latency_one_reset_clears_a_fault(during_reaction: bool) -> None:
    core, dev, drive = _delayed(dict(AxisDec=1000.0) if during_reaction else None)
    assert cmd(core, "MoveVelocity", Velocity=200.0, Direction=1)["error"] == 0
    run_until(core, lambda: abs(core.nctoplc[0]["ActVelo"] - 200.0) < 1e-3, 5000)
    dev.inject_fault(0, 0x2310)
    if during_reaction:  # MC_Reset while the drive still brakes (Fault reaction active): it is kept until Fault
        run_until(core, lambda: int(drive.state[0]) == int(State.FAULT_REACTION_ACTIVE), 100)
    else:
        run_until(core, lambda: int(drive.state[0]) == int(State.FAULT) and int(dev.velocity[0]) == 0, 5000)
    run_until(core, lambda: _err(core) == 0x4650, 10)
    assert cmd(core, "Reset")["error"] == 0
    for _ in range(20 if not during_reaction else 2000):
        core.step()
        if int(drive.state[0]) == int(State.FAULT):  # the reset is on its way: the axis is not ready meanwhile
            assert not _dw(core) & LOOP and not drive.ready[0]  # (a start would be refused with 0x4225)
        if int(drive.state[0]) == int(State.OPERATION_ENABLED):
            break
    for _ in range(5):
        core.step()
    assert int(drive.state[0]) == int(State.OPERATION_ENABLED)
    assert _err(core) == 0 and _dw(core) & LOOP  # one MC_Reset sufficed
    assert cmd(core, "MoveRelative", Distance=5.0, Velocity=100.0)["error"] == 0


def test_with_latency_a_short_power_off_and_on_is_no_drive_error() -> None:
    core, dev, drive = _delayed()
    power(core, ctrl=0)
    core.step()  # Shutdown sent for one cycle ...
    power(core)  # ... then Enable operation again: the drive obeys the Shutdown a cycle or two later
    states, loop = [], []
    for _ in range(20):
        core.step()
        states.append(int(drive.state[0]))
        loop.append(bool(_dw(core) & LOOP))
        assert _err(core) == 0, f"cycle {len(states)}: {_err(core):#x}"
        assert loop[-1] == (states[-1] == int(State.OPERATION_ENABLED))  # MC_Power's Status honest meanwhile
    assert int(State.READY_TO_SWITCH_ON) in states  # the drive did leave Operation enabled
    assert states[-1] == int(State.OPERATION_ENABLED) and not drive.device_error[0]
    assert cmd(core, "MoveRelative", Distance=5.0, Velocity=100.0)["error"] == 0


def test_a_drive_leaving_operation_enabled_by_itself_is_still_0x4650() -> None:
    core, dev, drive = _delayed()
    for _ in range(10):
        core.step()
    dev.state[0] = int(State.SWITCH_ON_DISABLED)  # e.g. its safe torque off
    run_until(core, lambda: _err(core) == 0x4650, 10)
    assert drive.device_error[0]


def test_a_latch_from_behind_the_search_is_not_taken() -> None:
    """The probe is armed all the time: a latch arriving late from before the sync pulse search (still on the
    cam) lies behind the previous position in the direction of travel and is refused; one ahead is taken."""
    core = _moving()
    drive = core.drive
    assert isinstance(drive, Cia402SimDrive)
    core.step()
    prev, now = float(core.prev_act_pos[0]), float(drive.act_pos[0])
    assert now > prev  # moving forward
    per_cycle = now - prev

    def latch_at(pos: float) -> float:
        c = drive.encoder
        inc = (pos - c.offset[0]) / c.scaling[0] * c.sign[0] - c.base[0]
        drive.tx = TxImage(**{**vars(drive.tx), "probe_position": np.array([inc])})
        drive._probe_new = np.array([True])
        return float(drive.latch_sync_pulse(np.array([0]), np.array([prev]))[0])

    assert latch_at(prev + 0.5 * per_cycle) == pytest.approx(prev + 0.5 * per_cycle)
    assert latch_at(prev - (drive.max_age - 0.5) * per_cycle) == pytest.approx(prev - (drive.max_age - 0.5) * per_cycle)
    assert np.isnan(latch_at(prev - (drive.max_age + 2) * per_cycle))  # from before the window: refused
