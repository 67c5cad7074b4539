"""Unmodified pyads (AdsLib) against AdsServer + FakeDevice in this process (server in its own thread).

Each test has its own 127.0.0.x (AdsLib always connects to 48898) and net id; notifications are
deleted before close() (PyadsSession), one Connection per AMS port.
"""
from __future__ import annotations

import ctypes
import struct
import threading
import time

import pytest

pyads = pytest.importorskip("pyads")

from nc_ads import ams, server  # noqa: E402
from nc_ads.server import AdsServer, WritePolicy  # noqa: E402
from nc_ads.testing import FakeDevice  # noqa: E402
from znc_testing import wait_until  # noqa: E402

LREAL = pyads.PLCTYPE_LREAL


def test_read_state_and_device_info(ads_server: AdsServer, pyads_session) -> None:
    plc = pyads_session(ads_server).open(501)
    assert plc.read_state() == (5, 0)
    name, version = plc.read_device_info()
    assert name == "FakeNC" and (version.version, version.revision, version.build) == (3, 1, 4024)


@pytest.mark.parametrize("pool", [False, True], ids=["inline", "pool"])
def test_read_write_and_by_name(ads_server: AdsServer, fake_device: FakeDevice, pyads_session, pool: bool) -> None:
    fake_device.inline_off = pool
    plc = pyads_session(ads_server).open(501)
    assert plc.read(0x4001, 0x27, LREAL) == 1234.5
    plc.write(0x4001, 0x27, 42.25, LREAL)
    assert fake_device.value(0x4001, 0x27) == struct.pack("<d", 42.25)
    assert plc.read(0x4001, 0x01, pyads.PLCTYPE_UDINT) == 1
    assert plc.read_by_name("MAIN.fVelo", LREAL) == 42.25           # handle by name, value by handle
    assert plc.read_by_name("MAIN.fVelo") == 42.25                  # SYM_INFOBYNAMEEX picks the type
    plc.write_by_name("MAIN.fVelo", 7.5, LREAL)
    assert plc.read(0x4001, 0x27, LREAL) == 7.5
    assert plc.read_by_name("MAIN.sName", pyads.PLCTYPE_STRING) == "Axis 1"
    plc.write_by_name("MAIN.sName", "X-Achse", pyads.PLCTYPE_STRING)
    assert plc.read_by_name("MAIN.sName", pyads.PLCTYPE_STRING) == "X-Achse"
    raw = plc.read(0x4101, 0, ctypes.c_ubyte * 256, return_ctypes=True)
    assert len(bytes(raw)) == 256


@pytest.mark.parametrize("op,code", [
    (lambda p: p.read(0x4999, 0, LREAL), 0x702),
    (lambda p: p.read(0x4001, 0x99, LREAL), 0x703),
    (lambda p: p.write(0x4101, 0, bytes(256), ctypes.c_ubyte * 256), 0x704),
    (lambda p: p.read(0x4001, 0x27, pyads.PLCTYPE_ARR_LREAL(2)), 0x705),
    (lambda p: p.read_by_name("MAIN.nothing", LREAL), 0x710),
    (lambda p: p.write(0x4001, 0x01, 5, pyads.PLCTYPE_UDINT), 0x704),
    (lambda p: p.read(0x4002, 0, LREAL), 0x4358),          # an NC code passes through
], ids=["0x702", "0x703", "0x704", "0x705", "0x710", "0x704-ro", "nc-code"])
def test_ads_errors_arrive_as_ADSError(ads_server: AdsServer, fake_device: FakeDevice, pyads_session,
                                       op, code: int) -> None:
    fake_device.errors[(0x4002, 0)] = 0x4358
    plc = pyads_session(ads_server).open(501)
    with pytest.raises(pyads.ADSError) as err:
        op(plc)
    assert err.value.err_code == code
    assert plc.read(0x4001, 0x27, LREAL) == 1234.5      # the stream stays in sync (pitfall 1), nothing changed


def test_wrong_net_id_and_port(ads_server: AdsServer, pyads_session) -> None:
    s = pyads_session(ads_server)
    with pytest.raises(pyads.ADSError) as err:
        s.open(501, net_id="1.2.3.4.1.1").read_state()
    assert err.value.err_code == 7
    with pytest.raises(pyads.ADSError) as err:
        s.open(851).read_state()
    assert err.value.err_code == 6
    assert s.open(500).read_state() == (5, 0)


