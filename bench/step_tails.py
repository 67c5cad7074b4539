"""The tails of ``core.step()`` in-process: thread CPU time per cycle, p50 / p99 / max, by cycle phase.

No server, no zenoh: the core of bench/nc_cycle.py under its quiet load (every axis under
MoveVelocity) and its coupled load (N // 3 geared pairs, the rest moving), stepped ``--n`` times;
each step timed with the thread's CPU clock (``time.thread_time_ns``: what another process takes
from this one does not count) and, beside it, the wall clock. Shown per point: p50, p99, max, the
ratio p99 / p50 (what the lookahead refill adds to the tail), the median step per phase
``core.cycle % 4`` (a heavy phase every 4th cycle shows as one high column) and the median and p99
time per pipeline stage (the core's own stage timers: wall clock).

    PYTHONPATH=$PWD .venv/bin/python bench/step_tails.py [--axes 8 64 256 1024] [--coupled 384]
                                                          [--n 6000] [--rounds 3] [--groups G] [--lookahead L]

``--groups`` / ``--lookahead`` override the profile stage's defaults (a new ProfileStage with that
lookahead; set_groups), to compare refill patterns. Rounds are interleaved over the points; the
figures are the median over the rounds of each round's percentile.
"""
from __future__ import annotations

import argparse
import gc
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

BENCH = Path(__file__).resolve().parent
sys.path.insert(0, str(BENCH))

import nc_cycle  # noqa: E402  (the axes' parameters and the load's requests)


def build(n: int, coupled: bool, lookahead: int | None, groups: int | None) -> Any:
    from nc_schema import parse_request
    from nc_server.core.stages import ProfileStage
    _, core = nc_cycle._make_core(n)
    if lookahead is not None:
        core.profile = ProfileStage(core, lookahead, groups)
    elif groups is not None:
        core.profile.set_groups(groups)
    ids = [int(x) for x in core.axis_ids]
    pairs = n // 3 if coupled else 0
    for k in range(pairs):
        num, den = nc_cycle.COUPLED_RATIOS[k % len(nc_cycle.COUPLED_RATIOS)]
        r = core.execute(parse_request(nc_cycle._gear_in_request(ids[2 * k], num, den, 10_000 + k)), ids[2 * k + 1])
        assert not r.get("error"), r
    for i in range(n):
        if i < 2 * pairs and i % 2:
            continue
        r = core.execute(parse_request(nc_cycle._velocity_request(i, 1 + i)), ids[i])
        assert not r.get("error"), r
    for _ in range(300):  # past the jerk-limited start: the steady cycle
        core.step()
    return core


def measure(core: Any, count: int) -> dict[str, Any]:
    cpu = np.empty(count, dtype=np.int64)
    wall = np.empty(count, dtype=np.int64)
    phase = np.empty(count, dtype=np.int64)
    stages = np.empty((count, len(core.pipeline)), dtype=np.int64)
    tt, pc = time.thread_time_ns, time.perf_counter_ns
    step = core.step
    last = core.stage_last_ns
    gc.collect()
    gc.disable()
    try:
        for k in range(count):
            phase[k] = core.cycle + 1
            w0 = pc()
            t0 = tt()
            step()
            t1 = tt()
            wall[k] = pc() - w0
            cpu[k] = t1 - t0
            stages[k] = last
    finally:
        gc.enable()
    v = np.abs(core.axes.set_velo)
    assert np.count_nonzero(v) == len(v), "not every axis moves"
    c = cpu / 1e3
    out = {"p50": float(np.percentile(c, 50)), "p90": float(np.percentile(c, 90)),
           "p99": float(np.percentile(c, 99)), "max": float(c.max()),
           "wall_p99": float(np.percentile(wall / 1e3, 99)),
           "phase": [float(np.median(c[phase % 4 == m])) for m in range(4)],
           "stages": [float(np.median(stages[:, j])) / 1e3 for j in range(stages.shape[1])],
           "stages99": [float(np.percentile(stages[:, j], 99)) / 1e3 for j in range(stages.shape[1])]}
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--axes", type=int, nargs="*", default=[8, 64, 256, 1024])
    ap.add_argument("--coupled", type=int, nargs="*", default=[384])
    ap.add_argument("--n", type=int, default=6000)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--groups", type=int)
    ap.add_argument("--lookahead", type=int)
    args = ap.parse_args()
    points = [("quiet", n) for n in args.axes] + [("coupled", n) for n in args.coupled]
    cores = {p: build(p[1], p[0] == "coupled", args.lookahead, args.groups) for p in points}
    res: dict[tuple[str, int], list[dict[str, Any]]] = {p: [] for p in points}
    for _ in range(args.rounds):
        for p in points:
            res[p].append(measure(cores[p], args.n))
    names = [s.name for s in next(iter(cores.values())).pipeline]
    print(f"load {tuple(round(x, 2) for x in __import__('os').getloadavg())}; n={args.n} x {args.rounds} rounds; "
          f"thread CPU time of core.step [us], median over rounds")
    print(f"{'load':<8} {'axes':>5} {'L/G':>6} {'p50':>7} {'p90':>7} {'p99':>7} {'max':>7} {'p99/p50':>7} "
          f"{'wall99':>7} | phase medians | stage medians ({', '.join(names)}) | stage p99s (wall clock)")
    for p in points:
        rs = res[p]
        med = {k: float(np.median([r[k] for r in rs])) for k in ("p50", "p90", "p99", "max", "wall_p99")}
        ph = np.median([r["phase"] for r in rs], axis=0)
        st = np.median([r["stages"] for r in rs], axis=0)
        st99 = np.median([r["stages99"] for r in rs], axis=0)
        prof = cores[p].profile
        print(f"{p[0]:<8} {p[1]:>5} {f'{prof.lookahead}/{prof.groups}':>6} {med['p50']:>7.1f} {med['p90']:>7.1f} "
              f"{med['p99']:>7.1f} {med['max']:>7.1f} {med['p99'] / med['p50']:>7.2f} {med['wall_p99']:>7.1f} | "
              + " ".join(f"{x:5.1f}" for x in ph) + " | " + " ".join(f"{x:.1f}" for x in st)
              + " | p99 " + " ".join(f"{x:.1f}" for x in st99))


if __name__ == "__main__":
    main()
