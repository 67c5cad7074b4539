"""PlcRuntime: the cyclic PLC task over zenoh (one session per NC, client mode).

Per NC (``ncs={"nc1": "tcp/127.0.0.1:7447"}``) the runtime opens one client link (:class:`nc_link.NcLink`:
the session, its declarations, the NC's liveliness and instance), a zenoh session with an
explicit configuration - never zenoh's defaults:

* ``mode: client``, ``connect/endpoints: [<the NC's endpoint>]``: a client is relayed by the
  NC's router and needs no listen socket of its own;
* multicast and gossip scouting off: only the configured endpoint is ever contacted;
* ``connect/retry``: a lost connection is retried every 100-250 ms (:data:`CONNECT_RETRY`);
* ``transport/link/tx/lease: 500`` ms (``lease_ms``, :data:`DEFAULT_LEASE_MS`): the lease this PLC
  announces, so a frozen PLC is dropped by the NC (its liveliness token vanishes: 0x8F01 on what it
  held, its motions stop) within ~0.4 s instead of zenoh's default ~7.5 s.

Declared on it: a subscriber on the status frames with a ``RingChannel(1)`` (only the newest
frame is kept; the cycle takes it with ``try_recv``), liveliness subscribers on ``nc/<nc>/alive`` (to notice an
unreachable NC at once) and ``nc/<nc>/alive/*`` (the NC process's instance token: a restart), the liveliness token ``nc/<nc>/client/<client_id>`` (the NC accepts claims only
from live clients and drops them when the token disappears) and a publisher for
``nc/<nc>/plctonc/<client_id>``.

Frames: the PLC reads one frame per cycle of its own axes only. It declares its view, the liveliness
token ``nc/<nc>/select/<client_id>/<P>ms/<axes>`` (the AxisIds its AXIS_REFs name on that NC, updated
when an AXIS_REF is bound later), and subscribes to ``nc/<nc>/view/<client_id>``: the NC's frame cut to
those axes, once per P ms of NC time, P the longest of ``nc_schema.VIEW_PERIODS_MS`` of at most one
cycle (``nc_schema.view_period_ms``: 10 ms at 10 ms; ``frame_period`` overrides it; 0 or a cycle shorter than
2 ms: every NC cycle). One frame per PLC cycle on average, so the data a cycle reads is at most one period
old (plus the link's latency); at half the cycle, as before, each frame woke the client's zenoh threads
twice as often (issue 19: ~0.5 % of a core per client at 10 ms). A 4-axis client of a 64-axis NC receives
and decodes 1.6 kB instead of 24.6 kB (before views, 16 such clients cost the NC's transport ~5 % of a core
each). A client without axes on an NC declares a view of none at ``nc_schema.IDLE_VIEW_PERIOD_MS`` (100 ms):
its frames only show the NC is there (:class:`nc_link.NcLink`).
Each view frame's attachment lists the axes it was cut for: an AXIS_REF bound later is not among them
until the NC has seen the new token (a few ms), and meanwhile has no data and is ``pending`` (its blocks'
calls wait, :mod:`plc_client.fb.base`), where one that is listed but absent is not on the NC (0x4012).
``view=False`` takes the whole frame on ``nc/<nc>/frame/<P>ms`` (or ``nc/<nc>/frame``) instead, as
clients of protocol version 2 did.

No Python code runs on zenoh's threads in a PLC client: frames, liveliness events and replies go
through zenoh channels that the cycle polls. A Python callback there (a reply callback, as the
runtime had) must take the GIL, and while it waits for it the link's receive task stands still:
no frame arrives on that session. On a loaded machine the GIL holder (the PLC thread in its cycle)
can be off the CPU for long, and a client saw no frame for more than 0.2 s (0x4B0F) while another
subscriber got every frame (tests/integration/test_plc_frame_starvation.py).

A zenoh client cannot open a session while its router is down, so a session that fails to
open is retried every ``reconnect_period`` seconds by a background thread while the PLC keeps
cycling (its axes stay invalid: blocks report 0x4B0F). An open session reconnects by itself
when the NC restarts; the runtime then sees a new NC instance (an instance token with another id, or
the frames' cycle counter going back: :class:`nc_schema.NcInstance`), stops following the old instance's
commands and claims again. The NC's liveliness token going away makes its data invalid at once, but is no
restart: zenoh drops the link (and the tokens with it) whenever this process, the NC or a router is starved
for a lease, and the same NC instance (the same instance id) is back 0.1-0.3 s later.

Commands (:class:`ZenohPort`) are ``session.get`` queries on the command's key
``nc/<nc>/axis/<id>/cmd/<class>/<client_id>`` (``Keys.command_key``; NC-level commands on
``nc/<nc>/cmd/<class>/<client_id>``) with a ``FifoChannel`` each; the cycle polls the channels of
the queries in flight (``try_recv``, no thread per query, nothing on zenoh's threads); the zenoh
query timeout (``query_timeout``, default 5 x command_timeout) is longer than
the blocks' Timeout so that a late acceptance still reaches the task (see
:mod:`plc_client.task`).

Each cycle (``cycle_time``, default 10 ms): newest frame -> AXIS_REF snapshots, replies, the
program, one batched PLCTONC frame per NC. Cycles are paced on ``time.monotonic``; a late
cycle is counted in ``overruns`` and never replayed.

Shutdown (:meth:`PlcRuntime.stop`, SIGINT/SIGTERM in :meth:`PlcRuntime.run`): the program is no
longer called; frames with all enables off are sent for ``shutdown_cycles`` cycles, then the
claims are released (waiting up to ``command_timeout`` for the replies; not sent to an NC whose
liveliness token is gone), the tokens undeclared and the sessions closed. Every step has a
deadline, so a dead or frozen NC cannot hold the PLC up: closing a zenoh session waits for the
session's pending work, e.g. a reconnection handshake with an NC that accepted the TCP
connection but does not answer (frozen, or a loaded machine), which zenoh ends only after its
``open_timeout`` (10 s). So the sessions are closed in helper threads, waited for at most
``close_timeout`` seconds; a session still closing then is left to the process exit (its
liveliness token was undeclared first, and the NC drops the claims when the connection ends;
``plc-run`` then ends with ``os._exit``). The SIGINT/SIGTERM handler only sets a flag (no lock
is taken in a signal handler); the cycle sees it within one cycle time.
"""
from __future__ import annotations

