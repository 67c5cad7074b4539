"""OpcuaDoor: the asyncua server of nc-opcua (address space, live values, methods, users and roles).

Address space (namespace ``urn:zenoh-nc:nc-opcua``; node ids are strings, stable across restarts)::

    Objects/NCs/<nc>                      ns;s=<nc>            Alive (Boolean), Cycle (UInt64)
      Axes/<Name or Axis<id>>             ns;s=<nc>.<id>       one object per axis, CncAxisType-like:
        ActPos, CmdPos, ActSpeed, CmdSpeed, RemDist            (Double, axis units)      s=<nc>.<id>.<name>
        ActStatus (String, the PLCopen state), IsReferenced (Boolean, Homed), Enabled (Boolean,
        ControlLoopClosed), ErrorCode (UInt32, the NC's ErrorID), ErrorText (String: its name and text)
        NcToPlc/<field>                   every NCTOPLC_AXIS_REF field, TwinCAT names   s=<nc>.<id>.NcToPlc.<field>
        Parameters/<name>                 every MC_AxisPara parameter (nc_schema.PARAMETERS), its unit in
                                          EngineeringUnits; read from the NC when a client reads it
                                          (then cached), refreshed after WriteParameter or by
                                          RefreshParameters, never polled      s=<nc>.<id>.P.<name>
        methods: Power, Reset, Halt, Stop, MoveAbsolute, MoveRelative, MoveVelocity, JogStart, JogStop,
                 Home, WriteParameter, RefreshParameters

The CNC names mimic OPC 40502 (CNC Systems) ``CncAxisType`` (ActPos, CmdPos, ActSpeed, CmdSpeed, RemDist,
ActStatus, IsReferenced), without its NodeSet (not importable here): plain BaseObjectType objects and
BaseDataVariableType variables of the same names.

Values are written every sampling interval (``sampling_ms``, default 100 ms; the frames are taken once per that
period, ``nc/<nc>/frame/<P>ms``) only when they changed: clients see them through subscriptions. Without a fresh
frame (1 s, or 5 sampling intervals) the NC's ``Alive`` is False and its axes' values keep their last value with
the status UncertainLastUsableValue until frames come back.

Methods and roles: a method needs the command class of the NC command it sends (``nc_schema.COMMAND_CLASS``:
``op`` for power and motion, ``eng`` for WriteParameter, ``read`` for RefreshParameters); the OPC UA user's
role (users file) capped by the door's own ``role`` (a door never grants more than its role) must allow it,
else the call returns **BadUserAccessDenied** and nothing is sent. Every method has two output arguments,
``ErrorID`` (UInt32) and ``ErrorText`` (String): 0 and "" on success. Decisions: an NC refusal returns a Bad
status *with* those outputs (the NC's ErrorID, e.g. 0x4221, and its text): BadInvalidState for the NC's own
error codes, BadCommunicationError for 0x707 (NC unreachable), BadTimeout for 0x719. Arguments are checked
against the declared input types before anything is sent (:func:`_check_args`; asyncua does not):
BadArgumentsMissing / BadTooManyArguments / BadTypeMismatch with ErrorID 0x706, bad values BadInvalidArgument
with the NC's code where it has one (0x4221 a velocity, 0x4B05 a Direction), else 0x706 (non-finite) or 0x4B06
(Override, Timeout, parameter name); a call on another object than the method's axis BadMethodInvalid;
anything unforeseen BadInternalError with the text (never BadUnexpectedError).

Client ids: the door connects as ``door_id``; what it commands or claims for user U is sent as
``<door_id>.<U>`` (nc_link: ``NcLink.request(sender=...)``, ``declare_holder``), so the NC's claims map,
commander records and logs name the user. Anonymous users (``allow_anonymous``) are observers.

Sessions: a session's closing (CloseSession, or asyncua's session timeout after its connection was lost,
``session_timeout``) is its vanishing: :meth:`nc_link.door.NcDoor.session_gone` (0x8F01 on what it
powered and on its motions, release, its jogs stop). A jog also stops at its own timeout unless renewed.
Sessions are numbered by the door (itertools.count, never reused; ``id()`` would be once a session is gone).

Client application certificates: checked by asyncua's rules (time, ApplicationUri, key usages); with a trust
directory (``trust``) only the certificates in it are accepted (:class:`_ClientCertificates`).

May import: ``asyncua``, ``cryptography``, ``nc_link``, ``nc_schema`` and this package.
"""
from __future__ import annotations

import asyncio
import contextvars
import itertools
import logging
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Awaitable, Callable, Sequence, cast

import numpy as np
from asyncua import Server, ua
from asyncua.common.utils import ServiceError
from asyncua.crypto.validator import CertificateValidator, CertificateValidatorOptions
from cryptography import x509
from cryptography.hazmat.primitives import hashes
from asyncua.common.callback import CallbackType
from asyncua.crypto.permission_rules import User as UaUser
from asyncua.crypto.permission_rules import UserRole
from asyncua.server.user_managers import UserManager

from nc_link import CommandError, open_session
from nc_schema import (
    COMMAND_CLASS, NCTOPLC_DTYPE, PARAMETERS, ROLE_CLASSES, ErrorCodes, StateDWord, error_name, error_text,
    motion_state,
)

from nc_link.door import OVERRIDE_100, CommandPool, NcDoor
from nc_link.users import LoginsBusy, PasswordGate, User, Verifier, check_door_config, role_min

log = logging.getLogger(__name__)

