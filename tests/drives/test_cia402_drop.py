"""A drive that leaves Operation enabled by itself shortly after the enable is a drive error (0x4650), whatever the
link's latency: the NC judges the statusword by the cycle it answers (``TxImage.rx_cycle``), not by how long ago it
sent the enable. Before: a drop within ``max_age + 1`` cycles of the enable went unnoticed and the NC switched the
drive on again by itself."""
from __future__ import annotations

from collections import deque
from typing import Any

import numpy as np
import pytest

import nc_server.core  # noqa: F401  (first: nc_server.drives imports the core, which imports drives.base)
from nc_schema import StateDWord
from nc_server.core import AxisConfig, AxisParams, NcCore
from nc_server.drives.cia402.device import Cia402Device
from nc_server.drives.cia402.drive import Cia402Drive
from nc_server.drives.cia402.image import ProcessDataLink, RxImage, TxImage
from nc_server.drives.cia402.objects import State
from nc_server.drives.cia402.sim import Cia402SimDrive
from znc_testing.nc_core import cmd, power, run_until

DT = 0.001
LOOP = int(StateDWord.ControlLoopClosed)


class LateLink(ProcessDataLink):
    """A link with latency: outputs reach the device ``out_delay`` exchanges later, its inputs come back
    ``in_delay`` exchanges later (age ``in_delay``), each stamped by the device with the outputs they answer."""

    def __init__(self, device: Cia402Device, out_delay: int, in_delay: int, stamped: bool = True) -> None:
        self.device, self.n = device, device.n
        self._rx: deque[RxImage | None] = deque([None] * out_delay)
        self._tx: deque[TxImage] = deque([device.tx] * in_delay)
        self.in_delay, self.stamped = in_delay, stamped

    def exchange(self, rx: RxImage) -> TxImage:
        self._rx.append(rx)
        self._tx.append(self.device.step(self._rx.popleft()))
        out = self._tx.popleft()
        extra: dict[str, Any] = {} if self.stamped else {"rx_cycle": np.zeros(0, dtype=np.int64)}
        return TxImage(**{**vars(out), "age": np.full(self.n, self.in_delay, dtype=np.int64), **extra})


def _rig(out_delay: int, in_delay: int, max_age: int, stamped: bool = True,
         local: bool = False) -> tuple[NcCore, Cia402Device, Cia402Drive]:
    p = [AxisParams()]
    if local:
        drive: Cia402Drive = Cia402SimDrive(p, DT, max_age=max_age)
        dev = drive.device  # type: ignore[attr-defined]
    else:
        dev = Cia402Device(1, DT)
        dev.configure(0, p[0])
        drive = Cia402Drive(p, DT, LateLink(dev, out_delay, in_delay, stamped), simulated=True, max_age=max_age)
    core = NcCore([AxisConfig(1, "A1", p[0])], DT, drive=drive)
    for _ in range(out_delay + in_delay + 3):
        core.step()
    return core, dev, drive


def _err(core: NcCore) -> int:
    return int(core.nctoplc[0]["ErrorCode"])


# (cia402-sim: zero latency, max_age 3; remote: a round trip of 2 cycles at its default max_age 50; 2 + 2 cycles at
# max_age 10; a round trip longer than max_age + 1 (inputs as old as accepted), where the old rule raised a false
# 0x4650 on a short MC_Power off/on)
LATENCIES = [(0, 0, 3, True), (1, 1, 50, False), (2, 2, 10, False), (2, 3, 3, False)]


