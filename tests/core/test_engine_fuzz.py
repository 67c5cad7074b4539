"""Random command sequences (fixed seeds) against the per-cycle checks of engine_check.Trace: every
cycle within the axis limits, no set-point jump, job records consistent with NCTOPLC, fates final --
whatever the mix of buffered moves, amendments, stops, override changes, jogs, feed enables, position
shifts, soft limits and homing."""
import random

import pytest

from nc_schema import ControlDWord, HomingState
from znc_testing.engine_check import Trace
from znc_testing.nc_core import ALL_ENABLES, cmd, power, powered

MODES = [0, 0, 1, 18, 19, 20, 21]


def random_command(rng: random.Random, core) -> tuple[str, dict]:
    p = float(core.nctoplc[0]["SetPos"])
    v = lambda: rng.choice([20.0, 100.0, 250.0, 600.0, 1000.0])  # noqa: E731
    dyn = lambda: rng.choice([{}, {}, dict(Acceleration=2000.0, Deceleration=3000.0, Jerk=30000.0),  # noqa: E731
                              dict(Acceleration=5000.0, Deceleration=5000.0, Jerk=50000.0)])
    k = rng.randrange(17)
    if k <= 3:
        return "MoveAbsolute", dict(Position=rng.uniform(-300, 300), Velocity=v(), BufferMode=rng.choice(MODES), **dyn())
    if k == 4:
        return "MoveRelative", dict(Distance=rng.uniform(-100, 100), Velocity=v(), BufferMode=rng.choice(MODES), **dyn())
    if k == 5:
        return "MoveAdditive", dict(Distance=rng.uniform(-50, 50), Velocity=v(), BufferMode=rng.choice(MODES))
    if k == 6:
        return "MoveVelocity", dict(Velocity=v(), Direction=rng.choice([1, 3]), BufferMode=rng.choice(MODES), **dyn())
    if k == 7:
        return "MoveContinuousAbsolute", dict(Position=rng.uniform(-300, 300), Velocity=v(),
                                              EndVelocity=rng.choice([0.0, 50.0, 300.0]), BufferMode=rng.choice(MODES))
    if k == 8:
        return "Halt", dict(BufferMode=rng.choice([0, 1]))
    if k == 9:
        return "NewPos", dict(NewPos=p + rng.uniform(-80, 80))
    if k == 10:
        mode = rng.choice([1, 2, 3, 9, 10, 11, 14])
        return "NewPosAndVelo", dict(Mode=mode, NewPos=p + rng.uniform(-80, 80), NewVelo=v(),
                                     ActivationPos=p + rng.uniform(-40, 40))
    if k == 11:
        return "ChangeDynParam", rng.choice([dict(Acceleration=3000.0, Deceleration=3000.0, Jerk=30000.0), {},
                                             dict(Deceleration=1000.0)])
    if k == 12:
        return "Jog", rng.choice([dict(Mode=0, Direction=1), dict(Mode=1, Direction=3),
                                  dict(Mode=3, Direction=1, Position=7.0, Velocity=v()),
                                  dict(Mode=4, Direction=3, Position=10.0, Velocity=v())])
    if k == 13:
        return "OrientedStop", dict(Position=rng.uniform(0, 359))
    if k == 14:
        return "Stop", rng.choice([{}, dict(Deceleration=8000.0, Jerk=100000.0)])
    if k == 15:
        return "override", dict(value=rng.choice([0, 250_000, 500_000, 1_000_000, 1_000_000]))
    return "MoveModulo", dict(Position=rng.uniform(0, 720), Velocity=v(), Direction=rng.choice([1, 2, 3, 4]),
                              BufferMode=rng.choice(MODES))


@pytest.mark.parametrize("variant", ["plain", "limits", "modulo+home"])
@pytest.mark.parametrize("seed", range(5))
def test_random_sequences_keep_the_cycle_rules(seed, variant):
    rng = random.Random(seed)
    params = dict(AxisJerk=100000.0, AxisDec=8000.0)  # MC_Stop's dynamics below stay within the axis limits
    if variant == "limits":
        params.update(AxisEnMaxSoftPosLimit=True, AxisMaxSoftPosLimit=250.0, AxisEnMinSoftPosLimit=True,
                      AxisMinSoftPosLimit=-250.0)
    homing = variant == "modulo+home"
    if homing:
        params.update(Modulo=True, AxisCalibrationVelocityForward=100.0, AxisCalibrationVelocityBackward=20.0)
    core = powered(**params)
    st = {"ctrl": ALL_ENABLES, "direct": False}

    def cam():  # a reference cam every 200 u, seen by the PLC from ActPos
        on = homing and 150.0 <= float(core.nctoplc[0]["ActPos"]) % 200.0 <= 170.0
        power(core, ctrl=st["ctrl"] | (int(ControlDWord.HomingSensor) if on else 0),
              override=int(core.plctonc[0]["Override"]))

    def position_set(p, r):  # homing sets the position at its end, MC_Direct at once
        direct, st["direct"] = st["direct"], False
        return direct or (int(p["HomingState"]) == int(HomingState.SET_POSITION) and int(r["HomingState"]) != int(p["HomingState"]))

    tr = Trace(core, before_step=cam, shift_ok=position_set)
    stopped_at = None
    for _ in range(70):
        k = rng.randrange(20)
        if k == 0:  # a feed enable withdrawn or given back
            st["ctrl"] = rng.choice([ALL_ENABLES, ALL_ENABLES & ~int(ControlDWord.FeedEnablePlus),
                                     ALL_ENABLES & ~int(ControlDWord.FeedEnableMinus)])
        elif k == 1:
            d = rng.uniform(-50, 50)
            if cmd(core, "SetActualPositionOnTheFly", ActualPosition=d, PreviousPosition=0.0)["error"] == 0:
                tr.shift(d)
        elif k == 2 and homing:
            cmd(core, "Home", Position=rng.uniform(-100, 100), BufferMode=rng.choice([0, 1]))
        elif k == 3 and homing:
            st["direct"] = cmd(core, "Home", HomingMode=4, Position=rng.uniform(-100, 100))["error"] == 0
        else:
            name, args = random_command(rng, core)
            if name == "override":
                power(core, ctrl=st["ctrl"], override=args["value"])
            else:
                rep = cmd(core, name, **args)
                assert rep["error"] != 0x4000, rep  # never an internal error
                if name == "Stop" and rep["error"] == 0:
                    stopped_at = len(tr.rows)
        tr.step(rng.choice([1, 2, 5, 20, 50, 120]))
        if stopped_at is not None and len(tr.rows) - stopped_at > 30:
            cmd(core, "StopRelease")
            stopped_at = None
        if core.nctoplc[0]["ErrorCode"]:
            tr.until(lambda r: r["SetVelo"] == 0.0 and not core.axes.traj_on[0], 5000)
            st["ctrl"] = ALL_ENABLES
            cmd(core, "Reset")
            tr.shift(float(tr.rows[-1]["ActPos"]) - float(tr.rows[-1]["SetPos"]))
    st["ctrl"] = ALL_ENABLES
    cmd(core, "StopRelease")
    cmd(core, "Stop")
    tr.settle(20_000)
