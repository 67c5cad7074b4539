"""``AXIS_REF.NcToPlc`` and ``AXIS_REF.PlcToNc``: the cyclic interface with TwinCAT's member names.

``Axis.NcToPlc.SetPos``, ``Axis.NcToPlc.StateDWord``, ``Axis.PlcToNc.Override := ...`` read (and for
PLCTONC write) the members as plain Python values: ``float`` for LREAL, ``int`` for the integer types,
a ``tuple`` for an array member (``CamCouplingState``, ``CamCouplingTableID``), so they go into JSON,
f-strings and arithmetic without ``float()``. The members are generated from the struct layouts of
``schema/structs.json`` (through ``nc_schema``'s dtypes), so they cannot drift from the wire contract;
members whose name starts with ``_`` (reserved bytes) are not exposed.

The item form ``Axis.NcToPlc["SetPos"]`` of earlier versions keeps working and returns the same plain
values (it returned numpy scalars; ``float()``/``int()`` of a plain value is the same number).

Cost (zenoh-nc choice): a PLC cycle copies each bound axis's 256 NCTOPLC bytes (one ``bytes`` object,
no numpy record); the members are unpacked together, once, at the first read in that cycle (the
axis's ``Status`` refresh reads some every cycle: one ``struct.unpack``, cheaper than the numpy field
accesses it replaces). PLCTONC members are packed into / unpacked from the record's bytes one at a
time (``struct.pack_into``), so a block writing ControlDWord every cycle touches four bytes.

Writing (PLCTONC only): the value must fit the member's type - an integer within the type's range for
DWORD/UDINT/DINT/BYTE/BOOL (a bool is accepted for BOOL and BYTE), a real number for LREAL - else
``TypeError``/``ValueError`` naming the member, and nothing is written (numpy would have truncated
5.5 to 5 or wrapped -1 to 4294967295 silently). NCTOPLC is read-only: writing raises (``ValueError``
for the item form, as the read-only numpy record did; ``AttributeError`` for an attribute).
"""
from __future__ import annotations

import struct
from typing import TYPE_CHECKING, Any, Iterator

import numpy as np

from nc_schema import (NCJOBS_DTYPE, NCTOPLC_DTYPE, PLCTONC_DTYPE, Member, load_json, member_struct, members,
                       struct_of)
from nc_schema.layout import flat_struct, pick_struct

__all__ = ["NCTOPLC_AXIS_REF", "PLCTONC_AXIS_REF"]

if TYPE_CHECKING:
    from typing import Generic, TypeVar

    _T = TypeVar("_T")

    class _Writable(Generic[_T]):
        """How the type checker sees a PLCTONC member: the property :func:`_plc_property` makes."""

        def __get__(self, obj: object, owner: type | None = None) -> _T: ...

        def __set__(self, obj: object, value: _T) -> None: ...


def _docs(struct_name: str) -> dict[str, str]:
    """Member -> a one-line doc (type, and the schema's doc where it has one)."""
    out = {}
    for f in load_json("structs.json")["structs"][struct_name]["fields"]:
        typ = f["type"] + (f"[{f['count']}]" if f.get("count") else "")
        out[f["name"]] = f"{typ}" + (f": {f['doc']}" if f.get("doc") else "")
    return out


_NC_MEMBERS: list[Member] = members(NCTOPLC_DTYPE)
_NC_STRUCT = struct_of(NCTOPLC_DTYPE)  # (raises if the layout is not packed)
#: member -> (first index in the unpacked tuple, count: 0 for a scalar)
_NC_INDEX: dict[str, tuple[int, int]] = {}
_i = 0
for _name, _off, _code, _n in _NC_MEMBERS:
    _NC_INDEX[_name] = (_i, _n)
    _i += max(_n, 1)


#: the members a program sees (reserved bytes left out)
NCTOPLC_FIELDS: tuple[str, ...] = tuple(n for n, *_ in _NC_MEMBERS if not n.startswith("_"))
_ZERO_NCTOPLC = bytes(NCTOPLC_DTYPE.itemsize)


#: StateDWord from an NCTOPLC record's bytes (NCTOPLC_AXIS_REF._sdw)
_SDW_OFF, _SDW = member_struct(NCTOPLC_DTYPE, "StateDWord")