def test_write_policy_refuses_with_0x723(start_ads, fake_device: FakeDevice, pyads_session) -> None:
    srv = start_ads(write_policy=WritePolicy(["10.0.0.0/8", "9.9.9.9.1.1"]))
    plc = pyads_session(srv).open(501)
    with pytest.raises(pyads.ADSError) as err:
        plc.write(0x4001, 0x27, 1.0, LREAL)
    assert err.value.err_code == 0x723
    with pytest.raises(pyads.ADSError) as err:
        plc.write_by_name("MAIN.fVelo", 1.0, LREAL)
    assert err.value.err_code == 0x723
    assert plc.read(0x4001, 0x27, LREAL) == 1234.5 and fake_device.writes == []


class Collector:
    def __init__(self, plc, plc_type) -> None:
        self.plc, self.type = plc, plc_type
        self.sizes: list[int] = []
        self.values: list = []
        self.lock = threading.Lock()

    def __call__(self, notification, name) -> None:
        size = notification.contents.cbSampleSize
        _, _, value = self.plc.parse_notification(notification, self.type)
        with self.lock:
            self.sizes.append(size)
            self.values.append(value)

    def count(self) -> int:
        with self.lock:
            return len(self.values)


def test_notification_on_change_initial_value_then_one_per_write(ads_server: AdsServer, pyads_session) -> None:
    s = pyads_session(ads_server)
    plc = s.open(501)
    writer = s.open(500)          # writes through another AMS port (one request in flight per port)
    got = Collector(plc, LREAL)
    attr = pyads.NotificationAttrib(8, pyads.constants.ADSTRANS_SERVERONCHA, 0, 10)
    h = plc.add_device_notification((0x4001, 0x27), attr, got)
    assert wait_until(lambda: got.count() >= 1)
    for v in (1.0, 2.0, 3.0):
        writer.write(0x4001, 0x27, v, LREAL)
        assert wait_until(lambda: got.values[-1] == v), got.values
    n = got.count()
    time.sleep(0.1)                # nothing more while the value stays
    assert got.count() == n
    plc.del_device_notification(*h)
    # the initial value may come twice (sent once more after 1 s unchanged, against the first-sample race)
    collapsed = [v for k, v in enumerate(got.values) if k == 0 or v != got.values[k - 1]]
    assert collapsed == [1234.5, 1.0, 2.0, 3.0] and got.values[1:].count(1234.5) <= 1 and set(got.sizes) == {8}


def test_notification_server_cycle_full_struct_and_by_name(ads_server: AdsServer, fake_device: FakeDevice,
                                                           pyads_session) -> None:
    s = pyads_session(ads_server)
    plc = s.open(501)
    plc500 = s.open(500)
    cyc = Collector(plc, ctypes.c_ubyte * 256)
    attr = pyads.NotificationAttrib(256, pyads.constants.ADSTRANS_SERVERCYCLE, 0, 10)
    h1 = plc.add_device_notification((0x4101, 0), attr, cyc)
    pos = Collector(plc500, LREAL)                      # port 500: samples must come from :500 (pitfall 3)
    h2 = plc500.add_device_notification((0x4101, 0x0A), pyads.NotificationAttrib(8, 4, 0, 10), pos)
    velo = Collector(plc, LREAL)
    h3 = plc.add_device_notification("MAIN.fVelo", pyads.NotificationAttrib(8, 4, 0, 10), velo)
    for _ in range(10):
        fake_device.step()
        time.sleep(0.03)
    # on a loaded machine steps may fall into one server tick: only the last value is sure to come
    assert wait_until(lambda: cyc.count() >= 20 and pos.count() >= 2 and pos.values[-1] == 10.0
                      and velo.count() >= 1), (cyc.count(), pos.values, velo.count())
    for h, p in ((h1, plc), (h2, plc500), (h3, plc)):
        p.del_device_notification(*h)
    assert set(cyc.sizes) == {256} and set(pos.sizes) == {8} and velo.values[0] == 1234.5
    assert pos.values == sorted(pos.values)
    assert wait_until(lambda: ads_server.subscription_count() == 0)


