"""zenoh-cli codec plugins (entry points in pyproject.toml).

``zenoh --mode client --connect tcp/127.0.0.1:7447 subscribe -k 'nc/nc1/axis/1/nctoplc' --decoder nctoplc``
prints each sample as one JSON line with the TwinCAT field names.

Every decoder takes ``(key, payload bytes)`` and returns one line of JSON; every encoder takes
``(key, text typed on the command line)`` and returns the payload bytes (zenoh-cli's plugin
interface). Decoders: ``nctoplc``, ``plctonc`` (per-axis samples), ``ncframe`` (``nc/<nc>/frame``,
``frame/<P>ms``, a client's ``view/<client>`` and ``nc/<nc>/status``), ``plcframe`` (``nc/<nc>/plctonc/<client>``), ``ncrequest`` / ``ncreply`` (command
messages), ``msgpack`` (stats, claims, anything msgpack). Encoders: ``ncrequest`` (a checked
request), ``msgpack`` (any JSON as msgpack, unchecked: for sending deliberately bad requests).
"""
from __future__ import annotations

import itertools
import json
import re
import time
from typing import Any

from .codec import bit_names, decode, decode_plc_frame, to_dict
from .codec import decode_frame as _decode_frame
from .errors import NcError, error_name
from .messages import COMMANDS, pack, parse_request, unpack
from .state import motion_state

