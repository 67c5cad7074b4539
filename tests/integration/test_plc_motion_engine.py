"""The motion engine's main behaviour through the real distributed path (``nc-server`` and
``plc-run`` processes on 127.0.0.1, free ports; the server's process group is killed at the end):
a buffered sequence of three blended moves, each block ending Done, and MC_NewPos on a running
move (the move block ends Done at the new target).

The PLC process runs ``plc_agent.py``; its blocks report each change of their outputs with the
PLC cycle, so the transitions can be checked cycle by cycle. Deadlines are generous (loaded
2-core machine).
"""
from __future__ import annotations

import math

from znc_testing.plc_harness import T, PlcProcess, ended, exclusive, first_cycle, power_on


def test_buffered_sequence_of_three_blended_moves(plc: PlcProcess) -> None:
    power_on(plc)
    plc.set("m1", "MC_MoveAbsolute", Execute=True, Position=100.0, Velocity=150.0)
    plc.wait("m1", lambda r: r.o["Active"], T)
    # one command can wait behind the active one: queue the next when its predecessor is active
    plc.set("m2", "MC_MoveAbsolute", Execute=True, Position=200.0, Velocity=250.0, BufferMode=20)  # BlendingNext
    plc.wait("m2", lambda r: r.o["Busy"] and not r.o["Active"], T)
    plc.wait("m2", lambda r: r.o["Active"], T)
    plc.set("m3", "MC_MoveAbsolute", Execute=True, Position=300.0, Velocity=100.0, BufferMode=18)  # BlendingLow
    plc.wait("m3", lambda r: r.o["Busy"], T)
    done = plc.wait("m3", ended, T)
    assert done.o["Done"], done
    assert math.isclose(done.a["ActPos"], 300.0, abs_tol=0.02)
    plc.wait_cycles(5)
    h1, h2, h3 = plc.history("m1"), plc.history("m2"), plc.history("m3")
    for h in (h1, h2, h3):
        exclusive(h)
        assert not any(r.o["Error"] or r.o["CommandAborted"] for r in h), h
    assert plc.last("m1").o["Done"] and plc.last("m2").o["Done"] and plc.last("m3").o["Done"]
    # each predecessor is Done in the cycle its successor becomes Active (blending: no stop between)
    assert first_cycle(h1, "Done") == first_cycle(h2, "Active")
    assert first_cycle(h2, "Done") == first_cycle(h3, "Active")
    # blended: the axis did not come to rest at 100 or 200 (DISCRETEMOTION until it reaches 300)
    states = [r.a["State"] for r in h1 + h2 + h3 if r.c >= first_cycle(h1, "Active") and r.a["ActPos"] < 299.0]
    assert states and "STANDSTILL" not in states, states


def test_new_pos_on_a_running_move(plc: PlcProcess) -> None:
    power_on(plc)
    plc.set("mv", "MC_MoveAbsolute", Execute=True, Position=300.0, Velocity=100.0)
    plc.set("pos", "MC_ReadActualPosition", Enable=True)
    plc.wait("mv", lambda r: r.o["Active"], T)
    plc.wait("pos", lambda r: r.o["Valid"] and r.o["Position"] > 50.0, T)
    plc.set("np", "MC_NewPos", Execute=True, NewPos=150.0)
    r = plc.wait("np", lambda r: r.o["Done"] or r.o["Error"], T)
    assert r.o["Done"], r
    assert plc.last("mv").o["Busy"], "the amended move goes on"
    done = plc.wait("mv", ended, T)
    assert done.o["Done"], done
    assert math.isclose(done.a["ActPos"], 150.0, abs_tol=0.02)
    exclusive(plc.history("mv"))
    exclusive(plc.history("np"))