import logging
import math
import os
import re
import signal
import socket
import threading
import time
from typing import Any, Iterable, Mapping

import zenoh
from zenoh.handlers import FifoChannel

from nc_link import NcLink, check_tls
# the one client config builder, re-exported (plc_client.runtime.client_config, DEFAULT_LEASE_MS, ...)
from nc_link import CONNECT_RETRY, CONNECT_TIMEOUT_MS, DEFAULT_LEASE_MS, client_config  # noqa: F401
from nc_link.link import BACK, GONE, RESTART
from nc_schema import (
    ErrorCodes, Keys, check_client_id, encode_plc_records, frame_period_ms, make_reply,
    parse_reply, parse_view_axes, view_period_ms,
)

from .axis_ref import AXIS_REF
from .port import CommandPort, PendingCommand
from .task import PlcTask

log = logging.getLogger(__name__)

#: Replies kept per query until the PLC cycle takes them (the NC sends one).
REPLY_CHANNEL = 4
#: The longest wait between cycles taken as a plain sleep [s] (longer ones: on the stop event)
SLEEP_MAX = 0.05
#: A reachable NC that sends no view frame for this long [s] is worth a warning (_no_view_yet)
NO_VIEW_WARNING = 5.0


def plc_frame(plc_cycle: int, axes: list[AXIS_REF]) -> bytes:
    """The PLC frame of ``axes`` (their ids and PlcToNc records): ``nc_schema.encode_plc_records``."""
    return encode_plc_records(plc_cycle, [(ax.axis_id, ax._plctonc) for ax in axes])


