"""NcLink: one client's zenoh session to one NC, its declarations, the NC's liveliness and instance.

May import: ``nc_schema``, ``zenoh`` and this package.
"""
from __future__ import annotations

import itertools
import threading
import time
from dataclasses import dataclass
from typing import Any, Iterable

import zenoh
from zenoh.handlers import FifoChannel, RingChannel

from nc_schema import (
    IDLE_VIEW_PERIOD_MS, MAX_VIEW_AXES, VIEW_PERIODS_MS, ErrorCodes, Keys, NcInstance, make_request, parse_alive_instance, parse_reply, unpack,
)
from nc_schema.zenoh_config import DEFAULT_LEASE_MS

from .session import open_session, short_error

#: LinkEvent kinds (see :class:`LinkEvent`).
GONE, ALIVE, BACK, RESTART = "gone", "alive", "back", "restart"


@dataclass(frozen=True, slots=True)
class LinkEvent:
    """One NC event taken by :meth:`NcLink.take_events`.

    ``kind``: ``gone`` (the NC's liveliness token vanished: unreachable, its data invalid; no restart),
    ``alive`` (its token is there), ``back`` (its token is back after ``gone``: the same instance or a new
    one, the instance token tells), ``restart`` (a new NC instance; ``why`` for the log).
    """

    kind: str
    why: str = ""


class CommandError(Exception):
    """A command of :meth:`NcLink.request` failed: the NC's error code, or the transport's
    (0x707 not connected / no route / denied, 0x706 a malformed reply, 0x719 no reply in time)."""

    def __init__(self, code: int, message: str) -> None:
        super().__init__(f"0x{code:X}: {message}")
        self.code = int(code)
        self.message = message