@pytest.mark.parametrize("out_delay,in_delay,max_age,local", LATENCIES)
@pytest.mark.parametrize("after", [0, 1, 2])
def test_a_drop_right_after_the_enable_is_0x4650_and_the_nc_does_not_ramp(
        out_delay: int, in_delay: int, max_age: int, local: bool, after: int) -> None:
    core, dev, drive = _rig(out_delay, in_delay, max_age, local=local)
    power(core)
    run_until(core, lambda: bool(drive.following[0]), 50)  # the NC sees Operation enabled ...
    assert cmd(core, "MoveVelocity", Velocity=200.0, Direction=1)["error"] == 0
    for _ in range(after):
        core.step()
    assert int(dev.state[0]) == int(State.OPERATION_ENABLED)
    dev.state[0] = int(State.SWITCH_ON_DISABLED)  # ... and the drive drops out at once (e.g. its safe torque off)
    run_until(core, lambda: _err(core) == 0x4650, 4 * (out_delay + in_delay) + 10)
    assert drive.device_error[0] and not drive.following[0]
    for _ in range(30):  # the NC does not switch it on again by itself, and runs no ramp: SetPos follows ActPos
        core.step()
        assert int(dev.state[0]) != int(State.OPERATION_ENABLED) and _err(core) == 0x4650
        assert not int(core.nctoplc[0]["StateDWord"]) & LOOP
    r = core.nctoplc[0]
    assert float(r["SetPos"]) == pytest.approx(float(r["ActPos"])) and float(r["SetVelo"]) == 0.0


def test_a_link_without_stamps_still_sees_a_drop_once_the_enable_is_older_than_its_latency() -> None:
    core, dev, drive = _rig(1, 1, 3, stamped=False)
    power(core)
    run_until(core, lambda: bool(drive.following[0]), 50)
    for _ in range(drive.max_age + 3):
        core.step()
    dev.state[0] = int(State.SWITCH_ON_DISABLED)
    run_until(core, lambda: _err(core) == 0x4650, 20)


@pytest.mark.parametrize("out_delay,in_delay,max_age,local", LATENCIES[1:])
def test_a_short_power_off_and_on_is_still_no_drive_error(out_delay: int, in_delay: int, max_age: int,
                                                         local: bool) -> None:
    """The statusword showing the Shutdown of a short MC_Power off/on answers the Shutdown's cycle: no drop."""
    core, dev, drive = _rig(out_delay, in_delay, max_age)
    power(core)
    run_until(core, lambda: bool(drive.following[0]), 50)
    for off in (1, 2):
        power(core, ctrl=0)
        for _ in range(off):
            core.step()
        power(core)
        states = []
        for _ in range(30):
            core.step()
            states.append(int(drive.state[0]))
            assert _err(core) == 0 and not drive.device_error[0], states
        assert int(State.READY_TO_SWITCH_ON) in states and states[-1] == int(State.OPERATION_ENABLED)


def test_the_remote_link_stamps_each_axis_with_its_hosts_echo() -> None:
    """RemoteLink: ``rx_cycle`` per axis is the NC cycle its host echoed (``tx`` ``rx_cycle``), kept while no newer
    inputs arrive."""
    from nc_server.drives.remote import wire
    from nc_server.drives.remote.link import HostSlots, RemoteLink

    class Sample:
        def __init__(self, b: bytes) -> None:
            self.payload = type("P", (), {"to_bytes": lambda _self: b})()

    class Sub:
        def __init__(self) -> None:
            self.q: list[Sample] = []

        def try_recv(self) -> Sample | None:
            return self.q.pop(0) if self.q else None

    link = RemoteLink("nc1", 3, [HostSlots("a", (0, 2), (1, 3)), HostSlots("b", (1,), (2,))], None)
    subs = [Sub(), Sub()]
    link._tx_subs, link._live_sub, link._pubs, link._ready = subs, Sub(), [], True
    link._send = lambda rx: None  # type: ignore[method-assign]
    dev2, dev1 = Cia402Device(2, DT), Cia402Device(1, DT)
    subs[0].q.append(Sample(wire.encode_tx(dev2.tx, 5, 17)))
    tx = link.exchange(RxImage.zeros(3))
    assert tx.rx_cycle.tolist() == [17, 0, 17]
    subs[1].q.append(Sample(wire.encode_tx(dev1.tx, 6, 20)))
    tx = link.exchange(RxImage.zeros(3))
    assert tx.rx_cycle.tolist() == [17, 20, 17] and tx.age.tolist() == [1, 0, 1]


