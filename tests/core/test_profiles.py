"""Set-point generation: jerk-limited, within limits, no jumps, exact end."""
import numpy as np
import pytest

from nc_schema import AxisState, CmdState, StateDWord
from znc_testing.nc_core import cmd, make_core, power, powered, run_until, state

DT = 0.001


def trace(core, cycles, i=0):
    rows = []
    for _ in range(cycles):
        core.step()
        r = core.nctoplc[i]
        rows.append((r["SetPos"], r["SetVelo"], r["SetAcc"], r["SetJerk"]))
    return np.array(rows)


@pytest.mark.parametrize("target,velo,acc,dec,jerk", [
    (100.0, 500.0, 0.0, 0.0, 0.0),          # axis defaults
    (-37.5, 120.0, 800.0, 2000.0, 20000.0),  # asymmetric acc/dec
    (0.3, 1000.0, 0.0, 0.0, 0.0),            # short move, velocity never reached
])
def test_move_absolute_profile_within_limits_and_exact_end(target, velo, acc, dec, jerk):
    core = powered()
    rep = cmd(core, "MoveAbsolute", Position=target, Velocity=velo, Acceleration=acc, Deceleration=dec, Jerk=jerk)
    assert rep["error"] == 0 and rep["CmdNo"] == 1 and rep["cycle"] == core.cycle + 1
    tr = trace(core, 3000)
    p = core.params[0]
    amax = max(acc or p.AxisAcc, dec or p.AxisDec)
    assert np.all(np.abs(tr[:, 1]) <= velo * (1 + 1e-9))
    assert np.all(np.abs(tr[:, 2]) <= amax * (1 + 1e-9))
    assert np.all(np.abs(tr[:, 3]) <= (jerk or p.AxisJerk) * (1 + 1e-9))
    # no set-point jump: successive positions differ by at most vmax*dt, velocities by amax*dt
    assert np.all(np.abs(np.diff(tr[:, 0])) <= velo * DT * (1 + 1e-6))
    assert np.all(np.abs(np.diff(tr[:, 1])) <= amax * DT * (1 + 1e-6))
    assert tr[-1, 0] == target  # exact end position
    r = core.nctoplc[0]
    assert r["CmdNo"] == 1 and r["CmdState"] == CmdState.DONE
    assert not r["StateDWord"] & StateDWord.HasJob
    assert r["AxisState"] == AxisState.INACTIVE


def test_abort_running_move_is_continuous():
    core = powered()
    cmd(core, "MoveAbsolute", Position=200.0, Velocity=800.0)
    before = trace(core, 150)
    rep = cmd(core, "MoveAbsolute", Position=-50.0, Velocity=300.0)
    assert rep["error"] == 0 and rep["CmdNo"] == 2
    after = trace(core, 4000)
    tr = np.vstack([before, after])
    amax = core.params[0].AxisAcc
    assert np.all(np.abs(np.diff(tr[:, 1])) <= amax * DT * (1 + 1e-6))  # velocity continuous
    assert np.all(np.abs(np.diff(tr[:, 2])) <= core.params[0].AxisJerk * DT * (1 + 1e-6))  # acceleration continuous
    assert tr[-1, 0] == -50.0
    assert core.nctoplc[0]["CmdNo"] == 2


def test_many_axes_vectorized_equal_single_axis():
    """64 axes with different moves give exactly the trajectory each would give alone."""
    n = 64
    core = make_core(n)
    rng = np.random.default_rng(7)
    targets = rng.uniform(-500, 500, n)
    velos = rng.uniform(10, 1000, n)
    for i in range(n):
        power(core, i)
    core.step()
    for i in range(n):
        assert cmd(core, "MoveAbsolute", axis=i + 1, Position=float(targets[i]), Velocity=float(velos[i]))["error"] == 0
    for _ in range(700):
        core.step()
    many = core.nctoplc["SetPos"].copy()
    for i in (0, 13, 63):
        single = make_core(1)
        power(single)
        single.step()
        cmd(single, "MoveAbsolute", Position=float(targets[i]), Velocity=float(velos[i]))
        for _ in range(700):
            single.step()
        assert single.nctoplc[0]["SetPos"] == pytest.approx(many[i], abs=1e-9)


