"""Masters on other NCs: their set-point samples, as the cycle's input, and what a slave follows.

A slave of this NC may follow an axis of another NC (MC_GearIn with ``MasterNc``). The server hands the
master's per-cycle samples (its NCTOPLC SetPos/SetVelo/SetAcc/SetJerk with the frame's Cycle and NcTimeNs)
to the core through ONE input, :meth:`NcCore.set_remote_samples` (like ``set_plctonc``): the core never reads
the network, so a standby NC that replays the same inputs computes the same set-points.

The transport delay is compensated by extrapolating from the newest sample to the slave cycle's NcTimeNs
(``tau`` = slave time - sample time) with the master's velocity and acceleration:
``p = p0 + v0 tau + a0 tau^2 / 2``. Its error is the triple integral of the jerk over ``tau``, so at most
``J tau^3 / 6`` with J the largest |jerk| of the master over that span: the bound the phase error is judged by.
(Extrapolating with the jerk too is exact within one jerk segment but can be off by twice that across a
jerk switch: the velocity and acceleration form keeps the stated bound.)

The phase error is measured afterwards, when later samples cover a slave cycle's time: the master's SetPos
at that time from the newest sample at or before it (its Taylor polynomial with the jerk: exact within a
constant-jerk segment), compared with the position extrapolated then. Both NCs' NcTimeNs must come from
the same clock (one host: CLOCK_REALTIME; different hosts: PTP or chrony-disciplined clocks, whose offset
adds ``v x offset`` to the phase error: docs/coupling-across-ncs.md).

It may import: nc_schema, numpy.
"""
from __future__ import annotations

import collections
import math
from dataclasses import dataclass
from typing import Iterable, Sequence

from nc_schema import CoupleState, ErrorCodes, NcError

#: samples kept per master (for the phase measurement: covers ``HISTORY`` master cycles of delay)
HISTORY = 256
#: a master's samples of a lower epoch than the highest taken are taken again once their NcTimeNs is this far past
#: the newest sample of that epoch [ns] (nc_schema.instance.EPOCH_HOLD_S: the higher-epoch NC is gone)
EPOCH_HOLD_NS = 5_000_000_000
_SLAVE_STATES = (int(CoupleState.SLAVE), int(CoupleState.MASTERSLAVE))


@dataclass(frozen=True)
class MasterSample:
    """One cycle of a remote master axis, as its NC published it."""

    nc: str
    axis_id: int
    cycle: int
    nc_time_ns: int
    set_pos: float
    set_velo: float
    set_acc: float
    set_jerk: float
    couple_state: int = 0
    epoch: int = 0  # (protocol 5: the master NC's epoch, its STAMP's; 0 without redundancy)


