"""What a superposition (MoveSuperImposed) may not do: start without the feed enable of its direction,
go beyond a software limit (refused, or no fault when a positioning move ends near it), exceed the
acceleration on top of an accelerating move (an error, not a silent excess), run during homing (and Home
is refused while one moves the axis), or jump when MC_Reset comes during one on a standing axis.
"""
from __future__ import annotations

import pytest

from nc_schema import ControlDWord, ErrorCodes as E
from znc_testing.nc_core import cmd, power, powered, snapshot

CT = 0.001


def test_mc_reset_during_a_superposition_of_a_standing_axis_does_not_jump() -> None:
    core = powered(1, SimTimeConstant=0.01)
    assert not cmd(core, "MoveSuperImposed", Mode=4, Distance=100.0, VelocityDiff=500.0, Length=1000.0, VelocityProcess=1.0)["error"]
    for _ in range(150):
        core.step()
    p, v = float(core.nctoplc[0]["SetPos"]), float(core.nctoplc[0]["SetVelo"])
    assert not cmd(core, "Reset")["error"]
    core.step()
    assert abs(float(core.nctoplc[0]["SetPos"]) - p - v * CT) < 0.01
    for _ in range(2000):
        core.step()
    assert float(core.nctoplc[0]["SetPos"]) == pytest.approx(100.0, abs=1e-9)


def test_a_superposition_needs_the_feed_enable_of_its_direction() -> None:
    core = powered(1)
    power(core, 0, ctrl=int(ControlDWord.Enable | ControlDWord.FeedEnableMinus))
    core.step()
    cmd(core, "MoveSuperImposed", Mode=4, Distance=10.0, VelocityDiff=50.0, Length=100.0, VelocityProcess=1.0)
    for _ in range(50):
        core.step()
    assert int(core.nctoplc[0]["ErrorCode"]) == E.NC_AXIS_FEED_ENABLE_PLUS
    assert float(core.nctoplc[0]["SetPos"]) < 1.0


def test_a_superposition_beyond_a_software_limit_is_refused() -> None:
    core = powered(1, AxisEnMaxSoftPosLimit=True, AxisMaxSoftPosLimit=50.0)
    assert not cmd(core, "MoveAbsolute", Position=45.0, Velocity=100.0)["error"]
    for _ in range(50):
        core.step()
    snap = snapshot(core)
    r = cmd(core, "MoveSuperImposed", Mode=4, Distance=30.0, VelocityDiff=100.0, Length=1000.0, VelocityProcess=1.0)
    assert r["error"] == E.NC_TARGET_POSITION_NOT_ALLOWED
    assert snapshot(core) == snap


def test_a_superposition_on_top_of_an_acceleration_is_an_error_not_a_silent_excess() -> None:
    core = powered(1)
    assert not cmd(core, "MoveVelocity", Velocity=500.0, Direction=1)["error"]
    for _ in range(30):
        core.step()
    assert not cmd(core, "MoveSuperImposed", Mode=3, Distance=20.0, VelocityDiff=400.0, Length=1e6, VelocityProcess=1.0)["error"]
    worst = 0.0
    for _ in range(400):
        core.step()
        worst = max(worst, abs(float(core.nctoplc[0]["SetAcc"])))
        if int(core.nctoplc[0]["ErrorCode"]):
            break
    assert int(core.nctoplc[0]["ErrorCode"]) == E.NC_ACCELERATION_NOT_ALLOWED
    assert worst <= (5000.0 + 2 * 50000.0 * CT) * (1 + 1e-9)  # (one cycle of both jerks at most)


def test_no_superposition_during_homing() -> None:
    core = powered(1, AxisCalibrationVelocityForward=50.0, AxisCalibrationVelocityBackward=10.0)
    assert not cmd(core, "Home", Position=0.0, HomingMode=0)["error"]
    for _ in range(50):
        core.step()
    snap = snapshot(core)
    assert cmd(core, "MoveSuperImposed", Mode=4, Distance=10.0, VelocityDiff=50.0, Length=100.0, VelocityProcess=1.0)["error"] == \
        E.MC_AXIS_CANNOT_BE_STARTED
    assert snapshot(core) == snap


def test_home_is_refused_while_a_superposition_moves_the_axis() -> None:
    core = powered(1)
    assert not cmd(core, "MoveSuperImposed", Mode=4, Distance=50.0, VelocityDiff=100.0, Length=1000.0, VelocityProcess=1.0)["error"]
    for _ in range(20):
        core.step()
    assert cmd(core, "Home", Position=0.0, HomingMode=4)["error"] == E.MC_AXIS_CANNOT_BE_STARTED


def test_a_superposition_on_a_positioning_move_near_the_limit_is_no_fault() -> None:
    core = powered(1, AxisEnMaxSoftPosLimit=True, AxisMaxSoftPosLimit=100.0)
    assert not cmd(core, "MoveAbsolute", Position=95.0, Velocity=1000.0)["error"]
    for _ in range(50):
        core.step()
    assert not cmd(core, "MoveSuperImposed", Mode=4, Distance=-5.0, VelocityDiff=100.0, Length=1000.0, VelocityProcess=1.0)["error"]
    for _ in range(2000):
        core.step()
    assert int(core.nctoplc[0]["ErrorCode"]) == 0
    assert float(core.nctoplc[0]["SetPos"]) == pytest.approx(90.0, abs=1e-9)
