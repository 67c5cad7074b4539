"""The frame publisher: puts each cycle's frame on zenoh, outside the NC cycle's interpreter.

A zenoh put of a 64-axis frame to 16 subscribers costs a few hundred microseconds, part of it
with the GIL held; in the NC process those puts kept the SCHED_FIFO cycle thread from the GIL
(missed NC cycles under bench/many_clients.py). So the cycle only writes its output into a
:class:`~.frame_ring.FrameRing` in shared memory and signals an eventfd; the publisher, by default
a child process (``python -m nc_server.server.publisher``, its own interpreter and GIL), reads the
newest slot and publishes it on the NC's keys:

* ``nc/<nc>/frame`` every frame, ``nc/<nc>/frame/<P>ms`` the first frame of each period of NC time,
  ``nc/<nc>/status`` every :data:`STATUS_PERIOD`; each only while it has a subscriber (matching
  listeners);
* per axis ``nc/<nc>/axis/<id>/nctoplc`` and ``.../plctonc`` (with the 16-byte stamp attachment)
  while each has a subscriber;
* per client view ``nc/<nc>/view/<client>``: the frame of the axes that client listed in its liveliness
  token ``nc/<nc>/select/<client>/<P>ms/<axes>``, once per P ms of NC time (0: every frame), while the token
  lives (:meth:`FramePublisher.take_view_tokens`). A PLC client reads only its own axes: at 64 axes a
  4-axis view is 1.6 kB instead of 24.6 kB, cut from the frame with byte slices (no decode).

Its zenoh session is a client of the NC's own session (router or peer mode) through an internal
unix socket in a private directory, whatever the NC's listen endpoints and certificates (with access
control, the NC admits that link by its protocol with the NC's own rules,
:func:`nc_server.security.acl.with_local_publisher`); or, for an NC in client mode, of the NC's
router(s), with the NC's certificate: on the wire it is the NC.
The child ends with the NC (a lifeline pipe). A second child stands by, fully started (session open,
publishers declared) and blocked on its control socket (no CPU); when the active child dies the NC
promotes the standby at once (it sees the exit on the child's pidfd), if it is ready, and the standby
puts the newest frame written since the last one put (the ring's Published; the frames written in between
are dropped, counted in frames_dropped; the ``frame/<P>ms`` windows go on from the last one put, ``status``
comes once early): the frames pause for a few NC cycles, not for the ~0.7 s a fresh interpreter and session
take. The NC then starts a new standby, and replaces a child that hung, with back-off (:class:`PublisherProcess`),
on a supervisor thread at normal priority. ``[nc] publisher = "thread"`` runs the same loop
in a thread of the NC process instead (one interpreter: simpler to debug, but its puts hold the cycle
thread's GIL).

The publisher wakes only when it has a put due: after each wake it writes the NC time of its next due put into
the ring (WakeAtNs: the next ``frame/<P>ms`` window of a subscribed P, the next window of a view, the next
``status``; 0 while anything goes out every frame: ``frame``, a per-axis key, a view of period 0), and the cycle
signals the eventfd only for a frame at or after that time (:meth:`FrameOutput.put`; always for the NC's last
frame). A subscriber that comes or goes (matching listener) or a view token sets WakeAtNs to 0 at once (zenoh
thread), so the next frame wakes the publisher, as before. With 16 PLC clients' views at 10 ms and no frame
subscriber the publisher wakes 100 times a second, not 1000, and the cycle makes one eventfd write per 10 cycles.

The ring relies on the eventfd's write/read pair to order the cycle's stores before the publisher's
loads (a system call on both sides); the seqlock check only guards against a slot being rewritten while
it is copied, RING_SLOTS - 1 cycles later.
"""
from __future__ import annotations

import argparse
import contextlib
import json
import logging
import mmap
import os
import select
import signal
import socket
import stat
import subprocess
import sys
import tempfile
import threading
import time
import weakref
from dataclasses import asdict
from typing import Any, Callable, Iterator, Sequence

import numpy as np

from nc_schema import (
    FRAME_HEADER_SIZE, FRAME_PERIODS_MS, NCTOPLC_SIZE, PLCTONC_SIZE, FrameFlags, Keys, encode_stamp, frame_epoch,
    frame_stamp, parse_view_select, view_axes_text, view_frame,
)

from .cycle import set_thread_name
from .frame_ring import FrameRing, RingCounters, ring_bytes

log = logging.getLogger("nc_server.server")

#: Period of ``nc/<nc>/status`` (the newest frame again, decimated for observers on slow links) [s].
STATUS_PERIOD = 0.1
#: The publisher looks at the ring (and its stop flag) at least this often, signalled or not [s].
PARENT_CHECK = 0.5
#: A publisher child that put nothing for this long while the cycle wrote at least STALL_FRAMES frames
#: is killed (then restarted) [s]. READY_TIMEOUT: how long a child may take to be ready (session open, publishers
#: declared) before it is killed and replaced (a loaded machine takes seconds; a hung one would never publish).
STALL_TIMEOUT = 2.0
STALL_FRAMES = 100
READY_TIMEOUT = 15.0
#: Restart delays of a publisher child that ended: from RESTART_MIN_DELAY, doubled per restart up to
#: RESTART_MAX_DELAY, back to the minimum once a child ran ready for RESTART_RESET_AFTER [s].
RESTART_MIN_DELAY = 0.1
RESTART_MAX_DELAY = 5.0
RESTART_RESET_AFTER = 10.0
#: How often the NC's supervisor of the children looks at them, besides their exits (seen at once) [s].
SUPERVISE_PERIOD = 0.1
#: Test hook (tests/integration/test_nc_publisher.py): a child started while the file this environment variable
#: names exists hangs before it says it is ready (as if stuck in zenoh.open), until the NC ends.
HANG_BEFORE_READY_ENV = "NC_PUBLISHER_TEST_HANG_BEFORE_READY"
#: The children's process names (/proc/<pid>/comm, ps, top): the one that puts the frames, the one standing by.
ACTIVE_COMM = "nc-publisher"
STANDBY_COMM = "nc-pub-standby"
#: Control messages on a child's socket: child -> NC "standing by" (publishers declared), NC -> child "publish".
_MSG_READY = b"R"
_MSG_GO = b"G"

