"""Keep every core busy while a command runs: the "loaded machine" of the engineering standards.

    python bench/cpu_burner.py [--procs N] [--seconds S] [-- COMMAND ...]

Starts N (default: one per online CPU) normal-priority processes spinning in pure Python. With a
COMMAND it runs that command meanwhile and exits with its exit code; without one it burns for
``--seconds`` (default 60, at most 4 h). The burners end with this process, also when it is killed
(PR_SET_PDEATHSIG), and never outlive ``--seconds`` + 4 h in any case.

``make test-loaded`` runs the whole suite under it (``RUNS=3`` for three runs in a row).
"""
from __future__ import annotations

import argparse
import ctypes
import os
import signal
import subprocess
import sys
import time
from collections.abc import Sequence

MAX_SECONDS = 4 * 3600.0


def _burn(until: float) -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the parent's: it kills the burners
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG: die with the parent
    except (OSError, AttributeError):
        pass
    x = 0
    while time.monotonic() < until:
        for _ in range(100_000):
            x = (x * 1103515245 + 12345) & 0xFFFFFFFF
    os._exit(0)


def main(argv: Sequence[str] | None = None) -> int:
    args = list(sys.argv[1:] if argv is None else argv)
    command: list[str] = []
    if "--" in args:
        i = args.index("--")
        args, command = args[:i], args[i + 1:]
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--procs", type=int, default=len(os.sched_getaffinity(0)), help="burner processes")
    p.add_argument("--seconds", type=float, default=60.0, help="how long without a command [s]")
    a = p.parse_args(args)
    if a.procs < 1:
        p.error("--procs must be at least 1")
    limit = MAX_SECONDS if command else min(max(a.seconds, 0.0), MAX_SECONDS)
    until = time.monotonic() + limit
    pids = []
    for _ in range(a.procs):
        pid = os.fork()
        if pid == 0:
            _burn(until)
        pids.append(pid)
    print(f"cpu_burner: {a.procs} burner processes", file=sys.stderr, flush=True)
    try:
        if command:
            return subprocess.call(command)
        while time.monotonic() < until:
            time.sleep(min(1.0, max(0.0, until - time.monotonic())))
        return 0
    except KeyboardInterrupt:
        return 130
    finally:
        for pid in pids:
            try:
                os.kill(pid, signal.SIGKILL)
                os.waitpid(pid, 0)
            except (ProcessLookupError, ChildProcessError):
                pass


if __name__ == "__main__":
    sys.exit(main())
