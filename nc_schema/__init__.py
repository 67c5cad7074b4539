"""nc_schema: the zenoh-nc wire contract.

The JSON files in the repository's ``schema/`` folder are the single source of truth
(language-neutral: a C, Rust or TypeScript client reads the same files); this package builds
the Python codec from them at import time (:mod:`.layout`: dtypes and the one dtype -> struct conversion;
:mod:`.frames`: the frame codec every client and the NC use), plus the typed enums and error codes that
``python -m nc_schema.generate`` writes into the committed :mod:`.generated`, and :mod:`.commands`: every
command's properties (:data:`COMMAND_SPECS`, the typed view of ``protocol.json``'s commands that the NC's
command registry and the clients' command sets are checked against). An installed wheel carries a
copy of the JSON in ``nc_schema/contract/`` (see ``layout.CONTRACT_DIR``).

May import: the standard library, numpy, msgpack, zenoh (the client config); not a client package
and never ``nc_server`` (everything else depends on this one; the TLS helpers live here, in ``tls.py``).

Imported as ``nc_schema`` (not ``schema``, which is an unrelated PyPI package).
"""
from .codec import (
    BITSETS, CONTRACT_DIR, DEFAULT_HOME_POSITION, DTYPES, ENUMS, FRAME_HEADER_DTYPE, FRAME_HEADER_SIZE,
    FRAME_HEADER_STRUCT, FRAME_MAGIC, JOB_RECORDS, NCJOBS_DTYPE, NCJOBS_SIZE, NCTOPLC_DTYPE, NCTOPLC_SIZE,
    PLCTONC_DTYPE, PLCTONC_SIZE, PLC_AXIS_HEAD_STRUCT, PLC_AXIS_RECORD_DTYPE, PLC_AXIS_RECORD_SIZE,
    PLC_FRAME_HEADER_DTYPE, PLC_FRAME_HEADER_SIZE, PLC_FRAME_HEADER_STRUCT, PLC_FRAME_MAGIC, STAMP_DTYPE,
    STAMP_SIZE, STAMP_STRUCT, STRUCTS, WIRE_VERSION, AxisState, CamCouplingState, CmdState, ControlDWord,
    CoupleState, E_CmdTypeNewTargPosAndVelo, E_DecoupleMode, E_JogMode, E_SignalEdge, E_StartPosType,
    E_SuperpositionMode, E_TargPosType, E_TouchProbe, E_TouchProbeState, FrameFlags, FrameHeader, HomingState,
    MC_AxisPara, MC_AxisStates, MC_BufferMode, MC_Direction, MC_HomingMode, Member, NcJobsFlags, NcJobsSyncFlags,
    OpModeDWord, StateDWord, StateDWord2, StateDWord3, bit_names, decode, decode_frame, decode_plc_frame,
    decode_stamp, decode_stamp_epoch, encode_frame, encode_plc_frame, encode_plc_records, encode_stamp, frame_epoch,
    frame_header, frame_header_values, frame_records, frame_stamp, load_json, member_struct, members,
    pack_frame_header_into, struct_of, to_dict, view_frame,
)
from .commands import COMMAND_SPECS, CommandSpec
from .errors import ERRORS, ErrorCodes, NcError, error_name, error_text
from .instance import NcInstance, new_instance_id
from .messages import (
    CLASSES, COMMAND_CLASS, COMMANDS, FRAME_PERIODS_MS, MAX_VIEW_AXES, MOTION_COMMANDS, PROTOCOL, ROLE_CLASSES,
    VIEW_PERIODS_MS, Keys, check_client_id, frame_period_ms, make_reply, make_request, pack, parse_alive_instance,
    parse_reply, parse_request, parse_view_axes, parse_view_select, unpack, view_axes_chunk, view_axes_text,
    view_period_ms, IDLE_VIEW_PERIOD_MS,
)
from .params import (
    PARAMETERS, ST_AXIS_COMPONENTS, ST_AXIS_PARAMETER_SET, E_DestallDetectMode, E_DestallMode, E_NcAxisType,
    E_NcDriveType, E_NcEncoderType, E_ReadMode, ParamEntry, decode_ads, decode_axis_components, decode_parameter_set,
    encode_ads, encode_axis_components, encode_parameter_set, pack_value, unpack_value,
)
from .state import cmdno_newer, motion_state, motion_state_array, next_cmdno

