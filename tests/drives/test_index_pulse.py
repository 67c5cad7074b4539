"""The index (sync) pulse crossing: one function (encoder.pulse_passed) for SimDrive's latch and the simulated
CiA 402 drive's touch probe."""
from __future__ import annotations

import math

import numpy as np

from nc_server.core.params import AxisParams
from nc_server.drives.cia402.device import PROBE_SYNC_PULSE, Cia402Device
from nc_server.drives.cia402.image import RxImage
from nc_server.drives.cia402.objects import CMD_ENABLE_OPERATION, CMD_SHUTDOWN, CMD_SWITCH_ON
from nc_server.drives.encoder import pulse_passed
from nc_server.drives.sim import SimDrive


def _one(a: float, b: float, spacing: float = 1.0, offset: float = 0.0) -> float:
    return float(pulse_passed(np.array([a]), np.array([b]), np.array([spacing]), np.array([offset]))[0])


def test_the_crossing_rule() -> None:
    assert _one(0.2, 1.7) == 1.0                      # one pulse passed moving up
    assert _one(0.2, 2.7) == 2.0                      # the last one passed counts
    assert _one(1.7, 0.2) == 1.0                      # moving down
    assert _one(2.7, 0.2) == 1.0                      # moving down: the last one is the lower
    assert math.isnan(_one(1.0, 1.5))                 # exactly at the start: passed the cycle before
    assert _one(0.5, 1.0) == 1.0                      # exactly at the end: passed now
    assert math.isnan(_one(0.2, 0.8))                 # none between
    assert math.isnan(_one(0.5, 0.5))                 # standstill
    assert _one(0.0, 6.9, spacing=5.0, offset=2.0) == 2.0
    assert _one(0.0, 7.5, spacing=5.0, offset=2.0) == 7.0


def test_sim_drive_and_cia402_device_latch_the_same_pulse() -> None:
    """Same parameters, same motion: SimDrive's latch [u] and the device's probe [inc -> u] agree."""
    p = AxisParams.from_mapping({"SimSyncPulseSpacing": 0.4, "SimSyncPulseOffset": 0.15,
                                 "AxisEncoderScalingFactor": 0.001, "SimTimeConstant": 0.0})
    sim = SimDrive([p], 0.001)
    dev = Cia402Device(1, 0.001)
    dev.configure(0, p)
    rx = RxImage.zeros(1)
    rx.probe_function[:] = PROBE_SYNC_PULSE
    for cw in (CMD_SHUTDOWN, CMD_SWITCH_ON, CMD_ENABLE_OPERATION):
        rx.controlword[:] = cw
        dev.step(rx)
    latched_sim, latched_dev = [], []
    last_toggle = int(dev.tx.probe_status[0]) & 0x80
    for k in range(1, 40):  # 0.037 u per cycle, up: passes 0.15, 0.55, 0.95, 1.35
        target = 0.037 * k
        prev = sim.act_pos.copy()
        sim.step(np.array([True]), np.array([target]), np.zeros(1), np.zeros(1))
        x = float(sim.latch_sync_pulse(np.array([0]), prev)[0])
        if not math.isnan(x):
            latched_sim.append(round(x, 9))
        rx.target_position[:] = target / 0.001
        tx = dev.step(rx)
        if (int(tx.probe_status[0]) & 0x80) != last_toggle:
            last_toggle = int(tx.probe_status[0]) & 0x80
            latched_dev.append(round(float(tx.probe_position[0]) * 0.001, 9))
    assert latched_sim == [0.15, 0.55, 0.95, 1.35]
    assert latched_dev == latched_sim
