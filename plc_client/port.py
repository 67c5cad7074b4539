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

The in-process NC (``InProcessPort``, ``InProcessNc``: tests and simulations without zenoh) is
:mod:`nc_sim`, which may import nc-server; this module may not (it is the PLC's, below every transport).
"""
from __future__ import annotations

import collections
import logging
import time
from abc import ABC, abstractmethod
from typing import Any, Callable, Mapping

from nc_schema import ErrorCodes, check_client_id, error_text, make_request

log = logging.getLogger(__name__)


def reply_cycle(reply: Mapping[str, Any] | None) -> int:
    """The NC cycle whose frame first shows the effect of the command a reply answers: the reply's
    ``cycle`` (the step in which the NC applied it), at least 1 (a reply without one then waits for any
    frame); 0 without a reply.

    Over a real network the reply arrives *before* that frame (the NC answers between two cycles, the
    frame of the next one follows), so a block that judges the command by the axis's data waits for
    ``AXIS_REF.shows_cycle(reply_cycle(reply))``: the one rule every block follows.
    """
    if reply is None:
        return 0
    return max(1, int(reply.get("cycle", 0) or 0))


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

    @property
    def text(self) -> str:
        """What the NC said about the outcome (its reply's ``text``: for a refusal, which rule refused
        and why), else the error code's table text; "" while waiting or on success."""
        code = self.error
        if not code:
            return ""
        said = self.reply.get("text") if self.reply is not None else None
        return said if isinstance(said, str) and said else error_text(code)

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
        inbox = self._inbox
        while inbox:  # (only this thread pops: a non-empty inbox stays non-empty until popleft)
            pending, reply, failed = inbox.popleft()
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

