"""The contract's byte layouts: the JSON files, the numpy dtypes built from ``structs.json`` and the one
dtype -> ``struct.Struct`` conversion every fast path uses.

Owns: locating and loading the contract's JSON (:data:`CONTRACT_DIR`, :func:`load_json`), the dtypes
(:data:`DTYPES`, ``NCTOPLC_DTYPE`` ...), their sizes, :func:`members` / :func:`struct_of` /
:func:`member_struct` / :func:`pick_struct` (the only place a layout becomes a struct format),
:func:`decode` and :func:`to_dict` of one record. Imports only the standard library and numpy (the generated
enums, the frame codec and the rest of ``nc_schema`` build on it).
"""
from __future__ import annotations

import json
import struct
from importlib import resources
from importlib.resources.abc import Traversable
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

__all__ = [
    "CONTRACT_DIR", "load_json", "STRUCTS", "BITSETS", "ENUMS", "DTYPES", "NCTOPLC_DTYPE", "PLCTONC_DTYPE",
    "FRAME_HEADER_DTYPE", "PLC_FRAME_HEADER_DTYPE", "PLC_AXIS_RECORD_DTYPE", "STAMP_DTYPE", "NCJOBS_DTYPE",
    "NCTOPLC_SIZE", "PLCTONC_SIZE", "NCJOBS_SIZE", "FRAME_HEADER_SIZE", "PLC_FRAME_HEADER_SIZE",
    "PLC_AXIS_RECORD_SIZE", "STAMP_SIZE", "Member", "members", "struct_of", "member_struct", "pick_struct", "decode", "to_dict",
]

#: IEC 61131 type of structs.json -> numpy type string
_TYPES: dict[str, str] = {
    "BOOL": "u1", "BYTE": "u1", "USINT": "u1",
    "WORD": "<u2", "UINT": "<u2",
    "DWORD": "<u4", "UDINT": "<u4", "DINT": "<i4",
    "ULINT": "<u8", "LREAL": "<f8",
}


def _contract_dir() -> Traversable:
    """The folder holding the contract's JSON files.

    An installed wheel ships them inside the package as ``nc_schema/contract/`` (pyproject.toml maps
    the data-only package ``nc_schema.contract`` to ``schema/``); a source checkout or an editable
    install has no such folder and reads the one source of truth, ``schema/`` beside the package.
    """
    shipped = resources.files(__package__).joinpath("contract")
    if shipped.joinpath("structs.json").is_file():
        return shipped
    source = Path(__file__).resolve().parent.parent / "schema"
    if (source / "structs.json").is_file():
        return source
    raise ImportError(f"nc_schema: contract JSON not found (neither {shipped} nor {source})")


CONTRACT_DIR: Traversable = _contract_dir()


def load_json(name: str) -> dict[str, Any]:
    """Load one of the contract's JSON files (``structs.json``, ... from :data:`CONTRACT_DIR`)."""
    data: dict[str, Any] = json.loads(CONTRACT_DIR.joinpath(name).read_text(encoding="utf-8"))
    return data


STRUCTS: dict[str, Any] = load_json("structs.json")["structs"]
BITSETS: dict[str, dict[str, str]] = load_json("bits.json")["bitsets"]
ENUMS: dict[str, Any] = load_json("enums.json")["enums"]


def _build_dtype(name: str, built: dict[str, np.dtype]) -> np.dtype:
    if name in built:
        return built[name]
    spec = STRUCTS[name]
    names: list[str] = []
    formats: list[Any] = []
    offsets: list[int] = []
    for f in spec["fields"]:
        t = f["type"]
        base = _build_dtype(t, built) if t in STRUCTS else np.dtype(_TYPES[t])
        names.append(f["name"])
        formats.append((base, (f["count"],)) if "count" in f else base)
        offsets.append(f["offset"])
    dt = np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": spec["size"]})
    built[name] = dt
    return dt


DTYPES: dict[str, np.dtype] = {}
for _n in STRUCTS:
    _build_dtype(_n, DTYPES)

