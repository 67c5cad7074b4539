"""MC_TouchProbe on the CiA 402 backends: the drive's touch probe 2 (0x60B8 bits 8-13, 0x60B9, 0x60BC / 0x60BD).

* the simulated device: first-event latch of the requested edge (enabling clears the stored bits), continuous mode,
  the sensor pattern through the encoder chain (scaled, inverted, offset), commanded signals (set_probe_signal);
* NcCore on ``cia402-sim`` (no latency, and a link with one cycle of latency each way), on ``canopen`` (simulated
  slaves on python-can's virtual bus, INT32 increments): the recorded position is the sensor pattern's edge, known
  in advance, within a tolerance that fails for a latch a cycle off (100 u/s x 1 ms = 0.1 u per cycle);
* a re-armed probe never takes the latch of the session before (a stored bit still in flight).

The ``remote`` backend (nc-drive-sim over zenoh) is in tests/drives/test_remote_process.py.
"""
from __future__ import annotations

import uuid
from typing import Any

import numpy as np
import pytest

import nc_server.core  # noqa: F401  (first: nc_server.drives imports the core, which imports drives.base)
from nc_schema import CmdState, ErrorCodes as E, MC_AxisStates as S
from nc_server.core import AxisConfig, AxisParams, NcCore
from nc_server.drives.base import DriveContext
from nc_server.drives.canopen.drive import CanopenDrive
from nc_server.drives.cia402.device import (TP2_CONTINUOUS, TP2_ENABLE, TP2_NEGATIVE, TP2_POSITIVE,
                                            TP2_STATUS_ENABLED, TP2_STATUS_INPUT, TP2_STATUS_NEG_STORED,
                                            TP2_STATUS_POS_STORED, Cia402Device)
from nc_server.drives.cia402.drive import Cia402Drive
from nc_server.drives.cia402.image import ProcessDataLink, RxImage, TxImage
from nc_server.drives.cia402.sim import Cia402SimDrive, LocalLink
from znc_testing.nc_core import cmd, power, state
from znc_testing.until import step_until

DT = 0.001
PATTERN = dict(SimProbePeriod=10.0, SimProbeOffset=2.0, SimProbeWidth=3.0)  # TRUE on [2, 5) + 10 k
ACTIVE, DONE = int(CmdState.ACTIVE), int(CmdState.DONE)


# -- the device ------------------------------------------------------------------------------------------
def _device(**params: Any) -> Cia402Device:
    d = Cia402Device(1, DT)
    d.configure(0, AxisParams(SimTimeConstant=0.0, **params))
    return d


def _rx(cw: int, target: float, probe: int) -> RxImage:
    rx = RxImage.zeros(1)
    rx.controlword[:] = cw
    rx.target_position[:] = target
    rx.probe_function[:] = probe
    return rx


def _enabled(d: Cia402Device, probe: int = 0) -> None:
    for cw in (0x06, 0x07, 0x0F):
        d.step(_rx(cw, float(d.position[0]), probe))


def test_device_first_event_latch_and_re_enable() -> None:
    d = _device(**PATTERN)
    on = TP2_ENABLE | TP2_POSITIVE
    _enabled(d)
    st = int(d.step(_rx(0x0F, 1.0, on)).probe_status[0])
    assert st & TP2_STATUS_ENABLED and not st & TP2_STATUS_POS_STORED
    tx = d.step(_rx(0x0F, 3.0, on))  # passes the rising edge at 2.0
    assert int(tx.probe_status[0]) & TP2_STATUS_POS_STORED and int(tx.probe_status[0]) & TP2_STATUS_INPUT
    assert float(tx.probe2_pos[0]) == pytest.approx(2.0, abs=1e-12)
    tx = d.step(_rx(0x0F, 13.0, on))  # first event: the next rising edge (12.0) is not latched
    assert float(tx.probe2_pos[0]) == pytest.approx(2.0, abs=1e-12)
    tx = d.step(_rx(0x0F, 13.0, 0))  # off: stored bits cleared
    assert int(tx.probe_status[0]) & 0x0700 == 0
    tx = d.step(_rx(0x0F, 26.0, TP2_ENABLE | TP2_NEGATIVE))  # falling edges at 15, 25: the first
    assert int(tx.probe_status[0]) & 0x0700 == TP2_STATUS_ENABLED | TP2_STATUS_NEG_STORED
    assert float(tx.probe2_neg[0]) == pytest.approx(15.0, abs=1e-12)


