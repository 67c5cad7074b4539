"""What the benchmarks share: the tree they run, the machine's busy share, process CPU, goal lines.

Every bench starts with::

    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    from bench.common import REPO, use_this_tree  # noqa: E402
    use_this_tree()

so that ``python bench/x.py`` from the root of a fresh clone (``make venv``, then ``make bench``)
imports this checkout's packages and the test helpers (``tests/znc_testing``), and so do the processes
it starts (nc-server, plc-run, nc-ads: ``PYTHONPATH`` leads with this checkout, whatever venv runs them).

Goal lines: :func:`goal_line` prints one goal as a same-run ratio with the absolute figures beside it and
MET / NOT MET; :func:`verdict` the bench's summary of all its goals.
"""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any, Iterable, Sequence

REPO = Path(__file__).resolve().parents[1]
TESTS = REPO / "tests"
#: when this bench started (its first import of this module): the summary line says how long it ran
T0 = time.monotonic()


def use_this_tree() -> None:
    """This checkout first on ``sys.path`` (with ``tests/`` for ``znc_testing``) and on the children's
    ``PYTHONPATH``. Idempotent."""
    for p in (str(TESTS), str(REPO)):
        if p in sys.path:
            sys.path.remove(p)
        sys.path.insert(0, p)
    old = [p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p and p != str(REPO)]
    os.environ["PYTHONPATH"] = os.pathsep.join([str(REPO), *old])


# ---- the machine and processes (/proc) ---------------------------------------------------------------------
def machine_ticks() -> tuple[int, int]:
    """(busy, total) clock ticks of all CPUs since boot (/proc/stat; busy = total - idle - iowait)."""
    try:
        f = [int(x) for x in Path("/proc/stat").read_text().split("\n", 1)[0].split()[1:]]
    except (OSError, ValueError):
        return 0, 0
    total = sum(f[:8])  # user nice system idle iowait irq softirq steal (guest is inside user)
    return total - f[3] - f[4], total


