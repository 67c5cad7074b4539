"""The test suite's helpers: one package, imported one way (``from znc_testing import ...`` or
``from znc_testing.<module> import ...``). ``tests/conftest.py`` puts ``tests/`` on ``sys.path`` once;
no test directory adds paths of its own.

Owns the helpers shared by the test directories; the front (this module) re-exports the most used ones:

* :mod:`znc_testing.until`: :func:`wait_until` (wall clock) and :func:`step_until` (cycles), the only
  two waiting loops of the suite;
* :mod:`znc_testing.nc_process`: a real ``nc-server`` / ``nc-router`` process and a zenoh client of it.

May import: the project's packages, the standard library and the test dependencies (pytest, numpy,
zenoh, msgpack); never a test module (``test_*.py``) or a ``conftest.py``.
"""
from znc_testing.nc_process import (
    BIT_CONTROL_LOOP_CLOSED, BIT_ERROR, BIT_OPERATIONAL, ENABLE_ALL, READY_TIMEOUT, RETAIN_CONFIG, NcServerProcess,
    NcTestClient, ReplyError, free_port, kill_process_group, nc_router_command, nc_server_command, start_nc_router,
    start_nc_server, unpack, zenoh_client_config,
)
from znc_testing.until import done, step_until, wait_until

__all__ = [
    "BIT_CONTROL_LOOP_CLOSED", "BIT_ERROR", "BIT_OPERATIONAL", "ENABLE_ALL", "READY_TIMEOUT", "RETAIN_CONFIG",
    "NcServerProcess", "NcTestClient", "ReplyError", "done", "free_port", "kill_process_group", "nc_router_command",
    "nc_server_command", "start_nc_router", "start_nc_server", "step_until", "unpack", "wait_until",
    "zenoh_client_config",
]
