"""The in-process NC's request path: nc-server's own handler, claims and watchdog for one in-process core.

:class:`InProcessPort` drives a real :class:`nc_server.core.NcCore` in the same process
(tests, simulations) through **nc-server's own request handler**: each core has one
:class:`InProcessNc` (its :class:`~nc_server.server.handler.RequestHandler`,
:class:`~nc_server.server.claims.ClaimTable` and
:class:`~nc_server.server.handler.CycleInputs`), shared by all in-process ports of that core.
So an in-process client gets exactly the server's behaviour: parsing and error replies, dedup
by (client, id), Claim (0x723 naming the holder) / Release / Info, SetOverride refused from a
non-holder, and the watchdog. Each request goes to its command key
(``nc/<nc>/[axis/<id>/]cmd/<class>/<client>``, ``Keys.command_key``) and through the same key
checks as over zenoh. ``send`` runs the request immediately, so the command takes
effect in the core's next ``step()``; the reply is queued and delivered by the next
:meth:`poll` (the next PLC cycle), as over zenoh.

An in-process port is a live client: creating it declares its liveliness, :meth:`InProcessPort.close`
withdraws it, and the holder's axes then fault with 0x8F01 and are released, as when a zenoh
client's token disappears. PLCTONC (:meth:`InProcessPort.publish_plctonc`, used by
:class:`plc_client.task.InProcessPlc`) goes through the server's per-cycle path: applied only to
axes the client holds, arming the watchdog (0x8F02), which runs on the core's NC time
(``core.cycle * core.cycle_time``; see :class:`InProcessNc`). ``hold`` keeps replies back (a
port that "never answers"); :meth:`InProcessPort.release_held` delivers them late.

Moved here from ``plc_client.port`` (issue 16): it is nc-server's side, so it lives in the simulation
package, which may import both sides; the PLC client does not import ``nc_server``.

May import: ``nc_server``, ``plc_client``, ``nc_schema``.
"""
from __future__ import annotations

import collections
import logging
import weakref
from typing import Any, Callable

import numpy as np

from nc_schema import COMMAND_CLASS, ErrorCodes, Keys, make_reply, unpack
from nc_server.server.claims import ClaimTable
from nc_server.server.handler import CycleInputs, RequestHandler
from plc_client.port import CommandPort, PendingCommand

log = logging.getLogger(__name__)


class _Frame:
    """One in-process PLCTONC frame (what ``handler.PlctoncFrame`` describes)."""

    __slots__ = ("arrival", "axis_ids", "plctonc")

    def __init__(self, arrival: float, axis_ids: np.ndarray, plctonc: np.ndarray) -> None:
        self.arrival = arrival
        self.axis_ids = axis_ids
        self.plctonc = plctonc


