"""The pure NC core's cost, this tree vs a baseline commit: ``core.step()`` with N moving axes and
``core.execute()`` of a ReadParameter and of a MoveAbsolute re-target, no server, no zenoh.

Two worker processes (this tree, the baseline's worktree imported through PYTHONPATH as
bench/nc_cycle.py does) are driven in turn, point by point and round by round (new, old, old, new,
...), so a machine loaded by other work shifts both alike. Each point times ``--n`` calls one by
one (perf_counter_ns around each); per engine and point the table shows the median over the rounds
of the per-round medians and the minimum of the per-round p10, and the ratios new/old.

    .venv/bin/python bench/core_step.py [--baseline 75a412e] [--axes 8 64 256] [--n 5000] [--rounds 6]

Loads: ``step``: every axis under MoveVelocity (the quiet load of nc_cycle.py); ``read``:
execute(ReadParameter 1, AxisId) round robin, a step between two; ``retarget``: every axis on a long
MoveAbsolute, execute(MoveAbsolute Aborting to another target ahead) round robin, a step between two
(the execute is timed, and the step under that load as ``step-stress``).
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

BENCH = Path(__file__).resolve().parent
REPO = BENCH.parent
sys.path.insert(0, str(BENCH))

import nc_cycle  # noqa: E402  (the baseline worktree and its PYTHONPATH, the axes' parameters)

POINTS = ("step", "read", "retarget", "step-stress")


# -- worker side ----------------------------------------------------------------------------------
def _moving_core(n: int, move: str) -> Any:
    from nc_schema import pack, parse_request
    _, core = nc_cycle._make_core(n)
    for i in range(n):
        if move == "velocity":
            req = nc_cycle._velocity_request(i, 1 + i)
        else:
            req = pack({"id": 1 + i, "cmd": "MoveAbsolute", "Position": 1e6 * (1 if i % 2 else -1),
                        "Velocity": 100.0 + (i % 4) * 100.0, "Acceleration": 0.0, "Deceleration": 0.0,
                        "Jerk": 0.0, "BufferMode": 0})
        r = core.execute(parse_request(req), i + 1)
        assert not r.get("error"), r
    for _ in range(50):
        core.step()
    return core


def worker() -> None:
    import numpy as np
    from nc_schema import pack, parse_request
    pc = time.perf_counter_ns
    cores: dict[tuple[int, str], Any] = {}
    for line in sys.stdin:
        job = json.loads(line)
        n, what, count = int(job["axes"]), job["what"], int(job["n"])
        t = np.zeros(count, dtype=np.int64)
        t2 = np.zeros(count, dtype=np.int64)
        if what == "step":
            core = cores.get((n, "velocity")) or cores.setdefault((n, "velocity"), _moving_core(n, "velocity"))
            step = core.step
            for k in range(count):
                t0 = pc()
                step()
                t[k] = pc() - t0
        elif what == "read":
            core = cores.get((n, "velocity")) or cores.setdefault((n, "velocity"), _moving_core(n, "velocity"))
            reqs = [parse_request(pack({"id": 7, "cmd": "ReadParameter", "ParameterNumber": 1})) for _ in range(n)]
            for k in range(count):
                i = k % n
                t0 = pc()
                r = core.execute(reqs[i], i + 1)
                t[k] = pc() - t0
                core.step()
            assert not r.get("error"), r
        else:
            core = cores.get((n, "absolute")) or cores.setdefault((n, "absolute"), _moving_core(n, "absolute"))
            # (ahead in the axis's direction, same velocity: never refused as an overshoot or a reversal)
            reqs = [[parse_request(pack({"id": 8, "cmd": "MoveAbsolute", "Position": s * (1 if i % 2 else -1),
                                         "Velocity": 100.0 + (i % 4) * 100.0, "Acceleration": 0.0,
                                         "Deceleration": 0.0, "Jerk": 0.0, "BufferMode": 0}))
                     for s in (2e6, 1e6)] for i in range(n)]
            sign = [0] * n
            bad = 0
            for k in range(count):
                i = k % n
                sign[i] ^= 1
                t0 = pc()
                r = core.execute(reqs[i][sign[i]], i + 1)
                t1 = pc()
                core.step()
                t[k] = t1 - t0
                t2[k] = pc() - t1
                bad += bool(r.get("error"))
            assert not bad, f"{bad} re-targets refused"
        out = {"p10": float(np.percentile(t, 10)), "p50": float(np.median(t))}
        if what == "retarget":
            out["stress"] = {"p10": float(np.percentile(t2, 10)), "p50": float(np.median(t2))}
        print(json.dumps(out), flush=True)


# -- driver side ----------------------------------------------------------------------------------
class Engine:
    def __init__(self, name: str, root: Path, pythonpath: str) -> None:
        env = dict(os.environ, PYTHONPATH=pythonpath)
        self.name = name
        self.proc = subprocess.Popen([sys.executable, str(Path(__file__).resolve()), "--worker"], env=env,
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, cwd=str(root))

    def run(self, axes: int, what: str, n: int) -> dict[str, Any]:
        assert self.proc.stdin is not None and self.proc.stdout is not None
        self.proc.stdin.write(json.dumps({"axes": axes, "what": what, "n": n}) + "\n")
        self.proc.stdin.flush()
        line = self.proc.stdout.readline()
        if not line:
            raise SystemExit(f"{self.name} worker died")
        return json.loads(line)

    def close(self) -> None:
        if self.proc.stdin is not None:
            self.proc.stdin.close()
        self.proc.wait(timeout=30)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--baseline", default="75a412e")
    ap.add_argument("--baseline-root", type=Path, help="an existing checkout of the baseline (else bench/.cache)")
    ap.add_argument("--axes", type=int, nargs="+", default=[8, 64, 256])
    ap.add_argument("--n", type=int, default=5000)
    ap.add_argument("--rounds", type=int, default=6)
    ap.add_argument("--points", nargs="+", default=["step", "read", "retarget"], choices=("step", "read", "retarget"))
    args = ap.parse_args()
    if args.worker:
        worker()
        return
    root = args.baseline_root or nc_cycle.rev_tree(args.baseline)[0]
    shim = Path(os.environ.get("TMPDIR", "/tmp")) / f"core_step_shim_{os.getpid()}"
    engines = {"new": Engine("new", REPO, str(REPO)),
               "old": Engine("old", root, nc_cycle.engine_pythonpath(Path(root), shim))}
    res: dict[tuple[str, int, str], list[dict[str, float]]] = {}
    try:
        for r in range(args.rounds):
            order = ("new", "old") if r % 2 == 0 else ("old", "new")
            for axes in args.axes:
                for what in args.points:
                    for name in order:
                        out = engines[name].run(axes, what, args.n)
                        res.setdefault((name, axes, what), []).append(out)
                        if "stress" in out:
                            res.setdefault((name, axes, "step-stress"), []).append(out["stress"])
            print(f"round {r + 1}/{args.rounds} done", file=sys.stderr, flush=True)
    finally:
        for e in engines.values():
            e.close()
    import numpy as np
    print(f"load: {os.getloadavg()}; n={args.n}, rounds={args.rounds}; times in us (median of the rounds' "
          f"medians / min of the rounds' p10)")
    print(f"{'point':<12} {'axes':>5} {'new p50':>9} {'old p50':>9} {'ratio':>6} {'new p10':>9} {'old p10':>9} {'ratio':>6}")
    for axes in args.axes:
        for what in POINTS:
            if ("new", axes, what) not in res:
                continue
            f = {name: (float(np.median([x["p50"] for x in res[(name, axes, what)]])) / 1e3,
                        min(x["p10"] for x in res[(name, axes, what)]) / 1e3) for name in ("new", "old")}
            print(f"{what:<12} {axes:>5} {f['new'][0]:>9.2f} {f['old'][0]:>9.2f} {f['new'][0] / f['old'][0]:>6.3f} "
                  f"{f['new'][1]:>9.2f} {f['old'][1]:>9.2f} {f['new'][1] / f['old'][1]:>6.3f}")


if __name__ == "__main__":
    main()