class LaggingLink(ProcessDataLink):
    """Zero transport latency, honest stamps, but a drive whose state machine runs ``lag`` exchanges behind its
    process data (a slower task): it acts on the controlword of ``lag`` cycles ago, so it shows Operation enabled
    for ``lag - 1`` cycles after the statusword stamped with a Shutdown's cycle."""

    def __init__(self, device: Cia402Device, lag: int) -> None:
        self.device, self.n = device, device.n
        self._cw: deque[np.ndarray] = deque([np.zeros(device.n, dtype=np.uint16)] * lag)

    def exchange(self, rx: RxImage) -> TxImage:
        self._cw.append(rx.controlword)
        return self.device.step(RxImage(self._cw.popleft(), rx.mode, rx.target_position, rx.target_velocity,
                                        rx.probe_function, rx.cycle))


def _lagging(lag: int, margin: int) -> tuple[NcCore, Cia402Device, Cia402Drive]:
    p = [AxisParams()]
    dev = Cia402Device(1, DT)
    dev.configure(0, p[0])
    drive = Cia402Drive(p, DT, LaggingLink(dev, lag), simulated=True, reaction_margin=margin)
    core = NcCore([AxisConfig(1, "A1", p[0])], DT, drive=drive)
    core.step()
    power(core)
    run_until(core, lambda: bool(drive.following[0]), 50)
    for _ in range(lag + 5):
        core.step()
    return core, dev, drive


def _off_on(core: NcCore, drive: Cia402Drive, off: int) -> list[int]:
    power(core, ctrl=0)
    for _ in range(off):
        core.step()
    power(core)
    errors = []
    for _ in range(40):
        core.step()
        errors.append(_err(core))
    assert bool(drive.following[0])
    return errors


# (lag 1 with margin 0: the statusword stamped with the Shutdown's own cycle still shows Operation enabled -- the
# comparison is strictly "after" (>), with >= it confirmed and then saw a false drop; lag 3 (Operation enabled for
# 2 cycles after the Shutdown's stamp) needs the margin 2, CANopen's default)
@pytest.mark.parametrize("lag,margin", [(1, 0), (2, 1), (3, 2)])
@pytest.mark.parametrize("off", [1, 2])
def test_a_drive_that_reacts_late_within_its_margin_gives_no_false_drop(lag: int, margin: int, off: int) -> None:
    core, dev, drive = _lagging(lag, margin)
    assert _off_on(core, drive, off) == [0] * 40


def test_without_the_margin_a_late_drive_shows_a_false_drop() -> None:
    """(What the margin is for: the same drive with margin 0.)"""
    core, dev, drive = _lagging(3, 0)
    assert 0x4650 in _off_on(core, drive, 1)


@pytest.mark.parametrize("lag,margin", [(1, 0), (3, 2)])
def test_a_drop_after_the_margin_is_still_0x4650(lag: int, margin: int) -> None:
    core, dev, drive = _lagging(lag, margin)
    dev.state[0] = int(State.SWITCH_ON_DISABLED)  # it drops out by itself
    run_until(core, lambda: _err(core) == 0x4650, 20)
    for _ in range(20):
        core.step()
        assert int(dev.state[0]) != int(State.OPERATION_ENABLED)


def test_reaction_margin_options() -> None:
    from nc_server.core.params import ConfigError
    from nc_server.drives.base import DriveContext
    from nc_server.drives.canopen.drive import DEFAULT_REACTION_MARGIN, _bus_options
    from nc_server.drives.remote.config import parse_options

    assert DEFAULT_REACTION_MARGIN == 2 and _bus_options({})[3] == 2 and _bus_options({"reaction_margin": 0})[3] == 0
    assert parse_options({}).reaction_margin == 0 and parse_options({"reaction_margin": 3}).reaction_margin == 3
    d = Cia402SimDrive.from_config([AxisParams()], DT, [{}], DriveContext(options={"reaction_margin": 1}))
    assert d.reaction_margin == 1 and Cia402SimDrive([AxisParams()], DT).reaction_margin == 0
    for bad in (-1, 1.5, True, 10_000):
        with pytest.raises(ConfigError, match="reaction_margin"):
            Cia402SimDrive.from_config([AxisParams()], DT, [{}], DriveContext(options={"reaction_margin": bad}))
        with pytest.raises(ConfigError, match="drives.canopen.reaction_margin"):
            _bus_options({"reaction_margin": bad})
        with pytest.raises(ConfigError, match="drives.remote.reaction_margin"):
            parse_options({"reaction_margin": bad})
