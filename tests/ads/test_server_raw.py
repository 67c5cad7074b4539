"""AdsServer over real loopback sockets with a raw AMS client: TCP reassembly, garbage, many connections,
out-of-order replies, notifications freed with their connection."""
from __future__ import annotations

import logging
import socket
import struct
import threading
import time

import pytest

from znc_testing.ads_testing import RawClient, connect
from nc_ads import ams
from nc_ads.ams import Command
from nc_ads.server import AdsServer
from nc_ads.testing import FakeDevice
from znc_testing import wait_until


def read_req(c: RawClient, g: int, o: int, n: int, **kw) -> ams.AmsPacket:
    return c.packet(Command.READ, ams.ReadRequest(g, o, n).encode(), **kw)


def test_several_packets_in_one_send(ads_server: AdsServer) -> None:
    with connect(ads_server) as c:
        pkts = [read_req(c, 0x4002, 8 * i, 8) for i in range(50)]
        c.send(*pkts)
        replies = {c.recv().header.invoke_id: None for _ in range(50)}
        assert set(replies) == {p.header.invoke_id for p in pkts}
        r = c.request(Command.READ, ams.ReadRequest(0x4002, 8 * 7, 8).encode())
        assert ams.DataResponse.decode(r.data) == ams.DataResponse(0, struct.pack("<d", 10.5))


def test_one_packet_over_many_sends(ads_server: AdsServer) -> None:
    with connect(ads_server) as c:
        frame = c.packet(Command.WRITE, ams.WriteRequest(0x4001, 0x27, struct.pack("<d", 77.0)).encode()).encode() \
            + read_req(c, 0x4001, 0x27, 8).encode()
        for i in range(len(frame)):
            c.send_raw(frame[i:i + 1])
            if i % 7 == 0:
                time.sleep(0.001)
        first, second = c.recv(), c.recv()
        assert ams.ResultOnly.decode(first.data).result == 0
        assert ams.DataResponse.decode(second.data).data == struct.pack("<d", 77.0)


@pytest.mark.parametrize("garbage", [
    b"GET / HTTP/1.1\r\nHost: x\r\n\r\n",
    struct.pack("<HI", 0, 10) + b"\0" * 10,                      # shorter than an AMS header
    struct.pack("<HI", 0, ams.MAX_FRAME_LENGTH + 1) + b"\0" * 64,  # oversized
    b"\xff" * 100,
], ids=["http", "short-length", "oversized", "ff"])
def test_garbage_closes_the_connection_and_is_logged_the_server_goes_on(
        ads_server: AdsServer, garbage: bytes, caplog: pytest.LogCaptureFixture) -> None:
    with caplog.at_level(logging.WARNING, logger="nc_ads.server"):
        with connect(ads_server) as c:
            c.send(read_req(c, 0x4001, 0x27, 8))
            assert ams.DataResponse.decode(c.recv().data).result == 0
            c.send_raw(garbage)
            assert c.closed_by_server()
        assert wait_until(lambda: "closing it" in caplog.text)
    with connect(ads_server) as c2:                  # the next connection is served
        r = c2.request(Command.READ_STATE)
        assert ams.ReadStateResponse.decode(r.data).ads_state == 5
        assert wait_until(lambda: ads_server.connection_count == 1)   # the garbage one is gone


def test_frames_before_garbage_in_the_same_send_are_answered(ads_server: AdsServer) -> None:
    with connect(ads_server) as c:
        p1, p2 = read_req(c, 0x4001, 0x27, 8), c.packet(Command.READ_STATE)
        c.send_raw(p1.encode() + p2.encode() + b"\x01\x02garbage" * 4)
        assert {c.recv().header.invoke_id, c.recv().header.invoke_id} == {p1.header.invoke_id, p2.header.invoke_id}
        assert c.closed_by_server()


def test_bad_header_gets_an_ams_error_and_the_connection_stays(ads_server: AdsServer) -> None:
    with connect(ads_server) as c:
        p = read_req(c, 0x4001, 0x27, 8)
        bad = ams.AmsPacket(ams.AmsHeader(p.header.target, p.header.source, 2, 4, 1000, 0, 555), p.data)
        c.send(bad)
        r = c.recv_reply(555)
        assert r.header.error_code == 0xE and r.data == b""
        r = c.request(Command.READ, ams.ReadRequest(0x4001, 0x27, 8).encode(), net_id="9.9.9.9.1.1")
        assert r.header.error_code == 7
        r = c.request(Command.READ, ams.ReadRequest(0x4001, 0x27, 8).encode(), port=851)
        assert r.header.error_code == 6
        r = c.request(Command.READ, b"\0" * 5)
        assert ams.DataResponse.decode(r.data).result == 0x705
        assert ams.DataResponse.decode(c.request(Command.READ, ams.ReadRequest(0x4001, 0x27, 8).encode()).data).result == 0


