"""NC restart detection: the one rule every client applies (PLC runtime, nc-ads, nc-status).

A restart is a new NC *process instance*, and only the status frames show one. The NC's liveliness
token ``nc/<nc>/alive`` is no such evidence: it disappears whenever the client's zenoh link to the NC
is dropped, and zenoh drops a link when either side hears nothing for the other side's lease (500 ms
by default here) - a starved or SIGSTOPped client, NC or router on a loaded machine - then reconnects
within 0.1-0.3 s and the token is back while the same NC ran on. So a token that goes means "NC
unreachable" (its data is invalid: the clients' stale handling), never a restart by itself.

An instance counts its cycles from 1 (frame header ``Cycle``) and stamps each frame with the NC time of
that cycle (``NcTimeNs``: CLOCK_REALTIME at its scheduled start; a missed cycle is skipped, so the NC
time runs ahead of ``Cycle`` x cycle time by the missed cycles; schema/README.md "Time and ordering").
:class:`NcInstance` declares a new instance when a frame

1. has a ``Cycle`` below the previous frame's (the counter went back), or
2. has an ``NcTimeNs`` later than the previous frame's by more than :data:`MIN_GAP_NS` *and* by more
   than its whole ``Cycle`` count takes (``(Cycle - 1) x`` the cycle time, learnt as the shortest NC
   time per cycle between two frames): that instance started after the previous frame. A new NC
   counts cycles before its first frame reaches anybody (its cycle starts while its frame publisher,
   a child process, is still starting: seconds on a loaded machine), so its first frame can carry a
   higher ``Cycle`` than the old instance's last when that one ran only seconds (a test under load
   missed such a restart with rule 1 alone). The same instance would have had to stand still for longer than
   :data:`MIN_GAP_NS` and than its whole life before: an NC frozen that long has stopped its moving
   axes itself (0x8F03).

Pure (no zenoh, no clock): the caller passes each frame's header fields.
"""
from __future__ import annotations

#: Rule 2 needs at least this much NC time between two frames [ns] (see the module docstring).
MIN_GAP_NS = 5_000_000_000


class NcInstance:
    """Which NC instance one client's frames come from (see the module docstring).

    Attributes:
        cycle: ``Cycle`` of the newest frame (None before the first).
        nc_time_ns: its ``NcTimeNs`` [ns] (None: not known).
        cycle_ns: the shortest NC time per cycle seen between two frames of this instance [ns]: its
            cycle time, or more while every pair seen had missed cycles in between (None: not yet).
        restarts: how many new instances were seen.
    """

    __slots__ = ("cycle", "nc_time_ns", "cycle_ns", "restarts")

    def __init__(self) -> None:
        self.cycle: int | None = None
        self.nc_time_ns: int | None = None
        self.cycle_ns: int | None = None
        self.restarts = 0

    def frame(self, cycle: int, nc_time_ns: int | None = None) -> str | None:
        """Take a frame's ``Cycle`` and ``NcTimeNs`` [ns] (None: unknown; then only rule 1 applies).

        Returns:
            None for the same instance; for a new one the reason (for the log), counted in ``restarts``.
        """
        cycle = int(cycle)
        t = None if nc_time_ns is None else int(nc_time_ns)
        why = None
        if self.cycle is not None:
            if cycle < self.cycle:
                why = "its cycle counter went back"
            elif t is not None and self.nc_time_ns is not None:
                gap = t - self.nc_time_ns
                if self.cycle_ns is not None and gap > max(MIN_GAP_NS, (cycle - 1) * self.cycle_ns):
                    why = f"its NC time ran {gap / 1e9:.1f} s on, more than its {cycle} cycles take"
                elif cycle > self.cycle and gap > 0:
                    per = gap // (cycle - self.cycle)
                    self.cycle_ns = per if self.cycle_ns is None else min(self.cycle_ns, per)
        if why is not None:
            self.restarts += 1
            self.cycle_ns = None  # the new instance may run another cycle time
        self.cycle, self.nc_time_ns = cycle, t
        return why
