"""A standby NC's takeover starts from the drives' state now, not from its drive object's state of when it last
exchanged (at its construction): HotStandby._become_active resyncs the real drive from the link's newest inputs
before the first step (DriveABC.resync). In process: one simulated CiA 402 device, the active NC's link driving it,
the standby's link reading it only (a drive host refusing the standby's epoch 0) until the takeover."""
from __future__ import annotations

import time
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

import nc_server.core  # noqa: F401  (first: nc_server.drives imports the core, which imports drives.base)
from nc_server.core import AxisConfig, AxisParams, NcCore
from nc_server.drives.cia402.device import Cia402Device
from nc_server.drives.cia402.drive import Cia402Drive
from nc_server.drives.cia402.image import ProcessDataLink, RxImage, TxImage
from nc_server.drives.cia402.objects import State
from nc_server.drives.group import DriveGroup
from nc_server.server.replication import CoreRecorder, snapshot
from nc_server.server.standby import HotStandby
from znc_testing.nc_core import cmd, power

DT = 0.001
SCALE = 0.01  # [u/inc]
VELO = 100.0  # [u/s]


class HostLink(ProcessDataLink):
    """A drive host's devices as one NC's link sees them: the outputs are applied only while ``driving`` (a host
    follows the active NC's epoch only), the newest inputs are there all the time."""

    def __init__(self, device: Cia402Device, driving: bool) -> None:
        self.device, self.n, self.driving = device, device.n, driving
        self.sent: list[RxImage] = []

    def exchange(self, rx: RxImage) -> TxImage:
        if not self.driving:
            return self.device.tx
        self.sent.append(rx)
        return self.device.step(rx)

    def peek(self) -> TxImage:
        return self.device.tx


def _standby(core: NcCore) -> HotStandby:
    """A HotStandby around ``core`` with the server parts _become_active touches (no zenoh: no session)."""
    srv: Any = SimpleNamespace(core=CoreRecorder(core), handler=SimpleNamespace(cache=SimpleNamespace(journal=None)),
                               transport=SimpleNamespace(instance="i"), config=SimpleNamespace(name="nc1", cycle_time=DT),
                               claims=SimpleNamespace(rebase=lambda now: None),
                               became_active=lambda now, serve=True: None)
    return HotStandby(srv, SimpleNamespace(node="b", takeover_cycles=10, catch_up_ms=0, start="standby"))


@pytest.mark.parametrize("built", ["before", "after"])  # the standby's drive built before / after the active NC's
@pytest.mark.parametrize("group", [False, True])
def test_a_takeover_mid_move_continues_from_the_drives_state(built: str, group: bool) -> None:
    p = AxisParams(AxisEncoderScalingFactor=SCALE)
    dev = Cia402Device(1, DT)
    dev.configure(0, p)
    link_a, link_b = HostLink(dev, True), HostLink(dev, False)
    axes = [AxisConfig(1, "X", p)]

    def drive(link: HostLink) -> Any:
        d = Cia402Drive([p], DT, link, simulated=True)
        return DriveGroup(1, DT, [(d, np.array([0]))]) if group else d

    if built == "before":  # the standby's drive saw Switch on disabled (old state: a Shutdown at the takeover)
        drive_b = drive(link_b)
        drive_a = drive(link_a)
    else:  # it saw Ready to switch on at position 0 (old state: 0x000F with the old target, a jump)
        drive_a = drive(link_a)
        drive_b = drive(link_b)
    act = CoreRecorder(NcCore(axes, DT, drive=drive_a))
    hs = _standby(NcCore(axes, DT, drive=drive_b))
    hs.follower.load(snapshot(act))
    power(act)  # type: ignore[arg-type]
    for _ in range(5):
        act.step()
        assert hs.follower.apply(act.take())
    assert int(dev.state[0]) == int(State.OPERATION_ENABLED)
    assert cmd(act, "MoveAbsolute", Position=50.0, Velocity=VELO, Acceleration=1000.0, Deceleration=1000.0,  # type: ignore[arg-type]
               Jerk=10000.0)["error"] == 0
    for _ in range(200):  # mid move at full speed
        act.step()
        assert hs.follower.apply(act.take())
    last = link_a.sent[-1]
    for _ in range(3):  # the active NC is gone; the drive holds its last target
        dev.step(None)
    hs.synced_once, hs._last_log = True, time.monotonic()
    hs._become_active(time.monotonic())
    assert hs.role == "active"
    link_b.driving = True
    for k in range(800):
        hs.rec.step()
        hs.rec.take()
        if k == 0:
            first = link_b.sent[0]
            assert int(first.controlword[0]) == 0x000F  # (was 0x0006: Shutdown, torque off for a cycle)
            step = abs(float(first.target_position[0]) - float(last.target_position[0])) * SCALE
            assert step <= 2 * VELO * DT + 1e-9, step  # (was a jump to the old target)
        assert int(link_b.sent[-1].controlword[0]) == 0x000F
        assert int(dev.state[0]) == int(State.OPERATION_ENABLED)
        assert int(hs.core.nctoplc[0]["ErrorCode"]) == 0
    targets = np.array([float(r.target_position[0]) for r in link_b.sent]) * SCALE
    assert np.abs(np.diff(targets)).max() <= VELO * DT + 1e-9
    assert float(hs.core.nctoplc[0]["SetPos"]) == pytest.approx(50.0)


