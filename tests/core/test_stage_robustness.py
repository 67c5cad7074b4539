"""A bug in a set-point stage stops the axes it drives with 0x4000, never the NC cycle."""
from __future__ import annotations

import pytest

from nc_schema import ErrorCodes
from znc_testing.nc_core import cmd, powered


def _raise(*args, **kwargs):
    raise RuntimeError("injected")


@pytest.mark.parametrize("stage", ["coupling", "superposition", "external"])
def test_a_failing_stage_faults_its_axes_and_the_cycle_goes_on(monkeypatch: pytest.MonkeyPatch, stage: str) -> None:
    core = powered(3)
    assert not cmd(core, "MoveVelocity", 1, Velocity=100.0, Direction=1)["error"]
    if stage == "coupling":
        assert not cmd(core, "GearIn", 2, Master=3, RatioNumerator=1, RatioDenominator=1)["error"]
        monkeypatch.setattr(core.coupling, "run", _raise)
        victims = [1]
    elif stage == "superposition":
        for _ in range(100):
            core.step()
        assert not cmd(core, "MoveSuperImposed", 1, Mode=4, Distance=5.0, VelocityDiff=20.0, Length=100.0,
                       VelocityProcess=100.0)["error"]
        monkeypatch.setattr(core.superposition, "evaluate", _raise)
        victims = [0]
    else:
        assert not cmd(core, "ExtSetPointGenEnable", 2)["error"]
        monkeypatch.setattr(core.external, "run", _raise)
        victims = [1]
    cycle = core.cycle
    for _ in range(5):
        core.step()  # must not raise
    assert core.cycle == cycle + 5
    for i in victims:
        assert int(core.nctoplc["ErrorCode"][i]) == ErrorCodes.NC_INTERNAL
    others = [i for i in range(3) if i not in victims]
    assert all(int(core.nctoplc["ErrorCode"][i]) == 0 for i in others)


def test_superposition_on_a_slave_runs_after_its_coupling() -> None:
    """Regression: the coupling stage called the superposition of each level with the wrong
    arguments, which raised out of step() (the NC cycle thread ended)."""
    core = powered(2)
    assert not cmd(core, "GearIn", 2, Master=1, RatioNumerator=1, RatioDenominator=2)["error"]
    core.step()
    assert not cmd(core, "MoveVelocity", 1, Velocity=100.0, Direction=1)["error"]
    for _ in range(200):
        core.step()
    r = cmd(core, "MoveSuperImposed", 2, Mode=1, Distance=10.0, VelocityDiff=50.0, Length=100.0, VelocityProcess=100.0)
    assert not r["error"], r
    p0, m0 = float(core.nctoplc["SetPos"][1]), float(core.nctoplc["SetPos"][0])
    for _ in range(1500):
        core.step()
    gained = float(core.nctoplc["SetPos"][1]) - p0 - 0.5 * (float(core.nctoplc["SetPos"][0]) - m0)
    assert gained == pytest.approx(10.0, abs=1e-9)
    assert int(core.ncjobs["SuperState"][1]) == 2 and int(core.nctoplc["ErrorCode"][1]) == 0
    # Length of an ADDITIVEMOTION on a slave is its master's travel (VelocityProcess: the master's velocity)
    assert float(core.ncjobs["SuperLength"][1]) == pytest.approx(100.0)
