"""Remote drives in tests (tests/drives): an ``nc-drive-sim`` process and its status file, powering remote axes.

Used by test_remote_process.py and test_standby_process.py.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any, Callable

from znc_testing.nc_process import BIT_CONTROL_LOOP_CLOSED, NcTestClient, kill_process_group
from znc_testing.until import wait_until

T = 30.0  # generous deadlines: a loaded 2-core machine


def drive_sim_command() -> list[str]:
    script = Path(sys.executable).with_name("nc-drive-sim")
    return [str(script)] if script.exists() else [sys.executable, "-m", "nc_server.drives.remote.host"]


class DriveSim:
    """An ``nc-drive-sim`` process (its own process group) and its status file."""

    def __init__(self, tmp: Path, args: list[str]) -> None:
        self.status_path = tmp / f"drives-{os.getpid()}-{id(self)}.json"
        self.err_path = tmp / f"drives-{id(self)}.stderr"
        with open(self.err_path, "w") as err:
            self.proc = subprocess.Popen([*drive_sim_command(), *args, "--status-file", str(self.status_path)],
                                         stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=err, text=True,
                                         start_new_session=True, env=dict(os.environ, PYTHONUNBUFFERED="1"))

    def stderr(self) -> str:
        return self.err_path.read_text(errors="replace")

    def status(self) -> dict[str, Any] | None:
        try:
            return json.loads(self.status_path.read_text())
        except (OSError, ValueError):
            return None

    def fresh_status(self, after: float) -> dict[str, Any] | None:
        """A status written after wall time ``after`` (None yet)."""
        s = self.status()
        return s if s is not None and s["time"] > after else None

    def kill(self) -> None:
        kill_process_group(self.proc)


def enabled(cl: NcTestClient, a: int) -> Callable[[], bool]:
    """A condition for ``wait_until``: axis ``a`` enabled without error. While it shows 0x4651 (the NC has not
    heard its drive host yet: it started first) MC_Reset is sent again; any other drive error (e.g. the drive's
    fault from the silence before the NC was there) gets one MC_Reset, which must suffice (a drive error raised
    again by the statusword's latency would never clear)."""
    reset_sent = [False]

    def up() -> bool:
        r = cl.nctoplc(a)
        if r is None:
            return False
        err = int(r["ErrorCode"])
        if err == 0x4651:
            cl.request("Reset", axis=a)
            reset_sent[0] = False
            return False
        if err:
            if not reset_sent[0]:
                assert cl.request("Reset", axis=a)["error"] == 0
                reset_sent[0] = True
            return False
        return bool(int(r["StateDWord"]) & BIT_CONTROL_LOOP_CLOSED)

    return up


def power(cl: NcTestClient, axes: list[int]) -> None:
    """Claim, enable and (MC_Reset while an error is shown: the NC started before its drive host, so its remote
    axes began in 0x4651; see :func:`enabled`) wait until each axis is enabled without error."""
    for a in axes:
        cl.claim(a)
    cl.feed_plctonc(axes)
    for a in axes:
        wait_until(enabled(cl, a), T, f"axis {a} enabled without error", interval=0.1)


def drive_axis(st: dict[str, Any], axis_id: int) -> dict[str, Any]:
    return next(a for a in st["axes"] if a["AxisId"] == axis_id)
