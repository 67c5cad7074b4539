"""WebDoor: the Starlette app of nc-web (pages, login, commands, live values over WebSocket).

Routes::

    GET  /                      the NCs (redirects to /login without a login)
    GET  /login, POST /login    the login form (urlencoded user, password); 401 on a failed login
    POST /logout                ends the login: its claims are released, its axes stop (NcDoor.session_gone)
    GET  /nc/<nc>               the page of one NC: axes, axis dialog (operator), parameters, scope
    GET  /static/<file>         the page's own script and style (nothing is loaded from elsewhere)
    GET  /api/nc/<nc>/params/<axis>[?refresh=1]   the axis's MC_AxisPara values (read on demand, cached)
    POST /api/nc/<nc>/axis/<axis>/<command>      an axis command (JSON arguments, see COMMANDS)
    WS   /ws/nc/<nc>            live values (``frame`` messages at the door's frame period) and hold-to-run jogs

Roles: a login's role is the users file's capped by the door's own (``role_min``); a command needs the class of
the NC command it sends (``nc_schema.COMMAND_CLASS``: ``op`` for power and motion, ``eng`` for WriteParameter and
SetActualPosition). A refusal by role is HTTP 403 with ``{"error": 0x723, "text": ...}`` and nothing is sent; the
page of an observer has no command buttons at all (rendered on the server). An NC refusal is HTTP 409 with the
NC's ErrorID and text (``{"error": 0x4221, "text": ...}``), 502/504 for an unreachable / silent NC, 404 for an
NC this door does not serve. Every POST and the WebSocket pass :func:`cross_site` (CSRF).

Client ids: the door connects as ``door_id``; what it commands for user U is sent as ``<door_id>.<U>``
(:class:`nc_link.door.NcDoor`, the same rule as nc-opcua's, docs/roles.md).

Logins and door sessions: a login is a door session (a number never reused). The cookie ``ncweb`` carries a
random login id with an HMAC-SHA256 under the door's secret (read from a file or made at start), HttpOnly,
SameSite=Strict (Secure under HTTPS). A login ends by logout, by its maximum age, or when none of its pages has
had its WebSocket open for ``session_idle`` s (the tab closed, the network cut; before its first page opened, at
least 60 s): then its claims are released
and the axes it powered or moved stop (0x8F01, ``NcDoor.session_gone``), and the browser must log in again.

Hold-to-run: a held jog button sends ``{"type": "jog", ...}`` on the page's WebSocket every ``heartbeat`` s;
each one renews the jog for ``hold_timeout`` s (``NcDoor.jog`` with that timeout): without heartbeats the door
sends Halt within ``hold_timeout`` plus one supply period; a closed WebSocket halts that page's jogs at once.

May import: ``starlette``, ``nc_link``, ``nc_schema``, the standard library and this package.
"""
from __future__ import annotations

import asyncio
import contextlib
import hashlib
import hmac
import html
import itertools
import json
import logging
import math
import os
import secrets
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, AsyncIterator, Awaitable, Callable
from urllib.parse import parse_qs

import numpy as np
from starlette.applications import Starlette
from starlette.requests import Request
from starlette.responses import HTMLResponse, JSONResponse, RedirectResponse, Response
from starlette.routing import Route, WebSocketRoute
from starlette.websockets import WebSocket, WebSocketDisconnect

from nc_link import CommandError
from nc_link.door import OVERRIDE_100, CommandPool, NcDoor
from nc_link.users import LoginsBusy, PasswordGate, User, Verifier, check_door_config, role_min
from nc_schema import (
    COMMAND_CLASS, NCTOPLC_DTYPE, PARAMETERS, ROLE_CLASSES, ErrorCodes, StateDWord, check_client_id, error_name,
    error_text, motion_state,
)

log = logging.getLogger(__name__)

__all__ = ["WebDoor", "WebConfig", "COMMANDS", "COOKIE"]

