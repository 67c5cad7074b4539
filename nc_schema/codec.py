"""The Python codec of the wire contract: one import for the layouts, the frames and the typed enums.

A front over the modules that own each part (nothing about a layout is written down twice):

* :mod:`nc_schema.layout`: the JSON files, the numpy dtypes of ``structs.json`` and the one
  dtype -> ``struct.Struct`` conversion (:func:`struct_of`, :func:`member_struct`, :func:`members`);
* :mod:`nc_schema.frames`: the status frame, the PLC frame and the STAMP, encoded and decoded;
* :mod:`nc_schema.generated`: the bit sets (IntFlag) and enums (IntEnum), generated from ``bits.json``
  and ``enums.json`` by ``python -m nc_schema.generate``.

Also here: :func:`bit_names` and :data:`DEFAULT_HOME_POSITION`. Imports only those three modules.
"""
from __future__ import annotations

from .frames import (
    FRAME_HEADER_STRUCT, FRAME_MAGIC, JOB_RECORDS, PLC_AXIS_HEAD_STRUCT, PLC_FRAME_HEADER_STRUCT, PLC_FRAME_MAGIC,
    STAMP_STRUCT, WIRE_VERSION, FrameHeader, decode_frame, decode_plc_frame, decode_stamp, decode_stamp_epoch,
    encode_frame, encode_plc_frame, encode_plc_records, encode_stamp, frame_epoch, frame_header, frame_header_values, frame_records,
    frame_stamp, pack_frame_header_into, view_frame,
)
from .generated import (
    AxisState, CamCouplingState, CmdState, ControlDWord, CoupleState, E_CmdTypeNewTargPosAndVelo, E_DecoupleMode,
    E_JogMode, E_SignalEdge, E_StartPosType, E_SuperpositionMode, E_TargPosType, E_TouchProbe, E_TouchProbeState,
    FrameFlags, HomingState, MC_AxisPara, MC_AxisStates, MC_BufferMode, MC_Direction, MC_HomingMode, NcJobsFlags,
    NcJobsSyncFlags, OpModeDWord, StateDWord, StateDWord2, StateDWord3,
)
from .layout import (
    BITSETS, CONTRACT_DIR, DTYPES, ENUMS, FRAME_HEADER_DTYPE, FRAME_HEADER_SIZE, NCJOBS_DTYPE, NCJOBS_SIZE,
    NCTOPLC_DTYPE, NCTOPLC_SIZE, PLC_AXIS_RECORD_DTYPE, PLC_AXIS_RECORD_SIZE, PLC_FRAME_HEADER_DTYPE,
    PLC_FRAME_HEADER_SIZE, PLCTONC_DTYPE, PLCTONC_SIZE, STAMP_DTYPE, STAMP_SIZE, STRUCTS, Member, decode,
    load_json, member_struct, members, struct_of, to_dict,
)

#: MC_Home.Position value that selects the axis's calibration value (any Position >= it does)
DEFAULT_HOME_POSITION = 1e300


def bit_names(bitset: str, value: int) -> list[str]:
    """Names of the bits set in ``value`` for bit set ``bitset`` (bits.json)."""
    return [n for k, n in BITSETS[bitset].items() if value >> int(k) & 1]


__all__ = [
    "BITSETS", "CONTRACT_DIR", "DTYPES", "ENUMS", "STRUCTS", "load_json", "FRAME_HEADER_DTYPE", "NCJOBS_DTYPE",
    "NCTOPLC_DTYPE", "PLC_AXIS_RECORD_DTYPE", "PLC_FRAME_HEADER_DTYPE", "PLCTONC_DTYPE", "STAMP_DTYPE",
    "FRAME_HEADER_SIZE", "NCJOBS_SIZE", "NCTOPLC_SIZE", "PLC_AXIS_RECORD_SIZE", "PLC_FRAME_HEADER_SIZE",
    "PLCTONC_SIZE", "STAMP_SIZE", "Member", "members", "struct_of", "member_struct", "decode", "to_dict",
    "bit_names", "DEFAULT_HOME_POSITION", "FRAME_MAGIC", "PLC_FRAME_MAGIC", "WIRE_VERSION", "JOB_RECORDS",
    "FRAME_HEADER_STRUCT", "PLC_FRAME_HEADER_STRUCT", "PLC_AXIS_HEAD_STRUCT", "STAMP_STRUCT", "FrameHeader",
    "encode_frame", "pack_frame_header_into", "frame_header", "frame_header_values", "frame_stamp", "frame_epoch", "decode_frame",
    "frame_records", "encode_plc_frame", "encode_plc_records", "decode_plc_frame", "encode_stamp", "decode_stamp",
    "decode_stamp_epoch", "view_frame", "AxisState",
    "CamCouplingState", "CmdState", "ControlDWord", "CoupleState", "E_CmdTypeNewTargPosAndVelo", "E_DecoupleMode",
    "E_JogMode", "E_SignalEdge", "E_StartPosType", "E_SuperpositionMode", "E_TargPosType", "E_TouchProbe",
    "E_TouchProbeState", "FrameFlags", "HomingState", "MC_AxisPara", "MC_AxisStates", "MC_BufferMode",
    "MC_Direction", "MC_HomingMode", "NcJobsFlags", "NcJobsSyncFlags", "OpModeDWord", "StateDWord", "StateDWord2",
    "StateDWord3",
]
