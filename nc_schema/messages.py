"""Key expressions and msgpack command/reply messages (``protocol.json``)."""
from __future__ import annotations

import math
import re
from typing import Any, Iterable, Mapping, cast

import msgpack

from .codec import load_json
from .errors import ErrorCodes, NcError, error_text
from .instance import INSTANCE_RE

PROTOCOL: dict[str, Any] = load_json("protocol.json")
COMMANDS: dict[str, Any] = PROTOCOL["commands"]
MOTION_COMMANDS = frozenset(n for n, c in COMMANDS.items() if c.get("motion"))
_ENVELOPE = frozenset(PROTOCOL["request"]["fields"])
_CLIENT_RE = re.compile(r"[A-Za-z0-9_.-]{1,64}")  # fullmatch: "$" would let a trailing newline through
_NAME_RE = re.compile(r"[A-Za-z0-9_.-]{1,64}")


#: Command classes (protocol.json ``classes``), lowest privilege first.
CLASSES: tuple[str, ...] = ("read", "op", "eng")
#: Command name -> its class.
COMMAND_CLASS: dict[str, str] = {n: c.get("class", "op") for n, c in COMMANDS.items()}  # "op": the rest (design)
#: Roles (roles file, ACL) -> the command classes they may send.
ROLE_CLASSES: dict[str, tuple[str, ...]] = {"observer": ("read",), "operator": ("read", "op"),
                                            "engineer": ("read", "op", "eng")}
_AXIS_RE = r"(?:0|[1-9][0-9]{0,8})"  # decimal, no leading zeros: axis/01 is not axis 1
#: Periods [ms] of the ``nc/<nc>/frame/<period>ms`` keys (protocol.json ``frame_every``).
FRAME_PERIODS_MS: tuple[int, ...] = tuple(PROTOCOL["keys"]["frame_every"]["periods_ms"])


def parse_alive_instance(key: object) -> tuple[str, str] | None:
    """(NC name, instance id) of an instance token's key ``nc/<nc>/alive/<instance>``; None for any
    other key (``nc/<nc>/alive``, a malformed name or id: such a token is ignored, never an error)."""
    parts = str(key).split("/")
    if len(parts) != 4 or parts[0] != "nc" or parts[2] != "alive":
        return None
    if not _NAME_RE.fullmatch(parts[1]) or not INSTANCE_RE.fullmatch(parts[3]):
        return None
    return parts[1], parts[3]


#: Periods [ms] of a client's view (protocol.json ``view_select``): 0 = every NC cycle, else a frame_every period.
VIEW_PERIODS_MS: tuple[int, ...] = (0,) + FRAME_PERIODS_MS
#: At most this many axes in one view token (a key stays short; an NC has at most a few hundred axes a client reads).
MAX_VIEW_AXES = 256
_VIEW_AXES_RE = re.compile(rf"none|{_AXIS_RE}(?:,{_AXIS_RE}){{0,{MAX_VIEW_AXES - 1}}}")


def view_axes_chunk(axes: Iterable[int]) -> str:
    """The ``{axes}`` chunk of a view token: ascending distinct ids joined by ',' (``none`` for no axis).

    Raises:
        ValueError: a negative id or more than MAX_VIEW_AXES axes.
    """
    ids = sorted({int(a) for a in axes})
    if ids and ids[0] < 0:
        raise ValueError(f"invalid axis id {ids[0]}")
    if len(ids) > MAX_VIEW_AXES:
        raise ValueError(f"a view lists at most {MAX_VIEW_AXES} axes, not {len(ids)}")
    return view_axes_text(ids)


def view_axes_text(axes: Iterable[int]) -> str:
    """A view frame's attachment (protocol.json ``view``): every AxisId the client asked for, ascending, joined
    by ',' (``none`` for no axis), whether the NC has it or not; no length limit (the union of its tokens)."""
    ids = sorted({int(a) for a in axes})
    return ",".join(map(str, ids)) if ids else "none"