_HEADER = FRAME_HEADER_SIZE  # (the NC's frames: encode_frame's layout, records right after the header)
_NREC = NCTOPLC_SIZE
_PREC = PLCTONC_SIZE
_SHUTTING_DOWN = int(FrameFlags.ShuttingDown)


class _View:
    """One client's view (protocol.json ``view``): its publisher, the frame rows of its axes, its period."""

    __slots__ = ("pub", "rows", "selected", "period_ns", "window")

    def __init__(self, pub: Any) -> None:
        self.pub = pub
        self.rows: list[int] = []
        #: the attachment of its frames: every AxisId the client asked for (protocol.json ``view``)
        self.selected = b"none"
        self.period_ns = 0
        self.window = -1


class FramePublisher:
    """Reads a :class:`FrameRing` and publishes its newest frame on ``session`` (see the module docstring).

    Args:
        session: an open zenoh session.
        keys: the NC's keys.
        axis_ids: the NC's axis ids (ring order).
        ring: the ring (reader side).
    """

    def __init__(self, session: Any, keys: Keys, axis_ids: Sequence[int], ring: FrameRing) -> None:
        import zenoh
        from zenoh.handlers import Callback

        self.ring = ring
        self.keys = keys
        self.axis_ids = [int(a) for a in axis_ids]
        n = len(self.axis_ids)
        self.sent = self.dropped = self.put_errors = 0
        self.frame_matched = np.zeros(1, dtype=bool)
        self.every_matched = np.zeros(len(FRAME_PERIODS_MS), dtype=bool)
        self.nc_matched = np.zeros(n, dtype=bool)
        self.pc_matched = np.zeros(n, dtype=bool)
        self._windows = [-1] * len(FRAME_PERIODS_MS)
        self._next_status = 0.0
        self._decl: list[Any] = []
        # the wake plan (WakeAtNs in the ring): written after each frame under _wake_lock, set to 0 by the zenoh
        # threads' callbacks (a subscriber or a view token came or went) under it too, so none is lost
        self._wake_lock = threading.Lock()
        self._closed = False  # (under _wake_lock) close() ran: the ring may be released, callbacks write nothing
        self._wake_at = 0  # the WakeAtNs this publisher wrote last (0: every frame)
        self._last_frame = (0, 0)  # (ring seq, NcTimeNs) of the last frame read
        opts = dict(congestion_control=zenoh.CongestionControl.DROP, express=False)
        s = session

        def matcher(arr: np.ndarray, i: int) -> Callable[[Any], None]:
            def on_matching(status: Any) -> None:  # on a zenoh thread: keep it tiny
                arr[i] = bool(status.matching)
                self.wake_now()
            return on_matching

        def declare(key: str, arr: np.ndarray | None = None, i: int = 0) -> Any:
            p = s.declare_publisher(key, **opts)
            self._decl.append(p)
            if arr is not None:
                self._decl.append(p.declare_matching_listener(Callback(matcher(arr, i), indirect=False)))
            return p

        self.status_pub = declare(keys.status)
        self.frame_pub = declare(keys.frame, self.frame_matched, 0)
        self.every_pubs = [(ms * 1_000_000, declare(keys.frame_every(ms), self.every_matched, i))
                           for i, ms in enumerate(FRAME_PERIODS_MS)]
        self.nc_pubs = [declare(keys.axis_nctoplc(a), self.nc_matched, i) for i, a in enumerate(self.axis_ids)]
        self.pc_pubs = [declare(keys.axis_plctonc(a), self.pc_matched, i) for i, a in enumerate(self.axis_ids)]
        # clients' views: a liveliness token per view (nc/<nc>/select/<client>/<P>ms/<axes>), applied between
        # frames. The zenoh thread only records each token's newest state (a dict bounded by the live tokens: a
        # standby child that stands by for days neither blocks zenoh on a full channel nor loses a DELETE).
        self._row_of = {a: i for i, a in enumerate(self.axis_ids)}
        self._view_opts = opts
        self._session = s
        self._tokens: dict[str, tuple[str, int, tuple[int, ...]]] = {}  # (changed under _token_lock)
        self._token_events: dict[str, bool] = {}  # token key -> alive
        self._token_lock = threading.Lock()
        self.views: dict[str, _View] = {}
        delete = zenoh.SampleKind.DELETE

        def on_token(sample: Any) -> None:  # on a zenoh thread: keep it tiny
            key, alive = str(sample.key_expr), sample.kind != delete
            with self._token_lock:
                if not alive and key not in self._tokens:  # never applied: forget it (a standby takes none)
                    self._token_events.pop(key, None)
                else:
                    self._token_events[key] = alive
            self.wake_now()  # (after the event is recorded: a plan made after this sees it)

        self.view_sub = s.liveliness().declare_subscriber(keys.view_select_any, Callback(on_token, indirect=False),
                                                          history=True)
        self._decl.append(self.view_sub)

    def wake_now(self) -> None:
        """Be signalled for the next frame (a zenoh thread: a subscriber or a view token came or went); after
        :meth:`close` nothing (the ring's view may be released: a write raised TypeError in the callback)."""
        with self._wake_lock:
            if not self._closed:
                self.ring.set_wake_at(0)

    def _plan_wake(self, nc_time_ns: int) -> None:
        """Write WakeAtNs for the frame at ``nc_time_ns`` just handled: the NC time of the next due put."""
        with self._wake_lock:
            at = self._due_ns(nc_time_ns)
            self.ring.set_wake_at(at)
            self._wake_at = at

    def _due_ns(self, nc_time_ns: int) -> int:
        """The NC time of the next put due after the frame at ``nc_time_ns`` (0: the next frame, and every one)."""
        if self._token_events or self.frame_matched[0] or self.nc_matched.any() or self.pc_matched.any():
            return 0
        # status: in wall time; its NC time is as far from this frame's (about: the NC's time runs with the clock; a
        # frame signalled early costs one wake, the next plan is from it)
        due = nc_time_ns + max(0, int((self._next_status - time.monotonic()) * 1e9))
        if self.every_matched.any():
            for i, (period_ns, _) in enumerate(self.every_pubs):
                if self.every_matched[i]:
                    due = min(due, (self._windows[i] + 1) * period_ns)
        for view in self.views.values():
            if not view.period_ns:
                return 0
            due = min(due, (view.window + 1) * view.period_ns)
        return max(1, due)

    def take_view_tokens(self) -> bool:
        """Apply the view tokens that came or went since the last call; whether any did. A client's view is the
        union of its tokens' axes (those this NC has, in AxisId order) at the shortest of their periods; its
        publisher lives while it has a token."""
        if not self._token_events:
            return False
        changed: set[str] = set()
        with self._token_lock:  # (on_token reads _tokens: a DELETE must not pass a PUT being applied)
            events, self._token_events = self._token_events, {}
            for key, alive in events.items():
                if not alive:
                    old = self._tokens.pop(key, None)
                    if old is not None:
                        changed.add(old[0])
                    continue
                parsed = parse_view_select(key)
                if parsed is None or parsed[0] != self.keys.nc:
                    continue  # a malformed token: ignored (nothing is sent for it)
                self._tokens[key] = parsed[1:]
                changed.add(parsed[1])
        for client in changed:
            self._rebuild_view(client)
        return bool(changed)

    def _rebuild_view(self, client: str) -> None:
        mine = [t for t in self._tokens.values() if t[0] == client]
        view = self.views.get(client)
        if not mine:
            if view is not None:
                del self.views[client]
                try:
                    view.pub.undeclare()
                except Exception:  # session closing
                    pass
            return
        if view is None:
            view = self.views[client] = _View(self._session.declare_publisher(self.keys.view(client),
                                                                              **self._view_opts))
        ids = sorted({a for _, _, axes in mine for a in axes})
        view.rows = [self._row_of[a] for a in ids if a in self._row_of]
        view.selected = view_axes_text(ids).encode()
        view.period_ns = min(p for _, p, _ in mine) * 1_000_000
        view.window = -1  # the new selection goes out with the next frame
        log.debug("view of %s: axes %s every %d ms", client, view.selected.decode(), view.period_ns // 1_000_000)

    def close(self) -> None:
        """Undeclare everything. A zenoh thread's callback that still comes (a matching listener firing while the
        session closes) then writes nothing: the ring is released after this."""
        with self._wake_lock:
            self._closed = True
        for v in self.views.values():
            try:
                v.pub.undeclare()
            except Exception:  # session closing
                pass
        self.views.clear()
        for d in reversed(self._decl):
            try:
                d.undeclare()
            except Exception:  # session closing
                pass
        self._decl.clear()

    def resume_after(self, frame: bytes | None) -> None:
        """Go on after ``frame``, the last one an earlier publisher put (None: none, or overwritten): its
        ``frame/<P>ms`` windows count as put, so a failover puts no frame twice on those keys. (``status``, decimated
        in wall time, which the earlier publisher did not record, goes out at once: one early status.)"""
        if frame is not None:
            nc_time_ns = frame_stamp(frame)[1]
            self._windows = [nc_time_ns // period_ns for period_ns, _ in self.every_pubs]
            self.take_view_tokens()
            for view in self.views.values():
                if view.period_ns:
                    view.window = nc_time_ns // view.period_ns

    def publish_newest(self) -> bool:
        """Publish the newest slot if there is one not yet published; whether there was."""
        got = self.ring.read_newest()
        if got is None:
            return False
        seq, frame, plc, skipped = got
        nc_time_ns = frame_stamp(frame)[1]
        self.dropped += self._skipped_due(seq, nc_time_ns, skipped)
        self._last_frame = (seq, nc_time_ns)
        if self.ring.stale(frame, time.time_ns()):
            self.dropped += 1
            self.ring.count_fenced()
        else:
            self.publish(frame, plc)
        self.ring.set_published(seq)
        self.ring.set_counters(self.sent, self.dropped, self.put_errors, True)
        self._plan_wake(nc_time_ns)
        return True

    def _skipped_due(self, seq: int, nc_time_ns: int, skipped: int) -> int:
        """How many of the ``skipped`` frames before the one read (slot ``seq``, at ``nc_time_ns``) were due: every one
        while every frame is (WakeAtNs 0; and after a takeover: the ring's Published), else those at or after the
        planned WakeAtNs (a late wake: the NC time per slot from the last frame read)."""
        last_seq, last_t = self._last_frame
        if not skipped or not self._wake_at or last_seq <= 0 or seq <= last_seq or nc_time_ns <= last_t:
            return skipped
        per_slot = (nc_time_ns - last_t) / (seq - last_seq)
        # (the skipped frames at or after WakeAtNs: those at nc_time_ns - k * per_slot >= WakeAtNs, k >= 1)
        late = (nc_time_ns - self._wake_at) // per_slot if nc_time_ns > self._wake_at else 0
        return int(min(skipped, max(0, late)))

    def publish(self, frame: bytes, plc: bytes | None) -> None:
        """Put one frame (and its PLCTONC) on every key that has a subscriber; the NC's last frame (flag
        ShuttingDown) on every frame key, whatever the period."""
        try:
            cycle, nc_time_ns, flags = frame_stamp(frame)
            final = bool(flags & _SHUTTING_DOWN)
            if self.frame_matched[0]:
                self.frame_pub.put(frame)
            if self.every_matched.any():
                for i, (period_ns, pub) in enumerate(self.every_pubs):
                    w = nc_time_ns // period_ns
                    if (w != self._windows[i] or final) and self.every_matched[i]:
                        self._windows[i] = w
                        pub.put(frame)
            self.take_view_tokens()
            if self.views:
                n = len(self.axis_ids)
                for view in self.views.values():
                    if view.period_ns:
                        w = nc_time_ns // view.period_ns
                        if w == view.window and not final:
                            continue
                        view.window = w
                    view.pub.put(view_frame(frame, n, view.rows), attachment=view.selected)
            now = time.monotonic()
            if now >= self._next_status or final:
                self._next_status = now + STATUS_PERIOD
                self.status_pub.put(frame)
            if self.nc_matched.any() or (plc is not None and self.pc_matched.any()):
                stamp = encode_stamp(cycle, nc_time_ns, frame_epoch(frame))
                for i in np.flatnonzero(self.nc_matched).tolist():
                    o = _HEADER + i * _NREC
                    self.nc_pubs[i].put(frame[o:o + _NREC], attachment=stamp)
                if plc is not None:
                    for i in np.flatnonzero(self.pc_matched).tolist():
                        o = i * _PREC
                        self.pc_pubs[i].put(plc[o:o + _PREC], attachment=stamp)
            self.sent += 1
        except Exception as exc:  # session closing, etc.
            self.put_errors += 1
            log.debug("put failed: %s", exc)

    def run(self, wait: Callable[[float], bool]) -> None:
        """Publish until the ring asks to stop (after publishing what is there).

        Args:
            wait: blocks until the writer signals or the timeout [s] passes; whether it signalled.
        """
        ring = self.ring
        ring.set_counters(self.sent, self.dropped, self.put_errors, True)  # (ready: the counters are this publisher's)
        # (the plan of an earlier publisher is not this one's: the next frame wakes it; the frames written since the
        # last one put count as dropped)
        self._wake_at, self._last_frame = 0, (0, 0)
        ring.set_wake_at(0)
        while True:
            wait(PARENT_CHECK)
            self.publish_newest()
            if ring.stop_requested:
                self.publish_newest()
                return


# ---- the child process -------------------------------------------------------------------------
def _eventfd_wait(fd: int, lifeline: int | None = None) -> Callable[[float], bool]:
    """A ``wait(timeout)`` on the eventfd; with ``lifeline`` (the read end of a pipe whose write end only
    the NC holds) it raises :class:`ParentGone` once that pipe is closed: the NC process ended."""
    poller = select.poll()
    poller.register(fd, select.POLLIN)
    if lifeline is not None:
        poller.register(lifeline, select.POLLIN | select.POLLHUP)

    def wait(timeout: float) -> bool:
        events = poller.poll(int(timeout * 1000))
        if lifeline is not None and any(f == lifeline for f, _ in events):
            raise ParentGone
        if not events:
            return False
        try:
            os.eventfd_read(fd)
        except BlockingIOError:
            return False
        return True
    return wait


class ParentGone(Exception):
    """The NC process ended (its end of the lifeline pipe closed)."""


def _set_comm(name: str) -> None:
    """Name this process (its main thread) for ps/top and /proc/<pid>/comm."""
    try:
        with open("/proc/self/comm", "w") as f:
            f.write(name)
    except OSError:
        pass


def _stand_by(ctl: socket.socket, lifeline: int) -> bool:
    """Tell the NC this child is ready, then block (no CPU) until it says publish: True; False when the NC
    closes the control socket (stop: end without publishing). Raises :class:`ParentGone` with the NC."""
    _set_comm(STANDBY_COMM)
    try:
        ctl.sendall(_MSG_READY)
    except OSError:
        return False
    poller = select.poll()
    poller.register(ctl.fileno(), select.POLLIN)
    poller.register(lifeline, select.POLLIN | select.POLLHUP)
    while True:
        events = poller.poll()
        if any(f == lifeline for f, _ in events):
            raise ParentGone
        try:
            return ctl.recv(1) == _MSG_GO
        except BlockingIOError:
            continue
        except OSError:
            return False


def child_main(argv: Sequence[str] | None = None) -> int:
    """``python -m nc_server.server.publisher --spec JSON``: the NC's frame publisher (started by the NC).

    It starts as a standby: session open, publishers declared, then blocked on its control socket until the
    NC promotes it (:func:`_stand_by`); then it publishes the newest frame after the last one put. It ends
    when the NC asks (the ring's stop flag, after the last frame; a standby: its control socket closes)
    or when the NC process ends
    (the lifeline pipe closes: a process-wide signal, unlike PR_SET_PDEATHSIG, which follows the
    *thread* that forked). Signals meant for the NC's process group (Ctrl-C, SIGTERM, SIGHUP) are
    ignored: the NC writes its last frame after them and then stops the publisher.
    """
    p = argparse.ArgumentParser(prog="nc-publisher")
    p.add_argument("--spec", required=True,
                   help="JSON: nc, axis_ids, ring_fd, event_fd, lifeline_fd, control_fd, zenoh, nice")
    args = p.parse_args(argv)
    spec = json.loads(args.spec)
    for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
        signal.signal(sig, signal.SIG_IGN)
    logging.basicConfig(level=spec.get("log_level", "WARNING"), format="%(asctime)s nc-publisher %(levelname)s %(message)s")
    try:
        os.setpriority(os.PRIO_PROCESS, 0, int(spec.get("nice", 0)))  # (set, not added to the forking thread's)
    except OSError:
        pass
    import zenoh

    from .config import ZenohSettings
    from .transport import zenoh_config

    axis_ids = [int(a) for a in spec["axis_ids"]]
    mm = mmap.mmap(int(spec["ring_fd"]), ring_bytes(len(axis_ids)))
    ring = FrameRing(memoryview(mm), len(axis_ids))
    wait = _eventfd_wait(int(spec["event_fd"]), int(spec["lifeline_fd"]))
    ctl = socket.socket(fileno=int(spec["control_fd"]))
    fields: dict[str, Any] = {k: (tuple(v) if isinstance(v, list) else v) for k, v in spec["zenoh"].items()}
    settings = ZenohSettings(**fields)
    session = zenoh.open(zenoh_config(settings, spec["nc"]))
    pub = FramePublisher(session, Keys(spec["nc"]), axis_ids, ring)
    try:
        hang = os.environ.get(HANG_BEFORE_READY_ENV)
        if hang and os.path.exists(hang):  # (the test hook: never ready; ends with the NC)
            log.warning("pid %d hangs before it is ready (test hook %s)", os.getpid(), HANG_BEFORE_READY_ENV)
            select.select([int(spec["lifeline_fd"])], [], [])
            raise ParentGone
        if _stand_by(ctl, int(spec["lifeline_fd"])):
            _set_comm(ACTIVE_COMM)
            ring.resume_after_published()
            pub.resume_after(ring.published_frame())
            pub.run(wait)
    except ParentGone:
        pass
    finally:
        pub.close()
        ring.release()
        session.close()
        mm.close()
        ctl.close()
    return 0


def publisher_settings(settings: Any, internal: str | None = None) -> dict[str, Any]:
    """The publisher's zenoh settings (a dict of ZenohSettings fields) for an NC with ``settings``: a client
    of the NC's own session through its internal endpoint ``internal`` (router or peer mode: a unix socket
    only the NC's user can open, see :func:`internal_endpoint`), or, for an NC in client mode, of the
    same router(s) with the NC's certificate."""
    d = asdict(settings)
    connect = [internal] if internal and settings.mode != "client" else list(settings.connect)
    d.update(mode="client", listen=[], connect=connect)
    if internal and settings.mode != "client":
        d["tls_dir"] = None  # (a local socket: no TLS; the NC's access control admits it by its link protocol)
    return d


def internal_endpoint(directory: str | None = None) -> tuple[str, str]:
    """(endpoint, socket path) of the unix socket through which the publisher child reaches the NC's
    session: ``<dir>/<pid>.sock`` in :func:`socket_dir` (or ``directory``).

    Sockets of NC processes that no longer exist (killed: nothing removed them) are removed first.
    """
    d = directory or socket_dir()
    for name in os.listdir(d):
        stem = name.split(".", 1)[0]  # <pid>.sock and zenoh's <pid>.sock.lock
        if name.endswith((".sock", ".sock.lock")) and stem.isdigit() and int(stem) != os.getpid() \
                and not _pid_alive(int(stem)):
            try:
                os.unlink(os.path.join(d, name))
            except OSError:
                pass
    path = os.path.join(d, f"{os.getpid()}.sock")
    remove_internal_socket(path)  # (ours from an earlier start in this process)
    return f"unixsock-stream/{path}", path


def remove_internal_socket(path: str) -> None:
    """Remove the socket and zenoh's lock file beside it (never raises)."""
    for p in (path, path + ".lock"):
        try:
            os.unlink(p)
        except OSError:
            pass


def socket_dir() -> str:
    """The directory of the NCs' internal sockets: ``$XDG_RUNTIME_DIR/zenoh-nc`` or ``<tmp>/zenoh-nc-<uid>``,
    0700 and owned by this user (made if missing; a directory that is not, or a symlink, is refused and a
    fresh private one used instead), so only this user (and root) can connect."""
    base = os.environ.get("XDG_RUNTIME_DIR")
    d = os.path.join(base, "zenoh-nc") if base and os.path.isdir(base) else \
        os.path.join(tempfile.gettempdir(), f"zenoh-nc-{os.getuid()}")
    try:
        os.mkdir(d, 0o700)
    except FileExistsError:
        pass
    except OSError:
        return tempfile.mkdtemp(prefix="zenoh-nc-")
    st = os.lstat(d)
    if not stat.S_ISDIR(st.st_mode) or st.st_uid != os.getuid() or st.st_mode & 0o077:
        log.warning("%s is not a private directory of this user: the internal socket goes elsewhere", d)
        return tempfile.mkdtemp(prefix="zenoh-nc-")
    return d


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


class FrameOutput:
    """The cycle's side of the frames: the ring in a memfd and the eventfd that wakes its reader.

    Made with the server (so a server driven cycle by cycle in a test has it too); the publisher
    (:class:`PublisherProcess` or :class:`PublisherThread`) reads it. Closed by :meth:`close` (or
    when garbage-collected).

    Args:
        nc: the NC name (names the memfd); n_axes: axes per frame.
    """

    def __init__(self, nc: str, n_axes: int) -> None:
        self.n_axes = int(n_axes)
        size = ring_bytes(self.n_axes)
        self.memfd = os.memfd_create(f"nc-{nc}-frames", os.MFD_CLOEXEC)
        os.ftruncate(self.memfd, size)
        self._mm = mmap.mmap(self.memfd, size)
        self.ring = FrameRing(memoryview(self._mm), self.n_axes, create=True)
        self.eventfd = os.eventfd(0, os.EFD_NONBLOCK | os.EFD_CLOEXEC)
        self._last_time = 0  # NcTimeNs of the last frame put into the ring
        self.signals = 0  # eventfd writes for frames (a diagnostic)
        self._readers: list[FrameRing] = []
        self._finalizer = weakref.finalize(self, FrameOutput._release, self._mm, self.memfd, self.eventfd,
                                           [self.ring], self._readers)

    def reader(self) -> FrameRing:
        """A reader of this ring in this process (it sees what is written after this call)."""
        r = FrameRing(self.ring.mv, self.n_axes)
        self._readers.append(r)
        return r

    def put(self, cycle: int, nc_time_ns: int, records: np.ndarray, flags: int, jobs: np.ndarray | None,
            plctonc: np.ndarray | None, versions: tuple[int, int] | None = None, epoch: int = 0) -> None:
        """Write one cycle's frame into the ring (:meth:`FrameRing.write`, ``versions`` and ``epoch`` as there) and
        wake the publisher if it has a put due for it (cycle thread): the frame reached the publisher's WakeAtNs
        (0: every frame), is the NC's last one (ShuttingDown), or the NC time went back (a plan made for other times)."""
        ring = self.ring
        ring.write(cycle, nc_time_ns, records, flags, jobs, plctonc, versions, epoch)
        if nc_time_ns >= ring.wake_at or flags & _SHUTTING_DOWN or nc_time_ns < self._last_time:
            self.signals += 1
            self.signal()
        self._last_time = nc_time_ns

    def signal(self) -> None:
        """Wake the publisher (cycle thread; one syscall, never blocks)."""
        try:
            os.eventfd_write(self.eventfd, 1)
        except OSError:  # counter full (nobody reads): nothing to do
            pass

    def close(self) -> None:
        self._finalizer()

    @staticmethod
    def _release(mm: mmap.mmap, memfd: int, efd: int, rings: list[FrameRing], readers: list[FrameRing]) -> None:
        for r in rings + readers:
            try:
                r.release()
            except Exception:
                pass
        try:
            mm.close()
        except BufferError:  # a view is still exported somewhere: the mapping goes with the process
            pass
        for fd in (memfd, efd):
            try:
                os.close(fd)
            except OSError:
                pass


class PublisherThread:
    """The frame publisher as a thread of the NC process, on the NC's own session (``publisher = "thread"``).

    Args:
        output: the server's frames; nc, axis_ids: the NC; session: the NC's open zenoh session.
    """

    restarts = 0
    failovers = 0
    standby_ready = False  # (no standby: the thread ends only with the NC)

    def __init__(self, output: FrameOutput, nc: str, axis_ids: Sequence[int], session: Any) -> None:
        self.output = output
        self.nc = nc
        self.axis_ids = [int(a) for a in axis_ids]
        self.session = session
        self.pub: FramePublisher | None = None
        self._thread: threading.Thread | None = None

    def start(self) -> None:
        self.pub = FramePublisher(self.session, Keys(self.nc), self.axis_ids, self.output.reader())
        self._thread = threading.Thread(target=self.pub.run, args=(_eventfd_wait(self.output.eventfd),),
                                        name="nc-publisher", daemon=True)
        self._thread.start()

    def watch(self) -> None:
        """(Nothing to watch: the thread ends only when asked.)"""

    def counters(self) -> RingCounters:
        return self.output.ring.counters()

    def stop(self, timeout: float = 3.0) -> None:
        """Publish the last frame written, then end the thread."""
        self.output.ring.request_stop()
        self.output.signal()
        if self._thread is not None:
            self._thread.join(timeout)
        if self.pub is not None:
            self.pub.close()


@contextlib.contextmanager
def _normal_while_forking(nice: int) -> Iterator[None]:
    """A SCHED_FIFO caller (the NC's I/O thread restarting the publisher) runs SCHED_OTHER at ``nice`` around a
    fork: Python's subprocess vforks holding the GIL until the child execs, and the child (SCHED_RESET_ON_FORK:
    nice 0) would queue behind every loaded process meanwhile, with the cycle thread waiting for the GIL."""
    from .cycle import is_realtime

    policy = param = None
    try:
        if is_realtime():
            policy, param = os.sched_getscheduler(0), os.sched_getparam(0)
            os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
            os.setpriority(os.PRIO_PROCESS, 0, nice)
    except (OSError, AttributeError):
        policy = None
    try:
        yield
    finally:
        if policy is not None and param is not None:
            try:
                os.sched_setscheduler(0, policy, param)
            except OSError:
                pass


class _Child:
    """One publisher child as the NC sees it: its process, its pidfd (readable once it exited) and the NC's
    end of its control socket."""

    def __init__(self, proc: subprocess.Popen[bytes], ctl: socket.socket) -> None:
        self.proc = proc
        self.ctl = ctl
        try:
            self.pidfd: int | None = os.pidfd_open(proc.pid)
        except (OSError, AttributeError):  # (no pidfd: the supervisor notices the exit within SUPERVISE_PERIOD)
            self.pidfd = None
        self.ready = False  # it stood by: session open, publishers declared
        self.started = self.since = time.monotonic()  # started; started or promoted [s]
        self.ready_at = float("inf")  # when the NC saw it ready [s]

    def poll_ready(self) -> bool:
        """Whether it said it stands by (never blocks)."""
        if not self.ready:
            try:
                self.ready = self.ctl.recv(1) == _MSG_READY
                self.ready_at = time.monotonic() if self.ready else self.ready_at
            except OSError:  # (BlockingIOError: not yet)
                pass
        return self.ready

    def promote(self) -> None:
        """Tell it to publish (it does once it stands by, at once if it does already)."""
        self.since = time.monotonic()
        try:
            self.ctl.send(_MSG_GO)
        except OSError:  # it died: its exit is handled like any other
            pass

    def close(self) -> None:
        """Close the NC's ends (a standby that still runs ends when its control socket closes)."""
        with contextlib.suppress(OSError):
            self.ctl.close()
        if self.pidfd is not None:
            with contextlib.suppress(OSError):
                os.close(self.pidfd)
            self.pidfd = None


def _run_normal(nice: int) -> None:
    """Make the calling thread SCHED_OTHER at ``nice`` if it inherited a real-time policy (a thread started by a
    SCHED_FIFO thread): the publisher's supervisor waits for processes and forks, which must not hold off the
    NC's real-time threads (nor run ahead of them)."""
    from .cycle import is_realtime

    try:
        if is_realtime():
            os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
            os.setpriority(os.PRIO_PROCESS, 0, nice)  # (Linux: 0 is the calling thread)
    except (OSError, AttributeError):
        pass


class PublisherProcess:
    """The frame publisher as child processes (``publisher = "process"``, the default): one active, one standby.

    Args:
        output: the server's frames (the children map the same memfd and wait on the same eventfd).
        nc, axis_ids: the NC.
        settings: the NC's ZenohSettings (the children's sessions: :func:`publisher_settings`).
        internal: the NC session's internal endpoint for the children (router/peer mode), None in client mode.
        nice: the children's nice value (the NC's zenoh threads' by default: ahead of the PLC clients).
        log_level: the children's logging level.

    Both children start alike (a session like the NC's, publishers declared) and stand by; the NC promotes
    one: only the active child puts frames. Everything else happens on a supervisor thread of the NC at normal
    priority (never on the SCHED_FIFO I/O thread: the kernel may take 100 ms or more to end a killed process, a
    fork and exec take milliseconds, and no reply would go out meanwhile). It blocks on the children's pidfds:
    when the active child exits (killed, crashed) it promotes the standby at once (``failovers``), if that one
    stands by ready; the standby then puts the newest frame (the frames written meanwhile are dropped, counted in
    ``frames_dropped``). A standby that is not ready yet (starting, or hung before it got ready) is never
    promoted: it is killed and a new active child starts after the back-off. Every :data:`SUPERVISE_PERIOD`
    the supervisor starts a new standby for a child that ended, kills and replaces an active child that
    published nothing for :data:`STALL_TIMEOUT` while the cycle wrote frames (hung, or stopped with SIGSTOP)
    and a child that was not ready :data:`READY_TIMEOUT` after its start (hung in its start), and falls back to
    polling the children when there is no pidfd. It only sends SIGKILL: a killed child is reaped when its
    pidfd says it has ended, never waited for.
    The first standby starts once the first child published; each child started after these two counts in
    ``restarts``; they back off from
    :data:`RESTART_MIN_DELAY` to :data:`RESTART_MAX_DELAY` (a child that keeps dying). The counters in the ring
    restart from zero with each active child: :meth:`counters` adds up every one's.
    """

    def __init__(self, output: FrameOutput, nc: str, axis_ids: Sequence[int], settings: Any,
                 internal: str | None = None, nice: int = 0, log_level: str = "WARNING") -> None:
        self.output = output
        self.nc = nc
        self.axis_ids = [int(a) for a in axis_ids]
        self.settings = settings
        self.internal = internal
        self.nice = nice
        self.log_level = log_level
        self.active: _Child | None = None
        self.standby: _Child | None = None
        self.restarts = 0
        self.failovers = 0
        self._stopping = False
        # (re-entrant: _ended runs under it from the supervisor's steps, which take it themselves; held only for
        # non-blocking work: the I/O thread's stats take it too)
        self._lock = threading.RLock()
        self._lifeline_r, self._lifeline_w = os.pipe()  # (both close-on-exec: only the children get the read end)
        self._wake_r, self._wake_w = os.pipe2(os.O_NONBLOCK | os.O_CLOEXEC)  # wakes the supervisor
        self._watcher: threading.Thread | None = None
        self._dying: list[_Child] = []  # killed, not yet ended (reaped when their pidfd says so)
        self._base = (0, 0, 0)  # the counters of the active children before this one
        self._delay = RESTART_MIN_DELAY
        self._restart_at: float | None = None
        self._seen = (-1, -1, 0.0)  # (ring seq, its sent counter, when): the last time it had published more
        self._first_standby = True  # the first standby is still to start (not a restart)

    def start(self) -> None:
        """Start the active child (returns at once; it declares its publishers within ~0.1-1 s) and the supervisor,
        which starts the standby once the first child published (not both at once: the NC's start would wait
        for two interpreters)."""
        self._adopt(self._launch())
        self._watcher = threading.Thread(target=self._supervise, name="nc-publisher-watch", daemon=True)
        self._watcher.start()

    @property
    def proc(self) -> subprocess.Popen[bytes] | None:
        """The active child's process (the last one after :meth:`stop`)."""
        return self.active.proc if self.active is not None else None

    @property
    def pid(self) -> int | None:
        return self.proc.pid if self.proc is not None else None

    @property
    def standby_ready(self) -> bool:
        """A standby child stands by, ready to take over."""
        with self._lock:
            return self.standby is not None and self.standby.poll_ready()

    def counters(self) -> RingCounters:
        """Every active child's counters added up; ``ready`` of the current one."""
        with self._lock:  # (a failover moves the ring's counters into _base: both read at one moment)
            c = self.output.ring.counters()
            b = self._base
        return RingCounters(b[0] + c.sent, b[1] + c.dropped, b[2] + c.put_errors, c.ready)

    def _launch(self) -> _Child:
        """Start a child process (without the lock: a failover never waits for a fork)."""
        o = self.output
        ours, theirs = socket.socketpair()
        spec = {"nc": self.nc, "axis_ids": self.axis_ids, "ring_fd": o.memfd, "event_fd": o.eventfd,
                "lifeline_fd": self._lifeline_r, "control_fd": theirs.fileno(),
                "zenoh": publisher_settings(self.settings, self.internal), "nice": self.nice, "log_level": self.log_level}
        try:
            with _normal_while_forking(self.nice):
                proc = subprocess.Popen([sys.executable, "-m", "nc_server.server.publisher", "--spec", json.dumps(spec)],
                                        pass_fds=(o.memfd, o.eventfd, self._lifeline_r, theirs.fileno()),
                                        stdin=subprocess.DEVNULL)
        except BaseException:
            ours.close()
            raise
        finally:
            theirs.close()
        ours.setblocking(False)
        return _Child(proc, ours)

    def _adopt(self, child: _Child) -> None:
        """Make a started child the active one (promoted at once) when there is none, else the standby."""
        with self._lock:
            if not self._stopping:
                if self.active is None:
                    self._promote(child)
                else:
                    self.standby = child
                self._wake()
                return
        child.close()  # (stopping meanwhile: it never published, it need not end cleanly)
        child.proc.kill()
        child.proc.wait()

    def _promote(self, child: _Child) -> None:
        """Make ``child`` the active publisher (lock held; the ring's counters were reset)."""
        self.active = child
        child.promote()
        self._seen = (self.output.ring.seq, 0, child.since)

    def _discard(self, child: _Child) -> None:
        """Forget a child that ended or was sent SIGKILL (lock held): closed now, or once its pidfd says it ended."""
        if child.proc.poll() is None:
            self._dying.append(child)
        else:
            child.close()

    def _kill(self, child: _Child, why: str) -> None:
        """SIGKILL ``child`` (active or standby) and go on as if it had ended (lock held; never waits for it)."""
        log.error("the %s frame publisher (pid %d) %s: killing it",
                  "active" if child is self.active else "standby", child.proc.pid, why)
        with contextlib.suppress(OSError):
            child.proc.kill()
        self._ended(child)

    def _ended(self, child: _Child) -> None:
        """``child`` exited (or was killed): the standby takes over from an active one if it is ready; a new
        child is due after the back-off (lock held; nothing if it was handled already)."""
        if self._stopping or child not in (self.active, self.standby):
            return
        rc = child.proc.poll()  # (reaped if it has exited; None: killed, not ended yet)
        how = f"ended with {rc}" if rc is not None else "was killed"
        self._discard(child)
        delay = self._delay
        if child is self.active:
            c = self.output.ring.counters()
            self._base = (self._base[0] + c.sent, self._base[1] + c.dropped, self._base[2] + c.put_errors)
            self.output.ring.set_counters(0, 0, 0, False)
            self.active, nxt, self.standby = None, self.standby, None
            if nxt is not None and nxt.proc.poll() is None and nxt.poll_ready():
                self.failovers += 1
                self._promote(nxt)
                log.error("the frame publisher (pid %d) %s: the standby (pid %d) took over; "
                          "restarting it as the standby in %.1f s", child.proc.pid, how, nxt.proc.pid, delay)
            elif nxt is not None:
                # (never promoted: one that hung before it was ready would never publish; a new one is as quick
                # as one that is still starting)
                with contextlib.suppress(OSError):
                    nxt.proc.kill()
                self._discard(nxt)
                log.error("the frame publisher (pid %d) %s and the standby (pid %d) was not ready (killed): "
                          "restarting it in %.1f s (clients miss frames meanwhile)", child.proc.pid, how,
                          nxt.proc.pid, delay)
            else:
                log.error("the frame publisher (pid %d) %s and no standby is left: restarting it in %.1f s "
                          "(clients miss frames meanwhile)", child.proc.pid, how, delay)
        else:
            self.standby = None
            log.error("the standby frame publisher (pid %d) %s: restarting it in %.1f s", child.proc.pid, how, delay)
        if self._restart_at is None:
            self._restart_at = time.monotonic() + delay
            self._delay = min(RESTART_MAX_DELAY, self._delay * 2)
        self._wake()

    def _exited(self, child: _Child) -> None:
        """``child``'s pidfd says it exited (or, without pidfd, poll() did): reap it, handle its end."""
        with self._lock:
            if child in self._dying:
                self._dying.remove(child)
                child.proc.poll()
                child.close()
            else:
                self._ended(child)

    def _wake(self) -> None:
        with contextlib.suppress(OSError):
            os.write(self._wake_w, b"x")

    def _supervise(self) -> None:
        """Thread, normal priority: block on the children's pidfds (and the wake pipe), handle an exit the
        moment it happens, and every SUPERVISE_PERIOD do :meth:`_step` (see the class docstring)."""
        set_thread_name("nc-pub-watch")
        _run_normal(self.nice)
        next_step = 0.0
        while True:
            with self._lock:
                if self._stopping:
                    return
                kids = {c.pidfd: c for c in (self.active, self.standby, *self._dying)
                        if c is not None and c.pidfd is not None}
            poller = select.poll()
            poller.register(self._wake_r, select.POLLIN)
            for fd in kids:
                poller.register(fd, select.POLLIN)
            for fd, _ in poller.poll(max(0, int((next_step - time.monotonic()) * 1000)) + 1):
                if fd == self._wake_r:
                    with contextlib.suppress(OSError):
                        os.read(self._wake_r, 4096)
                elif fd in kids:
                    self._exited(kids[fd])
            if time.monotonic() >= next_step:
                next_step = time.monotonic() + SUPERVISE_PERIOD
                try:
                    self._step()
                except Exception:  # (a bug here must not end the supervision)
                    log.exception("the frame publisher's supervisor failed (going on)")

    def watch(self) -> None:
        """(The I/O thread's periodic call: nothing to do here, the supervisor thread does the work.)"""

    def _step(self) -> None:
        """Start the due child, replace a stalled or never-ready one (see the class docstring); supervisor thread."""
        with self._lock:
            if self._stopping:
                return
            for child in (self.active, self.standby, *self._dying):
                if child is not None and child.proc.poll() is not None:  # (the pidfd's fallback)
                    self._exited(child)
            due = self._restart_at is not None and time.monotonic() >= self._restart_at
            if due:
                self._restart_at = None
                self.restarts += 1
            elif self._first_standby and self.active is not None and self.standby is None and \
                    self.output.ring.counters().ready:
                due, self._first_standby = True, False
        if due:
            self._adopt(self._launch())
        with self._lock:
            if self._stopping:
                return
            now = time.monotonic()
            if (self.active is None or self.standby is None) and self._restart_at is None and not self._first_standby:
                # both had ended: the standby's turn comes after the back-off
                self._restart_at = now + self._delay
                self._delay = min(RESTART_MAX_DELAY, self._delay * 2)
            for child in (self.active, self.standby):
                if child is not None and child in (self.active, self.standby) and not child.poll_ready() \
                        and now - child.started > READY_TIMEOUT:
                    self._kill(child, f"was not ready {now - child.started:.1f} s after its start")
            a = self.active
            if a is None:
                return
            c = self.output.ring.counters()
            seq = self.output.ring.seq
            if c.sent != self._seen[1] or seq == self._seen[0]:
                # it published since (progress), or the cycle wrote no frame since the last look (nothing to publish:
                # no stall either; a hot-standby NC writes none while it is the standby, for minutes: that time
                # counted as the child's silence made the first STALL_FRAMES frames after its takeover a "stall",
                # and a healthy child was killed right then, its frames gone until the failover, docs/standby.md)
                self._seen = (seq, c.sent, now)
            # (quiet since it published, was promoted or got ready, whichever came last: a fresh child that took
            # longer than STALL_TIMEOUT to start is not stalled; one not ready yet is READY_TIMEOUT's case)
            quiet = now - max(self._seen[2], a.ready_at if a.poll_ready() else now)
            if quiet > STALL_TIMEOUT and seq - self._seen[0] >= STALL_FRAMES:
                self._kill(a, f"published nothing for {quiet:.1f} s ({seq - self._seen[0]} frames written; {c})")
            elif c.ready and now - a.since > RESTART_RESET_AFTER and self._settled(self.standby, now):
                # both healthy for a while: the next failure starts the back-off anew (a standby that dies
                # at its start never gets here: its restarts keep backing off)
                self._delay = RESTART_MIN_DELAY

    @staticmethod
    def _settled(child: _Child | None, now: float) -> bool:
        """``child`` got ready and has run RESTART_RESET_AFTER since."""
        return child is not None and child.poll_ready() and now - child.ready_at > RESTART_RESET_AFTER

    def stop(self, timeout: float = 3.0) -> None:
        """Let the active child publish the last frame written and end, end the others; whatever has not ended
        ``timeout`` [s] after the call (one deadline for all) is killed."""
        end = time.monotonic() + timeout
        with self._lock:
            self._stopping = True
            children = [c for c in (self.active, self.standby, *self._dying) if c is not None]
            active = self.active
        self._wake()
        if self._watcher is not None:
            self._watcher.join(max(0.0, end - time.monotonic()))
        self.output.ring.request_stop()
        self.output.signal()
        for child in children:
            if child is not active:
                child.close()  # (its control socket closes: a standby ends; one still starting is killed below)
        for child in children:
            try:
                child.proc.wait(max(0.0, end - time.monotonic()))
            except subprocess.TimeoutExpired:
                child.proc.kill()
                child.proc.wait()
            child.close()
        for fd in (self._lifeline_r, self._lifeline_w, self._wake_r, self._wake_w):
            with contextlib.suppress(OSError):
                os.close(fd)


if __name__ == "__main__":
    sys.exit(child_main())
