"""The cycle loop: fixed rate, missed cycles skipped (never replayed), scheduling fallback."""
from __future__ import annotations

import os
import time

import pytest

from nc_server.server import cycle as cycle_mod
from nc_server.server.cycle import CycleLoop, CycleStats, RealtimeError, set_realtime


def run_loop(period: float, n: int, slow_at: int | None = None, slow_s: float = 0.0) -> tuple[CycleLoop, list[int]]:
    """Run ``n`` cycles; ``loop.missed_before_first`` is what a late start skipped before the first one."""
    deadlines: list[int] = []
    loop: CycleLoop

    def work(deadline_ns: int) -> None:
        if not deadlines:  # a loaded machine may start the thread after its first deadline(s)
            loop.missed_before_first = loop.stats.missed_cycles  # type: ignore[attr-defined]
        deadlines.append(deadline_ns)
        if len(deadlines) == slow_at:
            time.sleep(slow_s)
        if len(deadlines) >= n:
            loop.stop_event.set()

    loop = CycleLoop(period, work, realtime="off")
    loop.start()
    deadline = time.monotonic() + 60
    while loop.alive and time.monotonic() < deadline:
        time.sleep(0.01)
    loop.stop()
    assert loop.error is None
    return loop, deadlines


def test_deadlines_are_a_fixed_grid() -> None:
    loop, d = run_loop(0.002, 50)
    assert len(d) == 50
    steps = {(b - a) % loop.period_ns for a, b in zip(d, d[1:])}
    assert steps == {0}  # every deadline lies on the period grid
    assert all(b > a for a, b in zip(d, d[1:]))
    st = loop.stats
    assert st.cycles == 50 and st.timing == "SCHED_OTHER"
    # every cycle either ran on its own deadline or was counted as missed
    assert (d[-1] - d[0]) // loop.period_ns == 49 + st.missed_cycles - loop.missed_before_first


def test_missed_cycles_are_skipped_not_replayed() -> None:
    period = 0.002
    loop, d = run_loop(period, 20, slow_at=5, slow_s=10 * period)
    st = loop.stats
    assert st.overruns >= 1
    assert st.missed_cycles >= 8  # ~10 periods lost in the slow cycle
    gap = (d[5] - d[4]) // loop.period_ns
    assert gap >= 9  # the loop jumped ahead instead of running the lost cycles back to back
    assert (d[-1] - d[0]) // loop.period_ns == 19 + st.missed_cycles - loop.missed_before_first


def test_stats_percentiles() -> None:
    st = CycleStats()
    assert st.percentiles()["work_us_p99"] == 0.0
    for k in range(100):
        st.record(work_ns=(k + 1) * 1000, lateness_ns=5000)
    p = st.percentiles()
    assert p["work_us_max"] == 100.0 and 49 <= p["work_us_p50"] <= 52 and p["lateness_us_p99"] == 5.0


def test_stats_percentiles_cover_the_last_ring_of_cycles_only() -> None:
    """(histograms kept by record(): the cycles that leave the ring leave the histograms too)"""
    import numpy as np

    from nc_server.server.cycle import RING
    st = CycleStats()
    for _ in range(RING):
        st.record(work_ns=900_000, lateness_ns=400_000)  # an old slow period
    rng = np.random.default_rng(1)
    w = rng.integers(10_000, 300_000, RING)
    for x in w.tolist():
        st.record(work_ns=x, lateness_ns=7_000)
    p = st.percentiles()
    for q, key in ((50, "work_us_p50"), (99, "work_us_p99")):
        assert abs(p[key] - np.percentile(w / 1000, q)) <= 1.5, (key, p[key])
    assert p["lateness_us_p99"] == 7.0 and p["work_us_max"] == round(w.max() / 1000, 1)
    st.record(work_ns=50_000_000, lateness_ns=0)  # beyond the histogram: its last bin; the max is exact
    assert st.percentiles()["work_us_max"] == 50_000.0


def test_realtime_fallback(monkeypatch: pytest.MonkeyPatch) -> None:
    assert set_realtime("off", 49)[0] == "SCHED_OTHER"

    def refuse(*_a: object) -> None:
        raise PermissionError(1, "Operation not permitted")

    monkeypatch.setattr(cycle_mod.os, "sched_setscheduler", refuse)
    timing, detail = set_realtime("auto", 49)
    assert timing == "SCHED_OTHER" and "not permitted" in detail
    with pytest.raises(RealtimeError):
        set_realtime("fifo", 49)
    loop = CycleLoop(0.001, lambda d: None, realtime="fifo")
    with pytest.raises(RealtimeError):
        loop.start()


