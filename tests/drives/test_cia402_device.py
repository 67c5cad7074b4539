"""Simulated CiA 402 drives (nc_server.drives.cia402.device.Cia402Device): CSP lag, CSV, quick stop ramp,
fault injection and reset, the communication timeout, the index pulse probe."""
from __future__ import annotations

import math

import numpy as np
import pytest

import nc_server.core  # noqa: F401  (first: nc_server.drives imports the core, which imports drives.base)
from nc_server.core.params import AxisParams
from nc_server.drives.cia402.device import COMM_ERROR_CODE, PROBE_SYNC_PULSE, Cia402Device
from nc_server.drives.cia402.image import RxImage
from nc_server.drives.cia402.objects import Mode, State
from nc_server.drives.cia402 import statemachine as sm

DT = 0.001


def _device(n: int = 1, timeout: float | None = None, **params: float) -> Cia402Device:
    d = Cia402Device(n, DT, timeout)
    for i in range(n):
        d.configure(i, AxisParams(**params))
    return d


def _rx(n: int, cw: int, pos: float = 0.0, velo: float = 0.0, mode: int = 8, probe: int = 0) -> RxImage:
    rx = RxImage.zeros(n)
    rx.controlword[:] = cw
    rx.target_position[:] = pos
    rx.target_velocity[:] = velo
    rx.mode[:] = mode
    rx.probe_function[:] = probe
    return rx


def _enable(d: Cia402Device) -> None:
    d.step(_rx(d.n, 0x06))
    d.step(_rx(d.n, 0x0F, d.position[0]))
    assert list(sm.decode(d.tx.statusword)) == [int(State.OPERATION_ENABLED)] * d.n


def test_power_up_and_csp_first_order_lag() -> None:
    d = _device(SimTimeConstant=0.01)
    assert int(d.state[0]) == int(State.SWITCH_ON_DISABLED)
    _enable(d)
    alpha = 1 - math.exp(-DT / 0.01)
    d.step(_rx(1, 0x0F, 100.0))
    assert d.tx.position_actual[0] == pytest.approx(100.0 * alpha)
    for _ in range(2000):
        d.step(_rx(1, 0x0F, 100.0))
    assert d.tx.position_actual[0] == pytest.approx(100.0, abs=1e-6)
    assert d.tx.statusword[0] & 0x1000  # drive follows


def test_not_enabled_holds() -> None:
    d = _device()
    for _ in range(10):
        d.step(_rx(1, 0x06, 50.0, 1000.0))
    assert d.tx.position_actual[0] == 0.0
    assert int(sm.decode(d.tx.statusword)[0]) == int(State.READY_TO_SWITCH_ON)


def test_csv_follows_the_target_velocity() -> None:
    d = _device(SimTimeConstant=0.002)
    _enable(d)
    for _ in range(500):
        d.step(_rx(1, 0x0F, 0.0, 200.0, mode=int(Mode.CSV)))
    assert d.tx.velocity_actual[0] == pytest.approx(200.0, rel=1e-6)
    assert d.tx.position_actual[0] == pytest.approx(200.0 * 0.5, abs=1.0)
    assert d.tx.mode_display[0] == int(Mode.CSV)


def _run_at(d: Cia402Device, velo: float, cycles: int) -> float:
    pos = float(d.position[0])
    for _ in range(cycles):
        pos += velo * DT
        d.step(_rx(1, 0x0F, pos, velo))
    return pos


def test_quick_stop_ramps_down_with_axis_dec_and_stays() -> None:
    d = _device(SimTimeConstant=0.0, AxisDec=1000.0)
    _enable(d)
    _run_at(d, 100.0, 50)
    assert d.velocity[0] == pytest.approx(100.0)
    start = float(d.position[0])
    cycles = 0
    while True:
        d.step(_rx(1, 0x0B, 0.0))  # quick stop; the target is ignored
        cycles += 1
        if d.velocity[0] == 0.0:
            break
        assert cycles < 1000
    assert int(d.state[0]) == int(State.QUICK_STOP_ACTIVE)
    assert cycles == pytest.approx(100, abs=2)  # 100 u/s at 1000 u/s^2: 0.1 s
    assert float(d.position[0]) - start == pytest.approx(100.0 ** 2 / 2000.0, rel=0.05)
    held = float(d.position[0])
    for _ in range(20):
        d.step(_rx(1, 0x0B, 0.0))
    assert float(d.position[0]) == held
    d.step(_rx(1, 0x0F, held))  # transition 16
    assert int(d.state[0]) == int(State.OPERATION_ENABLED)


