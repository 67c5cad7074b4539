"""A PLC task against an in-process ``NcCore``: :class:`InProcessPlc` and :func:`run_cycles` (tests and
simulations without zenoh; virtual time, no threads).

Moved here from ``plc_client.task`` (issue 16), with the in-process NC it drives (:mod:`nc_sim.port`).

May import: ``nc_server`` (through :mod:`nc_sim.port`), ``plc_client``, ``nc_schema``.
"""
from __future__ import annotations

from typing import Any, Callable

import numpy as np

from plc_client.axis_ref import AXIS_REF
from plc_client.task import PlcTask

from .port import InProcessNc, InProcessPort


class InProcessPlc(PlcTask):
    """A PLC task bound to an in-process ``NcCore`` (tests, simulations; no zenoh, no threads).

    ``step()`` snapshots ``core.nctoplc`` (the frame of ``core.cycle``), runs the program
    (commands go through :class:`~plc_client.port.InProcessPort`, i.e. nc-server's request
    handler) and sends one PLCTONC frame through the server's per-cycle path
    (:meth:`InProcessPort.publish_plctonc`): applied only to the axes this client holds, feeding
    the watchdog, which runs right after it. It does **not** step the core: call ``core.step()``
    yourself (or use :func:`run_cycles`), so several PLC clients can share one core. Time is
    virtual: ``now = cycle * cycle_time``, so timeouts need no sleeping. :meth:`close` makes the
    client disappear (its claimed axes fault with 0x8F01).

    Args:
        core: the NcCore, or its :class:`~plc_client.port.InProcessNc`.
        program: see :class:`PlcTask`.
        nc: the NC name of this core (AXIS_REF.nc).
        **kw: PlcTask arguments (cycle_time, client_id, stale_cycles, command_timeout, ...).
    """

    def __init__(self, core: Any, program: Any = None, *, nc: str = "nc1", client_id: str = "plc1",
                 **kw: Any) -> None:
        super().__init__(program, client_id=client_id, **kw)
        self.port = InProcessPort(core, client_id=client_id, nc=nc)
        self.core = self.port.core
        self.nc = nc
        self.port.clock = lambda: self.now
        self.bind_axes()

    def clock(self) -> float:
        return self.cycle * self.cycle_time

    def _take_frames(self) -> None:
        self._set_frame(self.nc, int(self.core.cycle), self.core.nctoplc, getattr(self.core, "ncjobs", None))

    def _publish(self, nc: str, axes: list[AXIS_REF]) -> None:
        if nc != self.nc:
            return
        port = self.port
        assert isinstance(port, InProcessPort)
        # One frame, as PlcRuntime publishes it; the server side decides what it may enable.
        ids = np.fromiter((ax.axis_id for ax in axes), dtype=np.int64, count=len(axes))
        port.publish_plctonc(ids, np.concatenate([ax._plctonc for ax in axes]))

    def close(self) -> None:
        """The client disappears (idempotent): see :meth:`InProcessPort.close`."""
        self.port.close()


def run_cycles(core: Any, plcs: PlcTask | list[PlcTask], cycles: int = 1, nc_steps: int = 1,
               until: Callable[[], bool] | None = None) -> int:
    """Run ``cycles`` PLC cycles of every task in ``plcs``, stepping ``core`` ``nc_steps`` times
    after each PLC cycle. Stops early when ``until()`` becomes true (checked after each cycle).

    Before each NC step the core's in-process watchdog runs (:meth:`InProcessNc.cycle`), as
    nc-server checks it every cycle: a holder that stops sending PLCTONC faults with 0x8F02.

    Returns the number of cycles run.
    """
    tasks = plcs if isinstance(plcs, list) else [plcs]
    for n in range(1, cycles + 1):
        for t in tasks:
            t.step()
        for _ in range(nc_steps):
            srv = InProcessNc.registered(core)
            if srv is not None:
                srv.cycle()
            core.step()
        if until is not None and until():
            return n
    return cycles
