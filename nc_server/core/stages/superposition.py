"""The superposition stage: a relative motion added on top of an axis's set-points (TcMC 3.9-3.12).

Whatever produces the axis's set-points (its own plan, a coupling, the external generator, or
standstill) produces the *basic* motion; this stage adds the superimposed offset profile (a plan
of :func:`..superposition.plan_superposition`, jerk-limited like every plan) after it, level by
level with the couplings, so the slaves of an axis follow its total motion. Between cycles
``axes.S`` holds the total; ``NcCore.start_state`` gives the basic motion's state (total minus the
applied offset), so a command that replans the basic motion leaves the superposition running.

Ends: DONE (or ERROR 0x4243 when only part of Distance fitted) when the offset profile ends: the
final offset then becomes part of the basic motion (``NcCore.fold_offset``). MC_AbortSuperposition:
the superposition ends ABORTED at once, its offset brakes to rest with its Deceleration and is
folded. A stop of the axis, an error, Enable FALSE: ABORTED, and the stop plans from the total
state (the offset is part of it from then on). A new superposition while one runs takes over from
the running one's state (no jump; the old one ends ABORTED; what it had applied stays): this NC's
answer where TcMC is silent on re-triggering.
"""
from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from nc_schema import CmdState, ErrorCodes, StateDWord

from ..commands import core_command
from ..planning import Dynamics, StartState, plan_velocity
from ..profile import N_SEGMENTS, evaluate, velocity_extrema
from .profile import motion_dwords

if TYPE_CHECKING:
    from ..context import CoreContext
    from ..planning import Plan

_EPS_V = 1e-9
_DIR_BITS = np.uint32(int(StateDWord.NotMoving) | int(StateDWord.PositiveDirection) | int(StateDWord.NegativeDirection)
                      | int(StateDWord.ConstantVelocity))


