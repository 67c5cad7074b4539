"""The NC's side of remote CiA 402 drives: a :class:`ProcessDataLink` over zenoh (keys in :mod:`.wire`).

:class:`RemoteLink` has its own zenoh session (client mode, explicit endpoints, no scouting), so nothing of it
touches the NC's own session or its declarations. Per NC cycle :meth:`RemoteLink.exchange`:

1. takes what arrived since the last cycle, without waiting: per host the newest ``tx`` sample from a zenoh ring
   channel of one (a subscriber per host, no Python thread of its own: the cycle thread decodes) and, every
   :data:`LIVELINESS_EVERY` cycles, the hosts' liveliness events from a FIFO channel;
2. returns the newest inputs of every axis with their ``age`` in NC cycles (0: arrived during this cycle;
   counted by the link: +1 per exchange without a new sample of the axis's host; 0 on a host never heard from:
   its axes are not ready, not in an I/O error) and ``alive`` (the host's liveliness token is there and it has
   sent inputs);
3. hands each host its outputs (``rx``, encoded in the cycle): put from the cycle thread (``sender = "cycle"``,
   default) or by a sender thread through a one-slot mailbox (``sender = "thread"``).

Decisions:

* The session opens in a background thread that retries every :data:`OPEN_RETRY` s until it is open or the link
  is closed: the link usually connects to the NC's own listen endpoint, which opens only after the drives are
  built (the server builds the drives first), and a router or drive host may start later than the NC. Until then
  every host is not alive and nothing is sent.
* The put from the cycle thread by default. The publishers use ``CongestionControl.DROP`` with the session's drop
  wait cut to :data:`DROP_WAIT_US` (zenoh's default waits up to 1 ms for a full queue), priority REAL_TIME, no
  express. Measured side by side in one run (bench/remote_drives.py, 4 axes, 2-core VM at load ~9): the drive's
  step (Cia402Drive + exchange) p50 159 us with the cycle's put against 192 us with the sender thread, p99 5.5
  against 6.7 ms, round trip p99 13 against 19 cycles, and the sender thread, competing for the GIL, put only
  about every second cycle's outputs (its mailbox keeps the newest). A put's own tail (0.5-2 ms p99 in a loaded
  process) shows in both. ``sender = "thread"`` stays for links with many hosts (one put each).
* No zenoh shared memory: a host's message is 100-700 bytes (8 axes: ~250), far below zenoh's SHM threshold
  (3 KiB) and the size where it helped on this VM (it brought nothing for ~400-byte payloads,
  zenoh-ruckig-notes.md A9); the cost per cycle is Python's (encode, decode), not the copy.
* ``rx`` carries the NC cycle; ``tx`` echoes the newest NC cycle the host applied (``rx_cycle``):
  :attr:`RemoteLink.round_trip` is the NC cycles between sending outputs and seeing them applied (a figure for
  the stats), and ``TxImage.rx_cycle`` per axis tells the drive which outputs a statusword answers (a drive
  leaving Operation enabled is judged by it, whatever the latency).

It may import: numpy, zenoh, nc_schema, nc_server.drives.cia402, nc_server.drives.remote.
"""
from __future__ import annotations

import json
import logging
import threading
import time
from dataclasses import dataclass
from typing import Any, Callable, Sequence

import numpy as np
import zenoh
from zenoh.handlers import FifoChannel, RingChannel

from ..cia402.image import ProcessDataLink, RxImage, TxImage
from . import wire

log = logging.getLogger("nc_server.drives.remote")

_TX_ATTRS = ("statusword", "mode_display", "position_actual", "velocity_actual", "torque_actual", "error_code",
             "probe_status", "probe_position", "probe2_pos", "probe2_neg", "age", "alive", "rx_cycle")

#: How often the link tries to open its session until it is open [s].
OPEN_RETRY = 0.1
#: How long a DROP put waits for a full transmit queue before it drops the message [us] (zenoh's default: 1000).
DROP_WAIT_US = 50
#: The hosts' liveliness events are taken every this many exchanges (a host that vanished is seen <= 5 ms later;
#: each look costs a few microseconds).
LIVELINESS_EVERY = 5
#: Liveliness events kept between two exchanges.
LIVELINESS_CHANNEL = 256
#: The link's connect retry (as the NC's own sessions: nc_schema.zenoh_config.CONNECT_RETRY).
CONNECT_RETRY = '{period_init_ms: 100, period_max_ms: 250, period_increase_factor: 1.5}'


