"""The hot standby's loss detection (docs/standby.md, "Loss detection"): a late log of the active NC is no loss, a
missing one is; the limit the standby publishes follows what it saw. HotStandby over a server without zenoh."""
from __future__ import annotations

import math
import time
from types import SimpleNamespace

import pytest

import nc_server.core  # noqa: F401  (before nc_server.drives: circular import otherwise)
from nc_server.server.config import Redundancy
from nc_server.server.standby import (GAP_BIN_S, GAP_FACTOR, GAP_WINDOW_S, LIMIT_CAP_S, WARMUP_FLOOR_S, WARMUP_S,
                                     HotStandby, LossDetector)

from test_replication import Active

DT = 0.002
TAKEOVER = 15  # the default takeover_cycles: 30 ms


def standby() -> HotStandby:
    act = Active()
    srv = SimpleNamespace(core=act.rec, handler=act.handler, config=SimpleNamespace(name="nc1", cycle_time=DT),
                          transport=SimpleNamespace(instance="i1"))
    hs = HotStandby(srv, Redundancy(True, "standby", TAKEOVER, 10.0, "b"))  # type: ignore[arg-type]
    return hs


def in_step(hs: HotStandby, now: float) -> None:
    """As _take_snapshot then the first log: in step from a snapshot at ``now``."""
    hs.follower.waiting = False
    hs.synced_once = True
    hs._last_log = now
    hs.detector.restart(now)


def run(hs: HotStandby, t0: float, t1: float, log_gaps: dict[float, float]) -> float | None:
    """The standby's cycles from t0 to t1 (every DT); the active NC's logs every DT but for the gaps (start -> length)
    given. The time the standby deems the active NC lost, or None."""
    t, next_log = t0, t0
    while t < t1:
        if t >= next_log:
            hs.detector.log(t)
            hs._last_log = t
            gap = next((g for s, g in log_gaps.items() if s <= t < s + DT), 0.0)
            next_log = t + DT + gap
        if hs._lost(t):
            return t
        t += DT
    return None


def test_a_late_cycle_of_the_active_nc_at_the_start_is_no_takeover() -> None:
    # the false takeover of bench/takeover.py under bench/cpu_burner.py: the standby came in step, then the active NC
    # (realtime off, both cores busy) sent no log for 157 ms; with a fixed limit of takeover_cycles (30 ms) the
    # standby took over, the active NC demoted itself and the drives saw two epochs change hands without any fault
    hs = standby()
    in_step(hs, 0.0)
    assert run(hs, 0.0, WARMUP_S + 0.2, {0.5: 0.157, 1.2: 0.060}) is None
    # the gap raised the published limit (after the warm-up): GAP_FACTOR x 157 ms
    lim = hs.detector.limit(WARMUP_S + 0.2)
    assert abs(lim - GAP_FACTOR * (0.157 + DT)) < 3 * DT, lim
    assert hs._limit_cycles(WARMUP_S + 0.2) == math.ceil(lim / DT - 1e-9)


def test_a_frozen_active_nc_is_lost_within_the_published_limit() -> None:
    hs = standby()
    in_step(hs, 0.0)
    # after the warm-up, with logs on time: the limit is takeover_cycles
    assert run(hs, 0.0, WARMUP_S + 0.5, {}) is None
    t0 = WARMUP_S + 0.5
    assert hs._limit_cycles(t0) == TAKEOVER
    lost = run(hs, t0, t0 + 1.0, {t0: 10.0})  # the active NC freezes
    assert lost is not None and TAKEOVER * DT < lost - t0 <= (TAKEOVER + 2) * DT, lost - t0
    # during the warm-up the floor holds
    hs2 = standby()
    in_step(hs2, 0.0)
    lost = run(hs2, 0.0, 2.0, {0.1: 10.0})
    assert lost is not None and WARMUP_FLOOR_S < lost - 0.1 <= WARMUP_FLOOR_S + 3 * DT


def test_the_limit_is_capped_and_forgets_old_gaps() -> None:
    d = LossDetector(TAKEOVER * DT)
    d.restart(0.0)
    d.log(0.0)
    d.log(5.0)  # a 5 s gap
    assert d.limit(5.0) == LIMIT_CAP_S
    d.log(5.002)
    assert d.limit(5.0 + GAP_WINDOW_S - 1) == LIMIT_CAP_S  # (kept for the window)
    assert d.limit(5.0 + GAP_WINDOW_S + GAP_BIN_S + 0.01) == TAKEOVER * DT  # then forgotten, warm-up over


def test_the_gaps_outlive_a_resync_and_the_window_holds_however_many_gaps_come() -> None:
    # how late logs come is the machine's: a re-sync (restart) keeps the history, and 1000 small gaps a second do
    # not push a large one out before GAP_WINDOW_S
    d = LossDetector(TAKEOVER * DT)
    t = 10.0
    d.restart(t - 0.031)
    d.log(t - 0.030)
    d.log(t)  # a 30 ms gap
    d.restart(t + 1.0)  # (in step again from a snapshot)
    t += 1.0
    for _ in range(8_000):  # 40 s of 5 ms gaps, each above base/4
        t += 0.005
        d.log(t)
    assert abs(d.limit(t) - GAP_FACTOR * 0.030) < 1e-9
    d.restart(t, forget=True)
    assert d.limit(t + WARMUP_S + 0.1) == max(TAKEOVER * DT, GAP_FACTOR * 0.0)