def default_client_id() -> str:
    """``plc-<host>-<pid>``, restricted to the characters a client id may use."""
    host = re.sub(r"[^A-Za-z0-9_.-]", "_", socket.gethostname())[:40] or "host"
    return f"plc-{host}-{os.getpid()}"


#: the link of one NC (nc_link's; by its former name here)
_NcLink = NcLink


class ZenohPort(CommandPort):
    """Command port over zenoh queries (see the module docstring).

    Args:
        client_id: this client's id.
        links: the NC links by name (shared with the runtime).
        query_timeout: zenoh query timeout [s].
    """

    def __init__(self, client_id: str, links: Mapping[str, NcLink], query_timeout: float = 5.0) -> None:
        super().__init__(client_id)
        self.links = links
        self.query_timeout = float(query_timeout)
        #: queries in flight: (command, the zenoh reply channel of its get)
        self._inflight: list[tuple[PendingCommand, Any]] = []

    def _transmit(self, pending: PendingCommand, payload: bytes) -> None:
        link = self.links.get(pending.nc)
        if link is None or not link.ready or link.session is None:
            self._deliver(pending, None, ErrorCodes.ADSERR_DEVICE_NOTREADY)
            return
        try:
            key = link.keys.command_key(pending.cmd, pending.axis_id, self.client_id)
        except ValueError as exc:  # e.g. a negative axis id: there is no such key
            self._deliver(pending, make_reply(pending.id, pending.cmd, ErrorCodes.NC_AXIS_ID_NOT_ALLOWED, str(exc)))
            return
        try:
            # a channel, not a Python callback: zenoh's receive thread never waits for the GIL
            rx = link.session.get(key, FifoChannel(REPLY_CHANNEL), payload=payload, timeout=self.query_timeout,
                                  consolidation=zenoh.ConsolidationMode.NONE)
        except Exception as exc:  # session closing
            log.debug("get on %s failed: %s", key, exc)
            self._deliver(pending, None, ErrorCodes.ADSERR_DEVICE_NOTREADY)
            return
        self._inflight.append((pending, rx))

    def _collect(self) -> None:
        """Move the replies that arrived into the inbox (PLC thread; never blocks)."""
        if not self._inflight:
            return
        keep = []
        for pending, rx in self._inflight:
            try:
                reply = rx.try_recv()
            except Exception:  # "empty and closed": the query ended without a reply (no NC, timeout)
                self._deliver(pending, None, ErrorCodes.ADSERR_CLIENT_SYNCTIMEOUT)
                continue
            if reply is None:
                keep.append((pending, rx))
                continue
            # the first reply answers the command; dropping the channel ends our interest in the query
            self._deliver(pending, *_reply_of(reply))
        self._inflight = keep

    def poll(self) -> list[PendingCommand]:
        self._collect()
        return super().poll()


def _reply_of(reply: Any) -> tuple[dict[str, Any] | None, int]:
    """(reply map, 0) of a zenoh reply, or (None, error code) for an error reply or a bad payload."""
    ok = reply.ok
    if ok is None:
        return None, ErrorCodes.ADSERR_CLIENT_SYNCTIMEOUT
    try:
        return parse_reply(ok.payload.to_bytes()), 0
    except ValueError:  # not a reply the blocks could act on (error/cycle/CmdNo not integers, ...)
        return None, ErrorCodes.ADSERR_DEVICE_INVALIDDATA