def test_replies_of_different_ports_may_overtake(ads_server: AdsServer, fake_device: FakeDevice) -> None:
    fake_device.delays[(0x4001, 0x27)] = 0.5
    with connect(ads_server) as c:
        slow = read_req(c, 0x4001, 0x27, 8, src_port=30000)
        fast = read_req(c, 0x4001, 0x01, 4, src_port=30001)
        c.send(slow, fast)
        first, second = c.recv(), c.recv()
        assert first.header.invoke_id == fast.header.invoke_id and first.header.target.port == 30001
        assert second.header.invoke_id == slow.header.invoke_id
        assert ams.DataResponse.decode(second.data).data == struct.pack("<d", 1234.5)


@pytest.mark.parametrize("pool", [False, True], ids=["inline", "pool"])
def test_many_connections_at_once(ads_server: AdsServer, fake_device: FakeDevice, pool: bool) -> None:
    fake_device.inline_off = pool
    n_conn, n_req = 40, 25
    errors: list[str] = []
    clients = [connect(ads_server) for _ in range(n_conn)]
    try:
        def work(k: int, c: RawClient) -> None:
            try:
                for i in range(n_req):
                    idx = (k * n_req + i) % 600
                    r = c.request(Command.READ, ams.ReadRequest(0x4002, 8 * idx, 8).encode(), src_port=30000 + k)
                    got = ams.DataResponse.decode(r.data)
                    if got != ams.DataResponse(0, struct.pack("<d", 1.5 * idx)):
                        errors.append(f"conn {k} read {idx}: {got}")
            except Exception as exc:
                errors.append(f"conn {k}: {exc!r}")
        threads = [threading.Thread(target=work, args=(k, c)) for k, c in enumerate(clients)]
        for t in threads:
            t.start()
        for t in threads:
            t.join(timeout=120)
        assert not errors, errors[:5]
        assert ads_server.connection_count == n_conn
    finally:
        for c in clients:
            c.close()
    assert wait_until(lambda: ads_server.connection_count == 0)


def add_notification(c: RawClient, g: int, o: int, n: int, mode: int = 3, cycle: int = 20000,
                     port: int = 501) -> int:
    r = c.request(Command.ADD_DEVICE_NOTIFICATION, ams.AddNotificationRequest(g, o, n, mode, 0, cycle).encode(),
                  port=port)
    resp = ams.AddNotificationResponse.decode(r.data)
    assert resp.result == 0
    return resp.handle


def notifications(c: RawClient, count: int, timeout: float = 20.0) -> list[ams.AmsPacket]:
    out = []
    deadline = time.monotonic() + timeout
    while len(out) < count:
        p = c.recv(max(0.0, deadline - time.monotonic()))
        if p.header.command == Command.DEVICE_NOTIFICATION:
            out.append(p)
    return out


def test_notifications_over_the_wire(ads_server: AdsServer, fake_device: FakeDevice) -> None:
    with connect(ads_server) as c:
        h501 = add_notification(c, 0x4101, 0, 256)
        h500 = add_notification(c, 0x4101, 0x0A, 8, port=500)
        seen = {500: set(), 501: set()}
        for p in notifications(c, 20):
            assert p.header.state_flags == 4 and p.header.target.port == 30000
            n = ams.DeviceNotification.decode(p.data)
            for st in n.stamps:
                assert abs(ams.unix_from_filetime(st.timestamp) - time.time()) < 60
                for smp in st.samples:
                    seen[p.header.source.port].add((smp.handle, len(smp.data)))
        assert seen[501] == {(h501, 256)} and seen[500] == {(h500, 8)}     # pitfalls 3 and 4


