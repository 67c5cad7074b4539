"""The axis parameter table (``schema/params.json``) and its byte codecs.

``PARAMETERS`` holds one :class:`ParamEntry` per MC_AxisPara number of the TcMC manual 6.1 (numbers,
TwinCAT names, types, units, when they can be written, ranges, ADS addresses, the ST_AxisParameterSet
member). The NC's ReadParameter/WriteParameter, the blocks, the ADS door and docs/parameters.md all
use it; nothing about a parameter is written down twice.

Byte codecs (little-endian, as everything on ADS and in the PLC image):

* :func:`pack_value` / :func:`unpack_value`: one value of a PLC type (LREAL, BOOL, UDINT, DINT, UINT, WORD,
  DWORD, USINT, STRING(n));
* :func:`encode_ads` / :func:`decode_ads`: one parameter in the data type of its ADS address (REAL64,
  UINT32, UINT16);
* :func:`encode_parameter_set` / :func:`decode_parameter_set`: the 1024-byte ST_AxisParameterSet;
  :func:`encode_axis_components` / :func:`decode_axis_components`: the 108-byte ST_AxisComponents.
"""
from __future__ import annotations

import math
import struct
from dataclasses import dataclass
from typing import Any, Iterator, Mapping

# the parameter blocks' enums, generated from params.json / enums.json (re-exported: nc_schema.params.E_ReadMode, ...)
from .generated import E_DestallDetectMode as E_DestallDetectMode
from .generated import E_DestallMode as E_DestallMode
from .generated import E_NcAxisType as E_NcAxisType
from .generated import E_NcDriveType as E_NcDriveType
from .generated import E_NcEncoderType as E_NcEncoderType
from .generated import E_ReadMode as E_ReadMode
from .generated import (  # noqa: F401
    E_DestallDetectMode, E_DestallMode, E_NcAxisType, E_NcDriveType, E_NcEncoderType, E_ReadMode,
)
from .layout import load_json

_DATA: dict[str, Any] = load_json("params.json")
#: params.json ``stepper_terminal``: the stepper terminal's status bits and limits (MC_PowerStepper reads them)
STEPPER_TERMINAL: dict[str, Any] = _DATA["stepper_terminal"]

#: ADS groups of a parameter: the axis object and its sub-objects (Tc2_MC2 index offset prefixes)
ADS_GROUPS = ("axis", "encoder", "controller", "drive")
#: Tc2_MC2 writes a sub-object's offset as 0x000g_oooo inside the axis index group 0x4000+ID
ADS_GROUP_PREFIX = {"axis": 0x0000_0000, "encoder": 0x0001_0000, "controller": 0x0002_0000, "drive": 0x0003_0000}
#: the byte format of each ADS data type of the table
ADS_FORMATS = {"REAL64": "<d", "UINT32": "<I", "UINT16": "<H"}


@dataclass(frozen=True)
class AdsAddress:
    """Where TwinCAT serves a parameter over ADS: ``group`` (axis/encoder/controller/drive), index
    ``offset`` within that object, data ``type`` (REAL64, UINT32, UINT16)."""

    group: str
    offset: int
    type: str

    @property
    def axis_offset(self) -> int:
        """The index offset in the axis index group 0x4000+ID (Tc2_MC2 style, e.g. 0x0001_000E)."""
        return ADS_GROUP_PREFIX[self.group] | self.offset

    @property
    def size(self) -> int:
        return struct.calcsize(ADS_FORMATS[self.type])


