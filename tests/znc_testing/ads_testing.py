"""Helpers of the ADS tests (tests/ads/, also used by the nc-ads tests): loopback addresses for pyads.

AdsLib (inside pyads) always connects to TCP port 48898, so tests cannot use a free port: each test gets
its own loopback address 127.0.0.x (Linux routes all of 127.0.0.0/8 to lo) where 48898 is free.
"""
from __future__ import annotations

import errno
import random
import socket
import time

from nc_ads import ams
from nc_ads.ams import AmsAddr, AmsPacket, Command

from nc_ads.ams import AMS_TCP_PORT

#: the AMS net id of test servers that need a fixed one (pyads tests use `netid_for(host)`)
SERVER_NETID = "5.80.201.232.1.1"
#: the AMS address raw test clients send from
CLIENT_NETID = "10.1.2.3.1.1"


def netid_for(host: str) -> str:
    """A net id of its own per loopback address: AdsLib keeps one route per net id in the process
    and refuses a second one to another IP, so tests that reuse a net id would depend on each other."""
    return f"5.80.201.{host.rsplit('.', 1)[1]}.1.1"


#: the addresses handed out in this process: AdsLib (pyads) keeps one TCP connection per IP in the process, and a
#: connection to an earlier server on that IP that was not closed (a test of a lost server, a pyads client
#: left open) is reused for a new server there: its first request then waits the full timeout (1861, seen once
#: in CI). A fresh address per server avoids it while fresh ones last.
_HANDED_OUT: set[str] = set()


def free_ads_address(port: int = AMS_TCP_PORT, tries: int = 200) -> str:
    """A random 127.0.0.x (x in 2..250) where `port` can be bound right now (race: bind it soon); one not handed
    out before in this process while there is one."""
    rng = random.SystemRandom()
    for k in range(tries):
        fresh = [x for x in range(2, 251) if f"127.0.0.{x}" not in _HANDED_OUT]
        host = f"127.0.0.{rng.choice(fresh) if fresh and k < tries // 2 else rng.randint(2, 250)}"
        s = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        try:
            s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            s.bind((host, port))
        except OSError as exc:
            if exc.errno not in (errno.EADDRINUSE, errno.EADDRNOTAVAIL, errno.EACCES):
                raise
            continue
        finally:
            s.close()
        _HANDED_OUT.add(host)
        return host
    raise RuntimeError(f"no 127.0.0.x with port {port} free after {tries} tries")


def start_server_on_free_address(make, tries: int = 20):
    """`make(host)` -> a started server (e.g. AdsServer(...).start()); retried on another address when
    the bind fails because someone took it meanwhile. Returns (host, server)."""
    last: OSError | None = None
    for _ in range(tries):
        host = free_ads_address()
        try:
            return host, make(host)
        except OSError as exc:
            if exc.errno != errno.EADDRINUSE:
                raise
            last = exc
    raise RuntimeError(f"could not bind an ADS test server: {last}")


class RawClient:
    """An AMS/TCP client on a plain socket (no AdsLib): send frames, receive packets with deadlines."""

    def __init__(self, host: str, port: int = AMS_TCP_PORT, server_netid: str = SERVER_NETID,
                 timeout: float = 10.0) -> None:
        self.sock = socket.create_connection((host, port), timeout=timeout)
        self.sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self.server_netid = server_netid
        self.asm = ams.FrameAssembler()
        self.queue: list[AmsPacket] = []
        self.invoke = 0

    def packet(self, command: int, data: bytes = b"", port: int = 501, src_port: int = 30000,
               net_id: str | None = None, invoke_id: int | None = None) -> AmsPacket:
        if invoke_id is None:
            self.invoke += 1
            invoke_id = self.invoke
        return AmsPacket.build(AmsAddr(net_id or self.server_netid, port), AmsAddr(CLIENT_NETID, src_port),
                               command, data, invoke_id=invoke_id)

    def send(self, *packets: AmsPacket) -> None:
        self.sock.sendall(b"".join(p.encode() for p in packets))

    def send_raw(self, data: bytes) -> None:
        self.sock.sendall(data)

    def recv(self, timeout: float = 10.0) -> AmsPacket:
        """The next packet (replies and notifications in arrival order); TimeoutError after `timeout`."""
        deadline = time.monotonic() + timeout
        while not self.queue:
            left = deadline - time.monotonic()
            if left <= 0:
                raise TimeoutError("no AMS packet from the server")
            self.sock.settimeout(left)
            try:
                chunk = self.sock.recv(65536)
            except socket.timeout:
                continue
            if not chunk:
                raise ConnectionError("server closed the connection")
            self.queue.extend(self.asm.feed(chunk))
        return self.queue.pop(0)

    def recv_reply(self, invoke_id: int, timeout: float = 10.0) -> AmsPacket:
        """The reply with `invoke_id` (notifications and other replies before it are dropped)."""
        deadline = time.monotonic() + timeout
        while True:
            p = self.recv(max(0.0, deadline - time.monotonic()))
            if p.header.invoke_id == invoke_id and p.header.command != Command.DEVICE_NOTIFICATION:
                return p

    def request(self, command: int, data: bytes = b"", **kw) -> AmsPacket:
        p = self.packet(command, data, **kw)
        self.send(p)
        return self.recv_reply(p.header.invoke_id)

    def closed_by_server(self, timeout: float = 10.0) -> bool:
        """True once the server closed (EOF or reset) within `timeout`; frames before that are dropped."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            self.sock.settimeout(max(0.01, deadline - time.monotonic()))
            try:
                chunk = self.sock.recv(65536)
            except socket.timeout:
                continue
            except ConnectionError:
                return True
            if not chunk:
                return True
        return False

    def close(self) -> None:
        self.sock.close()

    def __enter__(self) -> RawClient:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def connect(server) -> RawClient:
    """A RawClient to an AdsServer, addressing its net id."""
    host, port = server.bound_address
    return RawClient(host, port, server.net_id)


class PyadsSession:
    """pyads Connections to an AdsServer that are always closed safely: every notification still
    registered is deleted before close() (pyads/AdsLib segfault otherwise, ads-bridge-notes pitfall 8).
    `open(ams_port)` -> Connection; one Connection per AMS port in flight at a time (AdsLib's rule)."""

    def __init__(self, server) -> None:
        self.server = server
        self.conns: list = []

    def open(self, ams_port: int = 501, net_id: str | None = None, timeout_ms: int = 5000):
        import pyads

        host = self.server.bound_address[0]
        plc = pyads.Connection(net_id or self.server.net_id, ams_port, host)
        plc.open()
        plc.set_timeout(timeout_ms)
        plc._znc_handles = []
        add, delete = plc.add_device_notification, plc.del_device_notification

        def add_tracked(*a, **kw):
            h = add(*a, **kw)
            plc._znc_handles.append(h)
            return h

        def del_tracked(*h):
            if h in plc._znc_handles:
                plc._znc_handles.remove(h)
            delete(*h)

        plc.add_device_notification = add_tracked
        plc.del_device_notification = del_tracked
        plc._znc_delete = delete
        self.conns.append(plc)
        return plc

    def close(self) -> None:
        import pyads

        for plc in self.conns:
            for h in list(plc._znc_handles):
                try:
                    plc._znc_delete(*h)
                except pyads.ADSError:
                    pass   # it still removes the handle locally
            plc._znc_handles.clear()
            try:
                plc.close()
            except pyads.ADSError:
                pass
        self.conns.clear()
