"""Where a request's time goes on the NC's cycle thread: parse, dedup, core.execute (accept, checks,
planning (ruckig), begin/sync, packing), reply; in-process, no zenoh, thread CPU time.

    .venv/bin/python bench/request_cost.py [--axes 4 64] [--n 400] [--two-phase]

Per command kind: p50 / p98 / max [us] of each part (inclusive: a part's children are inside it).
``--two-phase``: the server's path instead (RequestHandler.prepare when taken, RequestHandler.plan in the gap
before the cycle, RequestHandler.activate at its start): "handle (total)" is then the handler's part, "plan"
the core's part, "activate" the part in the cycle.
"""
from __future__ import annotations

import argparse
import collections
import functools
import sys
import time
from pathlib import Path
from typing import Any, Callable

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402

from nc_schema import Keys, pack  # noqa: E402
from nc_server.core import AxisConfig, AxisParams, NcCore  # noqa: E402
from nc_server.core import engine as E  # noqa: E402
from nc_server.core import nc as NC  # noqa: E402
from nc_server.core.jobs import KINDS  # noqa: E402
from nc_server.server import handler as H  # noqa: E402
from nc_server.server.claims import ClaimTable  # noqa: E402

clock = time.thread_time_ns
T: dict[str, list[int]] = collections.defaultdict(list)


def timed(label: str, fn: Callable[..., Any]) -> Callable[..., Any]:
    @functools.wraps(fn)
    def w(*a: Any, **k: Any) -> Any:
        t0 = clock()
        try:
            return fn(*a, **k)
        finally:
            T[label].append(clock() - t0)
    return w


def instrument() -> None:
    H.parse_request = timed("parse", H.parse_request)
    H.pack = timed("pack reply", H.pack)
    H.ReplyCache.get = timed("dedup get", H.ReplyCache.get)
    H.ReplyCache.put = timed("dedup put", H.ReplyCache.put)
    NcCore.execute = timed("core.execute", NcCore.execute)
    NcCore.plan = timed("  ruckig (core.plan)", NcCore.plan)
    NC.make_reply = timed("  make_reply", NC.make_reply)
    E.JobEngine.sync = timed("  sync (all)", E.JobEngine.sync)
    E.JobEngine.begin = timed("  begin", E.JobEngine.begin)
    E.JobEngine.motion = timed("  engine.motion", E.JobEngine.motion)
    NcCore.check_startable = timed("  check_startable", NcCore.check_startable)
    for kind in {k for k in KINDS.values()}:
        cls = type(kind)
        if "accept" in cls.__dict__:
            cls.accept = timed("  accept", cls.__dict__["accept"])
        if "activate" in cls.__dict__:
            cls.activate = timed("  activate (checks+plan)", cls.__dict__["activate"])


def make(n: int) -> tuple[NcCore, H.RequestHandler]:
    p = AxisParams(AxisVeloMax=2000.0, AxisAcc=5000.0, AxisDec=5000.0, AxisJerk=50000.0)
    core = NcCore([AxisConfig(i + 1, f"A{i + 1}", p) for i in range(n)], 0.001)
    rec = core.default_plctonc()
    rec["ControlDWord"] = 7
    for i in range(n):
        core.set_plctonc(i, rec)
    core.step()
    claims = ClaimTable([i + 1 for i in range(n)], 0.5)
    h = H.RequestHandler(core, claims, Keys("nc1"))
    return core, h


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--axes", type=int, nargs="+", default=[4, 64])
    ap.add_argument("--n", type=int, default=400)
    ap.add_argument("--two-phase", action="store_true")
    ap.add_argument("--kinds", nargs="*", default=None)
    args = ap.parse_args()
    instrument()
    rid = iter(range(1, 10**9))
    for n in args.axes:
        core, h = make(n)
        kinds: dict[str, Callable[[int], tuple[str, dict[str, Any]]]] = {
            "ReadParameter": lambda k: ("read", {"cmd": "ReadParameter", "ParameterNumber": 1003}),
            "MoveRelative (rest)": lambda k: ("op", {"cmd": "MoveRelative", "Distance": 5.0 * (1 if k % 2 else -1),
                                                    "Velocity": 400.0}),
            "MoveAbsolute re-target": lambda k: ("op", {"cmd": "MoveAbsolute", "Position": 1e5 + 100.0 * (k % 2),
                                                       "Velocity": 500.0}),
            "Halt (moving)": lambda k: ("op", {"cmd": "Halt"}),
        }
        for name, mk in kinds.items():
            if args.kinds and not any(k in name for k in args.kinds):
                continue
            T.clear()
            tot: list[int] = []
            for k in range(args.n):
                i = k % n
                if name == "MoveRelative (rest)":  # from standstill: let the previous one end
                    core.execute({"id": None, "client": "", "cmd": "Stop", "Deceleration": 0.0, "Jerk": 0.0}, i + 1) \
                        if core.moving[i] else None
                    for _ in range(3):
                        core.step()
                    core.execute({"id": None, "client": "", "cmd": "Reset"}, i + 1)
                elif name == "Halt (moving)":
                    core.execute({"id": None, "client": "c", "cmd": "MoveVelocity", "Velocity": 100.0,
                                  "Direction": 1, "Acceleration": 0.0, "Deceleration": 0.0, "Jerk": 0.0,
                                  "BufferMode": 0}, i + 1)
                    for _ in range(3):
                        core.step()
                cls, req = mk(k)
                payload = pack({"id": next(rid), "client": "c", **req})
                key = f"nc/nc1/axis/{i + 1}/cmd/{cls}/c"
                T.clear() if k == 0 else None
                t0 = clock()
                if args.two_phase:
                    got = h.prepare(key, payload, time.monotonic())
                    tot.append(clock() - t0)
                    if isinstance(got, H.PendingReply):
                        t1 = clock()
                        got = h.plan(got)
                        T["plan (the core's part)"].append(clock() - t1)
                    if isinstance(got, H.PendingReply):
                        t1 = clock()
                        rep = h.activate(got)
                        T["activate (in the cycle)"].append(clock() - t1)
                    else:
                        rep = got
                else:
                    rep = h.handle(key, payload, time.monotonic())
                    tot.append(clock() - t0)
                core.step()
            r = H.unpack(rep)
            print(f"\n== {n} axes, {name} (last reply error 0x{r['error']:x} {r.get('text', '')[:60]})")
            rows = [("handle (total)", tot)] + sorted(T.items(), key=lambda kv: -np.median(kv[1]))
            for label, xs in rows:
                a = np.array(xs) / 1000.0
                print(f"  {label:28s} n={len(a):5d}  p50 {np.percentile(a, 50):7.1f}  p98 {np.percentile(a, 98):7.1f}"
                      f"  max {a.max():7.1f} us   per request {a.sum() / args.n:7.1f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
