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
  while each has a subscriber.

Its zenoh session is a client of the NC's own session (router or peer mode: one of its listen
endpoints, over loopback when it listens on every address) or of the NC's router (client mode:
the NC's connect endpoints), with the NC's certificate when TLS is on: on the wire it is the NC.
The child dies with the NC (PR_SET_PDEATHSIG, and it checks its parent every second); the NC
restarts a child that died (:class:`PublisherProcess`). ``[nc] publisher = "thread"`` runs the
same loop in a thread of the NC process instead (one interpreter; for platforms without eventfd).
"""
from __future__ import annotations

import argparse
import json
import logging
import mmap
import os
import select
import signal
import subprocess
import sys
import threading
import time
import weakref
from dataclasses import asdict
from typing import Any, Callable, Sequence

import numpy as np

from nc_schema import FRAME_HEADER_DTYPE, FRAME_PERIODS_MS, NCTOPLC_DTYPE, PLCTONC_DTYPE, FrameFlags, Keys, encode_stamp

from .frame_ring import FrameRing, ring_bytes

log = logging.getLogger("nc_server.server")

#: Period of ``nc/<nc>/status`` (the newest frame again, decimated for observers on slow links) [s].
STATUS_PERIOD = 0.1
#: The publisher checks its parent (and the stop flag) at least this often [s].
PARENT_CHECK = 0.5
#: The NC checks its publisher child this often, and restarts it if it died [s].
WATCH_PERIOD = 0.5

_HEADER = FRAME_HEADER_DTYPE.itemsize
_NREC = NCTOPLC_DTYPE.itemsize
_PREC = PLCTONC_DTYPE.itemsize
_FRAME_CYCLE = 8   # offsets of Cycle and NcTimeNs in FRAME_HEADER
_FRAME_TIME = 16
_FRAME_FLAGS = 28
_SHUTTING_DOWN = int(FrameFlags.ShuttingDown)


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
        opts = dict(congestion_control=zenoh.CongestionControl.DROP, express=False)
        s = session

        def matcher(arr: np.ndarray, i: int) -> Callable[[Any], None]:
            def on_matching(status: Any) -> None:  # on a zenoh thread: keep it tiny
                arr[i] = bool(status.matching)
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
        self.ring.set_counters(0, 0, 0, True)

    def close(self) -> None:
        for d in reversed(self._decl):
            try:
                d.undeclare()
            except Exception:  # session closing
                pass
        self._decl.clear()

    def publish_newest(self) -> bool:
        """Publish the newest slot if there is one not yet published; whether there was."""
        got = self.ring.read_newest()
        if got is None:
            return False
        _seq, frame, plc, skipped = got
        self.dropped += skipped
        self.publish(frame, plc)
        self.ring.set_counters(self.sent, self.dropped, self.put_errors, True)
        return True

    def publish(self, frame: bytes, plc: bytes | None) -> None:
        """Put one frame (and its PLCTONC) on every key that has a subscriber; the NC's last frame (flag
        ShuttingDown) on every frame key, whatever the period."""
        try:
            final = bool(int.from_bytes(frame[_FRAME_FLAGS:_FRAME_FLAGS + 4], "little") & _SHUTTING_DOWN)
            if self.frame_matched[0]:
                self.frame_pub.put(frame)
            nc_time_ns = int.from_bytes(frame[_FRAME_TIME:_FRAME_TIME + 8], "little")
            if self.every_matched.any():
                for i, (period_ns, pub) in enumerate(self.every_pubs):
                    w = nc_time_ns // period_ns
                    if (w != self._windows[i] or final) and self.every_matched[i]:
                        self._windows[i] = w
                        pub.put(frame)
            now = time.monotonic()
            if now >= self._next_status or final:
                self._next_status = now + STATUS_PERIOD
                self.status_pub.put(frame)
            if self.nc_matched.any() or (plc is not None and self.pc_matched.any()):
                cycle = int.from_bytes(frame[_FRAME_CYCLE:_FRAME_CYCLE + 8], "little")
                stamp = encode_stamp(cycle, nc_time_ns)
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

    def run(self, wait: Callable[[float], bool], alive: Callable[[], bool] = lambda: True) -> None:
        """Publish until the ring asks to stop (after publishing what is there) or ``alive()`` is False.

        Args:
            wait: blocks until the writer signals or the timeout [s] passes; whether it signalled.
            alive: checked at least every PARENT_CHECK s.
        """
        ring = self.ring
        while True:
            wait(PARENT_CHECK)
            self.publish_newest()
            if ring.stop_requested or not alive():
                self.publish_newest()
                return


# ---- the child process -------------------------------------------------------------------------
def _eventfd_wait(fd: int) -> Callable[[float], bool]:
    poller = select.poll()
    poller.register(fd, select.POLLIN)

    def wait(timeout: float) -> bool:
        if not poller.poll(int(timeout * 1000)):
            return False
        try:
            os.eventfd_read(fd)
        except BlockingIOError:
            return False
        return True
    return wait


def _die_with_parent() -> None:
    try:
        import ctypes
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(1, signal.SIGKILL, 0, 0, 0)  # PR_SET_PDEATHSIG
    except Exception:  # not Linux: the parent check in run() still ends it
        pass


def child_main(argv: Sequence[str] | None = None) -> int:
    """``python -m nc_server.server.publisher --spec JSON``: the NC's frame publisher (started by the NC)."""
    p = argparse.ArgumentParser(prog="nc-publisher")
    p.add_argument("--spec", required=True, help="JSON: nc, axis_ids, ring_fd, event_fd, parent, zenoh settings")
    args = p.parse_args(argv)
    spec = json.loads(args.spec)
    _die_with_parent()
    parent = int(spec["parent"])
    if os.getppid() != parent:
        return 0  # the NC is already gone
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the NC's Ctrl-C: the NC stops us
    logging.basicConfig(level=spec.get("log_level", "WARNING"), format="%(asctime)s nc-publisher %(levelname)s %(message)s")
    try:
        os.nice(int(spec.get("nice", 0)))
    except OSError:
        pass
    import zenoh

    from .config import ZenohSettings
    from .transport import zenoh_config

    axis_ids = [int(a) for a in spec["axis_ids"]]
    mm = mmap.mmap(int(spec["ring_fd"]), ring_bytes(len(axis_ids)))
    ring = FrameRing(memoryview(mm), len(axis_ids))
    settings = ZenohSettings(**{k: (tuple(v) if isinstance(v, list) else v) for k, v in spec["zenoh"].items()})
    session = zenoh.open(zenoh_config(settings, spec["nc"]))
    pub = FramePublisher(session, Keys(spec["nc"]), axis_ids, ring)
    try:
        pub.run(_eventfd_wait(int(spec["event_fd"])), alive=lambda: os.getppid() == parent)
    finally:
        pub.close()
        ring.release()
        session.close()
        mm.close()
    return 0