__all__ = ["OpcuaDoor", "DoorConfig", "NAMESPACE"]

NAMESPACE = "urn:zenoh-nc:nc-opcua"
_SESSION: contextvars.ContextVar[Any] = contextvars.ContextVar("nc_opcua_session", default=None)
_NUMBER = "_nc_opcua_number"  # the attribute of an external asyncua session holding its number (the bridge's key)
_HOMED = int(StateDWord.Homed)
_CLOSED = int(StateDWord.ControlLoopClosed)
#: the CNC variables: name -> (OPC UA type, NCTOPLC source field or None for a derived one)
CNC_VARS: dict[str, tuple[ua.VariantType, str | None]] = {
    "ActPos": (ua.VariantType.Double, "ActPos"), "CmdPos": (ua.VariantType.Double, "SetPos"),
    "ActSpeed": (ua.VariantType.Double, "ActVelo"), "CmdSpeed": (ua.VariantType.Double, "SetVelo"),
    "RemDist": (ua.VariantType.Double, None), "ActStatus": (ua.VariantType.String, None),
    "IsReferenced": (ua.VariantType.Boolean, None), "Enabled": (ua.VariantType.Boolean, None),
    "ErrorCode": (ua.VariantType.UInt32, "ErrorCode"), "ErrorText": (ua.VariantType.String, None),
}
_KIND_TYPES = {("u", 1): ua.VariantType.Byte, ("u", 2): ua.VariantType.UInt16, ("u", 4): ua.VariantType.UInt32,
               ("i", 4): ua.VariantType.Int32, ("f", 8): ua.VariantType.Double}
NCTOPLC_FIELDS: dict[str, ua.VariantType] = {}
for _n in NCTOPLC_DTYPE.names or ():
    if _n.startswith("_"):
        continue
    _dt = NCTOPLC_DTYPE.fields[_n][0]  # type: ignore[index]
    _base = _dt.base if _dt.subdtype else _dt
    NCTOPLC_FIELDS[_n] = _KIND_TYPES[(_base.kind, _base.itemsize)]


@dataclass
class DoorConfig:
    """What an :class:`OpcuaDoor` serves (the CLI's options).

    Attributes:
        connect: the zenoh endpoint of the router (or an NC). door_id: the door's client id.
        ncs: the NC names to serve (empty: every NC found on the router, looked for every 2 s).
        url: the OPC UA endpoint, e.g. ``opc.tcp://127.0.0.1:4840/zenoh-nc``.
        users: the users (nc_link.users). allow_anonymous: anonymous sessions, read-only.
        role: the door's own role (caps every user's).
        sampling_ms: the value update period [ms] (one of nc_schema.FRAME_PERIODS_MS).
        cert, key: the application instance certificate (DER) and key (PEM); None: no security.
        security: offered policies among ``none``, ``sign``, ``encrypt`` (Basic256Sha256).
        app_uri: the ApplicationUri (must be the certificate's subjectAltName URI).
        tls_dir: zenoh mutual TLS directory (certificate ``<tls_dir>/<door_id>.pem``) or None.
        session_timeout: the longest session timeout granted [s]: how long a session whose connection was lost
            lives on (then it vanishes: :meth:`NcDoor.session_gone`).
        max_jog_timeout: the largest JogStart Timeout accepted [s].
        trust: a directory of trusted client application certificates (DER or PEM, each trusted as it is,
            read at every new session); None: any client certificate (its time range, ApplicationUri and key
            usages are checked either way when a client presents one).
    """

    connect: str
    door_id: str = "opcua"
    ncs: Sequence[str] = ()
    url: str = "opc.tcp://127.0.0.1:4840/zenoh-nc"
    users: dict[str, User] | None = None
    allow_anonymous: bool = False
    role: str = "engineer"
    sampling_ms: int = 100
    cert: str | None = None
    key: str | None = None
    security: Sequence[str] = ("none",)
    app_uri: str = "urn:zenoh-nc:nc-opcua"
    tls_dir: str | None = None
    session_timeout: float = 10.0
    max_jog_timeout: float = 30.0
    trust: str | None = None


class _ClientCertificates:
    """The check of a client's application certificate at CreateSession: asyncua's (time range, ApplicationUri in
    subjectAltName, key usages, EKU clientAuth), then, with a trust directory, its SHA-256 fingerprint among the
    certificates there (re-read each time: a certificate added is trusted from the next session on).

    Raises (to asyncua, which refuses the session): ServiceError BadCertificate*; BadCertificateUntrusted.
    """

    def __init__(self, trust: str | None) -> None:
        self.trust = Path(trust) if trust else None
        self.base = CertificateValidator(CertificateValidatorOptions.EXT_VALIDATION | CertificateValidatorOptions.PEER_CLIENT)

    def trusted(self) -> set[bytes]:
        out: set[bytes] = set()
        assert self.trust is not None
        for f in sorted(self.trust.iterdir()):
            if f.suffix.lower() not in (".der", ".pem", ".crt"):
                continue
            try:
                data = f.read_bytes()
                c = x509.load_pem_x509_certificate(data) if data.startswith(b"-----") else x509.load_der_x509_certificate(data)
            except (OSError, ValueError) as exc:
                log.warning("trust directory: %s is not a certificate (%s)", f, exc)
                continue
            out.add(c.fingerprint(hashes.SHA256()))
        return out

    async def __call__(self, cert: x509.Certificate, app: ua.ApplicationDescription) -> None:
        await self.base(cert, app)
        if self.trust is not None and cert.fingerprint(hashes.SHA256()) not in self.trusted():
            log.warning("client certificate %s (%s) is not in the trust directory %s: session refused",
                        cert.subject.rfc4514_string(), app.ApplicationUri, self.trust)
            raise ServiceError(ua.StatusCodes.BadCertificateUntrusted)