@dataclass(frozen=True)
class ParamEntry:
    """One MC_AxisPara number (schema/params.json ``parameters``).

    Attributes:
        number: the MC_AxisPara number.
        name: the TwinCAT name (MC_AxisPara).
        type: LREAL, BOOL or UDINT (the MC_AxisPara type of TcMC 6.1).
        unit: "u" (axis unit), "u/s", "u/s^2", "u/s^3", "s", "inc", "u/inc" or "" (see the table's ``units``).
        writable: writable at run time.
        when: for writable entries: "always", "standstill" or "disabled"; else None.
        min, max: the valid range (None: unbounded); ``min_exclusive``: the value must be above min.
        source: "param" (a stored axis parameter, ``store`` names the AxisParams field), "status" (from the
            live axis state, ``status`` says what) or "fixed" (no meaning for this NC: ``fixed`` is its value).
        ads: its ADS address (None where no source gives one).
        field: the ST_AxisParameterSet member that holds it (None: not in the set).
        doc: what it is.
        code: the TwinCAT error code of a bad value of this parameter (TwinCAT's axis error list, e.g. 0x4328
            for AxisLoopingDistance); None: 0x70B.
    """

    number: int
    name: str
    type: str
    unit: str
    writable: bool
    when: str | None
    min: float | None
    max: float | None
    min_exclusive: bool
    source: str
    store: str | None
    status: str | None
    fixed: Any
    ads: AdsAddress | None
    field: str | None
    doc: str
    code: int | None = None

    @property
    def is_bool(self) -> bool:
        return self.type == "BOOL"

    def in_range(self, value: float) -> bool:
        """Whether a (finite) number lies in [min, max] (above min when ``min_exclusive``)."""
        if self.min is not None and (value <= self.min if self.min_exclusive else value < self.min):
            return False
        return self.max is None or value <= self.max

    def range_text(self) -> str:
        """The range as the docs show it, e.g. ``> 0``, ``0 .. 1e+09``, ``''`` (unbounded)."""
        lo, hi = self.min, self.max
        if lo is None and hi is None:
            return ""
        if hi is None:
            return f"> {lo:g}" if self.min_exclusive else f">= {lo:g}"
        if lo is None:
            return f"<= {hi:g}"
        return f"{lo:g} < x <= {hi:g}" if self.min_exclusive else f"{lo:g} .. {hi:g}"


def _entry(d: Mapping[str, Any]) -> ParamEntry:
    a = d.get("ads")
    ads = AdsAddress(a["group"], int(a["offset"], 16), a["type"]) if a else None
    return ParamEntry(number=int(d["number"]), name=d["name"], type=d["type"], unit=d["unit"],
                      writable=bool(d["writable"]), when=d.get("when"), min=d.get("min"), max=d.get("max"),
                      min_exclusive=bool(d.get("min_exclusive", False)), source=d["source"], store=d.get("store"),
                      status=d.get("status"), fixed=d.get("fixed"), ads=ads, field=d.get("field"), doc=d["doc"],
                      code=int(d["code"], 16) if "code" in d else None)


class ParameterTable:
    """All parameter entries, looked up by number, name or ADS address."""

    def __init__(self, entries: list[ParamEntry]) -> None:
        self.entries: tuple[ParamEntry, ...] = tuple(sorted(entries, key=lambda e: e.number))
        self._by_number = {e.number: e for e in self.entries}
        self._by_name = {e.name: e for e in self.entries}
        if len(self._by_number) != len(self.entries) or len(self._by_name) != len(self.entries):
            raise ValueError("params.json: duplicate parameter numbers or names")
        self._by_ads: dict[tuple[str, int], ParamEntry] = {}
        for e in self.entries:
            if e.ads is None:
                continue
            key = (e.ads.group, e.ads.offset)
            # several numbers share one NC parameter (MaxVelocityAppl, AxisMaxVelocity, AxisVeloMax): the
            # address belongs to the one with the ST_AxisParameterSet member, else to the highest number
            # (the Beckhoff name)
            old = self._by_ads.get(key)
            if old is None or (e.field and not old.field) or (bool(e.field) == bool(old.field) and e.number > old.number):
                self._by_ads[key] = e

    def __iter__(self) -> Iterator[ParamEntry]:
        return iter(self.entries)

    def __len__(self) -> int:
        return len(self.entries)

    def by_number(self, number: int) -> ParamEntry | None:
        """The entry of MC_AxisPara ``number``; None for a number TcMC does not define."""
        return self._by_number.get(number) if isinstance(number, int) and not isinstance(number, bool) else None

    def by_name(self, name: str) -> ParamEntry | None:
        """The entry of the MC_AxisPara name ``name`` (e.g. ``"AxisVeloMax"``); None if there is none."""
        return self._by_name.get(name)

    def ads(self, group: str, offset: int) -> ParamEntry | None:
        """The entry TwinCAT serves at ``offset`` of ``group`` (axis/encoder/controller/drive); None if none.
        Where several numbers name the same NC parameter, the Beckhoff entry is returned (AxisVeloMax for 0x27)."""
        return self._by_ads.get((group, int(offset)))

    def ads_axis_offset(self, offset: int) -> ParamEntry | None:
        """The entry at a Tc2_MC2-style index offset of the axis group 0x4000+ID (0x0001_000E: encoder 0x0E)."""
        for g, prefix in ADS_GROUP_PREFIX.items():
            if offset & 0xFFFF_0000 == prefix:
                return self.ads(g, offset & 0xFFFF)
        return None

    def stores(self) -> dict[str, list[ParamEntry]]:
        """AxisParams field -> the entries that read/write it."""
        out: dict[str, list[ParamEntry]] = {}
        for e in self.entries:
            if e.store:
                out.setdefault(e.store, []).append(e)
        return out


