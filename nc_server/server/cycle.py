"""The fixed-rate cycle loop: the best timing the OS allows, counted honestly.

* Scheduling: ``SCHED_FIFO`` on the cycle thread only, set from inside that thread (Linux:
  pid 0 = the calling thread) after every zenoh thread exists, so nothing inherits it. If it
  is not permitted the loop runs with normal scheduling (``realtime="auto"``) or refuses to
  start (``realtime="fifo"``).
* Waiting: sleep until deadline - spin (GIL released), then spin on the clock. The spin is adaptive
  (:func:`adapted_spin`): as long as the sleeps' late wake-ups of the last second needed (their 99.8th
  percentile + 30 us), between 30 and 200 us: on a quiet machine about 100 us, on a loaded one 200 us. A SCHED_FIFO thread spinning takes its CPU from every
  normal process (sched_yield only lets threads of its own priority in): a fixed 200 us was 20 % of a
  core, whether the machine's wake-ups needed it or not. With an ``idle``
  callback the sleep is cut into slices with ``idle()`` between them, and with a ``wake`` event a
  slice ends early when the event is set (a command arrived: answered at once). While more
  than :data:`SPIN_YIELD_NS` remain the spin calls ``os.sched_yield()`` (releases the GIL and
  lets other threads in); only the last few microseconds are a pure spin. A FIFO thread never
  spins 100 % (RT throttling is 950 ms per 1 s): it sleeps for most of every cycle.
* Lateness: a deadline passed by more than one period is *missed*: the loop skips ahead to the
  newest due deadline (cycles are never replayed). A cycle whose work ends after the next
  deadline is an *overrun*.

All times are CLOCK_MONOTONIC nanoseconds (``time.monotonic_ns``) unless noted.
"""
from __future__ import annotations

import heapq
import logging
import os
import sys
import threading
import time
from dataclasses import dataclass
from typing import Callable

import numpy as np

log = logging.getLogger("nc_server.server")

#: Longest spin before a deadline [ns] (the spin the loop starts with).
SPIN_NS = 200_000
#: Shortest spin [ns].
SPIN_MIN_NS = 30_000
#: The spin is what the sleeps' late wake-ups needed: the SPIN_QUANTILE of the last SPIN_WINDOW wake-up
#: errors (how much later than asked a sleep returned, GIL included) plus SPIN_MARGIN_NS, between
#: SPIN_MIN_NS and SPIN_NS, recomputed every SPIN_EVERY cycles.
SPIN_WINDOW = 1000
SPIN_QUANTILE = 0.998
SPIN_MARGIN_NS = 30_000
SPIN_EVERY = 100
#: Below this remaining time the spin stops yielding the GIL [ns].
SPIN_YIELD_NS = 20_000
#: With an ``idle`` callback the sleep is cut into slices of this length, ``idle()`` between them [ns];
#: with a ``wake`` event a slice also ends when it is set, so requests arriving mid-cycle are answered at
#: once either way (each slice costs a wake-up and an idle() call: ~10 us of CPU).
IDLE_SLICE_NS = 500_000
#: Call ``idle()`` once right after the cycle's work too (before the first slice).
IDLE_AFTER_WORK = True
#: Cycles kept in the timing ring buffers (10 s at 1 kHz).
RING = 10_000
#: sys.setswitchinterval while the server runs [s]. CPython's 5 ms default would let the cycle thread
#: keep the GIL through a whole cycle while the I/O thread waits to send a reply; measured with
#: bench/command_rtt.py on a loaded 2-core VM, 0.1 ms gave MoveAbsolute round trips of ~2.0 ms p50
#: against ~2.7 ms with 0.5 ms, and no worse cycle work. (The other side: whatever the I/O thread does
#: with the GIL may delay the cycle by as much; it only sends replies, stats and claims.)
SWITCH_INTERVAL = 0.0001


def adapted_spin(errors: list[int]) -> int:
    """The spin [ns] for these wake-up errors [ns] (see the module docstring)."""
    if not errors:
        return SPIN_NS
    k = max(1, int(round(len(errors) * (1.0 - SPIN_QUANTILE))))
    q = heapq.nlargest(k, errors)[-1]
    return int(min(SPIN_NS, max(SPIN_MIN_NS, q + SPIN_MARGIN_NS)))


