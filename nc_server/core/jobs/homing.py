"""MC_Home: the NC's calibration sequence (HomingState of NCTOPLC, spec 000), and the homing modes
of Tc2_MC2 that need no motion.

MC_DefaultHoming, with the reference cam from the PLC (PLCTONC ControlDWord.HomingSensor) and the
drive's sync pulse latch (``DriveABC.latch_sync_pulse``):

1 START_TOWARDS_CAM   start towards the cam (AxisCalibrationVelocityForward; negative direction
                      unless AxisInvertCalibrationCamSearchDirection is False); cam already
                      occupied: straight to 3
2 WAIT_CAM_EDGE       wait for the rising cam edge, then stop
3 WAIT_STOP_THEN_SYNC when stopped, start off the cam towards the sync pulse
                      (AxisCalibrationVelocityBackward; positive unless
                      AxisInvertSyncPulseSearchDirection)
4 WAIT_CAM_FALLING    wait for the falling cam edge, judged by the ACTUAL motion, not by the cam
                      level when state 4 starts (the level is a cycle or two old and the actual
                      position overshoots after the set position stops): a cam fall (TRUE ->
                      FALSE, or FALSE seen) while the actual position moves in the cam-search
                      direction, the sync search being opposite, is the axis leaving the far side
                      of a narrow cam while braking (in state 3 or 4): the cam must be crossed
                      again, rise and fall; a fall or FALSE level at rest or while moving in the
                      sync-search direction is the edge: the latch is armed (5). So going on in
                      the search direction beyond a narrow cam, the edge lay in the braking, and
                      a cam FALSE at rest when state 4 starts (a PLC clearing its cam at
                      HomingState >= 3) is the edge: armed at once.
                      "Moving" = the actual position moved more than 1e-6 u in that direction in
                      this or the previous cycle (the cam level lags the position it was read
                      at); a cam that disappears for good while the axis goes back for it is not
                      detected (the axis goes on at AxisCalibrationVelocityBackward)
5 WAIT_LATCH          latch armed: wait for the sync pulse, then stop
6 SET_POSITION        when stopped, set the actual position: the latched position becomes the
                      reference position (MC_Home.Position, or AxisCalibrationValue for
                      DEFAULT_HOME_POSITION), i.e. the axis stands at reference + braking distance
0 READY               done; Homed is set (it is cleared when the sequence starts)

Homing without a cam (TcMC 3.14): the PLC sets the cam first and clears it once HomingState >= 4.
MC_Direct sets the actual position to Position; MC_ForceCalibration / MC_ResetCalibration set /
clear Homed; the other MC_HomingMode values are not implemented (0x4B04), as in Tc2_MC2.
Homing starts only from standstill: on a moving axis it is refused with 0x4B01 (buffer it instead).
"""
from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any, Mapping

import numpy as np

from nc_schema import DEFAULT_HOME_POSITION, ErrorCodes, HomingState, MC_BufferMode, MC_HomingMode, NcError

from ..planning import Plan, StartState, hold, plan_velocity
from .base import Job, JobKind

if TYPE_CHECKING:
    from ..context import CoreContext

_DEFAULT = int(MC_HomingMode.MC_DefaultHoming)
_DIRECT = int(MC_HomingMode.MC_Direct)
_FORCE = int(MC_HomingMode.MC_ForceCalibration)
_RESET = int(MC_HomingMode.MC_ResetCalibration)
S1, S2, S3, S4, S5, S6 = (int(HomingState.START_TOWARDS_CAM), int(HomingState.WAIT_CAM_EDGE),
                          int(HomingState.WAIT_STOP_THEN_SYNC), int(HomingState.WAIT_CAM_FALLING),
                          int(HomingState.WAIT_LATCH), int(HomingState.SET_POSITION))
#: an actual-position step per cycle up to this counts as rest (judging the cam edge in S3/S4)
_AT_REST = 1e-6


