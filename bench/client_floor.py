"""The transport's floor of one PLC client process: what a 10 ms client costs on this machine without our PLC code.

Issue 19 asks a ``plc-run`` (4 axes, 10 ms) for <= 1.5 % of one core. This bench measures, in separate processes,
how much of that a client costs before any PLC code runs, step by step (each variant adds one thing to the one
before; ``--clients`` (3) processes of a variant at once, each measured on its own):

* ``A``  a Python process with plc-run's 10 ms loop (``PlcRuntime._loop``: absolute deadlines ``t0 + k * cycle`` on
  ``time.monotonic``, ``time.sleep`` of the rest, a late cycle skipped), no zenoh imported;
* ``B``  + a zenoh session opened with plc-run's config (``nc_schema.zenoh_config.client_config``: client mode,
  scouting off, lease 500 ms), nothing declared;
* ``C``  + a ``RingChannel(1)`` subscriber on its view key ``nc/nc1/view/<id>``, ``try_recv`` every cycle (no decode);
* ``D``  + one ``put`` per cycle of a PLCTONC-sized payload (4 axes: ``PLC_FRAME_HEADER_SIZE + 4 x
  PLC_AXIS_RECORD_SIZE`` = 568 B) on a publisher declared with defaults, as ``NcLink`` does (zenoh 1.x's default
  congestion control for a put is DROP already, so "D with DROP" is D itself);
* ``D-express`` / ``D-block`` / ``D-besteffort``: D with ``express=True``, ``CongestionControl.BLOCK``,
  ``Reliability.BEST_EFFORT`` on the publisher (does any of them make a put cheaper?);
* ``E``  the real idle ``plc-run`` (bench/idle_program.py: connected, no axes, no program) and ``F`` the real working
  one (bench/many_clients_program.py: 4 axes moving back and forth), against a real ``nc-server`` started as
  bench/many_clients.py starts it (1 ms, router mode, ``--clients`` x 4 axes); ``--no-real`` skips them.

The NC side of A-D is a process of this script (``--role nc``): a zenoh router listening on a free
``tcp/127.0.0.1`` port (scouting off) that puts, every 10 ms, one frame the size of a 4-axis view (``FRAME_HEADER_SIZE
+ 4 x (NCTOPLC_SIZE + NCJOBS_SIZE)`` = 1704 B, with the view's ``1,2,3,4`` attachment, DROP, not express: the NC's
view publisher) on each client id's view key, and counts the PLCTONC puts arriving on ``nc/nc1/plctonc/*``. The real
sizes a real NC and plc-run exchange are measured while F runs and printed beside the ones used.

Measured: each process's CPU over each window [% of one core] from /proc/<pid>/stat utime + stime (all threads,
10 ms ticks: 0.1 % of a core over a 10 s window) and, beside it, the exact run time summed over its threads from
/proc/<pid>/task/*/schedstat (threads alive at both ends). Variants are interleaved in rounds (A B C D ... A B C D ...),
each window with only that variant's client processes started (fresh, ``--settle`` s before the window); the NC side
and the real NC run through all of them. The whole bench runs at nice 19 (it renices itself; children inherit).
Each process also tells how many cycles it ran in the window (A-E print their count at SIGUSR1; F's are its PLCTONC
puts, counted by a probe subscriber on the real NC, which also records the real frame sizes): a process-window counts
only if it ran >= ``--min-rate`` (95) cycles/s, since a starved process's CPU is low for it (on a saturated machine
nice 19 gets little). Printed per variant: how many process-windows counted, their median CPU, min and max, the exact
figure, the ratio to A, to E and to the 1.5 % goal, each step's cost per cycle [us] (1 % of a core at 100 cycles/s =
100 us per cycle), the CPU per cycle run, D - A per cycle, F - E; and the load average and the machine's busy share
over the windows. The rows are saved (``rows.json`` in the run's temporary directory; ``--report-from`` prints the
table again, e.g. with another ``--min-rate``).

    .venv/bin/python bench/client_floor.py --seconds 30            # 3 rounds of 10 s per variant (~8 min)
    .venv/bin/python bench/client_floor.py --seconds 60 --rounds 6 --variants A B C D

``--seconds`` is each variant's measured time in total, split into ``--rounds`` windows. Limits: on a shared machine
the figures move with the others' load (compare ratios of one run, not figures between runs); the processes of a
variant share 2 CPUs with everything else, so wake-up latencies (and cache misses) are the machine's of that moment;
the NC side is Python, not the real NC (its frames are zeros of the right size); not in ``make bench`` (no goal of
its own: figures for issue 19's closing note).
"""
from __future__ import annotations