class NCTOPLC_AXIS_REF:
    """The read-only NCTOPLC snapshot of one axis (TwinCAT ``AXIS_REF.NcToPlc``).

    Every member of ``schema/structs.json`` NCTOPLC_AXIS_REF is an attribute with a plain Python
    value (``.SetPos``, ``.ActPos``, ``.StateDWord``, ``.CmdNo``, ...; arrays as tuples); ``rec["SetPos"]``
    is the same. A new object every PLC cycle: one kept from an earlier cycle keeps that cycle's values.

    Also: :meth:`as_dict` (JSON-ready), :meth:`tobytes`, ``dtype``, ``record`` (the numpy record,
    read-only, made on first use), ``keys()``, ``in``.
    """

    __slots__ = ("_raw", "_v", "_rec", "_sdw")
    dtype = NCTOPLC_DTYPE
    # the members: read-only properties set from the layout below, declared here for the type checker
    # (tests/plc/test_declarations.py checks them against the layout)
    StateDWord: int
    ErrorCode: int
    AxisState: int
    AxisModeConfirmation: int
    HomingState: int
    CoupleState: int
    SvbEntries: int
    SafEntries: int
    AxisId: int
    OpModeDWord: int
    ActPos: float
    ModuloActPos: float
    ActiveControlLoopIndex: int
    ControlLoopIndex: int
    ModuloActTurns: int
    ActVelo: float
    PosDiff: float
    SetPos: float
    SetVelo: float
    SetAcc: float
    TargetPos: float
    ModuloSetPos: float
    ModuloSetTurns: int
    CmdNo: int
    CmdState: int
    SetJerk: float
    SetTorque: float
    ActTorque: float
    StateDWord2: int
    StateDWord3: int
    TouchProbeState: int
    TouchProbeCounter: int
    CamCouplingState: tuple[int, ...]
    CamCouplingTableID: tuple[int, ...]
    ActTorqueDerivative: float
    SetTorqueDerivative: float
    AbsPhasingPos: float
    TorqueOffset: float
    ActPosWithoutPosCorrection: float
    ActAcc: float
    DcTimeStamp: int
    UserData: float

    def __init__(self, raw: bytes = _ZERO_NCTOPLC) -> None:
        if len(raw) != NCTOPLC_DTYPE.itemsize:
            raise ValueError(f"NCTOPLC_AXIS_REF: {NCTOPLC_DTYPE.itemsize} bytes expected, got {len(raw)}")
        self._raw = bytes(raw)
        self._v: tuple[Any, ...] | None = None
        self._rec: np.void | None = None
        #: StateDWord, kept apart: the blocks and the task test its bits every cycle without unpacking the record
        self._sdw: int = _SDW.unpack_from(self._raw, _SDW_OFF)[0]

    @classmethod
    def _of(cls, raw: bytes) -> NCTOPLC_AXIS_REF:
        """A snapshot of ``raw`` (the runtime's per-cycle path: exactly 256 bytes, not copied again)."""
        self = object.__new__(cls)
        self._raw, self._v, self._rec, self._sdw = raw, None, None, _SDW.unpack_from(raw, _SDW_OFF)[0]
        return self

    def _unpack(self) -> tuple[Any, ...]:
        v = self._v = _NC_STRUCT.unpack(self._raw)
        return v

    def __getitem__(self, name: str) -> Any:
        try:
            i, n = _NC_INDEX[name]
        except (KeyError, TypeError):
            raise KeyError(f"NCTOPLC_AXIS_REF has no member {name!r}") from None
        v = self._v or self._unpack()
        return v[i:i + n] if n else v[i]

    def __setitem__(self, name: str, value: Any) -> None:
        raise ValueError(f"NcToPlc is read-only (the NC's data of this cycle): cannot set {name!r}")

    def __contains__(self, name: object) -> bool:
        return name in NCTOPLC_FIELDS

    def keys(self) -> tuple[str, ...]:
        return NCTOPLC_FIELDS

    def __iter__(self) -> Iterator[str]:
        return iter(NCTOPLC_FIELDS)

    def as_dict(self) -> dict[str, Any]:
        """Every member as a plain value (arrays as lists): ``json.dumps(ax.NcToPlc.as_dict())`` works."""
        v = self._v or self._unpack()
        out: dict[str, Any] = {}
        for name in NCTOPLC_FIELDS:
            i, n = _NC_INDEX[name]
            out[name] = list(v[i:i + n]) if n else v[i]
        return out

    def tobytes(self) -> bytes:
        return self._raw

    @property
    def record(self) -> np.void:
        """The snapshot as a read-only numpy record of ``NCTOPLC_DTYPE``."""
        if self._rec is None:
            self._rec = np.frombuffer(self._raw, dtype=NCTOPLC_DTYPE, count=1)[0]
        return self._rec

    def __eq__(self, other: object) -> bool:
        if isinstance(other, NCTOPLC_AXIS_REF):
            return self._raw == other._raw
        return NotImplemented

    __hash__ = None  # type: ignore[assignment]  # unhashable, as __eq__ makes it (typeshed: a method)

    def __repr__(self) -> str:
        return (f"NCTOPLC_AXIS_REF(AxisId={self['AxisId']}, SetPos={self['SetPos']!r}, ActPos={self['ActPos']!r}, "
                f"StateDWord=0x{self['StateDWord']:X}, ErrorCode=0x{self['ErrorCode']:X})")