class InProcessNc:
    """The server side of one in-process ``NcCore``: nc-server's own request handler.

    Holds the :class:`~nc_server.server.handler.RequestHandler`, the
    :class:`~nc_server.server.claims.ClaimTable` and the
    :class:`~nc_server.server.handler.CycleInputs` that nc-server runs, for one core; every
    :class:`InProcessPort` of that core (one per in-process client) goes through it. Get it with
    :meth:`of` (one per core; it lives as long as a port or task uses it).

    Time: claim bookkeeping and the watchdog run on the core's own time,
    ``core.cycle * core.cycle_time`` (override with ``clock``). The tasks' clocks cannot be
    used: each in-process task counts its own virtual time from 0, so one client's frame time
    compared with another client's "now" would fault live clients. NC time stands still while
    nobody steps the core, as a stalled nc-server blames nobody.

    Args:
        core: the ``nc_server.core.NcCore``.
        nc: the NC name this core answers for (``Info``'s name, the command keys).
        watchdog_timeout: maximum age of a holder's PLCTONC [s]; default: nc-server's default.
        clock: returns "now" [s] for claims and the watchdog; default: the core's NC time.

    Raises:
        ValueError: ``core`` already has an in-process NC (use :meth:`of`), or an invalid name.
    """

    _registry: "weakref.WeakValueDictionary[int, InProcessNc]" = weakref.WeakValueDictionary()

    def __init__(self, core: Any, nc: str = "nc1", watchdog_timeout: float | None = None,
                 clock: Callable[[], float] | None = None) -> None:
        if InProcessNc.registered(core) is not None:
            raise ValueError("this core already has an in-process NC; use InProcessNc.of(core)")
        if watchdog_timeout is None:
            from nc_server.server.config import ServerConfig  # the one default (lazy: pulls in the core)
            watchdog_timeout = ServerConfig.watchdog_timeout
        self.core = core
        self.keys = Keys(nc)
        self.claims = ClaimTable([int(a) for a in np.asarray(core.axis_ids).tolist()], watchdog_timeout)
        self.handler = RequestHandler(core, self.claims, self.keys, info_extra=self._info_extra)
        self.inputs = CycleInputs(core, self.claims)
        self.clock: Callable[[], float] = clock or self._nc_time
        self._ports: collections.Counter[str] = collections.Counter()
        InProcessNc._registry[id(core)] = self

    @classmethod
    def of(cls, core: Any, nc: str = "nc1") -> InProcessNc:
        """The in-process NC of ``core``, made on first use.

        Raises:
            ValueError: it exists under another NC name.
        """
        srv = cls.registered(core)
        if srv is None:
            return cls(core, nc)
        if srv.keys.nc != nc:
            raise ValueError(f"this core answers as NC {srv.keys.nc!r}, not {nc!r}")
        return srv

    @classmethod
    def registered(cls, core: Any) -> InProcessNc | None:
        """The in-process NC of ``core`` if one exists (keyed by identity; never made here)."""
        srv = cls._registry.get(id(core))
        return srv if srv is not None and srv.core is core else None

    @property
    def nc(self) -> str:
        return self.keys.nc

    def _nc_time(self) -> float:
        return self.core.cycle * self.core.cycle_time

    def _info_extra(self) -> dict[str, Any]:
        return {"timing": "in-process", "watchdog_timeout": self.claims.watchdog_timeout}

    # ---- clients ----------------------------------------------------------------------------
    def connect(self, client: str) -> None:
        """A port of ``client`` opened: its liveliness token is present (several ports may share one)."""
        self._ports[client] += 1
        self.handler.client_alive(client)

    def disconnect(self, client: str) -> list[tuple[int, int]]:
        """A port of ``client`` closed; with its last one the token disappears, as in nc-server:
        its claims fault with 0x8F01 now (the axes stop) and are released.

        Returns:
            The (axis_id, error code) pairs faulted.
        """
        if self._ports[client] <= 0:
            return []
        self._ports[client] -= 1
        if self._ports[client]:
            return []
        del self._ports[client]
        self.handler.client_gone(client)
        return self.inputs.watchdog(self.clock())

    # ---- the doors --------------------------------------------------------------------------
    def query(self, key: str, payload: bytes) -> dict[str, Any]:
        """Run one request that arrived on command key ``key`` through nc-server's handler now
        (the same key checks as over zenoh: class, identity, axis); the decoded reply.
        Never raises for bad input."""
        return unpack(self.handler.handle(key, payload, self.clock()))

    def request(self, axis_id: int | None, payload: bytes, client: str = "plc", cls: str | None = None) -> dict[str, Any]:
        """:meth:`query` on ``client``'s command key of class ``cls`` for axis ``axis_id`` (None:
        the NC-level key); ``cls`` None: the class of the payload's command (protocol.json), ``op``
        if the payload cannot be read.

        Raises:
            ValueError: invalid client id, class or axis id.
        """
        if cls is None:
            try:
                cmd = unpack(payload).get("cmd")
            except Exception:
                cmd = None
            cls = COMMAND_CLASS.get(cmd, "op") if isinstance(cmd, str) else "op"
        key = self.keys.cmd(cls, client) if axis_id is None else self.keys.axis_cmd(axis_id, cls, client)
        return self.query(key, payload)

    def plctonc(self, client: str, axis_ids: np.ndarray, records: np.ndarray) -> list[tuple[int, int]]:
        """A PLCTONC frame of ``client`` arrives now: applied to the axes it holds, then the watchdog.

        Args:
            axis_ids: AxisId per record.
            records: PLCTONC_AXIS_REF records (same length).

        Returns:
            The watchdog's (axis_id, error code) faults.
        """
        now = self.clock()
        return self.inputs.apply([(client, _Frame(now, axis_ids, records))], now)

    def cycle(self) -> list[tuple[int, int]]:
        """The watchdog at the current NC time (call before ``core.step()``, as nc-server does)."""
        return self.inputs.watchdog(self.clock())


