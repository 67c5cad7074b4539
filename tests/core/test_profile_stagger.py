"""The lookahead buffer is an optimization only: a core that evaluates its set-points ahead in
staggered groups (any lookahead, any refill pattern) produces exactly -- bit for bit -- the NCTOPLC
and NCJOBS of a core that evaluates every cycle (lookahead 1), whatever commands, amendments,
override changes, position shifts, faults and resets come in between."""
import random

import numpy as np
import pytest

from nc_schema import ControlDWord, make_request, parse_request
from nc_server.core import AxisConfig, AxisParams, NcCore
from znc_testing.nc_core import ALL_ENABLES

MODES = [0, 0, 1, 18, 20, 21]
PARAMS = dict(AxisJerk=100000.0, AxisDec=8000.0, AxisEnMaxSoftPosLimit=True, AxisMaxSoftPosLimit=400.0,
              AxisEnMinSoftPosLimit=True, AxisMinSoftPosLimit=-400.0)


def _command(rng: random.Random, p: float) -> tuple[str, dict]:
    v = rng.choice([20.0, 100.0, 250.0, 600.0, 1000.0])
    k = rng.randrange(14)
    if k <= 3:
        return "MoveAbsolute", dict(Position=rng.uniform(-300, 300), Velocity=v, BufferMode=rng.choice(MODES))
    if k == 4:
        return "MoveRelative", dict(Distance=rng.uniform(-100, 100), Velocity=v, BufferMode=rng.choice(MODES))
    if k == 5:
        return "MoveVelocity", dict(Velocity=v, Direction=rng.choice([1, 3]), BufferMode=rng.choice(MODES))
    if k == 6:
        return "MoveContinuousAbsolute", dict(Position=rng.uniform(-300, 300), Velocity=v,
                                              EndVelocity=rng.choice([0.0, 50.0]), BufferMode=rng.choice(MODES))
    if k == 7:
        return "Halt", dict(BufferMode=rng.choice([0, 1]))
    if k == 8:
        return "NewPos", dict(NewPos=p + rng.uniform(-80, 80))
    if k == 9:
        return "NewPosAndVelo", dict(Mode=rng.choice([1, 3, 9]), NewPos=p + rng.uniform(-80, 80), NewVelo=v,
                                     ActivationPos=p + rng.uniform(-40, 40))
    if k == 10:
        return "ChangeDynParam", dict(Acceleration=3000.0, Deceleration=3000.0, Jerk=30000.0)
    if k == 11:
        return "Stop", {}
    if k == 12:
        return "SetActualPositionOnTheFly", dict(ActualPosition=p + 5.0, PreviousPosition=p)
    return "Reset", {}


