"""Example 1: enable axis 1 and move it back and forth between 0 and 100.

    nc-server &                          # the NC (default config: axes 1..4 on tcp/127.0.0.1:7447)
    plc-run examples/01_power_and_move.py

MC_Power enables the axis (and claims it for this PLC); MC_MoveAbsolute starts on a rising
edge of Execute and reports Done once the axis is in its target window (TcMC appendix 7.1).
"""
from plc_client import AXIS_REF, MC_MoveAbsolute, MC_Power

X = AXIS_REF(nc="nc1", axis_id=1)
power = MC_Power()
move = MC_MoveAbsolute()
target = 100.0


def cycle(plc):
    global target
    power(Axis=X, Enable=True, Enable_Positive=True, Enable_Negative=True)
    move(Axis=X, Execute=power.Status, Position=target, Velocity=200.0)
    if move.Done:
        print(f"cycle {plc.cycle}: at {X.ActPos:.3f}")
        target = 0.0 if target else 100.0
        move(Execute=False)  # the next cycle's rising edge starts the next move
    elif move.Error:
        print(f"move failed: ErrorID 0x{move.ErrorID:X}")
        move(Execute=False)
