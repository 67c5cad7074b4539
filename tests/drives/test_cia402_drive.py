"""Cia402Drive over the in-process LocalLink (Cia402SimDrive): enables, targets, encoder chain, faults, reset,
stale and lost inputs, the probe latch -- at the drive interface, without the NC."""
from __future__ import annotations

import numpy as np
import pytest

import nc_server.core  # noqa: F401  (first: nc_server.drives imports the core, which imports drives.base)
from nc_server.core.params import AxisParams
from nc_server.drives.cia402.objects import State
from nc_server.drives.cia402.sim import Cia402SimDrive

DT = 0.001


def _drive(n: int = 1, **params: object) -> Cia402SimDrive:
    return Cia402SimDrive([AxisParams(**params) for _ in range(n)], DT)  # type: ignore[arg-type]


def _step(d: Cia402SimDrive, en: bool, pos: float, velo: float = 0.0) -> None:
    n = len(d.act_pos)
    d.step(np.full(n, en), np.full(n, pos), np.full(n, velo), np.zeros(n))


def test_power_up_enable_and_disable() -> None:
    d = _drive()
    assert d.simulated and bool(d.ready[0]) and not d.following[0]
    assert int(d.state[0]) == int(State.READY_TO_SWITCH_ON)
    _step(d, True, 0.0)
    assert d.following[0] and d.ready[0] and not d.faulty
    _step(d, False, 0.0)
    assert not d.following[0] and d.ready[0] and not d.faulty
    assert int(d.state[0]) == int(State.READY_TO_SWITCH_ON)


def test_follows_through_the_encoder_chain() -> None:
    d = _drive(SimTimeConstant=0.0, AxisEncoderScalingFactor=0.5, AxisEncoderOffset=10.0,
               AxisEncoderDirectionInverse=True)
    assert d.act_pos[0] == pytest.approx(10.0)
    _step(d, True, 10.0)
    _step(d, True, 20.0, 100.0)
    assert d.act_pos[0] == pytest.approx(20.0)
    assert d.device.position[0] == pytest.approx(-20.0)  # 10 u at 0.5 u/inc, inverted
    _step(d, True, 21.0, 1000.0)
    assert d.act_velo[0] == pytest.approx(1000.0)


def test_target_follows_actual_while_not_enabled() -> None:
    d = _drive(SimTimeConstant=0.0)
    for _ in range(3):
        _step(d, False, 5.0)
    assert d.act_pos[0] == 0.0
    _step(d, True, 5.0)  # the enabling cycle: the drive holds where it is
    assert d.act_pos[0] == 0.0 and d.following[0]
    _step(d, True, 5.0)
    assert d.act_pos[0] == pytest.approx(5.0)


def test_parameter_change_moves_the_reported_position_not_the_motor() -> None:
    d = _drive(SimTimeConstant=0.0)
    _step(d, True, 0.0)
    _step(d, True, 4.0)
    _step(d, False, 4.0)
    d.configure(0, AxisParams(SimTimeConstant=0.0, AxisEncoderOffset=1.0))
    assert d.act_pos[0] == pytest.approx(5.0)
    assert d.device.position[0] == pytest.approx(4.0)


def test_fault_reset_and_error_code() -> None:
    d = _drive(SimTimeConstant=0.0)
    _step(d, True, 0.0)
    d.inject_fault(0, 0x2310)
    _step(d, True, 0.0)
    assert d.device_error[0] and not d.following[0] and not d.ready[0] and d.faulty
    assert int(d.error_code[0]) == 0x2310
    for _ in range(5):
        _step(d, True, 0.0)
    assert int(d.state[0]) == int(State.FAULT)
    d.reset(np.array([0]))
    for _ in range(3):
        _step(d, True, 0.0)
    assert d.following[0] and not d.device_error[0] and int(d.error_code[0]) == 0 and not d.faulty


