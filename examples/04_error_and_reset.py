"""Example 4: read an axis error and clear it with MC_Reset.

    plc-run examples/04_error_and_reset.py --duration 3

A move beyond the software limit is rejected by the NC (0x4222); withdrawing the feed enable
while moving makes an axis error (ErrorStop, 0x4358) that MC_ReadAxisError shows (MC_Power's
Error/ErrorID show it too) and MC_Reset clears.

A step sequence (see example 1) runs it once: MC_Power.Status is the condition of the first
step only (it is FALSE in ErrorStop and while the NC's data is stale, and its return must not
start anything by itself).
"""
from plc_client import AXIS_REF, MC_MoveAbsolute, MC_MoveVelocity, MC_Power, MC_ReadAxisError, MC_Reset

X = AXIS_REF(nc="nc1", axis_id=1)
power, far, jog, err, reset = MC_Power(), MC_MoveAbsolute(), MC_MoveVelocity(), MC_ReadAxisError(), MC_Reset()
# 0 wait for the enable, 10 a move beyond the limit, 20 jog, 30 feed enable withdrawn (until the
# axis stands in ErrorStop), 40 MC_Reset, 50 done, 90 something else than expected happened
step = 0
since = 0.0  # when the step began [s]


def cycle(plc):
    global step, since
    t = plc.now - since
    err(Axis=X, Enable=True)
    if step == 0:
        if power.Status:
            step = 10
    elif step == 10:  # rejected by the NC at once
        if far.Error:
            print(f"MC_MoveAbsolute to 1e6 rejected: ErrorID 0x{far.ErrorID:X}")
            step, since = 20, plc.now
        elif far.Done or far.CommandAborted:
            step = 90
    elif step == 20:  # jog forward for 0.5 s, then withdraw the positive feed enable
        if jog.Error:
            step = 90
        elif t >= 0.5:
            step = 30
    elif step == 30:  # the axis error follows; the NC stops the axis
        if err.AxisErrorID and X.Status.NotMoving:
            print(f"axis error 0x{err.AxisErrorID:X}, state {X.Status.MotionState.name}, stopped at {X.ActPos:.2f}")
            step = 40
    elif step == 40:  # clear it
        if reset.Done:
            print(f"MC_Reset done, state {X.Status.MotionState.name}")
            step = 50
        elif reset.Error:
            step = 90
    if step == 90:
        print("an unexpected result; the sequence stops here")
        step = 91
    power(Axis=X, Enable=True, Enable_Positive=step < 30 or step >= 40, Enable_Negative=True)
    far(Axis=X, Execute=step == 10, Position=1e6, Velocity=10.0)
    jog(Axis=X, Execute=step in (20, 30), Velocity=20.0)
    reset(Axis=X, Execute=step == 40)
