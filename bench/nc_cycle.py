"""NC cycle cost, new engine vs the baseline engine vs a noise floor, in one run.

Three kinds of worker process, each started once and driven point by point (only one measures at
a time; the others wait idle on stdin):

  * ``new``: the engine in this working tree;
  * ``old``: the engine of ``--baseline REV`` (default 9ead11a, the last commit before the engine
    rewrite), from a git worktree cached in bench/.cache/ (created on first use, reused after),
    imported through PYTHONPATH (``nc_schema`` is the worktree's top-level ``nc_schema/`` if it has
    one, else a symlink to its ``schema/``, as pyproject's package-dir maps it);
  * ``floor``: the same cycle loop (this tree's ``CycleLoop``, same scheduling and interpreter
    settings) running a fixed synthetic numpy workload (bench/noise_floor.py): what the machine
    gives a cycle of known cost at that moment.

Both engines run this same file's measurement code:

  * the real ``NcServer``: its ``CycleLoop`` (SCHED_FIFO if permitted, sleep + spin), the core,
    the real zenoh session (router on a free 127.0.0.1 port), the frame publisher (a child
    process) putting the batched frame every cycle and per-axis NCTOPLC samples for the subscribed axes;
  * a subscriber process (client mode) taking the frame and the per-axis samples of 4 axes;
  * every axis enabled (PLCTONC preset in the core: no claims) and moving, under three loads:
    ``quiet``: continuous motion (MoveVelocity), no commands: the cycle itself;
    ``stress``: long MoveAbsolute profiles plus one command every cycle (1000 commands/s, round
    robin over the axes), each axis cycling through re-target (MoveAbsolute Aborting), MC_Buffered
    (BufferMode 1) behind the running move, MC_NewPos, re-target, MC_BlendingNext (BufferMode 20),
    MC_NewPosAndVelo (Mode 1 / 3). Each command is parsed (``nc_schema.parse_request``), executed
    (``core.execute``) and its reply packed inside the cycle, as the server does with a request;
    the time is part of the measured work. A probe at worker start finds which kinds each engine
    accepts (0x4B64 BufferMode refused, 0x701/0x706 unknown command or field: not supported);
    unsupported kinds are replaced by re-targets (the load stays 1000 commands/s) and the report
    says which kinds each engine actually ran. When the engines differ, ``stress-common`` (only
    the kinds both support) is measured too at 256 axes, for a like-for-like ratio;
    ``coupled``: linear gearing, at ``--coupled-axes`` only (default 384; not at ``--axes``): with N
    axes, P = N // 3 master/slave pairs (rows 2k master, 2k+1 slave, k < P) and the rows >= 2P
    single axes. At standstill every slave is coupled (GearIn to its master's AxisId, sent to the
    slave; ratio by k mod 4: 1/2, -1/1, 1/2, 3/2), then every master and single axis is started
    with MoveVelocity as under ``quiet``; no commands during the window: the cycle with P slaves
    following their masters (the coupling stage). At 384 axes: 128 pairs + 128 single axes. The
    slaves stay within BENCH_PARAMS: |SetVelo| <= 1.5 x 102 = 153 < AxisVeloMax 1000, |SetAcc| <= 1.5 x
    the masters' jerk-limited peak sqrt(v x AxisJerk) ~ 2.3e3 -> 3.4e3 < AxisAcc 5000. The worker's
    probe also tries GearIn (a slave at 1/2 must follow its started master at half its velocity):
    an engine without it (the baseline: no gearing) is not run at this point and the report says
    so; the point is then new vs floor only.

Runs are interleaved: round 1 runs every point as new, old, floor; round 2 as old, new, floor;
figures are taken over all rounds of a point (an engine a point does not apply to is left out of
its order). The whole run is bounded by ``--budget``: a point that does not fit is skipped and listed.

Measured by the loop itself: work time per cycle (drain, PLCTONC, watchdog, command, core.step,
encode_frame, hand-off) and start lateness; p50/p99/max in us; missed cycles and overruns. If the
engine shows its lookahead refills (a public ``refill_rows`` after each step, or the old engine's
``_buf_k``/``_lookahead``), refill cycles are counted and their p99 shown apart; always shown: the
strongest period in the step times (a p99 driven by every L-th cycle). 'moving' counts the axes
with |SetVelo| > 0 at the end of the window (coupled slaves included), 'start rejected' the start
commands (MoveVelocity, GearIn, first re-target) an engine refused: a valid point has none.

Goals (issue 19; not tests), as ratios to the same run's floor (the absolute microseconds beside them):
quiet work p99 / floor p99 at 64 moving axes <= 1.5x, at 1024 <= 2x, coupled 384 (128 pairs + 128 single
axes) <= 2x; a summary prints each with MET / NOT MET (NOT MEASURED when the point was not run: not in
``--axes``, or skipped by ``--budget``), and the machine's busy share (/proc/stat, every process) during the
new engine's and the floor's windows of that point. Every run set's busy share is in the details table.

    .venv/bin/python bench/nc_cycle.py [--seconds 1.5] [--rounds 2] [--axes 8 64 256 1024]
                                       [--loads quiet stress coupled] [--coupled-axes 384]
                                       [--baseline 9ead11a | none] [--budget 200]
"""
from __future__ import annotations

import argparse
import json
import os
import queue
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np

BENCH = Path(__file__).resolve().parent
REPO = BENCH.parent
CACHE = BENCH / ".cache"
DEFAULT_BASELINE = "9ead11a"

#: (load, axes) -> goal on the new engine's p99 work / the same run's floor p99 work (issue 19)
GOALS = {("quiet", 64): 1.5, ("quiet", 1024): 2.0, ("coupled", 384): 2.0}
LOADS = ("quiet", "stress", "coupled")
#: Engine features a load needs beyond the stress kinds (found by probe_features at worker start).
LOAD_NEEDS = {"coupled": "gearin"}
FEATURE_TEXT = {"gearin": "GearIn"}
#: (RatioNumerator, RatioDenominator) of pair k under the coupled load: COUPLED_RATIOS[k % 4].
COUPLED_RATIOS = ((1, 2), (-1, 1), (1, 2), (3, 2))
KINDS = ("retarget", "buffered", "blending_next", "new_pos", "new_pos_velo")
KIND_TEXT = {"retarget": "MoveAbsolute Aborting", "buffered": "MoveAbsolute MC_Buffered",
             "blending_next": "MoveAbsolute MC_BlendingNext", "new_pos": "NewPos", "new_pos_velo": "NewPosAndVelo"}
