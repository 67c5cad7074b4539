"""Example 10: the demo motion on CiA 402 drives on CANopen (python-canopen over python-can's virtual bus).

    nc-server --config examples/10_canopen_axes.toml &
    plc-run examples/10_canopen_axes.py      # ends by itself after two round trips of every axis (about 6 s)

    # or on another port (any free one; the default is 7447):
    nc-server --config examples/10_canopen_axes.toml --listen tcp/127.0.0.1:7500 &
    plc-run examples/10_canopen_axes.py --nc nc1=tcp/127.0.0.1:7500

The NC configuration examples/10_canopen_axes.toml puts the four axes of the default configuration on
CANopen drives (node ids 2..5, cyclic synchronous position),
simulated in the NC's process (``[drives.canopen] simulate_slaves = true``). For the PLC nothing changes: it
runs the demo's program (plc_client/demo_program.py: MC_Power, then MC_MoveAbsolute back and forth; C three
turns and back). The NC's drive side does the rest: the CiA 402 power state machine through the controlword
(MC_Power's enable -> Operation enabled), the targets as INT32 increments in an RPDO per NC cycle, one SYNC,
the actual values from the drives' TPDOs, their heartbeats watched.

The program prints every finished leg and exits with 0 once each axis has made two round trips without an axis
error and stands at its start position, 1 on an axis error (or after 90 s). A block error that is not the axis's
(0x4B0F: the NC's data were stale for the PLC, on a loaded machine) is printed and the leg is driven again, as the
demo does. Run it on a freshly started nc-server (every
axis at 0).
"""
from plc_client import AXIS_REF
from plc_client.demo_program import FAILED, MOVE, WAIT, Shuttle

LEGS = 4  # per axis: there and back, twice
TIMEOUT = 90.0


class Program:
    def __init__(self):
        self.axes = [AXIS_REF(nc="nc1", axis_id=i, name=n) for i, n in ((1, "X"), (2, "Y"), (3, "Z"), (4, "C"))]
        legs = ((0.0, 400.0, 300.0), (0.0, 250.0, 200.0), (0.0, -150.0, 120.0), (0.0, 1080.0, 540.0))
        self.shuttles = [Shuttle(ax, a, b, v) for ax, (a, b, v) in zip(self.axes, legs)]
        self.legs = [0] * len(self.axes)
        self.noted = [False] * len(self.axes)
        self.t0 = None

    def cycle(self, plc):
        if self.t0 is None:
            self.t0 = plc.now
        for k, (ax, sh) in enumerate(zip(self.axes, self.shuttles)):
            if self.legs[k] >= LEGS:  # done: keep the axis enabled, no new move
                sh.power(Axis=ax, Enable=True, Enable_Positive=True, Enable_Negative=True)
                continue
            was_moving = sh.step == MOVE
            sh.cycle()
            if was_moving and sh.step == WAIT:  # a leg finished (Done)
                self.legs[k] += 1
                print(f"{ax.name}: leg {self.legs[k]} done at {ax.ActPos:9.4f} (ActVelo {ax.ActVelo:.3f})")
            elif sh.step == FAILED and sh.move.Error and not ax.NcToPlc.ErrorCode:
                # not the axis (e.g. 0x4B0F: the NC's data were stale for the PLC on a loaded machine): the
                # demo's Shuttle moves to the same position again
                if not self.noted[k]:
                    print(f"{ax.name}: MC_MoveAbsolute ErrorID 0x{sh.move.ErrorID:X}, moving on")
                self.noted[k] = sh.move.Error
            elif ax.Status.Valid and (ax.Status.ErrorStop or ax.NcToPlc.ErrorCode):
                r = ax.NcToPlc
                print(f"{ax.name}: error 0x{r.ErrorCode:X} (MC_MoveAbsolute ErrorID 0x{sh.move.ErrorID:X}) at leg "
                      f"{self.legs[k] + 1}: SetPos {r.SetPos:.4f} ActPos {r.ActPos:.4f} PosDiff {r.PosDiff:.4f} "
                      f"SetVelo {r.SetVelo:.3f} ActVelo {r.ActVelo:.3f}")
                raise SystemExit(1)
        if all(n >= LEGS for n in self.legs):
            ok = all(abs(ax.ActPos) < 0.05 or abs(ax.ActPos - 360.0) < 0.05 for ax in self.axes)
            print("all axes: " + ", ".join(f"{ax.name} at {ax.ActPos:.4f}" for ax in self.axes))
            print("demo motion on CANopen drives done" if ok else "CHECK FAILED: an axis is not at its start")
            raise SystemExit(0 if ok else 1)
        if plc.now - self.t0 > TIMEOUT:
            print(f"gave up after {TIMEOUT:.0f} s: legs {self.legs}")
            raise SystemExit(1)
