"""Example 1: enable axis 1 and move it back and forth between 0 and 100.

    nc-server &                          # the NC (default config: axes 1..4 on tcp/127.0.0.1:7447)
    plc-run examples/01_power_and_move.py

MC_Power enables the axis (and claims it for this PLC); MC_MoveAbsolute starts on a rising
edge of Execute and reports Done once the axis is in its target window (TcMC appendix 7.1).

The program is a step sequence (a CASE over ``step`` in ST): each step sets the inputs of the
blocks and moves on when its condition is met. MC_Power.Status is only the condition of step 0,
never the Execute of the move: Status falls while the NC's data is stale (0x4B0F) and rises
again by itself, and that must not start a move. A failed move ends the sequence (step 90).
"""
from plc_client import AXIS_REF, MC_MoveAbsolute, MC_Power

X = AXIS_REF(nc="nc1", axis_id=1)
power = MC_Power()
move = MC_MoveAbsolute()
step = 0  # 0 wait for the enable, 10 move to the target, 90 failed (stays: start the program again)
target = 100.0


def cycle(plc):
    global step, target
    power(Axis=X, Enable=True, Enable_Positive=True, Enable_Negative=True)
    if step == 0:  # wait until the axis is ready
        if power.Status:
            step = 10
    elif step == 10:  # moving: Execute stays TRUE until the move ends
        if move.Done:
            print(f"cycle {plc.cycle}: at {X.ActPos:.3f}")
            target = 0.0 if target else 100.0
            step = 0  # Execute FALSE for a cycle: the next move is a new rising edge
        elif move.Error or move.CommandAborted:
            print(f"move failed: ErrorID 0x{move.ErrorID:X}; the sequence stops here")
            step = 90
    move(Axis=X, Execute=step == 10, Position=target, Velocity=200.0)
