"""Gearing (TcMC 3.17-3.21): the coupling job of a slave, and the decoupling commands.

MC_GearIn / MC_GearInFloat / MC_GearInDyn make a coupling *job* on the slave: numbered (the
block follows its CmdNo), ACTIVE while the slave is coupled, and the source of the slave's
set-points is then the coupling stage (:mod:`..stages.coupling`), not a plan. The job ends like
any job: DONE by MC_GearOut/MC_GearOutExt, ABORTED by another command that takes the slave
(MC_Stop; a motion command with AxisAllowMotionCmdToSlave; Enable FALSE), ERROR on an axis error.

MC_GearInDyn on a slave already coupled to the same master takes that coupling over (a new job,
the old one ABORTED): the applied ratio stays and moves to the new one within the rate limit,
without a jump (TcMC 3.19: after the falling edge "a rising edge at Execute will then be accepted").

Refusals (nothing changes): RatioDenominator 0, a non-finite ratio or one beyond +/-1e6, the
slave as its own master or a chain that would close a cycle: 0x4B06 (MC_PARAMETER_NOT_CORRECT,
the Master or ratio input is not correct); an unknown master: 0x4012; an already coupled slave:
0x4B08 (the axis is in protected mode: coupled); a slave that moves: 0x4B01 (TcMC: coupling
only at standstill); the usual start checks (error, MC_Stop lock, no enable): as for any move.

MC_GearOut: a moving slave reduces its acceleration to zero with its AxisJerk and goes on at the
velocity it then has (a numbered MoveVelocity job: ContinuousMotion, TcMC 3.20 "comparable to a
move commanded by MC_MoveVelocity"). MC_GearOutExt continues with the command of its Mode from
the slave's set-point state of this cycle (seamless; TcMC 3.21); at standstill both just decouple.
A superposition running on the slave ends with the coupling (ABORTED; what it applied stays).
"""
from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any, Mapping

from nc_schema import CmdState, E_DecoupleMode, ErrorCodes, MC_Direction, NcError

from ..commands import REGISTRY, core_command
from ..planning import Plan, StartState
from ..stages.coupling import MAX_RATIO
from .base import Job, JobKind

if TYPE_CHECKING:
    from ..context import CoreContext

_EPS_V = 1e-9