@dataclass(frozen=True)
class HostSlots:
    """The axes one drive host serves.

    Attributes:
        host: its name (``nc/<nc>/drive/<host>``).
        rows: the link rows (axes of the remote backend, in order) of its slots 0, 1, ...
        ids: the AxisIds of those slots (sent with the outputs: the host checks them).
    """

    host: str
    rows: tuple[int, ...]
    ids: tuple[int, ...]


def link_config(endpoints: Sequence[str], lease_ms: int = 500, tls_dir: str | None = None,
                identity: str = "") -> zenoh.Config:
    """The link's (or a drive host's) session: client mode, ``connect`` to ``endpoints``, nothing else contacted.

    The first connection fails at once when nobody listens (the caller retries: :func:`open_retrying`); a lost one
    is retried every 100-250 ms. With ``tls_dir`` mutual TLS as ``identity`` (the NC's certificate for the NC's
    link, the host's own for a drive host).

    Raises:
        zenoh.ZError: zenoh rejected a value (an endpoint).
        ValueError: a certificate file is missing.
    """
    c = zenoh.Config()
    c.insert_json5("mode", '"client"')
    c.insert_json5("connect/endpoints", json.dumps(list(endpoints)))
    c.insert_json5("listen/endpoints", "[]")
    c.insert_json5("scouting/multicast/enabled", "false")
    c.insert_json5("scouting/gossip/enabled", "false")
    c.insert_json5("transport/link/tx/lease", json.dumps(int(lease_ms)))
    c.insert_json5("connect/retry", CONNECT_RETRY)
    c.insert_json5("connect/timeout_ms", "0")
    c.insert_json5("transport/link/tx/queue/congestion_control/drop/wait_before_drop", str(DROP_WAIT_US))
    if tls_dir:
        from nc_schema.tls import apply_tls
        apply_tls(c, tls_dir, identity)
    return c


def open_retrying(config: Callable[[], zenoh.Config], stop: threading.Event, what: str,
                  on_open: Callable[[zenoh.Session], None]) -> threading.Thread:
    """Open a session in a daemon thread, retrying every :data:`OPEN_RETRY` s until it is open or ``stop`` is set;
    then ``on_open(session)`` in that thread (a session opened after ``stop`` is closed at once). Logs the
    first failure and then every 10 s."""
    def run() -> None:
        last_log = -1e9
        while not stop.is_set():
            try:
                s = zenoh.open(config())
            except zenoh.ZError as exc:
                now = time.monotonic()
                if now - last_log >= 10.0:
                    log.info("%s: waiting to connect (%s)", what, str(exc).split(" at ")[0])
                    last_log = now
                stop.wait(OPEN_RETRY)
                continue
            if stop.is_set():
                s.close()
                return
            try:
                on_open(s)
            except Exception:  # a bug: say so, leave the link down rather than half open
                log.exception("%s: cannot declare on the session", what)
                s.close()
            return

    t = threading.Thread(target=run, name=f"open-{what}", daemon=True)
    t.start()
    return t


