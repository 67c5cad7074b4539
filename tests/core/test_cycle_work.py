"""The work a cycle and a command do beyond their result (issue 16's no-regression rule): no row synced
twice for one change, none after a read, the pipeline's calls bound again after a change of it."""
from __future__ import annotations

from typing import Any

import pytest

from nc_server.core import NcCore
from znc_testing.nc_core import cmd, powered


def _count_syncs(core: NcCore) -> list[int]:
    rows: list[int] = []
    sync = core.engine.sync

    def counting(i: int) -> None:
        rows.append(i)
        sync(i)
    core.engine.sync = counting  # type: ignore[method-assign]
    return rows


@pytest.mark.parametrize("name, args", [("ReadParameter", {"ParameterNumber": 1}), ("ReadParameterSet", {}),
                                        ("ReadAxisComponents", {})])
def test_a_read_syncs_no_row(name: str, args: dict[str, Any]) -> None:
    core = powered(2)
    assert cmd(core, "MoveVelocity", 2, Velocity=10.0, Direction=1)["error"] == 0
    core.step()
    before = core.ncjobs.tobytes()
    rows = _count_syncs(core)
    assert cmd(core, name, 2, **args)["error"] == 0
    assert rows == []
    assert core.ncjobs.tobytes() == before


def test_a_motion_command_syncs_its_row_as_its_job_begins_and_not_again() -> None:
    core = powered(2)
    rows = _count_syncs(core)
    assert cmd(core, "MoveAbsolute", 1, Position=100.0, Velocity=10.0)["error"] == 0
    assert rows == [0]  # (JobEngine.begin: once; again after a kind's own on_begin, e.g. a gearing's)
    rows.clear()
    assert cmd(core, "MoveAbsolute", 1, Position=200.0, Velocity=10.0)["error"] == 0  # a re-target
    assert rows == [0]


def test_an_admin_command_syncs_its_row_once() -> None:
    core = powered(2)
    rows = _count_syncs(core)
    assert cmd(core, "SetReferenceFlag", 2, ReferenceFlag=True)["error"] == 0
    assert rows == [1]


def test_a_stage_added_or_replaced_in_place_runs_from_the_next_step() -> None:
    core = powered(1)
    ran: list[str] = []

    class Spy:
        def __init__(self, name: str) -> None:
            self.name = name

        def run(self, core: NcCore) -> None:
            ran.append(self.name)

        def rows_at_fault(self, core: NcCore) -> None:
            return None

    core.step()
    core.pipeline.append(Spy("a"))  # type: ignore[arg-type]
    core.step()
    core.pipeline[-1] = Spy("b")  # type: ignore[call-overload]
    core.step()
    del core.pipeline[-1]
    core.step()
    assert ran == ["a", "b"]
    assert [t["name"] for t in core.stage_times()][-1] == "output"
    core.pipeline = list(core.pipeline) + [Spy("c")]  # type: ignore[list-item]
    core.step()
    assert ran == ["a", "b", "c"]
    assert [t["name"] for t in core.stage_times()][-1] == "c"
