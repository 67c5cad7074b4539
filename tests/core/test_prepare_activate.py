"""A motion command in two phases (TwinCAT's SVB / SAF): ``NcCore.prepare`` checks and plans it from the
state the next step starts from and changes nothing; ``NcCore.activate`` starts it at the start of that
step, or returns None when its prediction no longer holds (then nothing changes either)."""
import random

import pytest

from nc_schema import ErrorCodes, make_request, parse_request
from nc_server.core.nc import Prepared
from znc_testing.nc_core import ALL_ENABLES, make_core, power, powered, snapshot

from tests.core.test_engine_fuzz import random_command  # noqa: E402  (the fuzz's command mix)


def _req(name: str, rid: int, **args):  # type: ignore[no-untyped-def]
    return parse_request(make_request(name, rid, "t", **args))


def _prepared(core, name: str, axis: int = 1, rid: int = 1, **args) -> Prepared:  # type: ignore[no-untyped-def]
    got = core.prepare(_req(name, rid, **args), axis)
    assert isinstance(got, Prepared), got
    return got


def test_a_preparation_changes_nothing_and_its_activation_is_the_execute() -> None:
    a, b = powered(), powered()
    for core in (a, b):
        core.execute(_req("MoveAbsolute", 1, Position=100.0, Velocity=200.0), 1)
        for _ in range(30):
            core.step()
    before = snapshot(a)
    p = _prepared(a, "MoveAbsolute", rid=2, Position=-50.0, Velocity=300.0)
    assert snapshot(a) == before  # SVB: nothing changed
    assert p.cycle == a.cycle + 1
    r_exec = b.execute(_req("MoveAbsolute", 2, Position=-50.0, Velocity=300.0), 1)
    r_act = a.activate(p)
    assert r_act == r_exec and r_act["cycle"] == a.cycle + 1 and r_act["CmdNo"] == 2
    for _ in range(400):
        a.step()
        b.step()
        assert snapshot(a) == snapshot(b)


@pytest.mark.parametrize("seed", range(3))
def test_random_sequences_prepared_then_activated_equal_execute(seed: int) -> None:
    """Every command of the fuzz's mix: through prepare + activate (a motion that starts now) or at once
    (anything else) the NC does exactly what execute does, cycle by cycle, replies included."""
    rng = random.Random(seed)
    params = dict(AxisJerk=100000.0, AxisDec=8000.0)
    a, b = powered(**params), powered(**params)
    rid = 0
    for _ in range(40):
        name, args = random_command(rng, a)
        if name == "override":
            for core in (a, b):
                power(core, ctrl=ALL_ENABLES, override=args["value"])
        else:
            rid += 1
            got = a.prepare(_req(name, rid, **args), 1)
            r_b = b.execute(_req(name, rid, **args), 1)
            r_a = a.activate(got) if isinstance(got, Prepared) else got
            assert r_a == r_b
        for _ in range(rng.randrange(1, 60)):
            a.step()
            b.step()
            assert snapshot(a) == snapshot(b)


def test_a_fault_before_the_activation_makes_it_stale_and_the_new_preparation_refuses() -> None:
    core = powered()
    p = _prepared(core, "MoveAbsolute", Position=100.0, Velocity=200.0)
    core.fault(0, 0x8F02)  # e.g. the watchdog at the cycle start
    before = snapshot(core)
    assert core.activate(p) is None and snapshot(core) == before  # never activated stale
    again = core.prepare(_req("MoveAbsolute", 1, Position=100.0, Velocity=200.0), 1)
    assert isinstance(again, dict) and again["error"] != 0 and snapshot(core) == before  # refused with its code


@pytest.mark.parametrize("change", ["enable", "override", "step", "other command"])
def test_a_prediction_that_no_longer_holds_is_not_activated(change: str) -> None:
    core = powered()
    p = _prepared(core, "MoveVelocity", Velocity=100.0, Direction=1)
    if change == "enable":
        power(core, ctrl=ALL_ENABLES & ~2)  # FeedEnablePlus off
    elif change == "override":
        power(core, override=500_000)
    elif change == "step":
        core.step()
    else:
        core.execute(_req("Halt", 9), 1)
    before = snapshot(core)
    assert not core.holds(p) and core.activate(p) is None and snapshot(core) == before


def test_a_gearing_is_stale_when_its_master_changed() -> None:
    core = powered(2)
    p = _prepared(core, "GearIn", axis=2, Master=1, RatioNumerator=1, RatioDenominator=1)
    assert {r for r, _ in p.rows} == {0, 1}
    core.execute(_req("MoveVelocity", 5, Velocity=100.0, Direction=1), 1)  # the master's row changed
    assert core.activate(p) is None


def test_other_commands_and_buffered_ones_run_at_once() -> None:
    core = powered()
    assert core.prepare(_req("ReadParameter", 1, ParameterNumber=1003), 1)["error"] == 0
    core.execute(_req("MoveAbsolute", 2, Position=500.0, Velocity=100.0), 1)
    core.step()
    r = core.prepare(_req("MoveAbsolute", 3, Position=600.0, Velocity=100.0, BufferMode=1), 1)
    assert isinstance(r, dict) and r["error"] == 0 and int(core.nctoplc[0]["SvbEntries"]) == 0  # (until the step)
    core.step()
    assert int(core.nctoplc[0]["SvbEntries"]) == 1  # queued behind the running job


def test_a_refused_preparation_changes_nothing() -> None:
    core = make_core()  # not enabled
    before = snapshot(core)
    r = core.prepare(_req("MoveAbsolute", 1, Position=100.0, Velocity=200.0), 1)
    assert isinstance(r, dict) and r["error"] != 0 and snapshot(core) == before
    r = core.prepare(_req("MoveAbsolute", 2, Position=100.0, Velocity=200.0), 99)
    assert isinstance(r, dict) and r["error"] == int(ErrorCodes.NC_AXIS_ID_NOT_ALLOWED)
