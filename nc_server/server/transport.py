"""The NC's zenoh side: session, declarations, PLCTONC inbox and the I/O thread.

Threads (all created by the thread that calls :meth:`Transport.open`, before the cycle thread
takes SCHED_FIFO, so none inherits it):

* zenoh's own Rust threads;
* liveliness events and command queries wait in zenoh channels (a FIFO and a ring) that the cycle
  thread polls (``try_recv``) at each cycle start and each idle slice (every <= 0.5 ms): no Python
  code runs on zenoh's threads for them. A Python callback there must take the GIL: the link's
  receive task stands still until it has it, and the thread holding it then competes with the cycle
  thread for the GIL (on a loaded 2-core machine such a holder was taken off the CPU for
  milliseconds while the cycle thread waited to run: missed NC cycles, bench/many_clients.py);
* PLCTONC frames wait in a zenoh ring channel; the cycle thread decodes them between cycles and
  before each cycle's inputs (:meth:`Transport.take_plctonc`), keeping only the newest one per
  client (:attr:`Transport.plc_inbox`);
* the I/O thread (:class:`IoThread`): replies, stats, and the claims map ``nc/<nc>/claims`` (made by
  the cycle thread when something changed, published here on every change and every
  :data:`CLAIMS_PERIOD`). The frames (``nc/<nc>/frame``, ``.../frame/<P>ms``, ``.../status`` and the
  per-axis samples) are not put here: the cycle writes them into shared memory and the frame
  publisher puts them, by default from a child process (:mod:`.publisher`), so that no put holds
  this process's GIL.

The cycle thread never waits for zenoh: it pops the query and liveliness inboxes, polls the PLCTONC
channel (``try_recv``), hands replies to the I/O thread through a ``SimpleQueue`` and its frame to the
publisher through the frame ring.
"""
from __future__ import annotations

import collections
import json
import logging
import os
import queue
import threading
import time
from dataclasses import dataclass, field
from typing import Any, Callable, Iterator

import numpy as np
import zenoh
from zenoh.handlers import FifoChannel, RingChannel

from nc_schema import (
    NCTOPLC_DTYPE, PLC_AXIS_RECORD_DTYPE, PLC_FRAME_HEADER_DTYPE, PLC_FRAME_HEADER_STRUCT, PLC_FRAME_MAGIC, PLCTONC_DTYPE,
    WIRE_VERSION, Keys, check_client_id, decode_stamp_epoch, new_instance_id, pack,
)
from nc_schema.zenoh_config import CONNECT_RETRY

from nc_schema.tls import apply_tls

from nc_server.core.remote import MasterSample

from .config import ZenohSettings
from .cycle import demote_other_threads, raise_other_threads, set_realtime, set_thread_name

log = logging.getLogger("nc_server.server")

#: An NC behind a router that is not up yet retries its first connection this often [s] and says so this often [s].
ROUTER_RETRY_S = 0.25
ROUTER_WAIT_LOG_S = 10.0


class OpenCancelled(Exception):
    """The NC was told to stop while it waited for its router (:meth:`Transport.open`)."""

#: Pending queries kept (a ring channel; the cycle drains a bounded number per cycle); beyond, the
#: oldest is dropped by zenoh, which finalizes it without a reply (its querier sees no answer).
QUERY_CHANNEL = 1024
#: Liveliness events kept until the cycle takes them (a FIFO channel: none may be lost; it is drained
#: every <= 0.5 ms, so it is never near full: a full one would hold zenoh's receive task back).
LIVELINESS_CHANNEL = 4096
#: A PLCTONC sample's router stamp corrects its arrival time only if it is younger than this [s].
HLC_MAX_AGE = 0.25
#: How long a BLOCK message waits for a full transmit queue before zenoh closes the link [us] (zenoh: 5 s);
#: below the PLC's command timeout (1 s), as long as the default lease and watchdog: a client that reads
#: nothing for that long counts as frozen. So dropped it loses its liveliness token: the NC stops its
#: axes (0x8F01), as the lease would.
BLOCK_WAIT_BEFORE_CLOSE_US = 500_000
#: Largest message the NC's zenoh session accepts [bytes].
MAX_MESSAGE_BYTES = 4 * 1024 * 1024
#: PLCTONC frames kept between two drains by the cycle thread (newest kept; the cycle drains every
#: ~0.2 ms: 16 clients at 100 Hz bring ~2 per ms).
PLCTONC_CHANNEL = 1024
#: How often the I/O thread sets threads that inherited SCHED_FIFO back to normal [s].
DEMOTE_PERIOD = 1.0
#: Stats period [s].
STATS_PERIOD = 0.1
#: The claims map is published on every change and at least this often [s].
CLAIMS_PERIOD = 1.0
#: A reply held for the retain file waits at most this long [s], then goes out as 0x4002 (applied, not
#: confirmed kept): below the clients' command timeout (1 s), so a slow or hung fsync (SD card, eMMC, NFS)
#: gives the block a clear error in time, never a timeout (0x745) and the Halt that follows it.
HOLD_MAX = 0.8