def parse_view_axes(text: bytes | str) -> frozenset[int] | None:
    """The AxisIds of a view frame's attachment (:func:`view_axes_text`); None if it is not one."""
    if isinstance(text, bytes):
        try:
            text = text.decode("ascii")
        except UnicodeDecodeError:
            return None
    if text == "none":
        return frozenset()
    try:
        ids = frozenset(int(a) for a in text.split(","))
    except ValueError:
        return None
    return ids if all(0 <= a <= 0xFFFF for a in ids) else None


def parse_view_select(key: object) -> tuple[str, str, int, tuple[int, ...]] | None:
    """(NC, client, period [ms], axis ids) of a view token's key ``nc/<nc>/select/<client>/<P>ms/<axes>``;
    None for anything else (a malformed token is ignored, never an error: the NC's publisher sees every
    token of its prefix)."""
    parts = str(key).split("/")
    if len(parts) != 6 or parts[0] != "nc" or parts[2] != "select":
        return None
    nc, client, period, axes = parts[1], parts[3], parts[4], parts[5]
    if not _NAME_RE.fullmatch(nc) or not _CLIENT_RE.fullmatch(client) or not period.endswith("ms"):
        return None
    try:
        p = int(period[:-2])
    except ValueError:
        return None
    if p not in VIEW_PERIODS_MS or str(p) + "ms" != period or not _VIEW_AXES_RE.fullmatch(axes):
        return None
    ids = () if axes == "none" else tuple(int(a) for a in axes.split(","))
    if list(ids) != sorted(set(ids)):
        return None
    return nc, client, p, ids


def view_period_ms(cycle_time: float) -> int:
    """The view period [ms] of a client reading once per ``cycle_time`` [s]: the longest of ``VIEW_PERIODS_MS`` of
    at most one cycle, 0 (every NC cycle) for a cycle shorter than the shortest period. One view frame per PLC
    cycle on average: the data a cycle reads is at most one period (plus the link's latency) old, as with whole
    frames at :func:`frame_period_ms`'s half cycle it was at most half a cycle; frames at half the cycle cost a
    PLC client's zenoh threads twice the wake-ups (issue 19: about 0.5 % of a core per client at 10 ms)."""
    fit = [p for p in VIEW_PERIODS_MS if p * 1e-3 <= cycle_time + 1e-12]
    return max(fit)


#: The period [ms] of a view of no axes (a client that reads none of the NC's axes yet): its frames carry no
#: record, they only show that the NC is there (its cycle counter: the restart rule), so the slowest one.
IDLE_VIEW_PERIOD_MS = max(VIEW_PERIODS_MS)


def frame_period_ms(cycle_time: float) -> int | None:
    """The ``frame_every`` period for a client reading once per ``cycle_time`` [s]: the longest one of at
    most half the cycle (each cycle then sees a newer frame), or None (take every frame: ``frame``)."""
    fit = [p for p in FRAME_PERIODS_MS if p * 1e-3 <= cycle_time / 2 + 1e-12]
    return max(fit) if fit else None


