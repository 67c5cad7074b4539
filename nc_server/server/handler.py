"""Request handling of the NC server (pure: no zenoh, no clock reads; runs in the cycle thread).

:class:`RequestHandler` turns one query (key + payload bytes) into the msgpack reply bytes:
parse (``nc_schema.parse_request``), dedup by (client, id), Claim/Release/Info here,
SetOverride after a permission check, everything else through ``core.execute``. Nothing
raises out of :meth:`RequestHandler.handle`: bad input becomes an error reply.
"""
from __future__ import annotations

import logging
from collections import OrderedDict
from typing import Any, Callable, Protocol

from nc_schema import COMMANDS, ErrorCodes, Keys, NcError, make_reply, pack, parse_request

from .claims import ClaimTable

log = logging.getLogger("nc_server.server")

#: Requests above this size are rejected (0x706) before msgpack sees them [bytes].
MAX_REQUEST_BYTES = 65536

INVALID_DATA = int(ErrorCodes.ADSERR_DEVICE_INVALIDDATA)  # type: ignore[attr-defined]
AXIS_NOT_ALLOWED = int(ErrorCodes.NC_AXIS_ID_NOT_ALLOWED)  # type: ignore[attr-defined]
INTERNAL = int(ErrorCodes.NC_INTERNAL)  # type: ignore[attr-defined]


class CoreLike(Protocol):
    """The part of ``nc_server.core.NcCore`` the server uses."""

    cycle: int

    def index(self, axis_id: int) -> int: ...
    def execute(self, request: dict[str, Any], axis_id: int) -> dict[str, Any]: ...
    def default_plctonc(self) -> Any: ...
    def set_plctonc(self, i: int, record: Any) -> None: ...
    def info(self) -> dict[str, Any]: ...


class ReplyCache:
    """LRU of packed replies keyed by (client, request id).

    Args:
        maxsize: entries kept; the oldest is evicted first.
    """

    def __init__(self, maxsize: int = 4096) -> None:
        self.maxsize = int(maxsize)
        self._d: OrderedDict[tuple[str, Any], bytes] = OrderedDict()
        self.hits = 0

    def __len__(self) -> int:
        return len(self._d)

    def get(self, client: str, rid: Any) -> bytes | None:
        """The cached reply, refreshed as most recently used; None if absent."""
        key = (client, rid)
        r = self._d.get(key)
        if r is not None:
            self._d.move_to_end(key)
            self.hits += 1
        return r

    def put(self, client: str, rid: Any, reply: bytes) -> None:
        key = (client, rid)
        self._d[key] = reply
        self._d.move_to_end(key)
        while len(self._d) > self.maxsize:
            self._d.popitem(last=False)

    def forget_client(self, client: str) -> int:
        """Drop every entry of ``client`` (its session ended; a restarted client may reuse ids)."""
        keys = [k for k in self._d if k[0] == client]
        for k in keys:
            del self._d[k]
        return len(keys)


