"""Parameters that act (issue 17, part F): the loop movement (AxisEnLoopingDistance, AxisLoopingDistance), the
override type (AxisOverrideType 1..4) and the jog increments (AxisJogIncrementForward/Backward: MC_Jog inching
with Position 0). For each: its effect on the pure core cycle by cycle (the per-cycle checker of
znc_testing.engine_check), that it is writable and read back, that a written value is retained, and that a bad
value gets TwinCAT's code and changes nothing."""
from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from nc_schema import CmdState, E_JogMode, ErrorCodes as E, MC_AxisPara, MC_BufferMode, MC_Direction, StateDWord
from nc_server.core import AxisConfig, AxisParams, NcCore
from nc_server.core.params import ConfigError
from nc_server.server.retain import RetainKeeper, encode_retain, write_atomic
from znc_testing.engine_check import Trace
from znc_testing.nc_core import cmd, make_core, power, powered, snapshot

EN_LOOP = int(MC_AxisPara.AxisEnLoopingDistance)
LOOP = int(MC_AxisPara.AxisLoopingDistance)
OV_TYPE = int(MC_AxisPara.AxisOverrideType)
INC_FW = int(MC_AxisPara.AxisJogIncrementForward)
INC_BW = int(MC_AxisPara.AxisJogIncrementBackward)
INCH, INCH_MOD = int(E_JogMode.MC_JOGMODE_INCHING), int(E_JogMode.MC_JOGMODE_INCHING_MODULO)
POS, NEG = int(MC_Direction.MC_Positive_Direction), int(MC_Direction.MC_Negative_Direction)
DONE = int(CmdState.DONE)


def ok(r: dict[str, Any]) -> dict[str, Any]:
    assert r["error"] == 0, r
    return r


def moved(core: NcCore, **kw: Any) -> Trace:
    """A trace (per-cycle checks) of axis 1 from now."""
    return Trace(core, 0, **kw)


def looping(dist: float = 5.0, **params: Any) -> NcCore:
    return powered(AxisEnLoopingDistance=True, AxisLoopingDistance=dist, **params)


# ---- loop movement ---------------------------------------------------------------------------------------------
def test_a_move_from_the_other_side_goes_on_to_the_loop_point_and_returns() -> None:
    core = looping(5.0)
    tr = moved(core)
    no = ok(cmd(core, "MoveAbsolute", Position=20.0, Velocity=100.0))["CmdNo"]
    tr.settle()
    p, v = tr.col("SetPos"), tr.col("SetVelo")
    assert p.max() == pytest.approx(25.0, abs=1e-6), "on to the loop point target + AxisLoopingDistance"
    assert p[-1] == 20.0 and tr.fate(no) == (DONE, 0)
    k = int(np.argmax(p))
    # at rest at the loop point (between two samples: a cycle of jerk from 0), then back downwards
    assert abs(v[k]) < 0.1 and (v[k + 1:] <= 1e-9).all()
    # one command throughout: the same CmdNo, HasJob until the target is reached
    assert (tr.col("CmdNo") == no).all()
    has_job = (tr.col("StateDWord").astype(np.int64) & int(StateDWord.HasJob)) != 0
    assert has_job[:-1].all() and not has_job[-1]


def test_from_the_named_side_there_is_no_loop() -> None:
    core = looping(5.0)
    ok(cmd(core, "SetActualPosition", Position=40.0))
    core.step()
    tr = moved(core)
    ok(cmd(core, "MoveAbsolute", Position=20.0, Velocity=100.0))
    tr.settle()
    p = tr.col("SetPos")
    assert p.min() >= 20.0 - 1e-9 and p[-1] == 20.0, "approached from above already: straight there"


