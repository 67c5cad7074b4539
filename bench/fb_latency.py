"""Function block latency through the real distributed path, next to raw zenoh.

In one run, on 127.0.0.1:
  1. raw zenoh: a client session's ``get`` to a trivial queryable in a router process
     (the same topology as a PLC client and nc-server);
  2. an nc-server process and an embedded PLC runtime: an MC_MoveRelative Execute edge ->
     the NC's acceptance (reply received) -> the block seeing its command with HasJob in NcToPlc.

Prints absolute figures (us) and the ratios; goals (not tests): the NC's acceptance (Execute
edge -> reply) within 1.5x the raw round trip + one NC cycle; HasJob seen within 1.5x raw + one NC
cycle + one PLC cycle. Also a same-run noise floor (bench/noise_floor.py: a fixed numpy workload in
the NC cycle loop, before and after the trials), so the figures can be put next to how loaded the
machine was.

    .venv/bin/python bench/fb_latency.py [--trials 60] [--plc-cycle 0.01]
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import zenoh

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))  # the test helpers (znc_testing)
from bench.noise_floor import floor_line  # noqa: E402
from bench.raw_zenoh import RAW_KEY, raw_queryable  # noqa: E402
from znc_testing import free_port, start_nc_server, zenoh_client_config  # noqa: E402

from nc_schema import StateDWord  # noqa: E402
from plc_client import AXIS_REF, MC_MoveRelative, MC_Power  # noqa: E402
from plc_client.runtime import PlcRuntime  # noqa: E402



def pct(xs: list[float], p: float) -> float:
    xs = sorted(xs)
    return xs[min(len(xs) - 1, int(round(p / 100 * (len(xs) - 1))))]


def fmt(xs: list[float]) -> str:
    return f"p50 {pct(xs, 50):8.0f}  p99 {pct(xs, 99):8.0f}  max {max(xs):8.0f} us  (n={len(xs)})"


def raw_rtt(n: int) -> list[float]:
    out = []
    with raw_queryable(free_port()) as port, zenoh.open(zenoh_client_config(port)) as s:
        for i in range(n + 20):
            t = time.perf_counter()
            replies = list(s.get(RAW_KEY, timeout=5.0))
            dt = (time.perf_counter() - t) * 1e6
            assert replies and replies[0].ok is not None
            if i >= 20:  # warm-up
                out.append(dt)
            time.sleep(0.01)
    return out


def fb_latency(trials: int, plc_cycle: float) -> tuple[list[float], list[float], float]:
    with tempfile.TemporaryDirectory() as tmp:
        nc = start_nc_server(Path(tmp))
        try:
            nc.wait_ready()
            X = AXIS_REF(nc="nc1", axis_id=1)
            power, move = MC_Power(), MC_MoveRelative()
            accept: list[float] = []
            seen: list[float] = []
            st = {"phase": "idle", "t_edge": 0.0, "sign": 1.0, "n": 0, "settle": 0}

            def program(plc: PlcRuntime) -> None:
                power(Axis=X, Enable=True, Enable_Positive=True, Enable_Negative=True)
                if not power.Status or st["n"] >= trials:
                    return
                if st["phase"] == "idle":
                    st["settle"] += 1
                    if st["settle"] < 3:  # a few cycles at standstill between trials
                        return
                    st["t_edge"] = time.perf_counter()
                    move(Axis=X, Execute=True, Distance=5.0 * st["sign"], Velocity=400.0)
                    st["phase"] = "wait"
                    return
                move(Axis=X)
                cmd_no = move._cmdno  # the CmdNo the NC gave this block's command (0 until the reply)
                if st["phase"] == "wait" and cmd_no and X.NcToPlc.CmdNo == cmd_no and X.NcToPlc.StateDWord & StateDWord.HasJob:
                    seen.append((time.perf_counter() - st["t_edge"]) * 1e6)
                    st["phase"] = "moving"
                if move.Done or move.Error or move.CommandAborted:
                    move(Execute=False)
                    st.update(phase="idle", sign=-st["sign"], n=st["n"] + 1, settle=0)

            rt = PlcRuntime(program, {"nc1": f"tcp/127.0.0.1:{nc.port}"}, cycle_time=plc_cycle, client_id="bench-fb")
            deliver = rt.port._deliver

            def timed_deliver(pending, reply, failed=0):  # runs on a zenoh thread: the reply's arrival
                if reply is not None and pending.cmd == "MoveRelative" and st["phase"] == "wait":
                    accept.append((time.perf_counter() - st["t_edge"]) * 1e6)
                deliver(pending, reply, failed)

            rt.port._deliver = timed_deliver  # type: ignore[method-assign]
            rt.open(wait=10.0)
            deadline = time.monotonic() + 60.0
            rt.start()
            while st["n"] < trials and time.monotonic() < deadline:
                time.sleep(0.05)
            rt.stop()
            return accept, seen, 0.001
        finally:
            nc.stop()


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--trials", type=int, default=60)
    ap.add_argument("--plc-cycle", type=float, default=0.010)
    args = ap.parse_args()
    floor0, f0 = floor_line()
    raw = raw_rtt(200)
    accept, seen, nc_cycle = fb_latency(args.trials, args.plc_cycle)
    floor1, f1 = floor_line()
    if not accept or not seen:
        print(f"FB latency: no complete trial (accepted {len(accept)}, seen {len(seen)})")
        return 1
    raw50 = pct(raw, 50)
    cyc_us = nc_cycle * 1e6
    print("== FB latency (MC_MoveRelative Execute edge) vs raw zenoh, loopback ==")
    print(f"raw zenoh get RTT (client -> router queryable): {fmt(raw)}")
    print(f"Execute edge -> NC reply (accepted):           {fmt(accept)}")
    print(f"Execute edge -> block sees HasJob + its CmdNo:  {fmt(seen)}")
    acc50, acc99 = pct(accept, 50), pct(accept, 99)
    budget_acc = 1.5 * raw50 + cyc_us
    budget_seen = 1.5 * raw50 + cyc_us + args.plc_cycle * 1e6
    print(f"accept p50 / raw p50: {acc50 / raw50:5.2f}x  (p99 / raw p99: {acc99 / pct(raw, 99):5.2f}x)")
    print(f"goal: accept p50 <= 1.5 x raw p50 + one NC cycle = 1.5 x {raw50:.0f} + {cyc_us:.0f} = {budget_acc:.0f} us: "
          f"{acc50:.0f} us -> ratio {acc50 / budget_acc:4.2f} (goal <= 1.0) -> {'met' if acc50 <= budget_acc else 'NOT met'}")
    print(f"goal: HasJob seen p50 <= 1.5 x raw + NC cycle + PLC cycle = {budget_seen:.0f} us: {pct(seen, 50):.0f} us "
          f"-> ratio {pct(seen, 50) / budget_seen:4.2f} (goal <= 1.0) -> "
          f"{'met' if pct(seen, 50) <= budget_seen else 'NOT met'}")
    print(f"(PLC cycle {args.plc_cycle * 1e3:.1f} ms: the block sees frames only at its cycle starts)")
    print(f"before: {floor0}")
    print(f"after:  {floor1}")
    fl50 = (f0["p50_us"] + f1["p50_us"]) / 2
    print(f"in noise-floor units (figure p50 / floor p50 {fl50:.0f} us, comparable between runs): raw {raw50 / fl50:5.1f}, "
          f"accept {acc50 / fl50:5.1f}, HasJob seen {pct(seen, 50) / fl50:5.1f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