def _nc_getter(name: str, doc: str) -> property:
    i, n = _NC_INDEX[name]
    if n:
        def get(self: NCTOPLC_AXIS_REF) -> Any:
            return (self._v or self._unpack())[i:i + n]
    else:
        def get(self: NCTOPLC_AXIS_REF) -> Any:
            return (self._v or self._unpack())[i]
    get.__name__ = name
    return property(get, doc=doc)


_nc_docs = _docs("NCTOPLC_AXIS_REF")
for _name in NCTOPLC_FIELDS:
    setattr(NCTOPLC_AXIS_REF, _name, _nc_getter(_name, _nc_docs.get(_name, "")))


# ---- PLCTONC ------------------------------------------------------------------------------------
_PLC_MEMBERS: list[Member] = members(PLCTONC_DTYPE)
struct_of(PLCTONC_DTYPE)  # raises if the layout is not packed
#: member -> (offset, struct.Struct of one value, count: 0 for a scalar)
_PLC_INDEX: dict[str, tuple[int, struct.Struct, int]] = {
    m.name: (*member_struct(PLCTONC_DTYPE, m.name), m.array_len) for m in _PLC_MEMBERS}
PLCTONC_FIELDS: tuple[str, ...] = tuple(n for n, *_ in _PLC_MEMBERS if not n.startswith("_"))
_INT_RANGE = {"B": (0, 0xFF), "H": (0, 0xFFFF), "I": (0, 0xFFFFFFFF), "Q": (0, 2 ** 64 - 1), "b": (-128, 127),
              "h": (-0x8000, 0x7FFF), "i": (-0x80000000, 0x7FFFFFFF), "q": (-2 ** 63, 2 ** 63 - 1)}


def _plc_value(name: str, code: str, value: Any) -> Any:
    """``value`` checked for member ``name`` (struct code ``code``); raises TypeError/ValueError."""
    if code in "fd":
        if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
            raise TypeError(f"PlcToNc.{name}: LREAL needs a number, got {value!r}")
        return float(value)
    if isinstance(value, (bool, np.bool_)):
        if code != "B":  # (Override = True would be 1 = 0.0001 %, silently)
            raise TypeError(f"PlcToNc.{name}: an integer is needed, got {value!r} (a bool only for BOOL/BYTE members)")
        return int(value)
    if not isinstance(value, (int, np.integer)):
        hint = " (round() it: a real is never truncated silently)" if isinstance(value, (float, np.floating)) else ""
        raise TypeError(f"PlcToNc.{name}: an integer is needed, got {value!r}{hint}")
    lo, hi = _INT_RANGE[code]
    if not lo <= value <= hi:
        raise ValueError(f"PlcToNc.{name}: must be within {lo}..{hi}, got {value!r}")
    return int(value)


