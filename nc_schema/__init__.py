"""nc_schema: the zenoh-nc wire contract.

The JSON files in the repository's ``schema/`` folder are the single source of truth
(language-neutral: a C, Rust or TypeScript client reads the same files); this package builds
the Python codec from them at import time. An installed wheel carries a copy of them in
``nc_schema/contract/`` (see ``codec.CONTRACT_DIR``).

Imported as ``nc_schema`` (not ``schema``, which is an unrelated PyPI package).
"""
from .codec import (
    BITSETS, DTYPES, ENUMS, FRAME_HEADER_DTYPE, NCJOBS_DTYPE, NCTOPLC_DTYPE, PLC_AXIS_RECORD_DTYPE, PLC_FRAME_HEADER_DTYPE,
    PLCTONC_DTYPE, STAMP_DTYPE, STRUCTS, AxisState, CamCouplingState, CmdState, ControlDWord, CoupleState, E_CmdTypeNewTargPosAndVelo, E_JogMode,
    E_DecoupleMode, E_SignalEdge, E_SuperpositionMode, E_TargPosType, E_TouchProbe, E_TouchProbeState, NcJobsSyncFlags,
    DEFAULT_HOME_POSITION, E_StartPosType, FrameFlags, HomingState, MC_AxisPara, MC_AxisStates, MC_BufferMode, MC_Direction,
    MC_HomingMode, OpModeDWord, StateDWord, StateDWord2, StateDWord3, bit_names, decode, decode_frame,
    decode_plc_frame, decode_stamp, encode_frame, encode_plc_frame, encode_stamp, to_dict,
)
from .errors import ERRORS, ErrorCodes, NcError, error_name, error_text
from .instance import NcInstance, new_instance_id
from .messages import (
    CLASSES, COMMAND_CLASS, COMMANDS, FRAME_PERIODS_MS, MOTION_COMMANDS, PROTOCOL, ROLE_CLASSES, Keys, check_client_id,
    frame_period_ms, make_reply, make_request, pack, parse_alive_instance, parse_reply, parse_request, unpack,
)
from .params import (
    PARAMETERS, ST_AXIS_COMPONENTS, ST_AXIS_PARAMETER_SET, E_DestallDetectMode, E_DestallMode, E_NcAxisType,
    E_NcDriveType, E_NcEncoderType, E_ReadMode, ParamEntry, decode_ads, decode_axis_components, decode_parameter_set,
    encode_ads, encode_axis_components, encode_parameter_set, pack_value, unpack_value,
)
from .state import cmdno_newer, motion_state, motion_state_array, next_cmdno

__all__ = [n for n in dir() if not n.startswith("_")]
