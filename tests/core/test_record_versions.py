"""The change counts the frame ring relies on (``core.records.version``, ``core.plctonc_version``): whenever the
bytes of NCJOBS or of the applied PLCTONC change -- commands, job ends, faults, a MC_GearInDyn ratio ramp,
SetOverride, PLCTONC frames -- the count changes with them (a ring slot
keeps the records it holds at an unchanged count: a missed count would publish stale job records)."""
from __future__ import annotations

from typing import Any, Callable

import numpy as np

from nc_schema import ControlDWord
from znc_testing.nc_core import ALL_ENABLES, cmd, power, powered

MOVE = dict(Velocity=200.0, Acceleration=2000.0, Deceleration=2000.0, Jerk=20000.0)


class Watch:
    """Checks after every call that a change of the bytes came with a change of its count."""

    def __init__(self, core: Any) -> None:
        self.core = core
        self.seen = self._now()
        self.changes = [0, 0]

    def _now(self) -> tuple[bytes, int, bytes, int]:
        c = self.core
        return c.ncjobs.tobytes(), c.records.version, c.plctonc.tobytes(), c.plctonc_version

    def __call__(self, what: str, fn: Callable[[], Any]) -> Any:
        out = fn()
        jb, jv, pb, pv = now = self._now()
        if jb != self.seen[0]:
            assert jv != self.seen[1], f"{what}: NCJOBS changed, records.version did not"
            self.changes[0] += 1
        if pb != self.seen[2]:
            assert pv != self.seen[3], f"{what}: PLCTONC changed, plctonc_version did not"
            self.changes[1] += 1
        self.seen = now
        return out


def test_every_change_of_the_job_records_and_plctonc_is_counted() -> None:
    core = powered(4, AxisEnPositionLagMonitoring=False)
    w = Watch(core)

    def steps(k: int) -> None:
        for _ in range(k):
            w("step", core.step)

    w("GearInDyn", lambda: cmd(core, "GearInDyn", 2, Master=1, GearRatio=1.0, Acceleration=5000.0))
    w("MoveVelocity", lambda: cmd(core, "MoveVelocity", 1, Direction=1, **MOVE))
    w("MoveAbsolute", lambda: cmd(core, "MoveAbsolute", 3, Position=30.0, **MOVE))
    steps(300)
    rec = core.plctonc[1].copy()
    rec["GearRatio1"] = 1.5  # the slave's ratio ramps: GearRatio in its job record every cycle
    w("GearRatio1", lambda: core.set_plctonc(1, rec))
    steps(300)
    w("SetOverride", lambda: cmd(core, "SetOverride", 4, Override=50.0))
    w("MoveAbsolute 4", lambda: cmd(core, "MoveAbsolute", 4, Position=-20.0, **MOVE))
    recs = core.plctonc[[0, 2]].copy()
    recs["Override"] = 700_000
    w("set_plctonc_many", lambda: core.set_plctonc_many(np.array([0, 2]), recs))
    steps(200)
    w("Stop", lambda: cmd(core, "Stop", 1, Deceleration=2000.0, Jerk=20000.0))
    steps(400)
    w("feed off", lambda: power(core, 3, int(ControlDWord.Enable)))  # a fault: feed enable missing
    w("MoveVelocity 4", lambda: cmd(core, "MoveVelocity", 4, Direction=3, **MOVE))
    steps(50)
    w("feed on", lambda: power(core, 3, ALL_ENABLES))
    w("Reset", lambda: cmd(core, "Reset", 4))
    steps(200)
    assert w.changes[0] > 100 and w.changes[1] >= 4  # (the scenario changed both, often)
