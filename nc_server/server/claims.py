"""Claim table and watchdog (pure: no zenoh, no clock reads; times are passed in, in seconds).

One client at a time supplies an axis's PLCTONC: the *holder*. A client may claim only while its
liveliness token ``nc/<nc>/client/<client>`` is present. :meth:`ClaimTable.check` returns the
axes to fault and releases them:

* 0x8F01 ZNC_CLIENT_LOST: the holder's liveliness token disappeared;
* 0x8F02 ZNC_PLCTONC_TIMEOUT: the holder sent PLCTONC after claiming (the watchdog is armed
  by the first frame after the claim) and its newest frame is older than ``watchdog_timeout``.

A claim whose holder never sent a PLCTONC frame is not watched: the NC applies the default
PLCTONC (all enables off) to it, so there is nothing a silent client could keep moving.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Iterable

import numpy as np

from nc_schema import ErrorCodes, NcError

ZNC_CLIENT_LOST = int(ErrorCodes.ZNC_CLIENT_LOST)  # type: ignore[attr-defined]
ZNC_PLCTONC_TIMEOUT = int(ErrorCodes.ZNC_PLCTONC_TIMEOUT)  # type: ignore[attr-defined]
ACCESS_DENIED = int(ErrorCodes.ADSERR_DEVICE_ACCESSDENIED)  # type: ignore[attr-defined]


@dataclass
class _Client:
    alive: bool = False
    last_plctonc: float | None = None  # arrival time of the newest PLCTONC frame [s]


@dataclass
class _Claim:
    client: str
    since: float  # claim time [s]


class ClaimTable:
    """Who supplies each axis's PLCTONC, and when to stop trusting them.

    Args:
        axis_ids: the configured axis ids (claims are keyed by axis id).
        watchdog_timeout: maximum age of the holder's newest PLCTONC [s].
    """

    def __init__(self, axis_ids: Iterable[int], watchdog_timeout: float) -> None:
        self.axis_ids = [int(a) for a in axis_ids]
        self._index = {a: i for i, a in enumerate(self.axis_ids)}
        self.watchdog_timeout = float(watchdog_timeout)
        self._clients: dict[str, _Client] = {}
        self._claims: dict[int, _Claim] = {}
        #: Incremented on every change of the claims (lets callers cache derived data).
        self.version = 0
        self._masks: dict[str, np.ndarray] = {}
        self._masks_version = -1

    # ---- liveliness -------------------------------------------------------------------------
    def client_alive(self, client: str) -> None:
        """The client's liveliness token appeared."""
        self._clients.setdefault(client, _Client()).alive = True

    def client_gone(self, client: str) -> None:
        """The client's liveliness token disappeared; its claims fault at the next :meth:`check`."""
        c = self._clients.get(client)
        if c is not None:
            c.alive = False
        self.forget_gone()

    def is_alive(self, client: str) -> bool:
        c = self._clients.get(client)
        return bool(c and c.alive)

    # ---- PLCTONC arrivals -------------------------------------------------------------------
    def plctonc_arrived(self, client: str, now: float) -> None:
        """A PLCTONC frame of ``client`` arrived at ``now`` [s] (kept only for known clients)."""
        c = self._clients.get(client)
        if c is not None:
            c.last_plctonc = now

    def grace(self, now: float) -> None:
        """Treat every client as heard from at ``now``.

        For after the NC itself stalled (e.g. the process was stopped): frames queued during the
        stall may not have been processed yet, so nobody is blamed for the gap.
        """
        for c in self._clients.values():
            if c.last_plctonc is not None:
                c.last_plctonc = now

    # ---- claims -----------------------------------------------------------------------------
    def holder(self, axis_id: int) -> str | None:
        """The client holding ``axis_id``, or None."""
        cl = self._claims.get(int(axis_id))
        return cl.client if cl else None

    def claims(self) -> dict[int, str]:
        """A snapshot {axis_id: holder}."""
        return {a: cl.client for a, cl in self._claims.items()}

    def claim(self, axis_id: int, client: str, now: float) -> None:
        """Make ``client`` the holder of ``axis_id`` (idempotent for the holder).

        Raises:
            NcError: 0x4012 unknown axis; 0x723 the client's liveliness token is not present, or
                another live client holds the axis (the message names the holder).
        """
        axis_id = int(axis_id)
        if axis_id not in self._index:
            raise NcError(ErrorCodes.NC_AXIS_ID_NOT_ALLOWED, f"no axis {axis_id}")
        cur = self._claims.get(axis_id)
        if cur is not None and cur.client != client:
            raise NcError(ACCESS_DENIED, f"axis {axis_id} is held by client {cur.client!r}")
        if not self.is_alive(client):
            raise NcError(ACCESS_DENIED, f"client {client!r} has no liveliness token nc/<nc>/client/{client} "
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
        axis_id = int(axis_id)
        if axis_id not in self._index:
            raise NcError(ErrorCodes.NC_AXIS_ID_NOT_ALLOWED, f"no axis {axis_id}")
        cur = self._claims.get(axis_id)
        if cur is None:
            return False
        if cur.client != client:
            raise NcError(ACCESS_DENIED, f"axis {axis_id} is held by client {cur.client!r}, not {client!r}")
        self._drop(axis_id)
        return True

    def may_override(self, axis_id: int, client: str) -> None:
        """SetOverride permission: the holder, or anyone while unclaimed.

        Raises:
            NcError: 0x723 another client holds the axis.
        """
        cur = self._claims.get(int(axis_id))
        if cur is not None and cur.client != client:
            raise NcError(ACCESS_DENIED, f"axis {axis_id} is held by client {cur.client!r}")

    # ---- watchdog ---------------------------------------------------------------------------
    def check(self, now: float) -> list[tuple[int, int]]:
        """The claims to fault at ``now`` [s], as (axis_id, error code); they are released.

        Also forgets clients that are gone and hold nothing.
        """
        out: list[tuple[int, int]] = []
        for axis_id, cl in list(self._claims.items()):
            c = self._clients.get(cl.client)
            if c is None or not c.alive:
                out.append((axis_id, ZNC_CLIENT_LOST))
            elif (c.last_plctonc is not None and c.last_plctonc >= cl.since
                  and now - c.last_plctonc > self.watchdog_timeout):
                out.append((axis_id, ZNC_PLCTONC_TIMEOUT))
        for axis_id, _ in out:
            self._drop(axis_id)
        if out:
            self.forget_gone()
        return out

    def forget_gone(self) -> list[str]:
        """Forget clients whose token is gone and that hold nothing; returns their ids."""
        held = {cl.client for cl in self._claims.values()}
        gone = [n for n, c in self._clients.items() if not c.alive and n not in held]
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
    def _set_holder(self, axis_id: int, client: str, now: float) -> None:
        """Record ``client`` as the holder of ``axis_id`` since ``now`` [s] (the one place claims are added)."""
        self._claims[axis_id] = _Claim(client, now)
        self.version += 1  # held_since() masks and the server's claim snapshot are rebuilt

    def _drop(self, axis_id: int) -> None:
        del self._claims[axis_id]
        self.version += 1