COOKIE = "ncweb"
STATIC = Path(__file__).with_name("static")
_STATIC_FILES = {"app.js": "text/javascript", "app.css": "text/css"}
_HOMED = int(StateDWord.Homed)
_CLOSED = int(StateDWord.ControlLoopClosed)
_ACCESS_DENIED = int(ErrorCodes.ADSERR_DEVICE_ACCESSDENIED)
_INVALID = int(ErrorCodes.ADSERR_DEVICE_INVALIDDATA)
_BAD_PARAM = int(ErrorCodes.MC_PARAMETER_NOT_CORRECT)
#: page command -> (NC command whose class it needs, {argument: required}); Jog runs over the WebSocket only
COMMANDS: dict[str, tuple[str, dict[str, bool]]] = {
    "Power": ("Claim", {"Enable": True, "Override": False}),
    "Reset": ("Reset", {}),
    "Halt": ("Halt", {}),
    "Stop": ("Stop", {}),
    "MoveAbsolute": ("MoveAbsolute", {"Position": True, "Velocity": True}),
    "MoveRelative": ("MoveRelative", {"Distance": True, "Velocity": True}),
    "Home": ("Home", {"Position": False}),
    "SetActualPosition": ("SetActualPosition", {"Position": True}),
    "JogStop": ("Halt", {}),
    "WriteParameter": ("WriteParameter", {"Name": True, "Value": True}),
}


@dataclass
class WebConfig:
    """nc-web's settings (the command line's, :mod:`nc_web.cli`).

    ncs: NC name -> zenoh endpoint (the NC's or its router's). users: the users file's users. role: the door's
    own role (caps every user's). door_id: its client id. tls_dir: zenoh mutual TLS as ``door_id``.
    frame_ms: the frames taken and pushed to the pages (``nc/<nc>/frame/<P>ms``). secret: the cookie key.
    hold_timeout: a jog stops this long after its last heartbeat [s]. session_idle: a login without an open
    page this long ends [s]. login_max_age [s]. secure_cookie: HTTPS. heartbeat: the page's jog heartbeat [s].
    """

    ncs: dict[str, str]
    users: dict[str, User]
    secret: bytes
    role: str = "engineer"
    door_id: str = "web"
    tls_dir: str | None = None
    frame_ms: int = 50
    hold_timeout: float = 0.1
    heartbeat: float = 0.03
    session_idle: float = 10.0
    login_max_age: float = 12 * 3600.0
    secure_cookie: bool = False
    connect_timeout: float = 10.0


@dataclass
class Login:
    """One login (a door session): ``number`` for NcDoor, the user and effective role, its open pages."""

    number: int
    user: str
    role: str
    started: float
    sockets: int = 0
    websockets: set[WebSocket] = field(default_factory=set)  # its pages' open WebSockets (closed when it ends)
    paged: bool = False  # a page of it opened its WebSocket once
    idle_since: float = field(default_factory=time.monotonic)
    ended: bool = False


class _Refused(Exception):
    def __init__(self, status: int, code: int, text: str) -> None:
        super().__init__(text)
        self.status, self.code, self.text = status, code, text


def _json_error(status: int, code: int, text: str) -> JSONResponse:
    return JSONResponse({"error": code, "text": text}, status_code=status)


def _http_status_of(code: int) -> int:
    if code == ErrorCodes.ADSERR_DEVICE_NOTREADY:
        return 502
    if code == ErrorCodes.ADSERR_DEVICE_TIMEOUT:
        return 504
    if code == _ACCESS_DENIED:
        return 403
    return 409


def cross_site(headers: Any, api: bool = False) -> str | None:
    """Why a request is refused as another site's (CSRF), or None: an ``Origin`` that is not this server's
    (``Host``), a ``Sec-Fetch-Site`` other than same-origin/none, and on ``/api/...`` a body that is not
    ``application/json`` (a form or text/plain POST needs no CORS preflight; JSON does). Used by every POST and
    the WebSocket."""
    origin, host = headers.get("origin"), headers.get("host")
    if origin is not None and (host is None or origin.split("://", 1)[-1].rstrip("/") != host):
        return f"Origin {origin} is not this server's"
    site = headers.get("sec-fetch-site")
    if site is not None and site not in ("same-origin", "none"):
        return f"Sec-Fetch-Site {site}"
    if api and headers.get("content-type", "").split(";", 1)[0].strip().lower() != "application/json":
        return "Content-Type must be application/json"
    return None


def script_json(value: Any) -> str:
    """``value`` as JSON to put inside ``<script type="application/json">``: a script's text is not HTML-decoded,
    so ``<``, ``>`` and ``&`` are JSON escapes (``\\u003c`` ...), which also keeps ``</script>`` out of it."""
    return json.dumps(value).replace("<", "\\u003c").replace(">", "\\u003e").replace("&", "\\u0026")