class RemoteMasters:
    """The remote master axes this NC may couple to (configured) and their newest samples.

    Args:
        own_nc: this NC's name (a master named with it is refused: that is the local path).
        sources: (nc, AxisId) of the masters, as configured ([remote] masters).
        max_age_ns: a sample older than this (slave time - sample time) is no master any more.
    """

    def __init__(self, own_nc: str = "", sources: Sequence[tuple[str, int]] = (), max_age_ns: int = 50_000_000) -> None:
        self.own_nc = own_nc
        self.sources = [(str(nc), int(ax)) for nc, ax in sources]
        self.max_age_ns = int(max_age_ns)
        self._index = {s: k for k, s in enumerate(self.sources)}
        self.hist: list[collections.deque[tuple[int, float, float, float, float]]] = [
            collections.deque(maxlen=HISTORY) for _ in self.sources]
        self.couple_state = [0] * len(self.sources)
        self.cycle = [0] * len(self.sources)
        self.received = [0] * len(self.sources)
        self.ignored = 0  # samples out of order, non-finite or of masters not configured
        #: per master, the highest epoch of its NC taken (a hot-standby pair's, protocol 5), and the samples dropped
        #: for a lower one (its old active NC's after a link cut: its own plan, not the master's)
        self.epoch = [0] * len(self.sources)
        self.stale_epoch = 0

    def name(self, k: int) -> str:
        nc, ax = self.sources[k]
        return f"{nc}/{ax}"

    def find(self, nc: str, axis_id: int) -> int:
        """The index of master ``nc``/``axis_id``.

        Raises:
            NcError: 0x4B06 this NC itself; 0x4012 a master not configured.
        """
        if nc == self.own_nc:
            raise NcError(ErrorCodes.MC_PARAMETER_NOT_CORRECT,
                          f"MasterNc {nc!r} is this NC: couple to a local master without MasterNc")
        k = self._index.get((nc, int(axis_id)))
        if k is None:
            listed = ", ".join(self.name(x) for x in range(len(self.sources))) or "none"
            raise NcError(ErrorCodes.NC_AXIS_ID_NOT_ALLOWED,
                          f"no remote master {nc}/{axis_id}: not in this NC's [remote] masters ({listed})")
        return k

    def feed(self, samples: Iterable[MasterSample]) -> None:
        """Take the samples that arrived since the last cycle (any order; older than the newest: ignored). A sample of
        a lower epoch than the master's highest taken is dropped (``stale_epoch``), unless its NcTimeNs is
        EPOCH_HOLD_NS past the newest sample taken (the receiver rule of the clients, nc_schema.NcInstance.take,
        in the master's time); a higher epoch is taken at once."""
        for s in samples:
            k = self._index.get((s.nc, int(s.axis_id)))
            vals = (s.set_pos, s.set_velo, s.set_acc, s.set_jerk)
            h = self.hist[k] if k is not None else None
            if h is None or not all(math.isfinite(v) for v in vals):
                self.ignored += 1
                continue
            assert k is not None
            epoch = int(s.epoch)
            if epoch < self.epoch[k] and h and s.nc_time_ns - h[-1][0] < EPOCH_HOLD_NS:
                self.stale_epoch += 1
                continue
            if epoch > self.epoch[k]:
                self.epoch[k] = epoch  # (at once: even a sample behind the newest, ignored below, raises it)
            if h and s.nc_time_ns <= h[-1][0]:
                self.ignored += 1
                continue
            self.epoch[k] = epoch
            h.append((int(s.nc_time_ns), float(s.set_pos), float(s.set_velo), float(s.set_acc), float(s.set_jerk)))
            self.couple_state[k] = int(s.couple_state)
            self.cycle[k] = int(s.cycle)
            self.received[k] += 1

    def age_ns(self, k: int, t_ns: int) -> int | None:
        """Age of master ``k``'s newest sample at time ``t_ns``; None: none yet."""
        h = self.hist[k]
        return int(t_ns) - h[-1][0] if h else None

    def check_fresh(self, k: int, t_ns: int) -> None:
        """Raises NcError 0x4012 when master ``k`` has no sample within ``max_age_ns``; 0x4B06 when it is a
        coupled slave itself (chains across NCs start at an uncoupled master: no cycle across NCs)."""
        age = self.age_ns(k, t_ns)
        if age is None or abs(age) > self.max_age_ns:  # (from the future: the two NCs' clocks are apart)
            what = ("no sample yet" if age is None else f"newest sample {age / 1e6:.1f} ms old" if age > 0 else
                    f"newest sample {-age / 1e6:.1f} ms in the future (the NCs' clocks differ: docs/coupling-across-ncs.md)")
            raise NcError(ErrorCodes.NC_AXIS_ID_NOT_ALLOWED,
                          f"remote master {self.name(k)}: {what} (NC not running, no such axis, or not allowed "
                          f"to read it; max_age {self.max_age_ns / 1e6:g} ms)")
        if self.couple_state[k] in _SLAVE_STATES:
            raise NcError(ErrorCodes.MC_PARAMETER_NOT_CORRECT,
                          f"remote master {self.name(k)} is itself a coupled slave: a coupling across NCs must start at "
                          f"an uncoupled master (no chains or cycles across NCs)")

    def state(self, k: int, t_ns: int) -> tuple[float, float, float, float, int] | None:
        """(pos, velo, acc, jerk, age [ns]) of master ``k`` extrapolated to ``t_ns`` from its newest sample with
        its velocity and acceleration; None without a sample."""
        h = self.hist[k]
        if not h:
            return None
        t0, p, v, a, j = h[-1]
        age = int(t_ns) - t0
        tau = age * 1e-9
        return p + tau * (v + 0.5 * a * tau), v + a * tau, a, j, age

    def actual(self, k: int, t_ns: int, since_ns: int) -> tuple[float, float] | None:
        """The master's SetPos at ``t_ns`` from the newest sample at or before it (with the jerk), and the largest
        |SetJerk| of the samples from ``since_ns`` to the first one at or after ``t_ns``; None while no sample at or
        after ``t_ns`` arrived (or the history does not reach back to it)."""
        h = self.hist[k]
        if not h or h[-1][0] <= t_ns or h[0][0] > t_ns:
            return None
        before = None
        jmax = after = 0.0  # (after: |jerk| of the oldest sample at or after t_ns seen so far)
        for s in reversed(h):  # (newest first: the cycles measured are a few samples back)
            if s[0] > t_ns:
                after = abs(s[4])
                continue
            if before is None:
                before = s
            jmax = max(jmax, abs(s[4]))
            if s[0] <= since_ns:  # (the sample extrapolated from: its jerk was in force from since_ns)
                break
        jmax = max(jmax, after)
        assert before is not None
        t0, p, v, a, j = before
        tau = (int(t_ns) - t0) * 1e-9
        return p + tau * (v + tau * (0.5 * a + tau * j / 6.0)), jmax