class HomeKind(JobKind):
    name = "Home"
    commands = ("Home",)
    buffer_modes = frozenset({int(MC_BufferMode.MC_Aborting), int(MC_BufferMode.MC_Buffered)})
    homing = True
    follows_override = False
    watches = True

    def accept(self, core: CoreContext, i: int, req: Mapping[str, Any], prev: Job | None) -> Job:
        mode = req["HomingMode"]
        if mode not in (_DEFAULT, _DIRECT, _FORCE, _RESET):
            raise NcError(ErrorCodes.MC_INVALID_MODE, f"HomingMode {mode} is not implemented (as in Tc2_MC2)")
        if req.get("BufferMode", 0) == int(MC_BufferMode.MC_Aborting) and (prev is not None or core.axes.traj_on[i]):
            # PLCopen: Homing only from StandStill -- also a job waiting at override 0 is a motion
            raise NcError(ErrorCodes.MC_AXIS_CANNOT_BE_STARTED, "homing starts only from standstill (buffer it instead)")
        pos = req["Position"]
        ref = core.params[i].AxisCalibrationValue if pos >= DEFAULT_HOME_POSITION else float(pos)
        if not abs(ref) < 1e9:
            raise NcError(ErrorCodes.MC_PARAMETER_NOT_CORRECT, f"Position {pos} outside +/-1e9")
        return Job(self, dict(req), dyn=core.dynamics(i, {}, None), data={"mode": mode, "ref": ref})

    def activate(self, core: CoreContext, i: int, job: Job, start: StartState) -> Plan:
        if abs(start.v) > 1e-9 or core.superposition.on[i]:  # (a buffered Home: the predecessor's end, at rest)
            raise NcError(ErrorCodes.MC_AXIS_CANNOT_BE_STARTED, "homing starts only from standstill")
        job.data.update(cleared=False, latched=None)
        if job.data["mode"] != _DEFAULT:
            job.phase = 0
            return hold(start.p)  # takes effect in its first cycle (on_end)
        if bool(core.cam(np.array([i]))[0]):
            job.phase = S3  # cam already occupied: leave it towards the sync pulse (S3 shown one cycle)
            job.data["s3_at_rest"] = True
            return hold(start.p)
        # else the cam is read again one cycle later (watch): its PLCTONC may follow the command
        p = core.params[i]
        core.check_feed(i, -1.0 if p.AxisInvertCalibrationCamSearchDirection else 1.0)
        job.phase = S1
        return hold(start.p)

    def on_end(self, core: CoreContext, i: int, job: Job) -> str:
        a = core.axes
        mode = job.data["mode"]
        if mode != _DEFAULT:
            if mode == _DIRECT:
                core.shift_position(i, job.data["ref"] - float(core.act_pos[i]))
            a.homed[i] = mode != _RESET
            return "done"
        if job.phase in (S2, S4, S5):
            return "steady"  # constant velocity, waiting for an edge
        if job.phase == S1:
            return "steady"  # at rest until watch() has seen the cam
        if job.phase == S3:  # stopped: off the cam towards the sync pulse
            if job.data.pop("s3_at_rest", False):
                return "steady"  # started on the cam: show state 3 for this cycle, leave it next (watch)
            self._leave_cam(core, i, job)
            return "continue"
        if job.phase == S6:  # stopped after the latch: the latched position is the reference position
            latched = job.data["latched"]
            core.shift_position(i, job.data["ref"] - latched)
            a.homed[i] = True
            return "done"
        return "done"

    def watch(self, core: CoreContext, rows: np.ndarray) -> None:
        a = core.axes
        cam = core.cam(rows)
        for n, i in enumerate(rows.tolist()):
            job = core.queues[i].active
            if job is None or not job.numbered:
                continue
            if not job.data["cleared"] and job.data["mode"] == _DEFAULT:
                job.data["cleared"] = True
                a.homed[i] = False
                core.touch(i)
            ph = job.phase
            if ph == S1:  # shown for one cycle, then: cam occupied -> leave it, else search it
                if not job.data.get("s1_shown"):
                    job.data["s1_shown"] = True
                    continue
                if cam[n]:
                    self._leave_cam(core, i, job)
                    continue
                p = core.params[i]
                sense = -1.0 if p.AxisInvertCalibrationCamSearchDirection else 1.0
                v = p.AxisCalibrationVelocityForward
                core.set_plan(i, core.plan(plan_velocity, core.start_state(i), sense * v,
                                           job.dyn.with_(velocity=v)))
                job.phase = S2
                continue
            if ph == S3 and a.traj_dur[i] == np.inf:  # started on the cam: show state 3, then leave it
                if job.data.get("s3_shown"):
                    self._leave_cam(core, i, job)
                else:
                    job.data["s3_shown"] = True
                continue
            if job.phase == S2 and cam[n]:
                self._stop(core, i, job, S3)
            elif ph in (S3, S4):
                # the edge by the actual motion (module doc): leaving the cam's far side while
                # braking in the search direction means it must be crossed again
                step = float(core.act_pos[i] - core.prev_act_pos[i])
                moved = (step, job.data.get("last_step", 0.0))
                job.data["last_step"] = step
                p = core.params[i]
                search = -1.0 if p.AxisInvertCalibrationCamSearchDirection else 1.0
                sync = -1.0 if p.AxisInvertSyncPulseSearchDirection else 1.0
                if cam[n]:
                    job.data["cross_again"] = False
                elif sync != search and any(d * search > _AT_REST for d in moved):
                    job.data["cross_again"] = True
                elif ph == S4 and not job.data.get("cross_again"):  # the falling edge
                    job.phase = S5
                    job.data["armed_at"] = float(core.act_pos[i])
                    core.touch(i)  # (HomingState shows the phase)
            elif ph == S5:
                # the latch reports drive positions: compare in the drive's frame
                off = float(a.offset[i])
                got = core.drive.latch_sync_pulse(np.array([i]), np.array([core.prev_act_pos[i] - off]))[0]
                if not math.isnan(got):
                    job.data["latched"] = float(got) + off
                    self._stop(core, i, job, S6)

    def shift(self, job: Job, diff: float) -> None:
        super().shift(job, diff)
        for key in ("latched", "armed_at"):  # NC positions of the sequence
            if job.data.get(key) is not None:
                job.data[key] += diff

    def _leave_cam(self, core: CoreContext, i: int, job: Job) -> None:
        p = core.params[i]
        sense = -1.0 if p.AxisInvertSyncPulseSearchDirection else 1.0
        try:
            core.check_feed(i, sense)
        except NcError as err:
            core.fault(i, err.code)
            return
        job.phase = S4  # waits for the falling cam edge (watch; module doc)
        v = p.AxisCalibrationVelocityBackward
        # (the ignore: a homing job's dyn is set on accept)
        core.set_plan(i, core.plan(plan_velocity, core.start_state(i), sense * v, job.dyn.with_(velocity=v)))  # type: ignore[union-attr]

    def _stop(self, core: CoreContext, i: int, job: Job, phase: int) -> None:
        job.phase = phase
        d = core.stop_dynamics(i)
        core.set_plan(i, core.plan(plan_velocity, core.start_state(i), 0.0, d))


def kinds() -> list[JobKind]:
    return [HomeKind()]