def test_a_negative_distance_approaches_from_below() -> None:
    core = looping(-5.0)
    tr = moved(core)
    ok(cmd(core, "MoveAbsolute", Position=-20.0, Velocity=100.0))
    tr.settle()
    p = tr.col("SetPos")
    assert p.min() == pytest.approx(-25.0, abs=1e-6) and p[-1] == -20.0
    tr2 = moved(core)
    ok(cmd(core, "MoveRelative", Distance=10.0, Velocity=100.0))  # upwards: from below already
    tr2.settle()
    assert tr2.col("SetPos").min() >= -20.0 - 1e-9 and tr2.col("SetPos")[-1] == -10.0


@pytest.mark.parametrize("params", [dict(AxisEnLoopingDistance=True, AxisLoopingDistance=0.0),
                                    dict(AxisEnLoopingDistance=False, AxisLoopingDistance=5.0)])
def test_no_loop_without_both_parameters(params: dict[str, Any]) -> None:
    core = powered(**params)
    tr = moved(core)
    ok(cmd(core, "MoveAbsolute", Position=20.0, Velocity=100.0))
    tr.settle()
    assert tr.col("SetPos").max() <= 20.0 + 1e-9


def test_positionings_with_an_end_velocity_do_not_loop() -> None:
    core = looping(5.0)
    tr = moved(core)
    ok(cmd(core, "MoveContinuousAbsolute", Position=20.0, Velocity=100.0, EndVelocity=50.0))
    tr.until(lambda r: r["SetPos"] > 21.0)
    assert (tr.col("SetVelo") > 0).all() or tr.col("SetVelo")[-1] == pytest.approx(50.0)
    ok(cmd(core, "Halt"))
    tr.settle()
    assert tr.col("SetVelo").min() >= -1e-9, "never turned back"


def test_the_loop_point_must_lie_inside_the_soft_limits() -> None:
    core = looping(5.0, AxisEnMaxSoftPosLimit=True, AxisMaxSoftPosLimit=22.0)
    before = snapshot(core)
    r = cmd(core, "MoveAbsolute", Position=20.0, Velocity=100.0)
    assert r["error"] == E.NC_TARGET_POSITION_NOT_ALLOWED, r
    assert snapshot(core) == before


def test_the_return_needs_its_feed_enable() -> None:
    core = looping(5.0)
    power(core, ctrl=int(core.plctonc["ControlDWord"][0]) & ~0x4)  # FeedEnableMinus off
    core.step()
    before = snapshot(core)
    r = cmd(core, "MoveAbsolute", Position=20.0, Velocity=100.0)
    assert r["error"] == E.NC_NO_ENABLE, r
    assert snapshot(core) == before
    ok(cmd(core, "WriteParameter", ParameterNumber=EN_LOOP, Value=False))
    ok(cmd(core, "MoveAbsolute", Position=20.0, Velocity=100.0))  # without the loop: no return leg


def test_a_blending_successor_commanded_on_the_way_out_starts_after_the_return() -> None:
    core = looping(5.0)
    tr = moved(core)
    first = ok(cmd(core, "MoveAbsolute", Position=20.0, Velocity=100.0))["CmdNo"]
    tr.step(20)
    second = ok(cmd(core, "MoveAbsolute", Position=40.0, Velocity=100.0,
                    BufferMode=int(MC_BufferMode.MC_BlendingNext)))["CmdNo"]
    tr.settle()
    p, v, no = tr.col("SetPos"), tr.col("SetVelo"), tr.col("CmdNo")
    assert tr.fate(first) == (DONE, 0) and p[-1] == 40.0
    k = int(np.argmax(no == second))
    assert p[:k].max() == pytest.approx(25.0, abs=1e-6), "the first one went on to its loop point"
    assert p[k - 1] == pytest.approx(20.0, abs=1e-3) and abs(v[k - 1]) < 0.1, "... and ended at rest at 20"
    assert (v[int(np.argmax(p[:k])) + 1:k] <= 1e-9).all(), "(the return: downwards until the successor took over)"


