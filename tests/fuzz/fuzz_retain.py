"""Fuzz target: the retain file parser ``nc_server.server.retain.parse_retain(raw, nc_name, axis_ids)``.

Skipped (exit status ``_runner.SKIPPED``) while ``nc_server.server.retain`` does not exist.

The file's header carries a sha256 of its body, so mutated bytes would almost never get past the
checksum; the input's first byte chooses what the fuzzer controls:

* the whole file (the header checks: magic, version, lengths, checksum);
* the msgpack body, wrapped in a correct header (the structure checks);
* the document, built field by field (plausible, boundary or hostile values, keys left out or extra),
  packed and wrapped (deep into the per-axis checks).

Checks: ``parse_retain`` raises only ``RetainError``; the module's inner parser, when it has one
(``_parse``: ``parse_retain`` turns anything it raises into a refusal, so a case its checks missed
would not crash the NC, but is still worth knowing), raises only ``RetainError`` too; a file it
accepts encodes again (``encode_retain``) to a file it accepts, with the same content.

Run: ``python -m tests.fuzz.fuzz_retain [libFuzzer args] [CORPUS_DIR | CRASH_FILE ...]``.
"""
from __future__ import annotations

import hashlib
import math
import struct
from typing import Any

from tests.fuzz._runner import Finding, Reader, Writer, instrument, main

SKIP: str | None = None
with instrument():
    import msgpack

    try:
        from nc_server.server import retain
    except ModuleNotFoundError as exc:
        if exc.name != "nc_server.server.retain":
            raise
        SKIP = "nc_server.server.retain does not exist yet (helper 'retain' writes it)"
        retain = None  # type: ignore[assignment]

NC, AXES = "nc1", (1, 2, 3, 4)
RAW, BODY, DOC = range(3)
KEYS = ("nc", "saved_ns", "axes", "name", "position", "homed", "standstill", "modulo", "params", "value",
        "configured", "x", "")
PARAMS = ("AxisVeloMax", "AxisAcc", "AxisEnMinSoftPosLimit", "AxisMinSoftPosLimit", "Modulo", "AxisEncoderModuloValue",
          "AxisEnDataPersistence", "Nonsense", "")
NUMBERS = (0.0, 1.0, -1.0, 360.0, 1e9, -1e9, 1e9 - 1, 1e300, math.nan, math.inf, -math.inf, -0.0, 5e-324, 0, 1, -1,
           2**63 - 1, -(2**63), 2**64 - 1, True, False)
AXIS_IDS = (1, 2, 3, 4, 0, 5, 65535, 65536, -1, True)


def header(body: bytes, version: int | None = None, length: int | None = None) -> bytes:
    v = retain.FORMAT_VERSION if version is None else version
    n = len(body) if length is None else length
    return retain.MAGIC + struct.pack("<HI", v, n) + hashlib.sha256(body).digest() + body


def value(r: Reader, depth: int = 0) -> Any:
    t = r.u8() % 10
    if t < 3:
        return r.pick(NUMBERS)
    if t == 3:
        return r.f64()
    if t == 4:
        return r.take(r.u8() % 300).decode("utf-8", "replace")
    if t == 5:
        return r.pick(("nc1", "nc2", "X", "Y", "Z", "C", ""))
    if t == 6:
        return None
    if t == 7:
        return r.take(r.u8() % 8)
    if t == 8 and depth < 2:
        return {r.pick(KEYS): value(r, depth + 1) for _ in range(r.u8() % 3)}
    return [value(r, depth + 1) for _ in range(r.u8() % 2)] if depth < 2 else 0