def test_device_continuous_mode_latches_every_cycle_with_an_edge() -> None:
    d = _device(**PATTERN)
    _enabled(d)
    fn = TP2_ENABLE | TP2_CONTINUOUS | TP2_POSITIVE | TP2_NEGATIVE
    got = []
    for k in range(1, 41):
        tx = d.step(_rx(0x0F, k * 1.0, fn))
        got.append((float(tx.probe2_pos[0]), float(tx.probe2_neg[0])))
    assert got[-1] == (pytest.approx(32.0), pytest.approx(35.0))


@pytest.mark.parametrize("scale,inverse,offset", [(0.001, False, 0.0), (0.0005, True, 7.25), (2.0, False, -3.0)])
def test_device_pattern_through_the_encoder_chain(scale: float, inverse: bool, offset: float) -> None:
    """The pattern is in axis units on the position the encoder chain reports; 0x60BC is in increments."""
    p = AxisParams(SimTimeConstant=0.0, AxisEncoderScalingFactor=scale, AxisEncoderDirectionInverse=inverse,
                   AxisEncoderOffset=offset, **PATTERN)
    d = Cia402Device(1, DT)
    d.configure(0, p)
    drive = Cia402Drive([p], DT, LocalLink(d))  # (the NC's chain, to read the increments back)
    _enabled(d)
    u0 = drive.encoder.position(0, 0.0)
    start = 10.0 * np.floor(u0 / 10.0) + 1.0  # the next rising edge is start + 1
    d.step(_rx(0x0F, drive.encoder.increments(0, start), 0))
    tx = d.step(_rx(0x0F, drive.encoder.increments(0, start + 4.5), TP2_ENABLE | TP2_POSITIVE))
    assert int(tx.probe_status[0]) & TP2_STATUS_POS_STORED
    assert drive.encoder.position(0, float(tx.probe2_pos[0])) == pytest.approx(start + 1.0, abs=1e-9)


def test_device_commanded_signal_and_refusals() -> None:
    d = _device()
    _enabled(d)
    d.step(_rx(0x0F, 10.0, TP2_ENABLE | TP2_POSITIVE))
    d.set_probe_signal(0, True, 0.25 * DT)
    tx = d.step(_rx(0x0F, 20.0, TP2_ENABLE | TP2_POSITIVE))
    assert float(tx.probe2_pos[0]) == pytest.approx(12.5) and int(tx.probe_status[0]) & TP2_STATUS_INPUT
    with pytest.raises(ValueError):
        d.set_probe_signal(0, True, DT)
    with pytest.raises(NotImplementedError):
        _device(**PATTERN).set_probe_signal(0, True, 0.0)
    with pytest.raises(IndexError):
        d.set_probe_signal(1, True, 0.0)


# -- NcCore on cia402-sim ------------------------------------------------------------------------------
def _probe(core: NcCore, i: int = 0) -> tuple[int, int, float]:
    j = core.ncjobs[i]
    return int(j["ProbeState"]), int(j["ProbeCounter"]), float(j["RecordedPosition"])


def _moving(core: NcCore, v: float, step: Any = None) -> None:
    step = step or core.step
    power(core)
    step_until(step, lambda: state(core) == S.MC_AXISSTATE_STANDSTILL, 2000)
    assert cmd(core, "MoveVelocity", Velocity=abs(v), Direction=1 if v > 0 else 3)["error"] == 0


class DelayedLink(ProcessDataLink):
    """One cycle of latency each way (the outputs reach the device an exchange later, the inputs are a cycle old)."""

    def __init__(self, device: Cia402Device) -> None:
        self.device, self.n = device, device.n
        self._pending: RxImage | None = None
        self._last = device.tx

    def exchange(self, rx: RxImage) -> TxImage:
        out = self._last
        if self._pending is not None:
            self._last = self.device.step(self._pending)
        self._pending = rx
        return out


