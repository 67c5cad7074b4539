"""The TcMC blocks through the real distributed path: ``nc-server`` and ``plc-run`` processes on
127.0.0.1, commands as zenoh queries, status as the NC's frames, PLCTONC as the PLC's frames.

The PLC process runs ``plc_agent.py`` (blocks created and driven from the test over stdin,
output changes reported per PLC cycle on stdout). Deadlines are generous (loaded 2-core VM).
"""
from __future__ import annotations

import math

from znc_testing.plc_harness import T, PlcProcess, exclusive, power_on


def test_power_and_move_absolute_done_held(plc: PlcProcess) -> None:
    r = power_on(plc)
    assert r.o["Busy"] and r.o["Active"] and not r.o["Error"] and r.a["State"] == "STANDSTILL"
    plc.set("mv", "MC_MoveAbsolute", Execute=True, Position=40.0, Velocity=200.0)
    plc.wait("mv", lambda r: r.o["Active"], T)
    done = plc.wait("mv", lambda r: r.o["Done"], T)
    assert math.isclose(done.a["ActPos"], 40.0, abs_tol=0.02) and done.a["State"] == "STANDSTILL"
    plc.wait_cycles(30)
    assert plc.last("mv").o["Done"], "Done is held while Execute stays TRUE"
    exclusive(plc.history("mv"))
    plc.set("mv", Execute=False)
    plc.wait("mv", lambda r: not r.o["Done"], T)


def test_done_pulse_and_retrigger(plc: PlcProcess) -> None:
    power_on(plc)
    plc.set("mv", "MC_MoveRelative", Execute=True, Distance=30.0, Velocity=20.0)
    plc.wait("mv", lambda r: r.o["Active"], T)
    # a rising edge while Busy: ignored (no new command: the axis ends at 30, not 100 further)
    plc.edge("mv", Distance=100.0)
    plc.sync()
    plc.set("mv", Execute=False)
    end = plc.wait("mv", lambda r: not r.o["Busy"], T)
    assert end.o["Done"]
    plc.wait_cycles(5)
    hist = plc.history("mv")
    i = next(k for k, r in enumerate(hist) if r.o["Done"])
    assert hist[i + 1].c == hist[i].c + 1 and not hist[i + 1].o["Done"], "Done for exactly one cycle"
    assert math.isclose(hist[i].a["ActPos"], 30.0, abs_tol=0.02)
    exclusive(hist)


def test_move_velocity_override_halt_and_reads(plc: PlcProcess) -> None:
    power_on(plc, axis=2)
    plc.set("rs", "MC_ReadStatus", axis=2, Enable=True)
    plc.set("jog", "MC_MoveVelocity", axis=2, Execute=True, Velocity=40.0, Direction=1)
    r = plc.wait("jog", lambda r: r.o["InVelocity"], T)
    assert not r.o["Busy"] and r.a["State"] == "CONTINOUSMOTION"
    plc.wait("rs", lambda r: r.o["ContinuousMotion"] and r.o["ConstantVelocity"], T)
    plc.set("ov", "MC_SetOverride", axis=2, Execute=True, Override=50.0)
    ov = plc.wait("ov", lambda r: r.o["Done"], T)
    # measure once the override's deceleration ramp is over (a ramp inside the window would add to
    # the rate): the first ConstantVelocity after the override was written (the ramp starts later)
    c_ov = ov.a["NcCycle"]
    plc.wait("rs", lambda r: r.a["NcCycle"] > c_ov and r.o["ConstantVelocity"], T)
    plc.set("pos", "MC_ReadActualPosition", axis=2, Enable=True)
    p1 = plc.wait("pos", lambda r: r.o["Valid"], T)
    plc.wait_cycles(100)
    plc.delete("pos")
    plc.set("pos2", "MC_ReadActualPosition", axis=2, Enable=True)
    p2 = plc.wait("pos2", lambda r: r.o["Valid"], T)
    # the simulated axis moves by NC cycles (1 ms each), whatever the wall clock does
    rate = (p2.o["Position"] - p1.o["Position"]) / ((p2.a["NcCycle"] - p1.a["NcCycle"]) * 0.001)
    assert 19.5 < rate < 20.5, rate  # 50 % of 40 u/s
    plc.set("halt", "MC_Halt", axis=2, Execute=True)
    plc.wait("halt", lambda r: r.o["Done"], T)
    plc.wait("rs", lambda r: r.o["StandStill"] and not r.o["ContinuousMotion"], T)