class InProcessPort(CommandPort):
    """A port that drives an in-process ``NcCore`` through nc-server's handler; see the module docstring.

    Creating it declares ``client_id``'s liveliness on the core's :class:`InProcessNc`;
    :meth:`close` withdraws it (the holder's claims fault with 0x8F01).

    Args:
        core: the ``nc_server.core.NcCore``, or its :class:`InProcessNc` (e.g. one made with
            another watchdog timeout).
        client_id: this client's id.
        nc: the NC name this core answers for; requests to other NCs are never answered.

    Attributes:
        server: the core's :class:`InProcessNc` (shared by all its ports).
        hold: while True, replies are kept back (the NC "never answers"); the commands are
            still executed by the core.

    Raises:
        ValueError: invalid client id, or ``nc`` differs from the name the core answers as.
    """

    def __init__(self, core: Any, client_id: str = "plc", nc: str = "nc1") -> None:
        super().__init__(client_id)
        self.server = core if isinstance(core, InProcessNc) else InProcessNc.of(core, nc)
        if self.server.nc != nc:
            raise ValueError(f"this core answers as NC {self.server.nc!r}, not {nc!r}")
        self.core = self.server.core
        self.nc = nc
        self.hold = False
        self.closed = False
        self._held: list[tuple[PendingCommand, dict[str, Any]]] = []
        self.server.connect(self.client_id)

    @property
    def claims(self) -> ClaimTable:
        """The core's claim table (shared by all its ports)."""
        return self.server.claims

    def holds_claim(self, axis_id: int) -> bool:
        return self.server.claims.holder(axis_id) == self.client_id

    def publish_plctonc(self, axis_ids: np.ndarray, records: np.ndarray) -> list[tuple[int, int]]:
        """Send this client's PLCTONC frame (:meth:`InProcessNc.plctonc`); ignored once closed."""
        if self.closed:
            return []
        return self.server.plctonc(self.client_id, axis_ids, records)

    def _transmit(self, pending: PendingCommand, payload: bytes) -> None:
        if pending.nc != self.nc or self.closed:
            return  # nobody answers: the owner's timeout decides
        try:
            key = self.server.keys.command_key(pending.cmd, pending.axis_id, self.client_id)
        except ValueError as exc:  # e.g. a negative axis id: no such key, as the NC would say
            reply = make_reply(pending.id, pending.cmd, ErrorCodes.NC_AXIS_ID_NOT_ALLOWED, str(exc))
        else:
            reply = self.server.query(key, payload)
        if self.hold:
            self._held.append((pending, reply))
        else:
            self._deliver(pending, reply)

    def release_held(self) -> None:
        """Deliver the replies kept back while ``hold`` was set (they arrive 'late')."""
        held, self._held = self._held, []
        for pending, reply in held:
            self._deliver(pending, reply)

    def close(self) -> None:
        """This client disappears (idempotent): with its last port on the core, its claims fault
        with 0x8F01 and are released, and its cached replies are forgotten."""
        if not self.closed:
            self.closed = True
            self.server.disconnect(self.client_id)