def error_label(code: int) -> str:
    """``NAME: text`` of an NC error code (the contract's errors.json), "" for 0."""
    return f"{error_name(code)}: {error_text(code)}" if code else ""


def axis_values(rec: bytes) -> dict[str, Any]:
    """What the page shows of one NCTOPLC record."""
    r = np.frombuffer(rec[:NCTOPLC_DTYPE.itemsize], dtype=NCTOPLC_DTYPE)[0]
    sdw, err = int(r["StateDWord"]), int(r["ErrorCode"])
    return {"ActPos": float(r["ActPos"]), "SetPos": float(r["SetPos"]), "ActVelo": float(r["ActVelo"]),
            "SetVelo": float(r["SetVelo"]), "PosDiff": float(r["PosDiff"]), "StateDWord": sdw,
            "State": motion_state(sdw, int(r["CoupleState"])).name.removeprefix("MC_AXISSTATE_"),
            "Homed": bool(sdw & _HOMED), "Enabled": bool(sdw & _CLOSED), "ErrorCode": err,
            "ErrorText": error_label(err), "DcTimeStamp": int(r["DcTimeStamp"])}


class WebDoor:
    """nc-web (see the module docstring): ``app`` is the ASGI app; ``door_factory`` makes the NC links (tests)."""

    def __init__(self, cfg: WebConfig, door_factory: Callable[[str, str], NcDoor] | None = None) -> None:
        check_door_config(cfg.door_id, cfg.users, cfg.role)
        if not cfg.ncs:
            raise ValueError("no NC (--nc NAME=ENDPOINT)")
        for nc in cfg.ncs:
            check_client_id(nc)  # an NC name is a key chunk too
        self.cfg = cfg
        self.verifier = Verifier(cfg.users)
        self.gate = PasswordGate(self.verifier)
        self.commands = CommandPool()
        self._factory = door_factory or (lambda nc, ep: NcDoor(nc, ep, cfg.door_id, cfg.frame_ms, cfg.tls_dir))
        self.doors: dict[str, NcDoor] = {}
        self.logins: dict[str, Login] = {}
        self._numbers = itertools.count(1)
        self._tasks: list[asyncio.Task[Any]] = []
        self.app = Starlette(routes=[
            Route("/", self.index), Route("/login", self.login_page, methods=["GET"]),
            Route("/login", self.login, methods=["POST"]), Route("/logout", self.logout, methods=["POST"]),
            Route("/nc/{nc}", self.nc_page), Route("/static/{name}", self.static),
            Route("/favicon.ico", lambda request: Response(status_code=204)),
            Route("/api/nc/{nc}/params/{axis:int}", self.params),
            Route("/api/nc/{nc}/axis/{axis:int}/{cmd}", self.command, methods=["POST"]),
            WebSocketRoute("/ws/nc/{nc}", self.live),
        ], lifespan=self._lifespan)

    # ---- lifecycle --------------------------------------------------------------------------------------------
    @contextlib.asynccontextmanager
    async def _lifespan(self, app: Starlette) -> AsyncIterator[None]:
        await self.startup()
        try:
            yield
        finally:
            await self.shutdown()

    async def startup(self) -> None:
        for nc in self.cfg.ncs:
            self._tasks.append(asyncio.create_task(self._connect(nc)))
        self._tasks.append(asyncio.create_task(self._reaper()))

    async def _connect(self, nc: str) -> None:
        """Open the link to ``nc``, retrying until it opens (an NC not there yet)."""
        while True:
            d = self._factory(nc, self.cfg.ncs[nc])
            try:
                await asyncio.to_thread(d.start, self.cfg.connect_timeout)
            except ConnectionError as exc:
                log.warning("%s (retrying)", exc)
                continue
            self.doors[nc] = d
            log.info("serving NC %s", nc)
            return

    async def shutdown(self) -> None:
        for t in self._tasks:
            t.cancel()
        for login in list(self.logins.values()):
            await self._end(login, "nc-web stops")
        await asyncio.gather(*(asyncio.to_thread(d.close) for d in self.doors.values()))
        self.gate.close()
        self.commands.close()

    async def _reaper(self) -> None:
        """End logins without an open page for ``session_idle`` s, or older than ``login_max_age``."""
        while True:
            await asyncio.sleep(min(1.0, self.cfg.session_idle / 4))
            now = time.monotonic()
            for sid, login in list(self.logins.items()):
                try:  # one failing end must not end the reaper: the other logins would never end
                    # before its first page: the page's load may take a while on a slow client, so at least 60 s
                    idle = self.cfg.session_idle if login.paged else max(60.0, self.cfg.session_idle)
                    if login.sockets == 0 and now - login.idle_since > idle:
                        await self._end(login, f"no page open for {self.cfg.session_idle:g} s")
                    elif time.time() - login.started > self.cfg.login_max_age:
                        await self._end(login, "login too old")
                except Exception:
                    log.exception("ending login %d of %s failed (tried again)", login.number, login.user)

    async def _end(self, login: Login, why: str) -> None:
        if login.ended:
            return
        login.ended = True
        for sid, lg in list(self.logins.items()):
            if lg is login:
                del self.logins[sid]
        log.info("login %d of %s ended (%s): its claims and motions end", login.number, login.user, why)
        for ws in list(login.websockets):  # its pages lose their live values and jogs with it
            asyncio.create_task(_close_quietly(ws, 4401))
        await asyncio.gather(*(self.commands.run(d.session_gone, login.number) for d in list(self.doors.values())))

    # ---- logins -------------------------------------------------------------------------------------------------
    def _sign(self, sid: str) -> str:
        return sid + "." + hmac.new(self.cfg.secret, sid.encode(), hashlib.sha256).hexdigest()

    def _login_of(self, cookies: dict[str, str]) -> Login | None:
        raw = cookies.get(COOKIE, "")
        sid, _, mac = raw.partition(".")
        if not sid or not hmac.compare_digest(self._sign(sid), raw):
            return None
        login = self.logins.get(sid)
        return None if login is None or login.ended else login

    async def login_page(self, request: Request) -> Response:
        return HTMLResponse(_login_html(""))

    async def login(self, request: Request) -> Response:
        if (why := cross_site(request.headers)) is not None:
            return Response(f"refused: {why}", status_code=403)
        form = parse_qs((await request.body()).decode(errors="replace"))
        user = (form.get("user") or [""])[0]
        password = (form.get("password") or [""])[0]
        try:  # scrypt: on the gate's own threads, never on the event loop nor the NC commands' threads
            ok = await self.gate.check(user, password)
        except LoginsBusy:
            log.warning("login of %r refused: too many logins at once", user)
            return HTMLResponse(_login_html("Too many logins at once: try again."), status_code=429,
                                headers={"Retry-After": "1"})
        if not ok:
            log.warning("login of %r refused", user)
            return HTMLResponse(_login_html("Login failed: unknown user or wrong password."), status_code=401)
        role = role_min(self.cfg.users[user].role, self.cfg.role)
        sid = secrets.token_urlsafe(24)
        self.logins[sid] = Login(next(self._numbers), user, role, time.time())
        resp = RedirectResponse("/", status_code=303)
        resp.set_cookie(COOKIE, self._sign(sid), max_age=int(self.cfg.login_max_age), httponly=True,
                        samesite="strict", secure=self.cfg.secure_cookie)
        return resp

    async def logout(self, request: Request) -> Response:
        if (why := cross_site(request.headers)) is not None:
            return Response(f"refused: {why}", status_code=403)
        login = self._login_of(request.cookies)
        if login is not None:
            await self._end(login, "logged out")
        resp = RedirectResponse("/login", status_code=303)
        resp.delete_cookie(COOKIE)
        return resp

    # ---- pages --------------------------------------------------------------------------------------------------
    async def index(self, request: Request) -> Response:
        login = self._login_of(request.cookies)
        if login is None:
            return RedirectResponse("/login", status_code=303)
        if len(self.cfg.ncs) == 1:
            return RedirectResponse(f"/nc/{next(iter(self.cfg.ncs))}", status_code=303)
        items = "".join(f'<li><a href="/nc/{html.escape(nc)}">{html.escape(nc)}</a></li>' for nc in self.cfg.ncs)
        return HTMLResponse(_page("zenoh-nc", f"<h1>NCs</h1><ul>{items}</ul>", login))

    async def nc_page(self, request: Request) -> Response:
        login = self._login_of(request.cookies)
        if login is None:
            return RedirectResponse("/login", status_code=303)
        nc = str(request.path_params["nc"])
        if nc not in self.cfg.ncs:
            return HTMLResponse(_page("unknown NC", f"<p>No NC {html.escape(nc)} here.</p>", login), status_code=404)
        classes = ROLE_CLASSES[login.role]
        cfg = {"nc": nc, "role": login.role, "user": login.user, "op": "op" in classes, "eng": "eng" in classes,
               "heartbeat_ms": int(self.cfg.heartbeat * 1000), "frame_ms": self.cfg.frame_ms,
               "params": [{"number": p.number, "name": p.name, "unit": p.unit or "", "writable": bool(p.writable),
                           "bool": p.is_bool, "doc": p.doc} for p in PARAMETERS]}
        body = _nc_body(nc, bool(cfg["op"]), bool(cfg["eng"]))
        script = (f'<script id="cfg" type="application/json">{script_json(cfg)}</script>'
                  '<script src="/static/app.js"></script>')
        return HTMLResponse(_page(f"{nc} - zenoh-nc", body + script, login))

    async def static(self, request: Request) -> Response:
        name = str(request.path_params["name"])
        if name not in _STATIC_FILES:
            return Response("not found", status_code=404)
        return Response((STATIC / name).read_bytes(), media_type=_STATIC_FILES[name],
                        headers={"Cache-Control": "no-cache"})

    # ---- parameters -------------------------------------------------------------------------------------------
    async def params(self, request: Request) -> Response:
        login = self._login_of(request.cookies)
        if login is None:
            return _json_error(401, _ACCESS_DENIED, "not logged in")
        nc = str(request.path_params["nc"])
        if nc not in self.cfg.ncs:
            return _json_error(404, _INVALID, f"no NC {nc!r} here")
        d = self.doors.get(nc)
        if d is None:
            return _json_error(502, int(ErrorCodes.ADSERR_DEVICE_NOTREADY), "NC not connected")
        axis = int(request.path_params["axis"])
        refresh = request.query_params.get("refresh") == "1"

        def read_all() -> list[dict[str, Any]]:
            got = d.read_parameters(axis, [p.number for p in PARAMETERS], refresh)  # refresh: at most every 5 s
            return [{"number": n, "value": None, "error": v.code, "text": v.message} if isinstance(v, CommandError)
                    else {"number": n, "value": v, "error": 0, "text": ""} for n, v in got.items()]
        return JSONResponse({"axis": axis, "params": await asyncio.to_thread(read_all)})

    # ---- commands -----------------------------------------------------------------------------------------------
    def _check_role(self, login: Login, what: str, nc_cmd: str) -> None:
        cls = COMMAND_CLASS[nc_cmd]
        if cls not in ROLE_CLASSES[login.role]:
            need = " or ".join(r for r, c in ROLE_CLASSES.items() if cls in c)
            raise _Refused(403, _ACCESS_DENIED, f"role: {login.user} is {login.role} here; {what} needs {need}")

    async def command(self, request: Request) -> Response:
        login = self._login_of(request.cookies)
        if login is None:
            return _json_error(401, _ACCESS_DENIED, "not logged in")
        if (why := cross_site(request.headers, api=True)) is not None:
            return _json_error(403, _ACCESS_DENIED, f"refused: {why}")
        nc, axis, cmd = str(request.path_params["nc"]), int(request.path_params["axis"]), str(request.path_params["cmd"])
        try:
            if cmd not in COMMANDS:
                raise _Refused(404, _INVALID, f"unknown command {cmd!r}")
            if nc not in self.cfg.ncs:
                raise _Refused(404, _INVALID, f"no NC {nc!r} here")
            self._check_role(login, cmd, COMMANDS[cmd][0])
            try:
                args = json.loads(await request.body() or b"{}")
            except ValueError:
                raise _Refused(400, _INVALID, f"{cmd}: the body is not JSON") from None
            args = _check_args(cmd, args)
            d = self.doors.get(nc)
            if d is None:
                raise _Refused(502, int(ErrorCodes.ADSERR_DEVICE_NOTREADY), f"NC {nc} is not connected")
            await self._run(d, login, cmd, axis, args)
        except _Refused as r:
            return _json_error(r.status, r.code, r.text)
        except CommandError as exc:
            return _json_error(_http_status_of(exc.code), exc.code, exc.message)
        return JSONResponse({"error": 0, "text": ""})

    async def _run(self, d: NcDoor, login: Login, cmd: str, axis: int, args: dict[str, Any]) -> None:
        sender, sid = f"{self.cfg.door_id}.{login.user}", login.number
        run: Callable[..., Awaitable[Any]] = self.commands.run
        if cmd == "Power":
            override = float(args.get("Override", 100.0))
            if not 0.0 <= override <= 100.0:
                raise _Refused(400, _BAD_PARAM, f"Override {override} % outside 0..100")
            await run(d.power, axis, sender, sid, bool(args["Enable"]), int(round(override / 100 * OVERRIDE_100)))
        elif cmd == "JogStop":
            await run(d.jog_stop, axis, sender, sid)
        elif cmd == "WriteParameter":
            p = PARAMETERS.by_name(str(args["Name"]))
            if p is None:
                raise _Refused(400, _BAD_PARAM, f"unknown parameter {args['Name']!r}")
            value: Any = bool(args["Value"]) if p.is_bool else float(args["Value"])
            try:
                await run(lambda: d.command("WriteParameter", axis, sender, sid, ParameterNumber=p.number, Value=value))
            finally:  # refreshed after a write (a refused one too: the cache shows the NC's value)
                try:
                    await run(d.read_parameter, axis, p.number, True)
                except CommandError:
                    pass
        else:
            await run(lambda: d.command(cmd, axis, sender, sid, **args))

    # ---- live values and hold-to-run ------------------------------------------------------------------------------
    async def live(self, ws: WebSocket) -> None:
        login = self._login_of(ws.cookies)
        if login is None or cross_site(ws.headers) is not None:
            await ws.close(code=4401 if login is None else 4403)
            return
        nc = str(ws.path_params["nc"])
        if nc not in self.cfg.ncs:
            await ws.close(code=4404)
            return
        await ws.accept()
        if login.ended:  # ended while the handshake ran
            await ws.close(code=4401)
            return
        login.sockets += 1
        login.websockets.add(ws)
        login.paged = True
        jogged: set[int] = set()
        pending: set[int] = set()
        sender = asyncio.create_task(self._push(ws, nc, login))
        try:
            while True:
                frame = await ws.receive()
                if frame["type"] == "websocket.disconnect":
                    raise WebSocketDisconnect(frame.get("code", 1000))
                if frame.get("text") is None:  # a binary frame: not the page's
                    continue
                msg = json.loads(frame["text"])
                if not isinstance(msg, dict):
                    continue
                kind = msg.get("type")
                if kind == "jog":
                    await self._jog(ws, nc, login, msg, jogged, pending)
                elif kind == "jogstop":
                    axis = msg.get("axis")
                    d = self.doors.get(nc)
                    if d is not None and isinstance(axis, int) and axis in jogged:
                        jogged.discard(axis)
                        asyncio.create_task(self.commands.run(d.end_jogs, login.number, {axis}))
        except (WebSocketDisconnect, ValueError, RuntimeError):
            pass
        finally:
            sender.cancel()
            login.sockets -= 1
            login.websockets.discard(ws)
            login.idle_since = time.monotonic()
            d = self.doors.get(nc)
            if d is not None and jogged:  # the page is gone: its jogs stop now, not at their timeout
                await self.commands.run(d.end_jogs, login.number, jogged)

    async def _jog(self, ws: WebSocket, nc: str, login: Login, msg: dict[str, Any], jogged: set[int],
                   pending: set[int]) -> None:
        axis, direction, velocity = msg.get("axis"), msg.get("direction"), msg.get("velocity", 0.0)
        if login.ended:  # its socket is being closed: nothing more for it
            return
        try:
            self._check_role(login, "Jog", "Jog")
            if not isinstance(axis, int) or isinstance(axis, bool) or direction not in (1, 3):
                raise _Refused(400, int(ErrorCodes.MC_COMMAND_NOT_PERMITTED), "jog: axis and direction 1 or 3")
            if not isinstance(velocity, (int, float)) or not math.isfinite(velocity) or velocity < 0:
                raise _Refused(400, int(ErrorCodes.NC_VELOCITY_NOT_ALLOWED), f"jog: velocity {velocity!r}")
            d = self.doors.get(nc)
            if d is None:
                raise _Refused(502, int(ErrorCodes.ADSERR_DEVICE_NOTREADY), f"NC {nc} is not connected")
        except _Refused as r:
            await ws.send_text(json.dumps({"type": "error", "axis": axis, "error": r.code, "text": r.text}))
            return
        if axis in pending:  # the jog's command is on its way: this heartbeat adds nothing
            return
        pending.add(axis)
        jogged.add(axis)
        sender = f"{self.cfg.door_id}.{login.user}"

        async def start() -> None:
            try:
                await self.commands.run(d.jog, axis, sender, login.number, int(direction), float(velocity),
                                        self.cfg.hold_timeout)
            except CommandError as exc:
                jogged.discard(axis)
                try:
                    await ws.send_text(json.dumps({"type": "error", "axis": axis, "error": exc.code,
                                                   "text": exc.message}))
                except Exception:
                    pass
            finally:
                pending.discard(axis)
        asyncio.create_task(start())

    async def _push(self, ws: WebSocket, nc: str, login: Login) -> None:
        """The page's live values: the newest frame every frame period (when it changed)."""
        period = self.cfg.frame_ms / 1000.0
        last = -1
        names: dict[int, str] = {}
        try:
            while not login.ended:
                d = self.doors.get(nc)
                img = d.image if d is not None else None
                alive = img is not None and time.monotonic() - img.received < max(1.0, 5 * period)
                if d is not None and img is not None and (img.cycle != last or not alive):
                    if set(img.records) - set(names):
                        names = await asyncio.to_thread(d.axis_names)
                    last = img.cycle
                    axes = [{"AxisId": a, "Name": names.get(a, f"Axis{a}"), **axis_values(rec)}
                            for a, rec in sorted(img.records.items())]
                    await ws.send_text(json.dumps({"type": "frame", "cycle": img.cycle, "alive": alive,
                                                   "t": time.time(), "axes": axes}))
                elif d is None:
                    await ws.send_text(json.dumps({"type": "frame", "cycle": 0, "alive": False, "axes": []}))
                await asyncio.sleep(period)
        except asyncio.CancelledError:
            raise
        except Exception:  # the socket closed under us
            return


