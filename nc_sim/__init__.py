"""nc_sim: the NC in the same process, for tests and simulations without zenoh.

* :class:`InProcessPlc` - a PLC task (``plc_client.PlcTask``, the same function blocks and claim rules as
  ``plc-run``) bound to an in-process ``nc_server.core.NcCore``; :func:`run_cycles` steps tasks and core.
* :class:`InProcessPort` - a command port that drives the core through nc-server's own request handler;
  :class:`InProcessNc` - that server side (handler, claim table, watchdog), one per core.

Example::

    from nc_server.core import NcCore
    from nc_sim import InProcessPlc, run_cycles

    core = NcCore(...)
    plc = InProcessPlc(core, program)
    run_cycles(core, plc, 100, nc_steps=10)

The only package that joins both sides: it may import ``nc_server``, ``plc_client`` and ``nc_schema``;
no production package imports it (tests/test_import_graph.py).
"""
from .plc import InProcessPlc, run_cycles
from .port import InProcessNc, InProcessPort

__all__ = ["InProcessPlc", "run_cycles", "InProcessPort", "InProcessNc"]