def test_client_gone_with_notifications_open_frees_them(ads_server: AdsServer, fake_device: FakeDevice) -> None:
    c = connect(ads_server)
    for _ in range(10):
        add_notification(c, 0x4101, 0, 256, cycle=10000)
    h = c.request(Command.READ_WRITE, ams.ReadWriteRequest(0xF003, 0, 4, b"MAIN.fVelo\0").encode())
    assert ams.DataResponse.decode(h.data).result == 0
    assert ads_server.subscription_count() == 10
    notifications(c, 3)
    c.sock.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))  # vanish with a reset
    c.close()
    assert wait_until(lambda: ads_server.subscription_count() == 0 and ads_server.connection_count == 0)
    assert wait_until(lambda: len(fake_device.closed_conns) == 1)
    with connect(ads_server) as c2:
        add_notification(c2, 0x4101, 0, 8)
        assert len(notifications(c2, 2)) == 2


def test_a_client_that_does_not_read_does_not_stop_the_others(start_ads, fake_device: FakeDevice,
                                                               caplog: pytest.LogCaptureFixture) -> None:
    srv = start_ads(tick_ms=1.0)
    hog = connect(srv)   # subscribes (reading its replies), then reads nothing more
    with caplog.at_level(logging.WARNING, logger="nc_ads.server"):
        for _ in range(20):
            add_notification(hog, 0x4101, 0, 60000, cycle=1)
        try:
            with connect(srv) as c:
                def other_served() -> bool:
                    r = c.request(Command.READ, ams.ReadRequest(0x4001, 0x27, 8).encode())
                    assert ams.DataResponse.decode(r.data).result == 0
                    return "does not read: notifications paused" in caplog.text
                assert wait_until(other_served, timeout=60, interval=0.05)
        finally:
            hog.close()
    assert wait_until(lambda: srv.subscription_count() == 0)


def test_close_with_open_connections_and_rebind(start_ads, fake_device: FakeDevice) -> None:
    srv = start_ads()
    c = connect(srv)
    add_notification(c, 0x4101, 0, 8)
    host, port = srv.bound_address
    srv.close()
    assert c.closed_by_server()
    c.close()
    again = AdsServer({501: fake_device}, srv.net_id, (host, port))   # the address is free again
    again.start()
    try:
        with connect(again) as c2:
            assert ams.ReadStateResponse.decode(c2.request(Command.READ_STATE).data).ads_state == 5
    finally:
        again.close()


def test_constructor_and_bind_errors(ads_server: AdsServer, fake_device: FakeDevice) -> None:
    with pytest.raises(ValueError):
        AdsServer({}, "1.2.3.4.1.1", ("127.0.0.1", 0))
    with pytest.raises(ValueError):
        AdsServer({501: fake_device}, "1.2.3.4.1.1", ("127.0.0.1", 0), tick_ms=0.5)
    with pytest.raises(ValueError):
        AdsServer({501: fake_device}, "not-a-netid", ("127.0.0.1", 0))
    busy = AdsServer({501: fake_device}, "1.2.3.4.1.1", ads_server.bound_address)
    with pytest.raises(OSError):
        busy.start()
    busy.close()
    with AdsServer({501: fake_device}, "1.2.3.4.1.1", ("127.0.0.1", 0)) as free:   # port 0: any free port
        assert free.bound_address[1] > 0
        with RawClient(*free.bound_address, server_netid="1.2.3.4.1.1") as c:
            assert ams.ReadStateResponse.decode(c.request(Command.READ_STATE).data).ads_state == 5


@pytest.mark.parametrize("push", [True, False])
def test_on_change_is_pushed_when_the_device_has_a_new_image(start_ads, fake_device: FakeDevice,
                                                              push: bool) -> None:
    srv = start_ads(tick_ms=30000.0, push_on_change=push)   # the first tick is 30 s away
    with connect(srv) as c:
        h_change = add_notification(c, 0x4101, 0, 256, mode=4, cycle=1)
        add_notification(c, 0x4101, 0, 256, mode=3, cycle=1)          # ServerCycle: stays on the tick
        time.sleep(0.05)                                              # past the first-sample delay
        fake_device.set_pos(42.0)                                     # the device's change listener fires
        if not push:
            with pytest.raises((socket.timeout, TimeoutError)):
                notifications(c, 1, timeout=1.0)
            return
        (p,) = notifications(c, 1, timeout=10.0)
        (stamp,) = ams.DeviceNotification.decode(p.data).stamps
        assert [s.handle for s in stamp.samples] == [h_change]
        assert struct.unpack_from("<d", stamp.samples[0].data, 16)[0] == 42.0
        assert wait_until(lambda: srv.pushes >= 1)
