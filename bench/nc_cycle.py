"""NC cycle cost with 8, 64 and 256 moving axes at 1 ms, through the real server loop.

What runs (per axis count, one after the other, in this process):
  * the real ``NcServer``: its ``CycleLoop`` (SCHED_FIFO if permitted, sleep + spin), an
    in-process ``NcCore``, the real zenoh session (router on a free 127.0.0.1 port), the I/O
    thread publishing the batched frame every cycle and per-axis NCTOPLC samples for the
    subscribed axes;
  * a subscriber process (client mode) taking the frame and the per-axis samples of 4 axes,
    so the puts go to a real remote subscriber;
  * every axis enabled (PLCTONC preset in the core: no claims) and moving: MoveAbsolute
    back and forth between two targets, so the axes are always in a jerk-limited profile, with
    ~10 % of them re-targeted every 50 ms through ``core.execute`` (between cycles, in the cycle thread).

Measured by the loop itself: work time per cycle (drain, PLCTONC, watchdog, core.step,
encode_frame, hand-off) and start lateness (actual start - deadline), p50/p99/max in us over
the measuring window; missed cycles and overruns counted.

Goals (not tests): 64 moving axes p99 work < 250 us; 256 axes p99 work < 500 us.

    .venv/bin/python bench/nc_cycle.py [--seconds 6] [--axes 8 64 256]
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from tests.znc_testing import free_port  # noqa: E402

from nc_schema import make_reply  # noqa: E402
from nc_server.core import AxisConfig, AxisParams, NcCore  # noqa: E402
from nc_server.server.app import NcServer  # noqa: E402
from nc_server.server.config import ServerConfig, ZenohSettings  # noqa: E402
from nc_server.server.cycle import RING  # noqa: E402

GOALS = {64: 250.0, 256: 500.0}

SUBSCRIBER = r"""
import json, sys, time, zenoh
port, seconds = int(sys.argv[1]), float(sys.argv[2])
c = zenoh.Config()
c.insert_json5("mode", '"client"')
c.insert_json5("connect/endpoints", json.dumps([f"tcp/127.0.0.1:{port}"]))
c.insert_json5("scouting/multicast/enabled", "false")
c.insert_json5("scouting/gossip/enabled", "false")
n = {"frame": 0, "axis": 0}
with zenoh.open(c) as s:
    def on_frame(smp): n["frame"] += 1
    def on_axis(smp): n["axis"] += 1
    subs = [s.declare_subscriber("nc/bench/frame", on_frame)]
    subs += [s.declare_subscriber(f"nc/bench/axis/{a}/nctoplc", on_axis) for a in (1, 2, 3, 4)]
    print("ready", flush=True)
    sys.stdin.readline()           # start counting
    n["frame"] = n["axis"] = 0
    sys.stdin.readline()           # stop
    print(json.dumps(n), flush=True)
