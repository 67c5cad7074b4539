"""Example 2: endless motion with MC_MoveVelocity, then MC_Stop (which locks the axis).

    plc-run examples/02_velocity_and_stop.py --duration 5

InVelocity comes once the constant velocity is reached. MC_Stop keeps the axis locked
(Busy/Active TRUE, Done once stopped) while its Execute is TRUE: any other motion command
is refused with 0x42EF. Execute FALSE releases the lock.
"""
from plc_client import AXIS_REF, MC_MoveVelocity, MC_Power, MC_Stop, MC_Direction

X = AXIS_REF(nc="nc1", axis_id=1)
power, jog, stop = MC_Power(), MC_MoveVelocity(), MC_Stop()
t0 = None


def cycle(plc):
    global t0
    power(Axis=X, Enable=True, Enable_Positive=True, Enable_Negative=True)
    t0 = plc.now if t0 is None else t0
    t = plc.now - t0
    jog(Axis=X, Execute=power.Status and t < 1.0, Velocity=50.0, Direction=MC_Direction.MC_Positive_Direction)
    stop(Axis=X, Execute=1.5 <= t < 3.0, Deceleration=500.0, Jerk=5000.0)
    if jog.InVelocity and plc.cycle % 25 == 0:
        print(f"t={t:.2f} s: constant velocity {float(X.NcToPlc['ActVelo']):.1f} u/s at {X.ActPos:.1f}")
    if stop.Done and stop.Busy and plc.cycle % 25 == 0:
        print(f"t={t:.2f} s: stopped at {X.ActPos:.2f}, axis locked: {X.Status.MotionCommandsLocked}")