def test_move_velocity_reaches_and_holds_velocity():
    core = powered()
    rep = cmd(core, "MoveVelocity", Velocity=250.0, Direction=3)
    assert rep["error"] == 0
    n = run_until(core, lambda: core.nctoplc[0]["StateDWord"] & StateDWord.ConstantVelocity)
    assert n < 200
    r = core.nctoplc[0]
    assert r["SetVelo"] == pytest.approx(-250.0)
    assert r["StateDWord"] & StateDWord.ContinuousMotion and r["StateDWord"] & StateDWord.NegativeDirection
    assert state(core).name == "MC_AXISSTATE_CONTINOUSMOTION"
    p0 = r["SetPos"]
    for _ in range(1000):
        core.step()
    assert core.nctoplc[0]["SetPos"] == pytest.approx(p0 - 250.0, abs=1e-6)
    assert core.nctoplc[0]["CmdState"] == CmdState.ACTIVE


def test_override_scales_velocity_and_zero_holds_the_job():
    core = make_core()
    power(core, override=500_000)  # 50 %
    core.step()
    cmd(core, "MoveVelocity", Velocity=200.0, Direction=1)
    run_until(core, lambda: core.nctoplc[0]["StateDWord"] & StateDWord.ConstantVelocity)
    assert core.nctoplc[0]["SetVelo"] == pytest.approx(100.0)
    power(core, override=0)
    run_until(core, lambda: core.nctoplc[0]["SetVelo"] == 0.0, 2000)
    r = core.nctoplc[0]
    assert r["AxisState"] == AxisState.OVERRIDE_ZERO and r["StateDWord"] & StateDWord.HasJob
    assert r["CmdState"] == CmdState.ACTIVE
    power(core, override=1_000_000)
    run_until(core, lambda: core.nctoplc[0]["StateDWord"] & StateDWord.ConstantVelocity, 2000)
    assert core.nctoplc[0]["SetVelo"] == pytest.approx(200.0)


def test_override_zero_during_positioning_resumes_to_exact_target():
    core = powered()
    cmd(core, "MoveAbsolute", Position=300.0, Velocity=400.0)
    for _ in range(200):
        core.step()
    power(core, override=0)
    for _ in range(500):
        core.step()
    held = core.nctoplc[0]["SetPos"]
    assert core.nctoplc[0]["SetVelo"] == 0.0 and held < 300.0
    power(core, override=250_000)
    run_until(core, lambda: core.nctoplc[0]["CmdState"] == CmdState.DONE, 10_000)
    assert core.nctoplc[0]["SetPos"] == 300.0


def test_cmdno_wraps_to_one():
    core = powered()
    core.axes.cmd_no[0] = 65535
    rep = cmd(core, "MoveRelative", Distance=1.0, Velocity=100.0)
    assert rep["CmdNo"] == 1
    core.step()
    assert core.nctoplc[0]["CmdNo"] == 1


def test_plans_do_not_depend_on_earlier_plans():
    """ruckig reuses its profile objects: an unused brake/post phase keeps an earlier motion's values.
    Such phases must not reach the segment table (the velocity checks read every segment: a command's
    answer, 0 or 0x423A, depended on what had been planned before)."""
    from nc_server.core.planning import Dynamics, StartState, plan_position, plan_velocity
    from nc_server.core.profile import velocity_extrema

    start = StartState(4.4729944805052675, -56.6064012359121, -2945.966692414831)
    dyn = Dynamics(50.0, 5000.0, 8000.0, 100000.0)
    first = plan_position(start, -318.4361482278317, dyn)
    rng = np.random.default_rng(3)
    for _ in range(200):  # motions with brake pre-profiles of one and two phases
        v0 = float(rng.uniform(-400, 400))
        s = StartState(float(rng.uniform(-200, 200)), v0, float(rng.uniform(-3000, 3000)))
        d = Dynamics(float(rng.uniform(10, 100)), 5000.0, 8000.0, 100000.0)
        plan_position(s, float(rng.uniform(-300, 300)), d)
        plan_velocity(s, float(rng.uniform(-50, 50)), d)
        again = plan_position(start, -318.4361482278317, dyn)
        assert again.seg.tobytes() == first.seg.tobytes()
    lo, hi = velocity_extrema(first.seg)
    # from -56.6 u/s at -2946 u/s^2 the acceleration needs 2946^2 / 2e5 = 43.4 u/s to come to 0:
    # -100 u/s at most, then down to -50; never positive
    assert hi <= 1e-9 and lo == pytest.approx(-56.6064012359121 - 2945.966692414831 ** 2 / 2e5, abs=1e-6)