def test_the_standbys_own_late_cycle_defers_the_judgement_once() -> None:
    d = LossDetector(TAKEOVER * DT)
    d.restart(-10.0)
    for k in range(5001):  # logs on time for 10 s
        d.log(-10.0 + k * DT)
        d.silent(-10.0 + k * DT)
    # the standby's cycle thread was descheduled 200 ms: the logs may be queued in zenoh; the next cycle judges
    assert not d.silent(0.2)
    assert d.silent(0.202)


def test_an_nc_that_drove_and_saw_a_higher_epoch_never_takes_over_without_a_snapshot() -> None:
    # a SIGCONT'd active NC demoted itself; its session recovered without logs for a second: it must not take over
    # from its own core, which is behind its successor's (a SetPos jump)
    hs = standby()
    hs.epoch = hs.highest = 5 << 16
    hs.synced_once = False
    hs._grace = 0.2
    hs._started = hs._last_log = 0.0
    assert hs._lost(1.0)  # nobody else took over: its own state is the newest, it takes over again
    hs.highest = 6 << 16  # a log of epoch 6 came (the standby took over)
    assert not hs._lost(1.0) and not hs._lost(100.0)
    hs.epoch = 0  # a fresh standby (never drove): the start rule, its core is a fresh NC's
    assert hs._lost(3.0)


def test_the_active_nc_demotes_itself_for_a_stall_near_its_standbys_limit() -> None:
    hs = standby()
    hs.srv.became_standby = lambda: None  # type: ignore[attr-defined]
    hs.role, hs.peer_in_step, hs.epoch = "active", True, 1 << 16
    hs._peer_limits["a"] = (0.300, time.monotonic())  # the standby's published limit
    assert not hs.after_stall(0.200)  # forgiven by the standby: it goes on
    assert hs.role == "active"
    assert hs.after_stall(0.240)  # > 0.75 x 0.3: the standby may have taken over (its last log came late)
    assert hs.role == "standby" and hs._grace == pytest.approx(max(2.0, 2 * 0.225 + 0.1))


def test_the_limit_follows_the_largest_gap_as_gaps_come_and_go() -> None:
    # limit() keeps the largest gap of its bins instead of scanning them every standby cycle: the same limits as a
    # scan of every gap whose bin is in the window
    import random
    rnd = random.Random(5)
    d = LossDetector(0.015, 10.0)
    d.restart(0.0)
    import collections
    every: collections.deque[tuple[float, float]] = collections.deque()  # (bin start, gap) of every gap above base/4
    now, prev = 0.0, 0.0
    for k in range(40000):
        now += rnd.choice((0.001, 0.004, 0.004, 0.005, 0.006, 0.02, 0.004 + 0.05 * rnd.random(), 0.4 * rnd.random()))
        d.log(now)
        if now - prev > d.base / 4:
            every.append((now - now % GAP_BIN_S, now - prev))
        prev = now
        if k == 20000:
            d.gaps.clear()
            every.clear()
        lim = d.limit(now)
        while every and now - every[0][0] > GAP_WINDOW_S + GAP_BIN_S:
            every.popleft()
        scan = max((x for _, x in every), default=0.0)
        want = max(d.base, GAP_FACTOR * scan)
        if now - d.since < WARMUP_S:
            want = max(want, WARMUP_FLOOR_S)
        assert lim == max(d.base, min(want, d.cap)), (k, lim, want)
    assert now > 3 * GAP_WINDOW_S  # (bins went out of the window)


def test_no_gap_before_the_first_restart_nor_while_not_in_step() -> None:
    # a standby's first log (waiting for its first snapshot) comes a whole clock after the detector was made, and a
    # standby waiting for a snapshot measures the cut or the snapshot's cost: neither is kept as the machine's gap
    d = LossDetector(TAKEOVER * DT, 1.0)
    d.log(5000.0)
    d.restart(5000.2)
    assert d.limit(5000.2 + WARMUP_S + 0.1) == TAKEOVER * DT
    d.log(5010.0, record=False)  # (a 9.8 s silence while out of step)
    assert d.limit(5010.0) == TAKEOVER * DT
    d.log(5010.1)  # (in step: kept)
    assert abs(d.limit(5010.1) - GAP_FACTOR * 0.1) < 1e-9


def test_a_demoted_active_nc_starts_with_its_standbys_limit() -> None:
    # the old active NC's detector saw no gap while it was active: _become_standby seeds it with what its standby
    # published (fresh statuses only)
    hs = standby()
    hs.srv.became_standby = lambda: None  # type: ignore[attr-defined]
    hs.role, hs.peer_in_step, hs.epoch = "active", True, 1 << 16
    now = time.monotonic()
    hs._peer_limits["b"] = (0.240, now - 1.0)
    hs._peer_limits["c"] = (0.900, now - 30.0)  # (not fresh: not counted)
    hs._become_standby(now, "test")
    assert hs.role == "standby"
    assert abs(hs.detector.limit(now + WARMUP_S + 0.1) - 0.240) < 1e-9
    assert hs.detector.limit(now + GAP_WINDOW_S + 2 * GAP_BIN_S) == hs.detector.base