def test_change_dyn_param_on_the_way_out_is_accepted() -> None:
    core = looping(5.0)
    tr = moved(core, check_jumps=False)
    ok(cmd(core, "MoveAbsolute", Position=20.0, Velocity=100.0))
    tr.step(30)
    ok(cmd(core, "ChangeDynParam", Acceleration=2000.0, Deceleration=2000.0, Jerk=20000.0))
    tr.settle()
    assert tr.col("SetPos").max() == pytest.approx(25.0, abs=1e-6) and tr.col("SetPos")[-1] == 20.0


def test_the_loop_point_moves_with_set_actual_position_on_the_fly() -> None:
    core = looping(5.0)
    tr = moved(core)
    ok(cmd(core, "MoveAbsolute", Position=20.0, Velocity=100.0))
    tr.step(50)
    ok(cmd(core, "SetActualPositionOnTheFly", PreviousPosition=0.0, ActualPosition=100.0))
    tr.shift(100.0)
    tr.settle()
    p = tr.col("SetPos")
    assert p.max() == pytest.approx(125.0, abs=1e-6) and p[-1] == pytest.approx(120.0)


def test_override_zero_on_the_way_out_holds_and_a_raise_goes_on() -> None:
    core = looping(5.0)
    tr = moved(core)
    ok(cmd(core, "MoveAbsolute", Position=20.0, Velocity=100.0))
    tr.step(80)
    power(core, override=0)
    tr.step(400)
    assert abs(tr.col("SetVelo")[-1]) < 1e-9 and tr.col("SetPos")[-1] < 25.0
    power(core, override=1_000_000)
    tr.settle()
    assert tr.col("SetPos").max() == pytest.approx(25.0, abs=1e-6) and tr.col("SetPos")[-1] == 20.0


def test_a_weak_stop_past_the_target_on_the_way_out_heads_for_the_loop_point() -> None:
    """TcMC 3.15 (weaker stop dynamics are not used if the target would be passed): on the way out of a loop
    the motion heads for the loop point, so a stop that ends before it keeps its own weak deceleration."""
    core = looping(50.0)
    tr = moved(core, check_jumps=False)
    ok(cmd(core, "MoveAbsolute", Position=100.0, Velocity=100.0))
    tr.until(lambda r: r["SetPos"] >= 105.0)
    assert float(core.nctoplc[0]["SetVelo"]) == pytest.approx(100.0)
    ok(cmd(core, "Stop", Deceleration=250.0, Jerk=2500.0))
    tr.settle()
    end = float(tr.col("SetPos")[-1])
    assert 120.0 < end < 150.0, end


def test_inching_loops_too() -> None:
    core = looping(0.5)
    tr = moved(core)
    ok(cmd(core, "Jog", Mode=INCH, Direction=POS, Position=2.0, Velocity=20.0))
    tr.settle()
    assert tr.col("SetPos").max() == pytest.approx(2.5, abs=1e-6) and tr.col("SetPos")[-1] == 2.0


# ---- override type -----------------------------------------------------------------------------------------------
def peak_of_short_move(override_type: int, override: float) -> float:
    """The peak SetVelo of MoveAbsolute 100 u at Velocity 1000 (at 100 % the profile peaks at 500 u/s)."""
    core = powered(AxisOverrideType=float(override_type))
    power(core, override=round(override * 1e6))
    core.step()
    tr = moved(core)
    ok(cmd(core, "MoveAbsolute", Position=100.0, Velocity=1000.0))
    tr.settle()
    assert tr.col("SetPos")[-1] == 100.0
    return float(tr.col("SetVelo").max())