def test_a_latched_drive_error_is_kept_over_a_takeover() -> None:
    """A drive that left Operation enabled under the lost NC (its 0x4650, replicated as the standby's device_error)
    is not enabled again by the new active NC before MC_Reset."""
    p = AxisParams()
    dev = Cia402Device(1, DT)
    dev.configure(0, p)
    link = HostLink(dev, False)
    drive = Cia402Drive([p], DT, link, simulated=True)
    dev.state[0] = int(State.SWITCH_ON_DISABLED)
    drive.resync(np.array([True]))
    assert drive.device_error[0] and not drive.following[0]
    link.driving = True
    for _ in range(5):
        drive.step(np.array([True]), np.zeros(1), np.zeros(1), np.zeros(1))
        assert int(link.sent[-1].controlword[0]) == 0x0000 or int(link.sent[-1].controlword[0]) & 0xF != 0xF
    assert int(dev.state[0]) != int(State.OPERATION_ENABLED) and drive.device_error[0]
    drive.reset(np.array([0]))
    for _ in range(5):
        drive.step(np.array([True]), np.zeros(1), np.zeros(1), np.zeros(1))
    assert int(dev.state[0]) == int(State.OPERATION_ENABLED) and not drive.device_error[0]


def test_the_remote_link_peeks_without_sending() -> None:
    """RemoteLink.peek: the hosts' newest inputs (their subscriptions keep receiving on a standby), nothing sent."""
    from nc_server.drives.remote import wire
    from nc_server.drives.remote.link import HostSlots, RemoteLink

    class Sample:
        def __init__(self, b: bytes) -> None:
            self.payload = SimpleNamespace(to_bytes=lambda: b)

    class Sub:
        def __init__(self) -> None:
            self.q: list[Any] = []

        def try_recv(self) -> Any:
            return self.q.pop(0) if self.q else None

    link = RemoteLink("nc1", 1, [HostSlots("a", (0,), (1,))], None)
    sub = Sub()
    link._tx_subs, link._live_sub, link._pubs, link._ready = [sub], Sub(), [], True
    link._host_alive[:] = True  # (its liveliness token is there)
    sent: list[RxImage] = []
    link._send = sent.append  # type: ignore[method-assign,assignment]
    dev = Cia402Device(1, DT)
    rx = RxImage.zeros(1)
    rx.controlword[:] = 0x0006
    dev.step(rx)
    rx.controlword[:] = 0x000F
    rx.target_position[:] = 1234.0
    rx.cycle = 4711
    for _ in range(3):
        dev.step(rx)
    sub.q.append(Sample(wire.encode_tx(dev.tx, 9, 4711, 3)))
    tx = link.peek()
    assert not sent and int(tx.statusword[0]) & 0x6F == 0x27 and tx.rx_cycle.tolist() == [4711]
    assert tx.age.tolist() == [0] and link.round_trip.tolist() == [-1] and link.host_epoch == 3
    drive = Cia402Drive([AxisParams()], DT, link)
    sent.clear()
    sub.q.append(Sample(wire.encode_tx(dev.tx, 10, 4711, 3)))
    drive.resync()
    assert not sent and drive.following[0] and drive._cycle >= 4711
    assert float(drive._pos_inc[0]) == pytest.approx(float(dev.position[0]))


def test_cia402_sim_resyncs_from_its_device() -> None:
    """cia402-sim (LocalLink.peek): the device's last inputs; a drive object with a stale state adopts them."""
    from nc_server.drives.cia402.sim import Cia402SimDrive

    d = Cia402SimDrive([AxisParams()], DT)
    on = np.array([True])
    for k in range(20):
        d.step(on, np.full(1, k * 0.01), np.zeros(1), np.zeros(1))
    assert d.following[0]
    d.state[:] = int(State.SWITCH_ON_DISABLED)  # (as a standby's object that last exchanged long ago)
    d.following = np.zeros(1, dtype=bool)
    d._pos_inc = np.zeros(1)
    d.resync()
    assert d.following[0] and d._confirmed[0] and float(d._pos_inc[0]) == pytest.approx(float(d.device.position[0]))
    d.step(on, np.full(1, 0.2), np.zeros(1), np.zeros(1))
    assert int(d.controlword[0]) == 0x000F and d.following[0]
