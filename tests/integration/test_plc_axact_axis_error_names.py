"""Issue 17's PLC-side rules through the real distributed path (``nc-server`` and ``plc-run plc_agent.py``
on 127.0.0.1, fixtures in conftest.py), where the NC's reply and its frames arrive as the network
delivers them: the reply first, the frame of its cycle a little later.

* AXACT: BUSY falls on the first frame that shows the accepted command, so in the PLC cycle BUSY falls
  the axis's HasJob is TRUE (TcMC: "as soon as BUSY goes FALSE, the bit 'axis has transport
  instruction' is set"); repeated edges, each from standstill;
* MC_ReadAxisError: ErrorID is the axis's error code, Error = (code != 0), Done while read;
* names in any case: a block driven and read in other spellings than the declared ones.

Only the order of events and positions are asserted, never how fast anything happened.
"""
from __future__ import annotations

import math

from znc_testing.plc_harness import T, PlcProcess, exclusive, power_on

#: AXACT edges from standstill (each a chance for the reply to arrive before its frame)
EDGES = 8


def test_axact_busy_falls_with_has_job(plc: PlcProcess) -> None:
    power_on(plc)  # AXACT only sends commands; MC_Power of this PLC holds the axis
    plc.trace(1)
    plc.set("ax", "AXACT", AXID=1, START=False, MODE=2, VELOCITY=100.0, TARGPOS=5.0)
    for k in range(EDGES):
        c = plc.edge("ax", "START", TARGPOS=5.0 if k % 2 == 0 else -5.0)  # 0.05 s or more of motion
        busy = plc.wait("ax", lambda r: r.c > c and r.o["BUSY"], T)
        fell = plc.wait("ax", lambda r: r.c > busy.c and not r.o["BUSY"], T)
        assert not fell.o["ERR"], fell
        assert fell.a["HasJob"], f"edge {k}: BUSY fell while HasJob was still FALSE: {fell}"
        plc.wait_trace(1, lambda s: s.c > fell.c and not s.a["HasJob"] and s.a["State"] == "STANDSTILL", T)
    # STOP (a Halt) follows the same rule
    c = plc.edge("ax", "START", MODE=3, VELOCITY=40.0)
    plc.wait_trace(1, lambda s: s.c > c and s.a["State"] == "CONTINOUSMOTION", T)
    plc.set("ax", START=False)
    c = plc.edge("ax", "STOP")
    busy = plc.wait("ax", lambda r: r.c > c and r.o["BUSY"], T)
    fell = plc.wait("ax", lambda r: r.c > busy.c and not r.o["BUSY"], T)
    assert not fell.o["ERR"] and fell.a["HasJob"], fell
    plc.wait_trace(1, lambda s: s.c > fell.c and s.a["State"] == "STANDSTILL", T)


def test_read_axis_error_shows_the_axis_error(plc: PlcProcess) -> None:
    power_on(plc)
    plc.set("err", "MC_ReadAxisError", Enable=True)
    ok = plc.wait("err", lambda r: r.o["Done"], T)
    assert not ok.o["Error"] and ok.o["ErrorID"] == 0 and ok.o["Valid"] and ok.o["Busy"]
    # an axis error: the positive feed enable withdrawn while moving in positive direction
    plc.set("jog", "MC_MoveVelocity", Execute=True, Velocity=20.0)
    plc.wait("jog", lambda r: r.o["InVelocity"], T)
    plc.set("pw", Enable_Positive=False)
    e = plc.wait("err", lambda r: r.o["Error"], T)
    assert e.o["ErrorID"] == e.o["AxisErrorID"] == 0x4358 and e.o["Done"] and e.a["ErrorId"] == 0x4358, e
    plc.set("pw", Enable_Positive=True)
    plc.set("rst", "MC_Reset", Execute=True)
    plc.wait("rst", lambda r: r.o["Done"], T)
    r = plc.wait("err", lambda r: not r.o["Error"], T)
    assert r.o["ErrorID"] == 0 and r.o["AxisErrorID"] == 0 and r.o["Done"], r
    plc.set("err", Enable=False)
    off = plc.wait("err", lambda r: not r.o["Busy"], T)
    assert not any(off.o.values()), off


def test_a_block_in_other_spellings(plc: PlcProcess) -> None:
    power_on(plc, axis=2)
    # ST ignores case: the agent passes these keywords as they are (fb(Axis=ax, execute=True, ...))
    plc.set("mv", "MC_MoveAbsolute", axis=2, execute=True, POSITION=12.0, velocity=100.0)
    done = plc.wait("mv", lambda r: r.o["Done"], T)
    assert math.isclose(done.a["ActPos"], 12.0, abs_tol=0.02), done
    assert plc.get("mv", "DONE") is True and plc.get("mv", "ErrorId") == 0 and plc.get("mv", "position") == 12.0
    # (the agent keeps each keyword as sent: one spelling per input, as an ST call has)
    plc.set("mv", execute=False)
    plc.wait("mv", lambda r: not r.o["Done"], T)
    plc.set("mv", execute=True, velocity=-1.0)
    bad = plc.wait("mv", lambda r: r.o["Error"], T)
    assert bad.o["ErrorID"] == 0x4221 and plc.get("mv", "errorid") == 0x4221, bad
    exclusive(plc.history("mv"))