class PLCTONC_AXIS_REF:
    """The writable PLCTONC record of one axis (TwinCAT ``AXIS_REF.PlcToNc``), published at the end of
    each PLC cycle for an axis the task controls.

    Every member of ``schema/structs.json`` PLCTONC_AXIS_REF is an attribute (``.Override``,
    ``.ControlDWord``, ``.GearRatio1``, ...) with a plain value; assigning one writes it (checked, see
    the module docstring). ``rec["Override"]`` and ``rec["Override"] = 500000`` are the same. The object
    stays the same for the AXIS_REF's life; ``record`` is a writable numpy view of the same bytes.
    """

    __slots__ = ("_buf", "_arr")
    dtype = PLCTONC_DTYPE
    # the members: properties set from the layout below, declared here for the type checker
    # (tests/plc/test_declarations.py checks them against the layout)
    ControlDWord: _Writable[int]
    Override: _Writable[int]
    AxisModeRequest: _Writable[int]
    AxisModeDWord: _Writable[int]
    AxisModeLReal: _Writable[float]
    PositionCorrection: _Writable[float]
    ExtSetPos: _Writable[float]
    ExtSetVelo: _Writable[float]
    ExtSetAcc: _Writable[float]
    ExtSetDirection: _Writable[int]
    ExtControllerOutput: _Writable[float]
    GearRatio1: _Writable[float]
    GearRatio2: _Writable[float]
    GearRatio3: _Writable[float]
    GearRatio4: _Writable[float]
    MapState: _Writable[int]
    PlcCycleControl: _Writable[int]
    PlcCycleCount: _Writable[int]
    ExtTorque: _Writable[float]

    def __init__(self) -> None:
        self._buf = bytearray(PLCTONC_DTYPE.itemsize)
        self._arr = np.frombuffer(self._buf, dtype=PLCTONC_DTYPE, count=1)  # shares _buf (writable)

    def __getitem__(self, name: str) -> Any:
        try:
            off, st, n = _PLC_INDEX[name]
        except (KeyError, TypeError):
            raise KeyError(f"PLCTONC_AXIS_REF has no member {name!r}") from None
        v = st.unpack_from(self._buf, off)
        return v if n else v[0]

    def __setitem__(self, name: str, value: Any) -> None:
        try:
            off, st, n = _PLC_INDEX[name]
        except (KeyError, TypeError):
            raise KeyError(f"PLCTONC_AXIS_REF has no member {name!r}") from None
        code = st.format[-1]
        if n:
            vals = list(value)
            if len(vals) != n:
                raise ValueError(f"PlcToNc.{name}: {n} values expected, got {len(vals)}")
            st.pack_into(self._buf, off, *(_plc_value(name, code, x) for x in vals))
        else:
            st.pack_into(self._buf, off, _plc_value(name, code, value))

    def __contains__(self, name: object) -> bool:
        return name in PLCTONC_FIELDS

    def keys(self) -> tuple[str, ...]:
        return PLCTONC_FIELDS

    def __iter__(self) -> Iterator[str]:
        return iter(PLCTONC_FIELDS)

    def as_dict(self) -> dict[str, Any]:
        """Every member as a plain value (JSON-ready)."""
        return {name: self[name] for name in PLCTONC_FIELDS}

    def tobytes(self) -> bytes:
        return bytes(self._buf)

    @property
    def record(self) -> np.void:
        """A writable numpy record (``PLCTONC_DTYPE``) over the same bytes."""
        return self._arr[0]

    def __repr__(self) -> str:
        return f"PLCTONC_AXIS_REF(ControlDWord=0x{self['ControlDWord']:X}, Override={self['Override']})"


def _plc_property(name: str, doc: str) -> property:
    off, st, n = _PLC_INDEX[name]
    code = st.format[-1]

    def get(self: PLCTONC_AXIS_REF) -> Any:
        v = st.unpack_from(self._buf, off)
        return v if n else v[0]

    def set_(self: PLCTONC_AXIS_REF, value: Any) -> None:
        if n:
            self[name] = value
        else:
            st.pack_into(self._buf, off, _plc_value(name, code, value))

    get.__name__ = name
    return property(get, set_, doc=doc)


_plc_docs = _docs("PLCTONC_AXIS_REF")
for _name in PLCTONC_FIELDS:
    setattr(PLCTONC_AXIS_REF, _name, _plc_property(_name, _plc_docs.get(_name, "")))


