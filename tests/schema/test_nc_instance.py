"""nc_schema.NcInstance: the one restart rule of the clients (PLC runtime, nc-ads, nc-status).

A restart is a new NC instance in the frames; the NC's liveliness token going and coming back (a zenoh
link dropped for a lease while the same NC ran on) is not fed to it.
"""
from __future__ import annotations

from nc_schema import NcInstance
from nc_schema.instance import MIN_GAP_NS

MS = 1_000_000  # one 1 ms NC cycle [ns]
T0 = 1_800_000_000 * 10**9  # some CLOCK_REALTIME [ns]


def feed(inst: NcInstance, first: int, last: int, step: int = 5, start: int = T0, missed: int = 0) -> set[str | None]:
    """Frames of cycles first..last every ``step`` cycles of an instance started at ``start`` that
    missed ``missed`` cycles so far; the set of what ``frame`` returned."""
    return {inst.frame(c, start + (c - 1 + missed) * MS) for c in range(first, last + 1, step)}


def test_the_same_instance_through_gaps_and_stalls_is_no_restart() -> None:
    inst = NcInstance()
    assert feed(inst, 1, 6000) == {None}
    assert inst.cycle_ns == MS
    assert inst.frame(6000, T0 + 5999 * MS) is None  # the same frame again
    # frozen 4.5 s (4500 missed cycles), then 6 s (longer than MIN_GAP_NS, shorter than its life)
    assert feed(inst, 6005, 7000, missed=4500) == {None}
    assert feed(inst, 7005, 8000, missed=10500) == {None}
    # a client that saw nothing for 20 s: the cycles went on with the NC time
    assert feed(inst, 28000, 28100, missed=10500) == {None}
    assert inst.restarts == 0


def test_the_cycle_going_back_is_a_restart() -> None:
    inst = NcInstance()
    feed(inst, 1, 3000)
    assert inst.frame(7, T0 + 10_000 * MS) == "its cycle counter went back"
    assert inst.frame(2, None) is not None  # (without NC time as well)
    assert inst.restarts == 2


def test_a_new_instance_that_counted_more_cycles_is_a_restart() -> None:
    inst = NcInstance()
    feed(inst, 1, 3000)  # the old instance ran 3 s
    t_last = inst.nc_time_ns
    assert t_last is not None
    # the new one started 1 s after that frame and counted 9000 cycles before its first frame came
    why = inst.frame(9000, t_last + 1000 * MS + 8999 * MS)
    assert why is not None and "NC time" in why and inst.restarts == 1
    assert inst.cycle_ns is None  # learnt again from the new instance's frames
    assert feed(inst, 9005, 10000, start=t_last + 1000 * MS) == {None}


def test_rule_2_needs_the_minimum_gap_and_a_known_cycle_time() -> None:
    inst = NcInstance()
    feed(inst, 1, 100)  # a young NC (0.1 s), frozen 4 s: not a restart (below MIN_GAP_NS)
    assert MIN_GAP_NS > 4000 * MS
    assert inst.frame(105, inst.nc_time_ns + 4000 * MS) is None  # type: ignore[operator]
    one = NcInstance()
    assert one.frame(10, T0) is None and one.frame(10, T0 + 60_000 * MS) is None  # no cycle time learnt yet
