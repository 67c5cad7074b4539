"""numpy dtypes and bit/enum helpers built from the JSON wire contract.

Everything here is generated at import time from ``structs.json``, ``bits.json``
and ``enums.json``; nothing about a layout is written down twice.
"""
from __future__ import annotations

import json
import struct
from enum import IntEnum, IntFlag
from importlib import resources
from importlib.resources.abc import Traversable
from pathlib import Path
from typing import Any

import numpy as np

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
    return json.loads(CONTRACT_DIR.joinpath(name).read_text(encoding="utf-8"))


STRUCTS: dict[str, Any] = load_json("structs.json")["structs"]
BITSETS: dict[str, dict[str, str]] = load_json("bits.json")["bitsets"]
ENUMS: dict[str, Any] = load_json("enums.json")["enums"]


def _build_dtype(name: str, built: dict[str, np.dtype]) -> np.dtype:
    if name in built:
        return built[name]
    spec = STRUCTS[name]
    names, formats, offsets = [], [], []
    for f in spec["fields"]:
        t = f["type"]
        base = _build_dtype(t, built) if t in STRUCTS else np.dtype(_TYPES[t])
        fmt = (base, (f["count"],)) if "count" in f else base
        names.append(f["name"])
        formats.append(fmt)
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

FRAME_MAGIC = 0x314E435A  # b"ZCN1"
PLC_FRAME_MAGIC = 0x31435050  # b"PPC1"
WIRE_VERSION = 1


def _flag(name: str) -> type[IntFlag]:
    members = {v: 1 << int(k) for k, v in BITSETS[name].items()}
    return IntFlag(name, members)  # type: ignore[return-value]


def _enum(name: str) -> type[IntEnum]:
    return IntEnum(name, ENUMS[name]["values"])  # type: ignore[return-value]


StateDWord = _flag("NCTOPLC_AXIS_REF_STATE")
StateDWord2 = _flag("NCTOPLC_AXIS_REF_STATE2")
StateDWord3 = _flag("NCTOPLC_AXIS_REF_STATE3")
OpModeDWord = _flag("NCTOPLC_AXIS_REF_OPMODE")
CamCouplingState = _flag("NCTOPLC_AXIS_REF_CAMCOUPLINGSTATE")
ControlDWord = _flag("PLCTONC_AXIS_REF_CTRL")
FrameFlags = _flag("FRAME_FLAGS")

AxisState = _enum("AxisState")
HomingState = _enum("HomingState")
CoupleState = _enum("CoupleState")
CmdState = _enum("CmdState")
MC_AxisStates = _enum("MC_AxisStates")
MC_Direction = _enum("MC_Direction")
MC_BufferMode = _enum("MC_BufferMode")
MC_HomingMode = _enum("MC_HomingMode")
E_StartPosType = _enum("E_StartPosType")
E_JogMode = _enum("E_JogMode")
E_CmdTypeNewTargPosAndVelo = _enum("E_CmdTypeNewTargPosAndVelo")
E_DecoupleMode = _enum("E_DecoupleMode")
E_SuperpositionMode = _enum("E_SuperpositionMode")
E_TouchProbe = _enum("E_TouchProbe")
E_SignalEdge = _enum("E_SignalEdge")
E_TouchProbeState = _enum("E_TouchProbeState")
E_TargPosType = _enum("E_TargPosType")
NcJobsSyncFlags = _flag("NCJOBS_SYNC_FLAGS")
#: MC_Home.Position value that selects the axis's calibration value (any Position >= it does)
DEFAULT_HOME_POSITION = 1e300
MC_AxisPara = _enum("MC_AxisPara")


def bit_names(bitset: str, value: int) -> list[str]:
    """Names of the bits set in ``value`` for bit set ``bitset`` (bits.json)."""
    return [n for k, n in BITSETS[bitset].items() if value >> int(k) & 1]


def to_dict(record: np.void | np.ndarray) -> dict[str, Any]:
    """One struct record as a plain dict (hidden/reserved members left out)."""
    out: dict[str, Any] = {}
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


def decode(struct: str, data: bytes | bytearray | memoryview) -> np.void:
    """Decode exactly one record of ``struct``.

    Raises:
        ValueError: the buffer's length is not the struct's size.
    """
    dt = DTYPES[struct]
    if len(data) != dt.itemsize:
        raise ValueError(f"{struct} is {dt.itemsize} bytes, got {len(data)}")
    return np.frombuffer(data, dtype=dt, count=1)[0]


def encode_stamp(cycle: int, nc_time_ns: int) -> bytes:
    """The 16-byte attachment of per-axis samples."""
    s = np.zeros((), dtype=STAMP_DTYPE)
    s["Cycle"] = cycle
    s["NcTimeNs"] = nc_time_ns
    return s.tobytes()


def decode_stamp(data: bytes) -> tuple[int, int]:
    """(cycle, nc_time_ns) from a per-axis sample's attachment."""
    s = decode("STAMP", data)
    return int(s["Cycle"]), int(s["NcTimeNs"])