PARAMETERS = ParameterTable([_entry(d) for d in _DATA["parameters"]])
PARAMS_DOC: dict[str, str] = dict(_DATA["doc"])
UNITS: dict[str, str] = dict(_DATA["units"])


# ---- values ----------------------------------------------------------------------------------------------------
_PLC_FORMATS = {"LREAL": "<d", "BOOL": "<B", "UDINT": "<I", "DWORD": "<I", "DINT": "<i", "UINT": "<H", "WORD": "<H",
                "USINT": "<B", "BYTE": "<B", "INT": "<h", "E_NcAxisType": "<I", "E_NcEncoderType": "<I",
                "E_NcDriveType": "<I"}


def _string_size(type_: str) -> int | None:
    """Bytes of a STRING(n) (n + 1) or T_AmsNetId (STRING(23)); None for other types."""
    if type_ == "T_AmsNetId":
        return 24
    if type_.startswith("STRING(") and type_.endswith(")"):
        return int(type_[7:-1]) + 1
    return None


def type_size(type_: str) -> int:
    """Bytes of one value of PLC type ``type_``.

    Raises:
        KeyError: an unknown type.
    """
    n = _string_size(type_)
    return n if n is not None else struct.calcsize(_PLC_FORMATS[type_])


def pack_value(type_: str, value: Any) -> bytes:
    """One value as the PLC stores it (little-endian; STRING(n): n + 1 bytes, zero padded, truncated to n).

    Raises:
        ValueError: a value the type cannot hold (out of range, not finite for LREAL is allowed: IEEE 754).
        KeyError: an unknown type.
    """
    n = _string_size(type_)
    if n is not None:
        raw = str(value).encode("latin-1", "replace")[: n - 1]
        return raw + b"\0" * (n - len(raw))
    fmt = _PLC_FORMATS[type_]
    if type_ == "LREAL":
        return struct.pack(fmt, float(value))
    if type_ == "BOOL":
        return struct.pack(fmt, 1 if value else 0)
    try:
        return struct.pack(fmt, int(value))
    except struct.error as exc:
        raise ValueError(f"{value!r} does not fit a {type_}: {exc}") from None


def unpack_value(type_: str, data: bytes | bytearray | memoryview) -> Any:
    """The value of :func:`pack_value`'s bytes (BOOL: any non-zero byte is TRUE; STRING: up to the first NUL).

    Raises:
        ValueError: ``data`` is not exactly the type's size.
    """
    data = bytes(data)
    size = type_size(type_)
    if len(data) != size:
        raise ValueError(f"{type_} is {size} bytes, got {len(data)}")
    if _string_size(type_) is not None:
        return data.split(b"\0", 1)[0].decode("latin-1")
    v = struct.unpack(_PLC_FORMATS[type_], data)[0]
    return bool(v) if type_ == "BOOL" else v


def to_lreal(entry: ParamEntry, value: Any) -> float | bool:
    """A parameter value as ReadParameter carries it: a bool for BOOL entries, else a float."""
    return bool(value) if entry.is_bool else float(value)


def encode_ads(entry: ParamEntry, value: Any) -> bytes:
    """``value`` in the ADS data type of ``entry`` (REAL64 double, UINT32, UINT16 0/1 for booleans).

    Raises:
        ValueError: the entry has no ADS address, or the value does not fit (negative/too large for UINTs,
            not finite for integers).
    """
    if entry.ads is None:
        raise ValueError(f"{entry.name} has no ADS address")
    fmt = ADS_FORMATS[entry.ads.type]
    if entry.ads.type == "REAL64":
        return struct.pack(fmt, float(value))
    if isinstance(value, float) and not math.isfinite(value):
        raise ValueError(f"{entry.name}: {value} is not an integer")
    try:
        return struct.pack(fmt, int(value))
    except struct.error as exc:
        raise ValueError(f"{entry.name}: {value!r} does not fit {entry.ads.type}: {exc}") from None