def publisher_settings(settings: Any) -> dict[str, Any]:
    """The publisher's zenoh settings (as a dict) for an NC with ``settings`` (ZenohSettings): a client of
    the NC's own session (its first listen endpoint; ``0.0.0.0``/``[::]`` -> loopback), or, for an NC in
    client mode, of the same router(s)."""
    d = asdict(settings)
    if settings.mode == "client":
        connect = list(settings.connect)
    else:
        ep = settings.listen[0] if settings.listen else None
        if ep is None:
            connect = list(settings.connect)
        else:
            proto, _, rest = ep.partition("/")
            host, _, port = rest.rpartition(":")
            if host in ("0.0.0.0", "[::]", "::"):
                host = "localhost" if proto == "tls" else "127.0.0.1"
            connect = [f"{proto}/{host}:{port.split('#')[0]}"]
    d.update(mode="client", listen=[], connect=connect)
    return d


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
        self._readers: list[FrameRing] = []
        self._finalizer = weakref.finalize(self, FrameOutput._release, self._mm, self.memfd, self.eventfd,
                                           [self.ring], self._readers)

    def reader(self) -> FrameRing:
        """A reader of this ring in this process (it sees what is written after this call)."""
        r = FrameRing(self.ring.mv, self.n_axes)
        self._readers.append(r)
        return r

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

    def stop(self, timeout: float = 3.0) -> None:
        """Publish the last frame written, then end the thread."""
        self.output.ring.request_stop()
        self.output.signal()
        if self._thread is not None:
            self._thread.join(timeout)
        if self.pub is not None:
            self.pub.close()


class PublisherProcess:
    """The frame publisher as a child process (``publisher = "process"``, the default).

    Args:
        output: the server's frames (the child maps the same memfd and waits on the same eventfd).
        nc, axis_ids: the NC.
        settings: the NC's ZenohSettings (the child's session: :func:`publisher_settings`).
        nice: the child's nice value (the NC's zenoh threads' by default: ahead of the PLC clients).
        log_level: the child's logging level.

    The child dies with the NC (PR_SET_PDEATHSIG, set in the child, and its parent check); one that
    dies on its own is restarted by :meth:`watch` (the NC's I/O thread calls it every second).
    """

    def __init__(self, output: FrameOutput, nc: str, axis_ids: Sequence[int], settings: Any, nice: int = 0,
                 log_level: str = "WARNING") -> None:
        self.output = output
        self.nc = nc
        self.axis_ids = [int(a) for a in axis_ids]
        self.settings = settings
        self.nice = nice
        self.log_level = log_level
        self.proc: subprocess.Popen[bytes] | None = None
        self.restarts = 0
        self._stopping = False

    def start(self) -> None:
        """Start the child (returns at once; it declares its publishers within ~0.1-1 s)."""
        o = self.output
        spec = {"nc": self.nc, "axis_ids": self.axis_ids, "ring_fd": o.memfd, "event_fd": o.eventfd,
                "parent": os.getpid(), "zenoh": publisher_settings(self.settings), "nice": self.nice,
                "log_level": self.log_level}
        self.proc = subprocess.Popen([sys.executable, "-m", "nc_server.server.publisher", "--spec", json.dumps(spec)],
                                     pass_fds=(o.memfd, o.eventfd), stdin=subprocess.DEVNULL)

    @property
    def pid(self) -> int | None:
        return self.proc.pid if self.proc is not None else None

    def watch(self) -> None:
        """Restart the child if it died."""
        p = self.proc
        if self._stopping or p is None or p.poll() is None:
            return
        log.error("the frame publisher (pid %d) ended with %s: restarting it (clients miss frames meanwhile)",
                  p.pid, p.returncode)
        self.restarts += 1
        self.start()

    def stop(self, timeout: float = 3.0) -> None:
        """Let the child publish the last frame written and end (killed after ``timeout``)."""
        self._stopping = True
        self.output.ring.request_stop()
        self.output.signal()
        p = self.proc
        if p is not None:
            try:
                p.wait(timeout)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()


if __name__ == "__main__":
    sys.exit(child_main())
