"""The frame publisher (nc_server/server/publisher.py): its supervisor does the process work off the I/O thread; a
promoted publisher goes on with the decimation of the one it replaces."""
from __future__ import annotations

import threading

import numpy as np
import pytest

from nc_schema import FRAME_PERIODS_MS, NCTOPLC_DTYPE, FrameFlags, encode_frame
from nc_server.server.publisher import FrameOutput, FramePublisher, PublisherProcess
from znc_testing import wait_until

pytestmark = pytest.mark.skipif(not hasattr(__import__("os"), "pidfd_open"), reason="needs Linux")


def test_the_io_threads_watch_never_forks_and_the_supervisor_does() -> None:
    """The NC's SCHED_FIFO I/O thread calls watch() every 0.1 s: it used to start the due child itself (fork and
    exec, and kill and wait), holding replies and stats back meanwhile. The supervisor thread does it now."""
    out = FrameOutput("nc1", 1)
    pp = PublisherProcess(out, "nc1", [1], settings=None)
    launched: list[str] = []

    def launch() -> None:  # (records who starts a child; starts none: the supervisor logs and goes on)
        launched.append(threading.current_thread().name)
        raise RuntimeError("no child in this test")

    pp._launch = launch  # type: ignore[method-assign]
    pp._restart_at, pp._first_standby = 0.0, False  # a restart is due
    try:
        pp.watch()  # (what the I/O thread does)
        assert launched == []
        pp._watcher = threading.Thread(target=pp._supervise, name="nc-publisher-watch", daemon=True)
        pp._watcher.start()
        wait_until(lambda: launched or None, 10.0, "the supervisor to start the due child")
        assert launched[0] == "nc-publisher-watch"
    finally:
        pp.stop(timeout=1.0)
        out.close()


class _Pub:
    """A zenoh publisher that records what it was given."""

    def __init__(self) -> None:
        self.puts: list[bytes] = []

    def put(self, payload: bytes, **_: object) -> None:
        self.puts.append(payload)


def _publisher() -> tuple[FramePublisher, _Pub]:
    """A FramePublisher without a session (its publishers recorded): frame/10ms has a subscriber, nothing else."""
    p = FramePublisher.__new__(FramePublisher)
    p.sent = p.dropped = p.put_errors = 0
    p.frame_matched = np.zeros(1, dtype=bool)
    p.every_matched = np.array([ms == 10 for ms in FRAME_PERIODS_MS])
    p.nc_matched = p.pc_matched = np.zeros(1, dtype=bool)
    p.status_pub, p._next_status = _Pub(), float("inf")
    p.every_pubs = [(ms * 1_000_000, _Pub()) for ms in FRAME_PERIODS_MS]
    p._windows = [-1] * len(FRAME_PERIODS_MS)
    p._token_events, p.views = {}, {}  # no client views
    return p, p.every_pubs[FRAME_PERIODS_MS.index(10)][1]


def test_a_promoted_publisher_goes_on_with_the_decimation_windows_of_the_last_frame_put() -> None:
    """After a failover the new publisher put the first frame it read on frame/10ms even when the dead one had
    put that 10 ms window already: a duplicate window for every frame/<P>ms subscriber."""
    recs = np.zeros(1, dtype=NCTOPLC_DTYPE)
    frames = [encode_frame(c, c * 1_000_000, recs) for c in (11, 13, 21)]  # NC time 11, 13, 21 ms
    dead, put = _publisher()
    dead.publish(frames[0], None)
    assert put.puts == [frames[0]]
    new, put = _publisher()
    new.resume_after(frames[0])
    new.publish(frames[1], None)  # (the same 10 ms window)
    new.publish(frames[2], None)
    assert put.puts == [frames[2]]


class _FakeChild:
    def __init__(self, ready_at: float | None) -> None:
        self.ready_at = ready_at if ready_at is not None else float("inf")

    def poll_ready(self) -> bool:
        return self.ready_at != float("inf")