_PREC = PLCTONC_DTYPE.itemsize
_PAREC = PLC_AXIS_RECORD_DTYPE.itemsize
assert PLC_AXIS_RECORD_DTYPE.fields is not None  # (a structured dtype)
_PC_OFF = int(PLC_AXIS_RECORD_DTYPE.fields["PlcToNc"][1])  # the PLCTONC's offset in a PLC_AXIS_RECORD
_PC_RAW = np.dtype(f"V{_PREC}")  # (a PLCTONC record as plain bytes: copied in one piece)
_ID_DTYPE = PLC_AXIS_RECORD_DTYPE.fields["AxisId"][0]
_ID_OFF = int(PLC_AXIS_RECORD_DTYPE.fields["AxisId"][1])
_PHDR = PLC_FRAME_HEADER_STRUCT


def zenoh_config(settings: ZenohSettings, identity: str | None = None,
                 access_control: dict[str, Any] | None = None, internal: str | None = None) -> zenoh.Config:
    """An explicit zenoh config: mode, listen/connect endpoints, no multicast or gossip scouting, lease;
    with ``settings.tls_dir`` mutual TLS as ``identity`` (its certificate; every endpoint ``tls/``),
    with ``access_control`` that section (``nc_server.security.acl``).

    The connect endpoints (``--mode client --connect EP``: an NC behind a router) are retried every
    100-250 ms once lost (``connect/retry``, :data:`nc_schema.zenoh_config.CONNECT_RETRY`; zenoh's
    default waits 1 s, doubling up to 4 s), so a restarted router or a link that comes back has
    the NC again within about a quarter of a second. The first connection fails at once
    (``connect/timeout_ms`` 0 in client mode); :meth:`Transport.open` retries it (an NC behind a router
    waits for the router, which may start later).

    With ``internal`` (a ``unixsock-stream/`` endpoint) the session also listens there, for the NC's own
    frame publisher (:mod:`.publisher`), also when TLS allows no other protocol.

    Raises:
        zenoh.ZError: zenoh rejected a value.
        nc_schema.tls.TlsError: a certificate file is missing.
    """
    c = zenoh.Config()
    c.insert_json5("mode", json.dumps(settings.mode))
    c.insert_json5("listen/endpoints", json.dumps(list(settings.listen)))
    c.insert_json5("connect/endpoints", json.dumps(list(settings.connect)))
    c.insert_json5("scouting/multicast/enabled", "false")
    c.insert_json5("scouting/gossip/enabled", "false")
    c.insert_json5("transport/link/tx/lease", json.dumps(int(settings.lease_ms)))
    # a BLOCK message (a reply: it takes the PLC's query's congestion control) to a peer whose queue stays
    # full waits at most this long, then zenoh closes that link: zenoh's 5 s held every other client's
    # replies back that long (one I/O thread sends them in order)
    c.insert_json5("transport/link/tx/queue/congestion_control/block/wait_before_close", str(BLOCK_WAIT_BEFORE_CLOSE_US))
    if settings.connect:
        c.insert_json5("connect/retry", CONNECT_RETRY)
    # zenoh's default accepts 1 GiB messages; nothing legitimate comes near 4 MiB here
    c.insert_json5("transport/link/rx/max_message_size", str(MAX_MESSAGE_BYTES))
    if internal is not None:
        c.insert_json5("listen/endpoints", json.dumps([*settings.listen, internal]))
    if settings.tls_dir:
        apply_tls(c, settings.tls_dir, identity or "")
        if internal is not None:
            c.insert_json5("transport/link/protocols", json.dumps(["tls", internal.split("/", 1)[0]]))
    if access_control is not None:
        c.insert_json5("access_control", json.dumps(access_control))
    return c


@dataclass
class PlcFrame:
    """The newest PLCTONC frame of one client.

    Attributes:
        arrival: monotonic arrival time [s].
        axis_ids: AxisId per record (uint32 array).
        plctonc: PLCTONC_AXIS_REF records (array, same length).
    """

    arrival: float
    axis_ids: np.ndarray
    plctonc: np.ndarray


