"""Example 7: the modulo application example of TcMC section 3.5, on the rotary axis C (axis 4).

    nc-server &
    plc-run examples/07_modulo_application.py    # ends by itself after about 6 s

A rotary axis works in cycles: each one starts at 90 deg and turns by a full 360 deg in positive
direction (reverse motion is not allowed mechanically). The step sequence:

1. basic positioning: MC_MoveModulo to 90 deg in positive direction (no motion if already there);
2. the working cycles: MC_MoveModulo to **450** deg, MC_Positive_Direction - a full turn back to
   modulo 90 (a target of 90 would not move at all);
3. after a fault, MC_Reset and back to step 1. Here an MC_Reset is simply injected after the
   second cycle: a reset sets the set position to the actual position, which may lie a little
   above or below 90 deg. The modulo tolerance window (AxisModuloToleranceWindow, written to
   1.5 deg at the start) makes the next modulo start behave as from exactly 90 deg.

The last cycle is run with the older AXACT block instead (MODE 517: modulo start in positive
direction, TARGPOS 450), followed as its manual describes: BUSY falls when the NC accepted,
the motion is complete when HasJob falls again.
"""
from plc_client import AXACT, AXIS_REF, MC_Direction, MC_MoveModulo, MC_Power, MC_Reset

C = AXIS_REF(nc="nc1", axis_id=4, name="C")
CYCLES = 4


class Program:
    def __init__(self):
        self.power, self.move, self.reset = MC_Power(), MC_MoveModulo(), MC_Reset()
        self.axact = AXACT(nc="nc1")
        self.ex_move = self.ex_reset = self.start = False
        self.target = 90.0
        self.plc = None
        self.steps = self.sequence()

    def cycle(self, plc):
        self.plc = plc
        self.power(Axis=C, Enable=True, Enable_Positive=True, Enable_Negative=True)
        self.move(Axis=C, Execute=self.ex_move, Position=self.target, Velocity=360.0,
                  Direction=MC_Direction.MC_Positive_Direction)
        self.reset(Axis=C, Execute=self.ex_reset)
        self.axact(AXID=4, START=self.start, MODE=517, TARGPOS=450.0, VELOCITY=360.0, TMOUT=1.0)
        next(self.steps)

    def wait(self, cond, what, timeout=20.0):
        t0 = self.plc.now
        while not cond():
            if self.plc.now - t0 > timeout:
                print(f"gave up waiting for {what}")
                raise SystemExit(1)
            yield

    def modulo_move(self, target, what):
        self.target, self.ex_move = target, True
        yield
        yield from self.wait(lambda: not self.move.Busy, what)
        if not self.move.Done:
            print(f"{what} failed: ErrorID 0x{self.move.ErrorID:X}")
            raise SystemExit(1)
        print(f"{what}: ActPos {C.ActPos:8.3f}, modulo {C.NcToPlc.ModuloActPos:7.3f}, "
              f"turns {C.NcToPlc.ModuloActTurns}")
        self.ex_move = False
        yield

    def sequence(self):
        yield from self.wait(lambda: self.power.Status, "the enable")
        # the System Manager setting of the example: modulo tolerance window 1.5 deg
        wp = self.plc.send(C, "WriteParameter", ParameterNumber=1045, Value=1.5)
        yield from self.wait(lambda: wp.done, "WriteParameter")
        if wp.error:
            print(f"AxisModuloToleranceWindow not written: 0x{wp.error:X}")
        n = 0
        while n < CYCLES - 1:
            yield from self.modulo_move(90.0, "basic positioning to 90")
            while n < CYCLES - 1:
                n += 1
                yield from self.modulo_move(450.0, f"cycle {n}: 450 positive")
                if n == 2:  # the "fault": reset, then the step sequence starts again
                    self.ex_reset = True
                    yield
                    yield from self.wait(lambda: not self.reset.Busy, "MC_Reset")
                    self.ex_reset = False
                    print(f"MC_Reset: set position now {C.NcToPlc.SetPos:.4f}")
                    yield
                    break
        # the last cycle with AXACT: MODE 517 (modulo, positive direction), TARGPOS 450
        self.start = True
        yield
        yield from self.wait(lambda: not self.axact.BUSY, "AXACT")
        if self.axact.ERR:
            print(f"AXACT failed: ERRID 0x{self.axact.ERRID:X}")
            raise SystemExit(1)
        self.start = False
        yield from self.wait(lambda: C.Status.HasJob, "the job")  # accepted: the job is there
        yield from self.wait(lambda: not C.Status.HasJob and C.Status.InTargetPosition, "the end of the turn")
        print(f"cycle {CYCLES} (AXACT 517/450): ActPos {C.ActPos:8.3f}, modulo "
              f"{C.NcToPlc.ModuloActPos:7.3f}, turns {C.NcToPlc.ModuloActTurns}")
        raise SystemExit(0)