def test_errors_reset_and_rejections(plc: PlcProcess) -> None:
    power_on(plc)
    # a BufferMode that is not an integer is refused by the block itself (integers go to the NC)
    plc.set("bm", "MC_MoveAbsolute", Execute=True, Position=1.0, Velocity=1.0, BufferMode=1.5)
    assert plc.wait("bm", lambda r: r.o["Error"], T).o["ErrorID"] == 0x4B64
    plc.set("bad", "MC_MoveAbsolute", Execute=True, Position=1.0, Velocity=-5.0)
    assert plc.wait("bad", lambda r: r.o["Error"], T).o["ErrorID"] == 0x4221
    plc.set("far", "MC_MoveAbsolute", Execute=True, Position=5000.0, Velocity=10.0)
    assert plc.wait("far", lambda r: r.o["Error"], T).o["ErrorID"] == 0x4222  # beyond the soft limit
    # an axis error: feed enable plus withdrawn while moving in plus direction
    plc.set("err", "MC_ReadAxisError", Enable=True)
    plc.set("jog", "MC_MoveVelocity", Execute=True, Velocity=20.0)
    plc.wait("jog", lambda r: r.o["InVelocity"], T)
    plc.set("pw", Enable_Positive=False)
    e = plc.wait("err", lambda r: r.o["AxisErrorID"] != 0, T)
    assert e.o["AxisErrorID"] == 0x4358 and e.a["State"] == "ERRORSTOP"
    plc.set("mv", "MC_MoveAbsolute", Execute=True, Position=0.0, Velocity=10.0)
    assert plc.wait("mv", lambda r: r.o["Error"], T).o["ErrorID"] == 0x4B01
    plc.set("rst", "MC_Reset", Execute=True)
    plc.wait("rst", lambda r: r.o["Done"], T)
    plc.wait("err", lambda r: r.o["AxisErrorID"] == 0 and r.a["State"] == "STANDSTILL", T)
    plc.set("mv", Execute=False)
    plc.wait("mv", lambda r: not r.o["Error"], T)
    plc.set("mv", Execute=True)
    plc.wait("mv", lambda r: r.o["Done"], T)


def test_power_off_disables(plc: PlcProcess) -> None:
    power_on(plc)
    plc.set("mv", "MC_MoveVelocity", Execute=True, Velocity=10.0)
    plc.wait("mv", lambda r: r.o["InVelocity"] or r.o["Active"], T)
    plc.set("pw", Enable=False)
    r = plc.wait("pw", lambda r: not r.o["Status"] and r.a["State"] == "DISABLED", T)
    assert not r.o["Busy"] and not r.o["Error"]


def test_move_modulo_on_the_modulo_axis(plc: PlcProcess) -> None:
    power_on(plc, axis=4)
    plc.set("mm", "MC_MoveModulo", axis=4, Execute=True, Position=90.0, Velocity=360.0, Direction=1)
    done = plc.wait("mm", lambda r: r.o["Done"], T)
    assert abs(done.a["ActPos"] - 90.0) < 0.05
    plc.edge("mm", Position=45.0, Direction=1)  # positive direction: a full turn minus 45
    done = plc.wait("mm", lambda r: r.o["Done"] and r.a["ActPos"] > 300.0, T)
    assert abs(done.a["ActPos"] - 405.0) < 0.05
