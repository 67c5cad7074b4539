"""Hot-standby takeovers (issue 21, docs/standby.md): ``--kills`` kill -9 of the active NC, each at a random moment of
a move, on real processes: an nc-router, two nc-server processes of NC ``nc1`` (nodes ``a`` and ``b``, cycle 2 ms),
an nc-drive-sim hosting axis 1 and an observer of the set-points and frames (tests/znc_testing/standby_rig.py, as
tests/drives/test_standby_process.py). After each takeover the killed node is started again as the standby; the
next kill hits the other node.

Per takeover: the time from the kill to the first set-point of the new active NC at the drive host (its log's
epoch change, ms resolution) and seen by the observer (its NCTOPLC samples; zenoh delivery included), the NC's own
figure (last log of the lost NC to the end of the takeover,
ha status ``takeover_cycles``); whether the move ended Done with its CmdNo; the drive host's epoch history (one
new epoch per kill, never back) and its refused outputs (``stale_epoch``). Over the run: the largest SetPos step
beyond the dynamics, the NC restarts and "NC gone" events the observer's nc_link saw, false takeovers (a role change
without a kill).

Same-run ratios with MET / NOT MET: p95 takeover time / (20 NC cycles) (the issue's goal: the first set-point
within 20 cycles of the loss, detection included) and the largest SetPos step / (one cycle at full velocity);
counts that must be 0: double drivers, jumps, blocks not ended Done, NC restarts and "NC gone" seen, false
takeovers.

    .venv/bin/python bench/takeover.py [--kills 10] [--soak 100] [--freeze] [--takeover-cycles 15] [--seed S]
                                       [--realtime off|auto|fifo]

``--freeze``: SIGSTOP instead of kill -9 (SIGCONT after the takeover; the old NC comes back as the standby).
"""
from __future__ import annotations

import argparse
import datetime
import os
import random
import re
import signal
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from bench.common import Busy, goal_line, mark, pct, use_this_tree, verdict  # noqa: E402

use_this_tree()

from znc_testing import NcServerProcess, NcTestClient, kill_process_group, start_nc_router, start_nc_server  # noqa: E402
from znc_testing.remote_drives import DriveSim, enabled, power  # noqa: E402
from znc_testing.standby_rig import CONFIG, LEASE_MS, Trace, close_all, ha_status, largest_step  # noqa: E402
from znc_testing.until import wait_until  # noqa: E402
from nc_server.server.standby import WARMUP_S  # noqa: E402

CYCLE = 0.002
V, A, J = 50.0, 500.0, 5000.0
GOAL_CYCLES = 20
PAUSE_CYCLES = 3
T = 30.0


def drive_epoch_time(log: str, epoch: int) -> float:
    """The wall time [s] the drive host logged the first outputs of ``epoch`` ("NC epoch E takes over"; its log's
    millisecond timestamps, local time as the logging module writes them): the first set-point at the drives."""
    m = re.search(r"^(\S+ \S+) nc-drive-sim \w+ NC epoch %d takes over" % epoch, log, re.M)
    return datetime.datetime.strptime(m.group(1), "%Y-%m-%d %H:%M:%S,%f").timestamp() if m else float("nan")