def axis_doc(r: Reader) -> dict[str, Any]:
    f = r.u16()
    d: dict[str, Any] = {"name": r.pick(("X", "Y", "Z", "C", "")) if f & 1 == 0 else value(r)}
    if f & 2:
        d["position"] = r.pick(NUMBERS) if f & 4 == 0 else value(r)
        d["homed"] = bool(f & 8) if f & 16 == 0 else value(r)
        d["standstill"] = True if f & 32 == 0 else value(r)
        d["modulo"] = 0.0 if f & 64 == 0 else value(r)
        if f & 128:  # one of the four left out
            del d[r.pick(("position", "homed", "standstill", "modulo"))]
    if f & 256:
        params: dict[Any, Any] = {}
        for _ in range(r.u8() % 4):
            e = r.u8()
            entry: Any = {"value": r.pick(NUMBERS), "configured": r.pick(NUMBERS)}
            if e & 1:
                entry[r.pick(("value", "configured", "x"))] = value(r)
            if e & 2:
                entry = value(r)
            name = r.pick(PARAMS) if e & 4 == 0 else value(r)
            params[name] = entry
        d["params"] = params if f & 512 == 0 else value(r)
    if f & 1024:
        key = r.pick(KEYS)
        d[key] = value(r)
    return d


def document(r: Reader) -> Any:
    f = r.u8()
    doc: dict[Any, Any] = {"nc": NC if f & 1 == 0 else value(r), "saved_ns": r.u64() if f & 2 == 0 else value(r)}
    axes: dict[Any, Any] = {}
    for _ in range(r.u8() % 6):
        key = r.pick(AXIS_IDS) if r.u8() % 8 else value(r)
        axes[key] = axis_doc(r)
    doc["axes"] = axes if f & 4 == 0 else value(r)
    if f & 8:
        del doc[r.pick(("nc", "saved_ns", "axes"))]
    if f & 16:
        key = r.pick(KEYS)
        doc[key] = value(r)
    return doc


def check(raw: bytes) -> None:
    inner = getattr(retain, "_parse", None)
    if inner is not None:
        try:
            inner(raw, NC, AXES)
        except retain.RetainError:
            pass
    try:
        data = retain.parse_retain(raw, NC, AXES)
    except retain.RetainError:
        return
    again = retain.encode_retain(data)
    try:
        data2 = retain.parse_retain(again, NC, AXES)
    except retain.RetainError as err:
        raise Finding(f"an accepted file, written again, is refused: {err}") from err
    if retain.encode_retain(data2) != again:
        raise Finding(f"an accepted file does not read back the same: {data!r} -> {data2!r}")


def test_one(data: bytes) -> None:
    r = Reader(data)
    mode = r.u8() % 3
    if mode == RAW:
        check(r.take(r.left()))
        return
    if mode == BODY:
        check(header(r.take(r.left())))
        return
    try:
        body = msgpack.packb(document(r), use_bin_type=True)
    except (OverflowError, TypeError, ValueError):
        return
    check(header(body))


def seeds() -> list[bytes]:
    R, A = retain.RetainData, retain.AxisRetain
    files = [
        R(NC, {}, 0),
        R(NC, {1: A("X", 10.0, True, True, 0.0)}, 1_700_000_000_000_000_000),
        R(NC, {1: A("X", -5.5, False, False, 0.0, {"AxisVeloMax": (400.0, 500.0)}),
               4: A("C", 359.0, True, True, 360.0, {"AxisEnMinSoftPosLimit": (True, False)})}, 5),
        R(NC, {2: A("Y", params={"AxisAcc": (1000.0, 5000.0), "AxisDec": (1000.0, 5000.0)})}, 7),
    ]
    out = []
    for d in files:
        f = retain.encode_retain(d)
        out.append(Writer().u8(RAW).raw(f).bytes())
        out.append(Writer().u8(BODY).raw(f[len(header(b"")):]).bytes())
    out.append(Writer().u8(RAW).raw(header(b"\x80", version=1)).bytes())
    w = Writer().u8(DOC).u8(0).u64(3).u8(2)  # nc1, saved_ns 3, two axes
    w.u8(1).index(AXIS_IDS, 1).u16(2 | 8 | 256).u8(0).index(NUMBERS, 1.0)  # X at 1.0, homed, standing
    w.u8(1).u8(0).index(NUMBERS, 360.0).index(NUMBERS, 1.0).index(PARAMS, "AxisVeloMax")  # one parameter
    w.u8(1).index(AXIS_IDS, 4).u16(0).u8(3)  # C: the name only
    out.append(w.bytes())
    return out


if __name__ == "__main__":
    main("retain", test_one, seeds, skip=SKIP)