import argparse
import json
import math
import os
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

BENCH = Path(__file__).resolve().parent
sys.path.insert(0, str(BENCH.parent))
from bench.common import HZ, Busy, cpu_ticks, kill_group, start_nc, use_this_tree  # noqa: E402

use_this_tree()
from nc_schema import Keys, view_axes_text  # noqa: E402
from nc_schema.layout import (  # noqa: E402
    FRAME_HEADER_SIZE, NCJOBS_SIZE, NCTOPLC_SIZE, PLC_AXIS_RECORD_SIZE, PLC_FRAME_HEADER_SIZE,
)
from nc_server.router import router_config  # noqa: E402

NC = "nc1"
CYCLE = 0.010
AXES = 4
GOAL = 1.5  # % of one core per plc-run (issue 19)
VIEW_SIZE = FRAME_HEADER_SIZE + AXES * (NCTOPLC_SIZE + NCJOBS_SIZE)
PLCTONC_SIZE = PLC_FRAME_HEADER_SIZE + AXES * PLC_AXIS_RECORD_SIZE
VARIANTS = {
    "A": "10 ms time.sleep loop, no zenoh",
    "B": "+ zenoh client session, nothing declared",
    "C": "+ RingChannel view subscriber, try_recv/cycle",
    "D": f"+ one {PLCTONC_SIZE} B put/cycle (defaults)",
    "D-express": "D, publisher express=True",
    "D-block": "D, congestion_control BLOCK",
    "D-besteffort": "D, reliability BEST_EFFORT",
    "E": "real plc-run, idle (no program)",
    "F": "real plc-run, 4 axes moving",
}


# ---- the processes measured and the NC side (this script with --role) ------------------------------------------
#: the idle plc-run of E: bench/idle_program.py plus a cycle counter that SIGUSR1 prints (one add per cycle)
IDLE_COUNTING = """import signal
n = 0
signal.signal(signal.SIGUSR1, lambda *_: print('{"at": %d}' % n, flush=True))


def cycle(plc):
    global n
    n += 1
"""


def pace(cycle: Any) -> None:
    """``PlcRuntime._loop``'s pacing around ``cycle()`` until SIGTERM (then it prints what was done, JSON); SIGUSR1
    prints the cycles so far."""
    stop = [False]
    cycles = overruns = 0
    signal.signal(signal.SIGTERM, lambda *_: stop.__setitem__(0, True))
    signal.signal(signal.SIGUSR1, lambda *_: print(json.dumps({"at": cycles}), flush=True))
    print("ready", flush=True)
    t0 = time.monotonic()
    k = 0
    while not stop[0]:
        cycle()
        cycles += 1
        k += 1
        deadline = t0 + k * CYCLE
        now = time.monotonic()
        if now > deadline + CYCLE:  # late: skip, never replay
            overruns += 1
            k = math.ceil((now - t0) / CYCLE)
            deadline = t0 + k * CYCLE
        wait = deadline - time.monotonic()
        if wait > 0.0:
            time.sleep(wait)
    print(json.dumps({"cycles": cycles, "overruns": overruns, "seconds": time.monotonic() - t0}), flush=True)