class GearInKind(JobKind):
    """MC_GearIn, MC_GearInFloat, MC_GearInDyn: the slave follows its master."""

    name = "GearIn"
    commands = ("GearIn", "GearInFloat", "GearInDyn")
    follows_override = False  # the master's override moves the slave; its own does not
    source = "coupling"

    def accept(self, core: CoreContext, i: int, req: Mapping[str, Any], prev: Job | None) -> Job:
        cmd = req["cmd"]
        if cmd == "GearIn":
            num, den = req["RatioNumerator"], req["RatioDenominator"]
            if not -32768 <= num <= 32767:
                raise NcError(ErrorCodes.MC_PARAMETER_NOT_CORRECT, f"RatioNumerator {num} is not an INT")
            if not 0 < den <= 65535:
                raise NcError(ErrorCodes.MC_PARAMETER_NOT_CORRECT, f"RatioDenominator {den}: must be 1..65535 (UINT, not 0)")
            ratio = num / den
        else:
            ratio = float(req["GearRatio"])
            if not (math.isfinite(ratio) and abs(ratio) <= MAX_RATIO):
                raise NcError(ErrorCodes.MC_PARAMETER_NOT_CORRECT, f"GearRatio {ratio}: must be finite, |ratio| <= {MAX_RATIO:g}")
        master_nc = str(req.get("MasterNc") or "")
        if master_nc:  # a master on another NC (stages/coupling.py, remote.py)
            if cmd == "GearInDyn":
                raise NcError(ErrorCodes.MC_PARAMETER_NOT_CORRECT,
                              "MC_GearInDyn with a master on another NC is not supported (MC_GearIn / MC_GearInFloat)")
            k = core.coupling.sources.find(master_nc, int(req["Master"]))
            return Job(self, dict(req), data={"master": -1, "remote": k, "ratio": ratio, "dyn": False, "rate": 0.0})
        m = core.index(req["Master"])
        if m == i:
            raise NcError(ErrorCodes.MC_PARAMETER_NOT_CORRECT, "an axis cannot be its own master")
        dyn = cmd == "GearInDyn"
        rate = 0.0
        if dyn:
            acc = req.get("Acceleration", 0.0) or 0.0
            if not (acc >= 0 and math.isfinite(acc)):
                raise NcError(ErrorCodes.NC_ACCELERATION_NOT_ALLOWED, f"Acceleration {acc} must be >= 0")
            # TcMC 3.19: the slave reaches Acceleration from ratio changes at the master's AxisVeloMax
            rate = (acc or float(core.axes.acc[i])) / float(core.axes.vmax[m])
        return Job(self, dict(req), data={"master": m, "remote": -1, "ratio": ratio, "dyn": dyn, "rate": rate})

    def activate(self, core: CoreContext, i: int, job: Job, start: StartState) -> Plan | None:
        a, cpl = core.axes, core.coupling
        m = int(job.data["master"])
        if int(job.data["remote"]) >= 0:
            self._check_remote(core, i, job, start)
            return None
        if cpl.is_slave(i):
            if job.data["dyn"] and int(cpl.master[i]) == m:
                return None  # MC_GearInDyn again (TcMC 3.19): it takes the coupling over at its ratio
            raise NcError(ErrorCodes.MC_AXIS_PROTECTED, f"axis {int(a.ids[i])} is already coupled (MC_GearOut first)")
        if cpl.closes_cycle(i, m):
            raise NcError(ErrorCodes.MC_PARAMETER_NOT_CORRECT,
                          f"axis {int(a.ids[m])} is (through a chain) a slave of axis {int(a.ids[i])}: the coupling would close a cycle")
        if a.traj_on[i] or abs(start.v) > _EPS_V or abs(start.a) > 1e-9 or core.superposition.on[i]:
            raise NcError(ErrorCodes.MC_AXIS_CANNOT_BE_STARTED, "the slave is moving: TcMC couples at standstill only")
        if not a.enabled[m]:
            # a disabled master's set position follows its actual position: no slave follows that
            raise NcError(ErrorCodes.NC_NO_ENABLE, f"the master axis {int(a.ids[m])} has no controller enable")
        v = abs(float(job.data["ratio"]) * float(a.set_velo[m]))
        if v > float(a.vmax[i]) * (1 + 1e-9):
            raise NcError(ErrorCodes.NC_VELOCITY_NOT_ALLOWED,
                          f"ratio x master velocity = {v:.6g} exceeds the slave's AxisVeloMax {float(a.vmax[i]):g}")
        return None

    def _check_remote(self, core: CoreContext, i: int, job: Job, start: StartState) -> None:
        """activate's checks for a master on another NC (nothing changes; on_begin couples)."""
        a, cpl = core.axes, core.coupling
        k = int(job.data["remote"])
        if cpl.is_slave(i):
            raise NcError(ErrorCodes.MC_AXIS_PROTECTED, f"axis {int(a.ids[i])} is already coupled (MC_GearOut first)")
        t_next = core.nc_time_ns + int(round(core.cycle_time * 1e9))
        cpl.sources.check_fresh(k, t_next)
        if a.traj_on[i] or abs(start.v) > _EPS_V or abs(start.a) > 1e-9 or core.superposition.on[i]:
            raise NcError(ErrorCodes.MC_AXIS_CANNOT_BE_STARTED, "the slave is moving: TcMC couples at standstill only")
        st = cpl.sources.state(k, t_next)
        assert st is not None  # (fresh)
        v = abs(float(job.data["ratio"]) * st[1])
        if v > float(a.vmax[i]) * (1 + 1e-9):
            raise NcError(ErrorCodes.NC_VELOCITY_NOT_ALLOWED,
                          f"ratio x master velocity = {v:.6g} exceeds the slave's AxisVeloMax {float(a.vmax[i]):g}")

    def on_begin(self, core: CoreContext, i: int, job: Job) -> None:
        d = job.data
        if int(d["remote"]) >= 0:
            core.coupling.couple_remote(core, i, int(d["remote"]), float(d["ratio"]))
            return
        core.coupling.couple(core, i, int(d["master"]), float(d["ratio"]), bool(d["dyn"]), float(d["rate"]),
                             float(core.plctonc["GearRatio1"][i]))


GEAR_IN = GearInKind()


def v_end_of(start: StartState, jerk: float) -> float:
    """The velocity reached when the acceleration is brought to zero with ``jerk`` [u/s]."""
    return start.v + start.a * abs(start.a) / (2.0 * jerk)


def _coupling_job(core: CoreContext, i: int) -> Job:
    job = core.queues[i].active
    if job is None or job.kind is not GEAR_IN:
        raise NcError(ErrorCodes.MC_COMMAND_NOT_PERMITTED, f"axis {int(core.axes.ids[i])} is not coupled")
    return job


