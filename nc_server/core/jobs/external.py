"""The external set-point generator (TcMC 4.16-4.18): a job whose set-points come from the PLC.

MC_ExtSetPointGenEnable makes an *external* job on the axis (numbered, ACTIVE while enabled:
HasJob, StateDWord.ExtSetPointGenEnabled); the external stage (:mod:`..stages.external`) then
takes the axis's set-points from PLCTONC ExtSetPos/ExtSetVelo/ExtSetAcc. Enabling needs an axis
that no command moves (0x4B01). While it is enabled, motion commands are refused with 0x4B08
(protected mode) unless AxisAllowMotionCmdToExtSetAxis is set (OpModeDWord bit 22): then the
command disables the generator and takes over from its set-point state. MC_Stop always does.

MC_ExtSetPointGenDisable ends the job DONE; an axis that still moves brakes from its set-point
state with AxisDec/AxisJerk (an NC ramp: no jump, never left moving without a generator).
"""
from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any, Mapping

from nc_schema import CmdState, E_TargPosType, ErrorCodes, NcError

from ..commands import core_command
from ..planning import Plan, StartState
from ..probe import modulo_position
from .base import Job, JobKind
from .stop import HALT_RAMP

if TYPE_CHECKING:
    from ..context import CoreContext

_EPS_V = 1e-9


class ExternalKind(JobKind):
    name = "ExtSetPointGen"
    commands = ("ExtSetPointGenEnable",)
    motion = False  # (enabling moves nothing: the fed set-points do)
    follows_override = False  # the PLC's generator owns the velocity
    source = "external"

    def accept(self, core: CoreContext, i: int, req: Mapping[str, Any], prev: Job | None) -> Job:
        ptype, pos = req.get("PositionType", 1), float(req.get("Position", 0.0))
        if ptype not in {int(t) for t in E_TargPosType}:
            raise NcError(ErrorCodes.MC_INVALID_MODE, f"PositionType {ptype} is not an E_TargPosType (1, 2, 5)")
        if not math.isfinite(pos) or abs(pos) >= 1e9:
            raise NcError(ErrorCodes.MC_PARAMETER_NOT_CORRECT, f"Position {pos} outside +/-1e9")
        return Job(self, dict(req))

    def activate(self, core: CoreContext, i: int, job: Job, start: StartState) -> Plan | None:
        a = core.axes
        if a.traj_on[i] or abs(start.v) > _EPS_V or core.coupling.is_slave(i):
            raise NcError(ErrorCodes.MC_AXIS_CANNOT_BE_STARTED, "a command moves the axis: stop it first")
        pos, ptype = float(job.args.get("Position", 0.0)), int(job.args.get("PositionType", 1))
        if ptype == int(E_TargPosType.POS_RELATIVE):
            pos += start.p
        elif ptype == int(E_TargPosType.POS_MODULO):
            period = float(core.params[i].AxisEncoderModuloValue)
            # in the axis's current modulo turn (floored: at -10 of a 360 period that is -360..0, as the
            # modulo position 350 says; fmod's truncation put it one turn ahead)
            pos = start.p - modulo_position(start.p, period) + pos
        job.target = pos
        return None

    def on_begin(self, core: CoreContext, i: int, job: Job) -> None:
        core.external.enable(core, i)  # (TargetPos = Position: the target window is watched when it stands)


EXTERNAL = ExternalKind()


@core_command("ExtSetPointGenDisable")
def ext_disable(core: CoreContext, i: int, req: Mapping[str, Any]) -> dict[str, Any]:
    """MC_ExtSetPointGenDisable (see the module docstring); not enabled: nothing to do."""
    q = core.queues[i]
    job = q.active
    if job is None or job.kind is not EXTERNAL:
        return {}
    a = core.axes
    moving = abs(float(a.set_velo[i])) > _EPS_V or abs(float(a.set_acc[i])) > 1e-9
    q.end(job, CmdState.DONE)
    if moving:
        core.start_ramp(i, HALT_RAMP, None)
    else:
        core.clear_profile(i)
        a.target_pos[i] = a.set_pos[i]
    return {}


def kinds() -> list[JobKind]:
    return [EXTERNAL]