def decode_plctonc(payload: bytes | bytearray | memoryview, arrival: float, max_bytes: int) -> PlcFrame:
    """Decode a client's PLCTONC frame (``nc/<nc>/plctonc/<client>``; pure, no zenoh).

    Args:
        payload: PLC_FRAME_HEADER + AxisCount x PLC_AXIS_RECORD.
        arrival: its arrival time [s] (becomes :attr:`PlcFrame.arrival`).
        max_bytes: the largest frame accepted (the header plus one record per configured axis).

    Raises:
        ValueError: longer than ``max_bytes``, wrong magic/version/sizes (``decode_plc_frame``),
            or an AxisId twice.
    """
    if len(payload) > max_bytes:
        raise ValueError("more records than axes")
    data = bytes(payload)
    # the checks of nc_schema.decode_plc_frame (tests/server/test_transport_pure.py holds them to it), without its
    # structured header and record arrays: 1600 frames a second from 16 clients, and those arrays were half the cost
    if len(data) < _PHDR.size:
        raise ValueError("PLC frame shorter than its header")
    magic, version, hsize, _, n, rs, _ = _PHDR.unpack_from(data)
    if magic != PLC_FRAME_MAGIC or version != WIRE_VERSION:
        raise ValueError(f"not a zenoh-nc v{WIRE_VERSION} PLC frame")
    if rs != _PAREC or hsize < _PHDR.size or len(data) != hsize + n * rs:
        raise ValueError("PLC frame sizes do not add up")
    # (the header's PlcCycle is not used by the NC: the watchdog goes by arrival time)
    # AxisIds and PLCTONC records: strided views of the records, copied out as raw bytes (a structured
    # array of 22 fields copied field by field cost ~10x more)
    if n == 0:  # (no records: no view into the buffer's end)
        return PlcFrame(arrival, np.zeros(0, _ID_DTYPE), np.zeros(0, PLCTONC_DTYPE))
    ids = np.ndarray((n,), _ID_DTYPE, data, hsize + _ID_OFF, (_PAREC,)).copy()
    if len(set(ids.tolist())) != n:
        raise ValueError("duplicate AxisId")
    plctonc = np.ndarray((n,), _PC_RAW, data, hsize + _PC_OFF, (_PAREC,)).copy().view(PLCTONC_DTYPE)
    return PlcFrame(arrival, ids, plctonc)


#: one remote master's samples kept between two cycles (the newest; more only after a stall)
REMOTE_CHANNEL = 64
_NCTOPLC_FIELDS = NCTOPLC_DTYPE.fields
assert _NCTOPLC_FIELDS is not None


def decode_master_sample(nc: str, axis: int, payload: bytes, attachment: bytes | None) -> MasterSample:
    """A remote master's per-axis sample: its NCTOPLC (256 B) and STAMP attachment (Cycle, NcTimeNs, Epoch).

    Raises:
        ValueError: wrong sizes, no STAMP, or the record of another axis.
    """
    if len(payload) != NCTOPLC_DTYPE.itemsize or attachment is None:
        raise ValueError("not an NCTOPLC sample with its STAMP")
    cycle, nc_time_ns, epoch = decode_stamp_epoch(attachment)
    r = np.frombuffer(payload, dtype=NCTOPLC_DTYPE, count=1)[0]
    if int(r["AxisId"]) != axis:
        raise ValueError(f"the record of axis {int(r['AxisId'])} on the key of axis {axis}")
    return MasterSample(nc, axis, int(cycle), int(nc_time_ns), float(r["SetPos"]), float(r["SetVelo"]),
                        float(r["SetAcc"]), float(r["SetJerk"]), int(r["CoupleState"]), int(epoch))


def liveliness_client(keys: Keys, key: str) -> str | None:
    """The client id of a client liveliness key ``nc/<nc>/client/<client>``; None for any other
    key or an invalid id (such a token is ignored: no valid request can name that client)."""
    head, sep, client = key.rpartition("/")
    if not sep or head != f"{keys.prefix}/client":
        return None
    try:
        return check_client_id(client)
    except ValueError:
        return None


def drain(sub: Any) -> Iterator[Any]:
    """The samples queued on a zenoh channel handler, without blocking; ends at the first empty poll or when the
    handler is undeclared (closing)."""
    while True:
        try:
            sample = sub.try_recv()
        except Exception:  # undeclared (closing)
            return
        if sample is None:
            return
        yield sample


_STOP = object()


