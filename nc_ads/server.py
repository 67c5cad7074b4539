"""Asyncio AMS/TCP server: serves `AdsDevice`s on AMS ports to pyads and other ADS clients.

`AdsServer(devices, net_id, listen, write_policy, strict_netid)` runs its own event loop in its own
thread (`start()` / `close()`). Per TCP connection a `Session` keeps the connection's symbol handles and
notification subscriptions; `Dispatcher.handle(packet, session)` turns one request into its reply and is
synchronous, so the same code runs on the loop, in the worker pool and in the fuzz target.

Decisions (the ones a user sees; docs/ads.md repeats them):
- Addressing: a request whose target net id is not the server's gets AMS error 7 (target machine not
  found) unless `strict_netid=False`; a target port without a device gets AMS error 6. Both go in the AMS
  header with no data. Replies come from exactly the address the request was sent to.
- Malformed input: a stream that cannot be cut into frames (AMS/TCP reserved field != 0, length below the
  32-byte AMS header or above `ams.MAX_FRAME_LENGTH` = 4 MiB) is logged and the connection is closed. A
  frame whose AMS header's data length disagrees with the frame gets AMS error 0xE (invalid AMS length).
  ADS data that does not have the command's layout gets 0x705 in the command's own reply layout (Read and
  ReadWrite replies always carry the length field, pitfall 1). Unknown command ids get AMS error 0x701
  in the header. Frames flagged as responses and DeviceNotifications sent to the server are ignored.
- Read/Write/ReadWrite/ReadState go to the device in a bounded worker pool (`max_workers`, default 8),
  except requests the device declares `nonblocking(group, offset, write)` (run on the loop; `write` is
  False for Read, True for Write/ReadWrite), so replies of different AMS source ports may complete out
  of order (matched by invoke id); at most
  `MAX_INFLIGHT_PER_CONNECTION` (64) requests per connection are in flight, then reading pauses.
  A device answer longer than the requested length is truncated and logged (pitfall 2). An exception
  other than AdsError inside a device is logged and answered with 0x700.
- WriteControl: always 0x701 (the NC's state is nc-server's business, not changed over ADS).
- Write policy: `WritePolicy(allow)` lists AMS net ids and/or IP addresses/CIDR networks that may write;
  `allow=None` (default) lets every client that can connect write (the listen address, loopback by
  default, is the boundary). ADS Write (command 3, also through symbol handles and sum write) from a
  client not allowed gets 0x723 from the server before the device sees it; ReadWrite goes to the device
  with `AdsSource.may_write` (a ReadWrite can be a read), the device refuses with 0x723 where it writes.
  Releasing a symbol handle (0xF006) is not a write.
- Symbols (0xF003 handle by name, 0xF004 value by name, 0xF005 value by handle, 0xF006 release, 0xF009
  info by name ex) come from `device.symbols()`; names match exactly, else case-insensitively (TwinCAT
  names are case-insensitive). Handles belong to the connection, at most `MAX_SYMBOL_HANDLES` (4096)
  per connection (then 0x716), freed when it closes; an unknown handle gets 0x710. A read longer than
  the symbol gets the symbol's bytes (pyads reads a STRING with 1024); a write longer than it gets 0x705.
- Sum commands: ReadWrite on 0xF080 (read), 0xF081 (write), 0xF082 (read-write), index offset = number
  of sub-commands, at most `MAX_SUM_COMMANDS` (500, pyads's chunk size); more, a read length too small for
  the reply, a sum read asking for more than `ams.MAX_FRAME_LENGTH` (4 MiB) in all, or a malformed
  sub-command list -> 0x705 for the whole request. Each sub-command has its own
  result; a sum read's data area holds every sub-read at its requested length (zeros on an error).
  Sub-commands may address symbol handles (0xF005), not other sum commands (0x701).
- Notifications: transmission modes ServerCycle (3) and ServerOnChange (4); others get 0x713. The
  server samples on its tick (`tick_ms`, default 10 ms, at least `MIN_TICK_MS` = 1 ms); a cycle time
  (wire unit 100 ns) is rounded to a whole number of ticks, at least one; nMaxDelay is not waited for
  (sending at once is allowed). ServerOnChange sends the first value and then only when the bytes
  changed; ServerCycle sends every cycle. With `push_on_change` (default) the server also registers
  with every device's `add_change_listener`: when a device reports a new image (NcDevice: every NC
  status frame) the ServerOnChange subscriptions are checked at once on the loop instead of on the
  next tick (lower latency, up to a tick less); such a check counts as the next tick's, so a
  subscription is still checked at most about once per cycle time. ServerCycle stays on the tick. The first sample goes out on the first tick at least
  `FIRST_SAMPLE_DELAY_S` (10 ms) after the AddDeviceNotification reply (pitfall 5: AdsLib registers the
  handle only after its calling thread woke up; 3 ms still lost first samples on a loaded 2-core
  machine), and a ServerOnChange value that did not change within `ONCHANGE_REPEAT_S` (1 s) after the
  first sample is sent once more, so a first sample lost in that race anyway is not lost for good
  (a client may see its initial value twice; a changed value supersedes it). Every sample has
  exactly the subscribed length (pitfall 4); samples due in one tick for the same (client address, server
  address) go into one DeviceNotification frame with one timestamp, sent from the address the client
  subscribed to (pitfall 3). Length 0 or above `MAX_NOTIFICATION_LENGTH` (64 KiB) -> 0x705; a
  (group, offset) the device cannot sample -> the device's code. At most `MAX_NOTIFICATIONS`
  (1024) per connection (then 0x716); an unknown handle on delete -> 0x714. A notification on a
  symbol handle (0xF005/handle, what pyads does for a name) follows the symbol the handle had when it
  was added; other 0xFxxx groups -> 0x701. A connection's
  subscriptions end when it closes. Sampling is bounded and fair, so that no client can deny service to
  the others (issue 18; `AdsServer._round`): each distinct (device, group, offset, length) is sampled
  once per round and shared by every subscription of every connection; connections a round did not
  reach go first in the next, then those asking for fewer samples per tick; a connection gets at most
  `MAX_SAMPLES_PER_VISIT` (128) samples per round, and no more than fit below `NOTIFY_PAUSE_BUFFER`
  unsent, and the loop serves requests between two connections; after `NOTIFY_BUDGET_SHARE` (30 %) of a
  tick no further connection is started (what was left out is sampled in a later round; a ServerCycle
  subscription's cycles that passed meanwhile are dropped and counted). A client
  that does not read its socket is not sampled at all while more than `NOTIFY_PAUSE_BUFFER` (64 KiB)
  wait to be sent to it (`_unsent`: ours and the kernel's not yet sent): the samples it misses are dropped, counted (`Session.samples_dropped`,
  `AdsServer.samples_dropped`, in the connection's "closed" log line) and logged once per connection;
  its requests are not read while more than `MAX_WRITE_BUFFER` (8 MiB) wait (until half of that is
  sent); other connections go on.
- `close()` returns within about `SHUTDOWN_WAIT_S` (2 s) whatever the clients do (nc-ads must end within
  5 s of SIGTERM; its cli releases the NC's axes before, on its own thread).
- At most `MAX_CONNECTIONS` (256) TCP connections at once; more are closed at once and logged.
"""
from __future__ import annotations

