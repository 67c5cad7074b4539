"""plc-run runs zenoh's work on one runtime (plc_client.cli.ZENOH_RUNTIME, issue 19): a connected PLC
client has no thread of zenoh's rx, tx or net pools, only the app runtime's."""
from __future__ import annotations

import os
from pathlib import Path
from typing import Callable

from znc_testing import NcServerProcess, wait_until
from znc_testing.plc_harness import NC_ARGS, T, PlcProcess, power_on


def _thread_names(pid: int) -> list[str]:
    names = []
    for tid in os.listdir(f"/proc/{pid}/task"):
        try:
            names.append(Path(f"/proc/{pid}/task/{tid}/comm").read_text().strip())
        except OSError:
            pass  # (ended meanwhile)
    return names


def test_plc_run_has_only_zenohs_app_threads(start_nc: Callable[..., NcServerProcess]) -> None:
    nc = start_nc(extra_args=NC_ARGS)
    with PlcProcess(nc.endpoint, "plc-threads") as p:
        p.wait_started()
        power_on(p)  # (frames in, PLCTONC and requests out: every kind of traffic has run)
        names = wait_until(lambda: (n := _thread_names(p.proc.pid)) and any(x.startswith("app-") for x in n) and n,
                           T, "zenoh's app runtime thread in plc-run")
        pools = sorted(x for x in names if x.split("-")[0] in ("rx", "tx", "net", "acc"))
        assert not pools, f"zenoh pools besides app in plc-run: {sorted(names)}"