class Transport:
    """Session and declarations of one NC.

    Args:
        settings: zenoh settings.
        keys: the NC's key expressions.
        axis_ids: configured axis ids (publishers are declared per axis, in this order).
        access_control: the zenoh ``access_control`` section its session enforces (None: none).
    """

    def __init__(self, settings: ZenohSettings, keys: Keys, axis_ids: list[int],
                 access_control: dict[str, Any] | None = None) -> None:
        self.settings = settings
        self.access_control = access_control
        self.keys = keys
        self.axis_ids = list(axis_ids)
        n = len(self.axis_ids)
        #: client id -> newest decoded frame (written by the subscriber thread, popped by the cycle).
        self.plc_inbox: dict[str, PlcFrame] = {}
        #: clients holding an axis (replaced by the cycle thread); frames of anybody else are dropped
        #: before decoding, so a flood of frames cannot cost the NC more than a dict lookup each
        self.holders: frozenset[str] = frozenset()
        #: (client id, present?) liveliness events in arrival order (take_liveliness, popped by the cycle).
        self.liveliness_events: collections.deque[tuple[str, bool]] = collections.deque()
        #: queries taken before the channel's (tests; try_recv_query pops them first)
        self.queries: collections.deque[Any] = collections.deque()
        self.queries_refused = 0  # (the ring channel drops the oldest query when full: not counted)
        self.replies_sent = 0
        self.reply_errors = 0
        self.liveliness_ignored = 0  # client tokens with an invalid id
        self.plc_frames = 0
        self.plc_malformed = 0
        self.plc_ignored = 0  # frames from clients that hold no axis
        self.remote_subs: list[tuple[str, int, Any]] = []  # (nc, AxisId, subscriber) of the remote masters
        self.remote_malformed = 0
        self._max_plc_frame = PLC_FRAME_HEADER_DTYPE.itemsize + len(self.axis_ids) * PLC_AXIS_RECORD_DTYPE.itemsize
        self.session: zenoh.Session | None = None
        #: an extra listen endpoint for the NC's frame publisher (set before open(); None: none)
        self.internal: str | None = None
        self._zid = ""
        self._decl: list[Any] = []
        #: this process's instance id: its token nc/<nc>/alive/<instance> tells clients a restart from a
        #: token that flapped (nc_schema.instance)
        self.instance = new_instance_id()

    # ---- setup / teardown -------------------------------------------------------------------
    def open(self, cancel: threading.Event | None = None, serve: bool = True) -> None:
        """Open the session and declare everything.

        An NC in client mode (behind a router) waits for its router: while no connect endpoint accepts,
        the open is retried every :data:`ROUTER_RETRY_S`, with a warning every :data:`ROUTER_WAIT_LOG_S`
        (a router started at the same time, e.g. by compose, may take seconds; exiting instead left the NC
        down for good where nothing restarts it).

        Args:
            cancel: set (e.g. by SIGTERM) to give up waiting for the router: raises :class:`OpenCancelled`.

        Raises:
            zenoh.ZError: e.g. the listen endpoint is in use.
            OpenCancelled: ``cancel`` was set while waiting for the router.
        """
        t0 = time.monotonic()
        next_log = t0
        while True:
            try:
                self.session = s = zenoh.open(zenoh_config(self.settings, self.keys.nc, self.access_control,
                                                           self.internal))
                break
            except zenoh.ZError as exc:
                if self.settings.mode != "client" or not self.settings.connect or "connect" not in str(exc).lower():
                    raise
                now = time.monotonic()
                if now >= next_log:
                    log.warning("waiting for a router at %s (%.0f s so far): %s", ", ".join(self.settings.connect),
                                now - t0, str(exc).split(" at ", 1)[0])
                    next_log = now + ROUTER_WAIT_LOG_S
                if cancel is not None and cancel.wait(ROUTER_RETRY_S):
                    raise OpenCancelled(f"stopped while waiting for a router at {', '.join(self.settings.connect)}")
                if cancel is None:
                    time.sleep(ROUTER_RETRY_S)
        self._zid = str(s.info.zid())
        k = self.keys
        self.queryable: Any = None
        self.token: Any = None
        self.instance_token: Any = None
        self.stats_pub: Any = None
        self.claims_pub: Any = None
        self.liveliness_sub = s.liveliness().declare_subscriber(k.client_alive_any, FifoChannel(LIVELINESS_CHANNEL),
                                                                history=True)
        # a channel drained by the cycle thread (take_plctonc), not a Python subscriber thread: that thread,
        # at normal priority and holding the GIL while decoding, made the SCHED_FIFO cycle thread wait
        # whenever the scheduler took it off the CPU (a loaded machine: NC cycles of tens of ms)
        self.plc_sub = s.declare_subscriber(k.plctonc_in_any, RingChannel(PLCTONC_CHANNEL))
        if serve:
            self.serve()

    def serve(self) -> None:
        """Declare what makes this process the NC its clients see: the command queryable, the stats and claims
        publishers, the NC's liveliness and instance tokens (at open; a hot standby at its takeover, with the
        active NC's instance id: docs/standby.md)."""
        s, k = self.session, self.keys
        if s is None or self.queryable is not None:
            return
        # channels polled by the cycle thread: no Python callback (and no GIL) on zenoh's threads
        self.queryable = s.declare_queryable(k.cmd_any, RingChannel(QUERY_CHANNEL), complete=True)
        pub: dict[str, Any] = dict(congestion_control=zenoh.CongestionControl.DROP, express=False)
        self.stats_pub = s.declare_publisher(k.stats, **pub)
        self.claims_pub = s.declare_publisher(k.claims)
        # (a standby in step already holds them: HotStandby hands them over before this call, no gap for the clients)
        if self.token is None:
            self.token = s.liveliness().declare_token(k.alive)
        if self.instance_token is None:
            self.instance_token = s.liveliness().declare_token(k.alive_instance(self.instance))

    def unserve(self) -> None:
        """Undeclare what :meth:`serve` declared (a replaced NC of a hot-standby pair; the tokens stay alive for the
        clients while the active NC holds the same ones)."""
        for name in ("queryable", "stats_pub", "claims_pub", "token", "instance_token"):
            d = getattr(self, name, None)
            setattr(self, name, None)
            if d is not None:
                try:
                    d.undeclare()
                except Exception:
                    pass
        self.queries.clear()

    def close(self) -> None:
        """Undeclare everything and close the session (idempotent, never raises)."""
        if self.session is None:
            return
        s, self.session = self.session, None
        items = [getattr(self, "token", None), getattr(self, "instance_token", None), *self._decl, getattr(self, "plc_sub", None),
                 getattr(self, "liveliness_sub", None), getattr(self, "queryable", None)]
        items += [getattr(self, "stats_pub", None), getattr(self, "claims_pub", None)]
        items += [sub for _, _, sub in self.remote_subs]
        self.remote_subs = []
        for d in items:
            if d is None:
                continue
            try:
                d.undeclare()
            except Exception:  # already undeclared or session closing: nothing to do
                pass
        self._decl.clear()
        try:
            s.close()
        except Exception as exc:
            log.warning("closing the zenoh session: %s", exc)

    # ---- command queries (a channel, polled by the cycle thread) --------------------------------
    def try_recv_query(self) -> Any:
        """The oldest pending query, or None (cycle thread; never blocks). Queries put into
        :attr:`queries` (tests) come first."""
        if self.queries:
            try:
                return self.queries.popleft()
            except IndexError:
                pass
        q = getattr(self, "queryable", None)
        if q is None:
            return None
        try:
            return q.try_recv()
        except Exception:  # undeclared (closing)
            return None

    def reply(self, q: Any, payload: bytes) -> bool:
        """Answer query ``q`` and finalize it (the I/O thread; never raises).

        Never from the cycle thread: a reply takes the query's congestion control (zenoh 1.10 ignores the
        replier's), BLOCK for the PLC clients' requests, and to a querier that froze with a full link it
        waits up to BLOCK_WAIT_BEFORE_CLOSE_US (zenoh's default: 5 s).
        """
        try:
            q.reply(q.key_expr, payload)
            self.replies_sent += 1
            return True
        except Exception as exc:  # e.g. the querier is gone; the NC keeps going
            self.reply_errors += 1
            log.debug("reply failed: %s", exc)
            return False
        finally:
            try:
                q.drop()  # finalize: the querier gets its answer now, not at its timeout
            except Exception:
                pass

    # ---- liveliness (a channel, polled by the cycle thread) ------------------------------------
    def take_liveliness(self) -> bool:
        """Move the liveliness events that arrived into :attr:`liveliness_events`; whether any is
        queued (cycle thread; never blocks)."""
        sub = getattr(self, "liveliness_sub", None)
        if sub is not None:
            for sample in drain(sub):
                self._on_liveliness(sample)
        return bool(self.liveliness_events)

    def _on_liveliness(self, sample: zenoh.Sample) -> None:
        client = liveliness_client(self.keys, str(sample.key_expr))
        if client is None:
            self.liveliness_ignored += 1
            return
        self.liveliness_events.append((client, sample.kind != zenoh.SampleKind.DELETE))

    def pop_liveliness(self) -> list[tuple[str, bool]]:
        """Liveliness events since the last call: (client id, True = token present / False = gone)."""
        ev = self.liveliness_events
        out = []
        while ev:
            out.append(ev.popleft())
        return out

    # ---- PLCTONC subscriber (a channel, drained by the cycle thread) ----------------------------
    def take_plctonc(self, limit: int = PLCTONC_CHANNEL) -> int:
        """Decode the PLCTONC frames that arrived into :attr:`plc_inbox` (at most ``limit``); how many
        (cycle thread, between cycles and before each cycle's inputs; never blocks)."""
        sub = getattr(self, "plc_sub", None)
        if sub is None:
            return 0
        n = 0
        while n < limit:
            try:
                sample = sub.try_recv()
            except Exception:  # undeclared (closing)
                break
            if sample is None:
                break
            n += 1
            self._on_plctonc(sample)
        return n

    def _on_plctonc(self, sample: zenoh.Sample) -> None:
        client = str(sample.key_expr).rsplit("/", 1)[-1]
        if client not in self.holders:
            self.plc_ignored += 1
            return
        now = time.monotonic()
        # The arrival time feeds the watchdog. Our router stamps every sample it receives (HLC,
        # wall clock) on zenoh's own thread; that stamp is used when it is ours, so a late run of
        # this Python thread (GIL, CPU load) cannot make a live client look silent.
        # (Only small ages are believed: the stamp is wall-clock time, and a step of the wall clock
        # must not make every frame look old - a late arrival time only ever makes a client look
        # fresher. Frames processed after an NC stall carry old stamps: ClaimTable never moves a
        # client's PLCTONC time backwards, and grace() covers the stall.)
        ts = sample.timestamp
        if ts is not None and str(ts.get_id()) == self._zid:
            age = time.time() - ts.get_time_as_ntp64().as_secs_f64()
            if 0.0 < age < HLC_MAX_AGE:
                now -= age
        try:
            if len(sample.payload) > self._max_plc_frame:  # before copying it out of zenoh
                raise ValueError("more records than axes")
            frame = decode_plctonc(sample.payload.to_bytes(), now, self._max_plc_frame)
        except Exception:  # malformed (ValueError): counted and dropped, never crash the subscriber
            self.plc_malformed += 1
            return
        self.plc_frames += 1
        self.plc_inbox[client] = frame  # newest wins

    # ---- remote masters (coupling across NCs): channels drained by the cycle thread ----------------
    def declare_remote_masters(self, masters: list[tuple[str, int]]) -> None:
        """Subscribe to the per-axis samples (``nc/<nc>/axis/<axis>/nctoplc``) of the masters on other NCs this
        NC's slaves may follow (``[remote] masters``; after :meth:`open`)."""
        assert self.session is not None
        for nc, axis in masters:
            sub = self.session.declare_subscriber(Keys(nc).axis_nctoplc(axis), RingChannel(REMOTE_CHANNEL))
            self.remote_subs.append((nc, axis, sub))

    def pop_master_samples(self) -> list[MasterSample]:
        """The remote masters' samples that arrived since the last call (cycle thread; never blocks). A malformed
        one is counted (``remote_malformed``) and dropped."""
        out: list[MasterSample] = []
        for nc, axis, sub in self.remote_subs:
            for sample in drain(sub):
                try:
                    out.append(decode_master_sample(nc, axis, sample.payload.to_bytes(),
                                                    None if sample.attachment is None else sample.attachment.to_bytes()))
                except ValueError:
                    self.remote_malformed += 1
        return out

    def pop_plc_frames(self) -> list[tuple[str, PlcFrame]]:
        """Take the newest frame of each client that sent one since the last call (cycle thread)."""
        self.take_plctonc()
        box = self.plc_inbox
        if not box:
            return []
        out = []
        for client in list(box):
            f = box.pop(client, None)  # atomic under the GIL: a frame stored meanwhile stays for next cycle
            if f is not None:
                out.append((client, f))
        return out