import asyncio
import collections
import concurrent.futures
import fcntl
import ipaddress
import itertools
import logging
import socket
import struct
import termios
import threading
import time
from collections.abc import Iterable, Iterator, Mapping
from dataclasses import dataclass

from nc_ads import ams
from nc_ads.ams import AmsAddr, AmsPacket, Command
from nc_ads.device import AdsDevice, AdsSource, Symbol
from nc_ads.errors import (
    ADSERR_DEVICE_ACCESSDENIED, ADSERR_DEVICE_ERROR, ADSERR_DEVICE_INVALIDSIZE,
    ADSERR_DEVICE_NOMOREHDLS, ADSERR_DEVICE_NOTIFYHNDINVALID, ADSERR_DEVICE_SRVNOTSUPP,
    ADSERR_DEVICE_SYMBOLNOTFOUND, ADSERR_DEVICE_TRANSMODENOTSUPP, AMS_INVALID_LENGTH,
    AMS_TARGET_MACHINE_NOT_FOUND, AMS_TARGET_PORT_NOT_FOUND, AdsError,
)

log = logging.getLogger("nc_ads.server")

MAX_SUM_COMMANDS = 500
MAX_NOTIFICATIONS = 1024            # per connection
MAX_SYMBOL_HANDLES = 4096           # per connection
MAX_NOTIFICATION_LENGTH = 65536     # bytes per subscription
MIN_TICK_MS = 1.0
SHUTDOWN_WAIT_S = 2.0               # AdsServer.close() waits at most about this long
DEFAULT_TICK_MS = 10.0
FIRST_SAMPLE_DELAY_S = 0.010
ONCHANGE_REPEAT_S = 1.0
MAX_INFLIGHT_PER_CONNECTION = 64
MAX_WRITE_BUFFER = 8 * 1024 * 1024
MAX_CONNECTIONS = 256
MAX_NOTIFICATION_FRAME = 1024 * 1024  # a tick's samples are split into frames of about this size
NOTIFY_PAUSE_BUFFER = 64 * 1024       # a connection with more unsent than this (ours and the kernel's) gets no
                                      # samples: it drops them
NOTIFY_BUDGET_SHARE = 0.3             # a sampling round starts no further connection after this share of a tick
INLINE_BATCH = 4                       # requests run on the loop before it serves other connections
MAX_SAMPLES_PER_VISIT = 128           # samples one connection gets per round (the rest are due in the next)
SAMPLE_OVERHEAD = 12                  # bytes of a DeviceNotification sample besides its data (handle, size)
SOCKET_SEND_BUFFER = 128 * 1024       # SO_SNDBUF: no kernel autotuning to 4 MiB per connection

_U32 = struct.Struct("<I")
_SUM_GROUPS = (ams.IG_SUMUP_READ, ams.IG_SUMUP_WRITE, ams.IG_SUMUP_READWRITE)

# IEC type name -> ADS data type id (pyads constants ADST_*), for SAdsSymbolEntry.dataType
_ADST = {
    "BOOL": 33, "BIT": 33, "SINT": 16, "USINT": 17, "BYTE": 17, "INT": 2, "UINT": 18, "WORD": 18,
    "DINT": 3, "UDINT": 19, "DWORD": 19, "LINT": 20, "ULINT": 21, "LWORD": 21, "REAL": 4, "LREAL": 5,
    "TIME": 19, "TOD": 19, "DATE": 19, "DT": 19, "TIME_OF_DAY": 19, "DATE_AND_TIME": 19,
}
ADST_STRING = 30
ADST_WSTRING = 31
ADST_BIGTYPE = 65


def ads_type_id(type_name: str) -> int:
    """ADS data type id of an IEC type name; structs and arrays are BIGTYPE (65)."""
    t = type_name.strip().upper()
    if t.startswith("WSTRING"):
        return ADST_WSTRING
    if t.startswith("STRING"):
        return ADST_STRING
    return _ADST.get(t, ADST_BIGTYPE)


def encode_symbol_entry(name: str, sym: Symbol) -> bytes:
    """SAdsSymbolEntry (0xF009 reply): u32 entryLength, iGroup, iOffs, size, dataType, flags, u16
    nameLength, typeLength, commentLength, then the three strings each NUL-terminated."""
    n, t, c = (s.encode("latin-1", "replace")[:255] for s in (name, sym.type_name, sym.comment))
    body = n + b"\0" + t + b"\0" + c + b"\0"
    length = 30 + len(body)
    return struct.pack("<IIIIIIHHH", length, sym.group, sym.offset, sym.size,
                       ads_type_id(sym.type_name), 0, len(n), len(t), len(c)) + body


#: 0x723 reasons logged lately (ADS replies carry no text, so the log says which rule refused), newest last;
#: the oldest is forgotten beyond _DENIED_LOGGED_MAX, so a client cycling through reasons cannot grow it and
#: a reason can be logged again later. Reasons name the peer's IP, never its port (a port per connection
#: would make every connection a new reason).
_DENIED_LOGGED: collections.OrderedDict[str, None] = collections.OrderedDict()
_DENIED_LOGGED_MAX = 256


def _log_denied(reason: str) -> None:
    """Log why a request got 0x723 (ADSERR_DEVICE_ACCESSDENIED), once per reason among the recent ones."""
    if reason in _DENIED_LOGGED:
        _DENIED_LOGGED.move_to_end(reason)
        return
    _DENIED_LOGGED[reason] = None
    if len(_DENIED_LOGGED) > _DENIED_LOGGED_MAX:
        _DENIED_LOGGED.popitem(last=False)
    log.warning("access denied (0x723): %s", reason)


class WritePolicy:
    """Who may write: `allow` is None (everyone who can connect) or a list of AMS net ids ("a.b.c.d.e.f")
    and IP addresses / CIDR networks ("127.0.0.1", "10.0.0.0/8"); an empty list lets nobody write."""

    def __init__(self, allow: Iterable[str] | None = None) -> None:
        self.allow_all = allow is None
        self.net_ids: set[str] = set()
        self.networks: list[ipaddress.IPv4Network | ipaddress.IPv6Network] = []
        for entry in allow or ():
            entry = entry.strip()
            try:
                ams.netid_to_bytes(entry)
                self.net_ids.add(entry)
                continue
            except ValueError:
                pass
            try:
                self.networks.append(ipaddress.ip_network(entry, strict=False))
            except ValueError:
                raise ValueError(f"--allow-write entry {entry!r} is neither an AMS net id "
                                 f"(a.b.c.d.e.f) nor an IP address/network") from None

    def may_write(self, net_id: str, ip: str) -> bool:
        if self.allow_all or net_id in self.net_ids:
            return True
        try:
            addr = ipaddress.ip_address(ip)
        except ValueError:
            return False
        if isinstance(addr, ipaddress.IPv6Address) and addr.ipv4_mapped is not None:
            addr = addr.ipv4_mapped   # an IPv4 client on a dual-stack listen socket
        return any(addr in net for net in self.networks)