async def _close_quietly(ws: WebSocket, code: int) -> None:
    try:
        await ws.close(code=code)
    except Exception:  # closed already
        pass


def _check_args(cmd: str, args: Any) -> dict[str, Any]:
    """The JSON arguments of ``cmd`` checked before anything is sent: known names, required ones present,
    numbers finite (a bool for Enable).

    Raises:
        _Refused: 400 with 0x706 (missing, unknown, wrong type) or the NC's code for a bad velocity (0x4221).
    """
    if not isinstance(args, dict):
        raise _Refused(400, _INVALID, f"{cmd}: arguments must be a JSON object")
    spec = COMMANDS[cmd][1]
    unknown = set(args) - set(spec)
    if unknown:
        raise _Refused(400, _INVALID, f"{cmd}: unknown argument(s) {sorted(unknown)}")
    missing = [a for a, req in spec.items() if req and a not in args]
    if missing:
        raise _Refused(400, _INVALID, f"{cmd}: missing argument(s) {missing}")
    out: dict[str, Any] = {}
    for k, v in args.items():
        if k == "Enable":
            if not isinstance(v, bool):
                raise _Refused(400, _INVALID, f"{cmd}: Enable must be true or false")
        elif k == "Name":
            if not isinstance(v, str):
                raise _Refused(400, _INVALID, f"{cmd}: Name must be a parameter name")
        elif k == "Value" and isinstance(v, bool):
            pass
        else:
            if not isinstance(v, (int, float)) or isinstance(v, bool) or not math.isfinite(v):
                raise _Refused(400, _INVALID, f"{cmd}: {k} must be a finite number, got {v!r}")
            v = float(v)
            if k == "Velocity" and v <= 0:
                raise _Refused(400, int(ErrorCodes.NC_VELOCITY_NOT_ALLOWED), f"{cmd}: Velocity {v} must be > 0")
        out[k] = v
    return out


