"""TcMC function blocks as plain Python classes (see :mod:`plc_client.fb.base` for the call style
and the PLCopen output rules, :mod:`plc_client.fb.motion` and :mod:`plc_client.fb.admin` for the
choices made where the manual is silent)."""
from .admin import (
    MC_Power, MC_ReadActualPosition, MC_ReadAxisError, MC_ReadStatus, MC_Reset, MC_SetOverride, override_to_plctonc,
)
from .amend import MC_ChangeDynParam, MC_NewPos, MC_NewPosAndVelo
from .base import EnableBlock, ExecuteBlock, FunctionBlock
from .motion import (
    DONE_WINDOW_TIMEOUT, MC_Halt, MC_MoveAbsolute, MC_MoveAbsoluteOrRestart, MC_MoveAdditive,
    MC_MoveContinuousAbsolute, MC_MoveContinuousRelative, MC_MoveModulo, MC_MoveRelative, MC_MoveVelocity,
    MC_OrientedStop, MC_Stop, MotionBlock,
)

__all__ = [
    "MC_Power", "MC_Reset", "MC_MoveAbsolute", "MC_MoveRelative", "MC_MoveModulo", "MC_MoveVelocity", "MC_Halt",
    "MC_Stop", "MC_SetOverride", "MC_ReadActualPosition", "MC_ReadStatus", "MC_ReadAxisError",
    "MC_ChangeDynParam", "MC_MoveAbsoluteOrRestart", "MC_MoveAdditive", "MC_MoveContinuousAbsolute",
    "MC_MoveContinuousRelative", "MC_NewPos", "MC_NewPosAndVelo", "MC_OrientedStop",
    "FunctionBlock", "ExecuteBlock", "EnableBlock", "MotionBlock", "DONE_WINDOW_TIMEOUT", "override_to_plctonc",
]

# homing, jogging, position administration, AXACT
from .axact import AXACT  # noqa: E402
from .home import MC_Home  # noqa: E402
from .jog import MC_Jog  # noqa: E402
from .position import (  # noqa: E402
    F_GetVersionTcMC, MC_SetActualPosition, MC_SetActualPositionOnTheFly, MC_SetReferenceFlag,
)

__all__ += ["MC_Jog", "MC_Home", "MC_SetActualPosition", "MC_SetActualPositionOnTheFly", "MC_SetReferenceFlag",
            "F_GetVersionTcMC", "AXACT"]

# coupling, superposition, external set-point generator, touch probe
from .coupling import E_DecoupleMode, MC_GearIn, MC_GearInDyn, MC_GearInFloat, MC_GearOut, MC_GearOutExt  # noqa: E402
from .external import (  # noqa: E402
    E_TargPosType, MC_ExtSetPointGenDisable, MC_ExtSetPointGenEnable, MC_ExtSetPointGenFeed,
)
from .probe import E_SignalEdge, E_TouchProbe, E_TouchProbeState, MC_AbortTrigger, MC_InputRef, MC_TouchProbe  # noqa: E402
from .superposition import (  # noqa: E402
    E_SuperpositionMode, MC_AbortSuperposition, MC_MoveSuperImposed, MC_MoveSuperImposedExt,
)

__all__ += ["MC_GearIn", "MC_GearInFloat", "MC_GearInDyn", "MC_GearOut", "MC_GearOutExt",
            "MC_MoveSuperImposed", "MC_MoveSuperImposedExt", "MC_AbortSuperposition",
            "MC_ExtSetPointGenEnable", "MC_ExtSetPointGenDisable", "MC_ExtSetPointGenFeed",
            "MC_InputRef", "MC_TouchProbe", "MC_AbortTrigger",
            "E_DecoupleMode", "E_SuperpositionMode", "E_TargPosType", "E_TouchProbe", "E_SignalEdge",
            "E_TouchProbeState"]

# parameters, axis components, override filter, stepper power (TcMC 4.6-4.11, 4.19, 4.23)
from .override import MC_OverrideFilter  # noqa: E402
from .params import (  # noqa: E402
    E_ReadMode, MC_ReadAxisComponents, MC_ReadBoolParameter, MC_ReadParameter, MC_ReadParameterSet,
    MC_WriteBoolParameter, MC_WriteParameter, ST_AxisComponents, ST_AxisParameterSet,
)
from .stepper import E_DestallDetectMode, E_DestallMode, MC_PowerStepper, ST_PowerStepperStruct  # noqa: E402

__all__ += ["MC_ReadParameter", "MC_ReadBoolParameter", "MC_WriteParameter", "MC_WriteBoolParameter",
            "MC_ReadParameterSet", "MC_ReadAxisComponents", "MC_OverrideFilter", "MC_PowerStepper",
            "ST_AxisParameterSet", "ST_AxisComponents", "ST_PowerStepperStruct", "E_ReadMode", "E_DestallMode",
            "E_DestallDetectMode"]