def _cores(n: int, variants: list[tuple[int, int | None]]) -> list[NcCore]:
    """One core per (lookahead, groups); the first (the reference) evaluates every refill in full (no
    steady groups: ``ProfileStage.steady`` False), the others with steady groups."""
    cores = []
    for lookahead, groups in variants:
        core = NcCore([AxisConfig(i + 1, f"A{i + 1}", AxisParams(**PARAMS)) for i in range(n)], 0.001,
                      lookahead=lookahead)
        if groups is not None:
            core.profile.set_groups(groups)
        core.profile.steady = bool(cores)
        cores.append(core)
    return cores


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("n, variants", [
    (7, [(1, None), (1, None), (16, None), (4, None), (16, 4), (16, 1)]),   # fewer axes than the lookahead
    (37, [(1, None), (1, None), (4, None), (16, None), (8, 2), (16, 1)]),   # uneven groups; large blocks
])
def test_staggered_lookahead_gives_the_set_points_of_lookahead_1(seed, n, variants):
    rng = random.Random(seed)
    cores = _cores(n, variants)
    ctrl = [ALL_ENABLES] * n
    override = [1_000_000] * n
    ids = iter(range(1, 10**6))

    def plctonc(i: int) -> None:
        for core in cores:
            rec = core.default_plctonc()
            rec["ControlDWord"] = ctrl[i]
            rec["Override"] = override[i]
            core.set_plctonc(i, rec)

    for i in range(n):
        plctonc(i)
    ref = cores[0]
    moving_seen = 0
    for cycle in range(700):
        if cycle > 2 and rng.random() < 0.6:  # commands between cycles, several in one cycle at times
            for _ in range(rng.choice([1, 1, 1, 2, 5])):
                i = rng.randrange(n)
                r = rng.random()
                if r < 0.06:
                    override[i] = rng.choice([0, 300_000, 1_000_000])
                    plctonc(i)
                    continue
                if r < 0.08:  # a feed enable withdrawn (a fault while moving) or given back
                    ctrl[i] = rng.choice([ALL_ENABLES, ALL_ENABLES & ~int(ControlDWord.FeedEnablePlus)])
                    plctonc(i)
                    continue
                name, args = _command(rng, float(ref.nctoplc[i]["SetPos"]))
                req = parse_request(make_request(name, next(ids), "test", **args))
                replies = [core.execute(dict(req), i + 1) for core in cores]
                for rep in replies[1:]:
                    assert rep == replies[0], (cycle, name, args)
        for core in cores:
            core.step()
        moving_seen += int(np.count_nonzero(ref.moving))
        want = ref.nctoplc.tobytes()
        for core in cores[1:]:
            if core.nctoplc.tobytes() != want:
                diff = [(int(i), f) for i in range(n) for f in ref.nctoplc.dtype.names
                        if ref.nctoplc[i][f].tobytes() != core.nctoplc[i][f].tobytes()]
                pytest.fail(f"cycle {cycle}: lookahead {core.profile.lookahead} groups {getattr(core.profile, 'groups', None)} "
                            f"differs from lookahead 1 in {diff[:8]}")
            assert core.ncjobs.tobytes() == ref.ncjobs.tobytes(), cycle
    assert moving_seen > 700 * n // 4  # the sequence kept axes moving most of the time


def test_staggered_lookahead_on_long_steady_motions():
    """Large refill blocks where most rows stay in one segment for the whole window (the segment
    search looks only at the rows that reach their next segment); steady groups (positions only) while
    no row changes, up to the end of a positioning's constant-velocity phase and from the start of a
    velocity job's: the same set-points, bit for bit, as the full evaluation."""
    n = 40
    cores = _cores(n, [(1, None), (1, None), (16, 1), (16, 4), (16, 16), (4, 1), (16, 2)])
    ids = iter(range(1, 10**6))
    for core in cores:
        for i in range(n):
            rec = core.default_plctonc()
            rec["ControlDWord"] = ALL_ENABLES
            core.set_plctonc(i, rec)
    ref = cores[0]
    for cycle in range(450):
        if cycle % 150 == 1:  # every axis (again) at its own velocity, then long stretches without commands
            for i in range(n):
                v = 50.0 + 7.0 * i + cycle / 10
                if i % 4 == 3:  # a positioning whose constant-velocity phase ends inside the stretch
                    p = float(ref.nctoplc[i]["SetPos"]) + (1 if (i + cycle) % 3 else -1) * v * 0.12
                    req = parse_request(make_request("MoveAbsolute", next(ids), "test", Position=p, Velocity=v))
                else:
                    req = parse_request(make_request("MoveVelocity", next(ids), "test", Velocity=v,
                                                     Direction=1 if (i + cycle) % 3 else 3))
                assert len({repr(core.execute(dict(req), i + 1)) for core in cores}) == 1
        for core in cores:
            core.step()
        for core in cores[1:]:
            assert core.nctoplc.tobytes() == ref.nctoplc.tobytes(), (cycle, core.profile.lookahead, core.profile.groups)
    for core in cores[1:]:  # (a group is steady when all its rows are: the groups of only velocity jobs here)
        if core.profile.groups >= 4:
            assert core.profile.steady_refills > 0, (core.profile.lookahead, core.profile.groups)
