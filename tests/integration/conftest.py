"""Fixtures of the integration tests that drive PLC processes (helpers in znc_testing.plc_harness).

* ``nc``: an ``nc-server`` with the embedded default configuration (axes 1-4, axis 4 modulo 360)
  and a lenient watchdog (``plc_harness.NC_ARGS``) on a free port; its process group is killed at
  the end, pass or fail (``start_nc``);
* ``plc``: a ``plc-run plc_agent.py`` process connected to it, stopped (process group killed) at
  the end.
"""
from __future__ import annotations

from typing import Callable, Iterator

import pytest

from znc_testing.plc_harness import NC_ARGS, STALE_ARGS, PlcProcess
from znc_testing import NcServerProcess


@pytest.fixture
def nc(start_nc: Callable[..., NcServerProcess]) -> NcServerProcess:
    return start_nc(extra_args=NC_ARGS)


@pytest.fixture
def plc(nc: NcServerProcess) -> Iterator[PlcProcess]:
    p = PlcProcess(nc.endpoint, "plc-a", extra=list(STALE_ARGS))
    try:
        p.wait_started()
        yield p
    finally:
        p.stop()