def _struct_of(dt: np.dtype) -> struct.Struct:
    """A struct.Struct for a packed dtype of scalar fields (the frame headers): one pack per frame
    instead of filling a numpy record field by field (the NC does this every cycle)."""
    codes = {("u", 1): "B", ("u", 2): "H", ("u", 4): "I", ("u", 8): "Q", ("i", 4): "i", ("f", 8): "d"}
    fmt, end = "<", 0
    for name in dt.names:
        fdt, off = dt.fields[name][:2]
        if off != end or fdt.shape:
            raise ValueError(f"{name}: not a packed scalar layout")
        fmt += codes[(fdt.kind, fdt.itemsize)]
        end = off + fdt.itemsize
    st = struct.Struct(fmt)
    assert st.size == dt.itemsize
    return st


_FRAME_HEADER = _struct_of(FRAME_HEADER_DTYPE)


_JOB_RECORDS = 2  # FRAME_FLAGS.JobRecords


def encode_frame(cycle: int, nc_time_ns: int, records: np.ndarray, flags: int = 0,
                 jobs: np.ndarray | None = None) -> bytes:
    """Batched NC status frame: FRAME_HEADER, the NCTOPLC records, then (with ``jobs``, flag
    JobRecords) one NCJOBS_AXIS_REF per axis in the same order."""
    if jobs is None:
        return _FRAME_HEADER.pack(FRAME_MAGIC, WIRE_VERSION, FRAME_HEADER_DTYPE.itemsize, cycle, nc_time_ns,
                                  len(records), NCTOPLC_DTYPE.itemsize, flags & ~_JOB_RECORDS) + records.tobytes()
    return b"".join((_FRAME_HEADER.pack(FRAME_MAGIC, WIRE_VERSION, FRAME_HEADER_DTYPE.itemsize, cycle, nc_time_ns,
                                        len(records), NCTOPLC_DTYPE.itemsize, flags | _JOB_RECORDS),
                     records.tobytes(), jobs.tobytes()))


def _split_frame(data: bytes, header: np.dtype, magic: int, record: np.dtype, what: str,
                 extra: int = 0) -> tuple[np.void, np.ndarray]:
    """Check a frame's header (magic, version, sizes) and view its records (``extra``: bytes per
    record that follow all records, e.g. the job records)."""
    if len(data) < header.itemsize:
        raise ValueError(f"{what} shorter than its header")
    h = np.frombuffer(data, dtype=header, count=1)[0]
    if int(h["Magic"]) != magic or int(h["Version"]) != WIRE_VERSION:
        raise ValueError(f"not a zenoh-nc v{WIRE_VERSION} {what}")
    n, rs = int(h["AxisCount"]), int(h["RecordSize"])
    if rs != record.itemsize or len(data) != int(h["HeaderSize"]) + n * (rs + extra):
        raise ValueError(f"{what} sizes do not add up")
    return h, np.frombuffer(data, dtype=record, count=n, offset=int(h["HeaderSize"]))


def decode_frame(data: bytes) -> tuple[np.void, np.ndarray, np.ndarray | None]:
    """Split a status frame into (header, NCTOPLC records, NCJOBS records or None).

    Raises:
        ValueError: wrong magic, version or sizes.
    """
    if len(data) >= FRAME_HEADER_DTYPE.itemsize:
        flags = int(np.frombuffer(data, dtype=FRAME_HEADER_DTYPE, count=1)[0]["Flags"])
    else:
        flags = 0
    if not flags & _JOB_RECORDS:
        h, recs = _split_frame(data, FRAME_HEADER_DTYPE, FRAME_MAGIC, NCTOPLC_DTYPE, "status frame")
        return h, recs, None
    h, recs = _split_frame(data, FRAME_HEADER_DTYPE, FRAME_MAGIC, NCTOPLC_DTYPE, "status frame", NCJOBS_DTYPE.itemsize)
    off = int(h["HeaderSize"]) + len(recs) * NCTOPLC_DTYPE.itemsize
    return h, recs, np.frombuffer(data, dtype=NCJOBS_DTYPE, count=len(recs), offset=off)


def encode_plc_frame(plc_cycle: int, axis_ids: list[int] | np.ndarray, plctonc: np.ndarray) -> bytes:
    """PLC runtime frame: PLC_FRAME_HEADER followed by (AxisId, PLCTONC) records."""
    n = len(axis_ids)
    h = np.zeros((), dtype=PLC_FRAME_HEADER_DTYPE)
    h["Magic"] = PLC_FRAME_MAGIC
    h["Version"] = WIRE_VERSION
    h["HeaderSize"] = PLC_FRAME_HEADER_DTYPE.itemsize
    h["PlcCycle"] = plc_cycle
    h["AxisCount"] = n
    h["RecordSize"] = PLC_AXIS_RECORD_DTYPE.itemsize
    recs = np.zeros(n, dtype=PLC_AXIS_RECORD_DTYPE)
    recs["AxisId"] = axis_ids
    recs["PlcToNc"] = plctonc
    return h.tobytes() + recs.tobytes()


def decode_plc_frame(data: bytes) -> tuple[np.void, np.ndarray]:
    """Split a PLC frame into (header, PLC_AXIS_RECORD records).

    Raises:
        ValueError: wrong magic, version or sizes.
    """
    return _split_frame(data, PLC_FRAME_HEADER_DTYPE, PLC_FRAME_MAGIC, PLC_AXIS_RECORD_DTYPE, "PLC frame")
