"""Example 5: watch axes without controlling them (no MC_Power, no claim, no block at all).

    plc-run examples/05_status_monitor.py --client-id monitor
    plc-run examples/05_status_monitor.py --client-id monitor --arg axes=1,3 --arg every=10

Any number of PLCs may read an axis; only the one that claimed it (with MC_Power) drives it.
The AXIS_REFs a program declares are bound when plc-run loads it, so their data (``NcToPlc``,
``Status``) is refreshed every cycle and ``Status.Valid`` is TRUE once the NC's data arrives,
without a block being called with them. ``NcToPlc`` members are plain Python values (TwinCAT's
names: ``ax.NcToPlc.SetPos``, ``.ActVelo``, ``.PosDiff``, ``.ErrorCode``, ...).

Arguments (``--arg NAME=VALUE``, typed like the defaults of ``program_args``): ``axes``, the AxisIds
to watch (comma-separated), ``every``, print every so many PLC cycles, ``nc``, the NC's name.
"""
from plc_client import AXIS_REF, program_args

args = program_args(axes="1,2,3,4", every=50, nc="nc1")
axes = [AXIS_REF(nc=args.nc, axis_id=int(i)) for i in args.axes.split(",")]


def cycle(plc):
    if plc.cycle % args.every:
        return
    print("  ".join(f"{ax.axis_id}: {ax.NcToPlc.ActPos:9.3f} {ax.NcToPlc.SetVelo:8.2f} u/s "
                    f"{ax.Status.MotionState.name[13:]:<18}" if ax.Status.Valid else f"{ax.axis_id}: no data"
                    for ax in axes), flush=True)
