"""The NC cycle on CANopen drives: cost per axis against the same run's sim drives, and the PDO timing.

One process, one NcCore per backend, each run in turn at a fixed 1 ms rate (sleep to the next deadline; not the
server's SCHED_FIFO CycleLoop) with every axis moving (MoveVelocity):

  * ``sim``: the first-order-lag SimDrive (the NC's default);
  * ``cia402-sim``: Cia402SimDrive, the CiA 402 layer over the in-process link (when the module is there);
  * ``canopen``: CanopenDrive on python-can's virtual bus with the simulated slaves in the same process
    (``simulate_slaves = true``): per cycle the NC packs and sends one RPDO per axis and a SYNC; the slaves'
    notifier thread applies the RPDOs, steps the device and sends two TPDOs per axis; the NC's notifier thread
    stores them. These threads share the GIL with the cycle.

Runs are interleaved (round 1: sim, cia402-sim, canopen; round 2 reversed). Measured per backend over all rounds:
the cycle's work (``core.step()``: for canopen the exchange included) as the cycle thread's CPU time (not
disturbed by other processes on a shared machine) and as wall time, p50 / p99 [us], the process CPU per cycle
run (all threads: the cycle, both notifier threads, heartbeats) [us], and for canopen: the slaves'
SYNC handler time per SYNC, SYNC -> TPDO arrival p50 / p99 / max [us], the ages the NC saw (cycles with age 0 /
1 / 2 / more) and the axis errors. Printed as same-run ratios to ``sim`` with the absolute figures, and the
cost per CANopen axis ((canopen - sim) / axes). No goal (figures only): the issue asks for the figure.

    .venv/bin/python bench/canopen_cycle.py [--axes 8] [--seconds 2] [--rounds 2] [--cycle 0.001]
"""
from __future__ import annotations

import argparse
import os
import sys
import time
import uuid
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from bench.common import Busy, ProcCpu, pct, use_this_tree, verdict  # noqa: E402

use_this_tree()

import numpy as np  # noqa: E402

import nc_server.core  # noqa: E402,F401  (first: nc_server.drives imports the core)
from nc_server.core import AxisConfig, AxisParams, NcCore  # noqa: E402
from nc_server.drives.base import DriveABC, DriveContext  # noqa: E402
from nc_server.drives.sim import SimDrive  # noqa: E402
from znc_testing.nc_core import cmd, power  # noqa: E402

DT = 0.001  # --cycle sets it
PARAMS = dict(AxisEncoderScalingFactor=0.0001, AxisVeloMax=1000.0, AxisAcc=5000.0, AxisDec=5000.0,
              AxisJerk=50000.0, AxisEnPositionLagMonitoring=False)


def build(backend: str, n: int) -> tuple[NcCore, DriveABC]:
    params = [AxisParams(**PARAMS) for _ in range(n)]  # type: ignore[arg-type]
    drive: DriveABC
    if backend == "sim":
        drive = SimDrive(params, DT)
    elif backend == "cia402-sim":
        from nc_server.drives.cia402.sim import Cia402SimDrive
        drive = Cia402SimDrive(params, DT)
    else:
        from nc_server.drives.canopen.drive import CanopenDrive
        drive = CanopenDrive.from_config(params, DT, [{"node_id": i + 1} for i in range(n)], DriveContext(
            options={"simulate_slaves": True, "channel": f"bench-{uuid.uuid4().hex[:8]}"}))
    core = NcCore([AxisConfig(i + 1, f"A{i + 1}", p) for i, p in enumerate(params)], DT, drive=drive)
    return core, drive