@dataclass
class Subscription:
    handle: int
    client: AmsAddr          # the subscriber's AMS address (reply target)
    server: AmsAddr          # the address it subscribed to: samples come from here (pitfall 3)
    device: AdsDevice
    group: int
    offset: int
    length: int
    trans_mode: int
    cycle_ticks: int
    not_before: float        # time.monotonic() of the earliest first sample (pitfall 5)
    next_tick: int = 0
    last: bytes | None = None
    first_sent: float | None = None   # when the first sample went out
    repeated: bool = False            # ServerOnChange: the first value was sent again (or changed since)


class Session:
    """State of one TCP connection. Symbol handles may be touched from worker threads (lock);
    subscriptions only from the thread that runs the loop (or the single-threaded fuzz target)."""

    def __init__(self, conn_id: int, peer: str) -> None:
        self.conn_id = conn_id
        self.peer = peer
        self.peer_ip = peer.rsplit(":", 1)[0].strip("[]")
        self.lock = threading.Lock()
        self.sym_handles: dict[int, tuple[AdsDevice, str, Symbol]] = {}
        self._next_sym = itertools.count(1)
        self.subs: dict[int, Subscription] = {}
        self.load = 0.0            # samples per tick its subscriptions ask for (sampling rounds serve light ones first)
        self.waited = 0            # rounds in a row that ended before reaching it (they serve it first next time)
        self.max_length = 0        # the longest sample it subscribed (bounds the bytes of one visit)
        self.next_sub = 0          # where its next visit starts among its subscriptions (round robin)
        self._may_write: dict[str, bool] = {}
        self.devices_used: set[int] = set()   # id() of devices this connection talked to
        self.throttled = False     # behind (NOTIFY_PAUSE_BUFFER): not sampled
        self.warned_behind = False  # logged once per connection
        self.samples_dropped = 0   # samples due while it was behind (NOTIFY_PAUSE_BUFFER): never sampled, never sent

    def add_sub(self, sub: Subscription) -> None:
        self.subs[sub.handle] = sub
        self.load += 1.0 / sub.cycle_ticks
        self.max_length = max(self.max_length, sub.length)

    def remove_sub(self, handle: int) -> bool:
        sub = self.subs.pop(handle, None)
        if sub is None:
            return False
        self.load = max(0.0, self.load - 1.0 / sub.cycle_ticks) if self.subs else 0.0
        return True


#: Linux ioctl: bytes in a TCP socket's send queue not yet sent (SIOCOUTQ would also count bytes sent and not
#: yet acknowledged: a reading client on a long link would look like one that does not read).
SIOCOUTQNSD = 0x894B


def _unsent(writer: asyncio.StreamWriter) -> int:
    """Bytes written to a connection and not yet taken by its client: the transport's buffer plus the
    kernel's send queue (SIOCOUTQ; on loopback the kernel's grows only once the client's window is full).
    A client that does not read is found behind after its receive window and NOTIFY_PAUSE_BUFFER, not after
    megabytes of kernel buffers."""
    n = writer.transport.get_write_buffer_size()
    sock = writer.get_extra_info("socket")
    if sock is not None:
        try:
            n += struct.unpack("i", fcntl.ioctl(sock.fileno(), SIOCOUTQNSD, b"\0\0\0\0"))[0]
        except (OSError, ValueError):   # closed meanwhile, or no SIOCOUTQ here: the transport's alone
            pass
    return n


def _clip(data: bytes, length: int, device: AdsDevice, what: str, group: int, offset: int) -> bytes:
    """A device's answer cut to the ``length`` asked (AdsLib discards a longer reply: pitfall 2), logged."""
    if len(data) > length:
        log.warning("device %s: %s 0x%X/0x%X returned %d bytes for %d asked; truncated",
                    device.name, what, group, offset, len(data), length)
        return data[:length]
    return data


