"""zenoh-nc PLC client: AXIS_REF, the TcMC function blocks and the cyclic PLC runtime.

Typical program (run with ``plc-run program.py``)::

    from plc_client import AXIS_REF, MC_Power, MC_MoveAbsolute

    X = AXIS_REF(nc="nc1", axis_id=1)
    power, move = MC_Power(), MC_MoveAbsolute()
    step = 0  # 0 wait for the enable, 10 move, 20 done (motion from a latched step, not from power.Status)

    def cycle(plc):
        global step
        power(Axis=X, Enable=True, Enable_Positive=True, Enable_Negative=True)
        if step == 0 and power.Status:
            step = 10
        move(Axis=X, Execute=step == 10, Position=100.0, Velocity=50.0)
        if step == 10 and (move.Done or move.Error or move.CommandAborted):
            step = 20

Owns the PLC side: AXIS_REF, the function blocks, the transport-independent task (claims per MC_Power,
late replies, orphans) and the zenoh runtime. May import ``nc_schema`` and the client link ``nc_link``
(sessions, liveliness, NC restarts); never ``nc_server`` (tests/test_import_graph.py). The in-process NC
(``InProcessPlc``, ``run_cycles``, ``InProcessPort``: tests and simulations without zenoh) is ``nc_sim``.
"""
from nc_schema import (
    E_CmdTypeNewTargPosAndVelo, E_JogMode, E_NcAxisType, E_NcDriveType, E_NcEncoderType, E_StartPosType, MC_AxisPara,
    MC_AxisStates, MC_BufferMode, MC_Direction, MC_HomingMode,
)

from .axis_ref import AXIS_REF, ST_AxisStatus
from .fb import (
    MC_ChangeDynParam, MC_Halt, MC_MoveAbsolute, MC_MoveAbsoluteOrRestart, MC_MoveAdditive, MC_MoveContinuousAbsolute,
    MC_MoveContinuousRelative, MC_MoveModulo, MC_MoveRelative, MC_MoveVelocity, MC_NewPos, MC_NewPosAndVelo,
    MC_OrientedStop, MC_Power, MC_ReadActualPosition, MC_ReadAxisError, MC_ReadStatus, MC_Reset, MC_SetOverride,
    MC_Stop,
)
from .port import CommandPort, PendingCommand
from .program import ProgramArgs, ProgramArgsError, program_args
from .records import NCTOPLC_AXIS_REF, PLCTONC_AXIS_REF

#: TcMC's names of the cyclic axis interface (the manual's blocks take ``Axis : NCTOPLC_AXLESTRUCT``): here
#: the records of an AXIS_REF (``X.NcToPlc``, ``X.PlcToNc``); the blocks take the AXIS_REF that holds both
NCTOPLC_AXLESTRUCT = NCTOPLC_AXIS_REF
PLCTONC_AXLESTRUCT = PLCTONC_AXIS_REF
from .task import PlcTask, current_task

__all__ = [
    "AXIS_REF", "ST_AxisStatus", "MC_Power", "MC_Reset", "MC_MoveAbsolute", "MC_MoveRelative", "MC_MoveModulo",
    "MC_MoveVelocity", "MC_Halt", "MC_Stop", "MC_SetOverride", "MC_ReadActualPosition", "MC_ReadStatus",
    "MC_ReadAxisError", "CommandPort", "PendingCommand", "PlcTask",
    "current_task", "MC_AxisStates", "MC_BufferMode", "MC_Direction",
    "MC_ChangeDynParam", "MC_MoveAbsoluteOrRestart", "MC_MoveAdditive", "MC_MoveContinuousAbsolute",
    "MC_MoveContinuousRelative", "MC_NewPos", "MC_NewPosAndVelo", "MC_OrientedStop",
    "program_args", "ProgramArgs", "ProgramArgsError", "NCTOPLC_AXIS_REF", "PLCTONC_AXIS_REF",
    # the data types the manual's blocks use, where a PLC programmer looks for them
    "NCTOPLC_AXLESTRUCT", "PLCTONC_AXLESTRUCT", "E_JogMode", "E_CmdTypeNewTargPosAndVelo", "MC_AxisPara",
    "MC_HomingMode", "E_StartPosType", "E_NcAxisType", "E_NcEncoderType", "E_NcDriveType",
]

# homing, jogging, position administration, AXACT
from .fb import (  # noqa: E402
    AXACT, F_GetVersionTcMC, MC_Home, MC_Jog, MC_SetActualPosition, MC_SetActualPositionOnTheFly, MC_SetReferenceFlag,
)

__all__ += ["MC_Jog", "MC_Home", "MC_SetActualPosition", "MC_SetActualPositionOnTheFly", "MC_SetReferenceFlag",
            "F_GetVersionTcMC", "AXACT"]

# coupling, superposition, external set-point generator, touch probe
from .fb import (  # noqa: E402
    E_DecoupleMode, E_SignalEdge, E_SuperpositionMode, E_TargPosType, E_TouchProbe, E_TouchProbeState,
    MC_AbortSuperposition, MC_AbortTrigger, MC_ExtSetPointGenDisable, MC_ExtSetPointGenEnable, MC_ExtSetPointGenFeed,
    MC_GearIn, MC_GearInDyn, MC_GearInFloat, MC_GearOut, MC_GearOutExt, MC_InputRef, MC_MoveSuperImposed,
    MC_MoveSuperImposedExt, MC_TouchProbe,
)

__all__ += ["MC_GearIn", "MC_GearInFloat", "MC_GearInDyn", "MC_GearOut", "MC_GearOutExt",
            "MC_MoveSuperImposed", "MC_MoveSuperImposedExt", "MC_AbortSuperposition",
            "MC_ExtSetPointGenEnable", "MC_ExtSetPointGenDisable", "MC_ExtSetPointGenFeed",
            "MC_InputRef", "MC_TouchProbe", "MC_AbortTrigger",
            "E_DecoupleMode", "E_SuperpositionMode", "E_TargPosType", "E_TouchProbe", "E_SignalEdge",
            "E_TouchProbeState"]

# parameters, axis components, override filter, stepper power
from .fb import (  # noqa: E402
    E_DestallDetectMode, E_DestallMode, E_ReadMode, MC_OverrideFilter, MC_PowerStepper, MC_ReadAxisComponents,
    MC_ReadBoolParameter, MC_ReadParameter, MC_ReadParameterSet, MC_WriteBoolParameter, MC_WriteParameter,
    ST_AxisComponents, ST_AxisParameterSet, ST_PowerStepperStruct,
)

__all__ += ["MC_ReadParameter", "MC_ReadBoolParameter", "MC_WriteParameter", "MC_WriteBoolParameter",
            "MC_ReadParameterSet", "MC_ReadAxisComponents", "MC_OverrideFilter", "MC_PowerStepper",
            "ST_AxisParameterSet", "ST_AxisComponents", "ST_PowerStepperStruct", "E_ReadMode", "E_DestallMode",
            "E_DestallDetectMode"]
