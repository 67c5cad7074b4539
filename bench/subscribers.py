"""The NC's and its frame publisher's CPU with 0, 1, 4 and 16 subscribing PLC clients, in one run.

Topology: one ``nc-server`` (``--axes`` axes, default 64, 1 ms cycle, its own router on a free 127.0.0.1 port,
the frame publisher a child process as by default) and, point by point, more ``plc-run`` clients of
``bench/many_clients_program.py`` in hold mode (``MANY_HOLD=1``): each declares and powers its own 4 axes
(claims them, sends its PLCTONC every PLC cycle, 10 ms) and takes the NC's frames; no moves. The clients are
added to the same NC (0 -> 1 -> 4 -> 16: each point keeps the clients of the one before), so only the number
of subscribers changes between the points.

Per point, over a window of ``--seconds`` after the new clients run and every axis is powered:

* CPU [% of one core] of the nc-server process and of its publisher children (the active one and the
  standby; /proc/<pid>/stat utime + stime of all threads, over the window), their sum, and the mean plc-run;
* the NC's missed cycles and the frames its publisher skipped (``nc/<nc>/stats`` counters);
* the machine's busy share over the window (/proc/stat, every process).

Then the ratios of the same run: the NC's (process + publisher) CPU at N subscribers over its CPU at 1, and
the cost of one more subscriber ((CPU at N - CPU at 0) / N). Issue 19 sets no goal for this point (figures
only: the closing note's); it says what the per-client selection of the status frame costs the NC.

    .venv/bin/python bench/subscribers.py [--subscribers 0 1 4 16] [--seconds 8] [--axes 64]
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from bench.common import REPO, Busy, ProcCpu, children, start_nc, stop_processes, use_this_tree, verdict  # noqa: E402

use_this_tree()
from bench.many_clients import AXES_PER_CLIENT, AXIS_TOML, NC_NAME, PROGRAM, Stats, free_port  # noqa: E402


def run(args: argparse.Namespace) -> int:
    points = sorted(set(args.subscribers))
    n_axes = max(args.axes, AXES_PER_CLIENT * max(points))
    tmp = Path(tempfile.mkdtemp(prefix="subscribers-"))
    cfg = tmp / "nc.toml"
    cfg.write_text(f'[nc]\nname = "{NC_NAME}"\ncycle_time = 0.001\n\n[zenoh]\nmode = "router"\n'
                   + "".join(AXIS_TOML.format(id=i + 1) for i in range(n_axes)))
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    print(f"subscribers: NC {n_axes} axes at 1 ms; points {points} plc-run clients x {AXES_PER_CLIENT} powered axes "
          f"(no moves), PLC {args.plc_cycle * 1e3:g} ms; window {args.seconds:g} s per point; code under test {REPO}; "
          f"logs in {tmp}", flush=True)
    nc = start_nc(cfg, endpoint, tmp, env)
    clients: list[subprocess.Popen[Any]] = []
    stats = None
    rows: list[dict[str, Any]] = []
    try:
        stats = Stats(endpoint)
        stats.wait()
        for want in points:
            while len(clients) < want:  # one at a time (interpreters importing at once stall the running ones)
                k = len(clients)
                axes = ",".join(str(k * AXES_PER_CLIENT + j + 1) for j in range(AXES_PER_CLIENT))
                report = tmp / f"plc{k}.json"
                cenv = dict(env, MANY_AXES=axes, MANY_REPORT=str(report), MANY_STOP=str(tmp / "stop"),
                            MANY_NC=NC_NAME, MANY_HOLD="1")
                p = subprocess.Popen([sys.executable, "-m", "plc_client.cli", str(PROGRAM), "--nc", f"{NC_NAME}={endpoint}",
                                      "--client-id", f"plc{k}", "--cycle-time", str(args.plc_cycle),
                                      "--log-level", "WARNING"],
                                     stdout=subprocess.DEVNULL, stderr=open(tmp / f"plc{k}.err", "w"), env=cenv,
                                     start_new_session=True)
                clients.append(p)
                t0 = time.monotonic()
                while True:  # running and every axis powered
                    try:
                        rep = json.loads(report.read_text())
                        if all(a.get("powered") for a in rep["axes"].values()):
                            break
                    except (OSError, ValueError, KeyError):
                        pass
                    if p.poll() is not None:
                        raise RuntimeError(f"plc{k} exited with {p.returncode}: {(tmp / f'plc{k}.err').read_text()[-2000:]}")
                    if time.monotonic() - t0 > args.start_timeout:
                        raise RuntimeError(f"plc{k} not powered within {args.start_timeout:g} s")
                    time.sleep(0.05)
            time.sleep(args.settle)
            pids = {"nc": nc.pid, **{f"pub{i}": c for i, c in enumerate(children(nc.pid))},
                    **{f"plc{k}": p.pid for k, p in enumerate(clients)}}
            s0 = stats.wait()
            cpu = ProcCpu(pids)
            busy = Busy()
            time.sleep(args.seconds)
            c = cpu.stop()
            busy.stop()
            s1 = stats.wait()
            for k, p in enumerate(clients):
                if p.poll() is not None:
                    raise RuntimeError(f"plc{k} exited with {p.returncode}")
            pl = [v for name, v in c.items() if name.startswith("plc")]
            cycles = int(s1["cycle"]) - int(s0["cycle"])
            missed = int(s1["missed_cycles"]) - int(s0["missed_cycles"])
            row = {"subs": want, "nc": c["nc"], "pub": sum(v for name, v in c.items() if name.startswith("pub")),
                   "n_pub": sum(1 for name in c if name.startswith("pub")),
                   "plc": sum(pl) / len(pl) if pl else float("nan"), "busy": busy.share, "busy_text": busy.text(),
                   "missed": missed, "due": cycles + missed,
                   "dropped": int(s1["frames_dropped"]) - int(s0["frames_dropped"]),
                   "faults": int(s1["faults"]) - int(s0["faults"])}
            row["total"] = row["nc"] + row["pub"]
            rows.append(row)
            print(f"  {want:>3} subscribers: NC process {row['nc']:5.1f} %, publisher children ({row['n_pub']}) "
                  f"{row['pub']:5.1f} %, sum {row['total']:5.1f} % of a core; plc-run mean {row['plc']:.2f} %; NC missed "
                  f"{missed} of {row['due']} cycles, frames skipped {row['dropped']}, faults {row['faults']}; machine "
                  f"{busy.text()}", flush=True)
    finally:
        if stats is not None:
            stats.close()
        stop_processes(clients, nc)

    print()
    print(f"== the NC's CPU by subscribing clients (NC {n_axes} axes, 1 ms; % of one core over {args.seconds:g} s) ==")
    print(f"{'subscribers':>11} | {'NC proc':>7} {'publisher':>9} {'sum':>6} | {'sum / at 1':>10} {'per client':>10} | "
          f"{'plc-run':>7} | {'missed':>7} {'faults':>6} {'machine busy':>12}")
    base = next((r for r in rows if r["subs"] == 0), None)
    one = next((r for r in rows if r["subs"] == 1), None)
    for r in rows:
        rel = f"{r['total'] / one['total']:9.2f}x" if one and one["total"] > 0 else f"{'-':>10}"
        per = (f"{(r['total'] - base['total']) / r['subs']:9.2f} %" if base and r["subs"] else f"{'-':>10}")
        plc = f"{r['plc']:7.2f}" if r["subs"] else f"{'-':>7}"
        print(f"{r['subs']:>11} | {r['nc']:7.1f} {r['pub']:9.1f} {r['total']:6.1f} | {rel} {per} | {plc} | "
              f"{100.0 * r['missed'] / max(1, r['due']):6.2f}% {r['faults']:6d} {r['busy']:11.0f}%")
    print("(sum / at 1: the NC's CPU (process + publisher children) at N subscribers over its CPU at 1, same run; per client: "
          "(sum at N - sum at 0) / N; machine busy: /proc/stat over the window, of "
          f"{100 * (os.cpu_count() or 1)} %)")
    verdict("subscribers", [], ", ".join(f"{r['subs']}: {r['busy']:.0f} %" for r in rows) + " busy")
    return 0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--subscribers", type=int, nargs="+", default=[0, 1, 4, 16], metavar="N",
                    help="numbers of subscribing plc-run clients, each a point (default 0 1 4 16)")
    ap.add_argument("--axes", type=int, default=64, help="NC axes (at least 4 per client of the largest point; 64)")
    ap.add_argument("--seconds", type=float, default=8.0, help="window per point [s] (8)")
    ap.add_argument("--settle", type=float, default=2.0, help="wait after the clients of a point run [s] (2)")
    ap.add_argument("--plc-cycle", type=float, default=0.01, help="PLC cycle time of the clients [s] (0.01)")
    ap.add_argument("--start-timeout", type=float, default=90.0)
    return run(ap.parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
