"""The frame codec: the NC's status frame, the PLC clients' PLCTONC frame and the per-axis STAMP.

Owns the frames' magic numbers and wire version, their header ``struct.Struct``s (built by
:func:`nc_schema.layout.struct_of` from ``structs.json``: no offset or format is written by hand), and the
one encoder and one decoder of each frame. Every producer and consumer (the NC's cycle and frame ring,
its publisher and transport, the PLC runtime, nc-ads, the tools) calls these; they run every cycle, so
they pack and check with one ``struct`` call and make numpy views only where a caller wants records.
Imports :mod:`nc_schema.layout`, :mod:`nc_schema.generated` and numpy.
"""
from __future__ import annotations

from typing import Any, NamedTuple, Sequence, Union

import numpy as np

from .generated import FrameFlags
from .layout import (
    FRAME_HEADER_DTYPE, FRAME_HEADER_SIZE, NCJOBS_DTYPE, NCJOBS_SIZE, NCTOPLC_DTYPE, NCTOPLC_SIZE,
    PLC_AXIS_RECORD_DTYPE, PLC_AXIS_RECORD_SIZE, PLC_FRAME_HEADER_DTYPE, PLC_FRAME_HEADER_SIZE, PLCTONC_SIZE,
    STAMP_DTYPE, STAMP_SIZE, member_struct, struct_of,
)

__all__ = [
    "FRAME_MAGIC", "PLC_FRAME_MAGIC", "WIRE_VERSION", "JOB_RECORDS", "FRAME_HEADER_STRUCT", "PLC_FRAME_HEADER_STRUCT",
    "PLC_AXIS_HEAD_STRUCT", "STAMP_STRUCT", "FrameHeader", "encode_frame", "pack_frame_header_into",
    "frame_header", "frame_stamp", "frame_epoch", "decode_frame", "frame_records", "encode_plc_records",
    "encode_plc_frame", "decode_plc_frame", "view_frame",
    "encode_stamp", "decode_stamp", "decode_stamp_epoch",
]

FRAME_MAGIC = 0x314E435A  # b"ZCN1"
PLC_FRAME_MAGIC = 0x31435050  # b"PPC1"
WIRE_VERSION = 1

#: FRAME_HEADER: Magic, Version, HeaderSize, Cycle, NcTimeNs, AxisCount, RecordSize, Flags, Epoch (protocol 5)
FRAME_HEADER_STRUCT = struct_of(FRAME_HEADER_DTYPE)
#: the header of an NC before protocol 5 (HeaderSize 32): everything before Epoch; its frames are read with Epoch 0
_HEADER_V4_STRUCT = struct_of(FRAME_HEADER_DTYPE, stop="Epoch")
FRAME_HEADER_V4_SIZE = _HEADER_V4_STRUCT.size
#: PLC_FRAME_HEADER: Magic, Version, HeaderSize, PlcCycle, AxisCount, RecordSize, _reserved
PLC_FRAME_HEADER_STRUCT = struct_of(PLC_FRAME_HEADER_DTYPE)
#: PLC_AXIS_RECORD before its PlcToNc: AxisId, _reserved
PLC_AXIS_HEAD_STRUCT = struct_of(PLC_AXIS_RECORD_DTYPE, stop="PlcToNc")
STAMP_STRUCT = struct_of(STAMP_DTYPE)
#: a STAMP before protocol 5 (Cycle, NcTimeNs: 16 bytes), read with Epoch 0
_STAMP_V4_STRUCT = struct_of(STAMP_DTYPE, stop="Epoch")
STAMP_V4_SIZE = _STAMP_V4_STRUCT.size
assert PLC_AXIS_HEAD_STRUCT.size + PLCTONC_SIZE == PLC_AXIS_RECORD_SIZE

#: a record's bytes: anything ``bytes.join`` takes (a one-record numpy array too)
_Buffer = Union[bytes, bytearray, memoryview, np.ndarray]
#: FRAME_FLAGS.JobRecords (a plain int: the flag test runs every frame)
JOB_RECORDS = int(FrameFlags.JobRecords)
_AXIS_ID_OFFSET, _axis_id = member_struct(NCTOPLC_DTYPE, "AxisId")
_AXIS_ID_UNPACK = _axis_id.unpack_from
_EPOCH_OFFSET, _epoch = member_struct(FRAME_HEADER_DTYPE, "Epoch")
_EPOCH_UNPACK = _epoch.unpack_from
_HEADER_SIZE_OFFSET, _header_size = member_struct(FRAME_HEADER_DTYPE, "HeaderSize")
_HEADER_SIZE_UNPACK = _header_size.unpack_from


