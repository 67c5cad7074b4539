"""MC_Stop / MC_Halt / MC_OrientedStop brake with the dynamics TcMC 3.15 names: Deceleration and Jerk 0 are
the *effective* values of the job they stop (its inputs, or AxisDec/AxisJerk where those were 0); a coupling
or external set-points (no dynamics of their own): AxisDec/AxisJerk; a buffered MC_Halt: the job it follows.
A lone non-zero value is used with the stopped job's other one; a negative one is refused (0x4230/0x422E)
and changes nothing. 3.15's exceptions still hold (never weaker than a stop already running, never past the
target). Each case is measured on the set-points: the largest |SetAcc| and |SetJerk| of the brake.
"""
from __future__ import annotations

import math

import pytest

from nc_schema import CmdState, ErrorCodes as E
from znc_testing.nc_core import cmd, powered, run_until, snapshot

CT = 0.001
#: axis defaults of these tests (AxisDec 5000, AxisJerk 50000: far from every command's values)
AXIS = dict(AxisVeloMax=1000.0, AxisAcc=5000.0, AxisDec=5000.0, AxisJerk=50000.0)


def moving(v: float = 400.0, axis: int = 1, **dyn: float):
    """A core with a MoveVelocity(v, **dyn) at its constant velocity."""
    core = powered(2, **AXIS)
    assert cmd(core, "MoveVelocity", axis=axis, Velocity=v, Direction=1, **dyn)["error"] == 0
    run_until(core, lambda: math.isclose(float(core.nctoplc[axis - 1]["SetVelo"]), v), 20_000)
    return core


def brake(core, i: int = 0, max_cycles: int = 20_000) -> tuple[float, float, int]:
    """Step until axis row ``i`` stands: (largest |SetAcc|, largest |SetJerk|, cycles)."""
    acc = jerk = 0.0
    n = 0
    while n < max_cycles:
        core.step()
        n += 1
        r = core.nctoplc[i]
        acc, jerk = max(acc, abs(float(r["SetAcc"]))), max(jerk, abs(float(r["SetJerk"])))
        if float(r["SetVelo"]) == 0.0 and not core.axes.traj_on[i]:
            return acc, jerk, n
    raise AssertionError("the axis did not stop")


def test_stop_with_zeros_brakes_with_the_stopped_jobs_own_dynamics() -> None:
    """Before: always AxisDec/AxisJerk (5000/50000): stopped in ~0.18 s instead of ~1.1 s."""
    core = moving(Deceleration=400.0, Jerk=4000.0)
    assert cmd(core, "Stop")["error"] == 0
    acc, jerk, n = brake(core)
    assert acc == pytest.approx(400.0, rel=1e-6) and jerk == pytest.approx(4000.0, rel=1e-6)
    assert n * CT == pytest.approx(400.0 / 400.0 + 400.0 / 4000.0, abs=3 * CT)


def test_stop_takes_the_axis_default_where_the_job_had_0() -> None:
    """The job's Deceleration was 0 (AxisDec 5000) and its Jerk 4000: the stop brakes with 5000 and 4000."""
    core = moving(Jerk=4000.0)
    assert cmd(core, "Stop", Deceleration=0.0, Jerk=0.0)["error"] == 0
    acc, jerk, _ = brake(core)
    assert jerk == pytest.approx(4000.0, rel=1e-6)
    # a triangle (AxisDec 5000 is not reached with this jerk): its peak sqrt(v j), sampled once a cycle
    assert acc == pytest.approx(math.sqrt(400.0 * 4000.0), rel=5e-3)


def test_stop_with_both_values_uses_them() -> None:
    core = moving(Deceleration=400.0, Jerk=4000.0)
    assert cmd(core, "Stop", Deceleration=800.0, Jerk=8000.0)["error"] == 0
    acc, jerk, _ = brake(core)
    assert acc == pytest.approx(800.0, rel=1e-6) and jerk == pytest.approx(8000.0, rel=1e-6)


@pytest.mark.parametrize("args, want", [(dict(Deceleration=800.0), (800.0, 4000.0)),
                                        (dict(Jerk=8000.0), (400.0, 8000.0))])
def test_a_lone_value_is_used_with_the_stopped_jobs_other_one(args, want) -> None:
    """Decision (TcMC: "only accepted together"): used, not ignored (before: the axis defaults)."""
    core = moving(Deceleration=400.0, Jerk=4000.0)
    assert cmd(core, "Stop", **args)["error"] == 0
    acc, jerk, _ = brake(core)
    assert (acc, jerk) == pytest.approx(want, rel=1e-6)


@pytest.mark.parametrize("name", ["Stop", "Halt"])
@pytest.mark.parametrize("args, code", [(dict(Deceleration=-1.0), E.NC_DECELERATION_NOT_ALLOWED),
                                        (dict(Deceleration=-1.0, Jerk=-1.0), E.NC_DECELERATION_NOT_ALLOWED),
                                        (dict(Jerk=-5.0), E.NC_JERK_NOT_ALLOWED)])