class Keys:
    """Key expressions of one NC (protocol.json ``keys``).

    Commands (protocol version 2 and later) carry their class and the sender's client id in the key:
    ``nc/<nc>/axis/<axis>/cmd/<class>/<client>`` and ``nc/<nc>/cmd/<class>/<client>``.

    Raises:
        ValueError: invalid NC name.
    """

    def __init__(self, nc: str) -> None:
        if not isinstance(nc, str) or not _NAME_RE.fullmatch(nc):
            raise ValueError(f"invalid NC name {nc!r}: use letters, digits, '_', '.', '-'")
        self.nc = nc
        self.prefix = f"nc/{nc}"
        self.frame = f"{self.prefix}/frame"
        self.stats = f"{self.prefix}/stats"
        self.status = f"{self.prefix}/status"
        self.claims = f"{self.prefix}/claims"
        #: the NC's one queryable: every command key (axis and NC level) of this NC
        self.cmd_any = f"{self.prefix}/**/cmd/*/*"
        self.alive = f"{self.prefix}/alive"
        #: every instance token of this NC (``alive_instance``): what clients watch for a restart
        self.alive_instance_any = f"{self.alive}/*"
        self.client_alive_any = f"{self.prefix}/client/*"
        self.plctonc_in_any = f"{self.prefix}/plctonc/*"
        #: every view token of this NC (``view_select``): what its frame publisher watches
        self.view_select_any = f"{self.prefix}/select/*/*/*"
        self._cmd_re = re.compile(re.escape(self.prefix) + rf"(?:/axis/({_AXIS_RE}))?/cmd/([a-z]+)/([A-Za-z0-9_.-]{{1,64}})")

    def frame_every(self, period_ms: int) -> str:
        """``nc/<nc>/frame/<period_ms>ms``: the status frame once per period (one of FRAME_PERIODS_MS).

        Raises:
            ValueError: not one of FRAME_PERIODS_MS.
        """
        if period_ms not in FRAME_PERIODS_MS:
            raise ValueError(f"frame period {period_ms!r} ms: use one of {FRAME_PERIODS_MS}")
        return f"{self.frame}/{int(period_ms)}ms"

    def view(self, client: str) -> str:
        """``nc/<nc>/view/<client>``: the frames of the axes ``client`` selected (:meth:`view_select`)."""
        return f"{self.prefix}/view/{check_client_id(client)}"

    def view_select(self, client: str, period_ms: int, axes: Iterable[int]) -> str:
        """``nc/<nc>/select/<client>/<period_ms>ms/<axes>``: the liveliness token that asks for ``client``'s view.

        Raises:
            ValueError: invalid client id, a period not in VIEW_PERIODS_MS, a negative id, too many axes.
        """
        if period_ms not in VIEW_PERIODS_MS:
            raise ValueError(f"view period {period_ms!r} ms: use one of {VIEW_PERIODS_MS}")
        return f"{self.prefix}/select/{check_client_id(client)}/{int(period_ms)}ms/{view_axes_chunk(axes)}"

    def axis_nctoplc(self, axis: int) -> str:
        return f"{self.prefix}/axis/{int(axis)}/nctoplc"

    def axis_plctonc(self, axis: int) -> str:
        return f"{self.prefix}/axis/{int(axis)}/plctonc"

    def axis_cmd(self, axis: int, cls: str, client: str) -> str:
        """``nc/<nc>/axis/<axis>/cmd/<cls>/<client>``.

        Raises:
            ValueError: unknown class, invalid client id or negative axis id.
        """
        if int(axis) < 0:
            raise ValueError(f"invalid axis id {axis!r}")
        return f"{self.prefix}/axis/{int(axis)}/cmd/{_check_class(cls)}/{check_client_id(client)}"

    def cmd(self, cls: str, client: str) -> str:
        """``nc/<nc>/cmd/<cls>/<client>`` (NC-level commands such as Info).

        Raises:
            ValueError: unknown class or invalid client id.
        """
        return f"{self.prefix}/cmd/{_check_class(cls)}/{check_client_id(client)}"

    def command_key(self, cmd: str, axis: int | None, client: str) -> str:
        """The key ``client`` sends ``cmd`` on: its class from protocol.json (``op`` for a command
        the contract does not know: the NC answers it with 0x701); ``axis`` None: the NC-level key.

        Raises:
            ValueError: invalid client id.
        """
        cls = COMMAND_CLASS.get(cmd, "op")
        return self.cmd(cls, client) if axis is None else self.axis_cmd(axis, cls, client)

    def alive_instance(self, instance: str) -> str:
        """``nc/<nc>/alive/<instance>``: the liveliness token of one NC process (``nc_schema.instance``).

        Raises:
            ValueError: not an instance id (16 lowercase hex digits).
        """
        if not isinstance(instance, str) or not INSTANCE_RE.fullmatch(instance):
            raise ValueError(f"invalid NC instance id {instance!r}: 16 lowercase hex digits")
        return f"{self.alive}/{instance}"

    def client_alive(self, client: str) -> str:
        check_client_id(client)
        return f"{self.prefix}/client/{client}"

    def plctonc_in(self, client: str) -> str:
        check_client_id(client)
        return f"{self.prefix}/plctonc/{client}"

    def parse_cmd_key(self, key: str) -> tuple[int | None, str, str]:
        """(axis id or None for the NC-level key, class, client) of a command key.

        Only the canonical form is accepted: a decimal axis id without leading zeros, a known class
        and a valid client id. Whether the axis exists is for the NC to say.

        Raises:
            NcError: 0x4012 for anything else.
        """
        m = self._cmd_re.fullmatch(key) if isinstance(key, str) else None
        if not m or m.group(2) not in CLASSES:
            shown = key[:200] if isinstance(key, str) else key
            raise NcError(ErrorCodes.NC_AXIS_ID_NOT_ALLOWED,
                          f"no such command key {shown!r}: expected {self.prefix}/[axis/<id>/]cmd/<read|op|eng>/<client>")
        axis = m.group(1)
        return (None if axis is None else int(axis)), m.group(2), m.group(3)