def test_the_back_off_resets_only_with_a_standby_that_got_ready_and_lived() -> None:
    """A standby dying at every start kept the restart delay at its minimum (a fresh interpreter and zenoh
    session every 0.1 s on a 2-core machine) once the active had run 10 s: the reset asked only that one existed."""
    from nc_server.server.publisher import RESTART_RESET_AFTER
    now = 1000.0
    assert not PublisherProcess._settled(None, now)
    assert not PublisherProcess._settled(_FakeChild(None), now)  # launched, never ready (dies at its start)
    assert not PublisherProcess._settled(_FakeChild(now - 1.0), now)  # ready, not for long yet
    assert PublisherProcess._settled(_FakeChild(now - RESTART_RESET_AFTER - 1.0), now)


class _ReadyChild:
    """An active child as the supervisor sees it: ready, alive (its publishing is the ring's sent counter)."""

    def __init__(self, at: float) -> None:
        self.proc = type("P", (), {"poll": lambda self: None, "pid": 4242})()
        self.ready_at = self.since = self.started = at

    def poll_ready(self) -> bool:
        return True


def test_a_hot_standby_ncs_quiet_time_is_no_stall_of_its_publisher(monkeypatch: pytest.MonkeyPatch) -> None:
    """A hot-standby NC writes no frame while it is the standby (minutes); at its takeover the cycle writes frames
    again. The supervisor counted the standby time as the active child's silence: once STALL_FRAMES frames were
    written before the child's first put was seen (100 ms at 1 ms cycles), it killed the healthy child ("published
    nothing for 29.5 s (544 frames written)", bench/many_clients.py --standby), and the clients had no frame until the
    failover. Only frames written and not published count: a child that publishes nothing for STALL_TIMEOUT while
    frames are written is still killed."""
    from nc_server.server import publisher as pubmod
    now = [1000.0]
    monkeypatch.setattr(pubmod, "time", type("T", (), {"monotonic": staticmethod(lambda: now[0])}))
    out = FrameOutput("nc1", 1)
    pp = PublisherProcess(out, "nc1", [1], settings=None)
    killed: list[str] = []
    pp._kill = lambda child, why: killed.append(why)  # type: ignore[method-assign]
    pp._first_standby = False
    child = _ReadyChild(now[0])
    pp.active = child  # type: ignore[assignment]
    pp.standby = _ReadyChild(now[0])  # type: ignore[assignment]
    pp._seen = (out.ring.seq, 0, now[0])
    rec = np.zeros(1, dtype=NCTOPLC_DTYPE)
    rec["AxisId"] = 1
    try:
        for _ in range(300):  # 30 s as the standby: no frame written
            now[0] += 0.1
            pp._step()
        for k in range(150):  # the takeover: 150 frames at 1 ms, the child has not put one yet
            out.put(k + 1, int(now[0] * 1e9), rec, 0, None, None)
        now[0] += 0.15
        pp._step()
        assert killed == []
        # a child that really publishes nothing while frames are written is still killed after STALL_TIMEOUT
        for k in range(30):
            for j in range(100):
                out.put(1000 + 100 * k + j, int(now[0] * 1e9), rec, 0, None, None)
            now[0] += 0.1
            pp._step()
        assert killed and killed[0].startswith("published nothing for 2."), killed  # (the fake kill ends nothing)
    finally:
        pp.active = pp.standby = None
        out.close()


def _waking_publisher(out: FrameOutput, n: int) -> FramePublisher:
    """A FramePublisher on ``out``'s ring without a session: nothing subscribed, no view yet."""
    p, _ = _publisher()
    p.every_matched = np.zeros(len(FRAME_PERIODS_MS), dtype=bool)
    p.nc_matched, p.pc_matched = np.zeros(n, dtype=bool), np.zeros(n, dtype=bool)
    p.ring, p.axis_ids, p._next_status = out.reader(), list(range(1, n + 1)), 0.0
    p._wake_lock, p._wake_at, p._last_frame, p._closed = threading.Lock(), 0, (0, 0), False
    p.frame_pub = _Pub()
    return p


def test_a_callback_after_close_writes_nothing_to_the_released_ring() -> None:
    """A matching listener may still fire on a zenoh thread while the child's session closes, after close() and
    ring.release(): it raised TypeError (a released memoryview) into zenoh's log, a Traceback at every clean exit
    where it happened. After close() wake_now writes nothing."""
    out = FrameOutput("nc1", 2)
    try:
        p = _waking_publisher(out, 2)
        p._decl, p.views = [], {}
        p.wake_now()  # (before close: it writes)
        p.close()
        p.ring.release()
        p.wake_now()  # raised TypeError: argument must be read-write bytes-like object, not memoryview
    finally:
        out.close()