def test_sum_read_and_write_over_the_symbol_table(ads_server: AdsServer, fake_device: FakeDevice,
                                                  pyads_session, monkeypatch: pytest.MonkeyPatch) -> None:
    counts: list[int] = []
    orig = ads_server.dispatcher._sum

    def spy(device, group, count, *a):  # type: ignore[no-untyped-def]
        counts.append(count)
        return orig(device, group, count, *a)
    monkeypatch.setattr(ads_server.dispatcher, "_sum", spy)
    plc = pyads_session(ads_server).open(501)
    names = [f"GVL.v{i}" for i in range(600)]
    values = plc.read_list_by_name(names)                 # pyads splits: 500 + 100
    assert values == {n: 1.5 * i for i, n in enumerate(names)}
    assert counts == [500, 100]
    counts.clear()
    result = plc.write_list_by_name({n: -float(i) for i, n in enumerate(names[:500])})
    assert counts == [500] and set(result.values()) == {"no error"}
    assert [struct.unpack("<d", fake_device.value(0x4002, 8 * i))[0] for i in range(500)] == \
        [-float(i) for i in range(500)]
    # a sum write with a read-only entry: its own error, the others written
    result = plc.write_list_by_name({"MAIN.nAxisId": 9, "GVL.v0": 11.0})
    assert result["GVL.v0"] == "no error" and result["MAIN.nAxisId"] != "no error"
    assert plc.read(0x4002, 0, LREAL) == 11.0 and plc.read(0x4001, 1, pyads.PLCTYPE_UDINT) == 1
    # more than 500 sub-commands in one request: refused as a whole
    with pytest.raises(pyads.ADSError) as err:
        plc.read_list_by_name(names[:501], ads_sub_commands=501)
    assert err.value.err_code == 0x705
    assert server.MAX_SUM_COMMANDS == 500


@pytest.mark.parametrize("pool", [False, True], ids=["inline", "pool"])
def test_concurrent_connections_share_the_socket(ads_server: AdsServer, fake_device: FakeDevice, pyads_session,
                                                 pool: bool) -> None:
    fake_device.inline_off = pool
    s = pyads_session(ads_server)
    conns = [s.open(501) for _ in range(4)]     # four AMS ports on one TCP connection
    errors: list[str] = []

    def work(k: int, plc) -> None:
        for i in range(200):
            idx = (k * 200 + i) % 600
            v = plc.read(0x4002, 8 * idx, LREAL)
            if v != 1.5 * idx:
                errors.append(f"{k}: {idx} -> {v}")
    threads = [threading.Thread(target=work, args=(k, c)) for k, c in enumerate(conns)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=120)
    assert not errors and ads_server.connection_count == 1


CHILD = """
import sys, time, pyads
net_id, host = sys.argv[1], sys.argv[2]
plc = pyads.Connection(net_id, 501, host)
plc.open()
attr = pyads.NotificationAttrib(256, pyads.constants.ADSTRANS_SERVERCYCLE, 0, 10)
plc.add_device_notification((0x4101, 0), attr, lambda n, name: None)
plc.add_device_notification("MAIN.fVelo", pyads.NotificationAttrib(8, 4, 0, 10), lambda n, name: None)
print("ready", flush=True)
time.sleep(120)
"""


def test_a_killed_pyads_client_frees_its_notifications(ads_server: AdsServer, fake_device: FakeDevice) -> None:
    import os
    import signal
    import subprocess
    import sys

    child = subprocess.Popen([sys.executable, "-c", CHILD, ads_server.net_id, ads_server.bound_address[0]],
                             stdout=subprocess.PIPE, text=True, start_new_session=True)
    try:
        assert child.stdout is not None and child.stdout.readline().strip() == "ready"
        assert wait_until(lambda: ads_server.subscription_count() == 2 and ads_server.connection_count == 1)
        os.killpg(child.pid, signal.SIGKILL)
        child.wait(timeout=30)
        assert wait_until(lambda: ads_server.subscription_count() == 0 and ads_server.connection_count == 0)
        assert wait_until(lambda: len(fake_device.closed_conns) == 1)
    finally:
        if child.poll() is None:
            os.killpg(child.pid, signal.SIGKILL)
            child.wait(timeout=30)
        if child.stdout is not None:
            child.stdout.close()
