"""Helpers of the inspection-tool tests (the ``rig`` fixture is in conftest.py).

The tools run as processes (``python -m nc_tools.<tool>``, so they do not depend on the installed
console scripts); :func:`run_tool` kills their process group whatever happens.
"""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import IO, Any

from znc_testing import BIT_CONTROL_LOOP_CLOSED, NcServerProcess, NcTestClient, wait_until

#: generous deadline for anything on a loaded 2-core machine [s]
T = 60.0
ROOT = Path(__file__).resolve().parents[2]


class Rig:
    """A running NC and a client ``t1`` to drive it."""

    def __init__(self, srv: NcServerProcess, client: NcTestClient) -> None:
        self.srv = srv
        self.cl = client

    @property
    def endpoint(self) -> str:
        return self.srv.endpoint

    def enable(self, *axes: int) -> None:
        """Claim ``axes`` as t1, feed an enabling PLCTONC, wait until their control loops are closed."""
        for a in axes:
            self.cl.claim(a)
        self.cl.feed_plctonc(axes)
        for a in axes:
            wait_until(lambda a=a: (s := self.cl.nctoplc(a)) is not None
                       and int(s["StateDWord"]) & BIT_CONTROL_LOOP_CLOSED, T, f"axis {a} enabled")

    def request(self, cmd: str, axis: int | None = None, **args: Any) -> dict[str, Any]:
        r = self.cl.request(cmd, axis=axis, **args)
        assert r["error"] == 0, r
        return r



def tool_command(tool: str, *args: str) -> list[str]:
    return [sys.executable, "-m", f"nc_tools.{tool}", *args]


def run_tool(tool: str, *args: str, timeout: float = 180.0, cwd: Path | None = None) -> subprocess.CompletedProcess[str]:
    """Run ``nc_tools.<tool>`` to its end (own process group, killed on timeout or error)."""
    p = subprocess.Popen(tool_command(tool, *args), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                         start_new_session=True, cwd=cwd, env=dict(os.environ, PYTHONUNBUFFERED="1"))
    try:
        out, err = p.communicate(timeout=timeout)
        return subprocess.CompletedProcess(p.args, p.returncode, out, err)
    finally:
        kill_group(p)


class JsonLines:
    """The JSON documents a running tool writes, one per stdout line, read by a thread of their own.

    A test waits for them with a deadline (:meth:`newest`): a blocking ``readline()`` inside a
    ``wait_until`` would never let its deadline fire while the tool writes nothing.
    """

    def __init__(self, stream: IO[str]) -> None:
        self.docs: list[Any] = []
        self.ended = False
        self._taken = 0
        self._cv = threading.Condition()
        threading.Thread(target=self._read, args=(stream,), daemon=True).start()

    def _read(self, stream: IO[str]) -> None:
        try:
            for line in stream:
                try:
                    doc = json.loads(line)
                except ValueError:  # not a document (e.g. cut off at a kill): not the tests' concern
                    continue
                with self._cv:
                    self.docs.append(doc)
                    self._cv.notify_all()
        except (OSError, ValueError):  # the pipe closed under us at teardown
            pass
        with self._cv:
            self.ended = True
            self._cv.notify_all()

    def newest(self, timeout: float = 5.0) -> Any:
        """The newest document written since the previous call, waiting up to ``timeout`` [s] for one.

        Raises:
            AssertionError: none came within ``timeout`` or the tool's output ended (``wait_until``
                takes it as "not yet" and polls again until its own deadline).
        """
        deadline = time.monotonic() + timeout
        with self._cv:
            while len(self.docs) <= self._taken:
                left = deadline - time.monotonic()
                if left <= 0 or self.ended:
                    raise AssertionError(f"no new JSON line within {timeout:g} s" + (" (output ended)" if self.ended else ""))
                self._cv.wait(left)
            self._taken = len(self.docs)
            return self.docs[-1]


def kill_group(p: subprocess.Popen[Any]) -> None:
    """SIGKILL the process group of ``p`` (idempotent)."""
    try:
        os.killpg(p.pid, signal.SIGKILL)
    except (ProcessLookupError, PermissionError):
        pass
    try:
        p.wait(10)
    except subprocess.TimeoutExpired:
        pass


#: Runs zenoh-cli with the codec entry points of *this* checkout's pyproject.toml (the installed
#: metadata may be of another checkout, e.g. the editable install of the main worktree).
_ZENOH_CLI = """
import sys, tomllib
from importlib.metadata import EntryPoint
import zenoh_cli
eps = tomllib.load(open(sys.argv.pop(1), "rb"))["project"]["entry-points"]
def gather():
    return tuple({n: EntryPoint(n, v, g) for n, v in eps[g].items()}
                 for g in ("zenoh_cli.codecs.encoders", "zenoh_cli.codecs.decoders"))
zenoh_cli.gather_plugins = gather
sys.argv[0] = "zenoh"
zenoh_cli.main()
"""


def zenoh_cli_command(*args: str) -> list[str]:
    """``zenoh ARGS...`` (zenoh-cli) with this checkout's codec plugins."""
    return [sys.executable, "-c", _ZENOH_CLI, str(ROOT / "pyproject.toml"), *args]