def test_reduced_types_scale_the_peak_of_the_profile_original_types_the_command_velocity() -> None:
    assert peak_of_short_move(4, 1.0) == pytest.approx(500.0, rel=1e-6)
    for t in (3, 1):  # reduced: 50 % of the 500 u/s the profile reaches
        assert peak_of_short_move(t, 0.5) == pytest.approx(250.0, rel=1e-6)
        assert peak_of_short_move(t, 0.9) == pytest.approx(450.0, rel=1e-6)
    for t in (4, 2):  # original: 50 % of the commanded 1000 u/s, which the profile's 500 u/s does not exceed
        assert peak_of_short_move(t, 0.5) == pytest.approx(500.0, rel=1e-6)
    assert peak_of_short_move(4, 0.3) == pytest.approx(300.0, rel=1e-6)


def raise_late(override_type: int, at: float, to: float) -> Trace:
    """MoveAbsolute 0 -> 1000 at Velocity 1000 under override 30 %; at SetPos ``at`` the override goes to ``to``."""
    core = powered(AxisOverrideType=float(override_type))
    power(core, override=300_000)
    core.step()
    tr = moved(core)
    ok(cmd(core, "MoveAbsolute", Position=1000.0, Velocity=1000.0))
    tr.until(lambda r: r["SetPos"] >= at)
    power(core, override=round(to * 1e6))
    return tr


@pytest.mark.parametrize("t", [1, 2])
def test_instantaneous_types_keep_the_running_profile_on_a_raise_it_cannot_reach(t: int) -> None:
    tr = raise_late(t, 900.0, 1.0)  # 100 u left: 1000 u/s is out of reach
    k = len(tr.rows)
    tr.settle()
    assert tr.col("SetVelo")[k:].max() <= 300.0 + 1e-6, "the raise was not applied"
    assert tr.col("SetPos")[-1] == 1000.0
    tr4 = raise_late(4, 900.0, 1.0)
    tr4.settle()
    assert tr4.col("SetVelo").max() > 350.0, "type 4 (iterated) speeds up as far as it can"


@pytest.mark.parametrize("t", [1, 2])
def test_after_a_kept_raise_a_lower_override_still_above_the_running_level_is_a_raise(t: int) -> None:
    # the kept plan runs at 30 %: 100 % -> 60 % is no reduction for it, and 60 % is out of reach too
    tr = raise_late(t, 900.0, 1.0)
    k = len(tr.rows)
    tr.until(lambda r: r["SetPos"] >= 950.0)
    power(tr.core, override=600_000)
    tr.settle()
    assert tr.col("SetVelo")[k:].max() <= 300.0 + 1e-6, "the unreachable level was partly applied"
    assert tr.col("SetPos")[-1] == 1000.0


@pytest.mark.parametrize("t", [1, 2])
def test_instantaneous_types_apply_a_raise_they_can_reach_and_every_reduction(t: int) -> None:
    tr = raise_late(t, 100.0, 0.5)
    tr.until(lambda r: r["SetPos"] >= 500.0)
    assert tr.col("SetVelo")[-1] == pytest.approx(500.0, rel=1e-6)
    power(tr.core, override=200_000)
    tr.until(lambda r: r["SetPos"] >= 800.0)
    assert tr.col("SetVelo")[-1] == pytest.approx(200.0, rel=1e-6)
    tr.settle()


def test_only_the_raise_keeps_the_profile_later_changes_plan_as_always() -> None:
    tr = raise_late(2, 900.0, 1.0)
    tr.step(5)
    core = tr.core
    assert float(core.nctoplc[0]["SetVelo"]) == pytest.approx(300.0, rel=1e-6)
    # ChangeDynParam plans with the override now (100 %): accepted, and it speeds up
    ok(cmd(core, "ChangeDynParam", Acceleration=5000.0, Deceleration=5000.0, Jerk=50000.0))
    tr2 = moved(core, check_jumps=False)
    tr2.settle()
    assert tr2.col("SetVelo").max() > 350.0
    # a BlendingNext successor after a kept raise blends (passes the first target moving)
    tr = raise_late(1, 850.0, 1.0)
    tr.step(5)  # the raise applied (kept: 1000 u/s cannot be reached in 150 u)
    core = tr.core
    assert float(core.nctoplc[0]["SetVelo"]) == pytest.approx(300.0, rel=1e-6)
    ok(cmd(core, "MoveAbsolute", Position=1200.0, Velocity=300.0, BufferMode=int(MC_BufferMode.MC_BlendingNext)))
    tr.until(lambda r: r["SetPos"] >= 1000.0)
    assert tr.col("SetVelo")[-1] == pytest.approx(300.0, rel=1e-3), "blended through 1000 at 300 u/s x 100 %"
    tr.settle()
    assert tr.col("SetPos")[-1] == 1200.0


