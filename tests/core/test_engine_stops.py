"""Stops and weaker dynamics on a moving axis, cycle by cycle (engine_check.Trace): a stop is never
weaker than the motion it stops, but never beyond the jerk of the axis or of that motion either; a
new command whose weaker jerk would turn a braking axis back is refused (0x4289), changing nothing.
Found by the random sequences of test_engine_fuzz.py."""
import pytest

from nc_schema import CmdState, ErrorCodes as E
from znc_testing.engine_check import Trace
from znc_testing.nc_core import cmd, power, powered, snapshot

DONE = int(CmdState.DONE)


def turning(override=1_000_000):
    """Running at -400 u/s, then MoveAbsolute to +100: braking at +5000 u/s^2 through v = 0 into the
    other direction (a reversal under way)."""
    core = powered()
    power(core, override=override)
    tr = Trace(core)
    cmd(core, "MoveVelocity", Velocity=400.0, Direction=3)
    tr.until(lambda r: abs(float(r["SetVelo"]) + 400.0 * override / 1e6) < 1e-9)
    cmd(core, "MoveAbsolute", Position=100.0, Velocity=100.0)
    return core, tr


@pytest.mark.parametrize("stop", ["Halt", "Stop"])
def test_stop_during_a_reversal_stays_within_the_axis_jerk(stop):
    core, tr = turning()
    tr.until(lambda r: float(r["SetVelo"]) > -90.0)
    r = tr.rows[-1]
    # still braking hard: stopping from here without turning would need a jerk a^2 / 2|v| > AxisJerk
    assert float(r["SetAcc"]) ** 2 / (2 * abs(float(r["SetVelo"]))) > 2 * 50000.0
    n = cmd(core, stop)["CmdNo"]
    tr.settle()  # Trace: |SetJerk| <= AxisJerk in every cycle
    assert int(tr.rows[-1]["CmdNo"]) == n and int(tr.rows[-1]["CmdState"]) == DONE


def braking_from(how="MoveVelocity", v0=200.0, threshold=36.0):
    core = powered()
    cmd(core, "MoveVelocity", Velocity=v0, Direction=1)
    while core.nctoplc[0]["SetVelo"] < v0 - 1e-9:
        core.step()
    if how == "MoveVelocity":
        cmd(core, "MoveVelocity", Velocity=20.0, Direction=1)
    else:
        cmd(core, "Halt")
    while core.nctoplc[0]["SetVelo"] > threshold:
        core.step()
    assert core.nctoplc[0]["SetAcc"] < -1000.0  # with Jerk 5000 a would need 100 u/s to come to 0
    return core


@pytest.mark.parametrize("braking", ["MoveVelocity", "Halt"])
@pytest.mark.parametrize("name,args", [
    ("MoveVelocity", dict(Velocity=20.0, Direction=1, Jerk=5000.0)),
    ("MoveAbsolute", dict(Position=400.0, Velocity=20.0, Jerk=5000.0)),
])
def test_a_weaker_jerk_that_would_turn_a_braking_axis_back_is_refused(name, args, braking):
    core = braking_from(braking)
    before = snapshot(core)
    rep = cmd(core, name, **args)
    assert rep["error"] == E.NC_ILLEGAL_REVERSAL == 0x4289, rep
    assert snapshot(core) == before
    tr = Trace(core)
    tr.until(lambda r: abs(float(r["SetVelo"]) - (20.0 if braking == "MoveVelocity" else 0.0)) < 1e-9)
    assert tr.col("SetVelo").min() >= 0


def test_a_target_within_the_braking_distance_is_passed_and_approached_back():
    """Not a turn 'on its way': past the target and back is how such a move ends (refused only by a
    soft limit)."""
    core = powered()
    tr = Trace(core)
    cmd(core, "MoveVelocity", Velocity=300.0, Direction=1)
    tr.until(lambda r: abs(float(r["SetVelo"]) - 300.0) < 1e-9)
    p = float(tr.rows[-1]["SetPos"])
    assert cmd(core, "MoveAbsolute", Position=p + 2.0, Velocity=300.0)["error"] == 0
    tr.settle()
    assert tr.col("SetPos").max() > p + 2.0 and tr.rows[-1]["SetPos"] == p + 2.0
