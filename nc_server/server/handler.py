"""Request handling and per-cycle inputs of the NC (pure: no zenoh, no clock reads).

This is the one implementation behind every door to an NC: nc-server's queryable
(:mod:`nc_server.server.app`, cycle thread) and the in-process port
(:class:`nc_sim.InProcessPort`, tests and simulations) both feed it.

* :class:`RequestHandler` turns one request (key + payload bytes) into the msgpack reply bytes:
  parse (``nc_schema.parse_request``), the key (``nc/<nc>/[axis/<id>/]cmd/<class>/<client>``,
  ``Keys.parse_cmd_key``: the sender's identity and the command's class, checked against the
  command, the request's ``client`` field, the configured axes and, with a roles file, the
  client's role), dedup by (key client, id), the commands of the contract's layer ``server``
  (Claim/Release/HandOver/Info) here, SetOverride after a claim check, everything else through
  ``core.execute`` (the request carries the key's
  client: the core records which client commanded each motion job). Nothing raises out of
  :meth:`RequestHandler.handle`: bad input becomes an error reply. It also keeps who was seen
  with which class and the last command per axis (:meth:`RequestHandler.arbitration`, the
  ``nc/<nc>/claims`` map). Client liveliness
  (:meth:`RequestHandler.client_alive` / :meth:`RequestHandler.client_gone`) goes through it too,
  so a vanished client's claims fault and its reply-cache entries are dropped in one place.
* :class:`CycleInputs` is what the NC does before each ``core.step()``: apply the newest PLCTONC
  frame of each claim holder, then the watchdog: a lost client (0x8F01 token gone, 0x8F02 PLCTONC
  timeout) gets each axis's ``ClientLossReaction`` on the axes it supplied, and the motions it
  commanded elsewhere stop with 0x8F01; its claims are released (docs/arbitration.md).
"""
from __future__ import annotations

import logging
from collections import OrderedDict
from dataclasses import dataclass
from typing import Any, Callable, Iterable, Mapping, Protocol, Sequence, TypeVar

import numpy as np

from nc_schema import (CLASSES, COMMAND_CLASS, COMMAND_SPECS, ROLE_CLASSES, ErrorCodes, Keys, NcError, make_reply,
                       pack, parse_request, unpack)

from ..core.commands import REGISTRY
from .claims import ZNC_CLIENT_LOST, ClaimTable, Loss
from .retain import RETAIN_ERROR_CODE

#: commands refused when they were queued across a long NC stall: those that start or change a motion,
#: stops excepted (protocol.json ``motion``, ``amends``, ``stop``)
REFUSED_AFTER_STALL = frozenset(n for n, s in COMMAND_SPECS.items() if (s.motion or s.amends) and not s.stop)

#: a command the handler executes itself: (handler, axis id or None, request, now [s]) -> reply (NcError: refused)
ServerCommand = Callable[["RequestHandler", "int | None", dict[str, Any], float], dict[str, Any]]
#: a check the handler makes before the core runs a command: (handler, axis id, client); NcError: refused
ServerGuard = Callable[["RequestHandler", int, str], None]
_S = TypeVar("_S", bound=Callable[..., dict[str, Any]])
_G = TypeVar("_G", bound=Callable[..., None])
#: the commands of the contract's layer "server", registered beside their code (:func:`_server_command`)
_OWN: dict[str, ServerCommand] = {}
#: the handler's checks of core commands (:func:`_guard`)
_GUARDS: dict[str, ServerGuard] = {}


def _server_command(*names: str) -> Callable[[_S], _S]:
    """Decorator: the method executes ``names`` here (the command registry's layer "server")."""
    def register(fn: _S) -> _S:
        for name in names:
            REGISTRY.register(name, where=f"{__name__}.{fn.__qualname__}", layer="server")
            _OWN[name] = fn
        return fn
    return register


def _guard(name: str) -> Callable[[_G], _G]:
    """Decorator: the method checks core command ``name`` before ``core.execute`` runs it."""
    def register(fn: _G) -> _G:
        REGISTRY.guard(name, layer="server", where=f"{__name__}.{fn.__qualname__}")
        _GUARDS[name] = fn
        return fn
    return register


#: ``ClientLossReaction`` of an axis (config key in the [[axis]] table); the first is the default.
LOSS_REACTIONS = ("stop_disable", "stop", "keep_others")

log = logging.getLogger("nc_server.server")

#: Requests above this size are rejected (0x706) before msgpack sees them [bytes].
MAX_REQUEST_BYTES = 65536