def _check_class(cls: str) -> str:
    if cls not in CLASSES:
        raise ValueError(f"unknown command class {cls!r}: one of {', '.join(CLASSES)}")
    return cls


def check_client_id(client: str) -> str:
    """Raise ValueError unless ``client`` is a valid client id."""
    if not isinstance(client, str) or not _CLIENT_RE.fullmatch(client):
        raise ValueError(f"invalid client id {client!r}: 1-64 of letters, digits, '_', '.', '-'")
    return client


def pack(obj: Mapping[str, Any]) -> bytes:
    return cast(bytes, msgpack.packb(obj, use_bin_type=True))  # (msgpack has no type information)


def unpack(data: bytes) -> Any:
    return msgpack.unpackb(data, raw=False, strict_map_key=False)


def _check_arg(cmd: str, name: str, spec: Mapping[str, Any], value: Any) -> Any:
    t = spec["type"]
    is_bool = isinstance(value, bool)
    if t == "LREAL":
        if is_bool or not isinstance(value, (int, float)):
            raise NcError(ErrorCodes.ADSERR_DEVICE_INVALIDDATA, f"{cmd}.{name} must be a number, got {type(value).__name__}")
        value = float(value)
        if not math.isfinite(value):
            raise NcError(ErrorCodes.ADSERR_DEVICE_INVALIDDATA, f"{cmd}.{name} must be finite, got {value}")
        return value
    if t == "INT":
        if is_bool or not isinstance(value, int):
            raise NcError(ErrorCodes.ADSERR_DEVICE_INVALIDDATA, f"{cmd}.{name} must be an integer, got {value!r}")
        if not -(2**31) <= value < 2**31:
            raise NcError(ErrorCodes.ADSERR_DEVICE_INVALIDDATA, f"{cmd}.{name} out of range: {value}")
        return value
    if t == "BOOL":
        if not is_bool:
            raise NcError(ErrorCodes.ADSERR_DEVICE_INVALIDDATA, f"{cmd}.{name} must be true or false, got {value!r}")
        return value
    if t == "LREAL|BOOL":
        if is_bool:
            return value
        return _check_arg(cmd, name, {"type": "LREAL"}, value)
    if t == "STRING":
        if not isinstance(value, str) or len(value) > 255:
            raise NcError(ErrorCodes.ADSERR_DEVICE_INVALIDDATA, f"{cmd}.{name} must be a string of at most 255 "
                                                                f"characters, got {str(value)[:40]!r}")
        return value
    raise AssertionError(f"unknown arg type {t}")  # contract bug, not input


