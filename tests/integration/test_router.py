"""Two NC servers behind one ``nc-router``: clients reach both through the router alone.

Real processes on 127.0.0.1: the router listens, both NCs run in client mode (``--mode client
--connect``), the test's client connects only to the router.
"""
from __future__ import annotations

from pathlib import Path

import pytest

from znc_testing import (BIT_CONTROL_LOOP_CLOSED, NcTestClient, start_nc_router, start_nc_server,
                         wait_until)
from znc_testing.plc_harness import NC_ARGS


@pytest.fixture
def router_and_ncs(tmp_path: Path):
    router = start_nc_router(tmp_path / "router")
    ncs = []
    try:
        for name in ("nc1", "nc2"):
            ncs.append(start_nc_server(tmp_path / name, name=name, extra_args=["--name", name, *NC_ARGS],
                                       connect=router.endpoint))
        yield router, ncs
    finally:
        for h in ncs:
            h.kill()
        router.kill()


def test_clients_reach_two_ncs_through_the_router(router_and_ncs) -> None:
    router, ncs = router_and_ncs
    assert all(h.port == router.port for h in ncs)
    c1 = NcTestClient(router.port, client_id="r1", nc="nc1")
    c2 = NcTestClient(router.port, client_id="r1b", nc="nc2")
    try:
        for c, name in ((c1, "nc1"), (c2, "nc2")):
            info = wait_until(lambda c=c: c.request("Info"), 30, f"Info from {name} via the router")
            assert info["error"] == 0 and info["Value"]["name"] == name
        # one NC's axis moves, commanded through the router; the other's stays put
        c1.claim(1)
        c1.feed_plctonc([1])  # (from a thread of pytest: NC_ARGS' 3 s watchdog tolerates its stalls)
        wait_until(lambda: c1.nctoplc(1) is not None and c1.nctoplc(1)["StateDWord"] & BIT_CONTROL_LOOP_CLOSED,
                   30, "nc1 axis 1 enabled")
        r = c1.request("MoveAbsolute", axis=1, Position=5.0, Velocity=100.0)
        assert r["error"] == 0, r
        wait_until(lambda: abs(float(c1.nctoplc(1)["ActPos"]) - 5.0) < 1e-6, 30, "nc1 axis 1 at 5.0")
        wait_until(lambda: c2.nctoplc(1) is not None, 30, "nc2 axis 1 status")
        assert float(c2.nctoplc(1)["ActPos"]) == 0.0
    finally:
        c1.close()
        c2.close()