def test_negative_values_are_refused_and_change_nothing(name, args, code) -> None:
    """Before: MC_Stop turned them silently into the axis defaults (MC_Halt refused them already)."""
    core = moving(Deceleration=400.0, Jerk=4000.0)
    before = snapshot(core)
    assert cmd(core, name, **args)["error"] == code
    assert snapshot(core) == before
    assert not core.axes.locked[0]


def test_halt_with_zeros_brakes_with_the_stopped_jobs_dynamics() -> None:
    core = moving(Deceleration=400.0, Jerk=4000.0)
    assert cmd(core, "Halt")["error"] == 0
    acc, jerk, _ = brake(core)
    assert acc == pytest.approx(400.0, rel=1e-6) and jerk == pytest.approx(4000.0, rel=1e-6)


def test_a_buffered_halt_takes_the_dynamics_of_the_job_it_follows() -> None:
    """The Halt waits behind the MoveVelocity (its dynamics 300/3000) and starts at its constant velocity."""
    core = powered(1, **AXIS)
    assert cmd(core, "MoveVelocity", Velocity=300.0, Direction=1, Deceleration=300.0, Jerk=3000.0)["error"] == 0
    core.step()
    assert cmd(core, "Halt", BufferMode=1)["error"] == 0
    run_until(core, lambda: core.queues[0].active is not None and core.queues[0].active.kind.name == "Halt", 20_000)
    acc, jerk, _ = brake(core)
    assert acc == pytest.approx(300.0, rel=1e-6) and jerk == pytest.approx(3000.0, rel=1e-6)


def test_a_coupled_slave_stops_with_axis_dec_and_jerk() -> None:
    """A coupling has no dynamics of its own: AxisDec/AxisJerk (the master's 400/4000 do not count).
    (A guard: the code before this change braked at AxisDec too.)"""
    core = powered(2, **AXIS)
    assert cmd(core, "GearIn", axis=2, Master=1, RatioNumerator=1, RatioDenominator=1)["error"] == 0
    core.step()
    assert cmd(core, "MoveVelocity", axis=1, Velocity=800.0, Direction=1, Deceleration=400.0, Jerk=4000.0)["error"] == 0
    run_until(core, lambda: math.isclose(float(core.nctoplc[1]["SetVelo"]), 800.0), 20_000)
    assert cmd(core, "Stop", axis=2)["error"] == 0
    acc, jerk, _ = brake(core, 1)
    assert jerk == pytest.approx(50000.0, rel=1e-6) and acc == pytest.approx(5000.0, rel=1e-6)


def test_a_weaker_stop_never_weakens_a_running_stop() -> None:
    """3.15: "a stop with more rigorous dynamics had already been initiated": the second Stop's 0s are the
    running stop's values (800/8000), a lone weaker Deceleration does not weaken it either."""
    core = moving(Deceleration=400.0, Jerk=4000.0)
    assert cmd(core, "Stop", Deceleration=800.0, Jerk=8000.0)["error"] == 0
    for _ in range(50):
        core.step()
    assert cmd(core, "Stop", Deceleration=100.0)["error"] == 0
    acc, jerk, _ = brake(core)
    assert acc <= 800.0 * (1 + 1e-6) and jerk <= 8000.0 * (1 + 1e-6)
    assert core.nctoplc[0]["CmdState"] == CmdState.DONE


def test_a_weaker_stop_that_would_pass_the_target_keeps_the_stronger_dynamics() -> None:
    """3.15: "if the target position would be exceeded": the stop ends before the positioning's target."""
    core = powered(1, **AXIS)
    assert cmd(core, "MoveAbsolute", Position=300.0, Velocity=400.0)["error"] == 0
    run_until(core, lambda: float(core.nctoplc[0]["SetPos"]) >= 250.0, 20_000)
    assert cmd(core, "Stop", Deceleration=100.0)["error"] == 0  # 100 u/s^2 from 400 u/s: 800 u of way
    brake(core)
    assert float(core.nctoplc[0]["SetPos"]) <= 300.0 + 1e-9


def test_oriented_stop_uses_the_running_jobs_effective_dynamics() -> None:
    """MC_OrientedStop (no dynamics inputs): the running MoveVelocity's 400/4000. (A guard: as before.)"""
    core = powered(1, **AXIS, Modulo=True, AxisEncoderModuloValue=360.0)
    assert cmd(core, "MoveVelocity", Velocity=400.0, Direction=1, Deceleration=400.0, Jerk=4000.0)["error"] == 0
    run_until(core, lambda: math.isclose(float(core.nctoplc[0]["SetVelo"]), 400.0), 20_000)
    assert cmd(core, "OrientedStop", Position=90.0)["error"] == 0
    acc, jerk, _ = brake(core)
    assert acc <= 400.0 * (1 + 1e-6) and jerk <= 4000.0 * (1 + 1e-6)
    assert math.fmod(float(core.nctoplc[0]["SetPos"]), 360.0) == pytest.approx(90.0, abs=1e-6)