class _Users(UserManager):
    """asyncua's user manager: the users file's names and passwords (:class:`nc_link.users.Verifier`).

    asyncua calls ``get_user`` synchronously inside ActivateSession (``InternalSession.activate_session`` is
    not a coroutine). The scrypt of a check (~0.1-1 s: a first login of a user, a wrong password, an unknown
    name, all the same cost) must not stall the event loop, so :func:`_install_async_login` runs
    :meth:`Verifier.precheck` on a worker thread before asyncua handles an ActivateSession with a user name
    token; ``get_user`` then finds the result remembered (an HMAC, no scrypt).
    """

    def __init__(self, users: dict[str, User], anonymous: bool) -> None:
        self.users, self.anonymous = users, anonymous
        self.verifier = Verifier(users)
        self.gate = PasswordGate(self.verifier)

    def get_user(self, iserver: Any, username: str | None = None, password: str | None = None,
                 certificate: Any = None) -> UaUser | None:
        if not username:
            return UaUser(role=UserRole.User, name=None) if self.anonymous else None
        if not self.verifier.check(username, password or ""):
            log.warning("OPC UA login of %r refused", username)
            return None
        return UaUser(role=UserRole.User, name=username)


def _install_async_login() -> None:
    """Run the password check of an ActivateSession on a worker thread (see :class:`_Users`): asyncua's
    ``UaProcessor._process_message`` wrapped once per process; servers with another user manager are
    untouched. The token is decoded from a copy of the request (asyncua decodes the original itself)."""
    from asyncua.server import uaprocessor
    from asyncua.ua.ua_binary import struct_from_binary

    cls: Any = uaprocessor.UaProcessor
    if getattr(cls, "_znc_async_login", False):
        return
    orig = cls._process_message
    activate = ua.NodeId(cast(Any, ua.ObjectIds.ActivateSessionRequest_Encoding_DefaultBinary))

    async def _process_message(self: Any, typeid: Any, requesthdr: Any, seqhdr: Any, body: Any) -> Any:
        um = self.iserver.user_manager
        if typeid == activate and isinstance(um, _Users) and self.session is not None:
            busy = False
            try:
                params = struct_from_binary(ua.ActivateSessionParameters, body.copy())
                token = params.UserIdentityToken
                if isinstance(token, ua.UserNameIdentityToken):
                    name, password = self.iserver.decrypt_user_token(self.session, token)
                    await um.gate.precheck(name or "", password or "")
            except LoginsBusy:
                busy = True
            except Exception:  # asyncua's own handling reports a bad request
                pass
            if busy:  # refused before any scrypt (asyncua answers a ServiceFault with this status)
                log.warning("OPC UA login refused: too many logins at once")
                raise ua.UaStatusCodeError(ua.StatusCodes.BadTooManyOperations)
        return await orig(self, typeid, requesthdr, seqhdr, body)
    cls._process_message = _process_message
    cls._znc_async_login = True


def _arg(name: str, vt: ua.VariantType, doc: str = "") -> ua.Argument:
    a = ua.Argument()
    a.Name = name
    a.DataType = ua.NodeId(cast(Any, vt.value))
    a.ValueRank = -1
    a.Description = ua.LocalizedText(doc)
    return a


_D, _I, _B, _S = ua.VariantType.Double, ua.VariantType.Int32, ua.VariantType.Boolean, ua.VariantType.String
_OUT = [_arg("ErrorID", ua.VariantType.UInt32, "the NC's ErrorID, 0: accepted"), _arg("ErrorText", _S)]
#: method -> (NC command whose class it needs, input arguments, description)
METHODS: dict[str, tuple[str, list[ua.Argument], str]] = {
    "Power": ("Claim", [_arg("Enable", _B), _arg("Override", _D, "[%] 0..100")],
              "MC_Power: claim for this user and supply Enable + feed enables and the override; FALSE: disable, release"),
    "Reset": ("Reset", [], "MC_Reset"),
    "Halt": ("Halt", [], "MC_Halt"),
    "Stop": ("Stop", [], "MC_Stop: locks the axis until Reset"),
    "MoveAbsolute": ("MoveAbsolute", [_arg("Position", _D, "[u]"), _arg("Velocity", _D, "[u/s]")], "MC_MoveAbsolute"),
    "MoveRelative": ("MoveRelative", [_arg("Distance", _D, "[u]"), _arg("Velocity", _D, "[u/s]")], "MC_MoveRelative"),
    "MoveVelocity": ("MoveVelocity", [_arg("Velocity", _D, "[u/s] > 0"),
                                      _arg("Direction", _I, "1 positive, 3 negative")], "MC_MoveVelocity"),
    "JogStart": ("Jog", [_arg("Direction", _I, "1 positive, 3 negative"),
                         _arg("Velocity", _D, "[u/s]; 0: AxisVeloManSlow"),
                         _arg("Timeout", _D, "[s] the jog stops then unless JogStart is called again")],
                 "hold-to-run jog: call again within Timeout to keep it going"),
    "JogStop": ("Halt", [], "end a jog (Halt)"),
    "Home": ("Home", [_arg("Position", _D, "reference position; NaN: AxisCalibrationValue")], "MC_Home"),
    "WriteParameter": ("WriteParameter", [_arg("Name", _S, "MC_AxisPara name, e.g. AxisVeloMax"), _arg("Value", _D)],
                       "MC_WriteParameter (engineer)"),
    "RefreshParameters": ("ReadParameter", [], "read every parameter of the axis from the NC now"),
}