def client_main(variant: str, client_id: str, endpoint: str) -> None:
    if variant == "A":
        pace(lambda: None)
        return
    import zenoh
    from zenoh.handlers import RingChannel

    from nc_schema.zenoh_config import client_config

    keys = Keys(NC)
    s = zenoh.open(client_config(endpoint))
    sub = pub = None
    if variant != "B":
        sub = s.declare_subscriber(keys.view(client_id), RingChannel(1))
    if variant.startswith("D"):
        extra: dict[str, dict[str, Any]] = {"D-express": {"express": True},
                                            "D-block": {"congestion_control": zenoh.CongestionControl.BLOCK},
                                            "D-besteffort": {"reliability": zenoh.Reliability.BEST_EFFORT}}
        opts = extra.get(variant, {})
        pub = s.declare_publisher(keys.plctonc_in(client_id), **opts)
    payload = bytes(PLCTONC_SIZE)
    got = [0]

    def cycle() -> None:
        if sub is not None and sub.try_recv() is not None:
            got[0] += 1
        if pub is not None:
            pub.put(payload)

    pace(cycle)
    print(json.dumps({"frames": got[0]}), flush=True)
    s.close()


def nc_main(endpoint: str, ids: list[str]) -> None:
    """The NC side: a router on ``endpoint`` putting a view-sized frame on each id's view key every 10 ms and counting
    PLCTONC puts; a line on stdin prints the counts so far (JSON), EOF ends it."""
    import json as js
    import threading

    import zenoh

    c = router_config([endpoint])  # (nc-router's: explicit endpoints, no scouting, its lease)
    keys = Keys(NC)
    counts: dict[str, int] = {}
    sizes: set[int] = set()

    def on_plc(sample: Any) -> None:
        k = str(sample.key_expr)
        counts[k] = counts.get(k, 0) + 1
        sizes.add(len(sample.payload.to_bytes()))

    with zenoh.open(c) as s:
        sub = s.declare_subscriber(f"nc/{NC}/plctonc/*", on_plc)
        pubs = [s.declare_publisher(keys.view(i), congestion_control=zenoh.CongestionControl.DROP, express=False)
                for i in ids]
        frame, att = bytes(VIEW_SIZE), view_axes_text(range(1, AXES + 1)).encode()
        done = threading.Event()

        def publish() -> None:
            t0, k = time.monotonic(), 0
            while not done.is_set():
                for p in pubs:
                    p.put(frame, attachment=att)
                k += 1
                wait = t0 + k * CYCLE - time.monotonic()
                if wait > 0:
                    time.sleep(wait)

        threading.Thread(target=publish, daemon=True).start()
        print("ready", flush=True)
        for _ in sys.stdin:
            print(js.dumps({"counts": counts, "sizes": sorted(sizes)}), flush=True)
        done.set()
        sub.undeclare()


# ---- the harness -------------------------------------------------------------------------------------------
def thread_ns(pid: int) -> dict[int, int]:
    """{tid: run time [ns]} of every thread of ``pid`` (/proc/<pid>/task/<tid>/schedstat)."""
    out = {}
    try:
        for t in os.listdir(f"/proc/{pid}/task"):
            try:
                out[int(t)] = int(Path(f"/proc/{pid}/task/{t}/schedstat").read_text().split()[0])
            except (OSError, ValueError, IndexError):
                pass
    except OSError:
        pass
    return out


def free_port() -> int:
    import socket
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sk:
        sk.bind(("127.0.0.1", 0))
        return int(sk.getsockname()[1])