def test_leaving_operation_enabled_unasked_is_a_device_error_until_reset() -> None:
    d = _drive()
    for _ in range(d.max_age + 2):  # (enabled for longer than the link's latency: see test_cia402_core)
        _step(d, True, 0.0)
    d.device.state[0] = int(State.SWITCH_ON_DISABLED)  # the drive drops out by itself (e.g. safe torque off)
    _step(d, True, 0.0)
    assert d.device_error[0] and not d.following[0] and int(d.error_code[0]) == 0
    for _ in range(5):  # the NC does not enable it again by itself
        _step(d, True, 0.0)
        assert d.device_error[0] and not d.following[0]
    d.reset(np.array([0]))
    for _ in range(2):
        _step(d, True, 0.0)
    assert d.following[0] and not d.device_error[0] and not d.faulty


def test_disabling_clears_the_drop() -> None:
    d = _drive()
    for _ in range(d.max_age + 2):  # (enabled for longer than the link's latency: see test_cia402_core)
        _step(d, True, 0.0)
    d.device.state[0] = int(State.SWITCH_ON_DISABLED)
    _step(d, True, 0.0)
    assert d.device_error[0]
    _step(d, False, 0.0)
    assert not d.device_error[0] and not d.faulty
    _step(d, True, 0.0)
    assert d.following[0]


def test_stale_inputs_are_invalid_after_max_age() -> None:
    d = _drive(SimTimeConstant=0.0)
    _step(d, True, 0.0)
    _step(d, True, 1.0, 1000.0)
    d.set_io_invalid(0, True)
    _step(d, True, 9.0, 1000.0)
    assert not d.io_valid[0] and d.faulty and int(d.tx.age[0]) == d.max_age + 1
    assert d.act_pos[0] == pytest.approx(1.0)  # the last valid value
    d.set_io_invalid(0, False)
    _step(d, True, 9.0)
    assert d.io_valid[0]


def test_lost_communication() -> None:
    d = _drive()
    _step(d, True, 0.0)
    d.set_silent(0, True)
    _step(d, True, 0.0)
    assert d.comm_error[0] and not d.following[0] and not d.ready[0] and d.faulty


def test_sync_pulse_latch() -> None:
    d = _drive(SimTimeConstant=0.0, SimSyncPulseSpacing=2.0, SimSyncPulseOffset=0.5)
    _step(d, True, 0.0)
    pos, found = 0.0, []
    for _ in range(100):
        prev = float(d.act_pos[0])
        pos += 0.04
        _step(d, True, pos, 40.0)
        x = float(d.latch_sync_pulse(np.array([0]), np.array([prev]))[0])
        if not np.isnan(x):
            found.append(x)
    assert found == pytest.approx([0.5, 2.5])


def test_torque_fields_from_the_drive() -> None:
    d = _drive(SimTimeConstant=0.0)
    _step(d, True, 0.0)
    pos = 0.0
    for _ in range(50):
        pos += 1.0
        _step(d, True, pos, 1000.0)
    f = d.torque_fields()
    assert f is not None
    assert f[1, 0] == pytest.approx(12.0, rel=1e-6)  # 1000 u/s against friction (mechanics defaults)
    assert f[0, 0] == pytest.approx(12.0, rel=1e-6)


def test_inputs_that_age_are_valid_up_to_max_age() -> None:
    d = _drive(SimTimeConstant=0.0)
    d._local.invalid_age = 1  # a link that stops delivering: the age grows cycle by cycle
    _step(d, True, 0.0)
    _step(d, True, 1.0, 1000.0)
    d.set_io_invalid(0, True)
    d._local.invalid_age = 1
    for k in range(d.max_age):
        _step(d, True, 2.0 + k, 1000.0)
        assert d.io_valid[0] and int(d.tx.age[0]) == k + 1, k
    _step(d, True, 9.0, 1000.0)
    assert not d.io_valid[0] and d.faulty
    assert d.act_pos[0] == pytest.approx(1.0)  # the newest inputs that arrived