@pytest.mark.parametrize("latency", [False, True])
@pytest.mark.parametrize("v,edge,x", [(100.0, 0, 2.0), (100.0, 1, 5.0), (-100.0, 0, -5.0), (-100.0, 1, -8.0)])
def test_touch_probe_on_cia402_sim_records_the_pattern_edge(latency: bool, v: float, edge: int, x: float) -> None:
    p = AxisParams(**PATTERN)
    if latency:
        dev = Cia402Device(1, DT)
        dev.configure(0, p)
        drive: Cia402Drive = Cia402Drive([p], DT, DelayedLink(dev), simulated=True)
    else:
        drive = Cia402SimDrive([p], DT)
    core = NcCore([AxisConfig(1, "A1", p)], DT, drive=drive)
    _moving(core, v)
    r = cmd(core, "TouchProbe", Edge=edge)
    assert r["error"] == 0
    step_until(core.step, lambda: _probe(core)[0] != ACTIVE, 2000)
    st, cnt, pos = _probe(core)
    assert (st, cnt) == (DONE, 1)
    assert pos == pytest.approx(x, abs=1e-6)  # the exact edge (a latch a cycle off is 0.1 away)
    # re-armed: the next edge of that kind (a period on), not the stale latch of the session before
    assert cmd(core, "TouchProbe", Edge=edge)["error"] == 0
    step_until(core.step, lambda: _probe(core)[0] != ACTIVE, 2000)
    assert _probe(core) == (DONE, 2, pytest.approx(x + (10.0 if v > 0 else -10.0), abs=1e-6))


def test_touch_probe_level_and_sim_probe_signal_on_cia402_sim() -> None:
    core = NcCore([AxisConfig(1, "A1", AxisParams())], DT, drive=Cia402SimDrive([AxisParams()], DT))
    _moving(core, 100.0)
    for _ in range(200):
        core.step()
    assert cmd(core, "TouchProbe")["error"] == 0
    core.step()  # (the probe is enabled the cycle after the arming)
    a = float(core.nctoplc[0]["ActPos"])
    assert cmd(core, "SimProbeSignal", Level=True, Offset=0.0004)["error"] == 0
    core.step()
    b = float(core.nctoplc[0]["ActPos"])
    assert int(core.nctoplc[0]["StateDWord3"]) & 1
    assert _probe(core) == (DONE, 1, pytest.approx(a + 0.4 * (b - a), abs=1e-9))
    r = cmd(core, "SimProbeSignal", Level=True, Offset=0.001)
    assert r["error"] == int(E.MC_PARAMETER_NOT_CORRECT)


def test_sim_probe_signal_on_a_pattern_axis_is_refused_0x4251() -> None:
    p = AxisParams(**PATTERN)
    core = NcCore([AxisConfig(1, "A1", p)], DT, drive=Cia402SimDrive([p], DT))
    assert cmd(core, "SimProbeSignal", Level=True)["error"] == int(E.NC_FUNCTION_NOT_SUPPORTED)


# -- canopen (virtual bus) --------------------------------------------------------------------------------
SCALE = 0.0001


class _Canopen:
    def __init__(self, **params: Any) -> None:
        self.params = [AxisParams(AxisEncoderScalingFactor=SCALE, **params)]
        opts = {"simulate_slaves": True, "channel": f"test-{uuid.uuid4().hex[:10]}", "heartbeat_timeout": 1.0}
        d = CanopenDrive.from_config(self.params, DT, [{"node_id": 5}], DriveContext(options=opts))
        assert isinstance(d, CanopenDrive)
        self.drive = d
        self.core = NcCore([AxisConfig(1, "A1", self.params[0])], DT, drive=d)

    def step(self) -> None:
        self.core.step()
        assert self.drive.link.wait_answered(5.0), "the slaves did not answer a SYNC"


@pytest.mark.parametrize("v,edge,x", [(100.0, 0, 2.0), (-100.0, 1, -8.0)])
def test_touch_probe_on_canopen_records_the_pattern_edge(v: float, edge: int, x: float) -> None:
    rig = _Canopen(**PATTERN)
    try:
        core = rig.core
        _moving(core, v, rig.step)
        assert cmd(core, "TouchProbe", Edge=edge)["error"] == 0
        step_until(rig.step, lambda: _probe(core)[0] != ACTIVE, 5000)
        st, cnt, pos = _probe(core)
        assert (st, cnt) == (DONE, 1)
        assert pos == pytest.approx(x, abs=2 * SCALE)  # INT32 increments of 0.0001: an increment or two
        assert cmd(core, "TouchProbe", Edge=edge)["error"] == 0
        step_until(rig.step, lambda: _probe(core)[0] != ACTIVE, 5000)
        assert _probe(core) == (DONE, 2, pytest.approx(x + (10.0 if v > 0 else -10.0), abs=2 * SCALE))
    finally:
        rig.drive.close()