class Bench:
    def __init__(self, args: argparse.Namespace) -> None:
        self.args = args
        self.tmp = Path(tempfile.mkdtemp(prefix="client-floor-"))
        self.ids = [f"c{k}" for k in range(args.clients)]
        self.ep = f"tcp/127.0.0.1:{free_port()}"
        self.real_ep = f"tcp/127.0.0.1:{free_port()}"
        self.procs: list[subprocess.Popen[Any]] = []
        self.nc_side: subprocess.Popen[str] | None = None
        self.real_sizes: dict[str, set[int]] = {"view": set(), "view attachment": set(), "plctonc": set()}
        self.probe: Any = None
        self.real_puts: dict[str, int] = {}  # PLCTONC puts per F client id (one per PLC cycle)

    def popen(self, cmd: list[str], **kw: Any) -> subprocess.Popen[Any]:
        p = subprocess.Popen(cmd, start_new_session=True, **kw)
        self.procs.append(p)
        return p

    def start_sides(self) -> None:
        py = sys.executable
        (self.tmp / "idle_counting.py").write_text(IDLE_COUNTING)
        self.nc_side = self.popen([py, __file__, "--role", "nc", "--endpoint", self.ep, "--ids", *self.ids],
                                  stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
        assert self.nc_side.stdout is not None
        if self.nc_side.stdout.readline().strip() != "ready":
            raise RuntimeError("the NC side did not start")
        if self.args.no_real:
            return
        from bench.many_clients import AXIS_TOML
        cfg = self.tmp / "nc.toml"
        cfg.write_text(f'[nc]\nname = "{NC}"\ncycle_time = 0.001\n\n[zenoh]\nmode = "router"\n'
                       + "".join(AXIS_TOML.format(id=i + 1) for i in range(AXES * self.args.clients)))
        env = dict(os.environ, PYTHONUNBUFFERED="1")
        self.procs.append(start_nc(cfg, self.real_ep, self.tmp, env))
        # the real sizes: a probe session on the real NC (closed after the first F window)
        import zenoh

        from nc_schema.zenoh_config import client_config

        def on(kind: str) -> Any:
            def f(s: Any) -> None:
                if not str(s.key_expr).rsplit("/", 1)[1].startswith("f"):  # (F's clients only)
                    return
                self.real_sizes[kind].add(len(s.payload.to_bytes()))
                if kind == "plctonc":
                    cid = str(s.key_expr).rsplit("/", 1)[1]
                    self.real_puts[cid] = self.real_puts.get(cid, 0) + 1
                if kind == "view" and s.attachment is not None:
                    self.real_sizes["view attachment"].add(len(s.attachment.to_bytes()))
            return f
        self.probe = zenoh.open(client_config(self.real_ep))
        self.probe.declare_subscriber(f"nc/{NC}/view/*", on("view"))
        self.probe.declare_subscriber(f"nc/{NC}/plctonc/*", on("plctonc"))

    def nc_counts(self) -> dict[str, Any]:
        assert self.nc_side is not None and self.nc_side.stdin is not None and self.nc_side.stdout is not None
        self.nc_side.stdin.write("?\n")
        self.nc_side.stdin.flush()
        return dict(json.loads(self.nc_side.stdout.readline()))

    def start_variant(self, v: str, rnd: int) -> list[tuple[subprocess.Popen[Any], Path]]:
        """Start ``--clients`` processes of variant ``v``, one after the other, each once it runs."""
        out: list[tuple[subprocess.Popen[Any], Path]] = []
        py = sys.executable
        for k, cid in enumerate(self.ids):
            log = self.tmp / f"{v}-{rnd}-{k}.out"
            env = dict(os.environ, PYTHONUNBUFFERED="1")
            if v in ("E", "F"):
                real_id = f"{v.lower()}{rnd}x{k}"
                prog = self.tmp / "idle_counting.py" if v == "E" else BENCH / "many_clients_program.py"
                if v == "F":
                    env.update(MANY_AXES=",".join(str(k * AXES + j + 1) for j in range(AXES)), MANY_NC=NC,
                               MANY_REPORT=str(self.tmp / f"{real_id}.json"), MANY_STOP=str(self.tmp / "never"))
                cmd = [py, "-m", "plc_client.cli", str(prog), "--nc", f"{NC}={self.real_ep}",
                       "--client-id", real_id, "--cycle-time", str(CYCLE), "--log-level", "WARNING"]
            else:
                cmd = [py, __file__, "--role", "client", "--variant", v, "--client-id", cid, "--endpoint", self.ep]
            p = self.popen(cmd, stdout=open(log, "w"), stderr=subprocess.STDOUT, env=env, cwd=BENCH.parent)
            out.append((p, log))
            ready = (lambda: (self.tmp / f"f{rnd}x{k}.json").exists()) if v == "F" else (
                lambda: any(w in log.read_text() for w in ("ready", "running")))
            t_end = time.monotonic() + self.args.start_timeout
            while not ready():
                if p.poll() is not None or time.monotonic() > t_end:
                    raise RuntimeError(f"{v} client {k} did not start: {log.read_text()[-2000:]}")
                time.sleep(0.05)
        if v == "F":  # moving: every axis had a move sent
            t_end = time.monotonic() + self.args.start_timeout
            while not all(all(a["sent"] > 0 for a in json.loads((self.tmp / f"f{rnd}x{k}.json").read_text())["axes"].values())
                          for k in range(len(self.ids))):
                if time.monotonic() > t_end:
                    raise RuntimeError("F clients not moving")
                time.sleep(0.2)
        return out

    def stop(self, ps: list[tuple[subprocess.Popen[Any], Path]]) -> list[dict[str, Any]]:
        for p, _ in ps:
            kill_group(p, signal.SIGTERM)
        rep = []
        for p, log in ps:
            try:
                p.wait(10)
            except subprocess.TimeoutExpired:
                kill_group(p)
                p.wait(5)
            d: dict[str, Any] = {}
            for line in log.read_text().splitlines():
                if line.startswith("{"):
                    d.update(json.loads(line))
            rep.append(d)
        return rep

    def cycles_now(self, v: str, rnd: int, ps: list[tuple[subprocess.Popen[Any], Path]]) -> list[int]:
        """Each process's PLC cycles so far: F its PLCTONC puts the probe counted, the others print them at SIGUSR1."""
        if v == "F":
            return [self.real_puts.get(f"f{rnd}x{k}", 0) for k in range(len(ps))]
        before = [log.read_text().count('"at"') for _, log in ps]
        for p, _ in ps:
            os.kill(p.pid, signal.SIGUSR1)
        out = []
        for (p, log), n in zip(ps, before):
            t_end = time.monotonic() + 5.0
            while (lines := [ln for ln in log.read_text().splitlines() if '"at"' in ln])[n:] == [] \
                    and time.monotonic() < t_end:
                time.sleep(0.02)
            out.append(int(json.loads(lines[-1])["at"]) if len(lines) > n else -1)
        return out

    def window(self, v: str, rnd: int) -> dict[str, Any]:
        ps = self.start_variant(v, rnd)
        time.sleep(self.args.settle)
        pids = [p.pid for p, _ in ps]
        k0 = self.cycles_now(v, rnd, ps)
        c0 = self.nc_counts()["counts"] if v not in ("E", "F") else {}
        t0, ticks0, ns0, busy = time.monotonic(), [cpu_ticks(p) for p in pids], [thread_ns(p) for p in pids], Busy()
        time.sleep(self.args.seconds / self.args.rounds)
        dt = time.monotonic() - t0
        ticks1, ns1 = [cpu_ticks(p) for p in pids], [thread_ns(p) for p in pids]
        k1 = self.cycles_now(v, rnd, ps)
        c1 = self.nc_counts()["counts"] if v not in ("E", "F") else {}
        share, load = busy.stop(), Path("/proc/loadavg").read_text().split()[0]
        reps = self.stop(ps)
        puts = sum(c1.values()) - sum(c0.values())
        exact = [sum(n - a.get(t, n) for t, n in b.items()) / 1e9 for a, b in zip(ns0, ns1)]  # [s]
        cyc = [b - a if a >= 0 and b >= 0 else 0 for a, b in zip(k0, k1)]
        return {"v": v, "cpu": [100.0 * (b - a) / HZ / dt for a, b in zip(ticks0, ticks1)],
                "exact": [100.0 * x / dt for x in exact], "cyc_per_s": [c / dt for c in cyc],
                "us_per_cycle": [1e6 * x / c if c > 0 else float("nan") for x, c in zip(exact, cyc)],
                "busy": share, "load": float(load), "puts_per_s": puts / dt / len(pids), "reports": reps}


def median(xs: list[float]) -> float:
    return statistics.median(xs) if xs else float("nan")


def report(rows: list[dict[str, Any]], variants: list[str], args: argparse.Namespace,
           real_sizes: dict[str, list[int]] | None = None) -> None:
    """The table. A process-window counts if the process ran >= ``--min-rate`` cycles/s in it (a starved one's CPU is
    low for it, and its rx work per cycle high): the figures are medians over those; a variant without any shows all
    its windows, marked ``*``."""
    print(f"\nclient_floor: {args.clients} processes per variant, {args.rounds} rounds x {args.seconds / args.rounds:g} s "
          f"per variant, PLC cycle {CYCLE * 1e3:g} ms; view frame {VIEW_SIZE} B, PLCTONC {PLCTONC_SIZE} B (nc_schema)")
    if real_sizes and any(real_sizes.values()):
        print("  real sizes seen (nc-server -> plc-run, F): " + ", ".join(f"{k} {s} B" for k, s in real_sizes.items()))
    print(f"{'variant':<13} {'what':<46} {'n ok':>5} {'% core':>6} {'min':>5} {'max':>5} {'exact':>5} {'/A':>5} {'/E':>5} "
          f"{'/goal':>5} {'step us/cyc':>12} {'us/cyc':>6} {'cyc/s':>5} {'frames/s':>8} {'puts/s':>6}")
    cols: dict[str, dict[str, Any]] = {}
    for v in variants:
        rs = [r for r in rows if r["v"] == v]
        samples = [(c, e, n, u) for r in rs for c, e, n, u in zip(r["cpu"], r["exact"], r["cyc_per_s"], r["us_per_cycle"])]
        ok = [x for x in samples if x[2] >= args.min_rate]
        use = ok or samples
        cols[v] = {"cpu": [x[0] for x in use], "exact": median([x[1] for x in use]), "n": f"{len(ok)}/{len(samples)}",
                   "us": median([x[3] for x in use if x[3] == x[3]]), "rate": median([x[2] for x in use]),
                   "mark": "" if ok else "*",
                   "frames": median([p["frames"] / p["seconds"] for r in rs for p in r.get("reports", [])
                                     if "frames" in p and p.get("seconds")]),
                   "puts": median([r["puts_per_s"] for r in rs if "puts_per_s" in r]) if v.startswith("D") else float("nan")}
    med = {v: median(c["cpu"]) for v, c in cols.items()}
    base = {"B": "A", "C": "B", "D": "C", "D-express": "D", "D-block": "D", "D-besteffort": "D", "F": "E"}
    for v, c in cols.items():
        m, b = med[v], base.get(v)
        step = f"{(c['exact'] - cols[b]['exact']) * 100:+.0f} vs {b}" if b in cols else ""
        print(f"{v + c['mark']:<13} {VARIANTS[v]:<46} {c['n']:>5} {m:6.2f} {min(c['cpu']):5.2f} {max(c['cpu']):5.2f} "
              f"{c['exact']:5.2f} {m / med.get('A', float('nan')):5.2f} {m / med.get('E', float('nan')):5.2f} {m / GOAL:5.2f} "
              f"{step:>12} {c['us']:6.0f} {c['rate']:5.0f} {c['frames']:8.1f} {c['puts']:6.1f}")
    ex = {v: c["exact"] for v, c in cols.items()}
    if "A" in ex and "D" in ex:
        print(f"D - A: {(ex['D'] - ex['A']) * 100:.0f} us per 10 ms cycle ({ex['D'] - ex['A']:.2f} % of a core, "
              f"{(ex['D'] - ex['A']) / GOAL * 100:.0f} % of the 1.5 % goal); D itself {ex['D']:.2f} % "
              f"({ex['D'] / GOAL * 100:.0f} % of the goal)")
    if "E" in ex and "F" in ex:
        print(f"F - E: {(ex['F'] - ex['E']) * 100:.0f} us per cycle; F - D: {(ex['F'] - ex.get('D', float('nan'))) * 100:.0f} us "
              f"per cycle (what the working plc-run costs above the transport's floor)")
    loads = [r["load"] for r in rows]
    print(f"machine: load average (1 min) {min(loads):.2f}-{max(loads):.2f} over the windows, busy "
          f"{min(r['busy'] for r in rows):.0f}-{max(r['busy'] for r in rows):.0f} % of {100 * (os.cpu_count() or 1)} %, "
          f"other processes of this shared VM included. 'n ok': process-windows with >= {args.min_rate:g} cycles/s (the "
          f"figures are medians over those); '% core' from /proc/<pid>/stat (10 ms ticks), 'exact' (and 'step', "
          f"'us/cyc': exact CPU per cycle run) from schedstat")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0] if __doc__ else None)
    ap.add_argument("--seconds", type=float, default=30.0, help="measured time per variant, split over the rounds (30)")
    ap.add_argument("--rounds", type=int, default=3, help="rounds (3): A B C D ... A B C D ...")
    ap.add_argument("--clients", type=int, default=3, help="processes of a variant at once (3)")
    ap.add_argument("--settle", type=float, default=2.0, help="seconds between a variant's start and its window (2)")
    ap.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=list(VARIANTS))
    ap.add_argument("--no-real", action="store_true", help="skip E and F (no nc-server, no plc-run)")
    ap.add_argument("--start-timeout", type=float, default=60.0, help="seconds a client may take to start (60)")
    ap.add_argument("--min-rate", type=float, default=95.0,
                    help="cycles/s a process must run in a window for it to count (95; fewer: starved)")
    ap.add_argument("--report-from", metavar="JSON", help="print the table of a saved run (its rows.json) and exit")
    ap.add_argument("--role", choices=["bench", "nc", "client"], default="bench", help=argparse.SUPPRESS)
    ap.add_argument("--variant", help=argparse.SUPPRESS)
    ap.add_argument("--client-id", help=argparse.SUPPRESS)
    ap.add_argument("--endpoint", help=argparse.SUPPRESS)
    ap.add_argument("--ids", nargs="*", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.role == "nc":
        nc_main(args.endpoint, args.ids)
        return 0
    if args.role == "client":
        client_main(args.variant, args.client_id, args.endpoint)
        return 0
    if args.report_from:
        saved = json.loads(Path(args.report_from).read_text())
        report(saved["rows"], saved["variants"], argparse.Namespace(**{**saved["args"], "min_rate": args.min_rate}),
               saved["real_sizes"])
        return 0
    os.nice(19 - os.nice(0))  # the bench and every process it starts at nice 19
    variants = [v for v in args.variants if not (args.no_real and v in ("E", "F"))]
    b = Bench(args)
    rows: list[dict[str, Any]] = []
    try:
        b.start_sides()
        for rnd in range(args.rounds):
            for v in variants:
                r = b.window(v, rnd)
                rows.append(r)
                print(f"  round {rnd + 1} {v:<13} " + " ".join(f"{x:.2f}" for x in r["cpu"]) + " % (exact "
                      + " ".join(f"{x:.2f}" for x in r["exact"]) + "), cycles/s " + " ".join(f"{x:.0f}" for x in r["cyc_per_s"])
                      + f", load {r['load']:.2f}, busy {r['busy']:.0f} %",
                      flush=True)
    finally:
        if b.probe is not None:
            b.probe.close()
        if b.nc_side is not None and b.nc_side.stdin is not None:
            b.nc_side.stdin.close()
        for p in reversed(b.procs):
            if p.poll() is None:
                kill_group(p, signal.SIGTERM)
        for p in reversed(b.procs):
            try:
                p.wait(10)
            except subprocess.TimeoutExpired:
                kill_group(p)
                p.wait(5)
    (b.tmp / "rows.json").write_text(json.dumps({"rows": rows, "variants": variants, "args": vars(args),
                                                 "real_sizes": {k: sorted(x) for k, x in b.real_sizes.items()}}))
    report(rows, variants, args, {k: sorted(x) for k, x in b.real_sizes.items()})
    print(f"(rows in {b.tmp / 'rows.json'}; --report-from it prints this table again)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
