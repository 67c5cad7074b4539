"""Job kinds of the motion engine, one module per family (see :mod:`.base` for the interface).

``KINDS`` maps each motion command of the wire contract to the kind that executes it; adding a
kind means adding a module and listing it here -- the NC core does not change.
"""
from __future__ import annotations

from . import external, gearing, homing, position, stop, velocity
from .base import Job, JobKind, JobQueue

KINDS: dict[str, JobKind] = {}
for _module in (position, velocity, stop, homing, gearing, external):
    for _kind in _module.kinds():
        for _cmd in _kind.commands:
            KINDS[_cmd] = _kind

__all__ = ["KINDS", "Job", "JobKind", "JobQueue"]