#: Each axis's command sequence under the stress load (one command per cycle, round robin over the axes).
MIX = ("retarget", "buffered", "new_pos", "retarget", "blending_next", "new_pos_velo")
#: Probe replies meaning "this engine does not have that command kind".
UNSUPPORTED = {0x4B64: "BufferMode refused", 0x0701: "unknown command", 0x0706: "refused on parse",
               0x4000: "internal error"}
PROTO = "@@"


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


# =============================================================================================
# Worker side (runs in a subprocess; imports the engine under test from its PYTHONPATH)
# =============================================================================================

SUBSCRIBER = r"""
import json, sys, time, zenoh
port = int(sys.argv[1])
c = zenoh.Config()
c.insert_json5("mode", '"client"')
c.insert_json5("connect/endpoints", json.dumps([f"tcp/127.0.0.1:{port}"]))
c.insert_json5("scouting/multicast/enabled", "false")
c.insert_json5("scouting/gossip/enabled", "false")
n = {"frame": 0, "axis": 0}
for attempt in range(100):  # the router may still be starting (a big NC takes a moment to build)
    try:
        session = zenoh.open(c)
        break
    except zenoh.ZError:
        if attempt == 99:
            raise
        time.sleep(0.1)
with session as s:
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

BENCH_PARAMS = dict(AxisVeloMax=1000.0, AxisAcc=5000.0, AxisDec=5000.0, AxisJerk=50000.0,
                    AxisEnPositionLagMonitoring=False)


def machine_ticks() -> tuple[int, int]:
    """(busy, total) clock ticks of all CPUs since boot (/proc/stat; busy = total - idle - iowait)."""
    try:
        f = [int(x) for x in Path("/proc/stat").read_text().split("\n", 1)[0].split()[1:]]
    except (OSError, ValueError):
        return 0, 0
    total = sum(f[:8])
    return total - f[3] - f[4], total


def busy_share(m0: tuple[int, int], m1: tuple[int, int]) -> float:
    """The machine's busy share between two machine_ticks() [% of one core; 100 x CPUs = all busy]."""
    return 100.0 * (os.cpu_count() or 1) * (m1[0] - m0[0]) / max(1, m1[1] - m0[1])


def _emit(tag: str, obj: Any) -> None:
    sys.stdout.write(f"{PROTO}{tag} {json.dumps(obj)}\n")
    sys.stdout.flush()


def _requests(n_axes: int) -> dict[str, list[tuple[bytes, bytes]]]:
    """Packed requests per kind and axis row: (for sign +1, for sign -1)."""
    from nc_schema import pack

    def move(pos: float, velo: float, mode: int) -> dict[str, Any]:
        return {"cmd": "MoveAbsolute", "Position": pos, "Velocity": velo, "Acceleration": 0.0,
                "Deceleration": 0.0, "Jerk": 0.0, "BufferMode": mode}

    out: dict[str, list[tuple[bytes, bytes]]] = {k: [] for k in KINDS}
    for i in range(n_axes):
        v = 100.0 + (i % 4) * 100.0
        for kind in KINDS:
            pair = []
            for s in (1.0, -1.0):
                if kind == "retarget":
                    m = move(1000.0 * s, v, 0)
                elif kind == "buffered":
                    m = move(-1000.0 * s, 200.0, 1)
                elif kind == "blending_next":
                    m = move(-1000.0 * s, 200.0, 20)
                elif kind == "new_pos":
                    m = {"cmd": "NewPos", "NewPos": 900.0 * s}
                else:
                    m = {"cmd": "NewPosAndVelo", "Mode": 1 if i % 2 else 3, "NewPos": 800.0 * s,
                         "NewVelo": 150.0 + (i % 4) * 50.0, "ActivationPos": 0.0}
                pair.append(pack({"id": 1_000_000 + i, **m}))
            out[kind].append((pair[0], pair[1]))
    return out


def _make_core(n_axes: int):  # type: ignore[no-untyped-def]
    from nc_server.core import AxisConfig, AxisParams, NcCore
    params = AxisParams(**BENCH_PARAMS)
    axes = tuple(AxisConfig(AxisId=i + 1, Name=f"A{i + 1}", params=params) for i in range(n_axes))
    core = NcCore(list(axes), cycle_time=0.001)
    enabled = core.default_plctonc()
    enabled["ControlDWord"] = 0x7  # Enable, FeedEnablePlus, FeedEnableMinus
    for i in range(n_axes):
        core.set_plctonc(i, enabled)
    core.step()
    return axes, core


def _run_request(core, payload: bytes, axis_id: int) -> dict[str, Any]:  # type: ignore[no-untyped-def]
    from nc_schema import NcError, pack, parse_request
    try:
        req = parse_request(payload)
    except NcError as err:
        return {"error": int(err.code)}
    reply = core.execute(req, axis_id)
    pack(reply)
    return reply


def probe() -> dict[str, Any]:
    """Which stress command kinds this engine accepts: each kind sent once behind a running move."""
    reqs = _requests(1)
    res: dict[str, Any] = {}
    for kind in KINDS:
        try:
            _, core = _make_core(1)
            r0 = _run_request(core, reqs["retarget"][0][0], 1)
            for _ in range(20):
                core.step()
            # the kind as the stress sends it after that re-target (same direction: index 0)
            r = _run_request(core, reqs[kind][0][0], 1) if kind != "retarget" else r0
            code = int(r.get("error", 0))
            res[kind] = {"code": code, "supported": code not in UNSUPPORTED,
                         "text": str(r.get("text", ""))[:160]}
        except Exception as exc:  # an engine without the command path: not supported
            res[kind] = {"code": -1, "supported": False, "text": f"{exc.__class__.__name__}: {exc}"[:160]}
    return res


def _velocity_request(i: int, req_id: int) -> bytes:
    """The quiet load's MoveVelocity of axis row i (also the coupled load's masters and single axes)."""
    from nc_schema import pack
    return pack({"id": req_id, "cmd": "MoveVelocity", "Velocity": 100.0 + i % 4, "Acceleration": 0.0,
                 "Deceleration": 0.0, "Jerk": 0.0, "Direction": 1 if i % 2 else 3, "BufferMode": 0})


