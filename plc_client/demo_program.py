"""The demo's PLC program: power all four default axes and keep them moving.

Run by ``zenoh-nc-demo`` with ``plc-run``; on its own::

    nc-server &
    plc-run plc_client/demo_program.py

X, Y and Z travel back and forth between two positions inside their software limits;
the modulo axis C turns three full turns (1080 degrees) one way, then back.
"""
from __future__ import annotations

from plc_client import AXIS_REF, MC_MoveAbsolute, MC_MoveRelative, MC_Power, MC_Reset


class Shuttle:
    """One axis moving back and forth between two positions with MC_MoveAbsolute."""

    def __init__(self, axis: AXIS_REF, a: float, b: float, velocity: float) -> None:
        self.axis, self.a, self.b, self.velocity = axis, a, b, velocity
        self.power, self.move, self.reset = MC_Power(), MC_MoveAbsolute(), MC_Reset()
        self.to_b = True

    def cycle(self) -> None:
        self.power(Axis=self.axis, Enable=True, Enable_Positive=True, Enable_Negative=True)
        self.reset(Axis=self.axis, Execute=self.axis.Status.ErrorStop and not self.reset.Busy)
        target = self.b if self.to_b else self.a
        self.move(Axis=self.axis, Execute=self.power.Status and not self.axis.Status.ErrorStop,
                  Position=target, Velocity=self.velocity)
        if self.move.Done or self.move.Error or self.move.CommandAborted:
            if self.move.Done:
                self.to_b = not self.to_b
            self.move(Execute=False)


class Turner:
    """The modulo axis: three full turns forward, then three back (MC_MoveRelative)."""

    def __init__(self, axis: AXIS_REF, velocity: float) -> None:
        self.axis, self.velocity = axis, velocity
        self.power, self.move = MC_Power(), MC_MoveRelative()
        self.forward = True

    def cycle(self) -> None:
        self.power(Axis=self.axis, Enable=True, Enable_Positive=True, Enable_Negative=True)
        self.move(Axis=self.axis, Execute=self.power.Status, Distance=1080.0 if self.forward else -1080.0,
                  Velocity=self.velocity)
        if self.move.Done or self.move.Error or self.move.CommandAborted:
            if self.move.Done:
                self.forward = not self.forward
            self.move(Execute=False)


class Program:
    """What the PLC task calls every cycle."""

    def __init__(self, nc: str = "nc1") -> None:
        self.parts = [
            Shuttle(AXIS_REF(nc=nc, axis_id=1), 0.0, 400.0, 300.0),
            Shuttle(AXIS_REF(nc=nc, axis_id=2), 0.0, 250.0, 200.0),
            Shuttle(AXIS_REF(nc=nc, axis_id=3), 0.0, -150.0, 120.0),
            Turner(AXIS_REF(nc=nc, axis_id=4), 540.0),
        ]

    def cycle(self) -> None:
        for part in self.parts:
            part.cycle()