# ---- jog increments ----------------------------------------------------------------------------------------------
def test_inching_with_position_0_moves_by_the_jog_increments() -> None:
    core = powered(AxisJogIncrementForward=2.5, AxisJogIncrementBackward=1.5)
    tr = moved(core)
    ok(cmd(core, "Jog", Mode=INCH, Direction=POS, Position=0.0, Velocity=20.0))
    tr.settle()
    assert tr.col("SetPos")[-1] == pytest.approx(2.5)
    ok(cmd(core, "Jog", Mode=INCH, Direction=NEG, Position=0.0, Velocity=20.0))
    tr.settle()
    assert tr.col("SetPos")[-1] == pytest.approx(1.0)
    ok(cmd(core, "Jog", Mode=INCH_MOD, Direction=POS, Position=0.0, Velocity=20.0))  # the next multiple of 2.5
    tr.settle()
    assert tr.col("SetPos")[-1] == pytest.approx(2.5)
    ok(cmd(core, "WriteParameter", ParameterNumber=INC_FW, Value=4.0))  # a written increment: the next jog
    ok(cmd(core, "Jog", Mode=INCH, Direction=POS, Position=0.0, Velocity=20.0))
    tr.settle()
    assert tr.col("SetPos")[-1] == pytest.approx(6.5)
    ok(cmd(core, "Jog", Mode=INCH, Direction=POS, Position=0.5, Velocity=20.0))  # Position given: Position
    tr.settle()
    assert tr.col("SetPos")[-1] == pytest.approx(7.0)


@pytest.mark.parametrize("direction, param", [(POS, "AxisJogIncrementForward"), (NEG, "AxisJogIncrementBackward")])
def test_a_zero_increment_refuses_inching_with_position_0(direction: int, param: str) -> None:
    core = powered(**{param: 0.0})
    before = snapshot(core)
    r = cmd(core, "Jog", Mode=INCH, Direction=direction, Position=0.0, Velocity=20.0)
    assert r["error"] == E.MC_PARAMETER_NOT_CORRECT, r
    assert snapshot(core) == before
    other = NEG if direction == POS else POS
    ok(cmd(core, "Jog", Mode=INCH, Direction=other, Position=0.0, Velocity=20.0))  # the other increment is 1


# ---- writable, retained, bad values --------------------------------------------------------------------------------
WRITES = [(EN_LOOP, True), (LOOP, -7.5), (OV_TYPE, 2.0), (INC_FW, 3.25), (INC_BW, 0.75)]


def test_writable_while_moving_and_read_back() -> None:
    core = powered()
    ok(cmd(core, "MoveAbsolute", Position=500.0, Velocity=100.0))
    core.step(); core.step()
    for number, value in WRITES:
        ok(cmd(core, "WriteParameter", ParameterNumber=number, Value=value))
        assert cmd(core, "ReadParameter", ParameterNumber=number)["Value"] == value
    ps = cmd(core, "ReadParameterSet")["Value"]
    assert ps["bEnableLoop"] == 1 and ps["fLoopDistance"] == -7.5