INVALID_DATA = int(ErrorCodes.ADSERR_DEVICE_INVALIDDATA)
AXIS_NOT_ALLOWED = int(ErrorCodes.NC_AXIS_ID_NOT_ALLOWED)
INTERNAL = int(ErrorCodes.NC_INTERNAL)
ACCESS_DENIED = int(ErrorCodes.ADSERR_DEVICE_ACCESSDENIED)
#: Clients remembered for the ``clients`` of :meth:`RequestHandler.arbitration` (beyond: the oldest
#: one without a liveliness token is forgotten first).
MAX_SEEN = 256
#: The role a client is shown with when the NC has no roles file: by the highest class it used.
SEEN_ROLE = {"read": "observer", "op": "operator", "eng": "engineer"}
_RANK = {c: i for i, c in enumerate(CLASSES)}
NO_NC_CYCLE = int(ErrorCodes.MC_NO_NC_CYCLE_UPDATE)
ZNC_NC_STALLED = int(ErrorCodes.ZNC_NC_STALLED)


class CoreLike(Protocol):
    """The part of ``nc_server.core.NcCore`` the server uses."""

    cycle: int

    def index(self, axis_id: int) -> int: ...
    def execute(self, request: dict[str, Any], axis_id: int) -> dict[str, Any]: ...
    def prepare(self, request: dict[str, Any], axis_id: int) -> Any: ...
    def activate(self, prepared: Any) -> dict[str, Any] | None: ...
    def default_plctonc(self) -> Any: ...
    def set_plctonc(self, i: int, record: Any) -> None: ...
    def info(self) -> dict[str, Any]: ...


class FaultingCore(CoreLike, Protocol):
    """What :class:`CycleInputs` needs in addition: raising an axis error."""

    def fault(self, i: int, code: int) -> None: ...


class PlctoncFrame(Protocol):
    """A client's PLCTONC frame (``transport.PlcFrame`` or the in-process task's).

    Attributes:
        arrival: when the NC received it [s], on the clock the claim table is fed with.
        axis_ids: AxisId per record (integer array).
        plctonc: PLCTONC_AXIS_REF records (array, same length).
    """

    arrival: float
    axis_ids: np.ndarray
    plctonc: np.ndarray


class ReplyCache:
    """LRU of packed replies keyed by (client, request id).

    Args:
        maxsize: entries kept; the oldest is evicted first.
    """

    def __init__(self, maxsize: int = 4096) -> None:
        self.maxsize = int(maxsize)
        self._d: OrderedDict[tuple[str, Any], bytes] = OrderedDict()
        self.hits = 0
        #: the changes since the last look, for a hot standby (None: not noted; replication.HandlerRecorder)
        self.journal: list[tuple[Any, ...]] | None = None

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
        if self.journal is not None:
            self.journal.append(("put", client, rid, reply))
        while len(self._d) > self.maxsize:
            self._d.popitem(last=False)

    def items(self) -> list[tuple[tuple[str, Any], bytes]]:
        """The entries, oldest first."""
        return list(self._d.items())

    def forget_client(self, client: str) -> int:
        """Drop every entry of ``client`` (its session ended; a restarted client may reuse ids)."""
        keys = [k for k in self._d if k[0] == client]
        for k in keys:
            del self._d[k]
        if self.journal is not None:
            self.journal.append(("forget", client))
        return len(keys)


#: the refusal of a prepared command whose prediction failed at activation this many times in a row
#: (NcServer.MAX_REPREPARE): the axis changed under it every time (0x4220: not ready for a new task)
NOT_READY = int(ErrorCodes.NC_GROUP_NOT_READY)


@dataclass(eq=False, slots=True)
class PendingReply:
    """A motion command in preparation (TwinCAT's SVB) and activation (SAF), in three steps of the cycle
    thread: :meth:`RequestHandler.prepare` (parse, key, dedup: the handler's part, valid until it ends),
    :meth:`RequestHandler.plan` (the core's checks, record and plan from the state the next cycle starts
    from: in the gap before that cycle) and :meth:`RequestHandler.activate` (right after the plan in the same gap
    when it fits there, else at that cycle's start: either way before that cycle's step).

    Attributes:
        req: the parsed request.
        axis_id, client, rid, cmd: the request's.
        prepared: the core's preparation (``nc_server.core.nc.Prepared``) once planned, else None.
        packed: its reply packed in advance (it goes out as it is when the activation is as predicted).
    """

    req: dict[str, Any]
    axis_id: int
    client: str
    rid: Any
    cmd: str
    prepared: Any = None
    packed: bytes = b""


#: the motion commands that start a job of the queue: prepared and activated in two phases
TWO_PHASE = frozenset(REGISTRY.kinds())