def run(backend: str, n: int, seconds: float) -> dict[str, Any]:
    core, drive = build(backend, n)
    try:
        for i in range(n):
            power(core, i)
        link = getattr(drive, "link", None)
        deadline = time.monotonic() + 5.0
        while not np.all(drive.following) and time.monotonic() < deadline:
            core.step()
            if hasattr(link, "wait_answered"):
                link.wait_answered(1.0)  # type: ignore[union-attr]
        for i in range(n):
            cmd(core, "MoveVelocity", i + 1, Velocity=100.0 + 10.0 * i, Acceleration=2000.0, Deceleration=2000.0,
                Jerk=20000.0)
        for _ in range(300):  # accelerate, settle (real time, as below)
            core.step()
            time.sleep(DT)
        timing: list[float] = []
        if hasattr(link, "timing"):
            link.timing = timing  # type: ignore[union-attr]
        slaves = getattr(drive, "slaves", None)
        busy0 = slaves.busy_s if slaves is not None else 0.0
        syncs0 = slaves.syncs if slaves is not None else 0
        work, cpu_work, late, ages = [], [], [], []  # type: ignore[var-annotated]
        cpu = ProcCpu({"self": os.getpid()})
        t_start = time.monotonic()
        cycles = int(seconds / DT)
        t_next = time.perf_counter()
        for _ in range(cycles):
            t_next += DT
            t0, c0 = time.perf_counter(), time.thread_time()
            core.step()
            work.append(time.perf_counter() - t0)
            cpu_work.append(time.thread_time() - c0)
            tx = getattr(drive, "tx", None)
            if tx is not None and link is not None:
                ages.append(int(tx.age.max()))
            rest = t_next - time.perf_counter()
            if rest > 0:
                time.sleep(rest)
            else:
                late.append(-rest)
                t_next = time.perf_counter()
        cpu_share = cpu.stop()["self"]
        proc_us = cpu_share / 100.0 * (time.monotonic() - t_start) / cycles * 1e6  # process CPU per NC cycle
        errors = sorted({hex(int(e)) for e in core.nctoplc["ErrorCode"] if int(e)})
        out: dict[str, Any] = dict(work=work, cpu_work=cpu_work, cpu=cpu_share, proc_us=proc_us, overruns=len(late), errors=errors, ages=ages,
                                   timing=list(timing))
        if slaves is not None:
            ds = max(1, slaves.syncs - syncs0)
            out["slave_us"] = 1e6 * (slaves.busy_s - busy0) / ds
            out["dropped"] = slaves.dropped_syncs
        if link is not None and hasattr(link, "timing"):
            link.timing = None  # type: ignore[union-attr]
        moving = int(np.count_nonzero(np.abs(core.nctoplc["ActVelo"]) > 1.0))
        out["moving"] = moving
        return out
    finally:
        drive.close()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    ap.add_argument("--axes", type=int, default=8)
    ap.add_argument("--seconds", type=float, default=2.0)
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--cycle", type=float, default=0.001, help="NC cycle [s] (default 0.001)")
    a = ap.parse_args()
    global DT
    DT = a.cycle
    backends = ["sim", "canopen"]
    try:
        import nc_server.drives.cia402.sim  # noqa: F401
        backends.insert(1, "cia402-sim")
    except ImportError:
        pass
    res: dict[str, list[dict[str, Any]]] = {b: [] for b in backends}
    busy = Busy()
    for r in range(a.rounds):
        for b in (backends if r % 2 == 0 else backends[::-1]):
            res[b].append(run(b, a.axes, a.seconds))
    busy.stop()
    print(f"canopen_cycle: {a.axes} axes moving, {DT * 1e3:g} ms cycle, {a.rounds} x {a.seconds:g} s per backend; "
          f"python-can virtual bus, simulated slaves in this process")
    agg: dict[str, dict[str, float]] = {}
    for b in backends:
        work = [w for x in res[b] for w in x["work"]]
        cw = [w for x in res[b] for w in x["cpu_work"]]
        agg[b] = dict(p50=1e6 * pct(work, 50), p99=1e6 * pct(work, 99), mean=1e6 * float(np.mean(work)),
                      cpu=float(np.mean([x["cpu"] for x in res[b]])), c50=1e6 * pct(cw, 50), c99=1e6 * pct(cw, 99),
                      cmean=1e6 * float(np.mean(cw)), proc_us=float(np.mean([x["proc_us"] for x in res[b]])))
        errs = sorted({e for x in res[b] for e in x["errors"]})
        over = sum(x["overruns"] for x in res[b])
        moving = min(x["moving"] for x in res[b])
        print(f"  {b:10s} step CPU p50 {agg[b]['c50']:6.1f} us p99 {agg[b]['c99']:6.1f} us mean {agg[b]['cmean']:6.1f} us"
              f" | wall p50 {agg[b]['p50']:7.1f} us p99 {agg[b]['p99']:8.1f} us  process CPU {agg[b]['proc_us']:5.0f} us/cycle  overruns {over}  moving {moving}/{a.axes}"
              f"  axis errors {errs or 'none'}")
    s, c = agg["sim"], agg["canopen"]
    print(f"  ratios canopen / sim (same run): step CPU p50 {c['c50'] / s['c50']:.1f}x, p99 {c['c99'] / s['c99']:.1f}x; "
          f"wall p50 {c['p50'] / s['p50']:.1f}x; process CPU per cycle {c['proc_us'] / max(s['proc_us'], 1e-9):.1f}x")
    print(f"  cost per CANopen axis: cycle thread {(c['cmean'] - s['cmean']) / a.axes:.1f} us/cycle (mean step CPU), "
          f"whole process {(c['proc_us'] - s['proc_us']) / a.axes:.1f} us/cycle (process CPU per cycle run; the "
          f"slaves and both notifier threads included)")
    if "cia402-sim" in agg:
        k = agg["cia402-sim"]
        print(f"  cia402-sim / sim: step CPU p50 {k['c50'] / s['c50']:.1f}x, {(k['cmean'] - s['cmean']) / a.axes:.1f} "
              f"us per axis and cycle more (mean step CPU)")
    timing = [t for x in res["canopen"] for t in x["timing"]]
    ages = [g for x in res["canopen"] for g in x["ages"]]
    slave_us = float(np.mean([x["slave_us"] for x in res["canopen"]]))
    hist = {k: sum(1 for g in ages if g == k) for k in (0, 1, 2)}
    more = sum(1 for g in ages if g > 2)
    print(f"  PDO timing: SYNC -> TPDO arrival p50 {1e6 * pct(timing, 50):.0f} us, p99 {1e6 * pct(timing, 99):.0f} us, "
          f"max {1e6 * max(timing, default=float('nan')):.0f} us ({len(timing)} TPDOs); slaves' SYNC handler CPU "
          f"{slave_us:.0f} us per SYNC ({slave_us / a.axes:.0f} us per axis)")
    dropped = sum(x.get("dropped", 0) for x in res["canopen"])
    print(f"  ages seen by the NC (worst axis per cycle): 0: {hist[0]}, 1: {hist[1]}, 2: {hist[2]}, >2: {more} "
          f"of {len(ages)} cycles; SYNCs the slaves reached a cycle late and dropped: {dropped}")
    from nc_server.drives.canopen.pdo import bus_load
    print(f"  a real bus: the cyclic PDOs of {a.axes} axes at 1 Mbit/s take {100 * bus_load(a.axes, DT, 1_000_000):.0f} "
          f"% of a {DT * 1e3:g} ms cycle")
    verdict("canopen_cycle", [], busy.text())


if __name__ == "__main__":
    main()
