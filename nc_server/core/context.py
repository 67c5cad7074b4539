"""The narrow context the job kinds (:mod:`.jobs`) and the set-point stages (:mod:`.stages`) see of the NC.

They type against :class:`CoreContext`, never against ``NcCore``: these members (all public) are
the whole plug-in interface, so a change behind it (the queue, the records, the cycle) needs no
kind or stage to be read. ``NcCore`` implements it (checked in tests/core/test_core_seams.py).

Records: a kind never syncs the job records; the job engine does after every hook. A hook that
changes its job without :meth:`~CoreContext.set_plan` / :meth:`~CoreContext.clear_profile` /
:meth:`~CoreContext.continue_plan` (e.g. only its phase) says so with :meth:`~CoreContext.touch`.

It may import: numpy and the core's types (TYPE_CHECKING only).
"""
from __future__ import annotations

from typing import TYPE_CHECKING, Any, Callable, Mapping, Protocol

import numpy as np

if TYPE_CHECKING:
    from nc_schema import CmdState

    from ..drives.base import DriveABC
    from .axes import AxisTable
    from .jobs.base import Job, JobKind, JobQueue
    from .params import AxisParams
    from .planning import Dynamics, Plan, StartState
    from .stages import CouplingStage, ExternalStage, ProbeStage, SuperpositionStage


class CoreContext(Protocol):
    """What a job kind or a set-point stage may read and call on the NC (one axis row ``i``)."""

    # -- the NC's tables (read; the columns of ``axes`` are written by the kinds that own them) --
    axes: AxisTable
    queues: list[JobQueue]
    params: list[AxisParams]
    drive: DriveABC
    cycle_time: float
    nc_time_ns: int
    #: applied PLCTONC records; ``plctonc_arrived``: a frame came since the last cycle (external feed)
    plctonc: np.ndarray
    plctonc_arrived: np.ndarray
    ncjobs: np.ndarray
    act_pos: np.ndarray
    prev_act_pos: np.ndarray
    #: the set-point StateDWord bits and AxisState the stages write (``sp_words`` = both, stacked)
    sp_words: np.ndarray
    sp_dw: np.ndarray
    axis_state: np.ndarray
    #: rows following a plan; all rows do; a plan origin is non-zero somewhere (the profile stage)
    on_rows: np.ndarray
    all_on: bool
    has_origin: bool
    #: derived state and records are recomputed before their next use (set on events)
    state_dirty: bool
    #: a command runs now, between cycles (``NcCore.execute`` / ``NcCore.prepare``): planning may spend
    #: more there (a blending end velocity searched by bisection); False in the cycle (an override
    #: change, a buffered job taking over), which keeps its cost bounded
    refine_plans: bool

    # -- the set-point stages ---------------------------------------------------------------
    superposition: SuperpositionStage
    coupling: CouplingStage
    external: ExternalStage
    probe: ProbeStage

    # -- reading ------------------------------------------------------------------------------
    def index(self, axis_id: int) -> int: ...
    def start_state(self, i: int, total: bool = False) -> StartState: ...
    def nc_set_pos(self, i: int) -> float: ...
    def override(self, i: int) -> float: ...
    def cam(self, rows: np.ndarray) -> np.ndarray: ...
    def plan_end_state(self, i: int) -> tuple[StartState, float]: ...

    # -- checks (NcError on failure; nothing changes) -------------------------------------------
    def dynamics(self, i: int, req: Mapping[str, Any], velocity: float | None) -> Dynamics: ...
    def stop_dynamics(self, i: int, dec: float = 0.0, jerk: float = 0.0, running: Job | None = None) -> Dynamics: ...
    def check_startable(self, i: int) -> None: ...
    def check_velocity(self, i: int, v: float) -> None: ...
    def check_feed(self, i: int, sense: float) -> None: ...
    def check_target(self, i: int, start: float, target: float, plan: Plan | None = None) -> None: ...
    def check_overshoot(self, i: int, plan: Plan, v_new: float) -> None: ...
    def check_reversal(self, i: int, plan: Plan, start: StartState, sense: float, target: float | None = None,
                       running: Job | None = None) -> None: ...
    def stop_within(self, i: int, plan: Plan, running: Job | None) -> bool: ...
    def plan(self, fn: Callable[..., Plan], *args: Any) -> Plan: ...

    # -- changing the row's motion --------------------------------------------------------------
    def set_plan(self, i: int, plan: Plan, elapsed: float = 0.0) -> None: ...
    def continue_plan(self, i: int, plan: Plan) -> None: ...
    def clear_profile(self, i: int, keep_velocity: bool = False) -> None: ...
    def shift_position(self, i: int, diff: float) -> None: ...
    def fold_offset(self, i: int, offset: float) -> None: ...
    def touch(self, i: int) -> None: ...
    def jobs_written(self) -> None: ...

    # -- the job lifecycle (the engine's) -----------------------------------------------------
    def begin(self, i: int, job: Job, plan: Plan | None, abort_waiting: bool = True) -> None: ...
    def finish(self, i: int, job: Job, state: CmdState = ..., error_id: int = 0) -> None: ...
    def start_ramp(self, i: int, kind: JobKind, running: Job | None) -> None: ...
    def fault(self, i: int, code: int) -> None: ...