NCTOPLC_DTYPE: np.dtype = DTYPES["NCTOPLC_AXIS_REF"]
PLCTONC_DTYPE: np.dtype = DTYPES["PLCTONC_AXIS_REF"]
FRAME_HEADER_DTYPE: np.dtype = DTYPES["FRAME_HEADER"]
PLC_FRAME_HEADER_DTYPE: np.dtype = DTYPES["PLC_FRAME_HEADER"]
PLC_AXIS_RECORD_DTYPE: np.dtype = DTYPES["PLC_AXIS_RECORD"]
STAMP_DTYPE: np.dtype = DTYPES["STAMP"]
NCJOBS_DTYPE: np.dtype = DTYPES["NCJOBS_AXIS_REF"]

#: sizes in bytes (the dtypes' itemsize, as plain ints for offset arithmetic)
NCTOPLC_SIZE: int = NCTOPLC_DTYPE.itemsize
PLCTONC_SIZE: int = PLCTONC_DTYPE.itemsize
NCJOBS_SIZE: int = NCJOBS_DTYPE.itemsize
FRAME_HEADER_SIZE: int = FRAME_HEADER_DTYPE.itemsize
PLC_FRAME_HEADER_SIZE: int = PLC_FRAME_HEADER_DTYPE.itemsize
PLC_AXIS_RECORD_SIZE: int = PLC_AXIS_RECORD_DTYPE.itemsize
STAMP_SIZE: int = STAMP_DTYPE.itemsize

#: (numpy kind, itemsize) -> struct format code
_CODES: dict[tuple[str, int], str] = {
    ("u", 1): "B", ("u", 2): "H", ("u", 4): "I", ("u", 8): "Q", ("i", 1): "b", ("i", 2): "h", ("i", 4): "i",
    ("i", 8): "q", ("f", 4): "f", ("f", 8): "d",
}


class Member(NamedTuple):
    """One scalar or array member of a struct: its struct format code and, for an array, its length."""

    name: str
    offset: int
    code: str
    array_len: int  # 0: a scalar

    @property
    def fmt(self) -> str:
        """Its struct format (without the byte order): ``"d"``, ``"8B"``."""
        return f"{self.array_len}{self.code}" if self.array_len else self.code


def members(dtype: np.dtype, stop: str | None = None) -> list[Member]:
    """Every member of ``dtype`` in layout order (with ``stop``: the ones before that member).

    Raises:
        ValueError: a member is itself a struct (only flat layouts have a struct format).
    """
    assert dtype.names is not None and dtype.fields is not None
    out = []
    for name in dtype.names:
        if name == stop:
            break
        fdt, off = dtype.fields[name][:2]
        base, n = (fdt.subdtype[0], int(np.prod(fdt.subdtype[1]))) if fdt.subdtype is not None else (fdt, 0)
        code = _CODES.get((base.kind, base.itemsize))
        if code is None:
            raise ValueError(f"{name}: {base} has no struct format (a nested struct?)")
        out.append(Member(name, int(off), code, n))
    return out


def struct_of(dtype: np.dtype, stop: str | None = None) -> struct.Struct:
    """The ``struct.Struct`` of a packed layout (every member in order; an array member gives
    ``array_len`` values): one ``pack``/``unpack`` for a whole record instead of numpy field by field.
    With ``stop``: only the members before that one (e.g. PLC_AXIS_RECORD's head before its PlcToNc).

    Raises:
        ValueError: the layout has gaps or a nested struct (before ``stop``).
    """
    fmt, end = "<", 0
    for m in members(dtype, stop):
        if m.offset != end:
            raise ValueError(f"{m.name}: not a packed layout (gap before offset {m.offset})")
        fmt += m.fmt
        end = m.offset + struct.calcsize("<" + m.fmt)
    st = struct.Struct(fmt)
    if stop is None and st.size != dtype.itemsize:
        raise ValueError(f"not a packed layout ({st.size} of {dtype.itemsize} bytes)")
    return st


def member_struct(dtype: np.dtype, name: str) -> tuple[int, struct.Struct]:
    """(offset, ``struct.Struct`` of the member's value(s)) of member ``name`` of ``dtype``: read it with
    ``st.unpack_from(buf, base + offset)``.

    Raises:
        KeyError: no such member.
    """
    for m in members(dtype):
        if m.name == name:
            return m.offset, struct.Struct("<" + m.fmt)
    raise KeyError(name)


