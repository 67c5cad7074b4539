"""Helpers of the nc-ads tests: an ``nc-ads`` process on its own loopback address in front of a real nc-server.

    nc = start_nc_server(tmp)                                   # znc_testing
    ads = start_nc_ads(tmp, nc.endpoint, role="operator")       # 127.0.0.x:48898, waits for its ready line
    plc = pyads.Connection(ads.netid, 500, ads.host); plc.open()
    ...
    plc.close(); ads.stop(); nc.kill()

Every process runs in its own process group and is killed at the end even on failure (the fixtures).
"""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Sequence

from znc_testing.ads_testing import free_ads_address
from znc_testing import kill_process_group
from znc_testing.nc_process import start_with_port_retry

class NcAdsProcess:
    """A running ``nc-ads`` (``python -m nc_ads.cli``) listening on ``host``:48898 with net id ``netid``."""

    def __init__(self, proc: subprocess.Popen[str], host: str, netid: str, stderr_path: Path) -> None:
        self.proc = proc
        self.host = host
        self.netid = netid
        self.stderr_path = stderr_path
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

    def wait_ready(self, timeout: float = 90.0) -> None:  # importing numpy alone took 20 s on the loaded machine
        deadline = time.monotonic() + timeout
        while not any(ln.startswith("nc-ads ready:") for ln in self.stdout_lines):
            if self.proc.poll() is not None:
                self._reader.join(2)
                raise RuntimeError(f"nc-ads exited with {self.proc.returncode}:\n{self.stderr()}")
            if time.monotonic() > deadline:
                raise AssertionError(f"nc-ads not ready after {timeout} s:\n{self.stderr()}")
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


def start_nc_ads(tmp_path: Path, endpoint: str, role: str = "operator", extra_args: Sequence[str] = (),
                 client_id: str = "ads1", nc: str = "nc1") -> NcAdsProcess:
    """Start nc-ads for NC ``nc`` at zenoh ``endpoint`` on a free 127.0.0.x (retried if the address is taken)."""
    tmp_path.mkdir(parents=True, exist_ok=True)
    def launch() -> NcAdsProcess:
        host = free_ads_address()
        netid = f"{host}.1.1"
        err_path = tmp_path / f"nc-ads-{host}.stderr"
        args = [sys.executable, "-m", "nc_ads.cli", "--nc", f"{nc}={endpoint}", "--listen", f"{host}:48898",
                "--netid", netid, "--role", role, "--client-id", client_id, *extra_args]
        with open(err_path, "w") as err:
            proc = subprocess.Popen(args, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=err, text=True,
                                    start_new_session=True, env=dict(os.environ, PYTHONUNBUFFERED="1"))
        return NcAdsProcess(proc, host, netid, err_path)

    return start_with_port_retry(launch, lambda h: h.wait_ready(), attempts=5)