"""


def make_server(n_axes: int, port: int, realtime: str) -> tuple[NcServer, NcCore]:
    params = AxisParams(AxisVeloMax=1000.0, AxisAcc=5000.0, AxisDec=5000.0, AxisJerk=50000.0,
                        AxisEnPositionLagMonitoring=False)
    axes = tuple(AxisConfig(AxisId=i + 1, Name=f"A{i + 1}", params=params) for i in range(n_axes))
    cfg = ServerConfig(name="bench", cycle_time=0.001, watchdog_timeout=0.5, realtime=realtime,
                       zenoh=ZenohSettings("router", (f"tcp/127.0.0.1:{port}",), (), 1000), axes=axes)
    core = NcCore(list(axes), cycle_time=cfg.cycle_time)
    enabled = core.default_plctonc()
    enabled["ControlDWord"] = 0x7  # Enable, FeedEnablePlus, FeedEnableMinus
    for i in range(n_axes):
        core.set_plctonc(i, enabled)
    core.step()
    return NcServer(cfg, core), core


class Mover:
    """Keeps every axis in a MoveAbsolute profile; runs inside the cycle (wraps NcServer.cycle)."""

    def __init__(self, server: NcServer, core: NcCore) -> None:
        self.core = core
        self.n = len(core.axis_ids)
        self.inner = server.cycle
        self.k = 0
        self.rejected = 0
        self.rid = 0
        server.loop.work = self.cycle

    def command(self, i: int) -> None:
        self.rid += 1
        target = 100.0 if float(self.core.nctoplc[i]["SetPos"]) < 50.0 else 0.0
        r = self.core.execute({"id": self.rid, "client": "", "cmd": "MoveAbsolute", "Position": target,
                               "Velocity": 200.0 + (i % 7) * 50.0, "Acceleration": 0.0, "Deceleration": 0.0,
                               "Jerk": 0.0, "BufferMode": 0}, int(self.core.axis_ids[i]))
        if r["error"]:
            self.rejected += 1

    def start_all(self) -> None:
        for i in range(self.n):
            self.command(i)

    def cycle(self, deadline_ns: int) -> None:
        self.k += 1
        if self.k % 50 == 0:  # re-target ~10 % of the axes every 50 ms (commands as they arrive in a real NC)
            for i in range((self.k // 50) % 10, self.n, 10):
                self.command(i)
        else:
            # axes whose profile ended turn around (always moving)
            done = np.flatnonzero(~self.core.moving)
            for i in done[:4].tolist():
                self.command(i)
        self.inner(deadline_ns)


def window(arr: np.ndarray, c0: int, c1: int) -> np.ndarray:
    """Ring entries recorded for cycles c0..c1-1 (the newest RING at most)."""
    c0 = max(c0, c1 - RING)
    idx = np.arange(c0, c1) % RING
    return arr[idx]


def pct(a: np.ndarray) -> str:
    p50, p99 = np.percentile(a, (50, 99))
    return f"{p50:7.1f} {p99:7.1f} {a.max():8.1f}"


def run_one(n_axes: int, seconds: float, realtime: str) -> dict[str, Any]:
    port = free_port()
    server, core = make_server(n_axes, port, realtime)
    mover = Mover(server, core)
    mover.start_all()
    sub = subprocess.Popen([sys.executable, "-c", SUBSCRIBER, str(port), str(seconds)], stdin=subprocess.PIPE,
                           stdout=subprocess.PIPE, text=True, start_new_session=True)
    try:
        server.start()
        assert sub.stdout is not None and sub.stdin is not None
        line = sub.stdout.readline()
        if line.strip() != "ready":
            raise RuntimeError("subscriber did not start")
        time.sleep(1.5)  # warm-up: connection, first puts of new publishers, matching
        st = server.loop.stats
        c0, m0, o0, d0 = st.cycles, st.missed_cycles, st.overruns, server.io.frames_dropped
        sub.stdin.write("go\n")
        sub.stdin.flush()
        time.sleep(seconds)
        c1, m1, o1, d1 = st.cycles, st.missed_cycles, st.overruns, server.io.frames_dropped
        sub.stdin.write("stop\n")
        sub.stdin.flush()
        got = json.loads(sub.stdout.readline())
        work = window(st.work_us, c0, c1)
        late = window(st.lateness_us, c0, c1)
        moving = int(np.count_nonzero(core.moving))
        return {"axes": n_axes, "timing": st.timing, "cycles": c1 - c0, "missed": m1 - m0, "overruns": o1 - o0,
                "work": work.copy(), "late": late.copy(), "moving": moving, "frames_dropped": d1 - d0,
                "sub_frames": got["frame"], "sub_axis_samples": got["axis"], "rejected": mover.rejected}
    finally:
        server.stop()
        try:
            sub.kill()
            sub.wait(10)
        except Exception:
            pass


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seconds", type=float, default=6.0, help="measuring window per axis count [s]")
    ap.add_argument("--axes", type=int, nargs="+", default=[8, 64, 256])
    ap.add_argument("--realtime", default="auto", choices=("auto", "fifo", "off"))
    args = ap.parse_args()
    seconds = min(args.seconds, 12.0)  # keep the whole run under a minute
    print(f"NC cycle benchmark: real NcServer loop + NcCore + zenoh publishing (frame every cycle, per-axis "
          f"samples for 4 subscribed axes), 1 ms cycle, {seconds:g} s per point, all axes moving")
    rows = []
    t0 = time.monotonic()
    for n in args.axes:
        rows.append(run_one(n, seconds, args.realtime))
    print()
    print(f"{'axes':>5} {'timing':>11} {'cycles':>7} | {'work us p50':>11} {'p99':>7} {'max':>8} | "
          f"{'late us p50':>11} {'p99':>7} {'max':>8} | {'missed':>6} {'overrun':>7} | moving  sub frames / axis samples")
    for r in rows:
        print(f"{r['axes']:>5} {r['timing']:>11} {r['cycles']:>7} | {pct(r['work']):>28} | {pct(r['late']):>28} | "
              f"{r['missed']:>6} {r['overruns']:>7} | {r['moving']:>3}/{r['axes']:<3}  {r['sub_frames']} / "
              f"{r['sub_axis_samples']}")
    print()
    for r in rows:
        goal = GOALS.get(r["axes"])
        if goal is not None:
            p99 = float(np.percentile(r["work"], 99))
            verdict = "met" if p99 < goal else "NOT met"
            print(f"goal {r['axes']} moving axes p99 work < {goal:.0f} us: {p99:.0f} us -> {verdict}")
    print(f"(total run {time.monotonic() - t0:.1f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