def _gear_in_request(master_id: int, num: int, den: int, req_id: int) -> bytes:
    from nc_schema import pack
    return pack({"id": req_id, "cmd": "GearIn", "Master": master_id, "RatioNumerator": num, "RatioDenominator": den})


def probe_features() -> dict[str, Any]:
    """Features a load needs (LOAD_NEEDS): 'gearin': axis 2 coupled to axis 1 at 1/2 at standstill, then axis 1
    started as the coupled load starts a master; supported if GearIn is accepted and after 300 cycles the slave
    moves at half the master's velocity."""
    res: dict[str, Any] = {}
    try:
        _, core = _make_core(2)
        r = _run_request(core, _gear_in_request(1, 1, 2, 1), 2)
        code, text = int(r.get("error", 0)), str(r.get("text", ""))[:160]
        ok = code == 0
        if ok:
            r = _run_request(core, _velocity_request(0, 2), 1)
            for _ in range(300):
                core.step()
            vm, vs = (float(v) for v in np.asarray(core.axes.set_velo)[:2])
            ok = int(r.get("error", 0)) == 0 and abs(vm) > 1.0 and abs(vs - 0.5 * vm) <= 1e-6 * abs(vm)
            if not ok:
                text = f"GearIn accepted but the slave does not follow: SetVelo master {vm:g}, slave {vs:g}"
        res["gearin"] = {"code": code, "supported": ok, "text": text}
    except Exception as exc:  # an engine without that path: not supported
        res["gearin"] = {"code": -1, "supported": False, "text": f"{exc.__class__.__name__}: {exc}"[:160]}
    return res


def refill_hook(core):  # type: ignore[no-untyped-def]
    """A function returning the lookahead rows refilled by the last step (-1 unknown), and a label."""
    if hasattr(core, "refill_rows"):
        return (lambda: int(core.refill_rows)), "public refill_rows"
    # a refill counter on the core or on one of its parts (e.g. a profile stage's ``refills``)
    for name, obj in [("core", core), *sorted(vars(core).items())]:
        if isinstance(getattr(obj, "refills", None), int) and not isinstance(getattr(obj, "refills"), bool):
            last = [int(obj.refills)]

            def counter(obj=obj, last=last) -> int:  # type: ignore[no-untyped-def]
                now = int(obj.refills)
                d, last[0] = now - last[0], now
                return d
            return counter, f"counter {name}.refills" if name != "core" else "counter core.refills"
    if hasattr(core, "_buf_k") and hasattr(core, "_lookahead"):
        n = len(core.axis_ids)
        if int(core._lookahead) <= 1:
            return (lambda: n), "lookahead 1: every cycle"
        # _fill_buffer resets _buf_k to 0; the step then takes column 0 -> _buf_k == 1 after a refill
        return (lambda: n if core._buf_k == 1 else 0), f"_buf_k/_lookahead (lookahead {int(core._lookahead)})"
    return None, "not exposed"


class Mover:
    """Keeps every axis moving; runs inside the cycle (wraps NcServer.cycle)."""

    def __init__(self, server, core, load: str, kinds: list[str]) -> None:  # type: ignore[no-untyped-def]
        from nc_server.server.cycle import RING
        self.RING = RING
        self.core = core
        self.stress = load == "stress"
        self.coupled = load == "coupled"
        self.n = len(core.axis_ids)
        self.ids = [int(a) for a in core.axis_ids]
        self.mix = [k if k in kinds else "retarget" for k in MIX]
        self.reqs = _requests(self.n) if self.stress else {}
        self.step_ns = np.zeros(RING, dtype=np.int64)
        self.exec_ns = np.zeros(RING, dtype=np.int64)
        self.refill = np.zeros(RING, dtype=np.int32)
        self.cycles = 0
        self.k = 0
        self.count = [0] * self.n
        self.sign = [1] * self.n
        self.sent: Counter[str] = Counter()
        self.rejected: Counter[str] = Counter()
        self.codes: Counter[str] = Counter()
        self.texts: dict[str, str] = {}  # the first reply text per rejection kind:code
        self.start_rejected = 0
        self.start_codes: Counter[str] = Counter()  # refused start commands by "command:0xCODE"
        self.start_texts: dict[str, str] = {}
        self.pairs = self.n // 3 if self.coupled else 0
        probe_refill, self.refill_label = refill_hook(core)
        step = core.step
        ring_step, ring_refill = self.step_ns, self.refill

        def timed_step(nc_time_ns: int | None = None) -> None:
            t0 = time.perf_counter_ns()
            step(nc_time_ns)
            k = self.cycles % RING
            ring_step[k] = time.perf_counter_ns() - t0
            if probe_refill is not None:
                ring_refill[k] = probe_refill()

        self.has_refill = probe_refill is not None
        core.step = timed_step  # type: ignore[method-assign]
        self.inner = server.cycle
        server.loop.work = self.cycle

    def command(self, i: int) -> None:
        kind = self.mix[self.count[i] % len(self.mix)]
        self.count[i] += 1
        if kind == "retarget":
            self.sign[i] = -self.sign[i]
        payload = self.reqs[kind][i][0 if self.sign[i] > 0 else 1]
        r = _run_request(self.core, payload, self.ids[i])
        self.sent[kind] += 1
        if r["error"]:
            self.rejected[kind] += 1
            key = f"{kind}:0x{int(r['error']):04X}"
            self.codes[key] += 1
            self.texts.setdefault(key, str(r.get("text", ""))[:200])

    def _start(self, what: str, payload: bytes, i: int) -> None:
        r = _run_request(self.core, payload, self.ids[i])
        if r["error"]:
            self.start_rejected += 1
            key = f"{what}:0x{int(r['error']):04X}"
            self.start_codes[key] += 1
            self.start_texts.setdefault(key, f"axis {self.ids[i]}: " + str(r.get("text", ""))[:200])

    def start_all(self) -> None:
        # coupled: every slave (row 2k+1) geared to its master (row 2k) at standstill, before anything moves
        for k in range(self.pairs):
            num, den = COUPLED_RATIOS[k % len(COUPLED_RATIOS)]
            self._start("GearIn", _gear_in_request(self.ids[2 * k], num, den, -self.n - k - 1), 2 * k + 1)
        for i in range(self.n):
            if self.stress:
                self.sign[i] = -1  # the first re-target flips it to +1
                self.count[i] = 0
                self.command(i)
            elif not (i < 2 * self.pairs and i % 2):  # quiet; coupled: the masters and the single axes
                self._start("MoveVelocity", _velocity_request(i, -i - 1), i)
        if self.stress:
            self.start_rejected = sum(self.rejected.values())
            self.start_codes.update(self.codes)
            self.start_texts.update(self.texts)
        self.sent.clear()
        self.rejected.clear()
        self.codes.clear()
        self.texts.clear()

    def cycle(self, deadline_ns: int) -> None:
        t0 = time.perf_counter_ns()
        if self.stress:
            self.command(self.k % self.n)
            self.k += 1
        self.exec_ns[self.cycles % self.RING] = time.perf_counter_ns() - t0
        self.inner(deadline_ns)
        self.cycles += 1