class SuperpositionStage:
    """Per axis: the offset profile (``seg``, time ``t`` and ``dur``), the offset applied in this
    cycle (``applied``: p, v, a, j), and the slot the wire shows (cmd_no, state, error, actual values)."""

    name = "superposition"

    def __init__(self, n: int, cycle_time: float) -> None:
        self.dt = cycle_time
        self.on = np.zeros(n, dtype=bool)          # an offset profile runs (numbered or braking)
        self.seg = np.zeros((5, n, N_SEGMENTS))
        self.seg[0] = np.inf
        self.t = np.zeros(n)
        self.dur = np.zeros(n)
        self.applied = np.zeros((4, n))
        self.cmd_no = np.zeros(n, dtype=np.uint16)
        self.state = np.zeros(n, dtype=np.uint16)
        self.error = np.zeros(n, dtype=np.uint32)
        self.actual = np.zeros((3, n))              # ActualDistance, ActualVelocityDiff, ActualLength
        self.end_error = np.zeros(n, dtype=np.uint32)  # the error the running one ends with (0x4243)
        self.dyn: list[Dynamics | None] = [None] * n  # the command's dynamics (MC_AbortSuperposition brakes with them)
        self.client: list[str] = [""] * n           # who commanded it (the server stops it when that client is lost)
        self.rows = np.zeros(0, dtype=np.intp)
        self._values: np.ndarray | None = None     # this cycle's (4, len(rows)) offsets
        self.changed: list[int] = []               # rows whose slot changed (job records)

    @property
    def active(self) -> bool:
        return bool(self.rows.size)

    def start(self, i: int, plan: Plan, cmd_no: int, actual: tuple[float, float, float], end_error: int,
              dyn: Dynamics | None = None) -> None:
        """Run ``plan`` (from the current offset state) as superposition ``cmd_no`` of row ``i``."""
        self.dyn[i] = dyn
        if self.on[i] and self.state[i] == int(CmdState.ACTIVE):
            self.state[i] = int(CmdState.ABORTED)  # (a new one takes over)
        self.seg[:, i, :] = plan.seg
        self.t[i], self.dur[i] = 0.0, plan.duration
        self.on[i] = True
        self.cmd_no[i], self.state[i], self.error[i] = cmd_no, int(CmdState.ACTIVE), 0
        self.actual[:, i] = actual
        self.end_error[i] = end_error
        self._rows()

    def offset_state(self, i: int) -> StartState:
        """The superimposed offset now (a new superposition starts from it)."""
        p, v, a, _ = self.applied[:, i]
        return StartState(float(p), float(v), float(a))

    def brake(self, core: CoreContext, i: int) -> None:
        """MC_AbortSuperposition: the slot ends ABORTED now, the offset brakes to rest and is folded."""
        if not self.on[i]:
            return
        if self.state[i] == int(CmdState.ACTIVE):
            self.state[i] = int(CmdState.ABORTED)
            self.changed.append(i)
        a = core.axes
        dyn = self.dyn[i] or core.dynamics(i, {}, None)
        try:
            plan = plan_velocity(self.offset_state(i), 0.0, dyn.with_(velocity=float(a.vmax[i])))
        except Exception:  # cannot plan a brake: fold what is applied now (the NC's stop rule: never keep moving)
            self.abort(core, i)
            return
        self.seg[:, i, :] = plan.seg
        self.t[i], self.dur[i] = 0.0, plan.duration
        self.end_error[i] = 0

    def abort(self, core: CoreContext, i: int) -> None:
        """End row ``i``'s superposition now: what it applied becomes part of the basic motion
        (the caller plans from the total state, or the axis stands)."""
        if not self.on[i] and not self.applied[:, i].any():
            return
        if self.state[i] == int(CmdState.ACTIVE):
            self.state[i] = int(CmdState.ABORTED)
        self.on[i] = False
        self.applied[:, i] = 0.0
        self._rows()
        self.changed.append(i)

    def _rows(self) -> None:
        self.rows = self.on.nonzero()[0]

    # -- the cycle ----------------------------------------------------------------------------
    def unapply(self, core: CoreContext) -> None:
        """Cycle start: the set-points of the rows return to their basic motion."""
        core.axes.S[:, self.rows] -= self.applied[:, self.rows]

    def evaluate(self) -> None:
        """This cycle's offsets of every running superposition."""
        r = self.rows
        self.t[r] += self.dt
        t = np.minimum(self.t[r], self.dur[r])  # (at rest after its end)
        p, v, a, j = evaluate(self.seg, t, r)
        self._values = np.stack((p, v, a, np.broadcast_to(j, p.shape)))
        self.applied[:, r] = self._values

    def apply(self, core: CoreContext, rows: np.ndarray) -> None:
        """Add the offsets to those of ``rows`` that have a superposition (after their basic motion)."""
        r = rows[self.on[rows]]
        if not r.size:
            return
        S = core.axes.S
        S[:, r] += self.applied[:, r]
        v = S[1, r]
        dw = core.sp_dw[r] & ~_DIR_BITS
        dw |= motion_dwords(v)
        core.sp_dw[r] = dw

    def ended(self, core: CoreContext) -> list[int]:
        """Rows whose offset profile ended in this cycle: their slot ends (DONE, or ERROR with the
        reduced-distance code) and the offset is folded into the basic motion."""
        r = self.rows
        done = r[self.t[r] >= self.dur[r]]
        ended: list[int] = done.tolist()
        for i in ended:
            offset = float(self.applied[0, i])
            if self.state[i] == int(CmdState.ACTIVE):
                code = int(self.end_error[i])
                self.state[i] = int(CmdState.ERROR if code else CmdState.DONE)
                self.error[i] = code
            self.on[i] = False
            self.applied[:, i] = 0.0
            core.fold_offset(i, offset)
            self.changed.append(i)
        if done.size:
            self._rows()
        return ended

    def limits(self, core: CoreContext) -> list[tuple[int, int]]:
        """(row, code) of the rows whose total motion goes beyond AxisVeloMax (0x4359; the fault ramp
        keeps it within a cycle of acceleration of it) or max(AxisAcc, AxisDec) (0x422F); the NC
        faults them."""
        r = self.rows
        a = core.axes
        v, acc = a.S[1, r], a.S[2, r]
        fast = np.abs(v) > a.vmax[r] * (1 + 1e-6) + _EPS_V
        hard = np.abs(acc) > np.maximum(a.acc[r], a.dec[r]) * (1 + 1e-6) + 1e-6
        return ([(int(i), int(ErrorCodes.NC_AXIS_SET_VELOCITY)) for i in r[fast].tolist()]
                + [(int(i), int(ErrorCodes.NC_ACCELERATION_NOT_ALLOWED)) for i in r[hard & ~fast].tolist()])


_INCOMPLETE = int(ErrorCodes.NC_COMPENSATION_INCOMPLETE)