def _record(ring: list[int], n: int, err: int) -> int:
    """Store wake-up error number ``n`` in the SPIN_WINDOW ring; returns n + 1."""
    if n < SPIN_WINDOW:
        ring.append(err)
    else:
        ring[n % SPIN_WINDOW] = err
    return n + 1


class RealtimeError(RuntimeError):
    """``realtime="fifo"`` was required but SCHED_FIFO is not permitted."""


class AffinityError(RuntimeError):
    """``[nc] cpu_affinity`` names CPUs the cycle thread cannot be moved to."""


def set_realtime(mode: str, priority: int) -> tuple[str, str]:
    """Apply the scheduling policy to the calling thread.

    Args:
        mode: ``"auto"`` (FIFO if permitted), ``"fifo"`` (required) or ``"off"``.
        priority: SCHED_FIFO priority 1..99.

    Returns:
        (timing, detail): timing is ``"SCHED_FIFO"`` or ``"SCHED_OTHER"``; detail says why.

    Raises:
        RealtimeError: mode is ``"fifo"`` and the OS refused.
    """
    if mode == "off":
        return "SCHED_OTHER", "realtime disabled by configuration"
    if not hasattr(os, "sched_setscheduler"):
        if mode == "fifo":
            raise RealtimeError("SCHED_FIFO is not available on this platform")
        return "SCHED_OTHER", "SCHED_FIFO not available on this platform"
    try:
        # (SCHED_RESET_ON_FORK: threads zenoh creates from this one lazily do not inherit SCHED_FIFO)
        os.sched_setscheduler(0, os.SCHED_FIFO | getattr(os, "SCHED_RESET_ON_FORK", 0), os.sched_param(priority))
    except OSError as exc:
        if mode == "fifo":
            raise RealtimeError(f"SCHED_FIFO not permitted: {exc.strerror or exc}") from None
        return "SCHED_OTHER", f"SCHED_FIFO not permitted ({exc.strerror or exc}); normal scheduling"
    return "SCHED_FIFO", f"SCHED_FIFO priority {priority} on the cycle thread"


def is_realtime(tid: int = 0) -> bool:
    """Whether thread ``tid`` (0: the calling one) runs SCHED_FIFO or SCHED_RR (whatever its
    SCHED_RESET_ON_FORK flag, which ``sched_getscheduler`` ORs into the policy)."""
    policy = os.sched_getscheduler(tid) & ~getattr(os, "SCHED_RESET_ON_FORK", 0)
    return policy in (getattr(os, "SCHED_FIFO", -1), getattr(os, "SCHED_RR", -1))


#: nice value of the NC's threads other than the cycle thread (zenoh's, the I/O thread) and of its frame
#: publisher when realtime is not "off": they receive the PLCTONC frames the watchdog judges and send
#: frames and replies, and at nice 0 on a loaded machine they waited behind every other process. (zenoh's
#: threads are not SCHED_FIFO: they move the data of every client; the I/O thread is, see transport.IoThread.)
IO_NICE = -10
#: nice value of the NC's I/O thread when it cannot run SCHED_FIFO (transport.IoThread: rt_priority) (below
#: IO_NICE: ahead of zenoh's threads). Whatever it does holding
#: the GIL, taken off the CPU meanwhile, keeps the cycle thread from the GIL: when it still put the frames
#: (~100-200 us each for 16 clients, now the publisher child's job), for milliseconds on a loaded 2-core
#: machine (bench/many_clients.py).
IO_THREAD_NICE = -15


def raise_io_priority(mode: str, nice: int = IO_NICE) -> str:
    """Give the calling thread, and every thread it creates afterwards (zenoh's), ``nice`` (Linux: nice is
    per thread and inherited). Call before opening zenoh. Returns what was done (for the log).
    """
    if mode == "off" or not hasattr(os, "setpriority"):
        return "normal priority"
    try:
        os.setpriority(os.PRIO_PROCESS, 0, nice)  # pid 0: the calling thread
    except OSError as exc:
        return f"normal priority (nice {nice} not permitted: {exc.strerror or exc})"
    return f"nice {nice}"


