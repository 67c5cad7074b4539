"""The pure NC core: axis state machine, motion engine (jobs, set-point stages), monitoring.

No zenoh, no threads, no clock reads: a test drives it one cycle at a time.
"""
from .jobs import KINDS, Job, JobKind, JobQueue
from .nc import NcCore
from .params import ALIASES, AxisConfig, AxisParams, ConfigError, param_name
from .planning import Dynamics, Plan, PlanningError, StartState, plan_position, plan_velocity

__all__ = ["NcCore", "AxisConfig", "AxisParams", "ConfigError", "ALIASES", "param_name", "KINDS", "Job", "JobKind",
           "JobQueue", "Dynamics", "Plan", "PlanningError", "StartState", "plan_position", "plan_velocity"]