class RequestHandler:
    """Executes requests against the core and the claim table.

    Args:
        core: the NcCore (owned by the calling thread).
        claims: the claim table.
        keys: the NC's key expressions.
        info_extra: returns extra Info fields (e.g. ``timing``) at call time.
        refresh_liveliness: applies liveliness events that arrived meanwhile (see Claim).
        cache_size: reply cache entries.

    Dedup applies to requests that carry a client id: a repeated (client, id) gets the cached
    reply and is not executed again. Anonymous requests (no ``client``) are never deduplicated,
    since unrelated anonymous tools would collide on ids like 1.
    """

    def __init__(self, core: CoreLike, claims: ClaimTable, keys: Keys,
                 info_extra: Callable[[], dict[str, Any]] | None = None, cache_size: int = 4096,
                 refresh_liveliness: Callable[[], None] | None = None) -> None:
        self.core = core
        self.claims = claims
        self.keys = keys
        self.info_extra = info_extra or (lambda: {})
        #: applies pending liveliness events (the server's); called before refusing an unknown client
        self.refresh_liveliness = refresh_liveliness or (lambda: None)
        self.cache = ReplyCache(cache_size)
        self.requests = 0
        self.errors = 0
        self.internal_errors = 0

    def handle(self, key: str, payload: bytes, now: float) -> bytes:
        """Execute one request and return the packed reply (never raises).

        Args:
            key: the query's key expression (``nc/<nc>/cmd`` or ``nc/<nc>/axis/<id>/cmd``).
            payload: the msgpack request.
            now: monotonic time [s] (claim bookkeeping).
        """
        self.requests += 1
        try:
            reply = self._handle(key, payload, now)
        except Exception as exc:  # a bug: answer it, keep cycling
            self.internal_errors += 1
            log.exception("internal error handling request on %s", key)
            reply = pack(make_reply(None, None, INTERNAL, f"internal error: {exc.__class__.__name__}: {exc}"[:200],
                                    cycle=self.core.cycle + 1))
        return reply

    def _error(self, rid: Any, cmd: str | None, err: NcError) -> bytes:
        self.errors += 1
        text = str(err)
        return pack(make_reply(rid, cmd, err.code, text[:512], cycle=self.core.cycle + 1))

    def too_large(self, size: int) -> bytes:
        """The reply to a request of ``size`` bytes over MAX_REQUEST_BYTES (0x706)."""
        return self._error(None, None, NcError(INVALID_DATA, f"request of {size} bytes exceeds {MAX_REQUEST_BYTES}"))

    def _handle(self, key: str, payload: bytes, now: float) -> bytes:
        if len(payload) > MAX_REQUEST_BYTES:
            return self.too_large(len(payload))
        try:
            req = parse_request(payload)
        except NcError as err:
            return self._error(getattr(err, "request_id", None), getattr(err, "cmd", None), err)
        rid, client = req["id"], req["client"]
        if client:
            cached = self.cache.get(client, rid)
            if cached is not None:
                return cached
        reply = self._execute(key, req, now)
        if client:
            self.cache.put(client, rid, reply)
        return reply

    def _execute(self, key: str, req: dict[str, Any], now: float) -> bytes:
        rid, client, cmd = req["id"], req["client"], req["cmd"]
        try:
            axis_id = self.keys.parse_cmd_key(key)
        except NcError as err:
            return self._error(rid, cmd, err)
        scope = COMMANDS[cmd].get("scope", "axis")
        cycle = self.core.cycle + 1
        if cmd == "Info":
            value = {"name": self.keys.nc, **self.core.info(), **self.info_extra(),
                     "claims": self.claims.claims(), "clients": self.claims.clients()}
            return pack(make_reply(rid, cmd, 0, "", cycle=cycle, value=value))
        if scope == "axis" and axis_id is None:
            where = f"{self.keys.prefix}/axis/<id>/cmd"
            return self._error(rid, cmd, NcError(AXIS_NOT_ALLOWED, f"{cmd} is an axis command: send it to {where}"))
        assert axis_id is not None
        if cmd in ("Claim", "Release"):
            if not client:
                return self._error(rid, cmd, NcError(INVALID_DATA, f"{cmd} needs a 'client' id"))
            try:
                i = self.core.index(axis_id)
                if cmd == "Claim":
                    if not self.claims.is_alive(client):
                        # its token event may have arrived a moment ago: take pending events first
                        self.refresh_liveliness()
                    self.claims.claim(axis_id, client, now)
                    return pack(make_reply(rid, cmd, 0, "", cycle=cycle, value=client))
                if self.claims.release(axis_id, client):
                    # Nobody supplies PLCTONC any more: all enables off, override 100 %.
                    self.core.set_plctonc(i, self.core.default_plctonc())
                    log.info("axis %d released by %s", axis_id, client)
                return pack(make_reply(rid, cmd, 0, "", cycle=cycle))
            except NcError as err:
                return self._error(rid, cmd, err)
        if cmd == "SetOverride":
            try:
                self.claims.may_override(axis_id, client)
            except NcError as err:
                return self._error(rid, cmd, err)
        reply = self.core.execute(req, axis_id)
        if reply.get("error"):
            self.errors += 1
        return pack(reply)