def cpu_ticks(pid: int) -> int:
    """utime + stime of a process (all its threads) [clock ticks]; 0 if it is gone."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
        return int(fields[11]) + int(fields[12])
    except (OSError, IndexError, ValueError):
        return 0


def children(pid: int) -> list[int]:
    """The child processes of ``pid`` (from /proc; e.g. nc-server's frame publisher children)."""
    out = []
    for d in Path("/proc").iterdir():
        if d.name.isdigit():
            try:
                if int((d / "stat").read_text().rsplit(")", 1)[1].split()[1]) == pid:
                    out.append(int(d.name))
            except (OSError, IndexError, ValueError):
                pass
    return out


NCPU = os.cpu_count() or 1
HZ = os.sysconf("SC_CLK_TCK")


class Busy:
    """The whole machine's busy share over a window [% of one core; 100 x CPUs = all busy] (/proc/stat).

    ``b = Busy()`` starts the window, ``b.stop()`` ends it (and returns the share); ``b.share`` after that.
    """

    def __init__(self) -> None:
        self.m0 = machine_ticks()
        self.t0 = time.monotonic()
        self.share: float | None = None
        self.seconds = 0.0

    def stop(self) -> float:
        m1 = machine_ticks()
        self.seconds = time.monotonic() - self.t0
        self.share = 100.0 * NCPU * (m1[0] - self.m0[0]) / max(1, m1[1] - self.m0[1])
        return self.share

    def text(self) -> str:
        if self.share is None:
            self.stop()
        return f"{self.share:.0f} % busy of {100 * NCPU} % ({NCPU} CPUs) over {self.seconds:.1f} s"


class ProcCpu:
    """CPU of named processes over a window [% of one core] (/proc/<pid>/stat utime + stime, all threads)."""

    def __init__(self, pids: dict[str, int]) -> None:
        self.pids = dict(pids)
        self.c0 = {k: cpu_ticks(p) for k, p in self.pids.items()}
        self.t0 = time.monotonic()

    def stop(self) -> dict[str, float]:
        c1 = {k: cpu_ticks(p) for k, p in self.pids.items()}
        dt = max(1e-9, time.monotonic() - self.t0)
        return {k: 100.0 * (c1[k] - self.c0[k]) / HZ / dt for k in self.pids}


# ---- goals -------------------------------------------------------------------------------------------------
def mark(ok: bool) -> str:
    return "MET" if ok else "NOT MET"


def goal_line(what: str, ratio: float, limit: float, beside: str) -> tuple[str, bool]:
    """``goal: <what>: ratio X (goal <= L) [beside] -> MET``; a NaN ratio (nothing measured) is NOT MET."""
    ok = ratio == ratio and ratio <= limit
    return f"goal: {what}: {ratio:.2f}x (goal <= {limit:g}x; {beside}) -> {mark(ok)}", ok


def verdict(bench: str, goals: Iterable[tuple[str, bool]], busy: str = "") -> bool:
    """Print every goal line and the bench's one summary line; True if all were met (no goals: True)."""
    goals = list(goals)
    for text, _ in goals:
        print(text)
    ok = all(g for _, g in goals)
    n_met = sum(1 for _, g in goals if g)
    tail = f" (machine {busy}; run {elapsed():.0f} s)" if busy else f" (run {elapsed():.0f} s)"
    if goals:
        print(f"{bench}: goals {n_met} of {len(goals)} met -> {mark(ok)}{tail}")
    else:
        print(f"{bench}: no goal set (figures only){tail}")
    return ok


def elapsed() -> float:
    """Seconds since this bench started (T0)."""
    return time.monotonic() - T0


def pct(xs: Iterable[float], p: float) -> float:
    """The p-th percentile (nearest rank on the sorted samples); NaN for none."""
    s = sorted(xs)
    if not s:
        return float("nan")
    return s[min(len(s) - 1, int(round(p / 100 * (len(s) - 1))))]


def start_nc(cfg: Path, endpoint: str, tmp: Path, env: "dict[str, str] | None" = None, extra: Sequence[str] = (),
             cwd: "Path | None" = None, err: str = "nc.err", connect: bool = False) -> "subprocess.Popen[Any]":
    """``nc-server --config cfg --listen endpoint`` (own process group, stderr in ``tmp/<err>``), started with
    ``extra`` arguments; returns once it printed its ready line. ``connect``: in client mode behind the router at
    ``endpoint`` instead (``--mode client --connect endpoint``: a hot-standby pair's members).

    Raises:
        RuntimeError: it ended or printed something else first (the process is killed; the text has its stderr).
    """
    where = ["--mode", "client", "--connect", endpoint] if connect else ["--listen", endpoint]
    nc = subprocess.Popen([sys.executable, "-m", "nc_server.server.cli", "--config", str(cfg), *where,
                           "--log-level", "WARNING", *extra], stdout=subprocess.PIPE, stderr=open(tmp / err, "w"),
                          text=True, env=env, start_new_session=True, cwd=cwd)
    line = nc.stdout.readline() if nc.stdout else ""
    if " ready: " not in line:
        kill_group(nc)
        raise RuntimeError(f"nc-server did not start: {line!r} {(tmp / err).read_text()[-2000:]}")
    return nc


def kill_group(proc: "subprocess.Popen[Any]", sig: int = signal.SIGKILL) -> None:
    """Send ``sig`` to ``proc``'s process group (started with ``start_new_session``); gone already: nothing."""
    try:
        os.killpg(proc.pid, sig)
    except ProcessLookupError:
        pass


def stop_processes(clients: "Sequence[subprocess.Popen[Any]]", nc: "subprocess.Popen[Any]",
                   rest: "Sequence[subprocess.Popen[Any]]" = ()) -> None:
    """The benches' orderly end: SIGTERM the clients (10 s for all of them), then the NC (10 s), then SIGKILL
    every group, ``rest`` too, and reap them."""
    for p in clients:
        kill_group(p, signal.SIGTERM)
    t_end = time.monotonic() + 10.0
    for p in clients:
        try:
            p.wait(max(0.1, t_end - time.monotonic()))
        except subprocess.TimeoutExpired:
            pass
    kill_group(nc, signal.SIGTERM)
    try:
        nc.wait(10)
    except subprocess.TimeoutExpired:
        pass
    for p in [*clients, nc, *rest]:
        if p.returncode is None:  # (a reaped leader's pid, hence its group id, may belong to another process now)
            kill_group(p)
        try:
            p.wait(5)
        except subprocess.TimeoutExpired:
            pass
