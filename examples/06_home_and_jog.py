"""Example 6: home two axes (with and without a reference cam), then jog one of them.

    nc-server &
    plc-run examples/06_home_and_jog.py          # ends by itself after about 5 s

MC_Home runs the NC's homing sequence; the program supplies the reference cam through
bCalibrationCam (it reaches the NC in the PLCTONC ControlDWord, so the axis must be powered by
this PLC). X has a real cam - simulated here from the position, occupied below -3.5 mm; the
default parameters search it in negative direction. Y has none: the TcMC recipe sets the cam
TRUE at the start and FALSE once HomingState >= 4, so the axis homes on the encoder's next sync
pulse. Then MC_Jog moves X: three inching steps of 5 mm (one key press each) and a continuous
jog backwards at the slow manual velocity while the key is held (the block stops the axis when
the key is released).
"""
from plc_client import AXIS_REF, MC_Home, MC_Jog, MC_Power
from nc_schema import E_JogMode

X = AXIS_REF(nc="nc1", axis_id=1, name="X")
Y = AXIS_REF(nc="nc1", axis_id=2, name="Y")
CAM_AT = -3.5  # X's reference cam: occupied below this position [mm]


class Program:
    def __init__(self):
        self.px, self.py = MC_Power(), MC_Power()
        self.hx, self.hy = MC_Home(), MC_Home()
        self.jog = MC_Jog()
        self.home = False
        self.fwd = self.bwd = False
        self.mode = E_JogMode.MC_JOGMODE_INCHING
        self.plc = None
        self.steps = self.sequence()

    def cycle(self, plc):
        self.plc = plc
        self.px(Axis=X, Enable=True, Enable_Positive=True, Enable_Negative=True)
        self.py(Axis=Y, Enable=True, Enable_Positive=True, Enable_Negative=True)
        # X: the cam as a real sensor would report it
        self.hx(Axis=X, Execute=self.home, bCalibrationCam=X.ActPos < CAM_AT)
        # Y: no cam - simulate one: TRUE first, FALSE once HomingState >= 4 (TcMC 3.14)
        cam_y = Y.NcToPlc.HomingState < 4 if self.hy.Busy else True
        self.hy(Axis=Y, Execute=self.home, bCalibrationCam=cam_y)
        self.jog(Axis=X, JogForward=self.fwd, JogBackwards=self.bwd, Mode=self.mode, Position=5.0, Velocity=50.0)
        next(self.steps)

    def wait(self, cond, what, timeout=20.0):
        t0 = self.plc.now
        while not cond():
            if self.plc.now - t0 > timeout:
                print(f"gave up waiting for {what}")
                raise SystemExit(1)
            yield

    def sequence(self):
        yield from self.wait(lambda: self.px.Status and self.py.Status, "the enables")
        print(f"enabled; X at {X.ActPos:.3f}, Y at {Y.ActPos:.3f}, homed: {X.Status.Homed} {Y.Status.Homed}")
        self.home = True
        yield  # the blocks see the new inputs in the next cycle
        yield from self.wait(lambda: not (self.hx.Busy or self.hy.Busy), "homing")
        for ax, fb in ((X, self.hx), (Y, self.hy)):
            if not fb.Done:
                print(f"{ax.name}: homing failed, ErrorID 0x{fb.ErrorID:X}")
                raise SystemExit(1)
            print(f"{ax.name}: homed={ax.Status.Homed}, HomingState {ax.NcToPlc.HomingState}, "
                  f"stands at {ax.ActPos:.4f} (reference 0 + braking distance)")
        self.home = False
        for n in range(3):  # three presses of the forward key: 5 mm each
            self.fwd = True
            yield
            yield from self.wait(lambda: self.jog.Done or self.jog.Error, "an inching step")
            print(f"inching step {n + 1}: X at {X.ActPos:.3f}" if self.jog.Done
                  else f"inching failed: 0x{self.jog.ErrorID:X}")
            self.fwd = False
            yield
        self.mode = E_JogMode.MC_JOGMODE_STANDARD_SLOW
        self.bwd = True  # hold the backward key for 0.3 s
        yield
        yield from self.wait(lambda: self.jog.Active, "the jog")
        t0 = self.plc.now
        yield from self.wait(lambda: self.plc.now - t0 >= 0.3, "0.3 s")
        print(f"jogging backwards at {X.NcToPlc.ActVelo:.1f} mm/s, X at {X.ActPos:.3f}")
        self.bwd = False  # release: MC_Jog sends a Halt and is Done at standstill
        yield
        yield from self.wait(lambda: not self.jog.Busy, "the stop")
        print(f"released: {'Done' if self.jog.Done else 'ErrorID 0x%X' % self.jog.ErrorID}, "
              f"X stands at {X.ActPos:.3f}, state {X.Status.MotionState.name}")
        raise SystemExit(0)  # the program ends: plc-run shuts down cleanly (enables off, claims released)