# ---- HTML ---------------------------------------------------------------------------------------------------------
def _page(title: str, body: str, login: Login | None) -> str:
    who = ""
    if login is not None:
        who = (f'<form class="who" method="post" action="/logout"><span id="who">{html.escape(login.user)} '
               f'({login.role})</span> <button id="logout" type="submit">Log out</button></form>')
    return (f'<!doctype html><html lang="en"><head><meta charset="utf-8"><title>{html.escape(title)}</title>'
            '<meta name="viewport" content="width=device-width, initial-scale=1">'
            f'<link rel="stylesheet" href="/static/app.css"></head><body>{who}{body}</body></html>')


def _login_html(message: str) -> str:
    msg = f'<p id="login-error" class="err">{html.escape(message)}</p>' if message else ""
    return _page("nc-web login", (
        '<h1>zenoh-nc</h1><form id="login" method="post" action="/login">'
        '<label>User <input id="user" name="user" autocomplete="username" required></label> '
        '<label>Password <input id="password" name="password" type="password" autocomplete="current-password">'
        f'</label> <button id="login-submit" type="submit">Log in</button></form>{msg}'), None)


def _nc_body(nc: str, op: bool, eng: bool) -> str:
    """The NC page's skeleton; the command controls exist only for a role that may use them."""
    ops = ""
    if op:
        ops = (
            '<section id="dialog"><h2>Online: <span id="dlg-axis">-</span></h2>'
            '<div class="row"><label>Override % <input id="override" type="number" value="100" min="0" max="100">'
            '</label> <button id="enable">Enable</button> <button id="disable">Disable</button> '
            '<button id="reset">Reset</button> <button id="stop" class="stop">Stop</button> '
            '<button id="halt">Halt</button></div>'
            '<div class="row"><label>Jog velocity <input id="jogvelo" type="number" value="0" min="0"></label> '
            '<button id="jog-minus" class="jog">&minus; Jog</button> '
            '<button id="jog-plus" class="jog">Jog +</button> <span class="hint">hold to run</span></div>'
            '<div class="row"><label>Target <input id="target" type="number" value="0"></label> '
            '<label>Velocity <input id="velo" type="number" value="100" min="0"></label> '
            '<button id="moveabs">Move to</button> <button id="moverel">Move by</button> '
            '<button id="home">Home</button></div>')
        if eng:
            ops += ('<div class="row"><label>Set position <input id="setpos" type="number" value="0"></label> '
                    '<button id="setpos-btn">Set</button></div>')
        ops += '<p id="cmd-result"></p></section>'
    return (f'<h1>NC <span id="nc">{html.escape(nc)}</span> <span id="alive" class="dead">no data</span></h1>'
            '<nav><a href="#axes">Axes</a> <a href="#params">Parameters</a> <a href="#scope">Scope</a></nav>'
            '<section id="axes"><table id="axis-table"><thead><tr><th>Axis</th><th>Name</th><th>ActPos</th>'
            '<th>SetPos</th><th>ActVelo</th><th>PosDiff</th><th>State</th><th>Error</th></tr></thead>'
            '<tbody></tbody></table></section>' + ops +
            '<section id="params"><h2>Parameters <span id="param-axis"></span></h2>'
            '<button id="param-read">Read</button> <button id="param-refresh">Refresh</button>'
            '<table id="param-table"><thead><tr><th>#</th><th>Name</th><th>Value</th><th>Unit</th>'
            + ('<th>Write</th>' if eng else '') + '</tr></thead><tbody></tbody></table></section>'
            '<section id="scope"><h2>Scope</h2><div class="row" id="scope-ctl">'
            '<span id="scope-axes"></span> <label><input type="checkbox" class="sig" value="SetPos" checked>SetPos'
            '</label><label><input type="checkbox" class="sig" value="ActPos" checked>ActPos</label>'
            '<label><input type="checkbox" class="sig" value="SetVelo">SetVelo</label>'
            '<label><input type="checkbox" class="sig" value="PosDiff">PosDiff</label> '
            '<button id="scope-pause">Pause</button> <button id="zoom-in">Zoom +</button> '
            '<button id="zoom-out">Zoom &minus;</button> <span id="scope-window"></span> '
            '<button id="export-csv">CSV</button> <button id="export-png">PNG</button></div>'
            '<canvas id="scope-canvas" width="900" height="300"></canvas></section>')


def new_secret() -> bytes:
    """A fresh cookie key (logins end when nc-web restarts)."""
    return os.urandom(32)
