"""Drive an in-process NcCore cycle by cycle: build powered cores, send commands, step until a condition.

May import: ``nc_schema``, ``nc_server.core`` and :mod:`znc_testing.until`."""
from __future__ import annotations

import itertools
from typing import Any, Callable

from nc_schema import ControlDWord, MC_AxisStates, make_request, motion_state, parse_request
from nc_server.core import AxisConfig, AxisParams, NcCore
from znc_testing.until import step_until

ALL_ENABLES = int(ControlDWord.Enable | ControlDWord.FeedEnablePlus | ControlDWord.FeedEnableMinus)
_ids = itertools.count(1)


def make_core(n: int = 1, cycle_time: float = 0.001, drive_cls: Any = None, **params: Any) -> NcCore:
    """``n`` axes with ``params``; ``drive_cls``: the drive class (default: NcCore's default drive, cia402-sim)."""
    p = [AxisParams(**params) for _ in range(n)]
    drive = None if drive_cls is None else drive_cls(p, cycle_time)
    return NcCore([AxisConfig(i + 1, f"A{i + 1}", p[i]) for i in range(n)], cycle_time, drive=drive)


def powered(n: int = 1, cycle_time: float = 0.001, drive_cls: Any = None, **params: Any) -> NcCore:
    """A core whose axes are all enabled (controller + both feeds) and stepped once: StandStill."""
    core = make_core(n, cycle_time, drive_cls, **params)
    for i in range(n):
        power(core, i)
    core.step()
    return core


def power(core: NcCore, i: int = 0, ctrl: int = ALL_ENABLES, override: int = 1_000_000) -> None:
    rec = core.default_plctonc()
    rec["ControlDWord"] = ctrl
    rec["Override"] = override
    core.set_plctonc(i, rec)


def cmd(core: NcCore, name: str, axis: int = 1, **args: Any) -> dict[str, Any]:
    return core.execute(parse_request(make_request(name, next(_ids), "test", **args)), axis)


def state(core: NcCore, i: int = 0) -> MC_AxisStates:
    r = core.nctoplc[i]
    return motion_state(int(r["StateDWord"]), int(r["CoupleState"]))


def run_until(core: NcCore, pred: Callable[[], Any], max_cycles: int = 100_000) -> int:
    """Step ``core`` until ``pred()`` (:func:`znc_testing.until.step_until`); return the number of steps."""
    return step_until(core.step, pred, max_cycles)


def snapshot(core: NcCore) -> bytes:
    """Everything observable about the axes (to prove a rejected command changed nothing)."""
    return (core.nctoplc.tobytes() + core.ncjobs.tobytes() + core.plctonc.tobytes()
            + repr([vars(p) for p in core.params]).encode())
