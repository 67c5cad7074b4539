"""`make demo` smoke test: the demo runs without a terminal and checks itself.

zenoh-nc-demo starts nc-server and plc-run as separate processes (each in its own session),
shows plain lines (no tty) and exits 0 only if every axis moved without an error and the modulo
axis turned several times.
"""
from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

from znc_testing import free_port


def _children(pid: int) -> list[int]:
    """Direct children of ``pid`` (Linux /proc)."""
    out: list[int] = []
    for task in Path(f"/proc/{pid}/task").glob("*"):
        try:
            out += [int(c) for c in (task / "children").read_text().split()]
        except OSError:
            pass
    return out


def _kill_tree(proc: subprocess.Popen[str]) -> None:
    groups = [proc.pid] + _children(proc.pid)  # the demo's children run in their own sessions
    for g in groups:
        try:
            os.killpg(g, signal.SIGKILL)
        except (ProcessLookupError, PermissionError):
            pass
    proc.wait(10)


def test_demo_runs_headless_and_checks_itself() -> None:
    demo = Path(sys.executable).with_name("zenoh-nc-demo")
    proc = subprocess.Popen([str(demo), "--duration", "12", "--port", str(free_port())], stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, start_new_session=True)
    try:
        out, _ = proc.communicate(timeout=120)
    except subprocess.TimeoutExpired:
        _kill_tree(proc)
        raise
    finally:
        if proc.poll() is None:
            _kill_tree(proc)
    assert proc.returncode == 0, out[-3000:]
    assert "demo OK" in out and "modulo axis 4 turned" in out
    assert "t=" in out and "\x1b[" not in out  # plain lines without a terminal