class NcLink:
    """The session of client ``client_id`` to NC ``nc`` (see the package docstring).

    Args:
        nc: the NC name (validated: ``Keys(nc)``).
        endpoint: the zenoh endpoint of the NC or its router, e.g. ``tcp/127.0.0.1:7447``.
        client_id: this client's id (its liveliness token, its command keys, its certificate's name).
        lease_ms: the zenoh lease this session announces [ms].
        tls_dir: certificate directory for mutual TLS (``tls/`` endpoint), or None.
        frame_key: the status frames taken (default ``nc/<nc>/frame``, every NC cycle's).
        holder: declare the client's liveliness token and PLCTONC publisher (a client that may hold axes;
            an observer has neither: the access control would deny both).
        claims: subscribe to the NC's claims map (``nc/<nc>/claims``, :meth:`take_claims`).
        query_timeout: how long :meth:`request` waits for a reply [s].
        config: a zenoh config to open instead of the built one (tests).
        view_period: take this client's view instead of whole frames (protocol.json ``view``): the frames of
            the axes given to :meth:`select` only, once per ``view_period`` ms of NC time (0: every NC cycle;
            one of ``nc_schema.VIEW_PERIODS_MS``); ``frame_key`` is then not used. None: whole frames. A view of
            no axes (nothing selected yet) is declared at ``nc_schema.IDLE_VIEW_PERIOD_MS``: its frames hold no
            record and only show the NC is there, so a client without axes is woken 10 times a second, not
            once per period.

    Attributes:
        keys: the NC's key builder. ready: the session is open and declared. session: the zenoh session.
        frames, alive_sub, instance_sub, claims_sub, token, pub: the declarations (None before :meth:`open`).
        view_tokens: the view's liveliness tokens (one per MAX_VIEW_AXES axes). view_axes: the axes of the view
            (:meth:`select`).
        instance: the NC instance followed (:class:`nc_schema.NcInstance`).
        nc_alive_seen, nc_gone: the NC's liveliness token was seen / is gone now.
        last_error: why the last :meth:`open` failed.
    """

    def __init__(self, nc: str, endpoint: str, client_id: str, lease_ms: int = DEFAULT_LEASE_MS,
                 tls_dir: str | None = None, frame_key: str | None = None, *, holder: bool = True,
                 claims: bool = False, query_timeout: float = 1.5, config: Any = None,
                 view_period: int | None = None) -> None:
        self.nc = nc
        self.endpoint = endpoint
        self.tls_dir = tls_dir
        self.keys = Keys(nc)
        self.frame_key = frame_key or self.keys.frame
        self.client_id = client_id
        self.lease_ms = lease_ms
        self.holder = holder
        self.claims = claims
        self.query_timeout = float(query_timeout)
        self.config = config
        if view_period is not None and view_period not in VIEW_PERIODS_MS:
            raise ValueError(f"view period {view_period!r} ms: use one of {VIEW_PERIODS_MS}")
        self.view_period = view_period
        self.view_axes: tuple[int, ...] = ()
        self.view_tokens: list[Any] = []
        self._view_keys: list[str] = []
        self._view_lock = threading.Lock()  # select() on the PLC thread, open() on the reconnect thread
        self.session: zenoh.Session | None = None
        self.frames: Any = None
        self.alive_sub: Any = None
        self.instance_sub: Any = None
        self.claims_sub: Any = None
        self.token: Any = None
        self.pub: Any = None
        self.ready = False
        self.last_error = ""
        self.nc_alive_seen = False
        self.nc_gone = False
        self.instance = NcInstance()
        self._instance_lock = threading.Lock()  # frames and tokens may be taken by two threads (nc-ads)
        self._ids = itertools.count(time.time_ns() // 1000)  # unique across restarts (see plc_client.port)

    @property
    def restarts(self) -> int:
        """NC restarts seen (new NC instances: instance tokens and frames)."""
        return self.instance.restarts

    def stats(self) -> dict[str, int | None]:
        """The link's diagnostics: ``restarts``, ``epoch`` (followed), ``stale_epoch_frames``, ``epoch_rises``
        (takeovers seen), ``epoch_falls`` (lower epochs taken: a new instance, or the hold ran out)."""
        i = self.instance
        with self._instance_lock:
            return {"restarts": i.restarts, "epoch": i.epoch, "stale_epoch_frames": i.stale_frames,
                    "epoch_rises": i.epoch_rises, "epoch_falls": i.epoch_falls}

    # ---- the session ------------------------------------------------------------------------------------------
    def open(self) -> bool:
        """Open the session and declare everything; False (and ``last_error``) if the NC is unreachable."""
        try:
            s = open_session(self.endpoint, self.client_id, self.lease_ms, self.tls_dir, self.config)
        except Exception as exc:  # zenoh.ZError: nobody listens there (yet)
            self.last_error = short_error(exc)
            return False
        try:
            if self.view_period is None:
                self.frames = s.declare_subscriber(self.frame_key, RingChannel(1))
            else:
                self.frames = s.declare_subscriber(self.keys.view(self.client_id), RingChannel(1))
            self.alive_sub = s.liveliness().declare_subscriber(self.keys.alive, FifoChannel(64), history=True)
            self.instance_sub = s.liveliness().declare_subscriber(self.keys.alive_instance_any, FifoChannel(64),
                                                                  history=True)
            if self.claims:
                self.claims_sub = s.declare_subscriber(self.keys.claims, RingChannel(1))
            if self.holder:
                self.token = s.liveliness().declare_token(self.keys.client_alive(self.client_id))
                self.pub = s.declare_publisher(self.keys.plctonc_in(self.client_id))
        except Exception as exc:
            self.last_error = str(exc)
            try:
                s.close()
            except Exception:
                pass
            return False
        with self._view_lock:  # (select() on another thread declares on this session from here on)
            self.view_tokens, self._view_keys = [], []  # (the tokens of an earlier session went with it)
            self.session = s
        self.ready = True
        if self.view_period is not None:
            self._declare_view()
        return True

    # ---- the view -----------------------------------------------------------------------------------------------
    def select(self, axes: Iterable[int]) -> None:
        """The axes of this client's view (with ``view_period``): from now on the NC sends the frames of these
        axes only (the new tokens are declared before the old ones go, so no frame is missed; more than
        ``nc_schema.MAX_VIEW_AXES`` axes take several tokens, which the NC joins). Does nothing without
        ``view_period`` or when the set is unchanged.

        Raises:
            ValueError: a negative id.
        """
        ids = tuple(sorted({int(a) for a in axes}))
        if self.view_period is None or ids == self.view_axes:
            return
        if ids and ids[0] < 0:
            raise ValueError(f"invalid axis id {ids[0]}")
        self.view_axes = ids
        if self.session is not None:
            self._declare_view()

    def _view_token_keys(self) -> list[str]:
        assert self.view_period is not None
        ids, n = self.view_axes, MAX_VIEW_AXES
        chunks = [ids[i:i + n] for i in range(0, len(ids), n)] or [()]
        period = self.view_period if ids else max(self.view_period, IDLE_VIEW_PERIOD_MS)
        return [self.keys.view_select(self.client_id, period, c) for c in chunks]

    def _declare_view(self) -> None:
        with self._view_lock:
            keys = self._view_token_keys()
            s = self.session
            if s is None or keys == self._view_keys:
                return
            tokens: list[Any] = []
            try:
                for key in keys:
                    tokens.append(s.liveliness().declare_token(key))
            except Exception as exc:  # session closing
                self.last_error = str(exc)
                for t in tokens:
                    try:
                        t.undeclare()
                    except Exception:
                        pass
                return
            old, self.view_tokens, self._view_keys = self.view_tokens, tokens, keys
            for t in old:
                try:
                    t.undeclare()
                except Exception:
                    pass

    def close(self, undeclare: bool = True) -> None:
        """Undeclare everything (unless ``undeclare`` is False: a thread may be blocked in ``frames.recv()``,
        which closing the session ends) and close the session. Idempotent, never raises."""
        self.ready = False
        if undeclare:
            for d in (*self.view_tokens, self.token, self.pub, self.alive_sub, self.instance_sub, self.claims_sub,
                      self.frames):
                if d is not None:
                    try:
                        d.undeclare()
                    except Exception:
                        pass
            self.token = self.pub = self.alive_sub = self.instance_sub = self.claims_sub = self.frames = None
            self.view_tokens, self._view_keys = [], []
        if self.session is not None:
            try:
                self.session.close()  # type: ignore[no-untyped-call]  # (zenoh's stub leaves close() unannotated)
            except Exception:
                pass
            if undeclare:
                self.session = None

    # ---- frames and the NC instance ----------------------------------------------------------------------------
    def take_frame(self) -> bytes | None:
        """The newest status frame's bytes if one arrived since the last call (never blocks)."""
        sample = self.frames.try_recv()
        return None if sample is None else sample.payload.to_bytes()

    def follow_frame(self, cycle: int, epoch: int) -> tuple[bool, str | None]:
        """Take a frame's ``Cycle`` and ``Epoch`` (``nc_schema.NcInstance.take``, clock: ``time.monotonic``):
        (taken, reason). Not taken: a frame of a lower epoch than the one followed (a hot-standby pair's old active
        NC after a link cut): its data must not be used, counted in :meth:`stats` (``stale_epoch_frames``). Taken: the
        reason if it shows a new NC instance (once per restart), else None."""
        with self._instance_lock:
            return self.instance.take(cycle, epoch, time.monotonic())

    def take_events(self) -> list[LinkEvent]:
        """The NC's liveliness events since the last call, in order: ``nc/<nc>/alive`` (gone / alive / back),
        then its instance tokens (``restart`` for another instance id than the one followed; the same id
        coming back after a dropped link, a malformed id or another NC's token is nothing)."""
        events: list[LinkEvent] = []
        while True:
            ev = self.alive_sub.try_recv()
            if ev is None:
                break
            if ev.kind == zenoh.SampleKind.DELETE:
                self.nc_gone = True
                events.append(LinkEvent(GONE))
            else:
                back = self.nc_alive_seen and self.nc_gone
                self.nc_alive_seen, self.nc_gone = True, False
                events.append(LinkEvent(BACK if back else ALIVE))
        while True:
            ev = self.instance_sub.try_recv()
            if ev is None:
                break
            parsed = parse_alive_instance(ev.key_expr)
            if ev.kind != zenoh.SampleKind.DELETE and parsed is not None and parsed[0] == self.nc:
                with self._instance_lock:
                    why = self.instance.token(parsed[1])
                if why is not None:
                    events.append(LinkEvent(RESTART, why))
        return events

    def take_claims(self) -> tuple[int, dict[int, str]] | None:
        """The NC's newest claims map (``nc/<nc>/claims``: NC cycle, AxisId -> holder) if one arrived since the
        last call and could be read, else None."""
        s = self.claims_sub.try_recv()
        if s is None:
            return None
        try:
            m = unpack(s.payload.to_bytes())
            return int(m.get("cycle", 0)), {int(k): str(v) for k, v in (m.get("claims") or {}).items()}
        except Exception:
            return None

    def publish(self, payload: bytes) -> None:
        """Put one PLC frame (PLCTONC of the axes this client holds) on ``nc/<nc>/plctonc/<client_id>``."""
        self.pub.put(payload)

    # ---- commands ---------------------------------------------------------------------------------------------
    def declare_holder(self, client_id: str) -> tuple[Any, Any]:
        """Declare, on this session, the liveliness token ``nc/<nc>/client/<client_id>`` and the PLCTONC publisher
        ``nc/<nc>/plctonc/<client_id>`` of another client id this door acts for (a door's user, ``<door>.<user>``):
        (token, publisher); undeclaring the token is that client's loss for the NC (docs/arbitration.md).

        Raises:
            ValueError: an invalid client id. CommandError: 0x707 no session.
        """
        s = self.session
        if s is None:
            raise CommandError(ErrorCodes.ADSERR_DEVICE_NOTREADY, f"not connected to NC {self.nc}")
        token = s.liveliness().declare_token(self.keys.client_alive(client_id))
        return token, s.declare_publisher(self.keys.plctonc_in(client_id))

    def request(self, cmd: str, axis: int | None, /, *, sender: str | None = None, **args: Any) -> dict[str, Any]:
        """Send ``cmd`` (to axis ``axis``, None: the NC-level key) and wait for the reply (a door's thread).
        ``sender``: the client id it is sent as (a door's user, ``<door>.<user>``); None: ``client_id``.

        Raises:
            CommandError: the NC's code; 0x707 no session, or zenoh ended the query without a reply early;
                0x706 a malformed reply; 0x719 no reply within ``query_timeout``.
        """
        s = self.session
        if s is None:
            raise CommandError(ErrorCodes.ADSERR_DEVICE_NOTREADY, f"not connected to NC {self.nc}")
        client = sender or self.client_id
        key = self.keys.command_key(cmd, axis, client)
        payload = make_request(cmd, next(self._ids), client, **args)
        t0 = time.monotonic()
        try:
            replies = s.get(key, payload=payload, timeout=self.query_timeout,
                            consolidation=zenoh.ConsolidationMode.NONE)
            for r in replies:
                if r.ok is None:
                    raise CommandError(ErrorCodes.ADSERR_DEVICE_NOTREADY, "error reply from the NC's queryable")
                try:
                    reply = parse_reply(r.ok.payload.to_bytes())
                except ValueError as exc:
                    raise CommandError(ErrorCodes.ADSERR_DEVICE_INVALIDDATA, f"malformed reply: {exc}") from None
                code = int(reply["error"])
                if code:
                    raise CommandError(code, f"{cmd}: {reply.get('text') or 'refused by the NC'}")
                return reply
        except CommandError:
            raise
        except Exception as exc:  # session closing
            raise CommandError(ErrorCodes.ADSERR_DEVICE_NOTREADY, f"query failed: {exc}") from None
        waited = time.monotonic() - t0
        if waited >= 0.9 * self.query_timeout:
            raise CommandError(ErrorCodes.ADSERR_DEVICE_TIMEOUT,
                               f"{cmd}: no reply from NC {self.nc} within {self.query_timeout:g} s")
        # zenoh ended the query at once: no route to the NC, or the router's access control denied it (a denied
        # query is finalized without a reply; docs/roles.md): the two cannot be told apart from here
        raise CommandError(ErrorCodes.ADSERR_DEVICE_NOTREADY, f"{cmd}: no reply (NC {self.nc} unreachable, or access "
                                                              f"control denied {client}'s query)")
