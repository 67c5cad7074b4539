"""Two PLC processes on one NC: claims, commands superseding each other, MC_Stop's lock."""
from __future__ import annotations

from typing import Callable, Iterator

import pytest

from znc_testing.plc_harness import NC_ARGS, T, PlcProcess, power_on
from znc_testing import NcServerProcess


@pytest.fixture
def two(start_nc: Callable[..., NcServerProcess]) -> Iterator[tuple[PlcProcess, PlcProcess]]:
    nc = start_nc(extra_args=NC_ARGS)
    a, b = PlcProcess(nc.endpoint, "plc-a"), PlcProcess(nc.endpoint, "plc-b")
    try:
        a.wait_started()
        b.wait_started()
        yield a, b
    finally:
        a.stop()
        b.stop()


def test_command_from_another_plc_aborts_the_first(two: tuple[PlcProcess, PlcProcess]) -> None:
    a, b = two
    power_on(a)
    a.set("mv", "MC_MoveAbsolute", Execute=True, Position=900.0, Velocity=50.0)
    a.wait("mv", lambda r: r.o["Active"], T)
    # plc-b does not control the axis, but may command it (the holder's enables are on)
    b.set("mv", "MC_MoveAbsolute", Execute=True, Position=5.0, Velocity=100.0)
    r = a.wait("mv", lambda r: not r.o["Busy"], T)
    assert r.o["CommandAborted"] and not r.o["Error"] and not r.o["Done"]
    done = b.wait("mv", lambda r: r.o["Done"], T)
    assert abs(done.a["ActPos"] - 5.0) < 0.02


def test_claim_is_exclusive_until_released(two: tuple[PlcProcess, PlcProcess]) -> None:
    a, b = two
    power_on(a)
    b.set("pw", "MC_Power", Enable=True, Enable_Positive=True, Enable_Negative=True)
    r = b.wait("pw", lambda r: r.o["Error"], T)
    assert r.o["ErrorID"] == 0x723 and not r.o["Status"]
    # plc-a ends (SIGTERM: enables off, Release); plc-b gets the axis on its next claim retry
    assert a.stop() == 0
    r = b.wait("pw", lambda r: r.o["Status"], T)
    assert not r.o["Error"]


def test_stop_from_one_plc_locks_out_moves_from_the_other(two: tuple[PlcProcess, PlcProcess]) -> None:
    a, b = two
    power_on(a)
    a.set("jog", "MC_MoveVelocity", Execute=True, Velocity=30.0)
    a.wait("jog", lambda r: r.o["Active"] or r.o["InVelocity"], T)
    b.set("stop", "MC_Stop", Execute=True)
    s = b.wait("stop", lambda r: r.o["Done"], T)
    assert s.o["Busy"] and s.o["Active"] and s.a["Locked"] and s.a["State"] == "STOPPING"
    a.set("mv", "MC_MoveAbsolute", Execute=True, Position=0.0, Velocity=50.0)
    r = a.wait("mv", lambda r: r.o["Error"], T)
    assert r.o["ErrorID"] == 0x42EF
    b.wait_cycles(20)
    assert b.last("stop").o["Done"] and b.last("stop").o["Busy"], "still locked while Execute is TRUE"
    b.set("stop", Execute=False)
    b.wait("stop", lambda r: not r.o["Busy"] and not r.o["Done"], T)
    a.wait("mv", lambda r: not r.a["Locked"] and r.a["State"] == "STANDSTILL", T)
    a.set("mv", Execute=False)
    a.wait_cycles(2)
    a.set("mv", Execute=True)
    done = a.wait("mv", lambda r: r.o["Done"], T)
    assert abs(done.a["ActPos"]) < 0.02