def _bad_for(code: int) -> int:
    if code == ErrorCodes.ADSERR_DEVICE_NOTREADY:
        return ua.StatusCodes.BadCommunicationError
    if code == ErrorCodes.ADSERR_DEVICE_TIMEOUT:
        return ua.StatusCodes.BadTimeout
    return ua.StatusCodes.BadInvalidState


def _result(status: int, code: int = 0, text: str = "") -> ua.CallMethodResult:
    r = ua.CallMethodResult()
    r.StatusCode = _status(status)
    r.OutputArguments = [ua.Variant(int(code), ua.VariantType.UInt32), ua.Variant(text, ua.VariantType.String)]
    return r


class _Refused(Exception):
    def __init__(self, status: int, code: int, text: str) -> None:
        super().__init__(text)
        self.status, self.code, self.text = status, code, text


class OpcuaDoor:
    """nc-opcua (see the module docstring): ``await start()``, ``await serve()`` / ``await stop()``."""

    def __init__(self, cfg: DoorConfig) -> None:
        check_door_config(cfg.door_id, cfg.users or {}, cfg.role)
        self.cfg = cfg
        _install_async_login()
        self._users = _Users(cfg.users or {}, cfg.allow_anonymous)
        self.server = Server(user_manager=self._users)
        self.bridges: dict[str, NcDoor] = {}
        self.commands = CommandPool()  # NC commands: never behind password checks or parameter reads
        self.idx = 0
        self._ncs_node: Any = None
        self._axis_nodes: dict[tuple[str, int], Any] = {}
        self._last: dict[ua.NodeId, Any] = {}
        self._param_nodes: dict[ua.NodeId, tuple[str, int, int, ua.VariantType]] = {}
        self._sessions: dict[int, Any] = {}  # session number -> asyncua session
        self._numbers = itertools.count(1)
        self._tasks: list[asyncio.Task[Any]] = []
        self._zsession: Any = None
        self._stopping = False

    # ---- lifecycle --------------------------------------------------------------------------------------------
    async def start(self) -> None:
        """Set the server up, start listening, connect to the NCs (named, or found on the router).

        Raises:
            ValueError: a security policy without a certificate, or an unknown policy name.
            OSError: the OPC UA port cannot be bound.
        """
        cfg, srv = self.cfg, self.server
        await srv.init()
        srv.set_endpoint(cfg.url)
        srv.set_server_name("zenoh-nc nc-opcua")
        await srv.set_application_uri(cfg.app_uri)
        policies = []
        for p in cfg.security:
            if p == "none":
                policies.append(ua.SecurityPolicyType.NoSecurity)
            elif p in ("sign", "encrypt"):
                if not (cfg.cert and cfg.key):
                    raise ValueError(f"security policy {p!r} (Basic256Sha256) needs --cert and --key")
                policies.append(ua.SecurityPolicyType.Basic256Sha256_Sign if p == "sign"
                                else ua.SecurityPolicyType.Basic256Sha256_SignAndEncrypt)
            else:
                raise ValueError(f"unknown security policy {p!r}: none, sign or encrypt")
        srv.set_security_policy(policies)
        if cfg.cert and cfg.key:
            await srv.load_certificate(cfg.cert)
            await srv.load_private_key(cfg.key)
        tokens: list[type] = [ua.UserNameIdentityToken]
        if cfg.allow_anonymous:
            tokens.append(ua.AnonymousIdentityToken)
        srv.set_identity_tokens(tokens)
        srv.iserver.min_session_timeout_ms = 1000
        srv.iserver.max_session_timeout_ms = cfg.session_timeout * 1000
        srv.set_certificate_validator(cast(Any, _ClientCertificates(cfg.trust)))
        self._hook_sessions()
        self.idx = await srv.register_namespace(NAMESPACE)
        self._ncs_node = await srv.nodes.objects.add_folder(_nid("NCs", self.idx), ua.QualifiedName("NCs", self.idx))
        srv.subscribe_server_callback(CallbackType.PreRead, self._pre_read)
        await srv.start()
        self._tasks.append(asyncio.create_task(self._update_loop()))
        self._tasks.append(asyncio.create_task(self._discover_loop()))

    async def serve(self) -> None:
        """Run until cancelled."""
        await asyncio.Event().wait()

    async def stop(self) -> None:
        """Stop the tasks, release every claim (enables off), close the links and the server."""
        import time as _time
        t0 = _time.monotonic()
        self._stopping = True
        for t in self._tasks:
            t.cancel()
        await asyncio.gather(*(asyncio.to_thread(b.close) for b in list(self.bridges.values())))
        t1 = _time.monotonic()
        if self._zsession is not None:
            await asyncio.to_thread(self._zsession.close)
        await self.server.stop()
        self.commands.close()
        self._users.gate.close()
        log.info("stopped: NC links closed in %.2f s, server in %.2f s", t1 - t0, _time.monotonic() - t1)

    # ---- sessions -----------------------------------------------------------------------------------------------
    def _hook_sessions(self) -> None:
        """asyncua gives a method callback no session: each external session's ``call`` sets :data:`_SESSION`
        (a context variable of the task running the call) and its ``close_session`` ends what it commanded."""
        iserver = self.server.iserver
        create = iserver.create_session

        def create_session(name: str, user: UaUser = UaUser(role=UserRole.Anonymous), external: bool = False) -> Any:
            s = create(name, user=user, external=external)
            if external:
                call0, close0 = s.call, s.close_session

                async def call(params: Any) -> Any:
                    tok = _SESSION.set(s)
                    try:
                        return await call0(params)
                    finally:
                        _SESSION.reset(tok)

                async def close_session(delete_subs: bool = True) -> None:
                    try:
                        await close0(delete_subs)
                    finally:  # its claims and motions end even if asyncua's closing failed
                        if self._sessions.pop(number, None) is not None and not self._stopping:
                            log.info("OPC UA session %s of %s ended: its claims and motions end", s.name, s.user.name)
                            for b in list(self.bridges.values()):
                                await self.commands.run(b.session_gone, number)

                number = next(self._numbers)  # never reused (an id() is, once its object is gone)
                setattr(s, "call", call)
                setattr(s, "close_session", close_session)
                setattr(s, _NUMBER, number)
                self._sessions[number] = s
            return s

        setattr(iserver, "create_session", create_session)

    def _role_of(self, session: Any) -> tuple[str, str | None]:
        """(effective role, user name) of ``session``: the users file's role capped by the door's."""
        name = getattr(getattr(session, "user", None), "name", None)
        users = self.cfg.users or {}
        role = users[name].role if name in users else "observer"
        return role_min(role, self.cfg.role), name

    # ---- NCs ----------------------------------------------------------------------------------------------------
    async def _discover_loop(self) -> None:
        cfg = self.cfg
        while True:
            try:
                # named NCs: each until its link opened (an NC not there yet is tried again); else every NC seen
                names = set(cfg.ncs) if cfg.ncs else await asyncio.to_thread(self._alive_ncs)
                for nc in names - set(self.bridges):
                    await self._add_nc(nc)
            except Exception as exc:
                log.warning("looking for NCs at %s failed: %s", cfg.connect, exc)
            await asyncio.sleep(2.0)

    def _alive_ncs(self) -> set[str]:
        if self._zsession is None:
            self._zsession = open_session(self.cfg.connect, self.cfg.door_id, 1000, self.cfg.tls_dir)
        out = set()
        for r in self._zsession.liveliness().get("nc/*/alive", timeout=1.0):
            if r.ok is not None:
                parts = str(r.ok.key_expr).split("/")
                if len(parts) == 3:
                    out.add(parts[1])
        return out

    async def _add_nc(self, nc: str) -> None:
        period = max([p for p in (2, 5, 10, 20, 50, 100) if p <= self.cfg.sampling_ms] or [2])
        b = NcDoor(nc, self.cfg.connect, self.cfg.door_id, period, self.cfg.tls_dir)
        try:
            await asyncio.to_thread(b.start)
        except ConnectionError as exc:
            log.warning("%s", exc)
            return
        self.bridges[nc] = b
        idx = self.idx
        node = await self._ncs_node.add_object(_nid(nc, idx), ua.QualifiedName(nc, idx))
        await node.add_variable(_nid(f"{nc}.Alive", idx), ua.QualifiedName("Alive", idx), False, _B)
        await node.add_variable(_nid(f"{nc}.Cycle", idx), ua.QualifiedName("Cycle", idx), 0, ua.VariantType.UInt64)
        await node.add_folder(_nid(f"{nc}.Axes", idx), ua.QualifiedName("Axes", idx))
        log.info("serving NC %s", nc)

    async def _add_axis(self, nc: str, axis: int, name: str) -> None:
        idx = self.idx
        axes = self.server.get_node(_nid(f"{nc}.Axes", idx))
        base = f"{nc}.{axis}"
        obj = await axes.add_object(_nid(base, idx), ua.QualifiedName(name or f"Axis{axis}", idx))
        await obj.add_property(_nid(f"{base}.AxisId", idx), ua.QualifiedName("AxisId", idx), axis,
                               ua.VariantType.UInt32)
        for var, (vt, _) in CNC_VARS.items():
            await obj.add_variable(_nid(f"{base}.{var}", idx), ua.QualifiedName(var, idx), _zero(vt), vt)
        f = await obj.add_folder(_nid(f"{base}.NcToPlc", idx), ua.QualifiedName("NcToPlc", idx))
        for field, vt in NCTOPLC_FIELDS.items():
            sub = NCTOPLC_DTYPE.fields[field][0]  # type: ignore[index]
            init: Any = [0] * int(np.prod(sub.shape)) if sub.subdtype else _zero(vt)
            await f.add_variable(_nid(f"{base}.NcToPlc.{field}", idx), ua.QualifiedName(field, idx),
                                 ua.Variant(init, vt))
        pf = await obj.add_folder(_nid(f"{base}.Parameters", idx), ua.QualifiedName("Parameters", idx))
        for e in PARAMETERS:
            nid = _nid(f"{base}.P.{e.name}", idx)
            vt = _param_type(e.type)
            v = await pf.add_variable(nid, ua.QualifiedName(e.name, idx), _zero(vt), vt)
            await self.server.write_attribute_value(nid, ua.DataValue(ua.Variant(_zero(vt), vt), StatusCode=_status(
                ua.StatusCodes.BadWaitingForInitialData)))  # until a client reads it (on demand)
            await v.write_attribute(ua.AttributeIds.Description, ua.DataValue(ua.Variant(
                ua.LocalizedText(f"[{e.unit or '-'}] #{e.number}: {e.doc}"), ua.VariantType.LocalizedText)))
            if e.unit:
                eu = ua.EUInformation()
                eu.DisplayName = ua.LocalizedText(e.unit)
                eu.Description = ua.LocalizedText(e.unit)
                await v.add_property(_nid(f"{base}.P.{e.name}.EU", idx), ua.QualifiedName("EngineeringUnits", 0), eu)
            self._param_nodes[nid] = (nc, axis, e.number, vt)
        for mname, (_, inputs, doc) in METHODS.items():
            m = await obj.add_method(_nid(f"{base}.{mname}", idx), ua.QualifiedName(mname, idx),
                                     self._method(mname, nc, axis), inputs, _OUT)
            await m.write_attribute(ua.AttributeIds.Description, ua.DataValue(ua.Variant(
                ua.LocalizedText(doc), ua.VariantType.LocalizedText)))
        self._axis_nodes[(nc, axis)] = obj

    # ---- live values --------------------------------------------------------------------------------------------
    async def _update_loop(self) -> None:
        period = self.cfg.sampling_ms / 1000.0
        seen: dict[str, tuple[int, bool]] = {}
        while True:
            await asyncio.sleep(period)
            for nc, b in list(self.bridges.items()):
                try:
                    await self._update_nc(nc, b, seen)
                except Exception:
                    log.exception("NC %s: value update failed", nc)

    async def _update_nc(self, nc: str, b: NcDoor, seen: dict[str, tuple[int, bool]]) -> None:
        import time as _time
        img = b.image
        alive = img is not None and _time.monotonic() - img.received < max(1.0, 5 * self.cfg.sampling_ms / 1000)
        await self._set(_nid(f"{nc}.Alive", self.idx), alive, _B)
        if img is None or seen.get(nc) == (img.cycle, alive):
            return
        seen[nc] = (img.cycle, alive)
        # no fresh frame: the last values stay, marked UncertainLastUsableValue until frames come back
        st = ua.StatusCodes.Good if alive else ua.StatusCodes.UncertainLastUsableValue
        await self._set(_nid(f"{nc}.Cycle", self.idx), img.cycle, ua.VariantType.UInt64, st)
        new = [a for a in img.records if (nc, a) not in self._axis_nodes]
        if new:
            names = await asyncio.to_thread(b.axis_names)
            for a in sorted(new):
                self._axis_nodes[(nc, a)] = None  # (once: a failure is logged, not retried every period)
                await self._add_axis(nc, a, names.get(a, ""))
        for a, data in img.records.items():
            if self._axis_nodes.get((nc, a)) is None:
                continue
            rec = np.frombuffer(data[:NCTOPLC_DTYPE.itemsize], dtype=NCTOPLC_DTYPE)[0]
            base = f"{nc}.{a}"
            for field, vt in NCTOPLC_FIELDS.items():
                v = rec[field]
                await self._set(_nid(f"{base}.NcToPlc.{field}", self.idx), v.tolist() if v.shape else v.item(), vt, st)
            sdw, err = int(rec["StateDWord"]), int(rec["ErrorCode"])
            cnc = {"ActPos": float(rec["ActPos"]), "CmdPos": float(rec["SetPos"]), "ActSpeed": float(rec["ActVelo"]),
                   "CmdSpeed": float(rec["SetVelo"]), "RemDist": float(rec["TargetPos"] - rec["SetPos"]),
                   "ActStatus": motion_state(sdw, int(rec["CoupleState"])).name.removeprefix("MC_AXISSTATE_"),
                   "IsReferenced": bool(sdw & _HOMED), "Enabled": bool(sdw & _CLOSED), "ErrorCode": err,
                   "ErrorText": _error_text(err)}
            for var, value in cnc.items():
                await self._set(_nid(f"{base}.{var}", self.idx), value, CNC_VARS[var][0], st)

    async def _set(self, nid: ua.NodeId, value: Any, vt: ua.VariantType, status: int = ua.StatusCodes.Good) -> None:
        if self._last.get(nid, _UNSET) == (value, status):
            return
        self._last[nid] = (value, status)
        await self.server.write_attribute_value(nid, ua.DataValue(ua.Variant(value, vt), StatusCode=_status(status)))

    # ---- parameters ---------------------------------------------------------------------------------------------
    async def _pre_read(self, event: Any, dispatcher: Any) -> None:
        """A client reads parameter nodes: read the ones not cached yet from the NC first (on demand)."""
        for rv in getattr(event.request_params, "NodesToRead", None) or []:
            ref = self._param_nodes.get(rv.NodeId)
            if ref is None or rv.AttributeId != ua.AttributeIds.Value:
                continue
            nc, axis, number, _ = ref
            b = self.bridges.get(nc)
            if b is None or (axis, number) in b.params:
                continue
            await self._read_param(b, rv.NodeId, axis, number, refresh=False)

    async def _read_param(self, b: NcDoor, nid: ua.NodeId, axis: int, number: int, refresh: bool) -> None:
        try:
            value = await asyncio.to_thread(b.read_parameter, axis, number, refresh)
        except CommandError as exc:
            value = exc
        await self._show_param(nid, value)

    async def _show_param(self, nid: ua.NodeId, value: Any) -> None:
        """The parameter node ``nid`` shows ``value`` (a CommandError: a Bad status)."""
        vt = self._param_nodes[nid][3]
        if isinstance(value, CommandError):
            await self.server.write_attribute_value(nid, ua.DataValue(StatusCode=_status(
                ua.StatusCodes.BadCommunicationError if value.code in (0x707, 0x719)
                else ua.StatusCodes.BadNotReadable)))
            return
        conv = {ua.VariantType.Boolean: bool, ua.VariantType.UInt32: int}.get(vt, float)
        try:
            v = ua.Variant(conv(value), vt)
        except (TypeError, ValueError):
            await self.server.write_attribute_value(nid, ua.DataValue(StatusCode=_status(ua.StatusCodes.BadNotReadable)))
            return
        await self.server.write_attribute_value(nid, ua.DataValue(v))

    # ---- methods ------------------------------------------------------------------------------------------------
    def _method(self, mname: str, nc: str, axis: int) -> Callable[..., Awaitable[ua.CallMethodResult]]:
        """The callback of method ``mname`` of axis ``axis`` of NC ``nc`` (bound here, not taken from the call's
        ObjectId: a call naming another object gets BadMethodInvalid). No input ends in BadUnexpectedError: an
        unforeseen failure is BadInternalError with its text."""
        own = _nid(f"{nc}.{axis}", self.idx)

        async def call(parent: ua.NodeId, *args: Any) -> ua.CallMethodResult:
            try:
                if parent != own:
                    raise _Refused(ua.StatusCodes.BadMethodInvalid, ErrorCodes.ADSERR_DEVICE_INVALIDDATA,
                                   f"{mname} of {nc}.{axis} called on another object ({parent})")
                await self._call(mname, nc, axis, [a.Value if isinstance(a, ua.Variant) else a for a in args])
            except _Refused as r:
                return _result(r.status, r.code, r.text)
            except CommandError as exc:
                return _result(_bad_for(exc.code), exc.code, exc.message)
            except Exception as exc:  # never BadUnexpectedError with a traceback to the client
                log.exception("%s of %s.%d failed", mname, nc, axis)
                return _result(ua.StatusCodes.BadInternalError, ErrorCodes.ADSERR_DEVICE_INVALIDDATA,
                               f"{mname}: internal error: {type(exc).__name__}: {exc}")
            return _result(ua.StatusCodes.Good)
        return call

    async def _call(self, mname: str, nc: str, axis: int, args: list[Any]) -> None:
        session = _SESSION.get()
        role, user = self._role_of(session)
        cmd, inputs, _ = METHODS[mname]
        cls = COMMAND_CLASS[cmd]
        if cls not in ROLE_CLASSES[role]:
            need = " or ".join(r for r, c in ROLE_CLASSES.items() if cls in c)
            raise _Refused(ua.StatusCodes.BadUserAccessDenied, ErrorCodes.ADSERR_DEVICE_ACCESSDENIED,
                           f"role: {user or 'anonymous'} is {role} here; {mname} needs {need}")
        args = _check_args(mname, inputs, args)  # before anything is sent
        b = self.bridges.get(nc)
        if b is None:
            raise _Refused(ua.StatusCodes.BadCommunicationError, ErrorCodes.ADSERR_DEVICE_NOTREADY,
                           f"NC {nc} is not served")
        sid = int(getattr(session, _NUMBER, 0))  # 0: no external session (not one a client can lose)
        sender = f"{self.cfg.door_id}.{user}"
        run = self.commands.run
        if mname == "Power":
            enable, override = args[0], args[1]
            if not 0.0 <= override <= 100.0:
                raise _Refused(ua.StatusCodes.BadInvalidArgument, ErrorCodes.MC_PARAMETER_NOT_CORRECT,
                               f"Override {override} % outside 0..100")
            await run(b.power, axis, sender, sid, enable, int(round(override / 100 * OVERRIDE_100)))
        elif mname in ("Reset", "Halt", "Stop"):
            await run(b.command, mname, axis, sender, sid)
        elif mname == "MoveAbsolute":
            await run(lambda: b.command("MoveAbsolute", axis, sender, sid, Position=args[0], Velocity=args[1]))
        elif mname == "MoveRelative":
            await run(lambda: b.command("MoveRelative", axis, sender, sid, Distance=args[0], Velocity=args[1]))
        elif mname == "MoveVelocity":
            await run(lambda: b.command("MoveVelocity", axis, sender, sid, Velocity=args[0], Direction=args[1]))
        elif mname == "JogStart":
            direction, velocity, timeout = args
            if not 0.0 < timeout <= self.cfg.max_jog_timeout:
                raise _Refused(ua.StatusCodes.BadInvalidArgument, ErrorCodes.MC_PARAMETER_NOT_CORRECT,
                               f"Timeout {timeout} s outside (0, {self.cfg.max_jog_timeout:g}]")
            await run(b.jog, axis, sender, sid, direction, velocity, timeout)
        elif mname == "JogStop":
            await run(b.jog_stop, axis, sender, sid)
        elif mname == "Home":
            pos = args[0]
            await run(lambda: b.command("Home", axis, sender, sid, **({} if math.isnan(pos) else {"Position": pos})))
        elif mname == "WriteParameter":
            p = PARAMETERS.by_name(args[0])
            if p is None:
                raise _Refused(ua.StatusCodes.BadInvalidArgument, ErrorCodes.MC_PARAMETER_NOT_CORRECT,
                               f"unknown parameter {args[0]!r}")
            value: Any = bool(args[1]) if p.is_bool else args[1]
            try:
                await run(lambda: b.command("WriteParameter", axis, sender, sid, ParameterNumber=p.number, Value=value))
            finally:  # refreshed after a write (also a refused one: the cache shows the NC's value)
                await self._read_param(b, _nid(f"{nc}.{axis}.P.{p.name}", self.idx), axis, p.number, True)
        elif mname == "RefreshParameters":  # at most every REFRESH_INTERVAL per axis; ends at an unreachable NC
            got = await asyncio.to_thread(b.read_parameters, axis, [e.number for e in PARAMETERS], True)
            for e in PARAMETERS:
                if e.number in got:
                    await self._show_param(_nid(f"{nc}.{axis}.P.{e.name}", self.idx), got[e.number])
            unreachable = [v for v in got.values() if isinstance(v, CommandError) and v.code in (0x707, 0x719)]
            if unreachable:
                raise unreachable[0]