class RequestHandler:
    """Executes requests against the core and the claim table.

    Args:
        core: the NcCore (owned by the calling thread).
        claims: the claim table.
        keys: the NC's key expressions.
        info_extra: returns extra Info fields (e.g. ``timing``) at call time.
        refresh_liveliness: applies liveliness events that arrived meanwhile (see Claim).
        cache_size: reply cache entries.
        roles: client id -> role (``observer`` / ``operator`` / ``engineer``) from the NC's roles
            file; a client must be listed and its role must allow the command's class (0x723
            otherwise). None: no roles file (the router's access control, if any, decides).
        keeps: ``keeps(cmd, axis_id)``: whether a successful ``cmd`` on that axis must be kept before its
            reply goes out (the retain file's :meth:`~nc_server.server.retain.RetainKeeper.keeps`; None:
            nothing): :attr:`durable`.

    Dedup applies to commands of class op and eng: a repeated (client, id), client being the
    key's, gets the cached reply and is not executed again. Reads (class read) are never cached:
    running them twice changes nothing, and tools that always send id 1 get fresh values.

    Attributes:
        seen: client -> highest command class rank it used (0 read, 1 op, 2 eng).
        last_command: AxisId -> (client, cmd, cycle) of the newest accepted op/eng command.
        clients_version: bumped when a client appears, disappears or uses a higher class.
        commands_version: bumped with every change of ``last_command``.
        durable: the last :meth:`handle` ran one of ``durable_commands`` and answered with no error, or
            gave a cached reply of one (the caller holds the reply until its effect is kept).
    """

    def __init__(self, core: CoreLike, claims: ClaimTable, keys: Keys,
                 info_extra: Callable[[], dict[str, Any]] | None = None, cache_size: int = 4096,
                 refresh_liveliness: Callable[[], None] | None = None,
                 roles: Mapping[str, str] | None = None,
                 keeps: Callable[[str, int | None], bool] | None = None) -> None:
        self.core = core
        self.claims = claims
        self.keys = keys
        self.info_extra = info_extra or (lambda: {})
        #: applies pending liveliness events (the server's); called before refusing an unknown client
        self.refresh_liveliness = refresh_liveliness or (lambda: None)
        # kept as given: a roles file's mapping also answers for the users of doors (<door>.<user>)
        self.roles: Mapping[str, str] | None = roles
        for client, role in (self.roles or {}).items():
            if role not in ROLE_CLASSES:
                raise ValueError(f"client {client!r}: unknown role {role!r} (one of {', '.join(ROLE_CLASSES)})")
        self.cache = ReplyCache(cache_size)
        self._axes = frozenset(claims.axis_ids)
        self.seen: dict[str, int] = {}
        self.last_command: dict[int, tuple[str, str, int]] = {}
        self.clients_version = 0
        self.commands_version = 0
        self.requests = 0
        self.errors = 0
        self.denied = 0  # 0x723 for the key: wrong class, client field, role
        self.internal_errors = 0
        self.keeps = keeps or (lambda cmd, axis_id: False)
        self.durable = False

    # ---- liveliness (the server's token events; an in-process port's creation / close) ------
    def client_alive(self, client: str, now: float | None = None) -> None:
        """``client``'s liveliness token appeared at ``now`` [s]: it may claim (back within an NC
        stall's window: its claims' watchdog restarts, ClaimTable.client_alive)."""
        self.claims.client_alive(client, now)
        self.clients_version += 1

    def client_gone(self, client: str, now: float = 0.0) -> None:
        """``client``'s token disappeared at ``now`` [s]: the next watchdog check
        (:meth:`CycleInputs.watchdog`) reacts to the loss, and its cached replies are dropped (a
        restarted client may reuse request ids)."""
        self.claims.client_gone(client, now)
        self.cache.forget_client(client)
        self.clients_version += 1

    # ---- requests ---------------------------------------------------------------------------
    def handle(self, key: str, payload: bytes, now: float) -> bytes:
        """Execute one request and return the packed reply (never raises).

        Args:
            key: the query's key expression (``nc/<nc>/cmd/<class>/<client>`` or
                ``nc/<nc>/axis/<id>/cmd/<class>/<client>``).
            payload: the msgpack request.
            now: monotonic time [s] (claim bookkeeping).
        """
        reply = self._request(key, payload, now, prepare=False)
        assert isinstance(reply, bytes)  # (prepare=False: always the packed reply)
        return reply

    def _request(self, key: str, payload: bytes, now: float, prepare: bool) -> bytes | PendingReply:
        """:meth:`handle` or :meth:`prepare`: counted, and a bug answered, never raised."""
        self.requests += 1
        self.durable = False
        try:
            return self._handle(key, payload, now, prepare=prepare)
        except Exception as exc:  # a bug: answer it, keep cycling
            return pack(self._internal(None, None, exc, f"handling request on {str(key)[:200]}"))

    def _internal(self, rid: Any, cmd: str | None, exc: Exception, what: str) -> dict[str, Any]:
        """The reply to a request that met a bug (``exc``, logged with its traceback): NC_INTERNAL."""
        self.internal_errors += 1
        log.error("internal error %s", what, exc_info=exc)
        return make_reply(rid, cmd, INTERNAL, f"internal error: {exc.__class__.__name__}: {exc}"[:200],
                          cycle=self.core.cycle + 1)

    def _error(self, rid: Any, cmd: str | None, err: NcError) -> bytes:
        return pack(self._error_reply(rid, cmd, err))

    def _error_reply(self, rid: Any, cmd: str | None, err: NcError) -> dict[str, Any]:
        self.errors += 1
        text = str(err)
        return make_reply(rid, cmd, err.code, text[:512], cycle=self.core.cycle + 1)

    def not_kept(self, reply: bytes, late: bool = False) -> bytes:
        """``reply`` (no error) of a durable command whose effect is not known to be in the retain file: the
        same reply with 0x4002 (TwinCAT's NC retain data error): applied, but not kept. ``late``: its write
        did not end within the I/O thread's HOLD_MAX (it may still reach the file); else it failed, or the
        NC does not write its retain file this run (a reply must not claim a durability it lacks)."""
        if late:
            text = ("NC retain data error: applied, but not confirmed kept within the time (the retain file's write "
                    "is slow; it may still reach the file)")
        else:
            text = "NC retain data error: applied, but the retain file could not be written (lost at a restart)"
        try:
            r = unpack(reply)
            if r.get("error"):  # a cached refusal given again (a retry): it stays what it was
                return reply
            return pack(make_reply(r.get("id"), r.get("cmd"), RETAIN_ERROR_CODE, text, cycle=int(r.get("cycle", 0))))
        except Exception:  # (the NC's own packed reply: never expected)
            return pack(make_reply(None, None, RETAIN_ERROR_CODE, text, cycle=self.core.cycle + 1))

    def too_large(self, size: int) -> bytes:
        """The reply to a request of ``size`` bytes over MAX_REQUEST_BYTES (0x706)."""
        self.durable = False
        return self._error(None, None, NcError(INVALID_DATA, f"request of {size} bytes exceeds {MAX_REQUEST_BYTES}"))

    def handle_after_stall(self, key: str, payload: bytes, now: float) -> bytes:
        """:meth:`handle` for a request taken right after a long stall of the NC: a command that
        would start or change a motion (:data:`REFUSED_AFTER_STALL`) is refused with 0x4B0F and not
        executed (it was queued across the stall: its block may have given up on stale data, or
        its session was dropped with the reply path); anything else runs as usual. Not cached: a
        retry with the same id is executed normally."""
        self.durable = False
        try:
            req = parse_request(payload[:MAX_REQUEST_BYTES])
        except Exception:
            return self.handle(key, payload, now)
        if req["cmd"] not in REFUSED_AFTER_STALL:
            return self.handle(key, payload, now)
        self.requests += 1
        return self._error(req["id"], req["cmd"], NcError(NO_NC_CYCLE, "the NC stalled: a motion command queued "
                                                                       "across the stall is refused, not executed late"))

    def prepare(self, key: str, payload: bytes, now: float) -> bytes | PendingReply:
        """:meth:`handle` in steps (nc-server's cycle thread): a motion command that starts a job
        (:data:`TWO_PHASE`) is parsed, checked against its key and the reply cache, and returned as a
        :class:`PendingReply` for :meth:`plan` (the core's part) and :meth:`activate`; every other request
        runs now and its packed reply is returned. Never raises."""
        return self._request(key, payload, now, prepare=True)

    def plan(self, pending: PendingReply) -> bytes | PendingReply:
        """The core's part of a prepared request (``core.prepare``: checks, record and plan from the state the
        next step starts from, nothing changed), in the gap before the cycle that activates it: ``pending``
        planned, or the packed reply of a command that is refused or ran at once (cached). Never raises."""
        try:
            got = self.core.prepare(pending.req, pending.axis_id)
        except Exception as exc:  # a bug: answer it, keep cycling
            got = self._internal(pending.rid, pending.cmd, exc, f"preparing {pending.cmd}")
        if isinstance(got, dict):
            return self._done(pending, got)
        pending.prepared = got
        pending.packed = pack(got.reply)
        return pending

    def activate(self, pending: PendingReply) -> bytes | None:
        """Activate a planned request before the step of its cycle (``core.activate``: in the gap of its plan or
        at that cycle's start); its packed reply (cached for a retry, with ``cycle`` = the step in which it takes
        effect), or None when its prediction no longer holds (nothing changed, ``pending.prepared`` cleared:
        plan it again, or :meth:`refuse_stale`)."""
        try:
            reply = self.core.activate(pending.prepared)
        except Exception as exc:  # a bug: answer it, keep cycling
            reply = self._internal(pending.rid, pending.cmd, exc, f"activating {pending.cmd}")
        if reply is None:
            pending.prepared = None
            return None
        return self._done(pending, reply)

    def _done(self, pending: PendingReply, reply: dict[str, Any]) -> bytes:
        """The end of a request in steps: counted, the last command noted, packed and cached."""
        if pending.prepared is not None and reply is pending.prepared.reply:
            packed = pending.packed
        else:
            packed = pack(reply)
        if reply.get("error"):
            self.errors += 1
        else:
            self.last_command[pending.axis_id] = (pending.client, pending.cmd, int(reply.get("cycle", self.core.cycle + 1)))
            self.commands_version += 1
        self.cache.put(pending.client, pending.rid, packed)
        return packed

    def refuse_stale(self, pending: PendingReply, code: int = NOT_READY, text: str = "") -> bytes:
        """The refusal of a prepared request that is not activated (nothing changed; cached for a retry):
        by default 0x4220, its axis changed under it each time it was prepared."""
        packed = self._error(pending.rid, pending.cmd, NcError(code, text or (
            f"{pending.cmd}: the axis changed each time the command was prepared; not activated (nothing changed)")))
        self.cache.put(pending.client, pending.rid, packed)
        return packed

    def _handle(self, key: str, payload: bytes, now: float, prepare: bool = False) -> bytes | PendingReply:
        if len(payload) > MAX_REQUEST_BYTES:
            return self.too_large(len(payload))
        try:
            req = parse_request(payload)
        except NcError as err:
            return self._error(getattr(err, "request_id", None), getattr(err, "cmd", None), err)
        rid, cmd = req["id"], req["cmd"]
        try:
            axis_id, cls, client = self.keys.parse_cmd_key(key)
            self._check_key(req, axis_id, cls, client)
        except NcError as err:
            return self._error(rid, cmd, err)
        req["client"] = client  # the identity is the key's (the field, if given, equals it)
        self._saw(client, cls)
        if cls == "read":
            read = self._execute(axis_id, req, now)
            assert read is not None  # (prepare=False: always a reply)
            return pack(read)
        cached = self.cache.get(client, rid)
        durable = self.keeps(cmd, axis_id)
        if cached is not None:
            self.durable = durable  # (an error reply held too: harmless, and no unpacking here)
            return cached
        two_phase = prepare and not durable and cmd in TWO_PHASE and axis_id is not None
        reply = self._execute(axis_id, req, now, two_phase)
        if reply is None:  # checked: the core's part follows (plan, activate)
            assert axis_id is not None
            return PendingReply(req, axis_id, client, rid, cmd)
        self.durable = durable and not reply.get("error")
        if axis_id is not None and not reply.get("error"):
            self.last_command[axis_id] = (client, cmd, int(reply.get("cycle", self.core.cycle + 1)))
            self.commands_version += 1
        packed = pack(reply)
        self.cache.put(client, rid, packed)
        return packed

    def _check_key(self, req: dict[str, Any], axis_id: int | None, cls: str, client: str) -> None:
        """The key's axis, class and client against the request (and the roles file).

        Raises:
            NcError: 0x4012 an axis that is not configured; 0x723 the command is of another
                class, the request names another client, or the client's role does not allow
                the class (or it is not in the roles file).
        """
        cmd = req["cmd"]
        if axis_id is not None and axis_id not in self._axes:
            raise NcError(AXIS_NOT_ALLOWED, f"no axis {axis_id} on NC {self.keys.nc!r}")
        want = COMMAND_CLASS[cmd]
        if cls != want:
            self.denied += 1
            where = self.keys.cmd(want, client) if axis_id is None else self.keys.axis_cmd(axis_id, want, client)
            raise NcError(ACCESS_DENIED, f"class key: {cmd} is a command of class {want!r}, not {cls!r}: send it on {where}")
        named = req.get("client", "")
        if named and named != client:
            self.denied += 1
            raise NcError(ACCESS_DENIED, f"client id: the request names client {named!r} but was sent on the key of client {client!r}")
        if self.roles is not None:
            role = self.roles.get(client)
            if role is None:
                self.denied += 1
                raise NcError(ACCESS_DENIED, f"role: client {client!r} is not in the NC's roles file")
            if cls not in ROLE_CLASSES[role]:
                self.denied += 1
                raise NcError(ACCESS_DENIED, f"role: client {client!r} is an {role}: {cmd} (class {cls!r}) needs "
                                             + " or ".join(r for r, c in ROLE_CLASSES.items() if cls in c))

    def _saw(self, client: str, cls: str) -> None:
        rank = _RANK[cls]
        old = self.seen.get(client)
        if old is not None and old >= rank:
            return
        if old is None and len(self.seen) >= MAX_SEEN:
            victim = next((c for c in self.seen if not self.claims.is_alive(c)), next(iter(self.seen)))
            del self.seen[victim]
        self.seen[client] = rank
        self.clients_version += 1

    def _execute(self, axis_id: int | None, req: dict[str, Any], now: float, prepare: bool = False) -> dict[str, Any] | None:
        """The request's reply map; with ``prepare`` None once the handler's checks passed (the core's part
        follows: :meth:`plan`)."""
        rid, client, cmd = req["id"], req["client"], req["cmd"]
        if COMMAND_SPECS[cmd].scope == "axis" and axis_id is None:
            where = f"{self.keys.prefix}/axis/<id>/cmd/{COMMAND_CLASS[cmd]}/{client}"
            return self._error_reply(rid, cmd, NcError(AXIS_NOT_ALLOWED, f"{cmd} is an axis command: send it to {where}"))
        own = _OWN.get(cmd)
        if own is not None:  # (the command registry's layer "server": claims, Info)
            try:
                return own(self, axis_id, req, now)
            except NcError as err:
                return self._error_reply(rid, cmd, err)
        assert axis_id is not None
        guard = _GUARDS.get(cmd)
        if guard is not None:
            try:
                guard(self, axis_id, client)
            except NcError as err:
                return self._error_reply(rid, cmd, err)
        # req["client"] (the key's) stays in the request: the core records it as the commander
        # of the motion job it starts.
        if prepare:
            return None
        reply = self.core.execute(req, axis_id)
        if reply.get("error"):
            self.errors += 1
        return reply

    # ---- the commands of the server's layer (registered in the command registry) ----------------
    @_server_command("Info")
    def _info(self, axis_id: int | None, req: dict[str, Any], now: float) -> dict[str, Any]:
        value = {"name": self.keys.nc, **self.core.info(), **self.info_extra(),
                 "claims": self.claims.claims(), "clients": self.claims.clients(),
                 "arbitration": self.arbitration()}
        return make_reply(req["id"], req["cmd"], 0, "", cycle=self.core.cycle + 1, value=value)

    @_server_command("Claim")
    def _claim(self, axis_id: int | None, req: dict[str, Any], now: float) -> dict[str, Any]:
        assert axis_id is not None
        client = req["client"]
        self.core.index(axis_id)  # (0x4012 for an axis the core does not have)
        if not self.claims.is_alive(client):
            # its token event may have arrived a moment ago: take pending events first
            self.refresh_liveliness()
        self.claims.claim(axis_id, client, now)
        return make_reply(req["id"], req["cmd"], 0, "", cycle=self.core.cycle + 1, value=client)

    @_server_command("HandOver")
    def _hand_over(self, axis_id: int | None, req: dict[str, Any], now: float) -> dict[str, Any]:
        # the claim moves; the applied PLCTONC stays until the new holder's first frame
        assert axis_id is not None
        client, to = req["client"], req["To"]
        self.core.index(axis_id)
        if to != client and not self.claims.is_alive(to):
            self.refresh_liveliness()
        if self.claims.hand_over(axis_id, client, to, now):
            log.info("axis %d handed over by %s to %s", axis_id, client, to)
        return make_reply(req["id"], req["cmd"], 0, "", cycle=self.core.cycle + 1, value=to)

    @_server_command("Release")
    def _release(self, axis_id: int | None, req: dict[str, Any], now: float) -> dict[str, Any]:
        assert axis_id is not None
        client = req["client"]
        i = self.core.index(axis_id)
        if self.claims.release(axis_id, client):
            # Nobody supplies PLCTONC any more: all enables off, override 100 %.
            self.core.set_plctonc(i, self.core.default_plctonc())
            log.info("axis %d released by %s", axis_id, client)
        return make_reply(req["id"], req["cmd"], 0, "", cycle=self.core.cycle + 1)

    @_guard("SetOverride")
    def _may_override(self, axis_id: int, client: str) -> None:
        self.claims.may_override(axis_id, client)

    # ---- who holds what -----------------------------------------------------------------------
    def role_of(self, client: str) -> tuple[str | None, str]:
        """(role, source): from the roles file (``"roles"``; None if unlisted), else by the highest
        class the client used (``"seen"``; None if it sent no command)."""
        if self.roles is not None:
            return self.roles.get(client), "roles"
        rank = self.seen.get(client)
        return (None if rank is None else SEEN_ROLE[CLASSES[rank]]), "seen"

    def arbitration(self) -> dict[str, Any]:
        """The ``nc/<nc>/claims`` map (protocol.json ``claims``): claims, clients (alive, role),
        the last command per axis. Call it on the thread that owns the handler."""
        alive = set(self.claims.clients())
        clients: dict[str, dict[str, Any]] = {}
        for c in sorted(alive | set(self.seen)):
            role, source = self.role_of(c)
            clients[c] = {"alive": c in alive, "role": role, "role_source": source}
        return {"cycle": int(self.core.cycle), "claims": self.claims.claims(), "clients": clients,
                "last_command": {a: {"client": c, "cmd": m, "cycle": cy}
                                 for a, (c, m, cy) in sorted(self.last_command.items())}}


