"""The ``cia402-sim`` backend in real processes: ``nc-server --set nc.drive=cia402-sim`` and a ``plc-run`` PLC
(plc_agent.py) that powers and moves an axis over zenoh on 127.0.0.1; the stats carry ``drive_errors``."""
from __future__ import annotations

import math
from typing import Callable

from znc_testing import NcServerProcess, NcTestClient
from znc_testing.plc_harness import NC_ARGS, T, PlcProcess, exclusive, power_on
from znc_testing.until import wait_until


def test_nc_server_with_cia402_sim_drives_powers_and_moves(
        start_nc: Callable[..., NcServerProcess], nc_client: Callable[..., NcTestClient]) -> None:
    nc = start_nc(extra_args=(*NC_ARGS, "--set", "nc.drive=cia402-sim"))
    obs = nc_client(nc.port, "observer")
    obs.watch("nc/nc1/stats")
    plc = PlcProcess(nc.endpoint, "plc-a")
    try:
        plc.wait_started()
        r = power_on(plc)
        assert r.o["Status"] and not r.o["Error"] and r.a["State"] == "STANDSTILL"
        plc.set("mv", "MC_MoveAbsolute", Execute=True, Position=40.0, Velocity=200.0)
        done = plc.wait("mv", lambda r: r.o["Done"], T)
        assert math.isclose(done.a["ActPos"], 40.0, abs_tol=0.02) and done.a["State"] == "STANDSTILL"
        exclusive(plc.history("mv"))
        plc.set("mr", "MC_MoveRelative", Execute=True, Distance=-15.0, Velocity=100.0)
        done = plc.wait("mr", lambda r: r.o["Done"], T)
        assert math.isclose(done.a["ActPos"], 25.0, abs_tol=0.02)
        stats = wait_until(lambda: (s := obs.stats()) is not None and "drive_errors" in s and s, T,
                           what="stats with drive_errors")
        assert stats["drive_errors"] == {}  # no drive reports an error
    finally:
        plc.stop()