def pick_struct(dtype: np.dtype, *names: str) -> struct.Struct:
    """A struct that reads only the scalar members ``names`` of one ``dtype`` record (``unpack(raw)``: their values
    in this order, the bytes between and after them skipped): the per-cycle paths read a few members without
    unpacking the whole record.

    Raises:
        KeyError: a name is not a member of ``dtype``.
        ValueError: ``names`` not in the record's order (or overlapping), or one is not a scalar.
    """
    assert dtype.fields is not None
    fmt, pos = "<", 0
    for name in names:
        fdt, off = dtype.fields[name][:2]
        code = _CODES.get((fdt.kind, fdt.itemsize)) if fdt.names is None and fdt.subdtype is None else None
        if code is None or off < pos:
            raise ValueError(f"pick_struct: {name!r} is out of order or not a scalar")
        fmt += (f"{off - pos}x" if off > pos else "") + code
        pos = off + fdt.itemsize
    return struct.Struct(fmt + (f"{dtype.itemsize - pos}x" if dtype.itemsize > pos else ""))


def _flat_codes(dt: np.dtype) -> str:
    """The struct codes of one value of ``dt``, nested structs and arrays of them flattened in order."""
    if dt.subdtype is not None:
        base, shape = dt.subdtype
        return _flat_codes(base) * int(np.prod(shape))
    if dt.names is None or dt.fields is None:
        code = _CODES.get((dt.kind, dt.itemsize))
        if code is None:
            raise ValueError(f"{dt} has no struct format")
        return code
    out, end = "", 0
    for name in dt.names:
        fdt, off = dt.fields[name][:2]
        if off != end:
            raise ValueError(f"{name}: not a packed layout (gap before offset {off})")
        out += _flat_codes(fdt)
        end = off + fdt.itemsize
    return out


def flat_struct(dtype: np.dtype, start: str | None = None, stop: str | None = None) -> struct.Struct:
    """The ``struct.Struct`` of the members of ``dtype`` from ``start`` (included; None: the first) to ``stop``
    (excluded; None: the end), nested structs flattened: one ``pack`` writes that span of a record, e.g.
    NCJOBS_AXIS_REF's queue part with its ``Ended`` array of (CmdNo, CmdState, ErrorId).

    Raises:
        ValueError: the span has gaps, or a member has no struct format.
        KeyError: ``start`` or ``stop`` is no member.
    """
    assert dtype.names is not None and dtype.fields is not None
    names = list(dtype.names)
    i = 0 if start is None else names.index(start) if start in names else -1
    j = len(names) if stop is None else names.index(stop) if stop in names else -1
    if i < 0 or j < 0:
        raise KeyError(start if i < 0 else stop)
    fmt, end = "<", None
    for name in names[i:j]:
        fdt, off = dtype.fields[name][:2]
        if end is not None and off != end:
            raise ValueError(f"{name}: not a packed layout (gap before offset {off})")
        fmt += _flat_codes(fdt)
        end = off + fdt.itemsize
    return struct.Struct(fmt)


def decode(struct_name: str, data: bytes | bytearray | memoryview) -> np.void:
    """Decode exactly one record of ``struct_name``.

    Raises:
        ValueError: the buffer's length is not the struct's size.
    """
    dt = DTYPES[struct_name]
    if len(data) != dt.itemsize:
        raise ValueError(f"{struct_name} is {dt.itemsize} bytes, got {len(data)}")
    rec: np.void = np.frombuffer(data, dtype=dt, count=1)[0]
    return rec


def to_dict(record: np.void | np.ndarray) -> dict[str, Any]:
    """One struct record as a plain dict (hidden/reserved members left out)."""
    out: dict[str, Any] = {}
    assert record.dtype.names is not None
    for name in record.dtype.names:
        if name.startswith("_"):
            continue
        v = record[name]
        if isinstance(v, np.void):
            out[name] = to_dict(v)
        elif isinstance(v, np.ndarray):
            out[name] = v.tolist()
        else:
            out[name] = v.item()
    return out
