"""Example 2: endless motion with MC_MoveVelocity, then MC_Stop (which locks the axis).

    plc-run examples/02_velocity_and_stop.py --duration 5

InVelocity comes once the constant velocity is reached. MC_Stop keeps the axis locked
(Busy/Active TRUE, Done once stopped) while its Execute is TRUE: any other motion command
is refused with 0x42EF. Execute FALSE releases the lock.

A step sequence drives the blocks (see example 1): the motion starts once, from step 0, and a
fall and return of MC_Power.Status (stale NC data, 0x4B0F) does not start it again.
"""
from plc_client import AXIS_REF, MC_Direction, MC_MoveVelocity, MC_Power, MC_Stop

X = AXIS_REF(nc="nc1", axis_id=1)
power, jog, stop = MC_Power(), MC_MoveVelocity(), MC_Stop()
step = 0  # 0 wait for the enable, 10 endless motion, 20 MC_Stop (locks), 30 release, 40 done, 90 failed
since = 0.0  # when the step began [s]


def cycle(plc):
    global step, since
    power(Axis=X, Enable=True, Enable_Positive=True, Enable_Negative=True)
    t = plc.now - since  # time in this step
    if step == 0:
        if power.Status:
            step, since = 10, plc.now
    elif step == 10:  # 1.5 s of endless motion
        if jog.Error:
            print(f"MC_MoveVelocity failed: 0x{jog.ErrorID:X}")
            step = 90
        elif t >= 1.5:
            step, since = 20, plc.now
    elif step == 20:  # stop and keep the axis locked for 1.5 s
        if stop.Error:
            print(f"MC_Stop failed: 0x{stop.ErrorID:X}")
            step = 90
        elif t >= 1.5 and stop.Done:
            step = 30
    elif step == 30:  # MC_Stop's Execute is FALSE now: the NC releases the lock
        if not X.Status.MotionCommandsLocked:
            print(f"lock released at {X.ActPos:.2f}")
            step = 40  # done; the axis stays enabled
    jog(Axis=X, Execute=step == 10, Velocity=50.0, Direction=MC_Direction.MC_Positive_Direction)
    stop(Axis=X, Execute=step == 20, Deceleration=500.0, Jerk=5000.0)
    if jog.InVelocity and plc.cycle % 25 == 0:
        print(f"t={t:.2f} s: constant velocity {X.NcToPlc.ActVelo:.1f} u/s at {X.ActPos:.1f}")
    if stop.Done and stop.Busy and plc.cycle % 25 == 0:
        print(f"t={t:.2f} s: stopped at {X.ActPos:.2f}, axis locked: {X.Status.MotionCommandsLocked}")