def test_fault_reaction_then_fault_and_reset() -> None:
    d = _device(SimTimeConstant=0.0, AxisDec=2000.0)
    _enable(d)
    _run_at(d, 100.0, 20)
    d.inject_fault(0, 0x2310)
    d.step(_rx(1, 0x0F, 1e6))
    assert int(d.state[0]) == int(State.FAULT_REACTION_ACTIVE)
    assert int(d.tx.error_code[0]) == 0x2310
    for _ in range(200):
        d.step(_rx(1, 0x0F, 1e6))
    assert int(d.state[0]) == int(State.FAULT)
    assert d.velocity[0] == 0.0
    assert float(d.position[0]) < 10.0  # the ramp, not the target
    d.step(_rx(1, 0x80))
    assert int(d.state[0]) == int(State.SWITCH_ON_DISABLED)
    assert int(d.tx.error_code[0]) == 0


def test_a_caller_reusing_its_arrays_keeps_the_controlword_edges() -> None:
    d = _device(SimTimeConstant=0.0)
    _enable(d)
    d.inject_fault(0, 0x2310)
    rx = _rx(1, 0x00)
    for _ in range(5):
        d.step(rx)
    assert int(d.state[0]) == int(State.FAULT)
    rx.controlword[:] = 0x80  # the same arrays, written in place: still an edge 0 -> 0x80
    d.step(rx)
    assert int(d.state[0]) == int(State.SWITCH_ON_DISABLED)


def test_persistent_fault_blocks_the_reset_until_cleared() -> None:
    d = _device()
    _enable(d)
    d.inject_fault(0, 0x5000, persistent=True)
    for _ in range(3):
        d.step(_rx(1, 0x00))
    assert int(d.state[0]) == int(State.FAULT)
    d.step(_rx(1, 0x80))
    assert int(d.state[0]) == int(State.FAULT)
    d.clear_fault(0)
    d.step(_rx(1, 0x00))
    d.step(_rx(1, 0x80))
    assert int(d.state[0]) == int(State.SWITCH_ON_DISABLED)


def test_timeout_faults_with_the_comm_code_and_keeps_position() -> None:
    d = _device(timeout=0.01, SimTimeConstant=0.0, AxisDec=5000.0)
    _enable(d)
    _run_at(d, 50.0, 20)
    for k in range(9):
        d.step(None)  # the last outputs stay in effect
        assert int(d.state[0]) == int(State.OPERATION_ENABLED), k
    d.step(None)
    assert int(d.state[0]) == int(State.FAULT_REACTION_ACTIVE)
    assert int(d.tx.error_code[0]) == COMM_ERROR_CODE
    for _ in range(100):
        d.step(None)
    assert int(d.state[0]) == int(State.FAULT)
    kept = float(d.position[0])
    for _ in range(100):
        d.step(None)
    assert float(d.position[0]) == kept
    d.step(_rx(1, 0x00))  # outputs again: the cause has gone, a reset acknowledges it
    d.step(_rx(1, 0x80))
    assert int(d.state[0]) == int(State.SWITCH_ON_DISABLED)


def test_index_pulse_probe_latches_exact_positions() -> None:
    d = _device(SimTimeConstant=0.0, SimSyncPulseSpacing=1.0, SimSyncPulseOffset=0.25)
    _enable(d)
    pos, toggles, latched = 0.0, 0, []
    last = 0
    for _ in range(100):
        pos += 0.03
        d.step(_rx(1, 0x0F, pos, 30.0, probe=PROBE_SYNC_PULSE))
        st = int(d.tx.probe_status[0])
        assert st & 1
        if (st ^ last) & 0x80:
            toggles += 1
            latched.append(float(d.tx.probe_position[0]))
        last = st
    assert latched == pytest.approx([0.25, 1.25, 2.25])


def test_probe_single_mode_latches_once() -> None:
    d = _device(SimTimeConstant=0.0)
    _enable(d)
    pos = 0.0
    for _ in range(100):
        pos += 0.05
        d.step(_rx(1, 0x0F, pos, 50.0, probe=0x15))  # enabled, single, index pulse, positive edge
    assert float(d.tx.probe_position[0]) == pytest.approx(1.0)
    assert d.tx.probe_status[0] & 0x02


def test_bad_fault_arguments() -> None:
    d = _device()
    with pytest.raises(IndexError):
        d.inject_fault(3, 0x2310)
    with pytest.raises(ValueError):
        d.inject_fault(0, 0)
