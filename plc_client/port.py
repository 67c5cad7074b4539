"""Command ports: how function blocks send requests to an NC without blocking the PLC cycle.

A :class:`CommandPort` turns ``send(nc, axis_id, cmd, **args)`` into a msgpack request
(:func:`nc_schema.make_request`) with a request id unique to this client, and returns a
:class:`PendingCommand` at once. Replies are appended (from any thread) to a thread-safe
queue; the PLC task drains it with :meth:`CommandPort.poll` at the start of each cycle, so a
reply is never seen in the cycle that sent the request and the block code is the same
whatever the transport.

Request ids: ``time.time_ns() // 1000`` at port creation, then +1 per request. The NC
answers a repeated (client, id) from its reply cache without executing it again, so ids
must not repeat when a PLC with the same client id restarts; a microsecond start stamp
guarantees that unless more than one request per microsecond was sent before the restart.

:class:`InProcessPort` drives a real :class:`nc_server.core.NcCore` in the same process
(tests, simulations): ``send`` parses the request exactly like the server
(:func:`nc_schema.parse_request`) and runs it through ``core.execute`` immediately, so the
command takes effect in the core's next ``step()``; the reply is queued and delivered by the
next :meth:`poll` (the next PLC cycle), as over zenoh. Claim/Release (server commands) are
handled by a small claim table shared by all in-process ports of one core. ``hold`` keeps
replies back (a port that "never answers"); :meth:`InProcessPort.release_held` delivers them
late.
"""
from __future__ import annotations

import collections
import logging
import time
import weakref
from abc import ABC, abstractmethod
from typing import Any, Callable

from nc_schema import ErrorCodes, NcError, check_client_id, make_reply, make_request, parse_request

log = logging.getLogger(__name__)


class PendingCommand:
    """One request in flight.

    Attributes:
        id: the request id.
        nc, axis_id, cmd, args: what was sent.
        sent_at: the task time [s] when it was sent.
        reply: the reply map (``error``, ``cycle``, ``CmdNo``, ...) once it arrived, else None.
        done: True once a reply arrived or the transport gave up (then ``failed`` is set).
        failed: 0, or the error code when no reply will ever come (0x745: transport timeout,
            0x719: nobody answered).
        abandoned: set by the owner that stopped waiting (its timeout); a reply arriving after
            that is a *late* reply (see :meth:`CommandPort.poll`).
    """

    __slots__ = ("id", "nc", "axis_id", "cmd", "args", "sent_at", "reply", "done", "failed", "abandoned", "owner")

    def __init__(self, request_id: int, nc: str, axis_id: int | None, cmd: str, args: dict[str, Any],
                 sent_at: float) -> None:
        self.id = request_id
        self.nc = nc
        self.axis_id = axis_id
        self.cmd = cmd
        self.args = args
        self.sent_at = sent_at
        self.reply: dict[str, Any] | None = None
        self.done = False
        self.failed = 0
        self.abandoned = False
        self.owner: Any = None

    @property
    def error(self) -> int | None:
        """The reply's error code, ``failed`` if the transport gave up, None while waiting."""
        if self.reply is not None:
            return int(self.reply.get("error", 0))
        return self.failed or None

    def abandon(self) -> None:
        """The owner stops waiting; a later reply is reported by poll() as late."""
        self.abandoned = True

    def __repr__(self) -> str:
        state = "waiting" if not self.done else f"error=0x{self.error or 0:X}"
        return f"PendingCommand({self.cmd} nc={self.nc} axis={self.axis_id} id={self.id} {state})"


class CommandPort(ABC):
    """Non-blocking request/reply channel of one PLC client.

    Args:
        client_id: the client id sent with every request ([A-Za-z0-9_.-], 1-64 chars).

    Raises:
        ValueError: invalid client id.
    """

    def __init__(self, client_id: str) -> None:
        self.client_id = check_client_id(client_id)
        self._next_id = time.time_ns() // 1000
        self._inbox: collections.deque[tuple[PendingCommand, dict[str, Any] | None, int]] = collections.deque()
        self.clock: Callable[[], float] = time.monotonic

    def send(self, nc: str, axis_id: int | None, cmd: str, **args: Any) -> PendingCommand:
        """Send ``cmd`` to axis ``axis_id`` of NC ``nc`` (None: NC-level key). Never blocks.

        Returns the :class:`PendingCommand`; a transport that cannot send marks it failed
        (delivered by the next poll) instead of raising.
        """
        self._next_id += 1
        p = PendingCommand(self._next_id, nc, axis_id, cmd, dict(args), self.clock())
        try:
            payload = make_request(cmd, p.id, self.client_id, **args)
        except Exception as exc:  # unpackable argument: a programming error, reported as 0x706
            log.error("cannot encode %s request: %s", cmd, exc)
            self._deliver(p, None, ErrorCodes.ADSERR_DEVICE_INVALIDDATA)
            return p
        self._transmit(p, payload)
        return p

    @abstractmethod
    def _transmit(self, pending: PendingCommand, payload: bytes) -> None:
        """Hand ``payload`` to the transport; arrange for ``_deliver`` to be called later."""

    def _deliver(self, pending: PendingCommand, reply: dict[str, Any] | None, failed: int = 0) -> None:
        """Queue a reply (or a failure code). Thread-safe: deque.append is atomic."""
        self._inbox.append((pending, reply, failed))

    def poll(self) -> list[PendingCommand]:
        """Apply queued replies to their PendingCommands (PLC thread, start of a cycle).

        Returns the *late* ones: commands whose owner had abandoned them before the reply
        arrived (the task decides what to do with an accepted late command).
        """
        late: list[PendingCommand] = []
        while True:
            try:
                pending, reply, failed = self._inbox.popleft()
            except IndexError:
                break
            if pending.done:
                continue  # a second reply (e.g. duplicate queryable) or a failure after a reply
            pending.reply = reply
            pending.failed = 0 if reply is not None else (failed or ErrorCodes.ADSERR_CLIENT_SYNCTIMEOUT)
            pending.done = True
            if pending.abandoned:
                late.append(pending)
        return late

    def close(self) -> None:
        """Release transport resources (default: nothing)."""