def _window(arr: np.ndarray, c0: int, c1: int, ring: int) -> np.ndarray:
    """Ring entries recorded for cycles c0..c1-1 (the newest ``ring`` at most)."""
    c0 = max(c0, c1 - ring)
    return arr[np.arange(c0, c1) % ring].copy()


def _r1(a: np.ndarray) -> list[float]:
    return np.round(np.asarray(a, dtype=np.float64), 1).tolist()


def run_engine(n_axes: int, load: str, seconds: float, warmup: float, realtime: str,
               kinds: list[str]) -> dict[str, Any]:
    from nc_server.server.app import NcServer
    from nc_server.server.config import ServerConfig, ZenohSettings
    from nc_server.server.cycle import RING

    port = free_port()
    t_build = time.perf_counter()
    sub: subprocess.Popen[str] | None = None
    try:
        axes, core = _make_core(n_axes)
        cfg = ServerConfig(name="bench", cycle_time=0.001, watchdog_timeout=0.5, realtime=realtime,
                           zenoh=ZenohSettings("router", (f"tcp/127.0.0.1:{port}",), (), 1000), axes=axes)
        server = NcServer(cfg, core)
        mover = Mover(server, core, load, kinds)
        mover.start_all()
        build_s = time.perf_counter() - t_build
        base_cycle = core.cycle  # the loop's cycle c (its stats entry c, Mover call c) steps to base + c + 1
        sub = subprocess.Popen([sys.executable, "-c", SUBSCRIBER, str(port)], stdin=subprocess.PIPE,
                               stdout=subprocess.PIPE, text=True, start_new_session=True)
        server.start()
        try:
            assert sub.stdout is not None and sub.stdin is not None
            if sub.stdout.readline().strip() != "ready":
                raise RuntimeError("subscriber did not start")
            time.sleep(warmup)  # connection, first puts of new publishers, matching
            st = server.loop.stats
            c0, m0, o0, d0 = st.cycles, st.missed_cycles, st.overruns, server.stats()["frames_dropped"]
            sub.stdin.write("go\n")
            sub.stdin.flush()
            b0 = machine_ticks()
            time.sleep(seconds)
            b1 = machine_ticks()
            c1, m1, o1, d1 = st.cycles, st.missed_cycles, st.overruns, server.stats()["frames_dropped"]
            k0, k1 = max(c0, c1 - RING), c1  # Mover's rings are indexed like the loop's (written first)
            sent, rejected, codes = dict(mover.sent), dict(mover.rejected), dict(mover.codes)
            sub.stdin.write("stop\n")
            sub.stdin.flush()
            got = json.loads(sub.stdout.readline())
            # moving: |SetVelo| > 0 (a coupled slave has a job but no plan: count what it does, not what it has)
            set_velo = getattr(getattr(core, "axes", None), "set_velo", None)
            moving = int(np.count_nonzero(np.abs(np.asarray(set_velo)) > 0)) if set_velo is not None else int(
                np.count_nonzero(core.moving))
            slaves = synchron = 0
            if mover.coupled:
                cpl = core.coupling
                slaves = int(np.count_nonzero(np.asarray(cpl.master) >= 0))
                from nc_schema import AxisState
                synchron = int(np.count_nonzero(np.asarray(cpl.state) == int(AxisState.SLAVE_SYNCHRON)))
            out = {"axes": n_axes, "load": load, "timing": st.timing, "cycles": c1 - c0, "missed": m1 - m0,
                   "busy": busy_share(b0, b1),
                   "overruns": o1 - o0, "frames_dropped": d1 - d0, "moving": moving, "build_s": round(build_s, 3),
                   "work": _r1(_window(st.work_us, k0, k1, RING)), "late": _r1(_window(st.lateness_us, k0, k1, RING)),
                   "step": _r1(_window(mover.step_ns, k0, k1, RING) / 1000.0),
                   "exec": _r1(_window(mover.exec_ns, k0, k1, RING) / 1000.0),
                   "core_cycle0": int(base_cycle) + k0 + 1,
                   "refill": _window(mover.refill, k0, k1, RING).tolist() if mover.has_refill else None,
                   "refill_label": mover.refill_label, "sub_frames": got["frame"], "sub_axis_samples": got["axis"],
                   "start_rejected": mover.start_rejected, "start_codes": dict(mover.start_codes),
                   "start_texts": dict(mover.start_texts), "pairs": mover.pairs, "slaves": slaves,
                   "synchron": synchron, "sent": sent, "rejected": rejected, "codes": codes,
                   "texts": dict(mover.texts),
                   "mix": mover.mix if mover.stress else []}
        finally:
            server.stop()
        return out
    finally:
        if sub is not None:
            try:
                os.killpg(sub.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
            sub.wait(10)


def worker_main(role: str, root: str | None, realtime: str) -> int:
    """Serve run requests (one JSON line each on stdin) until stdin closes."""
    info: dict[str, Any] = {"role": role, "pid": os.getpid()}
    try:
        import nc_schema
        import nc_server
        if role == "floor":
            import nc_server.server.cycle  # noqa: F401  (the floor needs only the loop)
        else:
            import nc_server.core  # noqa: F401  (an engine that does not import fails here, not in a run)
            import nc_server.server.app  # noqa: F401
        info["nc_server"] = str(Path(nc_server.__file__).resolve().parent)
        info["nc_schema"] = str(Path(nc_schema.__file__).resolve().parent)
        if root is not None:
            r = Path(root).resolve()
            for name in ("nc_server", "nc_schema"):
                if not Path(info[name]).is_relative_to(r):
                    raise RuntimeError(f"{name} imported from {info[name]}, not from {r}")
        if role == "floor":
            from noise_floor import calibrate
            info["calibration"] = calibrate()
        else:
            info["probe"] = probe()
            info["features"] = probe_features()
    except Exception as exc:
        info["error"] = f"{exc.__class__.__name__}: {exc}"
        _emit("ready", info)
        return 1
    _emit("ready", info)
    for line in sys.stdin:
        if not line.strip():
            continue
        req = json.loads(line)
        try:
            if role == "floor":
                from noise_floor import run_floor
                b0 = machine_ticks()
                r = run_floor(req["seconds"], min(req["warmup"], 0.3), realtime)
                res = {"timing": r["timing"], "cycles": r["cycles"], "missed": r["missed"], "overruns": r["overruns"],
                       "work": _r1(r["work"]), "late": _r1(r["late"]), "busy": busy_share(b0, machine_ticks())}
            else:
                res = run_engine(req["axes"], req["load"], req["seconds"], req["warmup"], realtime, req["kinds"])
        except Exception as exc:
            import traceback
            traceback.print_exc()
            res = {"error": f"{exc.__class__.__name__}: {exc}"}
        _emit("result", res)
    return 0


# =============================================================================================
# Orchestrator side
# =============================================================================================

def git(*args: str, cwd: Path = REPO) -> str:
    return subprocess.run(["git", *args], cwd=cwd, check=True, capture_output=True, text=True).stdout.strip()


def rev_tree(rev: str) -> tuple[Path, str]:
    """A git worktree of ``rev`` under bench/.cache (reused when it already has that commit)."""
    sha = git("rev-parse", "--verify", f"{rev}^{{commit}}")
    CACHE.mkdir(exist_ok=True)
    path = CACHE / f"rev-{sha[:12]}"
    if path.exists():
        try:
            if git("rev-parse", "HEAD", cwd=path) == sha and not git("status", "--porcelain", "-uno", cwd=path):
                return path, sha
        except subprocess.CalledProcessError:
            pass
        subprocess.run(["git", "worktree", "remove", "--force", str(path)], cwd=REPO, capture_output=True)
        shutil.rmtree(path, ignore_errors=True)
        git("worktree", "prune")
    git("worktree", "add", "--detach", str(path), sha)
    return path, sha


def engine_pythonpath(root: Path, shim_dir: Path) -> str:
    """PYTHONPATH importing nc_server and nc_schema from ``root`` (old layout: schema/ -> nc_schema)."""
    if (root / "nc_schema" / "__init__.py").exists():
        return str(root)
    shim_dir.mkdir(parents=True, exist_ok=True)
    link = shim_dir / "nc_schema"
    if not link.exists():
        link.symlink_to(root / "schema", target_is_directory=True)
    return f"{shim_dir}{os.pathsep}{root}"


class Worker:
    """One worker subprocess; requests and replies are JSON lines."""

    def __init__(self, name: str, role: str, root: Path, pythonpath: str, realtime: str, tmp: Path) -> None:
        self.name = name
        self.root = root
        self.errlog = tmp / f"{name}.stderr"
        env = dict(os.environ, PYTHONPATH=pythonpath)
        env.pop("PYTHONHOME", None)
        self._err = open(self.errlog, "w")
        self.proc = subprocess.Popen([sys.executable, str(Path(__file__).resolve()), "--worker", role,
                                      "--root", str(root), "--realtime", realtime],
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=self._err, text=True,
                                     env=env, start_new_session=True, cwd=str(tmp))
        self.lines: queue.Queue[str | None] = queue.Queue()
        threading.Thread(target=self._read, daemon=True).start()
        self.info: dict[str, Any] = {}
        self.dead = ""

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            if line.startswith(PROTO):
                self.lines.put(line[len(PROTO):])
        self.lines.put(None)

    def _get(self, tag: str, timeout: float) -> dict[str, Any]:
        try:
            line = self.lines.get(timeout=timeout)
        except queue.Empty:
            self.kill(f"no {tag} within {timeout:.0f} s")
            raise RuntimeError(self.dead) from None
        if line is None:
            self.kill(f"exited (code {self.proc.poll()})")
            raise RuntimeError(self.dead)
        t, _, body = line.partition(" ")
        if t != tag:
            raise RuntimeError(f"{self.name}: expected {tag}, got {t}")
        return json.loads(body)

    def ready(self, timeout: float = 60.0) -> dict[str, Any]:
        self.info = self._get("ready", timeout)
        if "error" in self.info:
            self.kill(self.info["error"])
            raise RuntimeError(self.dead)
        return self.info

    def run(self, req: dict[str, Any], timeout: float) -> dict[str, Any]:
        if self.dead:
            raise RuntimeError(self.dead)
        assert self.proc.stdin is not None
        self.proc.stdin.write(json.dumps(req) + "\n")
        self.proc.stdin.flush()
        return self._get("result", timeout)

    def kill(self, why: str) -> None:
        self.dead = self.dead or why
        if self.proc.poll() is None:
            try:
                os.killpg(self.proc.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
        self.proc.wait(10)

    def close(self) -> None:
        if self.proc.poll() is None:
            try:
                assert self.proc.stdin is not None
                self.proc.stdin.close()
                self.proc.wait(15)
            except Exception:
                self.kill("closed")
        self._err.close()

    def stderr_tail(self, n: int = 15) -> str:
        try:
            return "\n".join(self.errlog.read_text(errors="replace").splitlines()[-n:])
        except OSError:
            return ""


def pct(a: np.ndarray | list[float], p: float) -> float:
    a = np.asarray(a, dtype=np.float64)
    return float(np.percentile(a, p)) if a.size else float("nan")


def period_signature(runs: list[tuple[int, np.ndarray]]) -> str:
    """The period L (2..32) whose heaviest phase (core cycle mod L) has the highest median step, if >= 2x the median.

    Engine-independent: a p99 driven by every L-th cycle (unstaggered refills) shows up here. Computed per
    run (the phase of a refill differs from run to run) and averaged over the runs.
    """
    runs = [(c0, np.asarray(st)) for c0, st in runs if len(st) >= 200]
    if not runs:
        return "-"
    med = float(np.median(np.concatenate([st for _, st in runs]))) or 1e-9
    tops: dict[int, float] = {}
    for L in range(2, 33):
        t = []
        for c0, st in runs:
            ph = (c0 + np.arange(st.size)) % L
            t.append(max(float(np.median(st[ph == k])) for k in range(L) if np.any(ph == k)))
        tops[L] = float(np.mean(t))
    best = max(tops.values())
    L = min(k for k, v in tops.items() if v >= 0.9 * best)  # the smallest period of (nearly) the highest spike
    if tops[L] < 2.0 * med:
        return f"none (no phase >= 2x the median step {med:.0f} us)"
    return f"every {L} cycles: the heaviest phase at {tops[L]:.0f} us median = {tops[L] / med:.1f}x the median step"


class Point:
    """Samples of one (engine, load, axes) over its rounds."""

    def __init__(self) -> None:
        self.runs: list[dict[str, Any]] = []
        self.errors: list[str] = []

    def cat(self, key: str) -> np.ndarray:
        parts = [np.asarray(r[key], dtype=np.float64) for r in self.runs if r.get(key) is not None]
        return np.concatenate(parts) if parts else np.zeros(0)

    def total(self, key: str) -> int:
        return int(sum(r.get(key, 0) for r in self.runs))

    def busy(self) -> float:
        """The machine's busy share during this point's windows [% of one core], mean over the rounds; NaN if unknown."""
        b = [float(r["busy"]) for r in self.runs if r.get("busy") is not None]
        return sum(b) / len(b) if b else float("nan")

    def counter(self, key: str) -> Counter[str]:
        c: Counter[str] = Counter()
        for r in self.runs:
            c.update(r.get(key) or {})
        return c


def fmt(x: float, w: int = 8, d: int = 1) -> str:
    return f"{'-':>{w}}" if x != x else f"{x:{w}.{d}f}"


def ratio(a: float, b: float) -> str:
    return f"{'-':>7}" if a != a or b != b or b == 0 else f"{a / b:7.2f}"


def goal_summary(res: dict[tuple[str, str, int], Point]) -> bool:
    """The issue's goals, each as the same-run ratio new p99 / floor p99 with the figures beside it; True if all met."""
    from common import goal_line, mark  # bench/ is this script's sys.path[0]
    print()
    print("== goals (issue 19): work p99 of the new engine / the same run's floor p99 ==")
    met: list[bool] = []
    missing = []
    for (load, n), g in GOALS.items():
        pn, pf = res.get(("new", load, n)), res.get(("floor", load, n))
        wn = pn.cat("work") if pn else np.zeros(0)
        wf = pf.cat("work") if pf else np.zeros(0)
        what = f"{load} {n} axes work p99 / floor p99"
        if pn is None or pf is None or not (wn.size and wf.size):
            missing.append(what)
            print(f"goal: {what}: NOT MEASURED (not in --axes / --coupled-axes, skipped by --budget, or crashed)")
            continue
        a, f = pct(wn, 99), pct(wf, 99)
        bad = pn.total("start_rejected")
        text, ok = goal_line(what, a / f, g, f"new p99 {a:.0f} us, floor p99 {f:.0f} us; machine "
                             f"{pn.busy():.0f} % / {pf.busy():.0f} % busy in the new / floor windows"
                             + (f"; start_rejected {bad}: NOT a valid point" if bad else ""))
        print(text)
        met.append(ok and not bad)
    ok = all(met) and not missing
    print(f"nc_cycle: goals {sum(met)} of {len(GOALS)} met" + (f", {len(missing)} NOT MEASURED" if missing else "")
          + f" -> {mark(ok)}")
    return ok


def report(res: dict[tuple[str, str, int], Point], engines: list[str], labels: dict[str, str],
           points: list[tuple[str, int]], cal: dict[str, float] | None, probes: dict[str, dict[str, Any]],
           not_run: dict[tuple[str, int], dict[str, str]] | None = None) -> None:
    not_run = not_run or {}
    has_old = "old" in engines
    print()
    print("== work per cycle [us] (1 ms cycle, all axes moving): new = " + labels["new"]
          + (", old = " + labels["old"] if has_old else "") + "; floor = the fixed workload in the same loop, same run ==")
    print(f"{'load':<13} {'axes':>5} {'figure':>6} | {'new':>8} {'old':>8} {'new/old':>7} | {'floor':>7} "
          f"{'new/fl':>7} {'old/fl':>7} | goal")
    for load, n in points:
        pn, po, pf = res.get(("new", load, n)), res.get(("old", load, n)), res.get(("floor", load, n))
        wn = pn.cat("work") if pn else np.zeros(0)
        wo = po.cat("work") if po else np.zeros(0)
        wf = pf.cat("work") if pf else np.zeros(0)
        if not (wn.size or wo.size):
            continue
        for fig, p in (("p50", 50), ("p99", 99), ("max", 100)):
            a, b, f = pct(wn, p), pct(wo, p), pct(wf, p)
            goal = ""
            g = GOALS.get((load, n))
            if g is not None and fig == "p99":
                r = a / f if a == a and f == f and f > 0 else float("nan")
                goal = f"new/fl <= {g:g}x: " + ("NOT MEASURED" if r != r else "MET" if r <= g else "NOT MET")
                bad = pn.total("start_rejected") if pn else 0
                if bad:
                    goal += f"; new start_rejected {bad}: NOT a valid point"
            print(f"{load:<13} {n:>5} {fig:>6} | {fmt(a)} {fmt(b)} {ratio(a, b)} | {fmt(f, 7)} {ratio(a, f)} "
                  f"{ratio(b, f)} | {goal}")
    for (load, n), why in not_run.items():
        for e, w in why.items():
            print(f"({load} {n}: {e} skipped, {w}; measured for "
                  + (", ".join(x for x in engines if x not in why) or "no engine") + " and the floor only)")
    if cal:
        print(f"(floor workload: {cal['calls']} numpy calls, quiet cost {cal['min_us']:.1f} us best / "
              f"{cal['p50_us']:.1f} us median in a tight loop; floor p99 / quiet cost = how much the machine "
              "inflated a cycle at that moment)")

    print()
    print("== details per run set (all rounds of a point) ==")
    print(f"{'eng':<5} {'load':<13} {'axes':>5} {'timing':>10} {'cycles':>6} {'miss':>5} {'ovr':>4} | "
          f"{'late p50':>8} {'p99':>7} | {'step p50':>8} {'p99':>7} | {'cmd p50':>7} {'p99':>7} | "
          f"{'refill':>6} {'refl p99':>8} {'other p99':>9} | {'busy':>5} | moving, sub frames/axis samples")
    for load, n in points:
        for eng in engines:
            pt = res.get((eng, load, n))
            if not pt or not pt.runs:
                continue
            work, late, step, ex = pt.cat("work"), pt.cat("late"), pt.cat("step"), pt.cat("exec")
            rf = pt.cat("refill")
            if rf.size == work.size and rf.size:
                isr = rf > 0
                refill = f"{100.0 * isr.mean():5.1f}%"
                rp99, op99 = pct(work[isr], 99), pct(work[~isr], 99)
            else:
                refill, rp99, op99 = "n/a", float("nan"), float("nan")
            r0 = pt.runs[-1]
            print(f"{eng:<5} {load:<13} {n:>5} {r0['timing']:>10} {pt.total('cycles'):>6} {pt.total('missed'):>5} "
                  f"{pt.total('overruns'):>4} | {fmt(pct(late, 50))} {fmt(pct(late, 99), 7)} | "
                  f"{fmt(pct(step, 50))} {fmt(pct(step, 99), 7)} | {fmt(pct(ex, 50), 7)} {fmt(pct(ex, 99), 7)} | "
                  f"{refill:>6} {fmt(rp99)} {fmt(op99, 9)} | {fmt(pt.busy(), 4, 0)}% | {r0['moving']}/{n}, "
                  f"{sum(r['sub_frames'] for r in pt.runs)}/{sum(r['sub_axis_samples'] for r in pt.runs)}"
                  + (f"; slaves {r0.get('slaves', 0)}/{r0.get('pairs', 0)} coupled, {r0.get('synchron', 0)} synchron"
                     if load == "coupled" else ""))
    print("step = core.step; cmd = parse + core.execute + reply pack of the cycle's command (stress); refill = share "
          "of cycles whose step refilled the lookahead (engine's own signal), p99 work of those vs the others; "
          f"busy = the machine's busy share during the windows (/proc/stat, mean over the rounds, of {100 * (os.cpu_count() or 1)} %); "
          "moving = axes with |SetVelo| > 0 at the end of the last window")
    for load, n in points:
        for eng in engines:
            pt = res.get((eng, load, n))
            if not pt or not pt.runs or not pt.total("start_rejected"):
                continue
            codes = pt.counter("start_codes")
            texts: dict[str, str] = {}
            for r in pt.runs:
                for k, v in (r.get("start_texts") or {}).items():
                    texts.setdefault(k, v)
            print(f"  START REJECTED {eng} {load} {n}: {pt.total('start_rejected')} over {len(pt.runs)} run(s): "
                  + "; ".join(f"{k} x{v} ({texts.get(k, '')})" for k, v in codes.most_common(4)))
    print("period of heavy steps (median step of the heaviest phase of cycle mod L >= 2x the median):")
    for load, n in points:
        for eng in engines:
            pt = res.get((eng, load, n))
            if not pt or not pt.runs:
                continue
            runs = [(r["core_cycle0"], np.asarray(r["step"])) for r in pt.runs]
            print(f"  {eng:<5} {load:<13} {n:>5}: {period_signature(runs)}"
                  f"   [refill signal: {pt.runs[-1]['refill_label']}]")

    if not any(ld.startswith("stress") for ld, _ in points):
        return
    print()
    print("== stress command kinds actually run (sent / rejected over warm-up + windows; most frequent rejections) ==")
    for eng in engines:
        missing = [k for k, v in probes[eng].items() if not v["supported"]]
        if missing and any(ld.startswith("stress") for ld, _ in points):
            print(f"  {eng:<4} not run (probe): " + ", ".join(
                f"{KIND_TEXT[k]} ({UNSUPPORTED.get(probes[eng][k]['code'], 'failed')}"
                + (f" 0x{probes[eng][k]['code']:04X})" if probes[eng][k]["code"] > 0 else ")") for k in missing)
                + " -> replaced by MoveAbsolute Aborting")
        for load in ("stress", "stress-common"):
            sent: Counter[str] = Counter()
            rej: Counter[str] = Counter()
            codes: Counter[str] = Counter()
            mix: list[str] = []
            for (e, ld, _n), pt in res.items():
                if e == eng and ld == load:
                    sent += pt.counter("sent")
                    rej += pt.counter("rejected")
                    codes += pt.counter("codes")
                    mix = mix or (pt.runs[-1]["mix"] if pt.runs else [])
            if not sent:
                continue
            parts = [f"{KIND_TEXT[k]} {sent[k]}/{rej[k]}" for k in KINDS if sent[k]]
            print(f"  {eng:<4} {load:<13}: " + ", ".join(parts))
            print(f"  {'':<4} {'':<13}  per-axis sequence: {' -> '.join(mix)}")
            texts: dict[str, str] = {}
            for (e, ld, _n), pt in res.items():
                if e == eng and ld == load:
                    for r in pt.runs:
                        for k, v in (r.get("texts") or {}).items():
                            texts.setdefault(k, v)
            for k, v in codes.most_common(4):
                print(f"  {'':<4} {'':<13}  rejected {k} x{v}: {texts.get(k, '')}")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seconds", type=float, default=1.5, help="measuring window per run [s]")
    ap.add_argument("--warmup", type=float, default=1.0, help="warm-up before each window [s]")
    ap.add_argument("--rounds", type=int, default=2, help="interleaved rounds (new/old order alternates)")
    ap.add_argument("--axes", type=int, nargs="+", default=[8, 64, 256, 1024])
    ap.add_argument("--loads", nargs="+", default=list(LOADS), choices=LOADS,
                    help="quiet and stress at each --axes, coupled at each --coupled-axes (default: all)")
    ap.add_argument("--coupled-axes", type=int, nargs="+", default=[384], metavar="N",
                    help="axis counts of the coupled load (N // 3 master/slave pairs; default %(default)s)")
    ap.add_argument("--baseline", default=DEFAULT_BASELINE,
                    help="git revision of the old engine (default %(default)s, the last commit before the engine "
                         "rewrite); 'none' skips it")
    ap.add_argument("--new", metavar="REV", help="measure this git revision as 'new' instead of the working tree")
    ap.add_argument("--budget", type=float, default=200.0, help="bound on the whole run [s]; points that do not fit "
                    "are skipped and listed")
    ap.add_argument("--realtime", default="auto", choices=("auto", "fifo", "off"))
    ap.add_argument("--worker", choices=("engine", "floor"), help=argparse.SUPPRESS)
    ap.add_argument("--root", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.worker:
        return worker_main(args.worker, args.root, args.realtime)

    t_start = time.monotonic()
    seconds = min(args.seconds, 6.0)
    crashed: list[str] = []
    tmp = Path(tempfile.mkdtemp(prefix="znc-bench-"))
    workers: dict[str, Worker] = {}
    labels = {"new": f"working tree ({git('rev-parse', '--short', 'HEAD')}"
                     f"{' + uncommitted changes' if git('status', '--porcelain', '-uno') else ''})"}
    try:
        trees: dict[str, Path] = {"new": REPO}
        if args.new:
            path, sha = rev_tree(args.new)
            trees["new"] = path
            labels["new"] = f"{sha[:7]} (--new {args.new}, worktree {path.relative_to(REPO)})"
        if args.baseline.lower() != "none":
            path, sha = rev_tree(args.baseline)
            trees["old"] = path
            labels["old"] = f"{sha[:7]} (--baseline {args.baseline}, worktree {path.relative_to(REPO)})"
        for name, root in trees.items():
            workers[name] = Worker(name, "engine", root, engine_pythonpath(root, tmp / f"shim-{name}"), args.realtime, tmp)
        workers["floor"] = Worker("floor", "floor", trees["new"], engine_pythonpath(trees["new"], tmp / "shim-new"),
                                  args.realtime, tmp)
        engines: list[str] = []
        for name, w in workers.items():
            try:
                w.ready()
                if name != "floor":
                    engines.append(name)
            except RuntimeError as exc:
                crashed.append(f"{name} worker: {exc}\n{w.stderr_tail()}")
        print(f"NC cycle benchmark: real NcServer loop + core + zenoh publishing (frame every cycle, per-axis samples "
              f"for 4 subscribed axes), 1 ms cycle; {args.rounds} interleaved round(s) of {seconds:g} s per run "
              f"after {args.warmup:g} s warm-up; budget {args.budget:g} s")
        for name in engines:
            info = workers[name].info
            print(f"  {name}: {labels[name]}; nc_server from {info['nc_server']}, nc_schema from {info['nc_schema']}")
            pr = {**info["probe"], **info.get("features", {})}
            print(f"       probe: " + ", ".join(
                f"{KIND_TEXT.get(k) or FEATURE_TEXT[k]} {'ok' if v['supported'] else 'NOT supported'}"
                + (f" (0x{v['code']:04X})" if v["code"] > 0 else "") for k, v in pr.items()))
        cal = workers["floor"].info.get("calibration") if not workers["floor"].dead else None
        supported = {e: [k for k, v in workers[e].info["probe"].items() if v["supported"]] for e in engines}
        points = [(load, n) for load in args.loads if load != "coupled" for n in args.axes]
        if "stress" in args.loads and len(engines) == 2 and set(supported["new"]) != set(supported["old"]):
            common_n = 256 if 256 in args.axes else max(n for n in args.axes if n <= 256) if min(args.axes) <= 256 else None
            if common_n is not None:
                points.append(("stress-common", common_n))
        if "coupled" in args.loads:
            points += [("coupled", n) for n in dict.fromkeys(args.coupled_axes)]
        common = [k for k in KINDS if all(k in supported[e] for e in engines)]
        # (load, axes) -> {engine: why it is not run there}: a load needing a feature its probe did not find
        not_run: dict[tuple[str, int], dict[str, str]] = {}
        for load, n in points:
            need = LOAD_NEEDS.get(load)
            for e in engines:
                f = workers[e].info.get("features", {}).get(need) if need else None
                if need and not (f and f["supported"]):
                    why = f"it has no {FEATURE_TEXT[need]} (probe: " + (
                        (UNSUPPORTED.get(f["code"], "refused") + (f" 0x{f['code']:04X}" if f["code"] > 0 else ""))
                        if f else "not probed") + ")"
                    if f and f.get("text"):
                        why += f": {f['text']}"
                    not_run.setdefault((load, n), {})[e] = why

        res: dict[tuple[str, str, int], Point] = {}
        est: dict[tuple[str, int], float] = {}
        skipped: list[str] = []
        budget_end = t_start + args.budget
        for rnd in range(args.rounds):
            for pi, (load, n) in enumerate(points):
                order = list(engines) if (rnd + pi) % 2 == 0 else list(reversed(engines))
                order = [e for e in order if e not in not_run.get((load, n), {})]
                if not order:  # (the report lists why, from not_run)
                    continue
                guess = est.get((load, n), (args.warmup + seconds + 1.0 + n / 1000.0) * len(order) + seconds + 0.5)
                if time.monotonic() + guess > budget_end:
                    skipped.append(f"round {rnd + 1} {load} {n} axes")
                    continue
                t_pt = time.monotonic()
                for eng in order + ["floor"]:
                    w = workers[eng]
                    pt = res.setdefault((eng, load, n), Point())
                    if w.dead:
                        continue
                    kinds = common if load == "stress-common" else supported.get(eng, [])
                    req = {"axes": n, "load": load if load != "stress-common" else "stress", "seconds": seconds,
                           "warmup": args.warmup, "kinds": kinds}
                    try:
                        r = w.run(req, timeout=args.warmup + seconds + 60.0 + n / 20.0)
                    except RuntimeError as exc:
                        crashed.append(f"{eng} worker ({load} {n} axes): {exc}\n{w.stderr_tail()}")
                        continue
                    if "error" in r:
                        pt.errors.append(r["error"])
                        crashed.append(f"{eng} {load} {n} axes: {r['error']}\n{w.stderr_tail()}")
                    else:
                        pt.runs.append(r)
                est[(load, n)] = time.monotonic() - t_pt
        report(res, engines, labels, points, cal, {e: workers[e].info["probe"] for e in engines}, not_run)
        if skipped:
            print(f"\nskipped to stay within --budget {args.budget:g} s: " + "; ".join(skipped))
        if "stress-common" in [p[0] for p in points]:
            print(f"(stress-common: only {', '.join(KIND_TEXT[k] for k in common)} for both engines: the like-for-like "
                  "stress ratio; 'stress' runs what each engine supports)")
        goal_summary(res)
    finally:
        for w in workers.values():
            w.close()
        shutil.rmtree(tmp, ignore_errors=True)
    for c in crashed:
        print(f"\nCRASHED: {c}")
    print(f"(total run {time.monotonic() - t_start:.1f} s)")
    return 1 if crashed else 0


if __name__ == "__main__":
    sys.exit(main())