class IoThread:
    """Sends the replies and the periodic messages; never lets the network block the cycle.

    Replies in the order handed over (:meth:`Transport.reply`), but for those held for the retain file
    (below); stats every :data:`STATS_PERIOD`, the claims map on change and every :data:`CLAIMS_PERIOD`;
    every DEMOTE_PERIOD it sets threads that inherited SCHED_FIFO back to normal; with the stats it calls
    ``watch`` (the frame publisher's: restarts a child that died), all at most every STATS_PERIOD.

    Args:
        transport: the open transport.
        stats_source: returns the stats map (published every :data:`STATS_PERIOD` s).
        claims_source: returns (version, claims map) or None: the newest map the cycle thread made
            (never built here: the claim table belongs to the cycle thread); published when the
            version changes and every :data:`CLAIMS_PERIOD` s (then with ``cycle`` from ``cycle_source``).
        cycle_source: returns the NC's current cycle.
        rt_threads: see :attr:`rt_threads`.
        nice: the thread's nice value (``cycle.IO_THREAD_NICE``), set when it starts; None: inherited.
        others_nice: the nice value the process's other normal-policy threads get (``cycle.IO_NICE``: zenoh's
            threads, made lazily, some from the SCHED_FIFO cycle thread), every DEMOTE_PERIOD; None: left alone.
        watch: called every STATS_PERIOD (None: nothing).
        rt_priority: if given, the thread runs SCHED_FIFO at this priority (below the cycle thread's; with
            SCHED_RESET_ON_FORK, so the threads and processes it makes do not), else with ``nice``.
            It sends the replies and shares the cycle thread's GIL: at normal priority, taken off the
            CPU while holding the GIL, it made the cycle start late (bench/many_clients.py: lateness
            p99 100-260 us and 0.2-0.3 % overruns, against 13-22 us and 0.01-0.03 % as SCHED_FIFO). It
            never spins: it waits on its queue (at most STATS_PERIOD) and in zenoh's blocking calls.
        durability: returns (settled, durable) commit numbers of the retain file (:class:`~.retain.RetainKeeper`);
            None: no retain file (a reply handed over with a commit number is then sent at once).
        not_kept: ``not_kept(reply, late)`` turns a held reply into its error reply: its commit settled
            without being kept (``late`` False), or it waited :data:`HOLD_MAX` (``late`` True).

    Held replies (the retain file, ``durability``): a reply handed over with commit number n > 0 waits until
    the retain file's ``settled`` reaches n (the retain thread wakes this thread: :meth:`wake`), then goes out
    as it is when ``durable`` >= n, else as ``not_kept(reply, False)``. Only that reply waits: every other
    reply, of any client, goes out at once (replies to separate queries have no ordering guarantee; a
    client that needs one waits for the reply). A held reply waits at most :data:`HOLD_MAX`, then goes out
    as ``not_kept(reply, True)`` (0x4002: applied, not confirmed kept; it may still reach the file).
    """

    def __init__(self, transport: Transport, stats_source: Callable[[], dict[str, Any]],
                 claims_source: Callable[[], tuple[int, dict[str, Any]] | None] | None = None,
                 cycle_source: Callable[[], int] | None = None,
                 rt_threads: Callable[[], set[int]] | None = None, nice: int | None = None,
                 watch: Callable[[], None] | None = None, rt_priority: int | None = None,
                 durability: Callable[[], tuple[int, int]] | None = None,
                 not_kept: Callable[[bytes, bool], bytes] | None = None, others_nice: int | None = None) -> None:
        self.t = transport
        self.durability = durability
        self.not_kept = not_kept or (lambda reply, late: reply)
        #: held replies, in the order handed over: (query, reply, commit number, deadline [s, monotonic]);
        #: commit numbers and deadlines both never fall along it: its head is the first to go
        self.held: collections.deque[tuple[Any, bytes, int, float]] = collections.deque()
        self.replies_held = 0  # replies that waited for the retain file
        self.replies_not_kept = 0  # held replies sent as 0x4002 (write failed, or not kept within HOLD_MAX)
        self.rt_priority = rt_priority
        #: True while this thread runs SCHED_FIFO
        self.realtime = False
        #: the thread's nice value, set from inside it (None: inherited)
        self.nice = nice
        self.priority = "inherited"
        self.stats_source = stats_source
        self.claims_source = claims_source or (lambda: None)
        self.cycle_source = cycle_source
        self.watch = watch
        self.claims_sent = 0
        self._claims_version: int | None = None
        self._next_claims = 0.0
        #: native ids of the threads meant to run SCHED_FIFO (empty: none); any other thread that inherited
        #: it is set back to normal every DEMOTE_PERIOD (see cycle.demote_other_threads)
        self.rt_threads = rt_threads
        self.demoted: list[int] = []
        #: the nice value every other normal-policy thread of the process gets every DEMOTE_PERIOD (None: left
        #: alone; see cycle.raise_other_threads)
        self.others_nice = others_nice
        self.q: queue.SimpleQueue[Any] = queue.SimpleQueue()
        self.put_errors = 0
        self.errors = 0  # exceptions caught in its loop (a bug)
        self._thread = threading.Thread(target=self._main, name="nc-io", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def submit_replies(self, replies: list[tuple[Any, bytes]] | list[tuple[Any, bytes, int]]) -> None:
        """Hand (query, reply) pairs, or (query, reply, commit number) for a reply that waits for the retain
        file (0: none), over (cycle thread; never blocks): answered in this order, a held one later (see the class)."""
        self.q.put(replies)

    def wake(self) -> None:
        """The retain file settled commits: send the held replies that may go (any thread; never blocks)."""
        self.q.put(())

    def _reply(self, q: Any, payload: bytes, commit: int = 0) -> None:
        """Send one reply handed over, or hold it until the retain file holds its commit (at most HOLD_MAX)."""
        if commit == 0 or self.durability is None:
            self.t.reply(q, payload)
            return
        self.held.append((q, payload, commit, time.monotonic() + HOLD_MAX))
        self.replies_held += 1

    def _release_held(self, everything: bool = False) -> None:
        """Send the held replies whose commit settled or whose HOLD_MAX ran out (``everything``: all of them);
        those not kept as errors."""
        if not self.held or self.durability is None:
            return
        settled, durable = self.durability()
        now = time.monotonic()
        held = self.held
        while held:
            q, payload, commit, deadline = held[0]
            if commit <= settled or everything:
                if commit > durable:
                    payload = self.not_kept(payload, False)
                    self.replies_not_kept += 1
            elif now >= deadline:
                payload = self.not_kept(payload, True)
                self.replies_not_kept += 1
            else:
                break  # (the rest settle later and run out later)
            held.popleft()
            self.t.reply(q, payload)

    def _wait_time(self) -> float:
        """How long the loop may wait for the queue [s]: STATS_PERIOD, less when a held reply runs out sooner."""
        if not self.held:
            return STATS_PERIOD
        return min(STATS_PERIOD, max(0.0, self.held[0][3] - time.monotonic()))

    def stop(self, timeout: float = 5.0) -> None:
        """Send the replies handed over, then end the thread (after a last stats put)."""
        self.q.put(_STOP)
        self._thread.join(timeout)

    @property
    def native_id(self) -> int | None:
        return self._thread.native_id

    def _main(self) -> None:
        set_thread_name("nc-io")
        if self.rt_priority is not None:
            if set_realtime("auto", self.rt_priority)[0] == "SCHED_FIFO":  # (else not permitted: nice below)
                self.realtime = True
                self.priority = f"SCHED_FIFO priority {self.rt_priority}"
        if not self.realtime and self.nice is not None:
            try:
                os.setpriority(os.PRIO_PROCESS, 0, self.nice)  # pid 0: this thread (Linux: nice is per thread)
                self.priority = f"nice {self.nice}"
            except (OSError, AttributeError) as exc:
                self.priority = f"inherited (nice {self.nice} not permitted: {exc})"
        next_stats = time.monotonic() + STATS_PERIOD
        next_demote = time.monotonic() + DEMOTE_PERIOD
        running = True
        while running:
            try:
                item = self.q.get(timeout=self._wait_time())
            except queue.Empty:
                item = None
            try:
                while item is not None:
                    if item is _STOP:
                        running = False
                    else:
                        for entry in item:
                            self._reply(*entry)
                    try:
                        item = self.q.get_nowait()
                    except queue.Empty:
                        item = None
                self._release_held(everything=not running)
                now = time.monotonic()
                if now < next_stats and running:
                    continue  # (replies arrive up to once per cycle: the periodic work stays periodic)
                next_stats = now + STATS_PERIOD
                self._publish_stats()
                self._publish_claims(now)
                if now >= next_demote:
                    next_demote = now + DEMOTE_PERIOD
                    keep = self.rt_threads() if self.rt_threads is not None else set()
                    if keep:
                        self.demoted += demote_other_threads(keep)
                    if self.others_nice is not None:
                        raise_other_threads(keep | {threading.get_native_id()}, self.others_nice)
                if self.watch is not None and running:
                    self.watch()
            except Exception:  # never let anything end the I/O thread (the replies would pile up)
                self.errors += 1
                log.exception("I/O thread")

    def _publish_claims(self, now: float) -> None:
        try:
            got = self.claims_source()
            if got is None:
                return
            version, msg = got
            if version == self._claims_version and now < self._next_claims:
                return
            if version == self._claims_version and self.cycle_source is not None:
                msg = {**msg, "cycle": int(self.cycle_source())}  # unchanged: republished as of now
            self._claims_version = version
            self._next_claims = now + CLAIMS_PERIOD
            if self.t.claims_pub is None:  # (a standby NC: not serving)
                return
            self.t.claims_pub.put(pack(msg))
            self.claims_sent += 1
        except Exception as exc:
            self.put_errors += 1
            log.debug("claims put failed: %s", exc)

    def _publish_stats(self) -> None:
        if self.t.stats_pub is None:  # (a standby NC: not serving)
            return
        try:
            self.t.stats_pub.put(pack(self.stats_source()))
        except Exception as exc:
            self.put_errors += 1
            log.debug("stats put failed: %s", exc)