class FrameHeader(NamedTuple):
    """A status frame's FRAME_HEADER as plain ints (field names and order: structs.json, checked below)."""

    Magic: int
    Version: int
    HeaderSize: int
    Cycle: int
    NcTimeNs: int
    AxisCount: int
    RecordSize: int
    Flags: int
    Epoch: int

    @property
    def job_records(self) -> bool:
        """Flag JobRecords: an NCJOBS_AXIS_REF per axis follows the NCTOPLC records."""
        return bool(self.Flags & JOB_RECORDS)

    def record_offset(self, i: int) -> int:
        """Where the ``i``-th NCTOPLC record starts in the frame."""
        return self.HeaderSize + i * self.RecordSize


assert FrameHeader._fields == FRAME_HEADER_DTYPE.names, "FrameHeader must follow structs.json FRAME_HEADER"


# ---- the NC's status frame --------------------------------------------------------------------------------
def pack_frame_header_into(buf: bytearray | memoryview, offset: int, cycle: int, nc_time_ns: int, axis_count: int,
                           flags: int = 0, job_records: bool = False, epoch: int = 0) -> int:
    """Write a FRAME_HEADER at ``buf[offset:]`` (flag JobRecords set or cleared by ``job_records``; ``epoch``: the
    NC's, 0 without redundancy); its size."""
    fl = (flags | JOB_RECORDS) if job_records else (flags & ~JOB_RECORDS)
    FRAME_HEADER_STRUCT.pack_into(buf, offset, FRAME_MAGIC, WIRE_VERSION, FRAME_HEADER_SIZE, cycle, nc_time_ns,
                                  axis_count, NCTOPLC_SIZE, fl, epoch)
    return FRAME_HEADER_SIZE


def encode_frame(cycle: int, nc_time_ns: int, records: np.ndarray, flags: int = 0,
                 jobs: np.ndarray | None = None, epoch: int = 0) -> bytes:
    """Batched NC status frame: FRAME_HEADER (``epoch``: the NC's, 0 without redundancy), the NCTOPLC records,
    then (with ``jobs``, flag JobRecords) one NCJOBS_AXIS_REF per axis in the same order."""
    if jobs is None:
        return FRAME_HEADER_STRUCT.pack(FRAME_MAGIC, WIRE_VERSION, FRAME_HEADER_SIZE, cycle, nc_time_ns,
                                        len(records), NCTOPLC_SIZE, flags & ~JOB_RECORDS, epoch) + records.tobytes()
    return b"".join((FRAME_HEADER_STRUCT.pack(FRAME_MAGIC, WIRE_VERSION, FRAME_HEADER_SIZE, cycle, nc_time_ns,
                                              len(records), NCTOPLC_SIZE, flags | JOB_RECORDS, epoch),
                     records.tobytes(), jobs.tobytes()))


def view_frame(frame: bytes | memoryview, axis_count: int, rows: Sequence[int]) -> bytes:
    """The frame of ``rows`` only (a client's view, protocol.json ``view``) cut from an encoded frame of
    ``axis_count`` axes written by this process (:func:`encode_frame`'s layout; unchecked): the same header
    with AxisCount = ``len(rows)``, those rows' NCTOPLC records, then their NCJOBS records if the frame has
    them. Byte slices and one join: no numpy, no decode."""
    _, _, header_size, cycle, nc_time_ns, _, _, flags, epoch = FRAME_HEADER_STRUCT.unpack_from(frame)
    parts: list[bytes | memoryview] = [FRAME_HEADER_STRUCT.pack(FRAME_MAGIC, WIRE_VERSION, FRAME_HEADER_SIZE, cycle,
                                                                 nc_time_ns, len(rows), NCTOPLC_SIZE, flags, epoch)]
    parts += [frame[o:o + NCTOPLC_SIZE] for o in (header_size + r * NCTOPLC_SIZE for r in rows)]
    if flags & JOB_RECORDS:
        jobs = header_size + axis_count * NCTOPLC_SIZE
        parts += [frame[o:o + NCJOBS_SIZE] for o in (jobs + r * NCJOBS_SIZE for r in rows)]
    return b"".join(parts)


def frame_stamp(frame: bytes | bytearray | memoryview) -> tuple[int, int, int]:
    """(Cycle, NcTimeNs, Flags) of a frame's header, unchecked (for frames this process wrote itself)."""
    _, _, _, cycle, nc_time_ns, _, _, flags, _ = FRAME_HEADER_STRUCT.unpack_from(frame)
    return cycle, nc_time_ns, flags


def frame_epoch(frame: bytes | bytearray | memoryview) -> int:
    """The Epoch of a frame's header, unchecked (for frames this process wrote itself: protocol 5's layout)."""
    return int(_EPOCH_UNPACK(frame, _EPOCH_OFFSET)[0])