def count_line(what: str, n: int) -> tuple[str, bool]:
    return f"goal: {what}: {n} (goal 0) -> {mark(n == 0)}", n == 0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--kills", type=int, default=10, help="takeovers (10)")
    ap.add_argument("--soak", type=int, default=0, help="takeovers of a soak run (the issue's 100); overrides --kills")
    ap.add_argument("--takeover-cycles", type=int, default=15,
                    help="[redundancy] takeover_cycles (15, the default): the log silence that is a loss")
    ap.add_argument("--seed", type=int, default=None)
    ap.add_argument("--freeze", action="store_true",
                    help="SIGSTOP the active NC instead of kill -9 (SIGCONT after the takeover: it comes back as the "
                         "standby); each round waits for the standby's loss detection to leave its warm-up")
    ap.add_argument("--realtime", choices=("off", "auto", "fifo"), default="off",
                    help="the NCs' [nc] realtime (off, as the tests: other work on the machine is not starved)")
    args = ap.parse_args(argv)
    kills = args.soak or args.kills
    rng = random.Random(args.seed)
    tmp = Path(tempfile.mkdtemp(prefix="znc-takeover-"))
    started: list[Any] = []
    busy = Busy()
    rows: list[dict[str, Any]] = []
    false_takeovers = 0
    stopped = 0  # the process group SIGSTOP'd (--freeze)
    tr: Trace | None = None
    cl: NcTestClient | None = None
    try:
        router = start_nc_router(tmp / "router", ["--lease-ms", str(LEASE_MS)])
        started.append(router)
        text = CONFIG.format(cycle=CYCLE, port=router.port, takeover=args.takeover_cycles).replace(
            'realtime = "off"', f'realtime = "{args.realtime}"')
        cfg = tmp / "nc.toml"
        cfg.write_text(text)

        def start(node: str, i: int, first: bool = False) -> NcServerProcess:
            extra = ["--set", f"redundancy.node={node}"] + (["--set", "redundancy.start=active"] if first else [])
            p = start_nc_server(tmp / f"{node}{i}", text, name="nc1", connect=router.endpoint, extra_args=extra)
            started.append(p)
            return p

        nodes = {"a": start("a", 0, first=True), "b": start("b", 0)}
        sim = DriveSim(tmp, ["--config", str(cfg), "--host", "drives1", "--connect", router.endpoint,
                             "--timeout", "1.2", "--lease-ms", str(LEASE_MS)])
        started.append(sim)
        cl = NcTestClient(router.port, client_id="plc1", lease_ms=LEASE_MS)
        tr = Trace(router.port)
        wait_until(lambda: (s := sim.status()) is not None and s["connected"] and s["rx_count"] > 0, T, "drive host")
        roles = {"a": "active", "b": "standby"}
        for i in range(kills):
            wait_until(lambda: all((s := ha_status(cl, n)) is not None and time.time() - s["time"] < 1.0
                                   and s["in_step"] for n in nodes), T * 2, "both nodes in step")
            now_roles = {n: (ha_status(cl, n) or {}).get("role") for n in nodes}
            if now_roles != roles:  # a takeover without a kill (since the last round)
                false_takeovers += 1
                print(f"false takeover before round {i + 1}: {now_roles}", flush=True)
                roles = now_roles
            active = next(n for n, r in roles.items() if r == "active")
            standby = next(n for n in nodes if n != active)
            if args.freeze:  # (the published limit after the warm-up: what a freeze is detected by)
                time.sleep(WARMUP_S + 0.3)
            if i == 0:
                power(cl, [1])
            wait_until(enabled(cl, 1), T, "axis 1 enabled without error", interval=0.1)
            r = cl.nctoplc(1)
            target = 0.0 if r is not None and float(r["SetPos"]) > 20.0 else 40.0
            rep = cl.request("MoveAbsolute", axis=1, Position=target, Velocity=V, Acceleration=A, Deceleration=A,
                             Jerk=J)
            if rep["error"]:
                raise RuntimeError(f"MoveAbsolute: {rep}; ha {ha_status(cl, active)} {ha_status(cl, standby)}; "
                                   f"drive host {sim.status()}")
            time.sleep(rng.uniform(0.05, 0.7))  # (the move lasts ~0.9 s: the kill comes at a random point of it)
            s0 = sim.status() or {}
            before = [s[0] for s in tr.samples]
            last_cycle = max(before) if before else -1
            n_before = len(before)
            limit_before = (ha_status(cl, standby) or {}).get("takeover_limit_cycles")
            t_kill, t_kill_wall = time.monotonic(), time.time()
            if args.freeze:
                stopped = nodes[active].proc.pid
                os.killpg(stopped, signal.SIGSTOP)
            else:
                kill_process_group(nodes[active].proc)
            epochs = [s0.get("epoch")]
            st = None
            deadline = time.monotonic() + T
            while time.monotonic() < deadline:
                st = ha_status(cl, standby)
                hs = sim.status()
                if hs is not None and hs.get("epoch") != epochs[-1]:
                    epochs.append(hs.get("epoch"))
                if st is not None and st["role"] == "active" and st["takeovers"] >= 1 and \
                        hs is not None and hs.get("epoch") == st["epoch"]:
                    break
                time.sleep(0.01)
            else:
                raise RuntimeError(f"no takeover by {standby}:\n{nodes[standby].stderr()[-3000:]}")
            if stopped:
                os.killpg(stopped, signal.SIGCONT)
                stopped = 0
            # the new NC's first set-point: the first sample after the takeover's pause (a gap of more than
            # PAUSE_CYCLES in reception after the kill; the lost NC's samples in flight come before it), else the
            # first sample after the kill (a takeover faster than that)
            after = [s for s in tr.samples[n_before:] if s[5] > t_kill and s[0] > last_cycle]
            first = next((b for a, b in zip(after, after[1:]) if b[5] - a[5] > PAUSE_CYCLES * CYCLE),
                         after[0] if after else None)
            done = None
            try:
                done = wait_until(lambda: (x := cl.nctoplc(1)) is not None and int(x["CmdState"]) == 2
                                  and int(x["CmdNo"]) == rep["CmdNo"] and x, T, "the move ended Done")
            except AssertionError:
                x = cl.nctoplc(1)
                print(f"  the move did not end Done with CmdNo {rep['CmdNo']}: " + ("no NCTOPLC" if x is None else
                      f"CmdState {int(x['CmdState'])} CmdNo {int(x['CmdNo'])} SetPos {float(x['SetPos']):.4f} "
                      f"ErrorCode {int(x['ErrorCode']):#x}"), flush=True)
            s1 = sim.status() or {}
            ep = [e for e in epochs if e is not None]
            rows.append({"ms": (first[5] - t_kill) * 1e3 if first else float("nan"),
                         "drive_ms": (drive_epoch_time(sim.stderr(), st["epoch"]) - t_kill_wall) * 1e3,
                         "nc_cycles": st["takeover_cycles"], "nc_ms": st["takeover_ms"],
                         "catch_up": st["catch_up_cycles"], "detect_ms": st.get("takeover_detect_ms", float("nan")),
                         "work_ms": st.get("takeover_work_ms", float("nan")),
                         "limit": limit_before,
                         "double": int(len(ep) > 2 or any(b < a for a, b in zip(ep, ep[1:]))),
                         "stale": int(s1.get("stale_epoch", 0)) - int(s0.get("stale_epoch", 0)),
                         "done": done is not None and abs(float(done["SetPos"]) - target) < 1e-6})
            print(f"takeover {i + 1}/{kills}: {active} -> {standby}: first set-point {rows[-1]['ms']:.1f} ms after "
                  f"the kill, NC {st['takeover_cycles']} cycles ({st['takeover_ms']} ms, {st['catch_up_cycles']} "
                  f"caught up), move Done {rows[-1]['done']}", flush=True)
            if not args.freeze:
                nodes[active] = start(active, i + 1)
            roles = {active: "standby", standby: "active"}
        step = largest_step(tr.samples, CYCLE, A)
        restarts = list(tr.restarts)
        gone = list(tr.gone)
    finally:
        if stopped:
            os.killpg(stopped, signal.SIGCONT)
        close_all(tr, cl, started)
    busy.stop()
    ms = [r["ms"] for r in rows if r["ms"] == r["ms"]]
    cyc = [m / (CYCLE * 1e3) for m in ms]
    dms = [r["drive_ms"] for r in rows if r["drive_ms"] == r["drive_ms"]]
    dcyc = [m / (CYCLE * 1e3) for m in dms]
    nc_c = [r["nc_cycles"] for r in rows]
    kind = "SIGSTOP" if args.freeze else "kill -9"
    print(f"takeovers ({kind}): {len(rows)} (cycle {CYCLE * 1e3:g} ms, takeover_cycles {args.takeover_cycles}, "
          f"realtime "
          f"{args.realtime})")
    print(f"  kill -> first set-point seen: p50 {pct(ms, 50):.1f} ms ({pct(cyc, 50):.1f} cycles), p95 "
          f"{pct(ms, 95):.1f} ms ({pct(cyc, 95):.1f} cycles), max {max(ms, default=float('nan')):.1f} ms")
    print(f"  kill -> first set-point at the drive host (its log, ms resolution): p50 {pct(dms, 50):.1f} ms "
          f"({pct(dcyc, 50):.1f} cycles), p95 {pct(dms, 95):.1f} ms ({pct(dcyc, 95):.1f} cycles), max "
          f"{max(dms, default=float('nan')):.1f} ms ({max(dcyc, default=float('nan')):.1f} cycles)")
    print(f"  the NC's figure (last log -> takeover): p50 {pct(nc_c, 50):.0f} cycles, p95 {pct(nc_c, 95):.0f}, max "
          f"{max(nc_c, default=0)}; caught up p50 {pct([r['catch_up'] for r in rows], 50):.0f} cycles")
    det = [r["detect_ms"] / (CYCLE * 1e3) for r in rows]
    work = [r["work_ms"] / (CYCLE * 1e3) for r in rows]
    print(f"  its parts: detection (last log -> the cycle that takes over) p50 {pct(det, 50):.1f} / p95 "
          f"{pct(det, 95):.1f} / max {max(det, default=float('nan')):.1f} cycles; then to the first step p50 "
          f"{pct(work, 50):.1f} / p95 "
          f"{pct(work, 95):.1f} / max {max(work, default=float('nan')):.1f} cycles")
    lims = [r["limit"] for r in rows if r["limit"] is not None]
    print(f"  published limit for a freeze (the standby's takeover_limit_cycles at each kill): "
          f"min {min(lims, default=0)} max {max(lims, default=0)} cycles")
    print(f"  largest SetPos step beyond the dynamics {step:.6f} u; drive host refused outputs (stale_epoch) "
          f"{sum(r['stale'] for r in rows)}")
    goals = [
        goal_line(f"p95 takeover (kill -> first set-point at the drives) / {GOAL_CYCLES} NC cycles",
                  pct(dcyc, 95) / GOAL_CYCLES, 1.0, f"{pct(dms, 95):.1f} ms vs {GOAL_CYCLES * CYCLE * 1e3:g} ms"),
        goal_line(f"p95 takeover (kill -> first set-point seen by a client) / {GOAL_CYCLES} NC cycles",
                  pct(cyc, 95) / GOAL_CYCLES, 1.0, f"{pct(ms, 95):.1f} ms vs {GOAL_CYCLES * CYCLE * 1e3:g} ms"),
        goal_line("largest SetPos step beyond the dynamics / one cycle at full velocity", step / (V * CYCLE), 0.01,
                  f"{step:.6f} u vs {V * CYCLE:g} u"),
        count_line("double drivers (drive host epoch history)", sum(r["double"] for r in rows)),
        count_line("moves not ended Done with their CmdNo", sum(1 for r in rows if not r["done"])),
        count_line("NC restarts seen by nc_link", len(restarts)),
        count_line("'NC gone' seen by nc_link (the PLC runtime's 0x4B0F)", len(gone)),
        count_line("false takeovers (no kill)", false_takeovers),
    ]
    verdict("takeover", goals, busy.text())
    return 0  # (a goal NOT MET is no failure of the bench: the Makefile's rule)


if __name__ == "__main__":
    sys.exit(main())
