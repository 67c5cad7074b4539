"""The test suite's helpers: one package, imported one way (``from znc_testing import ...`` or
``from znc_testing.<module> import ...``). ``tests/conftest.py`` puts ``tests/`` on ``sys.path`` once;
no test directory adds paths of its own.

Owns the helpers shared by the test directories; the front (this module) re-exports the most used ones:

* :mod:`znc_testing.until`: :func:`wait_until` (wall clock) and :func:`step_until` (cycles), the only
  two waiting loops of the suite;
* :mod:`znc_testing.nc_process`: a real ``nc-server`` / ``nc-router`` process and a zenoh client of it;
  :func:`start_with_port_retry`, the one start-on-a-free-port loop (also nc-ads');
* per test directory: :mod:`~znc_testing.plc_rig` (tests/plc), :mod:`~znc_testing.plc_harness`,
  :mod:`~znc_testing.failsafe_support`, :mod:`~znc_testing.failsafe_recovery` (tests/integration),
  :mod:`~znc_testing.ads_testing`, :mod:`~znc_testing.nc_ads_testing` (tests/ads),
  :mod:`~znc_testing.hostlib` (tests/hosts), :mod:`~znc_testing.standby_rig` (tests/drives, bench/takeover.py), :mod:`~znc_testing.sec_testing` (tests/security),
  :mod:`~znc_testing.tools_testing` (tests/tools), :mod:`~znc_testing.nc_core` and
  :mod:`~znc_testing.engine_check` (the core's tests). The programs the tests start as processes
  (``plc_agent.py``, ``failsafe_client.py``, ...) stay beside the tests that run them.

May import: the project's packages, the standard library and the test dependencies (pytest, numpy,
zenoh, msgpack); never a test module (``test_*.py``) or a ``conftest.py``.
"""
from znc_testing.nc_process import (
    BIT_CONTROL_LOOP_CLOSED, BIT_ERROR, BIT_OPERATIONAL, ENABLE_ALL, READY_TIMEOUT, RETAIN_CONFIG, NcServerProcess,
    NcTestClient, ReplyError, free_port, kill_process_group, nc_router_command, nc_server_command, start_nc_router,
    start_nc_server, start_with_port_retry, unpack, zenoh_client_config,
)
from znc_testing.until import done, step_until, wait_until

__all__ = [
    "BIT_CONTROL_LOOP_CLOSED", "BIT_ERROR", "BIT_OPERATIONAL", "ENABLE_ALL", "READY_TIMEOUT", "RETAIN_CONFIG",
    "NcServerProcess", "NcTestClient", "ReplyError", "done", "free_port", "kill_process_group", "nc_router_command",
    "nc_server_command", "start_nc_router", "start_nc_server", "start_with_port_retry", "step_until", "unpack", "wait_until",
    "zenoh_client_config",
]
