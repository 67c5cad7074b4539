"""The demo's NC and PLC die with their launcher, also when it is killed with SIGKILL, and with
``make demo`` when make is killed (plc_client/lifeline.py: PR_SET_PDEATHSIG).

Each test starts the demo on a free port (never 7447), waits until the NC serves and the PLC
runs (their lines in the launcher's output), SIGKILLs the launcher (or make), then waits with a
deadline until every process it started is gone and the port is free again.
"""
from __future__ import annotations

import os
import shutil
import signal
import socket
import subprocess
import sys
import threading
from pathlib import Path

import pytest

from plc_client import lifeline
from znc_testing import free_port, wait_until

ROOT = Path(__file__).resolve().parents[2]
VENV = Path(sys.executable).parent.parent
#: generous: the NC's stop ramp, the PLC's bounded shutdown, a loaded 2-core machine
DEADLINE = 60.0


def _stat(pid: int) -> tuple[str, int] | None:
    """(state, start time) of ``pid`` from /proc, None if there is no such process."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except (OSError, IndexError):
        return None
    return fields[0], int(fields[19])


def _children(pid: int) -> list[int]:
    out: list[int] = []
    for task in Path(f"/proc/{pid}/task").glob("*"):
        try:
            out += [int(c) for c in (task / "children").read_text().split()]
        except OSError:
            pass
    return out


def _tree(pid: int) -> list[int]:
    """``pid``'s descendants (Linux /proc)."""
    out, todo = [], [pid]
    while todo:
        for c in _children(todo.pop()):
            out.append(c)
            todo.append(c)
    return out


def _cmdline(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
    except OSError:
        return ""


def _alive(procs: dict[int, int]) -> list[int]:
    """The pids of ``procs`` (pid -> start time) still running (a zombie has ended: not counted)."""
    out = []
    for pid, start in procs.items():
        st = _stat(pid)
        if st is not None and st[1] == start and st[0] != "Z":
            out.append(pid)
    return out


def _port_free(port: int) -> bool:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # TIME_WAIT remnants do not count
        try:
            s.bind(("127.0.0.1", port))
            s.listen(1)
        except OSError:
            return False
    return True


class _Output:
    """Collects a process's merged output lines in a thread."""

    def __init__(self, proc: subprocess.Popen[str]) -> None:
        self.lines: list[str] = []
        self._t = threading.Thread(target=self._read, args=(proc,), daemon=True)
        self._t.start()

    def _read(self, proc: subprocess.Popen[str]) -> None:
        assert proc.stdout is not None
        for line in proc.stdout:
            self.lines.append(line.rstrip("\n"))

    def has(self, text: str) -> bool:
        return any(text in line for line in self.lines)

    def tail(self) -> str:
        return "\n".join(self.lines[-30:])


def _wait_children_up(out: _Output) -> None:
    wait_until(lambda: out.has("[nc-server] nc-server nc1 ready") and out.has("[plc] plc-run demo-plc running"),
               DEADLINE, "the demo's NC and PLC")


def _demo_processes(launcher: int) -> dict[int, int]:
    """nc-server and plc-run under ``launcher``: pid -> start time."""
    procs = {}
    for pid in _tree(launcher):
        cmd = _cmdline(pid)
        st = _stat(pid)
        if st is not None and ("nc-server" in cmd or "plc-run" in cmd):
            procs[pid] = st[1]
    return procs


def _wait_gone(procs: dict[int, int], port: int, out: _Output) -> None:
    wait_until(lambda: not _alive(procs) and _port_free(port), DEADLINE,
               f"the demo's processes {sorted(procs)} to end and port {port} to be free")


def _cleanup(pids: list[int]) -> None:
    for pid in pids:  # each child has its own session/process group: kill those groups
        try:
            os.killpg(pid, signal.SIGKILL)
        except (ProcessLookupError, PermissionError):
            pass


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="PR_SET_PDEATHSIG is Linux only")
def test_demo_children_die_when_the_launcher_is_killed() -> None:
    port = free_port()
    demo = Path(sys.executable).with_name("zenoh-nc-demo")
    proc = subprocess.Popen([str(demo), "--duration", "600", "--port", str(port)], stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, start_new_session=True)
    out = _Output(proc)
    procs: dict[int, int] = {}
    try:
        _wait_children_up(out)
        procs = _demo_processes(proc.pid)
        assert len(procs) == 2, (procs, out.tail())
        proc.kill()  # SIGKILL: the launcher cannot stop anything itself
        proc.wait(10)
        _wait_gone(procs, port, out)
    finally:
        _cleanup([proc.pid, *procs])
        if proc.poll() is None:
            proc.wait(10)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="PR_SET_PDEATHSIG is Linux only")
@pytest.mark.skipif(shutil.which("make") is None, reason="no make on this machine")
def test_make_demo_ends_when_make_is_killed() -> None:
    port = free_port()
    stamp = VENV / ".installed"
    # -o: the venv counts as installed (never reinstalled into the test's interpreter)
    cmd = ["make", "-s", "-C", str(ROOT), "-o", str(stamp), "demo", f"VENV={VENV}",
           f"DEMO_ARGS=--duration 600 --port {port}"]
    make = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, start_new_session=True)
    out = _Output(make)
    launcher: list[int] = []
    procs: dict[int, int] = {}
    try:
        _wait_children_up(out)
        launcher = _children(make.pid)
        assert len(launcher) == 1 and "zenoh-nc-demo" in _cmdline(launcher[0]), (launcher, out.tail())
        procs = _demo_processes(launcher[0])
        assert len(procs) == 2, (procs, out.tail())
        procs[launcher[0]] = _stat(launcher[0])[1]  # type: ignore[index]
        make.kill()
        make.wait(10)
        _wait_gone(procs, port, out)
    finally:
        _cleanup([make.pid, *launcher, *procs])
        if make.poll() is None:
            make.wait(10)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="PR_SET_PDEATHSIG is Linux only")
def test_lifeline_ends_a_child_whose_parent_is_already_gone(tmp_path: Path) -> None:
    """The fallback: the parent ended before the prctl (here: a parent pid that is not ours)."""
    marker = tmp_path / "ran"
    cmd = lifeline.wrap([sys.executable, "-c", f"open({str(marker)!r}, 'w').close()"], parent=1)
    rc = subprocess.run(cmd, timeout=60).returncode
    assert rc == -signal.SIGTERM and not marker.exists()
    ok = subprocess.run(lifeline.wrap([sys.executable, "-c", f"open({str(marker)!r}, 'w').close()"]), timeout=60)
    assert ok.returncode == 0 and marker.exists()
