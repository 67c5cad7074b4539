"""What "acknowledged means kept" costs: WriteParameter round trips to an NC with and without ``--retain``.

Two ``nc-server`` processes with the same configuration (``RETAIN_CONFIG``: 2 axes), one with a retain
file (in a temporary directory, on the file system of ``--dir``), measured in interleaved blocks so
machine noise hits both alike, from a client-mode session in this process:

  * sequential: one WriteParameter at a time (AxisVeloMax of axis 1, alternating values): with
    ``--retain`` its reply waits until the retain file holds the value (written, fsync'ed, renamed,
    directory fsync'ed by the retain thread; then the I/O thread sends it);
  * concurrent: ``--writers`` threads writing at once (one parameter each): writes in flight while the
    file is written share the next write (group commit); acknowledged writes per second.

Also printed: the cost of one :func:`nc_server.server.retain.write_atomic` of a retain-file-sized
payload in this process (the disk's share), and the NCs' missed cycles / overruns (the cycle never waits
on the disk: they should not differ).

    .venv/bin/python bench/retain_ack.py [--n 600] [--writers 4] [--dir DIR]
"""
from __future__ import annotations

import argparse
import contextlib
import sys
import tempfile
import threading
import time
from pathlib import Path

import msgpack
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from bench.common import Busy, use_this_tree, verdict  # noqa: E402

use_this_tree()  # this checkout and its test helpers (znc_testing), also for the processes started
from bench.command_rtt import fmt, rtt_us  # noqa: E402
from nc_server.server.retain import write_atomic  # noqa: E402
from znc_testing import RETAIN_CONFIG, NcTestClient, start_nc_server  # noqa: E402

KEY = "nc/nc1/axis/{axis}/cmd/eng/bench-retain"
VELO_MAX, ACC = 1003, 1004


def no_error(b: bytes) -> None:
    r = msgpack.unpackb(b, strict_map_key=False)
    if r["error"]:
        raise RuntimeError(r)


def writes(ids: "iter[int]", n: int, number: int = VELO_MAX) -> list[bytes]:
    return [msgpack.packb({"id": next(ids), "client": "bench-retain", "cmd": "WriteParameter",
                           "ParameterNumber": number, "Value": 500.0 + (k % 2)}) for k in range(n)]


def concurrent(cl: NcTestClient, ids: "iter[int]", writers: int, seconds: float) -> float:
    """Acknowledged writes per second with ``writers`` threads writing at once (a parameter each)."""
    params = [(axis, number) for number in (VELO_MAX, ACC) for axis in (1, 2)][:writers]
    lock = threading.Lock()
    done = [0]
    end = time.monotonic() + seconds

    def run(axis: int, number: int) -> None:
        while time.monotonic() < end:
            with lock:
                batch = writes(ids, 20, number)
            rtt_us(cl.session, KEY.format(axis=axis), batch, no_error)
            with lock:
                done[0] += len(batch)

    threads = [threading.Thread(target=run, args=p) for p in params]
    t0 = time.monotonic()
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    return done[0] / (time.monotonic() - t0)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--n", type=int, default=600, help="sequential round trips per NC")
    ap.add_argument("--blocks", type=int, default=6)
    ap.add_argument("--writers", type=int, default=4, help="concurrent writers (1-4)")
    ap.add_argument("--dir", default=None,
                    help="where the retain file goes (default: the system's temporary directory)")
    args = ap.parse_args()
    n_block = max(1, args.n // args.blocks)
    tmp = Path(tempfile.mkdtemp(prefix="znc-retain-ack-", dir=args.dir))

    # the disk alone: write_atomic of a payload the size of a 2-axis retain file
    payload = b"x" * 400
    costs = []
    for _ in range(50):
        t0 = time.perf_counter_ns()
        write_atomic(tmp / "probe.retain", payload)
        costs.append((time.perf_counter_ns() - t0) / 1000.0)

    ids = iter(range(10**6, 10**9))
    res: dict[str, list[float]] = {"without": [], "with": []}
    rate: dict[str, float] = {}
    stats: dict[str, dict] = {}
    with contextlib.ExitStack() as stack:
        clients: dict[str, NcTestClient] = {}
        for kind, extra in (("without", ()), ("with", ("--retain", str(tmp / "nc1.retain")))):
            nc = start_nc_server(tmp / kind, RETAIN_CONFIG, extra)
            stack.callback(nc.stop)
            cl = NcTestClient(nc.port, "bench-retain")
            stack.callback(cl.close)
            cl.watch("nc/nc1/stats")
            clients[kind] = cl
            rtt_us(cl.session, KEY.format(axis=1), writes(ids, 50), no_error)  # warm-up
        busy = Busy()
        for _ in range(args.blocks):
            for kind, cl in clients.items():
                res[kind] += rtt_us(cl.session, KEY.format(axis=1), writes(ids, n_block), no_error)
        busy.stop()
        for kind, cl in clients.items():
            rate[kind] = concurrent(cl, ids, max(1, min(4, args.writers)), 3.0)
            stats[kind] = cl.stats() or {}

    a = {k: np.array(v) for k, v in res.items()}
    print(f"write_atomic (temp file, fsync, rename, directory fsync) on {tmp}: "
          f"p50 {np.percentile(costs, 50):.0f}  p99 {np.percentile(costs, 99):.0f} us")
    print("WriteParameter round trip, one at a time:")
    for k, v in a.items():
        print(fmt(f"{k} --retain", v))
    p50 = {k: float(np.percentile(v, 50)) for k, v in a.items()}
    p99 = {k: float(np.percentile(v, 99)) for k, v in a.items()}
    print(f"with / without --retain: p50 {p50['with'] / p50['without']:.1f}x (+{p50['with'] - p50['without']:.0f} us), "
          f"p99 {p99['with'] / p99['without']:.1f}x")
    print(f"{args.writers} concurrent writers: {rate['without']:.0f} acknowledged writes/s without --retain, "
          f"{rate['with']:.0f} with ({rate['with'] / rate['without']:.2f}x)")
    for k, s in stats.items():
        print(f"NC {k} --retain: missed cycles {s.get('missed_cycles')}, overruns {s.get('overruns')}, "
              f"work p99 {s.get('work_us_p99')} us")
    print(f"the machine during the sequential round trips: {busy.text()}")
    verdict("retain_ack", [], busy.text())
    return 0


if __name__ == "__main__":
    sys.exit(main())
