"""Example 4: read an axis error and clear it with MC_Reset.

    plc-run examples/04_error_and_reset.py --duration 3

A move beyond the software limit is rejected by the NC (0x4222); withdrawing the feed enable
while moving makes an axis error (ErrorStop, 0x4358) that MC_ReadAxisError shows and
MC_Reset clears.
"""
from plc_client import AXIS_REF, MC_MoveAbsolute, MC_MoveVelocity, MC_Power, MC_ReadAxisError, MC_Reset

X = AXIS_REF(nc="nc1", axis_id=1)
power, far, jog, err, reset = MC_Power(), MC_MoveAbsolute(), MC_MoveVelocity(), MC_ReadAxisError(), MC_Reset()
reported = set()


def say(key, text):
    if key not in reported:
        reported.add(key)
        print(text)


def cycle(plc):
    t = plc.now % 3.0
    power(Axis=X, Enable=True, Enable_Positive=t < 1.0, Enable_Negative=True)
    far(Axis=X, Execute=power.Status, Position=1e6, Velocity=10.0)
    if far.Error:
        say("far", f"MC_MoveAbsolute to 1e6 rejected: ErrorID 0x{far.ErrorID:X}")
    jog(Axis=X, Execute=power.Status and 0.5 < t < 1.0, Velocity=20.0)
    err(Axis=X, Enable=True)
    if err.AxisErrorID:
        say("axis", f"axis error 0x{err.AxisErrorID:X}, state {X.Status.MotionState.name}")
    reset(Axis=X, Execute=err.AxisErrorID != 0 and t > 2.0)
    if reset.Done:
        say("reset", f"MC_Reset done, state {X.Status.MotionState.name}")