@pytest.mark.skipif(not hasattr(os, "sched_getscheduler"), reason="Linux only")
def test_fifo_only_on_the_cycle_thread() -> None:
    seen: list[int] = []
    loop: CycleLoop

    def work(_d: int) -> None:
        seen.append(os.sched_getscheduler(0))
        # a thread made from the cycle thread (zenoh makes some lazily) does not inherit SCHED_FIFO
        import threading
        child: list[int] = []
        t = threading.Thread(target=lambda: child.append(os.sched_getscheduler(0)))
        t.start()
        t.join()
        seen.extend(child)
        loop.stop_event.set()

    loop = CycleLoop(0.001, work, realtime="auto")
    loop.start()
    deadline = time.monotonic() + 30
    while loop.alive and time.monotonic() < deadline:
        time.sleep(0.01)
    loop.stop()
    assert os.sched_getscheduler(0) == os.SCHED_OTHER  # the starting thread is untouched
    if loop.stats.timing == "SCHED_FIFO":
        assert seen == [os.SCHED_FIFO | getattr(os, "SCHED_RESET_ON_FORK", 0), os.SCHED_OTHER]
    else:
        assert seen == [os.SCHED_OTHER, os.SCHED_OTHER] and "not permitted" in loop.stats.timing_detail


def test_cpus_pin_the_cycle_thread_only() -> None:
    import os
    cpus = sorted(os.sched_getaffinity(0))
    seen: list[set[int]] = []
    loop = CycleLoop(0.001, lambda d: seen.append(os.sched_getaffinity(0)), realtime="off", cpus=frozenset({cpus[-1]}))
    loop.start()
    try:
        wait = time.monotonic() + 10
        while len(seen) < 5 and time.monotonic() < wait:
            time.sleep(0.01)
    finally:
        loop.stop()
    assert seen and seen[-1] == {cpus[-1]}
    assert f"on CPU {cpus[-1]}" in loop.stats.timing_detail
    assert sorted(os.sched_getaffinity(0)) == cpus  # the calling thread keeps its CPUs


def test_impossible_cpus_refuse_to_start() -> None:
    loop = CycleLoop(0.001, lambda d: None, realtime="off", cpus=frozenset({4096}))
    with pytest.raises(cycle_mod.AffinityError, match="cpu_affinity"):
        loop.start()


def test_a_relaxed_loop_sleeps_up_to_its_deadlines_without_spinning(monkeypatch: pytest.MonkeyPatch) -> None:
    # a hot-standby NC's cycle while it is a standby (NcServer.cycle sets relaxed): no spin, no yield loop; the
    # deadlines stay on the grid; set back to False, the loop spins again
    yields = [0]
    real = os.sched_yield

    def counted() -> None:
        yields[0] += 1
        real()

    monkeypatch.setattr(os, "sched_yield", counted)
    deadlines: list[int] = []
    woke: list[int] = []
    spin_from = [0.0]  # when relaxed was set back to False [monotonic s]
    loop: CycleLoop

    def work(deadline_ns: int) -> None:
        woke.append(time.monotonic_ns() - deadline_ns)
        deadlines.append(deadline_ns)
        if len(deadlines) == 30:
            assert yields[0] == 0  # (relaxed: never spun)
            loop.relaxed = False
            spin_from[0] = time.monotonic()
        # (until it yields, at most 10 s: a loaded machine can make cycles late, and a late one does not spin)
        if len(deadlines) >= 60 and (yields[0] > 0 or time.monotonic() > spin_from[0] + 10.0):
            loop.stop_event.set()

    loop = CycleLoop(0.002, work, realtime="off")
    loop.relaxed = True
    loop.start()
    end = time.monotonic() + 60
    while loop.alive and time.monotonic() < end:
        time.sleep(0.01)
    loop.stop()
    assert loop.error is None and len(deadlines) >= 60
    assert all(w >= 0 for w in woke)  # (never before a deadline)
    assert {(b - a) % loop.period_ns for a, b in zip(deadlines, deadlines[1:])} == {0}
    assert yields[0] > 0  # (spinning again once not relaxed)


def test_other_threads_are_given_the_io_nice_value_unless_kept_or_already_higher() -> None:
    # zenoh's threads made lazily from the SCHED_FIFO cycle thread start at nice 0 (SCHED_RESET_ON_FORK): the I/O
    # thread's pass gives them IO_NICE; a kept thread and one already at a lower nice value keep theirs
    import threading
    ready = threading.Barrier(4)
    done = threading.Event()
    ids: dict[str, int] = {}

    def worker(name: str, nice: int) -> None:
        os.setpriority(os.PRIO_PROCESS, 0, nice)
        ids[name] = threading.get_native_id()
        ready.wait()
        done.wait(30)

    if os.getpriority(os.PRIO_PROCESS, 0) > 2:
        pytest.skip("this process runs above nice 2")
    threads = [threading.Thread(target=worker, args=a) for a in (("zenoh", 4), ("kept", 5), ("higher", 1))]
    for t in threads:
        t.start()
    try:
        ready.wait(10)
        try:
            changed = cycle_mod.raise_other_threads({ids["kept"]}, 2)
        except PermissionError:
            pytest.skip("raising a thread's priority is not permitted here")
        prio = {k: os.getpriority(os.PRIO_PROCESS, v) for k, v in ids.items()}
        if prio["zenoh"] == 4:
            pytest.skip("raising a thread's priority is not permitted here")
        assert prio == {"zenoh": 2, "kept": 5, "higher": 1}
        assert ids["zenoh"] in changed and ids["kept"] not in changed and ids["higher"] not in changed
    finally:
        done.set()
        for t in threads:
            t.join(10)