class Dispatcher:
    """Request -> reply for every AMS command; no I/O of its own (see the module doc for the rules)."""

    def __init__(self, devices: Mapping[int, AdsDevice], net_id: str, write_policy: WritePolicy,
                 strict_netid: bool = True, tick_s: float = DEFAULT_TICK_MS / 1000) -> None:
        ams.netid_to_bytes(net_id)
        self.devices = dict(devices)
        self.net_id = net_id
        self.write_policy = write_policy
        self.strict_netid = strict_netid
        self.tick_s = tick_s
        self._handles = itertools.count(1)
        self._sym_index: dict[int, tuple[object, dict[str, tuple[str, Symbol]]]] = {}
        self.clock = time.monotonic

    # -- classification -------------------------------------------------------------------------------
    def runs_inline(self, pkt: AmsPacket, session: Session) -> bool:
        """True for what can run on the loop thread: no device call, or one the device says never
        blocks (`AdsDevice.nonblocking`); the rest goes to the worker pool."""
        h = pkt.header
        if h.command == Command.READ_STATE:
            return False
        if h.command not in (Command.READ, Command.WRITE, Command.READ_WRITE):
            return True
        device = self.devices.get(h.target.port)
        if device is None or len(pkt.data) < 8 or h.is_response:
            return True                     # answered without the device
        group, offset = struct.unpack_from("<II", pkt.data)
        if group in (ams.IG_SYM_HNDBYNAME, ams.IG_SYM_RELEASEHND, ams.IG_SYM_INFOBYNAMEEX):
            return True                     # the server's own symbol table work
        if group == ams.IG_SYM_VALBYHND:
            entry = self._handle_symbol(session, offset)
            if entry is None:
                return True
            device, group, offset = entry[0], entry[2].group, entry[2].offset
        elif group >= 0xF000:
            return False                    # sum commands, value by name: may touch many objects
        try:   # a Read only reads; a Write or ReadWrite may send commands
            return bool(device.nonblocking(group, offset, write=h.command != Command.READ))
        except Exception as exc:
            log.error("device %s: nonblocking raised %r", device.name, exc, exc_info=exc)
            return False

    # -- entry point ----------------------------------------------------------------------------------
    def handle(self, pkt: AmsPacket, session: Session) -> AmsPacket | None:
        h = pkt.header
        if h.is_response:
            log.debug("conn %d %s: ignoring a response frame (cmd %d)", session.conn_id,
                      session.peer, h.command)
            return None
        if h.command == Command.DEVICE_NOTIFICATION:
            log.debug("conn %d: ignoring a DeviceNotification sent to the server", session.conn_id)
            return None
        if self.strict_netid and h.target.net_id != self.net_id:
            return pkt.reply(error_code=AMS_TARGET_MACHINE_NOT_FOUND)
        device = self.devices.get(h.target.port)
        if device is None:
            return pkt.reply(error_code=AMS_TARGET_PORT_NOT_FOUND)
        if h.data_length != len(pkt.data):
            log.warning("conn %d %s: AMS data length %d but %d bytes follow", session.conn_id,
                        session.peer, h.data_length, len(pkt.data))
            return pkt.reply(error_code=AMS_INVALID_LENGTH)
        if h.command not in ams.RESPONSES:
            log.warning("conn %d %s: unknown AMS command %d", session.conn_id, session.peer, h.command)
            return pkt.reply(error_code=ADSERR_DEVICE_SRVNOTSUPP)
        try:
            req = ams.decode_request(h.command, pkt.data)
        except ams.PayloadError as exc:
            log.warning("conn %d %s: malformed command %d: %s", session.conn_id, session.peer,
                        h.command, exc)
            return pkt.reply(ams.error_response(h.command, ADSERR_DEVICE_INVALIDSIZE).encode())
        session.devices_used.add(id(device))
        resp = self._command(h.command, req, pkt, device, session)
        return pkt.reply(resp.encode())

    def _source(self, pkt: AmsPacket, session: Session) -> AdsSource:
        src = pkt.header.source
        may = session._may_write.get(src.net_id)
        if may is None:
            may = self.write_policy.may_write(src.net_id, session.peer_ip)
            session._may_write[src.net_id] = may
        return AdsSource(src.net_id, src.port, session.peer, session.conn_id, may)

    def _command(self, cmd: int, req, pkt: AmsPacket, device: AdsDevice, session: Session):
        if cmd == Command.READ_DEVICE_INFO:
            major, minor, build = device.version
            return ams.ReadDeviceInfoResponse(0, major & 0xFF, minor & 0xFF, build & 0xFFFF,
                                              device.name)
        if cmd == Command.READ_STATE:
            try:
                state, dev_state = device.read_state()
                return ams.ReadStateResponse(0, state & 0xFFFF, dev_state & 0xFFFF)
            except Exception as exc:  # the device's failure becomes the result, never a crash
                return ams.ReadStateResponse(self._code(exc, device, "read_state"), 0, 0)
        if cmd == Command.WRITE_CONTROL:
            return ams.ResultOnly(ADSERR_DEVICE_SRVNOTSUPP)
        if cmd == Command.ADD_DEVICE_NOTIFICATION:
            return self._add_notification(req, pkt, device, session)
        if cmd == Command.DEL_DEVICE_NOTIFICATION:
            if not session.remove_sub(req.handle):
                return ams.ResultOnly(ADSERR_DEVICE_NOTIFYHNDINVALID)
            return ams.ResultOnly(0)
        src = self._source(pkt, session)
        if cmd == Command.READ:
            code, data = self.read(device, req.group, req.offset, req.length, src, session)
            return ams.DataResponse(code, data if code == 0 else b"")
        if cmd == Command.WRITE:
            return ams.ResultOnly(self.write(device, req.group, req.offset, req.data, src, session))
        if cmd == Command.READ_WRITE:
            code, data = self.read_write(device, req.group, req.offset, req.read_length, req.data,
                                         src, session)
            return ams.DataResponse(code, data if code == 0 else b"")
        return ams.error_response(cmd, ADSERR_DEVICE_SRVNOTSUPP)  # pragma: no cover (guarded above)

    @staticmethod
    def _code(exc: Exception, device: AdsDevice, what: str) -> int:
        if isinstance(exc, AdsError):
            if exc.code == ADSERR_DEVICE_ACCESSDENIED:
                _log_denied(exc.message)
            return exc.code
        log.error("device %s: %s raised %r (answered 0x700)", getattr(device, "name", device), what,
                  exc, exc_info=exc)
        return ADSERR_DEVICE_ERROR

    # -- symbols -------------------------------------------------------------------------------------
    def _lookup(self, device: AdsDevice, name: str) -> tuple[str, Symbol] | None:
        table = device.symbols()
        sym = table.get(name)
        if sym is not None:
            return name, sym
        cached = self._sym_index.get(id(device))
        if cached is None or cached[0] is not table:
            index = {k.lower(): (k, v) for k, v in table.items()}
            self._sym_index[id(device)] = (table, index)
        else:
            index = cached[1]
        return index.get(name.lower())

    @staticmethod
    def _name(data: bytes) -> str:
        return data.split(b"\0", 1)[0].decode("latin-1")

    def _handle_symbol(self, session: Session, handle: int) -> tuple[AdsDevice, str, Symbol] | None:
        with session.lock:
            return session.sym_handles.get(handle)

    # -- reads and writes (also the sub-commands of sum commands) ------------------------------------
    def read(self, device: AdsDevice, group: int, offset: int, length: int, src: AdsSource,
             session: Session) -> tuple[int, bytes]:
        """(result, data) of an ADS Read; data never longer than `length`."""
        if group == ams.IG_SYM_VALBYHND:
            entry = self._handle_symbol(session, offset)
            if entry is None:
                return ADSERR_DEVICE_SYMBOLNOTFOUND, b""
            dev, _, sym = entry
            # like TwinCAT: a longer read gets the symbol's bytes (pyads reads STRINGs with 1024)
            device, group, offset, length = dev, sym.group, sym.offset, min(length, sym.size)
        elif group in (ams.IG_SUMUP_READ, ams.IG_SUMUP_WRITE, ams.IG_SUMUP_READWRITE,
                       ams.IG_SYM_HNDBYNAME, ams.IG_SYM_RELEASEHND, ams.IG_SYM_INFOBYNAMEEX,
                       ams.IG_SYM_VALBYNAME):
            return ADSERR_DEVICE_SRVNOTSUPP, b""
        try:
            data = bytes(device.read(group, offset, length, src))
        except Exception as exc:
            return self._code(exc, device, f"read 0x{group:X}/0x{offset:X}"), b""
        return 0, _clip(data, length, device, "read", group, offset)

    def write(self, device: AdsDevice, group: int, offset: int, data: bytes, src: AdsSource,
              session: Session) -> int:
        if group == ams.IG_SYM_RELEASEHND:
            handle = _U32.unpack(data)[0] if len(data) == 4 else offset if not data else None
            if handle is None:
                return ADSERR_DEVICE_INVALIDSIZE
            with session.lock:
                return 0 if session.sym_handles.pop(handle, None) else ADSERR_DEVICE_SYMBOLNOTFOUND
        if group in (ams.IG_SUMUP_READ, ams.IG_SUMUP_WRITE, ams.IG_SUMUP_READWRITE,
                     ams.IG_SYM_HNDBYNAME, ams.IG_SYM_INFOBYNAMEEX, ams.IG_SYM_VALBYNAME):
            return ADSERR_DEVICE_SRVNOTSUPP
        if not src.may_write:
            _log_denied(f"write policy: {src.net_id} ({session.peer_ip}) may not write (WritePolicy allow list)")
            return ADSERR_DEVICE_ACCESSDENIED
        if group == ams.IG_SYM_VALBYHND:
            entry = self._handle_symbol(session, offset)
            if entry is None:
                return ADSERR_DEVICE_SYMBOLNOTFOUND
            dev, _, sym = entry
            if len(data) > sym.size:
                return ADSERR_DEVICE_INVALIDSIZE
            device, group, offset = dev, sym.group, sym.offset
        try:
            device.write(group, offset, data, src)
        except Exception as exc:
            return self._code(exc, device, f"write 0x{group:X}/0x{offset:X}")
        return 0

    def read_write(self, device: AdsDevice, group: int, offset: int, length: int, data: bytes,
                   src: AdsSource, session: Session) -> tuple[int, bytes]:
        if group == ams.IG_SYM_HNDBYNAME:
            found = self._lookup(device, self._name(data))
            if found is None:
                return ADSERR_DEVICE_SYMBOLNOTFOUND, b""
            if length < 4:
                return ADSERR_DEVICE_INVALIDSIZE, b""
            with session.lock:
                if len(session.sym_handles) >= MAX_SYMBOL_HANDLES:
                    return ADSERR_DEVICE_NOMOREHDLS, b""
                handle = next(session._next_sym)
                session.sym_handles[handle] = (device, found[0], found[1])
            return 0, _U32.pack(handle)
        if group == ams.IG_SYM_INFOBYNAMEEX:
            found = self._lookup(device, self._name(data))
            if found is None:
                return ADSERR_DEVICE_SYMBOLNOTFOUND, b""
            entry = encode_symbol_entry(*found)
            if len(entry) > length:
                return ADSERR_DEVICE_INVALIDSIZE, b""
            return 0, entry
        if group == ams.IG_SYM_VALBYNAME:
            found = self._lookup(device, self._name(data))
            if found is None:
                return ADSERR_DEVICE_SYMBOLNOTFOUND, b""
            sym = found[1]
            return self.read(device, sym.group, sym.offset, min(length, sym.size), src, session)
        if group in (ams.IG_SUMUP_READ, ams.IG_SUMUP_WRITE, ams.IG_SUMUP_READWRITE):
            return self._sum(device, group, offset, length, data, src, session)
        if group in (ams.IG_SYM_VALBYHND, ams.IG_SYM_RELEASEHND):
            return ADSERR_DEVICE_SRVNOTSUPP, b""
        try:
            out = bytes(device.read_write(group, offset, length, data, src))
        except Exception as exc:
            return self._code(exc, device, f"read_write 0x{group:X}/0x{offset:X}"), b""
        return 0, _clip(out, length, device, "read_write", group, offset)

    def _sum(self, device: AdsDevice, group: int, count: int, length: int, data: bytes,
             src: AdsSource, session: Session) -> tuple[int, bytes]:
        if count > MAX_SUM_COMMANDS:
            log.warning("conn %d: sum command 0x%X with %d sub-commands (limit %d)", session.conn_id,
                        group, count, MAX_SUM_COMMANDS)
            return ADSERR_DEVICE_INVALIDSIZE, b""
        try:
            if group == ams.IG_SUMUP_READ:
                items = ams.decode_sum_read(count, data)
                need = 4 * count + sum(i.length for i in items)
                if length < need or need > ams.MAX_FRAME_LENGTH:   # the reply pads every sub-read
                    return ADSERR_DEVICE_INVALIDSIZE, b""
                results = [self.read(device, i.group, i.offset, i.length, src, session) for i in items]
                return 0, ams.encode_sum_read_response(results, [i.length for i in items])
            if group == ams.IG_SUMUP_WRITE:
                witems = ams.decode_sum_write(count, data)
                if length < 4 * count:
                    return ADSERR_DEVICE_INVALIDSIZE, b""
                codes = [self.write(device, i.group, i.offset, i.data, src, session) for i in witems]
                return 0, ams.encode_sum_results(codes)
            rwitems = ams.decode_sum_read_write(count, data)
            if length < 8 * count + sum(i.read_length for i in rwitems):
                return ADSERR_DEVICE_INVALIDSIZE, b""
            rw = []
            for i in rwitems:
                if i.group in _SUM_GROUPS:   # no sum inside a sum (no recursion, no amplification)
                    rw.append((ADSERR_DEVICE_SRVNOTSUPP, b""))
                    continue
                code, out = self.read_write(device, i.group, i.offset, i.read_length, i.data, src,
                                            session)
                rw.append((code, out if code == 0 else b""))
            return 0, ams.encode_sum_read_write_response(rw)
        except ams.PayloadError as exc:
            log.warning("conn %d: malformed sum command 0x%X: %s", session.conn_id, group, exc)
            return ADSERR_DEVICE_INVALIDSIZE, b""

    # -- notifications --------------------------------------------------------------------------------
    def _add_notification(self, req: ams.AddNotificationRequest, pkt: AmsPacket, device: AdsDevice,
                          session: Session) -> ams.AddNotificationResponse:
        if req.trans_mode not in (ams.TRANS_SERVERCYCLE, ams.TRANS_SERVERONCHA):
            return ams.AddNotificationResponse(ADSERR_DEVICE_TRANSMODENOTSUPP, 0)
        if not 0 < req.length <= MAX_NOTIFICATION_LENGTH:
            return ams.AddNotificationResponse(ADSERR_DEVICE_INVALIDSIZE, 0)
        if len(session.subs) >= MAX_NOTIFICATIONS:
            return ams.AddNotificationResponse(ADSERR_DEVICE_NOMOREHDLS, 0)
        group, offset, dev = req.group, req.offset, device
        if group == ams.IG_SYM_VALBYHND:
            entry = self._handle_symbol(session, offset)
            if entry is None:
                return ams.AddNotificationResponse(ADSERR_DEVICE_SYMBOLNOTFOUND, 0)
            dev, _, sym = entry
            if req.length > sym.size:
                return ams.AddNotificationResponse(ADSERR_DEVICE_INVALIDSIZE, 0)
            group, offset = sym.group, sym.offset
        elif group >= 0xF000:
            return ams.AddNotificationResponse(ADSERR_DEVICE_SRVNOTSUPP, 0)
        try:
            dev.sample(group, offset, req.length)   # can it be notified? (its code if not)
        except Exception as exc:
            return ams.AddNotificationResponse(self._code(exc, dev, "sample"), 0)
        ticks = max(1, round(req.cycle_time * 1e-7 / self.tick_s))
        handle = next(self._handles) % 0xFFFFFFFF + 1   # unique in this server, never 0
        session.add_sub(Subscription(
            handle, pkt.header.source, pkt.header.target, dev, group, offset, req.length,
            req.trans_mode, ticks, self.clock() + FIRST_SAMPLE_DELAY_S))
        return ams.AddNotificationResponse(0, handle)

    @staticmethod
    def _due(session: Session, tick: int, now: float, only_on_change: bool,
             limit: int | None) -> Iterator[Subscription]:
        """At most `limit` subscriptions of `session` due at `tick` (their next tick moves on as they are
        taken), from where its last visit stopped: a limit delays its other ones, never the same ones."""
        subs = list(session.subs.values())
        start = session.next_sub % len(subs) if subs else 0
        taken = 0
        for k in range(len(subs)):
            sub = subs[(start + k) % len(subs)]
            if only_on_change and sub.trans_mode != ams.TRANS_SERVERONCHA:
                continue
            if now < sub.not_before or tick < sub.next_tick:
                continue
            if limit is not None and taken >= limit:
                session.next_sub = start + k
                return
            taken += 1
            if (sub.trans_mode != ams.TRANS_SERVERONCHA and sub.first_sent is not None
                    and tick >= sub.next_tick + sub.cycle_ticks):
                # served late (left out of earlier rounds): its cycles in between were never sampled
                session.samples_dropped += (tick - sub.next_tick) // sub.cycle_ticks
            sub.next_tick = tick + sub.cycle_ticks
            yield sub

    @staticmethod
    def drop_missed(session: Session, tick: int) -> int:
        """Count the samples `session` missed before `tick` (it was behind: they were never sampled) in
        ``session.samples_dropped``; each subscription keeps its cycle (its next tick is the first of its
        ticks from `tick` on). Returns how many."""
        n = 0
        for sub in session.subs.values():
            missed = -((sub.next_tick - tick) // sub.cycle_ticks)   # its due ticks before `tick` (ceil)
            if missed > 0:
                n += missed
                sub.next_tick += missed * sub.cycle_ticks
        session.samples_dropped += n
        return n

    @staticmethod
    def _sample(sub: Subscription, cache: dict[tuple, bytes | None]) -> bytes | None:
        """`sub`'s bytes (exactly its length, pitfall 4), None if the device has none now. `cache` holds
        one round's samples: each distinct (device, group, offset, length) is sampled once per round,
        however many subscriptions (of however many connections) ask for it."""
        key = (id(sub.device), sub.group, sub.offset, sub.length)
        if key in cache:
            return cache[key]
        data: bytes | None = None
        try:
            data = bytes(sub.device.sample(sub.group, sub.offset, sub.length))
        except AdsError:
            pass          # not available this tick (e.g. the NC went away): nothing to send
        except Exception as exc:
            log.error("device %s: sample raised %r", sub.device.name, exc, exc_info=exc)
        if data is not None and len(data) != sub.length:
            data = data[:sub.length].ljust(sub.length, b"\0")
        cache[key] = data
        return data

    def collect(self, session: Session, tick: int, now: float, filetime: int,
                only_on_change: bool = False, cache: dict[tuple, bytes | None] | None = None,
                limit: int | None = None) -> list[bytes]:
        """The DeviceNotification frames due for `session` at tick number `tick` (monotonic `now`);
        `only_on_change`: ServerOnChange subscriptions only (a push on the device's new image); `cache`:
        the samples already taken in this round (shared by the connections of one round); `limit`: at
        most this many subscriptions (the others stay due)."""
        if cache is None:
            cache = {}
        batches: dict[tuple[AmsAddr, AmsAddr], list[ams.Sample]] = {}
        for sub in self._due(session, tick, now, only_on_change, limit):
            data = self._sample(sub, cache)
            if data is None:
                continue
            if sub.trans_mode == ams.TRANS_SERVERONCHA and sub.last is not None:
                if data != sub.last:
                    sub.repeated = True
                elif sub.repeated or sub.first_sent is None or now < sub.first_sent + ONCHANGE_REPEAT_S:
                    continue
                else:
                    sub.repeated = True   # unchanged for ONCHANGE_REPEAT_S: send it once more
            if sub.first_sent is None:
                sub.first_sent = now
            sub.last = data
            batches.setdefault((sub.client, sub.server), []).append(ams.Sample(sub.handle, data))
        frames = []
        for (client, server), samples in batches.items():
            chunk: list[ams.Sample] = []
            size = 0
            for s in samples:
                chunk.append(s)
                size += 8 + len(s.data)
                if size >= MAX_NOTIFICATION_FRAME:
                    frames.append(self._frame(client, server, filetime, chunk))
                    chunk, size = [], 0
            if chunk:
                frames.append(self._frame(client, server, filetime, chunk))
        return frames

    @staticmethod
    def _frame(client: AmsAddr, server: AmsAddr, filetime: int, samples: list[ams.Sample]) -> bytes:
        body = ams.DeviceNotification((ams.Stamp(filetime, tuple(samples)),)).encode()
        return AmsPacket.build(client, server, Command.DEVICE_NOTIFICATION, body,
                               state_flags=ams.FLAGS_REQUEST).encode()


class AdsServer:
    """AMS/TCP server in its own thread and event loop. `devices` maps AMS ports to devices (one device
    may serve several ports, e.g. {500: nc, 501: nc}). `listen` is (host, port); port 0 picks a free one
    (`bound_address` tells which). `start()` returns once listening (OSError if it cannot bind)."""

    def __init__(self, devices: Mapping[int, AdsDevice], net_id: str, listen: tuple[str, int],
                 write_policy: WritePolicy | None = None, strict_netid: bool = True, *,
                 tick_ms: float = DEFAULT_TICK_MS, max_workers: int = 8, push_on_change: bool = True) -> None:
        if not devices:
            raise ValueError("AdsServer needs at least one AMS port with a device")
        if tick_ms < MIN_TICK_MS:
            raise ValueError(f"tick_ms must be >= {MIN_TICK_MS}, got {tick_ms}")
        self.tick_s = tick_ms / 1000
        self.dispatcher = Dispatcher(devices, net_id, write_policy or WritePolicy(), strict_netid,
                                     self.tick_s)
        self.net_id = net_id
        self.listen = listen
        self._pool = concurrent.futures.ThreadPoolExecutor(max_workers, thread_name_prefix="nc-ads")
        self._loop: asyncio.AbstractEventLoop | None = None
        self._thread: threading.Thread | None = None
        self._server: asyncio.base_events.Server | None = None
        self._sessions: dict[int, tuple[Session, asyncio.StreamWriter]] = {}
        self._tasks: set[asyncio.Task] = set()
        self._conn_ids = itertools.count(1)
        self._bound: tuple[str, int] | None = None
        self._stopping = False
        self.push_on_change = push_on_change
        self._tick = 0                 # the notifier's last tick number (loop thread only)
        self._push_pending = False     # a push is scheduled on the loop (coalesces a burst of images)
        self.pushes = 0                # pushes that sent samples (tests, bench)
        self._rr = 0                   # where the next sampling round starts (round robin over connections)
        self.samples_dropped = 0       # samples not sent because their connection was behind (all connections)

    @property
    def bound_address(self) -> tuple[str, int]:
        if self._bound is None:
            raise RuntimeError("AdsServer not started")
        return self._bound

    @property
    def connection_count(self) -> int:
        return len(self._sessions)

    def subscription_count(self) -> int:
        return sum(len(s.subs) for s, _ in list(self._sessions.values()))

    # -- lifecycle ----------------------------------------------------------------------------------
    def start(self) -> None:
        ready = threading.Event()
        error: list[BaseException] = []

        def run() -> None:
            loop = asyncio.new_event_loop()
            self._loop = loop
            try:
                loop.run_until_complete(self._open())
            except BaseException as exc:
                error.append(exc)
                ready.set()
                loop.close()
                return
            ready.set()
            try:
                loop.run_forever()
            finally:
                loop.run_until_complete(loop.shutdown_asyncgens())
                loop.close()

        self._thread = threading.Thread(target=run, name="nc-ads-server", daemon=True)
        self._thread.start()
        ready.wait()
        if error:
            self._thread.join()
            self._pool.shutdown(wait=False)
            raise error[0]
        log.info("ADS server %s listening on %s:%d, AMS ports %s", self.net_id, *self.bound_address,
                 sorted(self.dispatcher.devices))

    async def _open(self) -> None:
        host, port = self.listen
        self._server = await asyncio.start_server(self._serve, host, port, reuse_address=True,
                                                  limit=1 << 16)
        sock = self._server.sockets[0]
        self._bound = sock.getsockname()[:2]
        self._spawn(self._notifier())
        if self.push_on_change:
            for device in {id(d): d for d in self.dispatcher.devices.values()}.values():
                device.add_change_listener(self._image_arrived)

    def _spawn(self, coro) -> asyncio.Task:
        task = asyncio.get_running_loop().create_task(coro)
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)
        return task

    def close(self) -> None:
        """Stop listening, close every connection, wait for running device calls (bounded by the
        devices' own timeouts, and in all by about SHUTDOWN_WAIT_S: nc-ads must exit within 5 s of
        SIGTERM, whatever its clients do). Idempotent."""
        loop, thread = self._loop, self._thread
        if loop is None or thread is None or self._stopping:
            return
        self._stopping = True
        end = time.monotonic() + SHUTDOWN_WAIT_S
        if thread.is_alive():
            try:
                fut = asyncio.run_coroutine_threadsafe(self._shutdown(), loop)
                fut.result(timeout=SHUTDOWN_WAIT_S)
            except (concurrent.futures.TimeoutError, RuntimeError):
                log.warning("ADS server shutdown timed out after %.0f s", SHUTDOWN_WAIT_S)
            try:
                loop.call_soon_threadsafe(loop.stop)
            except RuntimeError:   # the loop already closed
                pass
            thread.join(timeout=max(0.1, end - time.monotonic()))
        # device calls still running end by their own timeouts in the (daemon) worker threads
        self._pool.shutdown(wait=not thread.is_alive() and time.monotonic() < end, cancel_futures=True)

    async def _shutdown(self) -> None:
        if self._server is not None:
            self._server.close()
        for session, writer in list(self._sessions.values()):
            if _unsent(writer) > NOTIFY_PAUSE_BUFFER:
                writer.transport.abort()   # a client that does not read: flushing to it would never end
            else:
                writer.close()
        tasks = [t for t in self._tasks if t is not asyncio.current_task()]
        for t in tasks:
            t.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)

    def __enter__(self) -> AdsServer:
        self.start()
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # -- connections --------------------------------------------------------------------------------
    async def _serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        task = asyncio.current_task()
        if task is not None:
            self._tasks.add(task)
            task.add_done_callback(self._tasks.discard)
        peername = writer.get_extra_info("peername") or ("?", 0)
        peer = f"{peername[0]}:{peername[1]}"
        if len(self._sessions) >= MAX_CONNECTIONS or self._stopping:
            log.warning("refusing ADS connection from %s: %d connections open (limit %d)", peer,
                        len(self._sessions), MAX_CONNECTIONS)
            writer.close()
            return
        sock = writer.get_extra_info("socket")
        if sock is not None:
            try:
                sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, SOCKET_SEND_BUFFER)
            except OSError:
                pass
        session = Session(next(self._conn_ids), peer)
        self._sessions[session.conn_id] = (session, writer)
        log.info("ADS connection %d from %s", session.conn_id, peer)
        assembler = ams.FrameAssembler()
        inflight = asyncio.Semaphore(MAX_INFLIGHT_PER_CONNECTION)
        pending: set[asyncio.Future] = set()
        loop = asyncio.get_running_loop()
        try:
            while True:
                chunk = await reader.read(65536)
                if not chunk:
                    break
                broken: ams.FrameError | None = None
                try:
                    packets = assembler.feed(chunk)
                except ams.FrameError as exc:
                    log.warning("ADS connection %d from %s: %s; closing it", session.conn_id, peer, exc)
                    broken, packets = exc, exc.packets   # answer the whole frames before it, then close
                for k, pkt in enumerate(packets, 1):
                    if self.dispatcher.runs_inline(pkt, session):
                        self._send(writer, self._safe_handle(pkt, session))
                        if k % INLINE_BATCH == 0:
                            await asyncio.sleep(0)   # a burst of requests (1000 adds in one read) lets others in
                        continue
                    await inflight.acquire()
                    fut = loop.run_in_executor(self._pool, self._safe_handle, pkt, session)
                    pending.add(fut)

                    def done(f: asyncio.Future, pkt=pkt) -> None:
                        pending.discard(f)
                        inflight.release()
                        if not f.cancelled() and f.exception() is None:
                            self._send(writer, f.result())
                    fut.add_done_callback(done)
                if broken is not None:
                    break
                if writer.transport.get_write_buffer_size() > MAX_WRITE_BUFFER:
                    # a client that sends but does not read: stop reading it until half is sent
                    # (not drain(): it waits for a low-water mark notifications may never let it reach)
                    while (writer.transport.get_write_buffer_size() > MAX_WRITE_BUFFER // 2
                           and not writer.is_closing()):
                        await asyncio.sleep(0.005)
        except (ConnectionError, OSError) as exc:
            log.info("ADS connection %d from %s: %s", session.conn_id, peer, exc)
        except asyncio.CancelledError:
            pass
        except Exception as exc:   # a bug in here ends this connection only, never the server
            log.error("ADS connection %d from %s: %r; closing it", session.conn_id, peer, exc, exc_info=exc)
        finally:
            self._sessions.pop(session.conn_id, None)
            if session.throttled:
                self._count_dropped(session, self._tick)
            freed = len(session.subs)
            session.subs.clear()
            with session.lock:
                session.sym_handles.clear()
            log.info("ADS connection %d from %s closed: %d notifications freed, %d samples dropped",
                     session.conn_id, peer, freed, session.samples_dropped)
            if pending:   # replies of requests already read still go out (then the close sends them)
                await asyncio.gather(*pending, return_exceptions=True)
            writer.close()
            self._connection_closed(session)

    def _connection_closed(self, session: Session) -> None:
        devices = {id(d): d for d in self.dispatcher.devices.values()
                   if id(d) in session.devices_used}

        def tell() -> None:
            for d in devices.values():
                try:
                    d.connection_closed(session.conn_id)
                except Exception as exc:
                    log.error("device %s: connection_closed raised %r", d.name, exc, exc_info=exc)
        if devices:
            try:
                self._pool.submit(tell)
            except RuntimeError:   # pool already shut down (server closing)
                tell()

    def _safe_handle(self, pkt: AmsPacket, session: Session) -> AmsPacket | None:
        try:
            return self.dispatcher.handle(pkt, session)
        except Exception as exc:    # a bug must not take the connection or the server down
            log.error("conn %d: handling command %d raised %r", session.conn_id, pkt.header.command,
                      exc, exc_info=exc)
            if pkt.header.command in ams.RESPONSES and not pkt.header.is_response:
                return pkt.reply(ams.error_response(pkt.header.command, ADSERR_DEVICE_ERROR).encode())
            return None

    @staticmethod
    def _send(writer: asyncio.StreamWriter, reply: AmsPacket | None) -> None:
        if reply is not None and not writer.is_closing():
            writer.write(reply.encode())   # one write per frame: frames never interleave (pitfall 9)

    # -- notifications ------------------------------------------------------------------------------
    def _image_arrived(self) -> None:
        """A device's change listener (any thread, e.g. NcDevice's frame thread): ServerOnChange samples go
        out now instead of on the next tick. Only schedules work on the loop, never runs it here."""
        loop = self._loop
        if self._push_pending or loop is None or self._stopping:
            return
        self._push_pending = True
        try:
            loop.call_soon_threadsafe(self._push)
        except RuntimeError:   # loop closed (server closed; the device outlives it)
            self._push_pending = False

    def _push(self) -> None:
        if self._stopping:
            self._push_pending = False
            return
        self._spawn(self._push_round())

    async def _push_round(self) -> None:
        try:   # the push counts as the next tick's check: a subscription is checked at most once per cycle
            await self._round(self._tick + 1, only_on_change=True)
        finally:
            self._push_pending = False   # images that arrived meanwhile: the next tick samples them

    async def _notifier(self) -> None:
        loop = asyncio.get_running_loop()
        start = loop.time()
        tick = 0
        while True:
            tick += 1
            self._tick = tick
            deadline = start + tick * self.tick_s
            delay = deadline - loop.time()
            if delay < -self.tick_s:   # late by more than a tick (loaded machine): skip, no burst
                tick = self._tick = int((loop.time() - start) / self.tick_s)
            await asyncio.sleep(max(0.0, delay))   # always yields: requests go on even when a round is late
            if any(s.subs for s, _ in self._sessions.values()):
                await self._round(tick, only_on_change=False)

    async def _round(self, tick: int, only_on_change: bool) -> None:
        """One sampling round over the connections, fair and bounded (docs/ads.md "A slow or hostile client"):
        - each distinct (device, group, offset, length) is sampled once per round (a shared cache);
        - connections the last round did not reach go first (none is starved), then those asking for fewer
          samples per tick (a client with a few notifications is never queued behind one with a
          thousand), equal ones in round robin;
        - a connection gets at most MAX_SAMPLES_PER_VISIT samples per round and no more than fit below
          NOTIFY_PAUSE_BUFFER unsent, the loop serves other work between two connections, and after
          NOTIFY_BUDGET_SHARE of a tick no further connection is started: what was left out is sampled in
          a later round (late; a ServerCycle subscription's cycles that passed meanwhile are dropped, counted);
        - a connection with more than NOTIFY_PAUSE_BUFFER unsent is not sampled at all (no cost to anyone
          else); what it missed is counted as dropped when it catches up or closes, logged once.
        The push (`only_on_change`) does not move the round robin."""
        sessions = list(self._sessions.values())
        if not sessions:
            return
        first = self._rr % len(sessions)
        # a connection the last round did not reach goes first (none is starved, whatever the others ask
        # for), however long it waited: among those, light ones before heavy ones (a light one left out once
        # must not queue behind fifty heavy ones left out longer); equal ones rotate (sorted() is stable)
        order = sorted(sessions[first:] + sessions[:first], key=lambda sw: (-min(sw[0].waited, 1), sw[0].load))
        now = time.monotonic()
        filetime = ams.filetime_now()
        cache: dict[tuple, bytes | None] = {}
        budget_end = time.perf_counter() + self.tick_s * NOTIFY_BUDGET_SHARE
        pushed = False
        for i, (session, writer) in enumerate(order):
            if i and time.perf_counter() > budget_end:
                if not only_on_change:
                    self._rr = sessions.index((session, writer))
                    for left, _ in order[i:]:
                        if left.subs:
                            left.waited += 1
                break
            if not only_on_change:
                session.waited = 0
            if not session.subs or writer.is_closing():
                continue
            if _unsent(writer) > NOTIFY_PAUSE_BUFFER:
                if not session.warned_behind:
                    session.warned_behind = True
                    log.warning("ADS connection %d from %s does not read: notifications paused, its samples are "
                                "dropped while more than %d bytes wait to be sent to it", session.conn_id,
                                session.peer, NOTIFY_PAUSE_BUFFER)
                session.throttled = True
                continue
            if session.throttled:
                self._count_dropped(session, tick)
            # at most what fits below NOTIFY_PAUSE_BUFFER (a visit must not queue megabytes to a slow reader)
            room = NOTIFY_PAUSE_BUFFER - _unsent(writer)
            limit = max(1, min(MAX_SAMPLES_PER_VISIT, room // (session.max_length + SAMPLE_OVERHEAD)))
            before = session.samples_dropped
            try:
                frames = self.dispatcher.collect(session, tick, now, filetime, only_on_change, cache, limit)
            except Exception as exc:
                log.error("notifications of connection %d: %r", session.conn_id, exc, exc_info=exc)
                continue
            self.samples_dropped += session.samples_dropped - before   # served late: missed cycles
            if frames and only_on_change and not pushed:
                pushed = True
                self.pushes += 1   # before the write: a client may look at it as soon as the frame arrived
            for frame in frames:
                writer.write(frame)
            await asyncio.sleep(0)   # the other connections' requests between two connections' samples

    def _count_dropped(self, session: Session, tick: int) -> None:
        """`session` was behind until now: what it missed is dropped (counted here and in the session)."""
        session.throttled = False
        self.samples_dropped += self.dispatcher.drop_missed(session, tick)
