"""Command round trip to a real nc-server, next to a raw zenoh query round trip, in one run.

Same topology for both: a client-mode session in this process -> a router process on
127.0.0.1 (the raw one is a trivial Python queryable replying at once; the NC is ``nc-server``
with its default 4 axes). Measured request -> reply with ``session.get`` one at a time,
in interleaved blocks so machine noise hits both alike:

  * raw:           get on ``bench/raw``, reply b"ok" from a callback;
  * ReadParameter: AxisVeloMax of axis 1 (no motion);
  * MoveAbsolute:  re-targets of axis 1 (claimed, enabled by PLCTONC frames every 10 ms),
                   alternating 500 / 600 mm (both ahead of the axis for the whole run), each one
                   accepted and aborting the previous (targets behind a braking axis are refused
                   at times with 0x4289: it would turn back on its way).

Goal (not a test): NC p50 within 1.5 x raw p50 + one NC cycle. The NC answers in the cycle
after the request arrives, so about half a cycle of waiting is expected on top of the raw trip.
A same-run noise floor (bench/noise_floor.py: a fixed numpy workload in the NC cycle loop, before
and after the round trips) says how loaded the machine was.

    .venv/bin/python bench/command_rtt.py [--n 1500]
"""
from __future__ import annotations

import argparse
import contextlib
import sys
import tempfile
import time
from pathlib import Path

import msgpack
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))  # the test helpers (znc_testing)
from bench.noise_floor import floor_line  # noqa: E402
from bench.raw_zenoh import RAW_KEY, raw_queryable  # noqa: E402
from znc_testing import (  # noqa: E402
    BIT_CONTROL_LOOP_CLOSED, NcTestClient, free_port, start_nc_server, wait_until,
)


CYCLE_US = 1000.0


def rtt_us(session, key: str, payloads: list[bytes], check) -> list[float]:  # type: ignore[no-untyped-def]
    out = []
    for p in payloads:
        t0 = time.perf_counter_ns()
        replies = list(session.get(key, payload=p, timeout=5.0))
        t1 = time.perf_counter_ns()
        if not replies or replies[0].ok is None:
            raise RuntimeError(f"no reply from {key}")
        check(replies[0].ok.payload.to_bytes())
        out.append((t1 - t0) / 1000.0)
    return out


def fmt(name: str, xs: np.ndarray) -> str:
    p50, p99 = np.percentile(xs, (50, 99))
    return f"{name:>14}: p50 {p50:7.0f}  p99 {p99:7.0f}  max {xs.max():7.0f} us  (n={len(xs)})"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--n", type=int, default=1500, help="round trips per kind")
    ap.add_argument("--blocks", type=int, default=10)
    args = ap.parse_args()
    n_block = max(1, args.n // args.blocks)
    deadline = time.monotonic() + 55  # the whole run stays under a minute
    floor0, f0 = floor_line()

    tmp = Path(tempfile.mkdtemp(prefix="znc-rtt-"))
    nc = None
    clients: list[NcTestClient] = []
    with contextlib.ExitStack() as stack:
        raw_port = stack.enter_context(raw_queryable(free_port()))
        stack.callback(lambda: [c.close() for c in clients])
        nc = start_nc_server(tmp)
        stack.callback(nc.stop)
        print(nc.ready_line())
        raw_cl = NcTestClient(raw_port)
        cl = NcTestClient(nc.port, "bench-rtt")
        clients += [raw_cl, cl]
        cl.watch("nc/nc1/stats")
        cl.claim(1)
        cl.feed_plctonc([1])
        wait_until(lambda: (s := cl.nctoplc(1)) is not None and int(s["StateDWord"]) & BIT_CONTROL_LOOP_CLOSED,
                   30, "axis 1 enabled")

        ids = iter(range(10**6, 10**9))  # request ids are unique per client: stay clear of the claim's

        def ok(b: bytes) -> None:
            if b != b"ok":
                raise RuntimeError(b)

        def no_error(b: bytes) -> None:
            r = msgpack.unpackb(b, strict_map_key=False)
            if r["error"]:
                raise RuntimeError(r)

        def read_param() -> list[bytes]:
            return [msgpack.packb({"id": next(ids), "client": "bench-rtt", "cmd": "ReadParameter",
                                   "ParameterNumber": 1003}) for _ in range(n_block)]

        def moves() -> list[bytes]:
            return [msgpack.packb({"id": next(ids), "client": "bench-rtt", "cmd": "MoveAbsolute",
                                   "Position": 500.0 + 100.0 * (k % 2), "Velocity": 100.0}) for k in range(n_block)]

        # warm-up (first queries, publisher and route setup)
        rtt_us(raw_cl.session, RAW_KEY, [b"x"] * 100, ok)
        rtt_us(cl.session, "nc/nc1/axis/1/cmd/read/bench-rtt", read_param()[:100], no_error)
        res: dict[str, list[float]] = {"raw": [], "ReadParameter": [], "MoveAbsolute": []}
        for _ in range(args.blocks):
            if time.monotonic() > deadline - 5:
                print("(stopping early to stay within the time bound)")
                break
            res["raw"] += rtt_us(raw_cl.session, RAW_KEY, [b"x"] * n_block, ok)
            res["ReadParameter"] += rtt_us(cl.session, "nc/nc1/axis/1/cmd/read/bench-rtt", read_param(), no_error)
            res["MoveAbsolute"] += rtt_us(cl.session, "nc/nc1/axis/1/cmd/op/bench-rtt", moves(), no_error)
        stats = cl.stats() or {}
        floor1, f1 = floor_line()  # the NC still runs: the machine as the round trips saw it

    a = {k: np.array(v) for k, v in res.items()}
    print()
    print("command round trip (client -> router process -> reply), one at a time:")
    for k, v in a.items():
        print(fmt(k, v))
    raw50 = float(np.percentile(a["raw"], 50))
    goal = 1.5 * raw50 + CYCLE_US
    print()
    for k in ("ReadParameter", "MoveAbsolute"):
        p50 = float(np.percentile(a[k], 50))
        print(f"{k:>14}: p50 ratio to raw {p50 / raw50:4.1f}x; goal p50 <= 1.5 x raw + 1 cycle = {goal:.0f} us "
              f"-> {'met' if p50 <= goal else 'NOT met'}")
    if stats:
        print(f"NC during the run: timing {stats.get('timing')}, work p50/p99 {stats.get('work_us_p50')}/"
              f"{stats.get('work_us_p99')} us, missed {stats.get('missed_cycles')}, overruns {stats.get('overruns')}")
    print(f"before: {floor0}")
    print(f"after:  {floor1}")
    fl50 = (f0["p50_us"] + f1["p50_us"]) / 2
    print(f"in noise-floor units (p50 / floor p50 {fl50:.0f} us, comparable between runs): "
          + ", ".join(f"{k} {float(np.percentile(v, 50)) / fl50:5.1f}" for k, v in a.items()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