def test_sim_probe_signal_on_canopen_slaves() -> None:
    rig = _Canopen()
    try:
        core = rig.core
        _moving(core, 100.0, rig.step)
        for _ in range(100):
            rig.step()
        assert cmd(core, "TouchProbe", Edge=1)["error"] == 0
        for _ in range(5):
            rig.step()
        assert cmd(core, "SimProbeSignal", Level=True, Offset=0.0)["error"] == 0  # rising: no event for Edge=1
        for _ in range(5):
            rig.step()
        assert _probe(core)[0] == ACTIVE and int(core.nctoplc[0]["StateDWord3"]) & 1
        assert cmd(core, "SimProbeSignal", Level=False, Offset=0.0005)["error"] == 0
        step_until(rig.step, lambda: _probe(core)[0] != ACTIVE, 100)
        assert rig.drive.slaves is not None
        # the latch lies on the motor's path; the NC got it a cycle or two after the event
        st, cnt, pos = _probe(core)
        act = float(core.nctoplc[0]["ActPos"])
        assert (st, cnt) == (DONE, 1) and act - 0.5 < pos < act, (pos, act)
        assert not int(core.nctoplc[0]["StateDWord3"]) & 1
    finally:
        rig.drive.close()


@pytest.mark.parametrize("abort_first", [False, True])
def test_a_re_armed_probe_with_the_same_edge_never_takes_the_latch_in_flight(abort_first: bool) -> None:
    """MC_TouchProbe executed again while armed (or MC_AbortTrigger and MC_TouchProbe in one cycle) with the same
    edge: the device stored the old session's latch, the NC has not seen it yet (a cycle of latency); the new
    command must not complete with it but with the next edge (the NC closes probe 2's session first)."""
    p = AxisParams(**PATTERN)
    dev = Cia402Device(1, DT)
    dev.configure(0, p)
    link = DelayedLink(dev)
    drive = Cia402Drive([p], DT, link, simulated=True)
    core = NcCore([AxisConfig(1, "A1", p)], DT, drive=drive)
    _moving(core, 100.0)
    assert cmd(core, "TouchProbe", Edge=0)["error"] == 0
    step_until(core.step, lambda: bool(int(link._last.probe_status[0]) & TP2_STATUS_POS_STORED), 2000)
    # stored in the device, not yet seen by the NC
    assert not int(drive.tx.probe_status[0]) & TP2_STATUS_POS_STORED and _probe(core)[0] == ACTIVE
    old = float(drive.encoder.positions(link._last.probe2_pos)[0])
    assert (old - 2.0) / 10.0 == pytest.approx(round((old - 2.0) / 10.0), abs=1e-6)  # a pattern edge (2 + 10 k)
    if abort_first:
        assert cmd(core, "AbortTrigger")["error"] == 0
    assert cmd(core, "TouchProbe", Edge=0)["error"] == 0
    step_until(core.step, lambda: _probe(core)[0] != ACTIVE, 2000)
    st, cnt, pos = _probe(core)
    assert (st, cnt) == (DONE, 1)
    # the next rising edge of the pattern after the re-arming, not the old session's latch
    assert pos == pytest.approx(old + 10.0, abs=1e-6), (pos, old)


def test_a_drive_group_passes_the_arming_to_the_owning_part() -> None:
    from nc_server.drives.group import DriveGroup
    from nc_server.drives.sim import SimDrive

    c = Cia402SimDrive([AxisParams()] * 2, DT)
    g = DriveGroup(3, DT, [(SimDrive([AxisParams()], DT), np.array([1])), (c, np.array([0, 2]))])
    g.arm_probe(np.array([2, 1]))  # (SimDrive: the default no-op)
    assert c._tp_rearm.tolist() == [False, True]
