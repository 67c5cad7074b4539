"""zenoh-cli codec plugins (entry points in pyproject.toml).

``zenoh --mode client --connect tcp/127.0.0.1:7447 subscribe -k 'nc/nc1/axis/1/nctoplc' --decoder nctoplc``
prints each sample as one JSON line with the TwinCAT field names.
"""
from __future__ import annotations

import json
from typing import Any

from .codec import bit_names, decode, to_dict
from .codec import decode_frame as _decode_frame
from .messages import pack, unpack
from .state import motion_state


def _nctoplc(rec: Any) -> dict[str, Any]:
    d = to_dict(rec)
    d["StateDWordBits"] = bit_names("NCTOPLC_AXIS_REF_STATE", d["StateDWord"])
    d["MotionState"] = motion_state(d["StateDWord"], d["CoupleState"]).name
    return d


def decode_nctoplc(key: Any, value: bytes) -> str:
    return json.dumps(_nctoplc(decode("NCTOPLC_AXIS_REF", value)))


def decode_plctonc(key: Any, value: bytes) -> str:
    d = to_dict(decode("PLCTONC_AXIS_REF", value))
    d["ControlDWordBits"] = bit_names("PLCTONC_AXIS_REF_CTRL", d["ControlDWord"])
    return json.dumps(d)


def decode_frame(key: Any, value: bytes) -> str:
    h, recs, jobs = _decode_frame(value)
    out: dict[str, Any] = {"header": to_dict(h), "axes": [_nctoplc(r) for r in recs]}
    if jobs is not None:
        out["jobs"] = [to_dict(j) for j in jobs]
    return json.dumps(out)


def decode_msgpack(key: Any, value: bytes) -> str:
    return json.dumps(unpack(value), default=repr)


def encode_msgpack(key: str, value: str) -> bytes:
    return pack(json.loads(value))
