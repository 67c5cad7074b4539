"""The pure NC core: axis state machine, set-point generation, monitoring.

No zenoh, no threads, no clock reads: a test drives it one cycle at a time.
"""
from .nc import NcCore
from .params import ALIASES, AxisConfig, AxisParams, ConfigError, param_name
from .profile import Limits, Planner, PlanningError

__all__ = ["NcCore", "AxisConfig", "AxisParams", "ConfigError", "ALIASES", "param_name", "Limits", "Planner",
           "PlanningError"]
