"""Fixtures of the inspection-tool tests (nc-status, nc-scope, zenoh-cli codecs; helpers in
znc_testing.tools_testing).

``rig``: one real ``nc-server`` per test module (default config: ``nc1``, axes 1-4, a lenient
watchdog) and a client ``t1`` (liveliness token, PLCTONC feeder) that enables axes on request;
the server's process group is killed at the end of the module, pass or fail.
"""
from __future__ import annotations

from typing import Iterator

import pytest

from znc_testing.tools_testing import Rig
from znc_testing import NcTestClient, start_nc_server


@pytest.fixture(scope="module")
def rig(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Rig]:
    srv = start_nc_server(tmp_path_factory.mktemp("nc"), extra_args=("--watchdog-timeout", "3.0"))
    cl = None
    try:
        cl = NcTestClient(srv.port, "t1")
        yield Rig(srv, cl)
    finally:
        if cl is not None:
            cl.close()
        srv.kill()

