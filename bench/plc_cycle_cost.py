"""Python cost of one PLC cycle (``PlcTask.step()``) of a representative client, in-process (issue 19).

A 4-axis program (per axis MC_Power, MC_ReadStatus, MC_ReadActualPosition every cycle; axes 1-3 an
MC_MoveAbsolute back and forth, axis 4 an MC_MoveVelocity alternating its direction) against a real
``NcCore`` through nc_sim (nc-server's own request handler, no zenoh), next to an idle task (no program,
no axes). Only ``task.step()`` is timed, and the transport's own parts are done as the zenoh runtime
does them: the status frame is taken from the bytes of an encoded frame (``decode_frame``, as
``PlcRuntime._take_frames``: ``--frame-axes`` records in it, 64 as the bench NC sends today, 4 with a
per-client selection) and the PLCTONC frame is the one the runtime sends (``PlcTask.plc_frame``; before it,
``plc_client.runtime.plc_frame``),
handed to the NC after the timed step, as are the commands the blocks send (the in-process port would run
the NC's handler inside ``send``).

    .venv/bin/python bench/plc_cycle_cost.py                  # figures: us per step p50/p99, thread CPU
    .venv/bin/python bench/plc_cycle_cost.py --profile 2000   # cProfile of 2000 cycles, top functions
    .venv/bin/python bench/plc_cycle_cost.py --tree /work/main   # also another checkout, interleaved
    .venv/bin/python bench/plc_cycle_cost.py --instructions 200 --tree /work/main  # instructions per step (valgrind)

NC 1 ms, PLC 10 ms (10 NC steps per PLC cycle, not timed).
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

WORKER = r"""
import cProfile, io, json, os, pstats, sys, time
import numpy as np
from nc_schema import encode_frame, decode_plc_frame
from nc_server.core import AxisConfig, AxisParams, NcCore
from nc_sim import InProcessPlc
from plc_client import (AXIS_REF, MC_MoveAbsolute, MC_MoveVelocity, MC_Power, MC_ReadActualPosition,
                        MC_ReadStatus)
from plc_client.runtime import plc_frame
from plc_client.task import PlcTask
NEW_FRAME = hasattr(PlcTask, "plc_frame")  # (a tree with the task's preallocated PLC frame)
BYTES_PATH = os.environ.get("PLC_FRAME_PATH") == "bytes" and hasattr(PlcTask, "_set_frame_bytes")

mode, frame_axes, cycles, profile = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4])
N_CLIENT = 4
core = NcCore([AxisConfig(i + 1, f"A{i + 1}", AxisParams()) for i in range(max(frame_axes, N_CLIENT))], 0.001)


class Axis:
    def __init__(self, k):
        self.ax = AXIS_REF(nc="nc1", axis_id=k + 1)
        self.power, self.rs, self.rp = MC_Power(), MC_ReadStatus(), MC_ReadActualPosition()
        self.velo = k == 3
        self.move = MC_MoveVelocity() if self.velo else MC_MoveAbsolute()
        self.step, self.n, self.t = 0, 0, 0.0

    def cycle(self, plc):
        ax = self.ax
        p = self.power(Axis=ax, Enable=True, Enable_Positive=True, Enable_Negative=True)
        self.rs(Axis=ax, Enable=True)
        self.rp(Axis=ax, Enable=True)
        if self.step == 0:
            if p.Status:
                self.step, self.n, self.t = 10, self.n + 1, plc.now
            self.move(Axis=ax, Execute=False)
        elif self.velo:
            m = self.move(Axis=ax, Execute=True, Velocity=50.0, Direction=1 if self.n % 2 else 3)
            if m.Error or m.CommandAborted or plc.now - self.t > 0.5:
                self.step = 0
        else:
            m = self.move(Axis=ax, Execute=True, Position=40.0 * (self.n % 2), Velocity=100.0)
            if m.Done or m.Error or m.CommandAborted:
                self.step = 0


axes = [Axis(k) for k in range(N_CLIENT)] if mode in ("prog", "bound") else []


def program(plc):
    for a in axes:
        a.cycle(plc)