def _change_other_threads(keep: set[int], change: Callable[[int], bool]) -> list[int]:
    """``change(tid)`` for every thread of this process not in ``keep`` (native thread ids); the ids for which it
    returned True (Linux; elsewhere nothing). A thread that ended meanwhile, or a change not permitted, is skipped."""
    out: list[int] = []
    try:
        tids = [int(t) for t in os.listdir("/proc/self/task")]
    except (OSError, ValueError):
        return out
    for tid in tids:
        if tid in keep:
            continue
        try:
            if change(tid):
                out.append(tid)
        except OSError:
            pass
    return out


def demote_other_threads(keep: set[int]) -> list[int]:
    """Set every SCHED_FIFO/SCHED_RR thread of this process not in ``keep`` (native thread ids) back to
    SCHED_OTHER; the ids it demoted (Linux; elsewhere nothing).

    A thread inherits its creator's policy: zenoh creates some threads lazily (e.g. its SHM watchdog
    threads on first use), and one created from a SCHED_FIFO thread would run at real-time priority.
    """
    def demote(tid: int) -> bool:
        if not is_realtime(tid):
            return False
        os.sched_setscheduler(tid, os.SCHED_OTHER, os.sched_param(0))
        return True
    return _change_other_threads(keep, demote)


def raise_other_threads(keep: set[int], nice: int) -> list[int]:
    """Give every normal-policy thread of this process not in ``keep`` (native thread ids) at a nice value above
    ``nice`` that value; the ids it changed (Linux; elsewhere nothing).

    :func:`raise_io_priority` gives it to the threads created from the thread that called it; zenoh creates its
    runtimes' threads (tx, rx, app, net) lazily, at their first use, and one created from a SCHED_FIFO thread runs
    at nice 0 (SCHED_RESET_ON_FORK resets a negative nice too): seen in a hot-standby pair, its zenoh threads at
    nice 0 behind the clients' processes while the logs they carry were late.
    """
    def give(tid: int) -> bool:
        if is_realtime(tid) or os.getpriority(os.PRIO_PROCESS, tid) <= nice:
            return False
        os.setpriority(os.PRIO_PROCESS, tid, nice)
        return True
    return _change_other_threads(keep, give)


def set_thread_name(name: str) -> None:
    """Name the calling thread for the kernel (/proc/<pid>/task/<tid>/comm, top -H, perf; at most 15 bytes):
    Python 3.11 names only its own Thread objects, so every Python thread of the NC showed the process's name."""
    try:
        import ctypes
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(15, name.encode()[:15], 0, 0, 0)  # PR_SET_NAME; the calling thread only
    except Exception:  # not Linux or no prctl: unnamed
        pass


def _reduce_timer_slack() -> None:
    """Ask for 1 us timer slack (default 50 us) so normal-priority sleeps end closer to the deadline."""
    try:
        import ctypes
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(29, 1000, 0, 0, 0)  # PR_SET_TIMERSLACK, in ns; affects the calling thread only
    except Exception:  # not Linux or no prctl: keep the default slack
        pass


#: Bins of the work / lateness histograms behind CycleStats.percentiles [us]: 1 us wide, the last one
#: holds everything from HIST_BINS - 1 us on.
HIST_BINS = 10_000