_Header = tuple[int, int, int, int, int, int, int, int, int]


def frame_header_values(data: bytes | bytearray | memoryview) -> _Header:
    """The FRAME_HEADER values of a status frame, checked as :func:`frame_header` does, as a plain tuple in the
    order of ``FrameHeader._fields`` (no namedtuple made: this runs for every frame a client takes). A frame of an
    NC before protocol 5 (HeaderSize 32, no Epoch) gives Epoch 0.

    Raises:
        ValueError: not a status frame of this protocol, or its sizes do not add up.
    """
    size = len(data)
    if size >= FRAME_HEADER_SIZE and _HEADER_SIZE_UNPACK(data, _HEADER_SIZE_OFFSET)[0] >= FRAME_HEADER_SIZE:
        v: _Header = FRAME_HEADER_STRUCT.unpack_from(data)
    elif size >= FRAME_HEADER_V4_SIZE:
        v = (*_HEADER_V4_STRUCT.unpack_from(data), 0)
    else:
        raise ValueError("status frame shorter than its header")
    magic, version, header_size, _, _, n, record_size, flags, _ = v
    if magic != FRAME_MAGIC or version != WIRE_VERSION:
        raise ValueError(f"not a zenoh-nc v{WIRE_VERSION} status frame")
    per_axis = NCTOPLC_SIZE + NCJOBS_SIZE if flags & JOB_RECORDS else NCTOPLC_SIZE
    if record_size != NCTOPLC_SIZE or header_size < FRAME_HEADER_V4_SIZE or size != header_size + n * per_axis:
        raise ValueError("status frame sizes do not add up")
    return v


_checked_header = frame_header_values


def frame_header(data: bytes | bytearray | memoryview) -> FrameHeader:
    """The checked header of a status frame: magic, version, and the sizes add up to ``len(data)``.

    Raises:
        ValueError: shorter than a header, wrong magic or version, sizes that do not add up.
    """
    return FrameHeader._make(_checked_header(data))


def decode_frame(data: bytes) -> tuple[np.void, np.ndarray, np.ndarray | None]:
    """Split a status frame into (header, NCTOPLC records, NCJOBS records or None): numpy views of ``data``.

    Raises:
        ValueError: wrong magic, version or sizes (:func:`frame_header`).
    """
    v = _checked_header(data)
    _, _, header_size, _, _, n, _, flags, _ = v
    if header_size >= FRAME_HEADER_SIZE:
        hdr: np.void = np.frombuffer(data, dtype=FRAME_HEADER_DTYPE, count=1)[0]
    else:  # an NC before protocol 5: its 32-byte header, Epoch 0
        hdr = np.array([v], dtype=FRAME_HEADER_DTYPE)[0]
    recs = np.frombuffer(data, dtype=NCTOPLC_DTYPE, count=n, offset=header_size)
    if not flags & JOB_RECORDS:
        return hdr, recs, None
    return hdr, recs, np.frombuffer(data, dtype=NCJOBS_DTYPE, count=n, offset=header_size + n * NCTOPLC_SIZE)


def frame_records(data: bytes) -> tuple[FrameHeader, dict[int, bytes]]:
    """A status frame's header and its NCTOPLC records as ``bytes`` by AxisId (no numpy: for clients that
    keep a record's bytes, e.g. nc-ads).

    Raises:
        ValueError: wrong magic, version or sizes (:func:`frame_header`).
    """
    v = _checked_header(data)
    header_size, n = v[2], v[5]
    unpack_id = _AXIS_ID_UNPACK
    recs: dict[int, bytes] = {}
    for o in range(header_size, header_size + n * NCTOPLC_SIZE, NCTOPLC_SIZE):
        recs[unpack_id(data, o + _AXIS_ID_OFFSET)[0]] = data[o:o + NCTOPLC_SIZE]
    return FrameHeader._make(v), recs


# ---- a PLC client's PLCTONC frame ---------------------------------------------------------------------------
def encode_plc_records(plc_cycle: int, records: Sequence[tuple[int, _Buffer]]) -> bytes:
    """The PLC frame encoder: PLC_FRAME_HEADER, then per ``(AxisId, PLCTONC)`` of ``records`` a
    PLC_AXIS_RECORD. A PLCTONC is any 128-byte buffer (``bytes``, a ``bytearray``, a one-record numpy
    array): no numpy concatenation, under a microsecond for a PLC cycle's axes (the PLC runtime and nc-ads
    call it every cycle; not checked here: the NC's :func:`decode_plc_frame` refuses a frame whose sizes do
    not add up).
    """
    parts: list[Any] = [PLC_FRAME_HEADER_STRUCT.pack(PLC_FRAME_MAGIC, WIRE_VERSION, PLC_FRAME_HEADER_SIZE,
                                                         plc_cycle, len(records), PLC_AXIS_RECORD_SIZE, 0)]
    heads = _AXIS_HEADS
    for axis_id, rec in records:  # (parts.append bound to a local measured slower)
        parts.append(heads.get(axis_id) or _axis_head(axis_id))
        parts.append(rec)
    return b"".join(parts)


