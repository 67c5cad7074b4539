"""Claim table and watchdog (pure: no zenoh, no clock reads; times are passed in, in seconds).

One client at a time supplies an axis's PLCTONC: the *holder*. A client may claim only while its
liveliness token ``nc/<nc>/client/<client>`` is present. :meth:`ClaimTable.check` reports the
clients the NC lost since the last call (:class:`Loss`) and releases their claims:

* 0x8F01 ZNC_CLIENT_LOST: the client's liveliness token disappeared (process killed: within
  milliseconds; frozen or cut off: after the client's zenoh lease). Every claim it held is faulted.
* 0x8F02 ZNC_PLCTONC_TIMEOUT: a holder sent PLCTONC after claiming (the watchdog is armed by the
  first frame after the claim, or by a hand-over) and its newest frame is older than
  ``watchdog_timeout``. The claims it supplied are faulted, the others it held are released.

What the NC does with a loss (stop ramps, the axis's ``ClientLossReaction``, the motions the lost
client commanded on other axes) is :class:`~nc_server.server.handler.CycleInputs`' business.

A claim whose holder never sent a PLCTONC frame is not watched: the NC applies the default
PLCTONC (all enables off) to it, so there is nothing a silent client could keep moving.

The NC's own stalls are never blamed on a client (:meth:`ClaimTable.grace`): the PLCTONC age
starts again at the end of the stall (and never goes backwards, whatever order frames are
processed in afterwards), and a token that disappears during the stall or just after it (the
clients' zenoh dropped the link to the frozen NC and reconnects at once) is given
``reconnect_grace`` seconds to come back before it counts as a loss. After a stall of at least
half the NC's zenoh lease (``lease``) the NC's own session may not have renewed or processed the
links meanwhile: every link may be dropped and re-established (a client behind a router retries
every 100-250 ms, a loaded machine takes longer), so the window is ``lease_stall_grace``
(:data:`LEASE_STALL_GRACE`, 2 s) instead. A token that comes back within its window restarts the
watchdog of the claims it holds (:meth:`ClaimTable.client_alive`): its frames could not arrive
while it was disconnected, which is the NC's stall, not the client's silence. A stall within the
window of the one before counts with it as one (the larger window, from the later end): a token
lost across the first could not come back while the second lasted.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Iterable

import numpy as np

from nc_schema import ErrorCodes, NcError, check_client_id

ZNC_CLIENT_LOST = int(ErrorCodes.ZNC_CLIENT_LOST)
ZNC_PLCTONC_TIMEOUT = int(ErrorCodes.ZNC_PLCTONC_TIMEOUT)
ACCESS_DENIED = int(ErrorCodes.ADSERR_DEVICE_ACCESSDENIED)
INVALID_DATA = int(ErrorCodes.ADSERR_DEVICE_INVALIDDATA)
#: How long a token lost across an NC stall of at least half the NC's lease may take to come back [s]
#: (its links were dropped: reconnecting, through a router too, on a loaded machine).
LEASE_STALL_GRACE = 2.0


@dataclass
class _Client:
    alive: bool = False
    last_plctonc: float | None = None  # arrival time of the newest PLCTONC frame [s] (never decreases)
    gone_at: float | None = None       # when the token disappeared [s]; None: present (or loss reported)


@dataclass
class _Claim:
    client: str
    since: float                       # claim (or hand-over) time [s]
    watch_from: float | None = None    # hand-over: the watchdog counts from here until the first frame [s]


@dataclass(frozen=True)
class Loss:
    """A client the NC lost (reported once by :meth:`ClaimTable.check`; its claims are released then).

    Attributes:
        client: the client id.
        code: 0x8F01 (token gone) or 0x8F02 (PLCTONC timeout).
        faulted: AxisIds it held and supplied: they get ``code`` and the axis's loss reaction.
        released: AxisIds it held without ever supplying them (0x8F02 only): released, no fault.
    """

    client: str
    code: int
    faulted: tuple[int, ...] = ()
    released: tuple[int, ...] = ()


class ClaimTable:
    """Who supplies each axis's PLCTONC, and when to stop trusting them.

    Args:
        axis_ids: the configured axis ids (claims are keyed by axis id).
        watchdog_timeout: maximum age of the holder's newest PLCTONC [s].
        reconnect_grace: how long a token that vanished during or right after an NC stall may take
            to come back [s]; default ``watchdog_timeout``.
        lease: the NC's zenoh lease [s] (None: unknown): a stall of at least half of it gives lost
            tokens ``lease_stall_grace`` (if longer than ``reconnect_grace``) to come back.
        lease_stall_grace: see ``lease`` [s].
    """

    def __init__(self, axis_ids: Iterable[int], watchdog_timeout: float,
                 reconnect_grace: float | None = None, lease: float | None = None,
                 lease_stall_grace: float = LEASE_STALL_GRACE) -> None:
        self.axis_ids = [int(a) for a in axis_ids]
        self._index = {a: i for i, a in enumerate(self.axis_ids)}
        self.watchdog_timeout = float(watchdog_timeout)
        self.reconnect_grace = float(watchdog_timeout if reconnect_grace is None else reconnect_grace)
        self.lease = None if lease is None else float(lease)
        self.lease_stall_grace = float(lease_stall_grace)
        self._clients: dict[str, _Client] = {}
        self._claims: dict[int, _Claim] = {}
        #: the last NC stall, (start, end, window) [s] (stalls within each other's window merged): a token gone
        #: between start and end + window has window (from when it went, or the stall's end) to come back (grace())
        self._stall = (-math.inf, -math.inf, 0.0)
        #: Incremented on every change of the claims (lets callers cache derived data).
        self.version = 0
        self._masks: dict[str, np.ndarray] = {}
        self._masks_version = -1
        self._by_client_cache: tuple[dict[str, list[int]], dict[str, float]] = ({}, {})
        self._by_client_version = -1
        #: changes of the clients' state other than a newer PLCTONC arrival (tokens, an NC stall, a takeover)
        self._clients_changes = 0
        #: (version, _clients_changes, oldest PLCTONC arrival) of the last check that found every client quiet:
        #: alive, heard from within the timeout after its newest claim, or holding nothing (see check())
        self._quiet: tuple[int, int, float] = (-1, -1, math.inf)

    # ---- liveliness -------------------------------------------------------------------------
    def client_alive(self, client: str, now: float | None = None) -> None:
        """The client's liveliness token appeared at ``now`` [s] (or came back before its loss was
        reported).

        A token that comes back within the window of an NC stall (it was lost across the stall)
        restarts the watchdog of every armed claim it holds at ``now``: its frames could not reach
        the NC while its link was down, and that was the NC's stall.
        """
        c = self._clients.setdefault(client, _Client())
        self._clients_changes += 1
        if not c.alive and c.gone_at is not None and now is not None and self._excused(c.gone_at, float(now)):
            for cl in self._claims.values():
                if cl.client == client and self._watched_since(cl, c) is not None:
                    cl.watch_from = max(float(now), cl.watch_from if cl.watch_from is not None else -math.inf)
        c.alive, c.gone_at = True, None

    def client_gone(self, client: str, now: float = 0.0) -> None:
        """The client's liveliness token disappeared at ``now`` [s]; :meth:`check` reports the loss
        (at once, or after ``reconnect_grace`` if it happened during or right after an NC stall and
        the token did not come back)."""
        c = self._clients.get(client)
        if c is None or not c.alive:
            return
        self._clients_changes += 1
        c.alive, c.gone_at = False, float(now)

    def is_alive(self, client: str) -> bool:
        c = self._clients.get(client)
        return bool(c and c.alive)

    # ---- PLCTONC arrivals -------------------------------------------------------------------
    def plctonc_arrived(self, client: str, now: float) -> None:
        """A PLCTONC frame of ``client`` arrived at ``now`` [s] (kept only for known clients).

        The newest arrival time only moves forward: a frame that is processed late (it arrived
        before an NC stall, or the subscriber thread ran late) never makes the client look older.
        """
        c = self._clients.get(client)
        if c is not None and (c.last_plctonc is None or now > c.last_plctonc):
            c.last_plctonc = now

    def grace(self, now: float, since: float | None = None) -> None:
        """The NC itself stalled from ``since`` to ``now`` [s] (e.g. the process was stopped): nobody
        is blamed for it.

        Every client that sent PLCTONC counts as heard from at ``now`` (frames queued during the
        stall may not have been processed yet; older ones processed later do not move it back),
        and a token that disappears between ``since`` and ``now + window`` gets ``window`` to come
        back (:meth:`check`; when it does, the watchdog of its claims restarts:
        :meth:`client_alive`). ``window`` is ``reconnect_grace``, or ``lease_stall_grace`` if the
        stall lasted at least half of ``lease`` (the NC's session could not keep its links meanwhile).
        """
        self._clients_changes += 1
        for c in self._clients.values():
            if c.last_plctonc is not None and c.last_plctonc < now:
                c.last_plctonc = now
        start = float(now) if since is None else min(float(since), float(now))
        window = self.reconnect_grace
        if self.lease is not None and now - start >= self.lease / 2:
            window = max(window, self.lease_stall_grace)
        s0, e0, w0 = self._stall
        if start <= e0 + w0:  # within the window of the previous stall: one stall as far as an excuse goes (a token
            start, window = min(start, s0), max(window, w0)  # lost across the first one is not blamed for the second)
        self._stall = (start, float(now), window)

    def rebase(self, now: float) -> None:
        """A hot standby took over this table at ``now`` [s] (docs/standby.md): its times were the other process's
        clock (another host's, maybe). Every claim counts from ``now``, every client that sent PLCTONC as heard
        from at ``now`` (its frames come to this process from now on), a token gone meanwhile gets the
        reconnect window from ``now``."""
        for cl in self._claims.values():
            cl.since = float(now)
            if cl.watch_from is not None:
                cl.watch_from = float(now)
        for c in self._clients.values():
            if c.last_plctonc is not None:
                c.last_plctonc = float(now)
            if c.gone_at is not None:
                c.gone_at = float(now)
        self._stall = (float(now), float(now), self.reconnect_grace)
        self._clients_changes += 1
        self.version += 1

    def _excused(self, gone_at: float, now: float) -> bool:
        """A token gone at ``gone_at`` is not a loss yet at ``now`` (an NC stall explains it)."""
        start, end, window = self._stall
        # (its window counts from the stall's end at the earliest: a token lost in the first of two stalls could not
        # come back while the second one lasted)
        return start <= gone_at <= end + window and now < max(gone_at, end) + window

    # ---- claims -----------------------------------------------------------------------------
    def holder(self, axis_id: int) -> str | None:
        """The client holding ``axis_id``, or None."""
        cl = self._claims.get(int(axis_id))
        return cl.client if cl else None

    def claims(self) -> dict[int, str]:
        """A snapshot {axis_id: holder}."""
        return {a: cl.client for a, cl in self._claims.items()}

    def _check_axis(self, axis_id: int) -> int:
        axis_id = int(axis_id)
        if axis_id not in self._index:
            raise NcError(ErrorCodes.NC_AXIS_ID_NOT_ALLOWED, f"no axis {axis_id}")
        return axis_id

    def claim(self, axis_id: int, client: str, now: float) -> None:
        """Make ``client`` the holder of ``axis_id`` (idempotent for the holder).

        Raises:
            NcError: 0x4012 unknown axis; 0x723 the client's liveliness token is not present, or
                another live client holds the axis (the message names the holder).
        """
        axis_id = self._check_axis(axis_id)
        cur = self._claims.get(axis_id)
        if cur is not None and cur.client != client:
            raise NcError(ACCESS_DENIED, f"claim: axis {axis_id} is held by client {cur.client!r}")
        if not self.is_alive(client):
            raise NcError(ACCESS_DENIED, f"liveliness: client {client!r} has no liveliness token nc/<nc>/client/{client} "
                                         "(declare it before claiming; it may not have been seen yet)")
        if cur is None:
            self._set_holder(axis_id, client, now)

    def release(self, axis_id: int, client: str) -> bool:
        """Give up ``client``'s claim of ``axis_id``.

        Returns:
            True if a claim was released, False if the axis was not claimed (no error).

        Raises:
            NcError: 0x4012 unknown axis; 0x723 another client holds the axis.
        """
        axis_id = self._check_axis(axis_id)
        cur = self._claims.get(axis_id)
        if cur is None:
            return False
        if cur.client != client:
            raise NcError(ACCESS_DENIED, f"claim: axis {axis_id} is held by client {cur.client!r}, not {client!r}")
        self._drop(axis_id)
        return True

    def hand_over(self, axis_id: int, client: str, to: str, now: float) -> bool:
        """The holder ``client`` hands ``axis_id`` to the live client ``to`` at ``now`` [s].

        The claim moves at once; the PLCTONC applied stays until ``to``'s first frame after the
        hand-over (the caller leaves it as it is), and the watchdog counts from ``now``: a new holder
        that sends nothing faults with 0x8F02 after ``watchdog_timeout``.

        Returns:
            True if the claim moved, False if ``to`` is ``client`` (nothing to do).

        Raises:
            NcError: 0x4012 unknown axis; 0x706 ``to`` is not a valid client id; 0x723 ``client`` does
                not hold the axis, or ``to`` has no liveliness token.
        """
        axis_id = self._check_axis(axis_id)
        try:
            check_client_id(to)
        except ValueError as exc:
            raise NcError(INVALID_DATA, f"HandOver.To: {exc}") from None
        cur = self._claims.get(axis_id)
        if cur is None or cur.client != client:
            held = f"held by client {cur.client!r}" if cur is not None else "not claimed"
            raise NcError(ACCESS_DENIED, f"claim: axis {axis_id} is {held}: only its holder may hand it over")
        if to == client:
            return False
        if not self.is_alive(to):
            raise NcError(ACCESS_DENIED, f"liveliness: client {to!r} has no liveliness token nc/<nc>/client/{to}: "
                                         f"it cannot take axis {axis_id} over")
        self._set_holder(axis_id, to, now, watch_from=now)
        return True

    def may_override(self, axis_id: int, client: str) -> None:
        """SetOverride permission: the holder, or anyone while unclaimed.

        Raises:
            NcError: 0x723 another client holds the axis.
        """
        cur = self._claims.get(int(axis_id))
        if cur is not None and cur.client != client:
            raise NcError(ACCESS_DENIED, f"claim: axis {axis_id} is held by client {cur.client!r}")

    # ---- watchdog ---------------------------------------------------------------------------
    def _watched_since(self, cl: _Claim, c: _Client) -> float | None:
        """The time the claim's watchdog counts from, or None (not armed)."""
        if c.last_plctonc is not None and c.last_plctonc >= cl.since:
            return c.last_plctonc if cl.watch_from is None else max(c.last_plctonc, cl.watch_from)
        return cl.watch_from

    def check(self, now: float) -> list[Loss]:
        """The clients lost at ``now`` [s] (each reported once); their claims are released.

        Also forgets clients that are gone and hold nothing.

        Runs every NC cycle: when the last check found every client quiet (alive, and heard from within the
        timeout after its newest claim or holding nothing) and neither the claims nor a client's token changed
        since, only the oldest of those clients' newest PLCTONC arrivals is looked at: arrivals only move
        forward, so they all stay quiet until that one is older than the timeout (the same test as below).
        """
        timeout = self.watchdog_timeout
        version, changes, oldest = self._quiet
        if now - oldest <= timeout and version == self.version and changes == self._clients_changes:
            return []
        by_client, newest_since = self._by_client()
        out: list[Loss] = []
        gone = False
        quiet = True  # every client alive and heard from in time after its newest claim, or holding nothing
        oldest = math.inf
        for name, c in list(self._clients.items()):
            # a live client heard from within the timeout, after its newest claim, cannot be late on any claim:
            # each one's watchdog counts from that frame or later
            last = c.last_plctonc
            if c.alive and last is not None and now - last <= timeout and last >= newest_since.get(name, -math.inf):
                oldest = min(oldest, last)
                continue
            axes = by_client.get(name, [])
            if not c.alive:
                gone = True
                if c.gone_at is None or self._excused(c.gone_at, now):
                    continue
                c.gone_at = None
                out.append(Loss(name, ZNC_CLIENT_LOST, tuple(sorted(axes))))
                continue
            if axes:  # (a claim whose watchdog is not armed yet may be armed by a frame that arrived earlier)
                quiet = False
            late = []
            for a in axes:
                ref = self._watched_since(self._claims[a], c)
                if ref is not None and now - ref > self.watchdog_timeout:
                    late.append(a)
            if late:
                out.append(Loss(name, ZNC_PLCTONC_TIMEOUT, tuple(sorted(late)),
                                tuple(sorted(a for a in axes if a not in late))))
        for loss in out:
            for a in (*loss.faulted, *loss.released):
                self._drop(a)
        if gone:
            self.forget_gone()
        self._quiet = (self.version, self._clients_changes, oldest) if quiet and not out and not gone else \
            (-1, -1, math.inf)
        return out

    def _by_client(self) -> tuple[dict[str, list[int]], dict[str, float]]:
        """(client -> AxisIds it holds, client -> its newest claim time [s]), cached until the claims change."""
        if self._by_client_version != self.version:
            by_client: dict[str, list[int]] = {}
            newest: dict[str, float] = {}
            for axis_id, cl in self._claims.items():
                by_client.setdefault(cl.client, []).append(axis_id)
                newest[cl.client] = max(newest.get(cl.client, -math.inf), cl.since)
            self._by_client_cache = (by_client, newest)
            self._by_client_version = self.version
        return self._by_client_cache

    def forget_gone(self) -> list[str]:
        """Forget clients whose token is gone, whose loss was reported and that hold nothing."""
        held = {cl.client for cl in self._claims.values()}
        gone = [n for n, c in self._clients.items() if not c.alive and c.gone_at is None and n not in held]
        for n in gone:
            del self._clients[n]
        return gone

    def held_since(self, client: str) -> np.ndarray:
        """Per axis index (configuration order): the time ``client`` claimed it [s], +inf if not its holder.

        A PLCTONC frame applies only to axes claimed before it arrived (``since <= arrival``): an
        older frame must not enable an axis, or the watchdog (armed by frames after the claim)
        would never watch it. Cached until the claims change; do not modify the returned array.
        """
        if self._masks_version != self.version:
            self._masks.clear()
            self._masks_version = self.version
        m = self._masks.get(client)
        if m is None:
            m = np.full(len(self.axis_ids), np.inf)
            for a, cl in self._claims.items():
                if cl.client == client:
                    m[self._index[a]] = cl.since
            self._masks[client] = m
        return m

    def holders(self) -> frozenset[str]:
        """The clients holding at least one axis."""
        return frozenset(cl.client for cl in self._claims.values())

    def clients(self) -> list[str]:
        """The clients whose liveliness token is present."""
        return sorted(n for n, c in self._clients.items() if c.alive)

    # ---- internals --------------------------------------------------------------------------
    def _set_holder(self, axis_id: int, client: str, now: float, watch_from: float | None = None) -> None:
        """Record ``client`` as the holder of ``axis_id`` since ``now`` [s] (the one place claims are added)."""
        self._claims[axis_id] = _Claim(client, now, watch_from)
        self.version += 1  # held_since() masks and the server's claim snapshot are rebuilt

    def _drop(self, axis_id: int) -> None:
        if self._claims.pop(axis_id, None) is not None:
            self.version += 1