@dataclass
class CycleStats:
    """Counters and the timing ring buffers of a :class:`CycleLoop`.

    ``work_us`` and ``lateness_us`` hold the last :data:`RING` cycles [us]; :meth:`percentiles`
    reads 1-us histograms of the same cycles, kept up to date by :meth:`record` (safe from another
    thread, and cheap: computed from the rings with np.percentile, the stats held the GIL for ~0.3 ms
    ten times a second, and a cycle due meanwhile waited).
    """

    cycles: int = 0
    missed_cycles: int = 0
    overruns: int = 0
    spin_ns: int = SPIN_NS
    timing: str = "not started"
    timing_detail: str = ""

    def __post_init__(self) -> None:
        self.work_us = np.zeros(RING, dtype=np.float64)
        self.lateness_us = np.zeros(RING, dtype=np.float64)
        self._hist_w = np.zeros(HIST_BINS, dtype=np.int64)
        self._hist_l = np.zeros(HIST_BINS, dtype=np.int64)
        self._bin_w = [0] * RING
        self._bin_l = [0] * RING

    def record(self, work_ns: int, lateness_ns: int) -> None:
        k = self.cycles % RING
        bw = min(HIST_BINS - 1, max(0, work_ns // 1000))
        bl = min(HIST_BINS - 1, max(0, lateness_ns // 1000))
        hw, hl = self._hist_w, self._hist_l
        if self.cycles >= RING:  # the cycle leaving the window
            hw[self._bin_w[k]] -= 1
            hl[self._bin_l[k]] -= 1
        hw[bw] += 1
        hl[bl] += 1
        self._bin_w[k] = bw
        self._bin_l[k] = bl
        self.work_us[k] = work_ns * 1e-3
        self.lateness_us[k] = lateness_ns * 1e-3
        self.cycles += 1

    def percentiles(self) -> dict[str, float]:
        """p50/p99/max of work and start lateness over the ring [us] (zeros before the first cycle).

        p50 and p99 come from the 1-us histograms (to 1 us: the lower edge of the bin holding that rank),
        max from the ring itself."""
        n = min(self.cycles, RING)
        if n == 0:
            return {k: 0.0 for k in ("work_us_p50", "work_us_p99", "work_us_max",
                                     "lateness_us_p50", "lateness_us_p99", "lateness_us_max")}
        out: dict[str, float] = {}
        for name, hist, ring in (("work", self._hist_w, self.work_us), ("lateness", self._hist_l, self.lateness_us)):
            c = np.cumsum(hist)
            total = int(c[-1])
            for q, key in ((0.50, "p50"), (0.99, "p99")):
                b = int(np.searchsorted(c, max(1, int(np.ceil(q * total))), "left"))
                out[f"{name}_us_{key}"] = float(b)
            out[f"{name}_us_max"] = round(float(ring[:n].max()), 1)
        return out


class CycleLoop:
    """Calls ``work(deadline_ns)`` once per period until stopped.

    Args:
        period_s: the cycle time [s].
        work: the cycle body; receives the deadline (scheduled start) of this cycle [ns,
            CLOCK_MONOTONIC]. Exceptions propagate and end the loop (the caller decides).
        idle: optional, called as ``idle(deadline_ns, after_work)`` between sleep slices while waiting
            for the next deadline ``deadline_ns`` (after_work: the call right after the cycle's work);
            non-blocking, and it must leave the cycle its deadline: whatever it does past
            ``deadline_ns - spin_ns`` makes the next cycle late. Its time is not counted as cycle work.
        wake: optional (with ``idle``): an event that ends the current slice early when set (cleared,
            then ``idle()`` runs).
        realtime: ``"auto"``, ``"fifo"`` or ``"off"`` (see :func:`set_realtime`).
        rt_priority: SCHED_FIFO priority.
        cpus: CPUs the cycle thread may run on (``[nc] cpu_affinity``; None: wherever the process may).
            Isolation, not speed: on a loaded machine the cycle's work takes 3-4 times its quiet cost
            because other processes evict its caches while it sleeps; on a CPU that nothing else uses
            (``isolcpus``, a cpuset, or every other process pinned elsewhere) it keeps them.

    Attributes:
        relaxed: no spin before the deadlines, a sleep up to them (set by the owner at any time; a hot-standby NC
            sets it while it is a standby: its cycle drives nothing, and the spin, up to SPIN_NS of every period
            on a loaded machine, cost it a fifth of a core).
    """

    def __init__(self, period_s: float, work: Callable[[int], None], realtime: str = "auto",
                 rt_priority: int = 49, idle: Callable[[int, bool], None] | None = None,
                 wake: threading.Event | None = None, cpus: frozenset[int] | None = None) -> None:
        self.period_ns = int(round(period_s * 1e9))
        self.cpus = cpus
        self.work = work
        self.idle = idle
        self.wake = wake
        self.realtime = realtime
        self.rt_priority = rt_priority
        self.stats = CycleStats()
        self.relaxed = False
        self.stop_event = threading.Event()
        self.started = threading.Event()
        self.error: BaseException | None = None
        self._thread: threading.Thread | None = None

    # ---- thread control ---------------------------------------------------------------------
    def start(self, name: str = "nc-cycle", timeout: float = 10.0) -> None:
        """Start the cycle thread; returns once its scheduling is set.

        Raises:
            RealtimeError: SCHED_FIFO required but refused.
            AffinityError: ``cpus`` cannot be set.
            RuntimeError: the thread did not start in time.
        """
        self._thread = threading.Thread(target=self._main, name=name, daemon=True)
        self._thread.start()
        if not self.started.wait(timeout):
            raise RuntimeError("cycle thread did not start")
        if self.error is not None:
            raise self.error

    def stop(self, timeout: float = 5.0) -> None:
        """Ask the loop to end and wait for it (the current cycle completes)."""
        self.stop_event.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout)

    @property
    def alive(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def _main(self) -> None:
        set_thread_name(self._thread.name if self._thread is not None else "nc-cycle")
        try:
            self.stats.timing, self.stats.timing_detail = set_realtime(self.realtime, self.rt_priority)
        except RealtimeError as exc:
            self.error = exc
            self.started.set()
            return
        if self.stats.timing != "SCHED_FIFO":
            _reduce_timer_slack()
        if self.cpus:
            try:
                os.sched_setaffinity(0, self.cpus)  # pid 0: this thread only
                self.stats.timing_detail += f", on CPU {','.join(map(str, sorted(self.cpus)))}"
            except (OSError, AttributeError) as exc:
                self.error = AffinityError(f"cpu_affinity {sorted(self.cpus)}: cannot move the cycle thread there: {exc}")
                self.started.set()
                return
        self.started.set()
        try:
            self.run()
        except BaseException as exc:  # reported by the owner (it watches .alive / .error)
            self.error = exc
            log.exception("cycle loop ended by an exception")

    # ---- the loop ---------------------------------------------------------------------------
    def run(self) -> None:
        """Run in the calling thread until :attr:`stop_event` is set."""
        period = self.period_ns
        stats = self.stats
        stop = self.stop_event
        work = self.work
        clock = time.monotonic_ns
        sleep = time.sleep
        yield_ = os.sched_yield if hasattr(os, "sched_yield") else (lambda: sleep(0))
        idle = self.idle
        wake = self.wake
        spin = SPIN_NS
        errors: list[int] = []  # wake-up errors of the last SPIN_WINDOW sleeps [ns] (a ring)
        n_err = n_adapted = 0  # wake-ups recorded; and when the spin was last adapted
        woke: bool | None  # a wake event's wait(); None: a plain sleep (never "woken")
        deadline = clock() + period
        while not stop.is_set():
            # Wait: sleep most of it (in slices with idle() between them), spin the end
            # (yielding the GIL while there is time); relaxed: sleep all of it.
            spun = 0 if self.relaxed else spin
            remaining = deadline - clock()
            if idle is not None:
                if IDLE_AFTER_WORK and remaining > spun + IDLE_SLICE_NS // 2:
                    idle(deadline - spun, True)  # what arrived during the work: answered now, not a slice later
                    remaining = deadline - clock()
                while remaining > spun + IDLE_SLICE_NS // 2:
                    t = min(IDLE_SLICE_NS, remaining - spun)
                    target = deadline - remaining + t
                    if wake is not None:
                        woke = wake.wait(t * 1e-9)
                        wake.clear()  # (before idle(): whatever arrives later sets it again)
                    else:
                        woke = sleep(t * 1e-9)
                    if not woke:  # timed out: how late it returned counts (woken by a request: not)
                        n_err = _record(errors, n_err, clock() - target)
                    idle(deadline - spun, False)
                    remaining = deadline - clock()
            if remaining > spun:
                target = deadline - spun
                sleep(max(0, target - clock()) * 1e-9)
                n_err = _record(errors, n_err, clock() - target)
            if n_err - n_adapted >= SPIN_EVERY:
                n_adapted = n_err
                spin = stats.spin_ns = adapted_spin(errors)
            now = clock()
            while now < deadline:
                if deadline - now > SPIN_YIELD_NS:
                    yield_()
                now = clock()
            late = now - deadline
            if late >= period:
                # Deadlines passed entirely: skip to the newest due one, never replay.
                skipped = late // period
                stats.missed_cycles += skipped
                deadline += skipped * period
                late -= skipped * period
            work(deadline)
            end = clock()
            if end > deadline + period:
                stats.overruns += 1
            stats.record(end - now, late)
            deadline += period


def configure_interpreter() -> None:
    """Process-wide settings that help a 1 kHz loop (called once before the loop starts)."""
    sys.setswitchinterval(SWITCH_INTERVAL)