def parse_request(data: bytes) -> dict[str, Any]:
    """Decode and validate a request against protocol.json.

    Returns the request with defaults filled in: ``{"id", "client", "cmd", <args>}``.

    Raises:
        NcError: 0x706 malformed (not msgpack, not a map, bad types, unknown
            fields, NaN/inf), 0x701 unknown command. ``NcError.request_id`` is
            set when the id could be read, so the reply can carry it.
    """
    try:
        msg = unpack(data)
    except Exception as exc:  # msgpack raises many types
        raise NcError(ErrorCodes.ADSERR_DEVICE_INVALIDDATA, f"payload is not msgpack: {exc.__class__.__name__}") from None
    if not isinstance(msg, dict):
        raise NcError(ErrorCodes.ADSERR_DEVICE_INVALIDDATA, "request must be a msgpack map")
    rid = msg.get("id")
    try:
        if isinstance(rid, bool) or not isinstance(rid, (int, str)):
            raise NcError(ErrorCodes.ADSERR_DEVICE_INVALIDDATA, "request needs an 'id' (integer or string)")
        if isinstance(rid, str) and len(rid) > 128:
            raise NcError(ErrorCodes.ADSERR_DEVICE_INVALIDDATA, "request id longer than 128 characters")
        client = msg.get("client", "")
        if client != "":
            try:
                check_client_id(client)
            except ValueError as exc:
                raise NcError(ErrorCodes.ADSERR_DEVICE_INVALIDDATA, str(exc)) from None
        cmd = msg.get("cmd")
        if not isinstance(cmd, str):
            raise NcError(ErrorCodes.ADSERR_DEVICE_INVALIDDATA, "request needs a 'cmd' string")
        spec = COMMANDS.get(cmd)
        if spec is None:
            raise NcError(ErrorCodes.ADSERR_DEVICE_SRVNOTSUPP, f"unknown command {cmd[:64]!r}")
        args = spec["args"]
        unknown = [k for k in msg if k not in _ENVELOPE and k not in args]
        if unknown:
            raise NcError(ErrorCodes.ADSERR_DEVICE_INVALIDDATA, f"{cmd}: unknown field(s) {sorted(map(str, unknown))[:5]}")
        out: dict[str, Any] = {"id": rid, "client": client, "cmd": cmd}
        for name, aspec in args.items():
            if name in msg:
                out[name] = _check_arg(cmd, name, aspec, msg[name])
            elif aspec.get("required"):
                raise NcError(ErrorCodes.ADSERR_DEVICE_INVALIDDATA, f"{cmd}: missing field {name!r}")
            else:
                out[name] = aspec.get("default")
        return out
    except NcError as err:
        err.request_id = rid if isinstance(rid, (int, str)) and not isinstance(rid, bool) else None
        cmd = msg.get("cmd")
        err.cmd = cmd if isinstance(cmd, str) and cmd in COMMANDS else None
        raise


def make_reply(request_id: Any, cmd: str | None, error: int = 0, text: str = "", cycle: int = 0,
               cmd_no: int | None = None, value: Any = None) -> dict[str, Any]:
    """A reply map (protocol.json ``reply``)."""
    r: dict[str, Any] = {"id": request_id, "cmd": cmd, "error": int(error),
                         "text": text if error == 0 or text else error_text(error), "cycle": int(cycle)}
    if cmd_no is not None:
        r["CmdNo"] = int(cmd_no)
    if value is not None:
        r["Value"] = value
    return r


def parse_reply(data: bytes) -> dict[str, Any]:
    """Decode and check a reply (client side): a msgpack map whose ``error`` (UDINT) and ``cycle``
    (ULINT) are integers, ``CmdNo`` (UINT) an integer if present, ``text`` a string if present.

    Raises:
        ValueError: not msgpack, not a map, or one of those fields missing or of the wrong type or
            range (a reply the function blocks could not act on).
    """
    try:
        msg = unpack(data)
    except Exception as exc:  # msgpack raises many types
        raise ValueError(f"reply is not msgpack: {exc.__class__.__name__}") from None
    if not isinstance(msg, dict):
        raise ValueError("reply must be a msgpack map")
    for name, hi, required in (("error", 2**32, True), ("cycle", 2**64, True), ("CmdNo", 2**16, False)):
        v = msg.get(name)
        if v is None and not required and name not in msg:
            continue
        if type(v) is not int or not 0 <= v < hi:
            raise ValueError(f"reply field {name!r} must be an integer in [0, {hi}), got {v!r:.40}")
    if not isinstance(msg.get("text", ""), str):
        raise ValueError("reply field 'text' must be a string")
    return msg


def make_request(cmd: str, request_id: int | str, client: str = "", **args: Any) -> bytes:
    """Encode a request (client side helper)."""
    msg: dict[str, Any] = {"id": request_id, "cmd": cmd}
    if client:
        msg["client"] = client
    msg.update(args)
    return pack(msg)
