"""The demo's PLC program: power all four default axes and keep them moving.

Run by ``zenoh-nc-demo`` with ``plc-run``; on its own::

    nc-server &
    plc-run plc_client/demo_program.py

X, Y and Z travel back and forth between two positions inside their software limits;
the modulo axis C turns three full turns (1080 degrees) one way, then back.

Each axis runs a step sequence (:class:`Shuttle`): motion is started by the sequence, never by an
edge of MC_Power.Status (Status falls while the NC's data is stale, 0x4B0F, and rises again by
itself; see ``MC_Power``).
"""
from __future__ import annotations

from plc_client import AXIS_REF, MC_MoveAbsolute, MC_Power, MC_Reset

#: the steps of :class:`Shuttle`
WAIT, MOVE, FAILED = 0, 10, 30


class Shuttle:
    """One axis moving back and forth between two positions with MC_MoveAbsolute.

    Steps (a CASE in ST): WAIT until the axis is ready (MC_Power.Status), MOVE with Execute TRUE
    until the move ends (Done: the other position next, via WAIT, so that Execute falls for a
    cycle), FAILED after an error or an abort: MC_Reset while the axis is in ErrorStop, then WAIT.
    After a failure the program goes on on purpose, to the same position (an absolute target: an
    interrupted leg is finished, never travelled twice).
    """

    def __init__(self, axis: AXIS_REF, a: float, b: float, velocity: float) -> None:
        self.axis, self.a, self.b, self.velocity = axis, a, b, velocity
        self.power, self.move, self.reset = MC_Power(), MC_MoveAbsolute(), MC_Reset()
        self.to_b = True
        self.step = WAIT

    def cycle(self) -> None:
        st = self.axis.Status
        self.power(Axis=self.axis, Enable=True, Enable_Positive=True, Enable_Negative=True)
        if self.step == WAIT:
            if self.power.Status:
                self.step = MOVE
        elif self.step == MOVE:
            if self.move.Done:
                self.to_b = not self.to_b
                self.step = WAIT
            elif self.move.Error or self.move.CommandAborted:
                self.step = FAILED
        elif self.step == FAILED:
            if self.power.Status and not self.reset.Busy:
                self.step = WAIT
        # a reset pulse while the axis shows ErrorStop (a new edge if one did not clear it)
        self.reset(Axis=self.axis, Execute=self.step == FAILED and st.Valid and st.ErrorStop
                   and not (self.reset.Done or self.reset.Error))
        self.move(Axis=self.axis, Execute=self.step == MOVE, Position=self.b if self.to_b else self.a,
                  Velocity=self.velocity)


class Program:
    """What the PLC task calls every cycle."""

    def __init__(self, nc: str = "nc1") -> None:
        self.parts = [
            Shuttle(AXIS_REF(nc=nc, axis_id=1), 0.0, 400.0, 300.0),
            Shuttle(AXIS_REF(nc=nc, axis_id=2), 0.0, 250.0, 200.0),
            Shuttle(AXIS_REF(nc=nc, axis_id=3), 0.0, -150.0, 120.0),
            Shuttle(AXIS_REF(nc=nc, axis_id=4), 0.0, 1080.0, 540.0),  # C: three turns and back
        ]

    def cycle(self) -> None:
        for part in self.parts:
            part.cycle()