if mode == "many":  # plc-run's program of bench/plc_cpu.py (MC_Power + MC_MoveAbsolute on 4 axes)
    import importlib.util, tempfile
    _tmp = tempfile.mkdtemp(prefix="plc-cost-")
    os.environ.update(MANY_AXES="1,2,3,4", MANY_REPORT=os.path.join(_tmp, "r.json"),
                      MANY_STOP=os.path.join(_tmp, "stop"))
    _spec = importlib.util.spec_from_file_location("many_prog", os.path.join(os.getcwd(), "bench",
                                                                             "many_clients_program.py"))
    _mod = importlib.util.module_from_spec(_spec)
    _spec.loader.exec_module(_mod)
    _prog = _mod.Program()
    axes = _prog.axes
    program = _prog.cycle
    mode = "prog"


class Bench(InProcessPlc):
    def _take_frames(self):  # as PlcRuntime._take_frames: a frame's bytes decoded
        if BYTES_PATH:  # (--frame-path bytes: the task takes the bytes itself, no numpy)
            self._set_frame_bytes(self.nc, self.wire)
            return
        from nc_schema import decode_frame
        h, recs, jobs = decode_frame(self.wire)
        self._set_frame(self.nc, int(h["Cycle"]), recs, jobs)

    def _publish(self, nc, axes):  # as PlcRuntime._publish; the frame is handed to the NC after the timed step
        frame = bytes(self.plc_frame(nc, axes)) if NEW_FRAME else plc_frame(self.cycle, axes)
        self.out = (frame, axes)


plc = Bench(core, program if mode == "prog" else None, axes=[a.ax for a in axes])  # bound: axes, no program
# requests reach the NC after the timed step (a real client's send is a zenoh get: the NC's work is not the PLC's)
_sent = []
_transmit = plc.port._transmit
plc.port._transmit = lambda pending, payload: _sent.append((pending, payload))


def wire():
    c = core
    sel = slice(0, frame_axes)
    plc.wire = encode_frame(c.cycle, 0, c.nctoplc[sel], jobs=c.ncjobs[sel])


def nc_side():
    while _sent:
        _transmit(*_sent.pop(0))
    out = getattr(plc, "out", None)
    if out is not None:
        frame, ax = out
        _, recs = decode_plc_frame(frame)
        InProcessPlc._publish(plc, "nc1", ax)
        plc.out = None
    for _ in range(10):
        core.step()


def run(n, timed):
    wall, cpu = [], []
    pc, tt = time.perf_counter_ns, time.thread_time_ns
    for _ in range(n):
        wire()
        if timed:
            w0, c0 = pc(), tt()
            plc.step()
            cpu.append(tt() - c0)
            wall.append(pc() - w0)
        else:
            plc.step()
        nc_side()
    return wall, cpu


run(300 if profile >= 0 else 80, False)  # powered, moving
if profile < 0:  # under callgrind (--instructions): the steps run inside operator.call, the only code it counts
    import operator
    for _ in range(-profile):
        wire()
        operator.call(plc.step)
        nc_side()
    print(json.dumps({"cycles": -profile, "moves": sum(getattr(a, "n", 0) or getattr(a, "k", 0) for a in axes)}))
    sys.exit(0)
if profile:
    pr = cProfile.Profile(time.thread_time_ns, 1e-9)
    orig = plc.step
    def step():
        pr.enable(); orig(); pr.disable()
    plc.step = step
    run(profile, False)
    s = io.StringIO()
    pstats.Stats(pr, stream=s).sort_stats("tottime").print_stats(35)
    print(s.getvalue())
    s = io.StringIO()
    pstats.Stats(pr, stream=s).sort_stats("cumulative").print_stats(40)
    print(s.getvalue())
    sys.exit(0)
wall, cpu = run(cycles, True)
wall.sort(); cpu.sort()
q = lambda v, f: v[min(len(v) - 1, int(f * len(v)))] / 1000
print(json.dumps({"p50": q(wall, 0.5), "p99": q(wall, 0.99), "cpu_mean": sum(cpu) / len(cpu) / 1000,
                  "cpu_p50": q(cpu, 0.5), "moves": sum(getattr(a, "n", 0) or getattr(a, "k", 0) for a in axes)}))