# ---- NCJOBS (the blocks' view) ------------------------------------------------------------------
_JOBS_STRUCT = flat_struct(NCJOBS_DTYPE)  # every value of the record, the Ended entries flattened
#: member -> (first index in the unpacked tuple, values of one element (0: a scalar), elements)
_JOBS_INDEX: dict[str, tuple[int, int, int]] = {}
_i = 0
assert NCJOBS_DTYPE.names is not None and NCJOBS_DTYPE.fields is not None
for _k, _name in enumerate(NCJOBS_DTYPE.names):
    _fdt = NCJOBS_DTYPE.fields[_name][0]
    _stop = NCJOBS_DTYPE.names[_k + 1] if _k + 1 < len(NCJOBS_DTYPE.names) else None
    _n = len(flat_struct(NCJOBS_DTYPE, start=_name, stop=_stop).unpack(bytes(_fdt.itemsize)))
    if _fdt.subdtype is None:
        _JOBS_INDEX[_name] = (_i, 0, 0) if _n == 1 else (_i, _n, 1)
    else:
        _count = int(np.prod(_fdt.subdtype[1]))
        _JOBS_INDEX[_name] = (_i, _n // _count, _count)
    _i += _n
_ZERO_NCJOBS = bytes(NCJOBS_DTYPE.itemsize)


class NcJobsValues:
    """One cycle's NCJOBS_AXIS_REF of an axis as plain values, for the function blocks and the task
    (``AXIS_REF._jobs``): the record's bytes, unpacked with one ``struct.unpack`` at the first read, as
    :class:`NCTOPLC_AXIS_REF` does; every member is an attribute (``.ActiveCmdNo``, ``.NewestCmdNo``, ...),
    an array of structs a tuple of value tuples (``.Ended``: four ``(CmdNo, CmdState, ErrorId)``).

    ``AXIS_REF.NcJobs`` (the public, numpy form) is :attr:`record`, made on first use: the blocks read a
    few members every cycle, and a numpy record and its field accesses cost ~10x an unpack.
    """

    __slots__ = ("_raw", "_v", "_rec")
    dtype = NCJOBS_DTYPE
    # the members (properties set from the layout below), declared for the type checker
    AxisId: int
    ActiveCmdNo: int
    ActiveState: int
    BufferedCmdNo: int
    BufferedMode: int
    NewestCmdNo: int
    Flags: int
    Ended: tuple[tuple[int, int, int], ...]
    MasterId: int
    SyncFlags: int
    GearRatio: float
    SuperCmdNo: int
    SuperState: int
    SuperErrorId: int
    SuperDistance: float
    SuperVelocityDiff: float
    SuperLength: float
    ProbeCmdNo: int
    ProbeState: int
    ProbeCounter: int
    RecordedPosition: float
    RecordedTimeNs: int
    ProbeErrorId: int
    DriveStatus: int

    def __init__(self, raw: bytes = _ZERO_NCJOBS) -> None:
        if len(raw) != NCJOBS_DTYPE.itemsize:
            raise ValueError(f"NCJOBS_AXIS_REF: {NCJOBS_DTYPE.itemsize} bytes expected, got {len(raw)}")
        self._raw = bytes(raw)
        self._v: tuple[Any, ...] | None = None
        self._rec: np.void | None = None

    @classmethod
    def _of(cls, raw: bytes) -> NcJobsValues:
        """A snapshot of ``raw`` (exactly one record's bytes, not copied again)."""
        self = object.__new__(cls)
        self._raw, self._v, self._rec = raw, None, None
        return self

    def _unpack(self) -> tuple[Any, ...]:
        v = self._v = _JOBS_STRUCT.unpack(self._raw)
        return v

    def __getitem__(self, name: str) -> Any:
        try:
            get = _jobs_get[name]
        except (KeyError, TypeError):
            raise KeyError(f"NCJOBS_AXIS_REF has no member {name!r}") from None
        return get(self)

    def tobytes(self) -> bytes:
        return self._raw

    @property
    def record(self) -> np.void:
        """The snapshot as a read-only numpy record of ``NCJOBS_DTYPE`` (what ``AXIS_REF.NcJobs`` gives)."""
        if self._rec is None:
            self._rec = np.frombuffer(self._raw, dtype=NCJOBS_DTYPE, count=1)[0]
        return self._rec

    def __repr__(self) -> str:
        return (f"NcJobsValues(AxisId={self.AxisId}, Active={self.ActiveCmdNo}/{self.ActiveState}, "
                f"Buffered={self.BufferedCmdNo}, Newest={self.NewestCmdNo})")


def _jobs_getter(name: str) -> Any:
    i, per, count = _JOBS_INDEX[name]
    if not per:
        def get(self: NcJobsValues) -> Any:
            return (self._v or self._unpack())[i]
    elif count == 1:  # an array of scalars
        def get(self: NcJobsValues) -> Any:
            return (self._v or self._unpack())[i:i + per]
    else:  # an array of structs: a tuple of value tuples
        def get(self: NcJobsValues) -> Any:
            v = self._v or self._unpack()
            return tuple(v[j:j + per] for j in range(i, i + per * count, per))
    get.__name__ = name
    return get


_jobs_get: dict[str, Any] = {}
for _name in _JOBS_INDEX:
    _jobs_get[_name] = _jobs_getter(_name)
    setattr(NcJobsValues, _name, property(_jobs_get[_name]))
#: the zero record (no job records yet): immutable, shared
NO_JOBS = NcJobsValues()