def decode_ads(entry: ParamEntry, data: bytes | bytearray | memoryview) -> float | bool:
    """The parameter value (as :func:`to_lreal`) of ADS bytes in ``entry``'s data type.

    Raises:
        ValueError: no ADS address, or the length is not the type's size (ADS 0x705).
    """
    if entry.ads is None:
        raise ValueError(f"{entry.name} has no ADS address")
    data = bytes(data)
    if len(data) != entry.ads.size:
        raise ValueError(f"{entry.name}: {entry.ads.type} is {entry.ads.size} bytes, got {len(data)}")
    return to_lreal(entry, struct.unpack(ADS_FORMATS[entry.ads.type], data)[0])


# ---- the structures ------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class StructField:
    """A member of ST_AxisParameterSet / ST_AxisComponents: name, PLC type, byte offset, element count,
    ADS address (``"encoder:0x0E"`` style, may be empty), where the NC's value comes from, doc."""

    name: str
    type: str
    offset: int
    count: int
    ads: str
    value: str
    doc: str

    @property
    def size(self) -> int:
        return type_size(self.type) * self.count


@dataclass(frozen=True)
class StructLayout:
    name: str
    size: int
    fields: tuple[StructField, ...]
    doc: str

    def defaults(self) -> dict[str, Any]:
        """Every member at its zero value (0, 0.0, "", or a list of zeros)."""
        out: dict[str, Any] = {}
        for f in self.fields:
            z: Any = "" if _string_size(f.type) is not None else (0.0 if f.type == "LREAL" else 0)
            out[f.name] = [z] * f.count if f.count > 1 else z
        return out

    def encode(self, values: Mapping[str, Any]) -> bytes:
        """The struct's bytes (missing members: zero; padding: zero).

        Raises:
            ValueError: a value that does not fit its member, or an unknown member name.
        """
        known = {f.name for f in self.fields}
        unknown = set(values) - known
        if unknown:
            raise ValueError(f"{self.name} has no member(s) {sorted(unknown)}")
        buf = bytearray(self.size)
        for f in self.fields:
            if f.name not in values:
                continue
            v = values[f.name]
            items = list(v) if f.count > 1 else [v]
            if len(items) != f.count:
                raise ValueError(f"{self.name}.{f.name} has {f.count} elements, got {len(items)}")
            n = type_size(f.type)
            for k, item in enumerate(items):
                buf[f.offset + k * n:f.offset + (k + 1) * n] = pack_value(f.type, item)
        return bytes(buf)

    def decode(self, data: bytes | bytearray | memoryview) -> dict[str, Any]:
        """The members of the struct's bytes.

        Raises:
            ValueError: ``data`` is not exactly the struct's size.
        """
        data = bytes(data)
        if len(data) != self.size:
            raise ValueError(f"{self.name} is {self.size} bytes, got {len(data)}")
        out: dict[str, Any] = {}
        for f in self.fields:
            n = type_size(f.type)
            items = [unpack_value(f.type, data[f.offset + k * n:f.offset + (k + 1) * n]) for k in range(f.count)]
            out[f.name] = items if f.count > 1 else items[0]
        return out


def _layout(name: str) -> StructLayout:
    s = _DATA["structs"][name]
    fields = tuple(StructField(f["name"], f["type"], int(f["offset"]), int(f.get("count", 1)), f.get("ads", ""),
                               f.get("value", ""), f.get("doc", "")) for f in s["fields"])
    return StructLayout(name, int(s["size"]), fields, s["doc"])


ST_AXIS_PARAMETER_SET = _layout("ST_AxisParameterSet")
ST_AXIS_COMPONENTS = _layout("ST_AxisComponents")


def encode_parameter_set(values: Mapping[str, Any]) -> bytes:
    """ST_AxisParameterSet's 1024 bytes from a map of its members (ReadParameterSet's reply Value)."""
    return ST_AXIS_PARAMETER_SET.encode(values)


def decode_parameter_set(data: bytes | bytearray | memoryview) -> dict[str, Any]:
    """The members of ST_AxisParameterSet's 1024 bytes."""
    return ST_AXIS_PARAMETER_SET.decode(data)


def encode_axis_components(values: Mapping[str, Any]) -> bytes:
    """ST_AxisComponents's 108 bytes from {EncoderIDs, ControllerIDs, DriveIDs} (9 ids each)."""
    return ST_AXIS_COMPONENTS.encode(values)


def decode_axis_components(data: bytes | bytearray | memoryview) -> dict[str, Any]:
    return ST_AXIS_COMPONENTS.decode(data)