"""


def run(tree: str, mode: str, frame_axes: int, cycles: int, profile: int = 0) -> str:
    env = dict(os.environ, PYTHONPATH=tree)
    return subprocess.run([sys.executable, "-c", WORKER, mode, str(frame_axes), str(cycles), str(profile)], env=env,
                          cwd=tree, capture_output=True, text=True, check=True).stdout


def instructions(tree: str, mode: str, frame_axes: int, cycles: int) -> float:
    """Instructions per PLC step (valgrind's callgrind, counting only inside the steps): what a step costs,
    whatever else the machine runs (thread CPU times on a loaded machine vary by 2x and more)."""
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "cg.out"
        subprocess.run(["valgrind", "--tool=callgrind", "--toggle-collect=_operator_call", f"--callgrind-out-file={out}",
                        sys.executable, "-c", WORKER, mode, str(frame_axes), "0", str(-cycles)],
                       env=dict(os.environ, PYTHONPATH=tree), cwd=tree, capture_output=True, text=True, check=True)
        for line in out.read_text().splitlines():
            if line.startswith(("summary:", "totals:")):
                return int(line.split()[1]) / cycles
    raise RuntimeError("callgrind wrote no totals")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--tree", help="another checkout to measure in the same run")
    ap.add_argument("--frame-axes", default="64,4", help="records per status frame (comma list)")
    ap.add_argument("--cycles", type=int, default=3000)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--modes", default="prog,idle", help="prog (the 4-axis program), idle (no program, no axes), bound "
                    "(the 4 axes bound, no program), many (bench/many_clients_program.py, plc_cpu.py's program)")
    ap.add_argument("--profile", type=int, default=0, help="cProfile this many cycles (program, first frame size)")
    ap.add_argument("--frame-path", choices=("decode", "bytes"), default="decode",
                    help="decode: decode_frame + _set_frame (what PlcRuntime does); bytes: PlcTask._set_frame_bytes "
                         "(where the tree has it)")
    ap.add_argument("--instructions", type=int, default=0, metavar="CYCLES",
                    help="instead: instructions per step under valgrind (callgrind), CYCLES steps per mode and tree")
    a = ap.parse_args()
    os.environ["PLC_FRAME_PATH"] = a.frame_path
    here = str(Path(__file__).resolve().parents[1])
    sizes = [int(x) for x in a.frame_axes.split(",")]
    trees0 = [("this", here)] + ([("other", a.tree)] if a.tree else [])
    if a.instructions:
        print(f"instructions per PLC step (callgrind, {a.instructions} steps each; load-independent)")
        for n in sizes:
            for mode in a.modes.split(","):
                for name, tree in trees0:
                    print(f"{name:6} {mode:6} frame {n:3d}: {instructions(tree, mode, n, a.instructions) / 1e3:9.1f} k",
                          flush=True)
        return
    if a.profile:
        print(run(here, a.modes.split(",")[0], sizes[0], 0, a.profile))
        return
    trees = [("this", here)] + ([("other", a.tree)] if a.tree else [])
    best: dict[tuple[str, str, int], dict[str, float]] = {}
    for _ in range(a.rounds):
        for n in sizes:
            for mode in a.modes.split(","):
                for name, tree in trees:
                    r = json.loads(run(tree, mode, n, a.cycles))
                    k = (name, mode, n)
                    if k not in best or r["cpu_mean"] < best[k]["cpu_mean"]:
                        best[k] = r
    print(f"us per PLC step (best of {a.rounds} rounds by mean thread CPU; {a.cycles} cycles each)")
    print(f"{'tree':6} {'program':6} {'frame':>5} {'p50':>8} {'p99':>8} {'cpu mean':>9} {'cpu p50':>8}")
    for (name, mode, n), r in best.items():
        print(f"{name:6} {mode:6} {n:5d} {r['p50']:8.1f} {r['p99']:8.1f} {r['cpu_mean']:9.1f} {r['cpu_p50']:8.1f}")
    for n in sizes:
        for name, _ in trees:
            if (name, "prog", n) not in best or (name, "idle", n) not in best:
                continue
            p, i = best[(name, "prog", n)], best[(name, "idle", n)]
            print(f"{name} frame {n}: program / idle (cpu mean) = {p['cpu_mean'] / i['cpu_mean']:.1f}x")


if __name__ == "__main__":
    main()
