"""A door process of the tests (nc-ads, nc-opcua): its stdout read line by line in a thread, its stderr in a file,
ready when a line starts with its ready prefix, stopped with SIGTERM then its process group killed.

May import: the standard library and znc_testing.
"""
from __future__ import annotations

import os
import signal
import subprocess
import threading
import time
from pathlib import Path

from znc_testing import kill_process_group


class DoorProcess:
    """A running door; subclasses set ``NAME`` and ``READY`` (the start of its ready line)."""

    NAME = "door"
    READY = "ready"

    def __init__(self, proc: subprocess.Popen[str], stderr_path: Path) -> None:
        self.proc, self.stderr_path = proc, stderr_path
        self.stdout_lines: list[str] = []
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            self.stdout_lines.append(line.rstrip("\n"))

    def stderr(self) -> str:
        try:
            return self.stderr_path.read_text(errors="replace")
        except OSError:
            return ""

    def wait_ready(self, timeout: float = 90.0) -> None:
        """Until the ready line (a loaded machine: importing numpy alone took 20 s, asyncua over 90 s).

        Raises:
            RuntimeError: the process exited first (its stderr in the message).
            AssertionError: no ready line within ``timeout`` s.
        """
        deadline = time.monotonic() + timeout
        while not any(ln.startswith(self.READY) for ln in self.stdout_lines):
            if self.proc.poll() is not None:
                self._reader.join(2)
                raise RuntimeError(f"{self.NAME} exited with {self.proc.returncode}:\n{self.stderr()}")
            if time.monotonic() > deadline:
                raise AssertionError(f"{self.NAME} not ready after {timeout} s:\n{self.stderr()}")
            time.sleep(0.01)

    def stop(self, timeout: float = 10.0) -> int | None:
        """SIGTERM, wait, then SIGKILL the group; the exit code if it ended by itself."""
        rc = None
        if self.proc.poll() is None:
            try:
                os.kill(self.proc.pid, signal.SIGTERM)
                rc = self.proc.wait(timeout)
            except subprocess.TimeoutExpired:
                pass
        else:
            rc = self.proc.returncode
        self.kill()
        return rc

    def kill(self) -> None:
        kill_process_group(self.proc)