# Claim tables of in-process cores: core -> {axis_id: client_id}
_CLAIMS: "weakref.WeakKeyDictionary[Any, dict[int, str]]" = weakref.WeakKeyDictionary()
_CLAIMS_BY_ID: dict[int, dict[int, str]] = {}


def _claims_of(core: Any) -> dict[int, str]:
    try:
        return _CLAIMS.setdefault(core, {})
    except TypeError:  # not weak-referenceable
        return _CLAIMS_BY_ID.setdefault(id(core), {})


class InProcessPort(CommandPort):
    """A port that drives an in-process ``NcCore`` (no zenoh); see the module docstring.

    Args:
        core: the ``nc_server.core.NcCore``.
        client_id: this client's id.
        nc: the NC name this core answers for; requests to other NCs are never answered.

    Attributes:
        hold: while True, replies are kept back (the NC "never answers"); the commands are
            still executed by the core.
        claims: the claim table ``{axis_id: client_id}`` shared by all ports of this core.
    """

    def __init__(self, core: Any, client_id: str = "plc", nc: str = "nc1") -> None:
        super().__init__(client_id)
        self.core = core
        self.nc = nc
        self.hold = False
        self._held: list[tuple[PendingCommand, dict[str, Any]]] = []
        self.claims = _claims_of(core)

    def holds_claim(self, axis_id: int) -> bool:
        return self.claims.get(axis_id) == self.client_id

    def _transmit(self, pending: PendingCommand, payload: bytes) -> None:
        if pending.nc != self.nc:
            return  # nobody answers: the owner's timeout decides
        reply = self._execute(pending.axis_id, payload)
        if self.hold:
            self._held.append((pending, reply))
        else:
            self._deliver(pending, reply)

    def release_held(self) -> None:
        """Deliver the replies kept back while ``hold`` was set (they arrive 'late')."""
        held, self._held = self._held, []
        for pending, reply in held:
            self._deliver(pending, reply)

    def _execute(self, axis_id: int | None, payload: bytes) -> dict[str, Any]:
        core = self.core
        try:
            req = parse_request(payload)
        except NcError as err:
            return make_reply(getattr(err, "request_id", None), None, err.code, str(err), cycle=core.cycle + 1)
        cmd = req["cmd"]
        if axis_id is None:
            if cmd == "Info":
                return make_reply(req["id"], cmd, cycle=core.cycle + 1, value=core.info())
            return make_reply(req["id"], cmd, ErrorCodes.ADSERR_DEVICE_SRVNOTSUPP, cycle=core.cycle + 1)
        if cmd in ("Claim", "Release", "SetOverride"):
            try:
                core.index(axis_id)
            except NcError as err:
                return make_reply(req["id"], cmd, err.code, cycle=core.cycle + 1)
            holder = self.claims.get(axis_id)
            if cmd == "Claim":
                if holder not in (None, req["client"]):
                    return make_reply(req["id"], cmd, ErrorCodes.ADSERR_DEVICE_ACCESSDENIED,
                                      f"axis {axis_id} is claimed by {holder}", cycle=core.cycle + 1, value=holder)
                self.claims[axis_id] = req["client"]
                return make_reply(req["id"], cmd, cycle=core.cycle + 1, value=req["client"])
            if cmd == "Release":
                if holder == req["client"]:
                    del self.claims[axis_id]
                    core.set_plctonc(core.index(axis_id), core.default_plctonc())
                return make_reply(req["id"], cmd, cycle=core.cycle + 1)
            if holder not in (None, req["client"]):  # SetOverride from a non-holder
                return make_reply(req["id"], cmd, ErrorCodes.ADSERR_DEVICE_ACCESSDENIED, cycle=core.cycle + 1)
        return core.execute(req, axis_id)