class RemoteLink(ProcessDataLink):
    """The process data of ``n`` remote CiA 402 drives on one or more drive hosts.

    Args:
        nc_name: the NC's name (key prefix).
        n: axes of the link (the remote backend's axes, in order).
        hosts: which rows each host serves (every row exactly once).
        config: a function returning the session's config (:func:`link_config`); None: no session (tests of the
            bookkeeping; every host stays not alive).
        sender: ``"cycle"`` (put from :meth:`exchange`) or ``"thread"`` (one-slot mailbox, sender thread).
        missing_warn_cycles: a host not heard from this many exchanges after the session opened is logged (once).

    Attributes (read by the drive and the stats; written by the cycle thread only):
        round_trip: per row, NC cycles from sending outputs to the host echoing them (-1: none yet).
        malformed: tx samples that could not be decoded or did not fit their host (counted, ignored).
        received: tx samples used; sent: rx messages put; send_errors: puts that raised.

    Raises:
        ValueError: a row missing or served twice, a bad host name, unknown ``sender``.
    """

    def __init__(self, nc_name: str, n: int, hosts: Sequence[HostSlots],
                 config: Callable[[], zenoh.Config] | None, sender: str = "cycle",
                 missing_warn_cycles: int = 5000) -> None:
        if sender not in ("cycle", "thread"):
            raise ValueError(f"sender must be 'cycle' or 'thread', got {sender!r}")
        rows = sorted(r for h in hosts for r in h.rows)
        if rows != list(range(n)):
            raise ValueError(f"the hosts must serve rows 0..{n - 1} once each, got {rows}")
        self.n = n
        self.nc_name = nc_name
        self.hosts = [h.host for h in hosts]
        if len(set(self.hosts)) != len(self.hosts):
            raise ValueError(f"a host listed twice: {self.hosts}")
        for h in self.hosts:
            wire.check_host(h)
        self.host_slots = list(hosts)
        self._missing_warn = int(missing_warn_cycles)
        self._since_open = 0
        self._rows = [np.asarray(h.rows, dtype=np.intp) for h in hosts]
        self._ids = [np.asarray(h.ids, dtype="<u4").tobytes() for h in hosts]
        # a host serving every row in order (the usual single host): its columns are the image's, no copy
        self._whole = [list(h.rows) == list(range(n)) for h in hosts]
        self._index = {h: i for i, h in enumerate(self.hosts)}
        self.sender = sender
        self._tx = TxImage.zeros(n)
        self._tx.alive[:] = False
        self._host_alive = np.zeros(len(hosts), dtype=bool)  # liveliness token present
        self._host_seen = np.zeros(len(hosts), dtype=bool)   # inputs arrived at least once
        self.round_trip = np.full(n, -1, dtype=np.int64)
        #: the epoch sent with the outputs (a hot standby's, docs/standby.md; 0 without redundancy), and the highest
        #: one a host reported following: above ``epoch``, another NC drives these hosts now
        self.epoch = 0
        self.host_epoch = 0
        #: the takeover limit of a hot-standby pair [ms] (0: none; its standby's limit in use, as its ha status's
        #: ``takeover_limit_ms``), sent with the outputs: a drive host warns when its silence timeout does not exceed
        #: it (nc_server.server.standby sets it)
        self.takeover_limit_ms = 0.0
        #: True: exchange() takes the inputs but sends nothing (a takeover's catch-up steps: only the last one's
        #: outputs go to the drives, nc_server.server.standby)
        self.mute = False
        #: the epoch of the newest drive host inputs taken (host_epoch is the highest ever seen)
        self.input_epoch = 0
        self._seen_rows = np.zeros(n, dtype=np.int64)  # 1 on the rows of hosts that sent inputs
        self.malformed = 0
        self.received = 0
        self.sent = 0
        self.send_errors = 0
        self._cycle = 0
        self._stop = threading.Event()
        self._session: zenoh.Session | None = None
        self._ready = False  # set by the opener thread once everything is declared
        self._pubs: list[Any] = []
        self._tx_subs: list[Any] = []
        self._live_sub: Any = None
        self._mail: list[bytes | None] = [None] * len(hosts)
        self._mail_lock = threading.Lock()
        self._mail_event = threading.Event()
        self._sender: threading.Thread | None = None
        self._opener = open_retrying(config, self._stop, f"drive link of {nc_name}", self._declare) \
            if config is not None else None

    # ---- session (opener thread) -----------------------------------------------------------------
    def _declare(self, s: zenoh.Session) -> None:
        self._pubs = [s.declare_publisher(wire.rx_key(self.nc_name, h), congestion_control=zenoh.CongestionControl.DROP,
                                          priority=zenoh.Priority.REAL_TIME) for h in self.hosts]
        # one ring of 1 per host: try_recv gives the newest sample (older ones were overwritten), no key to parse
        self._tx_subs = [s.declare_subscriber(wire.tx_key(self.nc_name, h), RingChannel(1)) for h in self.hosts]
        self._live_sub = s.liveliness().declare_subscriber(f"nc/{self.nc_name}/drive/*/alive",
                                                           FifoChannel(LIVELINESS_CHANNEL), history=True)
        self._session = s
        if self.sender == "thread":
            self._sender = threading.Thread(target=self._send_loop, name=f"drive-send-{self.nc_name}", daemon=True)
            self._sender.start()
        self._ready = True
        log.info("drive link of %s: connected, hosts %s", self.nc_name, ", ".join(self.hosts))

    @property
    def connected(self) -> bool:
        """The session is open and declared."""
        return self._ready

    # ---- the cycle -----------------------------------------------------------------------------------
    def exchange(self, rx: RxImage) -> TxImage:
        """Send this cycle's outputs, return the newest inputs (never waits for the network).

        The image returned is new each cycle (its arrays are not changed later: a drive may keep them)."""
        self._cycle += 1
        tx = self._tx
        tx.age = tx.age + self._seen_rows  # (a host never heard from is not ready, its data not "old": no 0x4655)
        if self._ready:
            self._since_open += 1
            if self._since_open == self._missing_warn and not self._host_seen.all():
                log.warning("drive link of %s: no inputs from drive host(s) %s since the link connected %d cycles ago "
                            "(is nc-drive-sim running with --host and this NC's name?)", self.nc_name,
                            ", ".join(h for h, seen in zip(self.hosts, self._host_seen) if not seen), self._since_open)
            if self._since_open % LIVELINESS_EVERY == 1 or LIVELINESS_EVERY == 1:
                self._take_liveliness()
            self._take_inputs(int(rx.cycle))
            if not self.mute:
                self._send(rx)
        out = TxImage(**{a: getattr(tx, a) for a in _TX_ATTRS})
        return out

    def peek(self) -> TxImage:
        """The newest inputs (the hosts' liveliness and newest ``tx``, which the link's subscriptions keep receiving
        also while nothing is sent, e.g. on a standby NC), sending nothing; the age of inputs that arrived since the
        last exchange is 0."""
        if self._ready:
            self._take_liveliness()
            self._take_inputs(None)
        return TxImage(**{a: getattr(self._tx, a) for a in _TX_ATTRS})

    def _take_liveliness(self) -> None:
        while True:
            try:
                s = self._live_sub.try_recv()
            except Exception:  # the session is closing
                return
            if s is None:
                return
            i = self._index.get(wire.host_of(str(s.key_expr)))
            if i is None:
                continue
            present = s.kind == zenoh.SampleKind.PUT
            if present != self._host_alive[i]:
                log.info("drive host %s of %s: %s", self.hosts[i], self.nc_name, "present" if present else "gone")
            self._host_alive[i] = present
            alive = self._tx.alive.copy()
            alive[self._rows[i]] = present and self._host_seen[i]
            self._tx.alive = alive

    def _take_inputs(self, nc_cycle: int | None) -> None:
        """The newest ``tx`` of each host (``nc_cycle``: this exchange's NC cycle, for the round trip; None: a peek,
        no round trip)."""
        tx = self._tx
        cols: dict[str, np.ndarray] | None = None
        for i, sub in enumerate(self._tx_subs):
            try:
                s = sub.try_recv()
            except Exception:  # the session is closing
                return
            if s is None:
                continue
            try:
                new, _, rx_cycle, host_epoch = wire.decode_tx_columns(s.payload.to_bytes())
            except Exception as exc:  # (WireError; anything else from a host's bytes must not stop the NC cycle)
                self._malformed(i, str(exc) or type(exc).__name__)
                continue
            rows = self._rows[i]
            if len(new["statusword"]) != len(rows):
                self._malformed(i, f"{len(new['statusword'])} slots, the NC has {len(rows)} axes on it")
                continue
            if cols is None:  # (new arrays: the drive may hold the last cycle's)
                cols = {} if self._whole[i] else {a: getattr(tx, a).copy() for a, _ in wire.TX_COLUMNS.values()}
                age, alive, rtt, answered = tx.age.copy(), tx.alive, self.round_trip.copy(), tx.rx_cycle.copy()
            if self._whole[i]:
                cols.update(new)  # read-only views of the message: nobody writes into an input
            else:
                for a, c in new.items():
                    cols[a][rows] = c
            age[rows] = 0
            answered[rows] = rx_cycle  # (the statusword answers these outputs: the drive judges drops by it)
            rtt[rows] = nc_cycle - rx_cycle if rx_cycle and nc_cycle is not None else -1
            if host_epoch > self.host_epoch:
                self.host_epoch = host_epoch
            self.input_epoch = host_epoch
            self.received += 1
            if not self._host_seen[i]:
                self._host_seen[i] = True
                self._seen_rows = self._seen_rows.copy()
                self._seen_rows[rows] = 1
                log.info("drive host %s of %s: inputs arrive", self.hosts[i], self.nc_name)
                alive = alive.copy()
                alive[rows] = self._host_alive[i]
        if cols is None:
            return
        for a, c in cols.items():
            setattr(tx, a, c)
        tx.age, tx.alive, self.round_trip, tx.rx_cycle = age, alive, rtt, answered

    def _malformed(self, i: int, why: str) -> None:
        self.malformed += 1
        if self.malformed <= 3 or self.malformed % 1000 == 0:
            log.warning("drive host %s of %s: unusable inputs (%s; %d so far)", self.hosts[i], self.nc_name, why,
                        self.malformed)

    def _send(self, rx: RxImage) -> None:
        msgs = [wire.encode_rx(rx, None if whole else rows, ids, self.epoch, self.takeover_limit_ms)
                for rows, ids, whole in zip(self._rows, self._ids, self._whole)]
        if self.sender == "thread":
            with self._mail_lock:
                self._mail = list(msgs)  # one slot per host: a message not yet sent is replaced by the newer one
            self._mail_event.set()
            return
        for pub, m in zip(self._pubs, msgs):
            self._put(pub, m)

    def _put(self, pub: Any, m: bytes) -> None:
        try:
            pub.put(m)
            self.sent += 1
        except Exception as exc:  # the session closing; never raise into the NC cycle
            self.send_errors += 1
            if self.send_errors <= 3:
                log.warning("drive link of %s: put failed: %s", self.nc_name, exc)

    def _send_loop(self) -> None:
        while not self._stop.is_set():
            self._mail_event.wait(0.5)
            self._mail_event.clear()
            with self._mail_lock:
                msgs, self._mail = self._mail, [None] * len(self._pubs)
            for pub, m in zip(self._pubs, msgs):
                if m is not None and not self._stop.is_set():
                    self._put(pub, m)

    def figures(self) -> list[dict[str, Any]]:
        """Per axis (row) for the NC's stats ``drive_link``: its ``host``, whether the host is ``alive`` (token there,
        inputs seen), the ``age`` of its inputs and the ``round_trip`` of its outputs [NC cycles; -1: none yet]."""
        age, rtt = self._tx.age.tolist(), self.round_trip.tolist()  # (arrays replaced by the cycle, not written)
        out: list[dict[str, Any]] = [{} for _ in age]
        for i, h in enumerate(self.hosts):
            alive = bool(self._host_alive[i] and self._host_seen[i])
            for r in self.host_slots[i].rows:
                out[r] = {"link": "remote", "host": h, "alive": alive, "age": int(age[r]), "round_trip": int(rtt[r])}
        return out

    def stats(self) -> dict[str, Any]:
        """Counters of the link as a whole: per host alive / heard from, the axes' current input age and round trip
        [NC cycles], tx samples used, malformed, rx sent, failed puts (per axis: :meth:`figures`)."""
        return {"hosts": {h: {"alive": bool(a), "seen": bool(s)}
                          for h, a, s in zip(self.hosts, self._host_alive, self._host_seen)},
                "age": self._tx.age.tolist(), "round_trip": self.round_trip.tolist(), "received": self.received,
                "malformed": self.malformed, "sent": self.sent, "send_errors": self.send_errors}

    # ---- teardown -------------------------------------------------------------------------------------
    def close(self) -> None:
        """Stop the exchange, close the session (idempotent; the hosts see the NC go silent)."""
        self._stop.set()
        self._mail_event.set()
        self._ready = False
        if self._sender is not None:
            self._sender.join(2.0)
        if self._opener is not None:
            self._opener.join(2.0)
        s, self._session = self._session, None
        if s is not None and not s.is_closed():
            try:
                s.close()
            except Exception as exc:
                log.warning("drive link of %s: close: %s", self.nc_name, exc)
