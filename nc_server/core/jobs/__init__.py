"""Job kinds of the motion engine, one module per family (see :mod:`.base` for the interface).

Each family module lists its kinds (``kinds()``); each kind names the commands it executes
(``JobKind.commands``) and is registered for them in the command registry (:mod:`..commands`), checked
against the wire contract. Adding a kind means adding a module and listing it here -- the NC core does
not change. ``KINDS`` (command -> kind) is the registry's view of them.
"""
from __future__ import annotations

from ..commands import REGISTRY, register_kind
from . import external, gearing, homing, position, stop, velocity
from .base import Job, JobKind, JobQueue

for _module in (position, velocity, stop, homing, gearing, external):
    for _kind in _module.kinds():
        register_kind(_kind)
#: command -> the job kind that executes it (from the registry)
KINDS: dict[str, JobKind] = REGISTRY.kinds()

__all__ = ["KINDS", "Job", "JobKind", "JobQueue"]
