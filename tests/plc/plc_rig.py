"""Fixtures for the PLC-side unit tests: a real in-process NcCore driven by InProcessPlc tasks.

Timing: NC cycle 1 ms, PLC cycle 10 ms -> 10 NC steps per PLC cycle; time is virtual
(``plc.now = plc.cycle * 0.01``), so nothing sleeps.
"""
from __future__ import annotations

from typing import Any, Callable

import numpy as np
from nc_server.core import AxisConfig, AxisParams, NcCore
from nc_server.drives.sim import SimDrive
from plc_client import InProcessPlc

NC_CYCLE = 0.001
PLC_CYCLE = 0.010
STEPS = round(PLC_CYCLE / NC_CYCLE)


def check_exclusive(fb: Any) -> None:
    """PLCopen: Busy/Done/Error/CommandAborted mutually exclusive; Active only with Busy
    (MC_Stop: Busy+Active+Done while locked is the documented exception)."""
    names = [n for n in ("Busy", "Done", "InVelocity", "Error", "CommandAborted") if hasattr(fb, n)]
    on = [n for n in names if getattr(fb, n)]
    if type(fb).__name__ == "MC_Stop" and set(on) == {"Busy", "Done"}:
        assert fb.Active
        return
    assert len(on) <= 1, f"{type(fb).__name__}: {on} TRUE together"
    if getattr(fb, "Active", False):
        assert fb.Busy, f"{type(fb).__name__}: Active without Busy"
    if not fb.Error:
        assert fb.ErrorID == 0


class Rig:
    """One NcCore and any number of in-process PLC clients stepped in lockstep.

    ``rig.run(n)`` runs n PLC cycles: each client's ``step()`` (snapshot, program, PLCTONC),
    then 10 NC steps. Every ExecuteBlock registered with :meth:`watch` is checked for output
    exclusivity after every cycle, and its outputs are recorded in ``rig.trace[fb]``.
    """

    def __init__(self, n_axes: int = 2, params: AxisParams | None = None, drive_cls: type | None = None) -> None:
        p = params or AxisParams()
        cfg = [AxisConfig(AxisId=i + 1, Name=f"A{i + 1}", params=AxisParams(**vars(p))) for i in range(n_axes)]
        drive = drive_cls([c.params for c in cfg], NC_CYCLE) if drive_cls else None
        self.core = NcCore(cfg, cycle_time=NC_CYCLE, drive=drive)
        self.plcs: dict[str, InProcessPlc] = {}
        self.watched: list[Any] = []
        self.trace: dict[int, list[dict[str, Any]]] = {}
        self.nc_running = True

    def plc(self, client_id: str = "plc1", program: Callable[[Any], None] | None = None, **kw: Any) -> InProcessPlc:
        kw.setdefault("cycle_time", PLC_CYCLE)
        t = InProcessPlc(self.core, program, client_id=client_id, **kw)
        self.plcs[client_id] = t
        return t

    def watch(self, *fbs: Any) -> None:
        for fb in fbs:
            self.watched.append(fb)
            self.trace[id(fb)] = []

    def outputs(self, fb: Any) -> list[dict[str, Any]]:
        return self.trace[id(fb)]

    def run(self, n: int = 1, until: Callable[[], bool] | None = None) -> int:
        for k in range(1, n + 1):
            for t in self.plcs.values():
                t.step()
            for fb in self.watched:
                check_exclusive(fb)
                self.trace[id(fb)].append({o: getattr(fb, o) for o in fb._OUTPUTS})
            if self.nc_running:
                for _ in range(STEPS):
                    self.core.step()
            if until is not None and until():
                return k
        return n

    def run_until(self, cond: Callable[[], bool], limit: int = 1000) -> int:
        n = self.run(limit, until=cond)
        assert cond(), f"condition not reached in {limit} cycles"
        return n

    def rec(self, axis_id: int = 1) -> np.void:
        return self.core.nctoplc[self.core.index(axis_id)]


class OffsetDrive(SimDrive):
    """A simulated drive that settles 0.5 u short of the set position (never in the 0.02 target window)."""

    def step(self, enabled: np.ndarray, set_pos: np.ndarray, set_velo: np.ndarray, set_acc: np.ndarray) -> None:
        super().step(enabled, set_pos - 0.5 * enabled, set_velo, set_acc)