class PlcRuntime(PlcTask):
    """The PLC task over zenoh (see the module docstring).

    Args:
        program: a callable ``program(plc)``, or an object with ``cycle(plc)`` / ``cycle()``.
        ncs: NC name -> zenoh endpoint of its server, e.g. ``{"nc1": "tcp/127.0.0.1:7447"}``.
        cycle_time: PLC cycle [s].
        client_id: this PLC's client id (default ``plc-<host>-<pid>``).
        stale_cycles: see :class:`~plc_client.task.PlcTask`.
        command_timeout: default function block Timeout [s].
        query_timeout: zenoh query timeout [s] (default 5 x command_timeout).
        lease_ms: zenoh transport lease [ms].
        reconnect_period: retry period for an NC whose session could not be opened [s].
        shutdown_cycles: cycles of enables-off frames sent before releasing the claims.
        claim_retry: see :class:`~plc_client.task.PlcTask`.
        close_timeout: how long the shutdown waits for the zenoh sessions to close [s].
        tls_dir: certificate directory (``deploy/certs/make-certs.sh``): mutual TLS with the
            certificate ``<tls_dir>/<client_id>.pem`` (its CN is the identity the router's access
            control knows); every endpoint must be ``tls/``. None: plain TCP.
        frame_period: period [ms] of the status frames taken (one of ``nc_schema.FRAME_PERIODS_MS``);
            None: for the view the longest of at most ``cycle_time`` (``nc_schema.view_period_ms``), for whole
            frames the longest of at most half ``cycle_time`` (``nc_schema.frame_period_ms``); 0: every NC
            cycle's frame (``nc/<nc>/frame``).
        axes: AXIS_REFs to bind at once (see :class:`~plc_client.task.PlcTask`).
        view: take this client's view (the frames of its own axes, see the module docstring); False: whole
            frames.

    Attributes:
        frame_period_ms: the period of the frames taken [ms] (None: every NC cycle's).
        overruns: cycles that started later than one cycle_time after their deadline.
        error: the exception that stopped the program, if any.
        unclosed: NCs whose session had not finished closing within ``close_timeout`` at shutdown.

    Raises:
        ValueError: invalid client id, NC name or timing arguments; with ``tls_dir``: a missing
            certificate file or a non-TLS endpoint.
    """

    def __init__(self, program: Any = None, ncs: Mapping[str, str] | None = None, *, cycle_time: float = 0.010,
                 client_id: str | None = None, stale_cycles: int | None = None, command_timeout: float = 1.0,
                 query_timeout: float | None = None, lease_ms: int = DEFAULT_LEASE_MS, reconnect_period: float = 1.0,
                 shutdown_cycles: int = 3, claim_retry: float = 1.0, close_timeout: float = 2.0,
                 tls_dir: str | None = None, frame_period: int | None = None,
                 axes: Iterable[AXIS_REF] = (), view: bool = True) -> None:
        cid = check_client_id(client_id or default_client_id())
        super().__init__(program, cycle_time=cycle_time, client_id=cid, stale_cycles=stale_cycles,
                         command_timeout=command_timeout, claim_retry=claim_retry, axes=axes)
        ncs = dict(ncs if ncs is not None else {"nc1": "tcp/127.0.0.1:7447"})
        if tls_dir:
            check_tls(tls_dir, cid, ncs.values(), "ncs")
        self.tls_dir = tls_dir
        period = frame_period_ms(self.cycle_time) if frame_period is None else (frame_period or None)
        vperiod = view_period_ms(self.cycle_time) if frame_period is None else frame_period
        self.frame_period_ms = (vperiod or None) if view else period
        self.links: dict[str, NcLink] = {}
        #: NC -> its view frames' last attachment and its AxisIds (nc_schema.parse_view_axes)
        self._view_attachment: dict[str, tuple[bytes, frozenset[int]]] = {}
        self._no_view_since: dict[str, float] = {}  # NC -> when a cycle first found no view frame of it
        self._view_dirty: set[str] = set()  # NCs whose view must be declared again (an AXIS_REF was bound)
        for nc, ep in ncs.items():
            keys = Keys(nc)  # validates the name
            link = self.links[nc] = NcLink(nc, ep, cid, lease_ms, tls_dir,
                                           keys.frame if period is None else keys.frame_every(period),
                                           view_period=vperiod if view else None)
            # one restart rule per NC: the link's instance takes the tokens, the task's frames go to the same one
            self._instances[nc] = link.instance
        self.port = ZenohPort(cid, self.links, query_timeout or 5.0 * command_timeout)
        self.port.clock = lambda: self.now
        self.reconnect_period = float(reconnect_period)
        self.shutdown_cycles = int(shutdown_cycles)
        self.close_timeout = float(close_timeout)
        self.overruns = 0
        self.error: BaseException | None = None
        self.unclosed: list[str] = []
        self._stop = threading.Event()
        self._signalled = 0  # set by the SIGINT/SIGTERM handler of run() (a plain store: no lock)
        self._stopped = threading.Event()
        self._thread: threading.Thread | None = None
        self._connector: threading.Thread | None = None
        self._opened = False
        self._closed = False
        self._lock = threading.Lock()
        self._warned: set[str] = set()
        self.bind_axes()  # the program's declared axes (an unconfigured NC is named now, not at first use)
        self._select_views()

    # -- sessions ----------------------------------------------------------------------
    def open(self, wait: float = 0.0) -> bool:
        """Open the sessions; NCs that are not reachable are retried in the background.

        Args:
            wait: seconds to wait for every NC's first status frame (0: do not wait).

        Returns:
            True if every NC is connected (and, with ``wait``, has sent a frame).
        """
        if self._opened:
            return all(link.ready for link in self.links.values())
        self._opened = True
        missing = [link for link in self.links.values() if not link.open()]
        for link in missing:
            log.warning("NC %s at %s not reachable (%s); retrying every %.1f s", link.nc, link.endpoint,
                        link.last_error, self.reconnect_period)
        if missing:
            self._connector = threading.Thread(target=self._reconnect, args=(missing,), name="plc-connect",
                                               daemon=True)
            self._connector.start()
        if wait > 0:
            deadline = time.monotonic() + wait
            while time.monotonic() < deadline:
                self._take_frames()
                if all(nc in self._frames for nc in self.links):
                    return True
                time.sleep(0.005)
            return False
        return not missing

    def _reconnect(self, links: list[NcLink]) -> None:
        todo = list(links)
        while todo and not self._stop.wait(self.reconnect_period):
            for link in list(todo):
                if self._closed:
                    return
                if link.open():
                    if self._closed:  # closed while we were opening
                        link.close()
                        return
                    log.info("connected to NC %s at %s", link.nc, link.endpoint)
                    todo.remove(link)

    def reachable(self, nc: str) -> bool:
        return self.connected(nc)

    def connected(self, nc: str) -> bool:
        link = self.links.get(nc)
        return bool(link and link.ready)

    def _select_views(self) -> None:
        """Give each link with a changed set of axes its view (:meth:`NcLink.select`)."""
        dirty, self._view_dirty = self._view_dirty, set()
        for nc in dirty:
            link = self.links.get(nc)
            if link is not None:
                try:
                    link.select(a for n, a in self._refs if n == nc)
                except ValueError as exc:  # (AXIS_REF ids are 1..65535: not expected) the old view stays
                    log.error("NC %s: view not changed: %s", nc, exc)

    def _on_new_axis(self, ax: AXIS_REF) -> None:
        self._view_dirty.add(ax.nc)
        if ax.nc not in self.links and ax.nc not in self._warned:
            self._warned.add(ax.nc)
            log.warning("%r: NC %r is not configured (ncs=%s); its data stays invalid", ax, ax.nc, list(self.links))

    # -- the cycle hooks -----------------------------------------------------------------
    def _take_frames(self) -> None:
        if self._view_dirty:
            self._select_views()
        for nc, link in self.links.items():
            if not link.ready:
                continue
            try:
                self._liveliness(link)
                sample = link.frames.try_recv()
            except Exception:  # undeclared while closing
                continue
            if sample is None:
                if nc not in self._frames and link.view_period is not None and nc not in self._nc_down:
                    self._no_view_yet(nc)
                continue
            covers = None
            att = sample.attachment if link.view_period is not None else None
            if att is not None:  # a view frame: the axes it was cut for (a malformed list: none of them)
                raw = att.to_bytes()
                last = self._view_attachment.get(nc)
                if last is None or last[0] != raw:
                    last = self._view_attachment[nc] = (raw, parse_view_axes(raw) or frozenset())
                covers = last[1]
            try:  # as its bytes: header and AxisIds by struct, the records sliced (no numpy per frame)
                self._set_frame_bytes(nc, sample.payload.to_bytes(), covers)
            except ValueError as exc:
                if f"bad-frame-{nc}" not in self._warned:
                    self._warned.add(f"bad-frame-{nc}")
                    log.error("NC %s: undecodable status frame ignored (%s)", nc, exc)

    def _no_view_yet(self, nc: str) -> None:
        """No view frame of a reachable NC yet: after NO_VIEW_WARNING s, say why that may be, once."""
        now = time.monotonic()
        since = self._no_view_since.setdefault(nc, now)
        if now - since > NO_VIEW_WARNING and f"no-view-{nc}" not in self._warned:
            self._warned.add(f"no-view-{nc}")
            log.warning("NC %s: no view frame for %.0f s although its session is open: an NC of protocol version 2, "
                        "or an access control made without the view rules (nc-acl of this version)? Whole frames: "
                        "plc-run --whole-frames, PlcRuntime(view=False)", nc, now - since)

    def _liveliness(self, link: NcLink) -> None:
        """The NC's liveliness events (the link's): ``nc/<nc>/alive`` (reachable or not), then its instance tokens."""
        for ev in link.take_events():
            if ev.kind == GONE:
                self.nc_token_gone(link.nc)
                # (nc_token_gone: its data is invalid from now on, blocks end with 0x4B0F at once)
                log.warning("NC %s is gone (liveliness token deleted)", link.nc)
            elif ev.kind == RESTART:  # a new instance id (the link's instance is the task's: self._instances)
                self.nc_restarted(link.nc, ev.why)
            else:
                if ev.kind == BACK:
                    log.info("NC %s is back", link.nc)  # the same instance or a new one: its instance token tells
                self.nc_token_back(link.nc)  # its data counts again

    def _publish(self, nc: str, axes: list[AXIS_REF]) -> None:
        link = self.links.get(nc)
        if link is None or not link.ready:
            return
        try:
            # the task's preallocated frame; bytes(): NcLink.publish takes bytes (zenoh would copy a bytearray too)
            link.publish(bytes(self.plc_frame(nc, axes)))
        except Exception as exc:  # session closing
            log.debug("PLCTONC put failed: %s", exc)

    # -- running ---------------------------------------------------------------------------
    def step(self) -> None:
        """One PLC cycle (opens the sessions on first use)."""
        if not self._opened:
            self.open()
        with self._lock:
            super().step()

    def _loop(self, duration: float | None) -> None:
        t0 = time.monotonic()
        end = None if duration is None else t0 + duration
        k = 0
        try:
            while not (self._stop.is_set() or self._signalled):
                try:
                    self.step()
                except Exception as exc:  # the user program failed: stop safely
                    log.exception("PLC program raised; stopping")
                    self.error = exc
                    break
                k += 1
                deadline = t0 + k * self.cycle_time
                now = time.monotonic()
                if end is not None and now >= end:
                    break
                if now > deadline + self.cycle_time:
                    self.overruns += 1
                    k = math.ceil((now - t0) / self.cycle_time)  # skip, never replay
                    deadline = t0 + k * self.cycle_time
                wait = deadline - time.monotonic()
                if wait > SLEEP_MAX:
                    self._stop.wait(wait)  # (a long cycle: stop() ends the wait)
                elif wait > 0.0:
                    time.sleep(wait)  # cheaper than Event.wait (0.3 % of a core at 100 Hz); stop() waits for it
        finally:
            self._shutdown()

    def start(self) -> threading.Thread:
        """Run the cycle in a background thread (returns it); stop with :meth:`stop`."""
        if self._thread is not None:
            raise RuntimeError("runtime already started")
        self.open()
        self._thread = threading.Thread(target=self._loop, args=(None,), name="plc-cycle", daemon=True)
        self._thread.start()
        return self._thread

    def run_for(self, seconds: float) -> None:
        """Run the cycle in the calling thread for ``seconds``, then shut down."""
        self.open()
        self._loop(float(seconds))

    def run(self, duration: float | None = None) -> int:
        """Run in the calling (main) thread until SIGINT/SIGTERM, :meth:`stop` or ``duration``.

        Returns 0, or 1 if the program raised.
        """
        handlers = {}
        if threading.current_thread() is threading.main_thread():
            for sig in (signal.SIGINT, signal.SIGTERM):
                handlers[sig] = signal.signal(sig, self._on_signal)
        try:
            self.open()
            self._loop(duration)
        finally:
            for sig, h in handlers.items():
                signal.signal(sig, h)
        return 1 if self.error is not None else 0

    def _on_signal(self, signum: int, frame: Any) -> None:
        # Runs in the main thread between two bytecodes, possibly while that thread holds the
        # lock inside self._stop.wait(): Event.set() here could deadlock. A plain store cannot;
        # the cycle sees the flag within one cycle time.
        self._signalled = signum

    def stop(self, timeout: float = 5.0) -> None:
        """Stop the cycle and shut down cleanly (idempotent)."""
        self._stop.set()
        t = self._thread
        if t is not None and t is not threading.current_thread():
            t.join(timeout)
        elif t is None:
            self._shutdown()

    def _shutdown(self) -> None:
        with self._lock:
            if self._closed:
                return
            self._stop.set()
            self.program = None
            try:
                if self._opened:
                    for _ in range(self.shutdown_cycles):
                        self.disable_all()
                        super().step()
                        time.sleep(self.cycle_time)
                    self._release_claims()
            except Exception:
                log.exception("error during shutdown")
            finally:
                self._closed = True
                self._close_links()
                self._stopped.set()

    def _close_links(self) -> None:
        """Close every NC session, in parallel helper threads, waiting at most ``close_timeout``."""
        threads = []
        for link in self.links.values():
            link.ready = False  # no more commands or frames through it
            t = threading.Thread(target=link.close, name=f"plc-close-{link.nc}", daemon=True)
            t.start()
            threads.append((link, t))
        deadline = time.monotonic() + self.close_timeout
        for link, t in threads:
            t.join(max(0.0, deadline - time.monotonic()))
            if t.is_alive():
                self.unclosed.append(link.nc)
                log.warning("NC %s: the zenoh session did not close within %.1f s (NC frozen or unreachable?); "
                            "left to the process exit", link.nc, self.close_timeout)

    def _release_claims(self) -> None:
        pend = [self.port.send(nc, axis, "Release") for nc, axis in self.held_claims()
                if self.connected(nc) and not self.links[nc].nc_gone]
        deadline = time.monotonic() + self.command_timeout
        while pend and time.monotonic() < deadline:
            self.port.poll()
            pend = [p for p in pend if not p.done]
            time.sleep(0.002)
        for p in pend:
            log.warning("Release of %s/%s: no reply", p.nc, p.axis_id)

    def __enter__(self) -> PlcRuntime:
        self.open()
        return self

    def __exit__(self, *exc: Any) -> None:
        self.stop()