@core_command("GearOut", "GearOutExt", motion=True)
def gear_out(core: CoreContext, i: int, req: Mapping[str, Any]) -> dict[str, Any]:
    """MC_GearOut and MC_GearOutExt (see the module docstring). Returns the follow-on command's
    CmdNo (none at standstill). A follow-on command that cannot start (e.g. a NEWPOS target beyond
    a software limit, a missing feed enable) refuses the request: the slave stays coupled. Not so
    Mode ORIENTEDSTOP with its oriented position beyond an enabled software limit: as MC_OrientedStop
    (TcMC 3.16 fault condition) it is accepted, the slave is decoupled and makes the standard stop,
    and the follow-on job ends ERROR 0x4222 (``OrientedStopKind``)."""
    job = _coupling_job(core, i)
    a = core.axes
    start = core.start_state(i, total=True)  # (a superposition of the slave ends with the coupling)
    mode = int(req.get("Mode", E_DecoupleMode.MC_DECOUPLEMODE_ENDLESS)) if req["cmd"] == "GearOutExt" else int(
        E_DecoupleMode.MC_DECOUPLEMODE_ENDLESS)
    if mode not in {int(x) for x in E_DecoupleMode}:
        raise NcError(ErrorCodes.MC_INVALID_MODE, f"Mode {mode} is not an E_DecoupleMode")
    standing = abs(start.v) <= _EPS_V and abs(start.a) <= 1e-9
    if standing or mode == int(E_DecoupleMode.MC_DECOUPLEMODE_INSTANTANEOUSSTOP):
        core.queues[i].end(job, CmdState.DONE)
        core.superposition.abort(core, i)
        core.clear_profile(i)  # (INSTANTANEOUSSTOP: the velocity jumps to zero, as TwinCAT's mode says)
        a.target_pos[i] = a.set_pos[i]
        return {}
    sense = 1.0 if v_end_of(start, float(a.jerk[i]) if not req.get("Jerk") else float(req["Jerk"])) > 0 else -1.0
    direction = int(MC_Direction.MC_Positive_Direction if sense > 0 else MC_Direction.MC_Negative_Direction)
    dyn_args = {k: req.get(k, 0.0) for k in ("Acceleration", "Deceleration", "Jerk")}
    jerk = dyn_args["Jerk"] or float(a.jerk[i])
    v_end = v_end_of(start, jerk)
    v_end = math.copysign(min(abs(v_end), float(a.vmax[i])), v_end)
    D = E_DecoupleMode
    if mode == int(D.MC_DECOUPLEMODE_STOP):
        cmd, args = "Halt", {"Deceleration": dyn_args["Deceleration"], "Jerk": dyn_args["Jerk"], "BufferMode": 0}
    elif mode == int(D.MC_DECOUPLEMODE_ORIENTEDSTOP):
        cmd, args = "OrientedStop", {"Position": req.get("Position", 0.0)}
    elif mode in (int(D.MC_DECOUPLEMODE_ENDLESS), int(D.MC_DECOUPLEMODE_ENDLESS_NEWVELO)):
        v = abs(v_end) if mode == int(D.MC_DECOUPLEMODE_ENDLESS) else req.get("Velocity", 0.0)
        if abs(v_end) <= _EPS_V and mode == int(D.MC_DECOUPLEMODE_ENDLESS):
            cmd, args = "Halt", {"Deceleration": 0.0, "Jerk": 0.0, "BufferMode": 0}
        else:
            cmd, args = "MoveVelocity", {"Velocity": v, "Direction": direction, **dyn_args, "BufferMode": 0}
    else:
        # (a hair above |v_end|: exactly the velocity at zero acceleration made ruckig plan a creeping profile)
        v = min(abs(v_end) * (1 + 1e-9), float(a.vmax[i])) if mode == int(D.MC_DECOUPLEMODE_NEWPOS) else req.get("Velocity", 0.0)
        cmd, args = "MoveAbsolute", {"Position": req.get("Position", 0.0), "Velocity": v, **dyn_args, "BufferMode": 0}
    follow = {"cmd": cmd, "id": req.get("id"), "client": req.get("client", ""), **args}
    kind = REGISTRY[cmd].kind  # (a job kind of another family: registered when gear_out runs)
    assert kind is not None
    new = kind.accept(core, i, follow, None)
    new.client = str(req.get("client") or "")
    plan = kind.activate(core, i, new, start)
    core.queues[i].end(job, CmdState.DONE)  # the coupling ended as commanded; the follow-on takes over
    core.superposition.abort(core, i)
    core.begin(i, new, plan)
    return {"cmd_no": new.cmd_no}


def kinds() -> list[JobKind]:
    return [GEAR_IN]
