"""NC restart detection: the one rule every client applies (PLC runtime, nc-ads, nc-status).

A restart is a new NC *process instance*, and only the status frames show one: an instance counts its
cycles from 1 (frame header ``Cycle``, schema/README.md "Time and ordering"), so a frame whose
``Cycle`` is below the previous frame's comes from a new instance. The NC's liveliness token
``nc/<nc>/alive`` is no such evidence: it disappears whenever the client's zenoh link to the NC is
dropped, and zenoh drops a link when either side hears nothing for the other side's lease (500 ms by
default here) - a starved or SIGSTOPped client, NC or router on a loaded machine - then reconnects
within 0.1-0.3 s and the token is back while the same NC ran on. So a token that goes means "NC
unreachable" (its data is invalid: the clients' stale handling), never a restart by itself.

What the frames cannot show (zenoh-nc's choice, documented): a new instance whose first frame a client
sees has counted at least as many cycles as the old one's last frame it saw (the old one ran shorter
than the client's outage plus the new one's age then). ``NcTimeNs`` does not help: an NC frozen for
longer than it had run before shows the same header stamps as a new one. nc-ads then still learns
from the NC's claims map that its claims are gone; a PLC's MC_Power waits for an enable the new NC
does not apply until its Enable is toggled.

Pure (no zenoh, no clock): the caller passes each frame's ``Cycle``.
"""
from __future__ import annotations


class NcInstance:
    """Which NC instance one client's frames come from (see the module docstring).

    Attributes:
        cycle: ``Cycle`` of the newest frame (None before the first).
        restarts: how many new instances were seen.
    """

    __slots__ = ("cycle", "restarts")

    def __init__(self) -> None:
        self.cycle: int | None = None
        self.restarts = 0

    def frame(self, cycle: int) -> str | None:
        """Take a frame's ``Cycle``.

        Returns:
            None for the same instance; for a new one the reason (for the log), counted in ``restarts``.
        """
        cycle = int(cycle)
        why = None
        if self.cycle is not None and cycle < self.cycle:
            why = "its cycle counter went back"
            self.restarts += 1
        self.cycle = cycle
        return why