# static, so a type checker sees the re-exports (tests/schema/test_generated.py checks it is complete)
__all__ = [
    "AxisState", "BITSETS", "CLASSES", "COMMANDS", "COMMAND_CLASS", "COMMAND_SPECS", "CONTRACT_DIR", "CamCouplingState",
    "CmdState", "CommandSpec", "ControlDWord", "CoupleState", "DEFAULT_HOME_POSITION", "DTYPES", "ENUMS", "ERRORS",
    "E_CmdTypeNewTargPosAndVelo", "E_DecoupleMode", "E_DestallDetectMode", "E_DestallMode", "E_JogMode",
    "E_NcAxisType", "E_NcDriveType", "E_NcEncoderType", "E_ReadMode", "E_SignalEdge", "E_StartPosType",
    "E_SuperpositionMode", "E_TargPosType", "E_TouchProbe", "E_TouchProbeState", "ErrorCodes", "FRAME_HEADER_DTYPE",
    "FRAME_HEADER_SIZE", "IDLE_VIEW_PERIOD_MS", "view_period_ms", "FRAME_HEADER_STRUCT", "FRAME_MAGIC", "FRAME_PERIODS_MS", "FrameFlags", "FrameHeader",
    "HomingState", "JOB_RECORDS", "Keys", "MAX_VIEW_AXES", "MC_AxisPara", "MC_AxisStates", "MC_BufferMode", "MC_Direction",
    "MC_HomingMode", "MOTION_COMMANDS", "Member", "NCJOBS_DTYPE", "NCJOBS_SIZE", "NCTOPLC_DTYPE", "NCTOPLC_SIZE",
    "NcError", "NcInstance", "NcJobsFlags", "NcJobsSyncFlags", "OpModeDWord", "PARAMETERS", "PLCTONC_DTYPE",
    "PLCTONC_SIZE", "PLC_AXIS_HEAD_STRUCT", "PLC_AXIS_RECORD_DTYPE", "PLC_AXIS_RECORD_SIZE",
    "PLC_FRAME_HEADER_DTYPE", "PLC_FRAME_HEADER_SIZE", "PLC_FRAME_HEADER_STRUCT", "PLC_FRAME_MAGIC", "PROTOCOL",
    "ParamEntry", "ROLE_CLASSES", "STAMP_DTYPE", "STAMP_SIZE", "STAMP_STRUCT", "STRUCTS", "ST_AXIS_COMPONENTS",
    "ST_AXIS_PARAMETER_SET", "StateDWord", "StateDWord2", "StateDWord3", "VIEW_PERIODS_MS", "WIRE_VERSION", "bit_names",
    "check_client_id", "cmdno_newer", "decode", "decode_ads", "decode_axis_components", "decode_frame",
    "decode_parameter_set", "decode_plc_frame", "decode_stamp", "decode_stamp_epoch", "encode_ads",
    "encode_axis_components",
    "encode_frame", "encode_parameter_set", "encode_plc_frame", "encode_plc_records", "encode_stamp", "error_name",
    "error_text", "frame_epoch", "frame_header", "frame_header_values", "frame_period_ms", "frame_records", "frame_stamp", "load_json",
    "make_reply",
    "make_request", "member_struct", "members", "motion_state", "motion_state_array", "new_instance_id",
    "next_cmdno", "pack", "pack_frame_header_into", "pack_value", "parse_alive_instance", "parse_reply",
    "parse_request", "parse_view_axes", "parse_view_select", "struct_of", "to_dict", "unpack", "unpack_value", "view_axes_chunk", "view_axes_text",
    "view_frame",
]
