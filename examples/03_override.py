"""Example 3: velocity override. MC_Power's Override input scales every motion of the axis;
MC_SetOverride changes it on an Execute edge (the last writer wins).

    plc-run examples/03_override.py --duration 4
"""
from plc_client import AXIS_REF, MC_MoveVelocity, MC_Power, MC_SetOverride

Y = AXIS_REF(nc="nc1", axis_id=2)
power, jog, override = MC_Power(), MC_MoveVelocity(), MC_SetOverride()


def cycle(plc):
    power(Axis=Y, Enable=True, Enable_Positive=True, Enable_Negative=True, Override=100.0)
    jog(Axis=Y, Execute=power.Status, Velocity=40.0)
    # every second a new override: 100 % -> 50 % -> 25 % -> 100 % ...
    percent = 100.0 / 2 ** (plc.cycle // 100 % 3)
    override(Axis=Y, Execute=plc.cycle % 100 == 0, Override=percent)
    if plc.cycle % 100 == 50:  # half a second later
        print(f"override {percent:5.1f} %: set velocity {float(Y.NcToPlc['SetVelo']):5.1f} u/s")