@core_command("MoveSuperImposed", motion=True)
def cmd_move_superimposed(core: CoreContext, i: int, req: dict[str, Any]) -> dict[str, Any]:
    """MoveSuperImposed (MC_MoveSuperImposed / MC_MoveSuperImposedExt, TcMC 3.9/3.10: Infosys
    https://infosys.beckhoff.com/content/1033/tcplclibmc/10988419339.html and .../10988420875.html):
    plan and start the offset profile. The reference velocity for Length is |VelocityProcess|
    ("absolute value > 0": 0 is refused with 0x4B06), in the direction the basic motion travels
    (a standing axis: positive, and the window |Length| / |VelocityProcess| in every mode:
    :func:`..superposition.plan_superposition`).
    "Jerk: the jerk value is not used": the offset profile is limited by AxisJerk whatever the
    request's Jerk (no check either); Acceleration/Deceleration 0 = AxisAcc/AxisDec.

    Raises:
        NcError: the start checks of any motion; 0x4B04 unknown Mode; 0x4B06 Distance 0,
            VelocityDiff, Length or VelocityProcess not > 0; 0x422F/0x4230 bad dynamics; 0x427E
            unplannable.
    """
    from ..superposition import plan_superposition  # (pure planning, like ..planning)

    from nc_schema import NcError, next_cmdno

    core.check_startable(i)
    if core.axes.homing[i]:
        raise NcError(ErrorCodes.MC_AXIS_CANNOT_BE_STARTED, "the axis is homing (PLCopen: Homing accepts only MC_Stop)")
    mode = req.get("Mode", 4)
    if mode not in (1, 2, 3, 4):
        raise NcError(ErrorCodes.MC_INVALID_MODE, f"Mode {mode} is not an E_SuperpositionMode (1..4)")
    # (no Jerk: TcMC does not use it; AxisJerk)
    dyn = core.dynamics(i, {"Acceleration": req.get("Acceleration", 0.0), "Deceleration": req.get("Deceleration", 0.0)},
                        None)
    base = core.start_state(i)
    vp = abs(float(req.get("VelocityProcess", 0.0) or 0.0))
    if not vp > 0:
        raise NcError(ErrorCodes.MC_PARAMETER_NOT_CORRECT, "VelocityProcess must be non-zero (TcMC: absolute value > 0)")
    standing = abs(base.v) <= _EPS_V
    v_ref = vp if base.v >= 0 else -vp
    stage = core.superposition
    start = stage.offset_state(i) if stage.on[i] else StartState(0.0)
    try:
        sp = plan_superposition(int(mode), float(req["Distance"]), abs(float(req["VelocityDiff"])), dyn.acceleration,
                                dyn.deceleration, dyn.jerk, v_ref, float(req["Length"]), start, standing)
    except ValueError as exc:
        raise NcError(ErrorCodes.MC_PARAMETER_NOT_CORRECT, str(exc)) from None
    except Exception as exc:  # (planning.PlanningError)
        raise NcError(ErrorCodes.NC_MOTION_NOT_REALIZED, f"the superposition cannot be planned ({exc})") from None
    # the total velocity must stay within AxisVeloMax (the basic motion as it is now plus the offset's peak)
    lo, hi = velocity_extrema(sp.plan.seg)
    vmax = float(core.axes.vmax[i])
    if max(abs(base.v + lo), abs(base.v + hi)) > vmax * (1 + 1e-9):
        raise NcError(ErrorCodes.NC_VELOCITY_NOT_ALLOWED,
                      f"velocity {base.v:.6g} + superimposed up to {sp.velocity_diff:.6g} would exceed AxisVeloMax {vmax:g}")
    q = core.queues[i]
    job = q.running_numbered
    a = core.axes
    if a.en_max[i] or a.en_min[i]:
        # where the basic motion ends (standing, or a positioning job's target) plus all offsets
        basic_end = base.p if job is None else (job.target if job.target is not None and not job.continuous else None)
        if basic_end is not None:
            end = basic_end + sp.plan.end.p
            if (a.en_max[i] and end > a.max_lim[i]) or (a.en_min[i] and end < a.min_lim[i]):
                raise NcError(ErrorCodes.NC_TARGET_POSITION_NOT_ALLOWED,
                              f"the superimposed motion would end at {end:.6g}, beyond a software limit")
    if job is None:
        a.stopped[i] = False  # (a new motion: HasBeenStopped goes, as with the next motion command)
    cmd_no = q.newest = next_cmdno(q.newest)
    stage.start(i, sp.plan, cmd_no, (sp.distance, sp.velocity_diff, sp.length), _INCOMPLETE if sp.incomplete else 0, dyn)
    stage.client[i] = str(req.get("client") or "")
    stage.changed.append(i)
    core.state_dirty = True
    return {"cmd_no": cmd_no, "value": {"ActualDistance": sp.distance, "ActualVelocityDiff": sp.velocity_diff,
                                        "ActualLength": sp.length, "Incomplete": bool(sp.incomplete)}}


@core_command("AbortSuperposition")
def cmd_abort_superposition(core: CoreContext, i: int, req: dict[str, Any]) -> dict[str, Any]:
    """AbortSuperposition: see :meth:`SuperpositionStage.brake` (none running: nothing changes)."""
    core.superposition.brake(core, i)
    core.state_dirty = True
    return {}
