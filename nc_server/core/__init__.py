"""The pure NC core: axis state machine, motion engine (jobs, set-point stages), monitoring.

Owns: :class:`NcCore` (the front: execute, step, PLCTONC in, parameters), the narrow
:class:`~.context.CoreContext` jobs and stages type against, the job lifecycle (:mod:`.engine`), the
pure checks (:mod:`.checks`), the record packing (:mod:`.packing`), the cycle's pipeline
(:mod:`.pipeline`) and the command registry (:mod:`.commands`: every core command registered where it
is implemented, checked against ``schema/protocol.json``).

May import: ``nc_schema``, numpy, ruckig, ``nc_server.drives``; never zenoh, threads or a client package.
No zenoh, no threads; the only clock reads are the pipeline's per-stage timing (stats ``stages``): a test
drives the core one cycle at a time.
"""
from .jobs import KINDS, Job, JobKind, JobQueue
from .nc import NcCore
from .params import ALIASES, AxisConfig, AxisParams, ConfigError, param_name
from .planning import Dynamics, Plan, PlanningError, StartState, plan_position, plan_velocity
from .remote import MasterSample

__all__ = ["NcCore", "AxisConfig", "AxisParams", "ConfigError", "ALIASES", "param_name", "KINDS", "Job", "JobKind",
           "JobQueue", "Dynamics", "Plan", "PlanningError", "StartState", "plan_position", "plan_velocity",
           "MasterSample"]
