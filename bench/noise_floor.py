"""The same-run noise floor: the NC cycle loop running a fixed synthetic numpy workload.

A shared 2-core machine gives different figures from one minute to the next. The floor is what
the machine itself gives *at that moment* to a cycle of known cost: the real
``nc_server.server.cycle.CycleLoop`` (same timing code, same scheduling: SCHED_FIFO if
permitted, sleep + spin, ``configure_interpreter()``, frozen gc) calling :class:`Workload`, a
fixed sequence of :data:`N_CALLS` numpy calls on 64-element arrays, at 1 ms. Measured in the
same run as the figure it normalizes (interleaved with the NC runs in bench/nc_cycle.py), a
figure divided by the floor's is comparable between runs far better than the figure itself.

The workload is fixed by its number of calls (numpy costs about 1-3 us per call on small arrays
here, the unit docs/ARCHITECTURE.md reasons in); :func:`calibrate` measures its quiet cost once
(best of a tight loop, no cycle loop), so the floor's p99 over that cost says how much the machine
inflates a cycle right now.
"""
from __future__ import annotations

import gc
import sys
import time
from typing import Any

import numpy as np

#: numpy calls per workload run (25 rounds of 4 calls).
N_CALLS = 100
ARRAY_LEN = 64


class Workload:
    """A fixed synthetic cycle body: :data:`N_CALLS` numpy calls on small preallocated arrays."""

    def __init__(self) -> None:
        self.a = np.linspace(0.0, 1.0, ARRAY_LEN)
        self.b = np.empty(ARRAY_LEN)
        self.acc = 0.0

    def __call__(self, deadline_ns: int = 0) -> None:
        a, b = self.a, self.b
        s = 0.0
        for _ in range(N_CALLS // 4):
            np.multiply(a, 1.0001, out=b)
            np.add(b, a, out=b)
            np.maximum(b, 0.5, out=b)
            s += float(b.sum())
        self.acc = s


def calibrate(reps: int = 300) -> dict[str, float]:
    """Quiet cost of one :class:`Workload` run [us]: best and median of a tight loop."""
    w = Workload()
    for _ in range(20):
        w()
    ts = np.empty(reps)
    for k in range(reps):
        t0 = time.perf_counter_ns()
        w()
        ts[k] = (time.perf_counter_ns() - t0) / 1000.0
    return {"calls": N_CALLS, "min_us": float(ts.min()), "p50_us": float(np.percentile(ts, 50))}


def run_floor(seconds: float, warmup: float = 0.3, realtime: str = "auto", period_s: float = 0.001,
              cpus: frozenset[int] | None = None) -> dict[str, Any]:
    """Run the workload in the NC cycle loop for ``seconds`` (after ``warmup``); in this process
    (with ``cpus``: the loop's thread on those CPUs, as ``[nc] cpu_affinity``).

    Uses ``nc_server.server.cycle`` as imported by the caller's ``sys.path`` (the tree under test).

    Returns:
        {"timing", "cycles", "missed", "overruns", "work": [us per cycle], "late": [us]}
    """
    from nc_server.server.cycle import RING, CycleLoop, configure_interpreter

    w = Workload()
    switch = sys.getswitchinterval()
    configure_interpreter()
    loop = CycleLoop(period_s, lambda deadline_ns: w(), realtime, **({"cpus": cpus} if cpus else {}))
    gc.collect()
    gc.freeze()  # as NcServer.start does
    try:
        loop.start(name="noise-floor")
        time.sleep(warmup)
        st = loop.stats
        c0, m0, o0 = st.cycles, st.missed_cycles, st.overruns
        time.sleep(seconds)
        c1, m1, o1 = st.cycles, st.missed_cycles, st.overruns
    finally:
        loop.stop()
        gc.unfreeze()
        sys.setswitchinterval(switch)  # leave the caller's process as it was (the latency benches)
    c0 = max(c0, c1 - RING)
    idx = np.arange(c0, c1) % RING
    return {"timing": st.timing, "cycles": c1 - c0, "missed": m1 - m0, "overruns": o1 - o0,
            "work": st.work_us[idx].copy(), "late": st.lateness_us[idx].copy()}


def floor_line(seconds: float = 0.5, realtime: str = "auto") -> tuple[str, dict[str, float]]:
    """Measure the floor now (calibration + a short loop run); a printable line and the figures.

    For the latency benchmarks: their own same-run reference is the raw zenoh round trip; this line
    says how loaded the machine was while they ran.
    """
    cal = calibrate()
    r = run_floor(seconds, realtime=realtime)
    p50, p99 = (float(x) for x in np.percentile(r["work"], (50, 99)))
    figs = {"p50_us": p50, "p99_us": p99, "quiet_us": cal["min_us"], "factor_p50": p50 / cal["min_us"],
            "factor_p99": p99 / cal["min_us"]}
    line = (f"noise floor ({N_CALLS} numpy calls in the NC cycle loop, {r['timing']}, {r['cycles']} cycles): "
            f"p50 {p50:.0f} us, p99 {p99:.0f} us; quiet cost {cal['min_us']:.0f} us -> machine factor "
            f"p50 {figs['factor_p50']:.2f}x, p99 {figs['factor_p99']:.2f}x")
    return line, figs