#: method -> argument -> (the smallest value accepted, whether that value itself is accepted); other value rules:
#: Direction in _DIRECTIONS, Home's Position may be NaN (AxisCalibrationValue)
_MINIMA: dict[str, dict[str, tuple[float, bool]]] = {
    "MoveAbsolute": {"Velocity": (0.0, False)}, "MoveRelative": {"Velocity": (0.0, False)},
    "MoveVelocity": {"Velocity": (0.0, False)}, "JogStart": {"Velocity": (0.0, True)},
}
#: method -> the MC_Direction values the NC takes for it (1 positive, 3 negative, 4 current: MC_MoveVelocity)
_DIRECTIONS: dict[str, tuple[int, ...]] = {"MoveVelocity": (1, 3, 4), "JogStart": (1, 3)}


def _check_args(mname: str, inputs: list[ua.Argument], args: list[Any]) -> list[Any]:
    """``args`` of method ``mname`` checked against its declared ``inputs`` (asyncua does not) and converted:
    Boolean -> bool, Double -> float, Int32 -> int, String -> str.

    Raises:
        _Refused: BadArgumentsMissing / BadTooManyArguments (0x706) for a wrong count, BadTypeMismatch (0x706)
            for a value of another type (a Boolean must be a bool, a Double an int or float, not a bool),
            BadInvalidArgument for a bad value: non-finite (0x706; Home's NaN excepted), a velocity <= 0
            (JogStart's < 0: 0x4221, as the NC), a Direction outside the method's (0x4B05, as the NC).
    """
    if len(args) != len(inputs):
        status = ua.StatusCodes.BadArgumentsMissing if len(args) < len(inputs) else ua.StatusCodes.BadTooManyArguments
        raise _Refused(status, ErrorCodes.ADSERR_DEVICE_INVALIDDATA,
                       f"{mname} takes {len(inputs)} arguments, got {len(args)}")
    out: list[Any] = []
    for spec, a in zip(inputs, args):
        name, vt = spec.Name, ua.VariantType(spec.DataType.Identifier)
        mismatch = _Refused(ua.StatusCodes.BadTypeMismatch, ErrorCodes.ADSERR_DEVICE_INVALIDDATA,
                            f"{mname}: {name} must be {vt.name}, got {type(a).__name__}")
        invalid = lambda why, code=ErrorCodes.ADSERR_DEVICE_INVALIDDATA: _Refused(  # noqa: E731
            ua.StatusCodes.BadInvalidArgument, code, f"{mname}: {name} {why}")
        if vt == ua.VariantType.Boolean:
            if not isinstance(a, bool):
                raise mismatch
            out.append(a)
        elif vt == ua.VariantType.String:
            if not isinstance(a, str):
                raise mismatch
            out.append(a)
        elif vt == ua.VariantType.Int32:
            if not isinstance(a, int) or isinstance(a, bool):
                raise mismatch
            allowed = _DIRECTIONS.get(mname, ())
            if name == "Direction" and a not in allowed:
                raise invalid(f"{a}: one of {', '.join(map(str, allowed))} (MC_Direction)",
                              ErrorCodes.MC_COMMAND_NOT_PERMITTED)
            out.append(a)
        else:  # Double
            if not isinstance(a, (int, float)) or isinstance(a, bool):
                raise mismatch
            try:
                v = float(a)
            except OverflowError:
                raise invalid(f"{a} is not a finite Double") from None
            if not math.isfinite(v) and not (mname == "Home" and math.isnan(v)):
                raise invalid(f"{v} is not finite")
            low = _MINIMA.get(mname, {}).get(name)
            if low is not None and (v < low[0] or (v == low[0] and not low[1])):
                raise invalid(f"{v} must be {'>=' if low[1] else '>'} {low[0]:g}", ErrorCodes.NC_VELOCITY_NOT_ALLOWED)
            out.append(v)
    return out


_UNSET = object()


def _nid(ident: str, idx: int) -> ua.NodeId:
    """A string node id of namespace ``idx`` (asyncua's NewType'd constructor, typed once here)."""
    return ua.NodeId(cast(Any, ident), cast(Any, idx))


def _status(code: int) -> ua.StatusCode:
    return ua.StatusCode(cast(Any, code))


def _param_type(t: str) -> ua.VariantType:
    return {"BOOL": ua.VariantType.Boolean, "UDINT": ua.VariantType.UInt32}.get(t, ua.VariantType.Double)


def _zero(vt: ua.VariantType) -> Any:
    return {ua.VariantType.String: "", ua.VariantType.Boolean: False, ua.VariantType.Double: 0.0}.get(vt, 0)


def _error_text(code: int) -> str:
    if not code:
        return ""
    return f"{error_name(code)}: {error_text(code)}"