#: AxisId -> its PLC_AXIS_RECORD head (AxisId, _reserved): the same 8 bytes every cycle, a look-up is
#: cheaper than packing them
_AXIS_HEADS: dict[int, bytes] = {}


def _axis_head(axis_id: int) -> bytes:
    if len(_AXIS_HEADS) >= 4096:  # (a bound: ids are few in practice, any value is allowed)
        _AXIS_HEADS.clear()
    head = _AXIS_HEADS[int(axis_id)] = PLC_AXIS_HEAD_STRUCT.pack(axis_id, 0)
    return head


def encode_plc_frame(plc_cycle: int, axis_ids: Sequence[int] | np.ndarray, plctonc: np.ndarray) -> bytes:
    """:func:`encode_plc_records` of ``axis_ids`` and a PLCTONC_AXIS_REF array (one record per id).

    Raises:
        ValueError: not one PLCTONC record per axis id.
    """
    if len(plctonc) != len(axis_ids):
        raise ValueError(f"PLC frame: {len(axis_ids)} axis ids, {len(plctonc)} PLCTONC records")
    raw = plctonc.tobytes()
    return encode_plc_records(plc_cycle, [(a, raw[k * PLCTONC_SIZE:(k + 1) * PLCTONC_SIZE])
                                          for k, a in enumerate(axis_ids)])


def decode_plc_frame(data: bytes) -> tuple[np.void, np.ndarray]:
    """Split a PLC frame into (header, PLC_AXIS_RECORD records).

    Raises:
        ValueError: wrong magic, version or sizes.
    """
    if len(data) < PLC_FRAME_HEADER_SIZE:
        raise ValueError("PLC frame shorter than its header")
    magic, version, hsize, _, n, rs, _ = PLC_FRAME_HEADER_STRUCT.unpack_from(data)
    if magic != PLC_FRAME_MAGIC or version != WIRE_VERSION:
        raise ValueError(f"not a zenoh-nc v{WIRE_VERSION} PLC frame")
    if rs != PLC_AXIS_RECORD_SIZE or hsize < PLC_FRAME_HEADER_SIZE or len(data) != hsize + n * rs:
        raise ValueError("PLC frame sizes do not add up")  # (a HeaderSize below the header: records over it)
    hdr: np.void = np.frombuffer(data, dtype=PLC_FRAME_HEADER_DTYPE, count=1)[0]
    return hdr, np.frombuffer(data, dtype=PLC_AXIS_RECORD_DTYPE, count=n, offset=hsize)


# ---- the per-axis samples' attachment ----------------------------------------------------------------------
def encode_stamp(cycle: int, nc_time_ns: int, epoch: int = 0) -> bytes:
    """The 24-byte STAMP attachment of per-axis samples (``epoch``: the NC's, 0 without redundancy)."""
    return STAMP_STRUCT.pack(cycle, nc_time_ns, epoch)


def decode_stamp_epoch(data: bytes | bytearray | memoryview) -> tuple[int, int, int]:
    """(cycle, nc_time_ns, epoch) from a per-axis sample's attachment; a 16-byte STAMP of an NC before protocol 5
    gives epoch 0.

    Raises:
        ValueError: neither 24 nor 16 bytes.
    """
    if len(data) == STAMP_SIZE:
        cycle, nc_time_ns, epoch = STAMP_STRUCT.unpack(data)
        return cycle, nc_time_ns, epoch
    if len(data) == STAMP_V4_SIZE:
        cycle, nc_time_ns = _STAMP_V4_STRUCT.unpack(data)
        return cycle, nc_time_ns, 0
    raise ValueError(f"STAMP is {STAMP_SIZE} bytes ({STAMP_V4_SIZE} before protocol 5), got {len(data)}")


def decode_stamp(data: bytes | bytearray | memoryview) -> tuple[int, int]:
    """(cycle, nc_time_ns) from a per-axis sample's attachment (:func:`decode_stamp_epoch` without the epoch).

    Raises:
        ValueError: neither 24 nor 16 bytes.
    """
    cycle, nc_time_ns, _ = decode_stamp_epoch(data)
    return cycle, nc_time_ns
