"""Example 5: watch axes without controlling them (no MC_Power, no claim).

    plc-run examples/05_status_monitor.py --client-id monitor

Any number of PLCs may read an axis; only the one that claimed it (with MC_Power) drives it.
"""
from plc_client import AXIS_REF, MC_ReadActualPosition, MC_ReadStatus

axes = [AXIS_REF(nc="nc1", axis_id=i) for i in (1, 2, 3, 4)]
positions = [MC_ReadActualPosition() for _ in axes]
states = [MC_ReadStatus() for _ in axes]


def cycle(plc):
    for ax, pos, st in zip(axes, positions, states):
        pos(Axis=ax, Enable=True)
        st(Axis=ax, Enable=True)
    if plc.cycle % 50 == 0:
        print("  ".join(f"{ax.axis_id}: {p.Position:9.3f} {s.Status.MotionState.name[13:]:<18}" if p.Valid
                        else f"{ax.axis_id}: no data (0x{p.ErrorID:X})" for ax, p, s in zip(axes, positions, states)))