#: Entries of CycleInputs' PLCTONC row cache (one per client and AxisIds list in use).
APPLY_CACHE_MAX = 256


class CycleInputs:
    """The NC's inputs of one cycle, applied before ``core.step()`` (pure: times are passed in).

    nc-server calls :meth:`apply` once per cycle with the newest frame of each client; the
    in-process NC (:class:`nc_sim.InProcessNc`) with each PLC task's frame as it is
    published, and :meth:`watchdog` when a port closes.

    A lost client (:class:`~nc_server.server.claims.Loss`), on each axis it supplied, per the axis's
    ``ClientLossReaction``:

    * ``"stop_disable"`` (default; TwinCAT's behaviour when the PLC stops): the axis stops on its
      fault ramp with the loss's error (0x8F01 / 0x8F02) and gets the default PLCTONC: disabled
      once it stands;
    * ``"stop"``: the same stop and error, but the last applied PLCTONC stays: the axis stays
      enabled, holding its position, until someone claims it and sends another;
    * ``"keep_others"``: if the axis runs a motion commanded by other live clients only, nothing
      stops: the NC keeps the last applied PLCTONC until the axis has no motion of a live client
      and stands, then applies the default (unless somebody claimed it meanwhile); otherwise as
      ``"stop_disable"``.

    On every other axis, a motion the lost client commanded (running or buffered, a superposition
    included; stops excepted) stops with 0x8F01 on the axis, so every client sees why; that axis's
    PLCTONC is not touched (its holder's stays).

    Args:
        core: the NcCore (owned by the calling thread).
        claims: the claim table (its ``axis_ids`` are the core's, in configuration order).
        reactions: ``ClientLossReaction`` per axis, in the same order (default: all "stop_disable").

    Attributes:
        faults: watchdog faults raised so far.
    """

    def __init__(self, core: FaultingCore, claims: ClaimTable, reactions: Sequence[str] | None = None) -> None:
        self.core = core
        self.claims = claims
        ids = claims.axis_ids
        # AxisId -> index lookup for PLC frames (vectorized); -1 = not configured.
        self._lut = np.full(max(ids, default=0) + 1, -1, dtype=np.int64)
        self._lut[ids] = np.arange(len(ids))
        self.reactions = list(reactions) if reactions else [LOSS_REACTIONS[0]] * len(ids)
        if len(self.reactions) != len(ids) or any(r not in LOSS_REACTIONS for r in self.reactions):
            raise ValueError(f"reactions must be {len(ids)} of {LOSS_REACTIONS}, got {reactions!r}")
        #: rows whose last PLCTONC the NC keeps after their holder was lost ("keep_others")
        self.kept: set[int] = set()
        self._apply_cache: dict[tuple[str, str, bytes], tuple[np.ndarray, np.ndarray, np.ndarray, float]] = {}
        self._apply_version = -1
        self.faults = 0

    def apply(self, frames: Iterable[tuple[str, PlctoncFrame]], now: float) -> list[tuple[int, int]]:
        """:meth:`apply_plctonc` then :meth:`watchdog`; returns the watchdog's faults."""
        self.apply_plctonc(frames)
        return self.watchdog(now)

    def apply_plctonc(self, frames: Iterable[tuple[str, PlctoncFrame]]) -> None:
        """Apply each (client, frame) to the axes the client holds.

        A record counts only for an axis claimed before the frame arrived (see
        ``ClaimTable.held_since``); records of other axes and unknown AxisIds are ignored.
        Only frames that count for a claim feed (and arm) the watchdog.
        """
        claims, lut = self.claims, self._lut
        cache = self._apply_cache
        if self._apply_version != claims.version:
            cache.clear()
            self._apply_version = claims.version
        for client, f in frames:
            # a client sends the same AxisIds frame after frame: their rows and claim times are cached
            # until the claims change (the usual frame then costs one dict lookup and the copy)
            raw = np.asarray(f.axis_ids)
            key = (client, raw.dtype.str, raw.tobytes())
            hit = cache.get(key)
            if hit is None:
                since = claims.held_since(client)
                ids = raw.astype(np.int64)
                ok = (ids >= 0) & (ids < len(lut))
                idx = np.where(ok, lut[np.where(ok, ids, 0)], -1)
                mine = np.flatnonzero(idx >= 0)
                t = since[idx[mine]]
                newest = float(t.max()) if t.size else np.inf
                hit = cache[key] = (idx, mine, t, newest)
                if len(cache) > APPLY_CACHE_MAX:  # (clients sending ever other AxisIds: bounded)
                    cache.clear()
            idx, mine, t, newest = hit
            if f.arrival >= newest:  # every held axis was claimed before this frame arrived
                sel = mine
            else:
                sel = mine[t <= f.arrival]
            if sel.size:
                claims.plctonc_arrived(client, f.arrival)
                # (all records apply in the usual case: no copy of the structured records)
                self._set_plctonc(idx[sel], f.plctonc if sel.size == len(idx) else f.plctonc[sel])

    def watchdog(self, now: float) -> list[tuple[int, int]]:
        """React to the clients lost at ``now`` [s] (see the class docstring); review kept axes.

        Returns:
            The (axis_id, error code) pairs faulted now.
        """
        out: list[tuple[int, int]] = []
        for loss in self.claims.check(now):
            out += self.client_lost(loss)
        if self.kept:
            self._review_kept()
        return out

    def client_lost(self, loss: Loss) -> list[tuple[int, int]]:
        """Apply one loss (its claims are already released); the (axis_id, code) pairs faulted."""
        core, claims = self.core, self.claims
        out: list[tuple[int, int]] = []
        done: set[int] = set()
        for axis_id in loss.faulted:
            i = core.index(axis_id)
            done.add(i)
            reaction = self.reactions[i]
            if reaction == "keep_others" and self._others_only(i, loss.client):
                self.kept.add(i)  # nothing stops: the other clients' motion goes on with the last PLCTONC
                log.warning("axis %d: client %s lost (0x%04X); the motion of %s goes on (keep_others)",
                            axis_id, loss.client, loss.code, ", ".join(sorted(self._commanders(i))))
                continue
            self._fault(i, axis_id, loss.code, out)
            if reaction != "stop":
                core.set_plctonc(i, core.default_plctonc())
            self.kept.discard(i)
            log.warning("axis %d: client %s lost: fault 0x%04X, claim released (%s)", axis_id, loss.client,
                        loss.code, reaction)
        for axis_id in loss.released:
            log.info("axis %d: claim of lost client %s released (it never supplied the axis)", axis_id, loss.client)
        # the motions it commanded on axes somebody else supplies (or nobody)
        for i in range(len(claims.axis_ids)):
            if i not in done and loss.client in self._commanders(i):
                axis_id = claims.axis_ids[i]
                self._fault(i, axis_id, ZNC_CLIENT_LOST, out)
                log.warning("axis %d: the motion commanded by lost client %s stopped (0x%04X)", axis_id,
                            loss.client, ZNC_CLIENT_LOST)
        if not out and not loss.faulted:
            log.info("client %s lost (0x%04X): it held nothing and commanded no running motion", loss.client, loss.code)
        return out

    def nc_stalled(self, gap: float) -> list[tuple[int, int]]:
        """The NC itself did not run for ``gap`` seconds (more than the watchdog timeout): every
        moving axis stops with 0x8F03 (nothing supervised its motion meanwhile; no client is
        blamed). Returns the (axis_id, code) pairs faulted."""
        out: list[tuple[int, int]] = []
        moving = getattr(self.core, "moving", None)
        if moving is None:
            return out
        for i in np.flatnonzero(np.asarray(moving)).tolist():
            self._fault(i, self.claims.axis_ids[i], ZNC_NC_STALLED, out)
        if out:
            log.error("the NC stalled for %.3f s: %d moving axes stopped with 0x%04X", gap, len(out), ZNC_NC_STALLED)
        return out

    def _fault(self, i: int, axis_id: int, code: int, out: list[tuple[int, int]]) -> None:
        self.core.fault(i, code)
        self.faults += 1
        out.append((axis_id, code))

    def _commanders(self, i: int) -> set[str]:
        fn = getattr(self.core, "commanders", None)
        return fn(i) if fn is not None else set()

    def _others_only(self, i: int, lost: str) -> bool:
        """Axis row ``i`` runs motions commanded by live clients other than ``lost`` only."""
        who = self._commanders(i)
        return bool(who) and all(c and c != lost and self.claims.is_alive(c) for c in who)

    def _review_kept(self) -> None:
        """Kept axes: the default PLCTONC once no live client's motion runs and the axis stands
        (not if somebody claimed it meanwhile: the new holder's frames apply)."""
        core, claims = self.core, self.claims
        moving = np.asarray(getattr(core, "moving", np.zeros(len(claims.axis_ids), dtype=bool)))
        for i in sorted(self.kept):
            axis_id = claims.axis_ids[i]
            if claims.holder(axis_id) is not None:
                self.kept.discard(i)
            elif not moving[i] and not any(c and claims.is_alive(c) for c in self._commanders(i)):
                core.set_plctonc(i, core.default_plctonc())
                self.kept.discard(i)
                log.info("axis %d: the kept motion ended; default PLCTONC (keep_others)", axis_id)

    def _set_plctonc(self, idx: np.ndarray, records: np.ndarray) -> None:
        core = self.core
        many = getattr(core, "set_plctonc_many", None)
        if many is not None:
            many(idx, records)
            return
        for i, r in zip(idx.tolist(), records):
            core.set_plctonc(i, r)
