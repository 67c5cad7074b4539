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
import subprocess
import sys
from pathlib import Path
from typing import Sequence

from znc_testing.ads_testing import free_ads_address
from znc_testing.door_process import DoorProcess
from znc_testing.nc_process import start_with_port_retry

class NcAdsProcess(DoorProcess):
    """A running ``nc-ads`` (``python -m nc_ads.cli``) listening on ``host``:48898 with net id ``netid``."""

    NAME, READY = "nc-ads", "nc-ads ready:"

    def __init__(self, proc: subprocess.Popen[str], host: str, netid: str, stderr_path: Path) -> None:
        super().__init__(proc, stderr_path)
        self.host = host
        self.netid = netid


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
