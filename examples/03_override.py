"""Example 3: velocity override. MC_Power's Override input scales every motion of the axis;
MC_SetOverride changes it on an Execute edge (the last writer wins).

    plc-run examples/03_override.py --duration 4

The motion is started once, by a latched step (see example 1), not by MC_Power.Status, which
falls and rises again when the NC's data is stale for a moment (0x4B0F).
"""
from plc_client import AXIS_REF, MC_MoveVelocity, MC_Power, MC_SetOverride

Y = AXIS_REF(nc="nc1", axis_id=2)
power, jog, override = MC_Power(), MC_MoveVelocity(), MC_SetOverride()
step = 0  # 0 wait for the enable, 10 endless motion, 90 failed


def cycle(plc):
    global step
    power(Axis=Y, Enable=True, Enable_Positive=True, Enable_Negative=True, Override=100.0)
    if step == 0 and power.Status:
        step = 10
    elif step == 10 and (jog.Error or jog.CommandAborted):
        print(f"MC_MoveVelocity ended: ErrorID 0x{jog.ErrorID:X}")
        step = 90
    jog(Axis=Y, Execute=step == 10, Velocity=40.0)
    # every second a new override: 100 % -> 50 % -> 25 % -> 100 % ...
    percent = 100.0 / 2 ** (plc.cycle // 100 % 3)
    override(Axis=Y, Execute=plc.cycle % 100 == 0, Override=percent)
    if plc.cycle % 100 == 50:  # half a second later
        print(f"override {percent:5.1f} %: set velocity {Y.NcToPlc.SetVelo:5.1f} u/s")
