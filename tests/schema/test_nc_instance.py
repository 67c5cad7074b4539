"""nc_schema.NcInstance: the one restart rule of the clients (PLC runtime, nc-ads, nc-status).

A restart is a new NC instance in the frames (the cycle counter went back); the NC's liveliness token
going and coming back (a zenoh link dropped for a lease while the same NC ran on) is not fed to it.
"""
from __future__ import annotations

from nc_schema import NcInstance


def test_cycles_going_on_through_gaps_are_the_same_instance() -> None:
    inst = NcInstance()
    for c in [*range(1, 5000, 5), 5000, 5000, 9000, 9001]:  # repeated frames, gaps (stalls, a dropped link)
        assert inst.frame(c) is None
    assert inst.restarts == 0 and inst.cycle == 9001


def test_each_cycle_going_back_is_one_restart() -> None:
    inst = NcInstance()
    assert inst.frame(3000) is None
    assert inst.frame(7) == "its cycle counter went back"
    assert [inst.frame(c) for c in (8, 500, 2)] == [None, None, "its cycle counter went back"]
    assert inst.restarts == 2 and inst.cycle == 2
