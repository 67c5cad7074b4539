"""PLC cycle cost of the axis snapshot: ``PlcTask.step()`` with N bound axes and a program that reads a
few NCTOPLC members of each (no transport: the frame is set in memory), next to the same measurement of
another checkout (``--tree DIR``, e.g. the main branch before attribute access) in the same run.

    .venv/bin/python bench/plc_snapshot.py                      # this tree
    .venv/bin/python bench/plc_snapshot.py --tree /work/main    # and another checkout, interleaved

Prints us per PLC cycle (best of ``--rounds``, interleaved) for each N; ratios against the other tree.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

WORKER = r"""
import json, sys, time
import numpy as np
from nc_schema import NCTOPLC_DTYPE
from plc_client import AXIS_REF
from plc_client.task import PlcTask
from plc_client.port import CommandPort

n, cycles, style = int(sys.argv[1]), int(sys.argv[2]), sys.argv[3]
axes = [AXIS_REF(nc="nc1", axis_id=i + 1) for i in range(n)]
attr = style == "attr" and hasattr(type(axes[0].NcToPlc), "SetPos")

def program(plc):
    s = 0.0
    for ax in axes:
        r = ax.NcToPlc
        if attr:
            s += r.SetPos + r.SetVelo + r.ActPos + r.StateDWord
        else:
            s += float(r["SetPos"]) + float(r["SetVelo"]) + float(r["ActPos"]) + int(r["StateDWord"])

recs = np.zeros(n, dtype=NCTOPLC_DTYPE)
recs["AxisId"] = np.arange(1, n + 1)
task = PlcTask(program, client_id="bench")
class _NoPort(CommandPort):
    def _transmit(self, pending, payload):  # the program sends nothing
        pass

task.port = _NoPort("bench")
for ax in axes:
    task.register(ax)
k = [0]
def take():
    k[0] += 1
    recs["SetPos"] += 0.001
    task._set_frame("nc1", k[0], recs)
task._take_frames = take
for _ in range(200):
    task.step()
t0 = time.perf_counter()
for _ in range(cycles):
    task.step()
print(json.dumps((time.perf_counter() - t0) / cycles * 1e6))
"""


def run(tree: str, n: int, cycles: int, style: str) -> float:
    env = dict(os.environ, PYTHONPATH=tree)
    out = subprocess.run([sys.executable, "-c", WORKER, str(n), str(cycles), style], env=env, cwd=tree,
                         capture_output=True, text=True, check=True).stdout
    return float(json.loads(out))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--tree", help="another checkout to measure in the same run")
    ap.add_argument("--axes", default="4,64,256")
    ap.add_argument("--cycles", type=int, default=2000)
    ap.add_argument("--rounds", type=int, default=5)
    a = ap.parse_args()
    here = str(Path(__file__).resolve().parents[1])
    trees = [("this", here)] + ([("other", a.tree)] if a.tree else [])
    print("PlcTask.step() with N bound axes, program reading SetPos/SetVelo/ActPos/StateDWord of each [us/cycle]")
    for n in (int(x) for x in a.axes.split(",")):
        res: dict[str, list[float]] = {}
        for _ in range(a.rounds):  # interleaved: both trees see the same machine load
            for name, tree in trees:
                res.setdefault(f"{name} item", []).append(run(tree, n, a.cycles, "item"))
                if name == "this":
                    res.setdefault("this attr", []).append(run(tree, n, a.cycles, "attr"))
        med = {k: min(v) for k, v in res.items()}  # the least disturbed round (a shared machine)
        line = "  ".join(f"{k}: {v:8.1f}" for k, v in med.items())
        if "other item" in med:
            line += f"   this attr / other item = {med['this attr'] / med['other item']:.2f}"
        print(f"N={n:4d}  {line}")


if __name__ == "__main__":
    main()