def test_the_publisher_is_signalled_only_for_the_frames_it_has_a_put_due_for() -> None:
    """Issue 19: the cycle signalled the publisher every frame (1 ms) although the clients' views go out every 10 ms:
    ~10 % of a core for wakes with nothing to put. The publisher plans its next due put (WakeAtNs) and the cycle
    signals only for it; a subscriber of every frame (or a view of period 0) gets every frame as before, and a
    matching listener or view token that comes makes the next frame signal."""
    import os
    from nc_server.server.publisher import _View
    n = 4
    out = FrameOutput("nc1", n)
    p = _waking_publisher(out, n)
    view = _View(_Pub())
    view.rows, view.selected, view.period_ns = [0, 2], b"1,3", 10_000_000
    p.views["plc1"] = view
    rec = np.zeros(n, dtype=NCTOPLC_DTYPE)
    rec["AxisId"] = np.arange(1, n + 1)
    woken: list[int] = []
    cycle = [0]

    def run(frames: int) -> None:
        for _ in range(frames):
            cycle[0] += 1
            out.put(cycle[0], cycle[0] * 1_000_000, rec, 0, None, None)  # 1 ms cycles, NC time = cycle ms
            try:
                os.eventfd_read(out.eventfd)
            except BlockingIOError:
                continue
            woken.append(cycle[0])
            assert p.publish_newest()

    try:
        p._next_status = __import__("time").monotonic() + 3600.0  # (no status due in this test)
        run(100)
        assert woken == [1] + list(range(10, 101, 10))  # the first frame (no plan yet), then each 10 ms window
        assert len(view.pub.puts) == len(woken) and p.dropped == 0
        p.frame_matched[0] = True
        p.wake_now()  # (the matching listener: nc-scope subscribed nc/<nc>/frame)
        woken.clear()
        run(20)
        assert woken == list(range(101, 121)) and len(p.frame_pub.puts) == 20
        p.frame_matched[0] = False
        p.wake_now()
        woken.clear()
        run(30)
        assert woken == [121, 130, 140, 150]
        final = len(woken)
        cycle[0] += 1
        out.put(cycle[0], cycle[0] * 1_000_000, rec, int(FrameFlags.ShuttingDown), None, None)
        assert os.eventfd_read(out.eventfd) == 1 and final == 4  # the last frame always wakes it
    finally:
        out.close()


def test_frames_skipped_before_the_due_one_are_not_dropped_ones_after_it_are() -> None:
    """A publisher that wakes only for its due frames skips the others by design (not counted in frames_dropped); one
    that woke late skipped due frames (counted); with every frame due, every skipped frame counts, as before."""
    n = 1
    out = FrameOutput("nc1", n)
    p = _waking_publisher(out, n)
    p._next_status = __import__("time").monotonic() + 3600.0
    p.every_matched[FRAME_PERIODS_MS.index(10)] = True
    rec = np.zeros(n, dtype=NCTOPLC_DTYPE)
    off = 300_000  # (NC time is no multiple of the cycle: frames at 1.3, 2.3, ... ms)
    try:
        out.put(1, 1_000_000 + off, rec, 0, None, None)
        assert p.publish_newest() and out.ring.wake_at == 10_000_000 and p.dropped == 0
        for c in range(2, 11):  # up to the due frame (the first at or after 10 ms: 10.3 ms): read at once
            out.put(c, c * 1_000_000 + off, rec, 0, None, None)
        assert p.publish_newest() and p.dropped == 0
        for c in range(11, 24):  # woke 3 frames late (due: 20.3 ms, read: 23.3 ms)
            out.put(c, c * 1_000_000 + off, rec, 0, None, None)
        assert p.publish_newest() and p.dropped == 3
        p.frame_matched[0] = True  # every frame due: every skipped one counts, as before
        p.wake_now()
        out.put(24, 24_000_000 + off, rec, 0, None, None)
        assert p.publish_newest() and out.ring.wake_at == 0 and p.dropped == 3
        for c in range(25, 28):
            out.put(c, c * 1_000_000 + off, rec, 0, None, None)
        assert p.publish_newest() and p.dropped == 5
    finally:
        out.close()