#: a command key of either layout: ``nc/<nc>[/axis/<axis>]/cmd[/<class>/<client>]``
_CMD_KEY = re.compile(r"nc/[^/]+(?:/axis/(?P<axis>[^/]+))?/cmd(?:/(?P<cls>[^/]+)/(?P<client>[^/]+))?")
#: request ids the ``ncrequest`` encoder makes up: unique per process and across runs (ms clock)
_ids = itertools.count(time.time_ns() // 1_000_000)


def _json(obj: Any) -> str:
    return json.dumps(obj, default=repr)


def _nctoplc(rec: Any) -> dict[str, Any]:
    d = to_dict(rec)
    d["StateDWordBits"] = bit_names("NCTOPLC_AXIS_REF_STATE", d["StateDWord"])
    d["MotionState"] = motion_state(d["StateDWord"], d["CoupleState"]).name
    return d


def _plctonc(rec: Any) -> dict[str, Any]:
    d = to_dict(rec)
    d["ControlDWordBits"] = bit_names("PLCTONC_AXIS_REF_CTRL", d["ControlDWord"])
    return d


def decode_nctoplc(key: Any, value: bytes) -> str:
    """One NCTOPLC_AXIS_REF (256 B) -> JSON with StateDWordBits and MotionState added.

    Raises:
        ValueError: not 256 bytes.
    """
    return _json(_nctoplc(decode("NCTOPLC_AXIS_REF", value)))


def decode_plctonc(key: Any, value: bytes) -> str:
    """One PLCTONC_AXIS_REF (128 B) -> JSON with ControlDWordBits added.

    Raises:
        ValueError: not 128 bytes.
    """
    return _json(_plctonc(decode("PLCTONC_AXIS_REF", value)))


def decode_frame(key: Any, value: bytes) -> str:
    """A status frame (``nc/<nc>/frame``, a view ``nc/<nc>/view/<client>``, ``nc/<nc>/status``) ->
    ``{"header", "axes", ["jobs"]}``.

    Raises:
        ValueError: wrong magic, version or sizes.
    """
    h, recs, jobs = _decode_frame(value)
    out: dict[str, Any] = {"header": to_dict(h), "axes": [_nctoplc(r) for r in recs]}
    if jobs is not None:
        out["jobs"] = [to_dict(j) for j in jobs]
    return _json(out)


def decode_plcframe(key: Any, value: bytes) -> str:
    """A PLC client's frame (``nc/<nc>/plctonc/<client>``) -> ``{"header", "axes": [{AxisId, PLCTONC fields}]}``.

    Raises:
        ValueError: wrong magic, version or sizes.
    """
    h, recs = decode_plc_frame(value)
    axes = [{"AxisId": int(r["AxisId"]), **_plctonc(r["PlcToNc"])} for r in recs]
    return _json({"header": to_dict(h), "axes": axes})


def decode_msgpack(key: Any, value: bytes) -> str:
    """Any msgpack payload -> JSON (bytes and other non-JSON values as their repr)."""
    return _json(unpack(value))


def decode_request(key: Any, value: bytes) -> str:
    """A command request (msgpack map) -> the map as JSON, exactly as sent.

    A request the NC would refuse gets ``"invalid": "0x0706 ADSERR_DEVICE_INVALIDDATA: ..."`` added
    (the NC's own check, :func:`nc_schema.parse_request`).

    Raises:
        ValueError: not msgpack at all.
    """
    msg = unpack(value)
    try:
        parse_request(value)
    except NcError as err:
        if isinstance(msg, dict):
            msg = {**msg, "invalid": str(err)}
        else:
            msg = {"value": msg, "invalid": str(err)}
    return _json(msg)


def decode_reply(key: Any, value: bytes) -> str:
    """A command reply (msgpack map) -> the map as JSON, plus ``"error_name"`` when ``error`` != 0.

    Raises:
        ValueError: not msgpack.
    """
    msg = unpack(value)
    if isinstance(msg, dict) and isinstance(msg.get("error"), int) and msg["error"]:
        msg = {**msg, "error_name": error_name(msg["error"])}
    return _json(msg)


def encode_request(key: str, value: str) -> bytes:
    """A request typed as JSON -> msgpack, checked the way the NC checks it.

    ``id`` may be left out: a fresh one is made (ids are deduplicated per client, so a request
    repeated by hand with the same id would only get the cached reply). When ``key`` is a command
    key, the command must fit it: an axis command on an axis key, an NC command on the NC key, the
    class of the command (protocol.json ``class``) on a ``.../cmd/<class>/<client>`` key, and a
    ``client`` field, if given, equal to the key's client.

    Raises:
        ValueError: not JSON, not an object, refused by the NC's check (the message carries its
            TwinCAT code, e.g. ``0x0706 ADSERR_DEVICE_INVALIDDATA``), or the command does not fit the key.
    """
    try:
        msg = json.loads(value)
    except json.JSONDecodeError as exc:
        raise ValueError(f"request is not JSON: {exc}") from None
    if not isinstance(msg, dict):
        raise ValueError("request must be a JSON object, e.g. {\"cmd\": \"Info\"}")
    if "id" not in msg:
        msg = {"id": next(_ids), **msg}
    data = pack(msg)
    try:
        parse_request(data)
    except NcError as err:
        raise ValueError(str(err)) from None
    m = _CMD_KEY.fullmatch(str(key))
    if m is not None:
        spec = COMMANDS[msg["cmd"]]
        scope = spec.get("scope")
        if scope == "axis" and m["axis"] is None:
            raise ValueError(f"{msg['cmd']} is an axis command: send it to nc/<nc>/axis/<axis>/cmd/...")
        if scope == "nc" and m["axis"] is not None:
            raise ValueError(f"{msg['cmd']} is an NC command: send it to nc/<nc>/cmd/...")
        cls = spec.get("class")
        if m["cls"] is not None and cls is not None and m["cls"] != cls:
            raise ValueError(f"{msg['cmd']} is of class {cls!r}, the key says {m['cls']!r} (the NC would answer 0x723)")
        if m["client"] is not None and msg.get("client") and msg["client"] != m["client"]:
            raise ValueError(f"request client {msg['client']!r} is not the key's client {m['client']!r} "
                             "(the NC would answer 0x723)")
    return data


def encode_msgpack(key: str, value: str) -> bytes:
    """Any JSON -> msgpack, unchecked."""
    return pack(json.loads(value))