def test_written_values_are_retained(tmp_path: Path) -> None:
    core = NcCore([AxisConfig(1, "A1", AxisParams())], cycle_time=0.001)
    core.step()
    k = RetainKeeper(tmp_path / "nc1.retain", "nc1", core)
    k.load()
    k.apply(core)
    for number, value in WRITES:
        ok(cmd(core, "WriteParameter", ParameterNumber=number, Value=value))
    data = k.data_of(k._snapshot(core))
    kept = data.axes[1].params
    assert kept == {"AxisEnLoopingDistance": (True, False), "AxisLoopingDistance": (-7.5, 0.0),
                    "AxisOverrideType": (2.0, 4.0), "AxisJogIncrementForward": (3.25, 1.0),
                    "AxisJogIncrementBackward": (0.75, 1.0)}
    k.close()
    write_atomic(tmp_path / "nc1.retain", encode_retain(data))
    again = NcCore([AxisConfig(1, "A1", AxisParams())], cycle_time=0.001)
    k2 = RetainKeeper(tmp_path / "nc1.retain", "nc1", again)
    k2.load()
    again.step()
    k2.apply(again)
    for number, value in WRITES:
        assert cmd(again, "ReadParameter", ParameterNumber=number)["Value"] == value
    k2.close()


@pytest.mark.parametrize("number, value, code", [
    (EN_LOOP, 0.5, E.NC_AXIS_LOOP_NOT_ALLOWED),
    (EN_LOOP, 2.0, E.NC_AXIS_LOOP_NOT_ALLOWED),
    (LOOP, 2e9, E.NC_AXIS_LOOP_DISTANCE_NOT_ALLOWED),
    (LOOP, -2e9, E.NC_AXIS_LOOP_DISTANCE_NOT_ALLOWED),
    (OV_TYPE, 0.0, E.NC_AXIS_OVERRIDE_TYPE_NOT_ALLOWED),
    (OV_TYPE, 5.0, E.NC_AXIS_OVERRIDE_TYPE_NOT_ALLOWED),
    (OV_TYPE, 2.5, E.NC_AXIS_OVERRIDE_TYPE_NOT_ALLOWED),
    (INC_FW, -1.0, E.NC_AXIS_PULSE_WIDTH_POS_NOT_ALLOWED),
    (INC_FW, 2e9, E.NC_AXIS_PULSE_WIDTH_POS_NOT_ALLOWED),
    (INC_BW, -1.0, E.NC_AXIS_PULSE_WIDTH_NEG_NOT_ALLOWED),
    (LOOP, True, E.ADSERR_DEVICE_INVALIDPARM),  # the wrong type stays 0x70B
])
def test_bad_values_get_twincats_codes_and_change_nothing(number: int, value: Any, code: int) -> None:
    core = powered()
    before = snapshot(core)
    r = cmd(core, "WriteParameter", ParameterNumber=number, Value=value)
    assert r["error"] == code, r
    assert snapshot(core) == before


@pytest.mark.parametrize("key, value, code", [
    ("AxisOverrideType", 2.5, E.NC_AXIS_OVERRIDE_TYPE_NOT_ALLOWED),
    ("AxisLoopingDistance", float("inf"), E.NC_AXIS_LOOP_DISTANCE_NOT_ALLOWED),
    ("AxisEnLoopingDistance", 1, E.NC_AXIS_LOOP_NOT_ALLOWED),
    ("AxisJogIncrementBackward", -0.1, E.NC_AXIS_PULSE_WIDTH_NEG_NOT_ALLOWED),
])
def test_the_configuration_gets_the_same_codes(key: str, value: Any, code: int) -> None:
    with pytest.raises(ConfigError) as ei:
        AxisParams.from_mapping({key: value})
    assert ei.value.code == code


def test_defaults_are_how_this_nc_behaved() -> None:
    core = make_core()
    assert cmd(core, "ReadParameter", ParameterNumber=EN_LOOP)["Value"] is False
    assert cmd(core, "ReadParameter", ParameterNumber=LOOP)["Value"] == 0.0
    assert cmd(core, "ReadParameter", ParameterNumber=OV_TYPE)["Value"] == 4.0
