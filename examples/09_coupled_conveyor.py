"""Example 9: a conveyor with two geared slaves, a registration correction and a product sensor.

    nc-server --config examples/09_coupled_conveyor.toml &
    plc-run examples/09_coupled_conveyor.py      # ends by itself after about 4 s

    # or on another port (any free one; the default is 7447):
    nc-server --config examples/09_coupled_conveyor.toml --listen tcp/127.0.0.1:7500 &
    plc-run examples/09_coupled_conveyor.py --nc nc1=tcp/127.0.0.1:7500

The NC configuration examples/09_coupled_conveyor.toml has three axes: the master Conveyor
(axis 1) with a simulated product sensor on its touch probe input 1 (SimProbePeriod 150,
SimProbeOffset 100, SimProbeWidth 40: a product 40 mm long every 150 mm, leading edges at 100,
250, 400, ... mm), the PrintRoller (axis 2) and the FeedBelt (axis 3). The steps:

1. couple at standstill: the PrintRoller with MC_GearIn at the fixed ratio 1:2
   (RatioNumerator 1, RatioDenominator 2), the FeedBelt with MC_GearInDyn at GearRatio 1.0;
2. arm MC_TouchProbe on the Conveyor (TouchProbe1, rising edge, WindowOnly 200..300: the first
   product's edge at 100 is rejected, the second one's at 250 is recorded - by the drive's latch,
   exact, not in the PLC cycle), then run the Conveyor with MC_MoveVelocity at 200 mm/s;
3. once the Conveyor passed 150 mm, raise the FeedBelt's GearRatio to 1.5: MC_GearInDyn writes it
   into PlcToNc.GearRatio1 every cycle, the NC ramps the ratio (Acceleration 1000 mm/s^2 at the
   master's AxisVeloMax, i.e. 2 per second);
4. the registration: the roller's phase was set for an edge at 230 mm, the edge passed at 250 mm,
   so the PrintRoller's phase is corrected by (250 - 230) x 1/2 = 10 mm (the sign of such a
   correction depends on the machine). MC_MoveSuperImposedExt adds those 10 mm on top of
   the coupling (SUPERPOSITIONMODE_VELOREDUCTION_ADDITIVEMOTION with VelocityProcess 100 mm/s, the
   roller's geared velocity, and Length 100 mm: the correction is spread over exactly 1 s, while
   the roller's basic motion travels 100 mm and the conveyor 200 mm; VelocityDiff at most 50 mm/s);
5. MC_GearOutExt with MC_DECOUPLEMODE_NEWPOS decouples the FeedBelt and brings it, at the
   velocity it has, to the next position a multiple of 100 mm at least 150 mm ahead;
6. MC_Halt stops the Conveyor (the PrintRoller stops with it, still geared), MC_GearOut then
   decouples the standing PrintRoller.

The program prints what happened - the ratios the NC applies (NCJOBS.GearRatio) and the
velocity ratios seen in the set-points, the recorded position, the distance the superposition
added (the PrintRoller's SetPos minus 1/2 of the Conveyor's), where the FeedBelt stopped - and
exits with 0 when every check passed, 1 on any block error or failed check. Run it on a freshly
started nc-server (every axis at 0).
"""
import math

from plc_client import (
    AXIS_REF, E_DecoupleMode, E_SuperpositionMode, MC_GearIn, MC_GearInDyn, MC_GearOut, MC_GearOutExt, MC_Halt,
    MC_InputRef, MC_MoveSuperImposedExt, MC_MoveVelocity, MC_Power, MC_TouchProbe,
)

CONVEYOR = AXIS_REF(nc="nc1", axis_id=1, name="Conveyor")
ROLLER = AXIS_REF(nc="nc1", axis_id=2, name="PrintRoller")
FEED = AXIS_REF(nc="nc1", axis_id=3, name="FeedBelt")
AXES = (CONVEYOR, ROLLER, FEED)

CONVEYOR_VELO = 200.0  # mm/s
ROLLER_RATIO = (1, 2)  # MC_GearIn RatioNumerator, RatioDenominator
FEED_RATIOS = (1.0, 1.5)  # MC_GearInDyn GearRatio before and after the change
RATIO_CHANGE_AT = 150.0  # Conveyor position [mm]
PROBE_WINDOW = (200.0, 300.0)  # WindowOnly: the second product's leading edge
EXPECTED_EDGE = 250.0  # SimProbeOffset + 1 * SimProbePeriod
NOMINAL_EDGE = 230.0  # where the PrintRoller's phase expects the edge
SUPER_LENGTH = 100.0  # mm of the roller's basic travel (at VelocityProcess) over which the correction is spread


def set_pos(ax):
    return ax.NcToPlc.SetPos


def set_velo(ax):
    return ax.NcToPlc.SetVelo


class Program:
    def __init__(self):
        self.power = [MC_Power() for _ in AXES]
        self.conveyor_move, self.conveyor_halt = MC_MoveVelocity(), MC_Halt()
        self.gear_in, self.gear_dyn = MC_GearIn(), MC_GearInDyn()
        self.trigger = MC_InputRef()  # TouchProbe1, RisingEdge (the defaults)
        self.probe = MC_TouchProbe()
        self.correction = MC_MoveSuperImposedExt()
        self.feed_out, self.roller_out = MC_GearOutExt(), MC_GearOut()
        self.ex = dict.fromkeys(("move", "halt", "gear_in", "gear_dyn", "probe", "correction", "feed_out",
                                 "roller_out"), False)
        self.feed_ratio = FEED_RATIOS[0]
        self.distance = 0.0
        self.feed_target = 0.0
        self.failed = []
        self.plc = None
        self.steps = self.sequence()

    def cycle(self, plc):
        self.plc = plc
        ex = self.ex
        for fb, ax in zip(self.power, AXES):
            fb(Axis=ax, Enable=True, Enable_Positive=True, Enable_Negative=True)
        self.conveyor_move(Axis=CONVEYOR, Execute=ex["move"], Velocity=CONVEYOR_VELO)
        self.conveyor_halt(Axis=CONVEYOR, Execute=ex["halt"])
        self.gear_in(Master=CONVEYOR, Slave=ROLLER, Execute=ex["gear_in"], RatioNumerator=ROLLER_RATIO[0],
                     RatioDenominator=ROLLER_RATIO[1])
        self.gear_dyn(Master=CONVEYOR, Slave=FEED, Execute=ex["gear_dyn"], GearRatio=self.feed_ratio,
                      Acceleration=1000.0)
        self.probe(Axis=CONVEYOR, TriggerInput=self.trigger, Execute=ex["probe"], WindowOnly=True,
                   FirstPosition=PROBE_WINDOW[0], LastPosition=PROBE_WINDOW[1])
        self.correction(Axis=ROLLER, Execute=ex["correction"],
                        Mode=E_SuperpositionMode.SUPERPOSITIONMODE_VELOREDUCTION_ADDITIVEMOTION,
                        Distance=self.distance, VelocityDiff=50.0, Length=SUPER_LENGTH,
                        VelocityProcess=CONVEYOR_VELO * ROLLER_RATIO[0] / ROLLER_RATIO[1])
        self.feed_out(Slave=FEED, Execute=ex["feed_out"], Mode=E_DecoupleMode.MC_DECOUPLEMODE_NEWPOS,
                      Position=self.feed_target)
        self.roller_out(Slave=ROLLER, Execute=ex["roller_out"])
        self.watch_blocks()
        next(self.steps)

    # -- helpers ------------------------------------------------------------------------------
    def watch_blocks(self):
        """Any block error (or an unexpected abort) ends the program with exit code 1."""
        blocks = {"MC_Power " + ax.name: fb for fb, ax in zip(self.power, AXES)}
        blocks.update(MC_MoveVelocity=self.conveyor_move, MC_Halt=self.conveyor_halt, MC_GearIn=self.gear_in,
                      MC_GearInDyn=self.gear_dyn, MC_TouchProbe=self.probe, MC_MoveSuperImposedExt=self.correction,
                      MC_GearOutExt=self.feed_out, MC_GearOut=self.roller_out)
        for name, fb in blocks.items():
            if fb.Error or getattr(fb, "CommandAborted", False):
                print(f"{name}: Error={fb.Error} ErrorID=0x{fb.ErrorID:X} "
                      f"CommandAborted={getattr(fb, 'CommandAborted', False)}")
                raise SystemExit(1)

    def wait(self, cond, what, timeout=20.0):
        t0 = self.plc.now
        while not cond():
            if self.plc.now - t0 > timeout:
                print(f"gave up waiting for {what}")
                raise SystemExit(1)
            yield

    def check(self, ok, what):
        if not ok:
            print(f"CHECK FAILED: {what}")
            self.failed.append(what)

    def ratios(self):
        """(applied ratio of the FeedBelt's coupling, both slaves' set velocity / the Conveyor's)."""
        v = set_velo(CONVEYOR)
        return (float(FEED.NcJobs["GearRatio"]), set_velo(ROLLER) / v if v else math.nan,
                set_velo(FEED) / v if v else math.nan)

    # -- the sequence -----------------------------------------------------------------------------
    def sequence(self):
        yield from self.wait(lambda: all(p.Status for p in self.power), "the enables")
        if any(abs(ax.ActPos) > 0.05 for ax in AXES):
            print("the axes are not at 0: run it on a freshly started nc-server")
            raise SystemExit(1)

        # 1. couple both slaves to the standing conveyor
        self.ex["gear_in"] = self.ex["gear_dyn"] = True
        yield
        yield from self.wait(lambda: self.gear_in.InGear and self.gear_dyn.InGear, "InGear")
        print(f"coupled: {ROLLER.name} MC_GearIn {ROLLER_RATIO[0]}:{ROLLER_RATIO[1]} "
              f"(NC ratio {float(ROLLER.NcJobs['GearRatio']):.3f}, CoupleState {ROLLER.NcToPlc.CoupleState}), "
              f"{FEED.name} MC_GearInDyn (NC ratio {float(FEED.NcJobs['GearRatio']):.3f}), "
              f"{CONVEYOR.name} CoupleState {CONVEYOR.NcToPlc.CoupleState}")

        # 2. arm the product sensor, then start the conveyor
        self.ex["probe"] = True
        yield
        yield from self.wait(lambda: CONVEYOR.NcToPlc.TouchProbeState & 1, "the armed latch")
        self.ex["move"] = True
        yield
        yield from self.wait(lambda: self.conveyor_move.InVelocity, "the conveyor's velocity")
        self.ex["move"] = False
        _, v_roller, v_feed = self.ratios()
        print(f"{CONVEYOR.name} at {set_velo(CONVEYOR):.1f} mm/s: velocity ratios {ROLLER.name} {v_roller:.3f}, "
              f"{FEED.name} {v_feed:.3f}")
        self.check(math.isclose(v_roller, 0.5, abs_tol=1e-6), f"{ROLLER.name} moves at 1/2 of the conveyor")
        self.check(math.isclose(v_feed, FEED_RATIOS[0], abs_tol=1e-6), f"{FEED.name} moves at ratio 1.0")

        # 3. change the FeedBelt's ratio on the fly
        yield from self.wait(lambda: set_pos(CONVEYOR) >= RATIO_CHANGE_AT, "the conveyor at 150 mm")
        self.feed_ratio = FEED_RATIOS[1]
        t0 = self.plc.now
        yield from self.wait(lambda: math.isclose(self.ratios()[0], FEED_RATIOS[1], abs_tol=1e-9), "the new ratio")
        print(f"{FEED.name}: GearRatio {FEED_RATIOS[0]} -> {FEED_RATIOS[1]} at {CONVEYOR.name} "
              f"{RATIO_CHANGE_AT:.0f} mm, reached in {self.plc.now - t0:.2f} s")
        for _ in range(5):
            yield
        r_feed, v_roller, v_feed = self.ratios()
        print(f"velocity ratios now: {ROLLER.name} {v_roller:.3f}, {FEED.name} {v_feed:.3f} (NC ratio {r_feed:.3f})")
        self.check(math.isclose(v_feed, FEED_RATIOS[1], abs_tol=1e-6), f"{FEED.name} moves at ratio 1.5")
        self.check(math.isclose(v_roller, 0.5, abs_tol=1e-6), f"{ROLLER.name} still at 1/2")

        # the product edge
        yield from self.wait(lambda: not self.probe.Busy, "the product edge")
        recorded = self.probe.RecordedPosition
        self.ex["probe"] = False
        print(f"product edge recorded at {recorded:.3f} mm (window {PROBE_WINDOW[0]:.0f}..{PROBE_WINDOW[1]:.0f}; "
              f"TouchProbeCounter {CONVEYOR.NcToPlc.TouchProbeCounter})")
        self.check(math.isclose(recorded, EXPECTED_EDGE, abs_tol=1e-3), f"the edge at {EXPECTED_EDGE} mm")

        # 4. the registration correction on the PrintRoller
        ratio = ROLLER_RATIO[0] / ROLLER_RATIO[1]
        self.distance = ratio * (recorded - NOMINAL_EDGE)
        phase_before = set_pos(ROLLER) - ratio * set_pos(CONVEYOR)
        conveyor_before = set_pos(CONVEYOR)
        self.ex["correction"] = True
        yield
        yield from self.wait(lambda: not self.correction.Busy, "the correction")
        self.ex["correction"] = False
        added = set_pos(ROLLER) - ratio * set_pos(CONVEYOR) - phase_before
        c = self.correction
        print(f"superposition on {ROLLER.name}: Distance {self.distance:.3f}, added {added:.3f} mm "
              f"(ActualDistance {c.ActualDistance:.3f}, ActualVelocityDiff {c.ActualVelocityDiff:.3f}, "
              f"ActualLength {c.ActualLength:.3f}) while the {CONVEYOR.name} travelled "
              f"{set_pos(CONVEYOR) - conveyor_before:.0f} mm")
        self.check(math.isclose(added, self.distance, abs_tol=1e-3), "the superposition added Distance")
        self.check(math.isclose(set_velo(ROLLER) / set_velo(CONVEYOR), 0.5, abs_tol=1e-6),
                   f"{ROLLER.name} back at 1/2 after the correction")

        # 5. decouple the FeedBelt to a new position
        self.ex["gear_dyn"] = False  # MC_GearInDyn ends; the coupling stays at ratio 1.5
        yield
        self.feed_target = math.ceil((set_pos(FEED) + 150.0) / 100.0) * 100.0
        print(f"{FEED.name} at {set_pos(FEED):.1f} ({set_velo(FEED):.1f} mm/s): MC_GearOutExt NEWPOS "
              f"{self.feed_target:.0f}")
        self.ex["feed_out"] = True
        yield
        yield from self.wait(lambda: not self.feed_out.Busy, "MC_GearOutExt")
        self.ex["feed_out"] = False
        print(f"{FEED.name} decoupled, stopped at {FEED.ActPos:.3f} (target {self.feed_target:.0f}, "
              f"InTargetPosition {FEED.Status.InTargetPosition}, CoupleState {FEED.NcToPlc.CoupleState})")
        self.check(math.isclose(FEED.ActPos, self.feed_target, abs_tol=0.02), f"{FEED.name} at its target")
        self.check(FEED.NcToPlc.CoupleState == 0, f"{FEED.name} decoupled")

        # 6. stop the conveyor (the roller follows), then decouple the standing roller
        self.ex["halt"] = True
        yield
        yield from self.wait(lambda: not self.conveyor_halt.Busy, "MC_Halt")
        self.ex["halt"] = False
        self.ex["roller_out"] = True
        yield
        yield from self.wait(lambda: not self.roller_out.Busy, "MC_GearOut")
        self.ex["roller_out"] = False
        self.ex["gear_in"] = False
        yield
        print(f"stopped: {CONVEYOR.name} at {CONVEYOR.ActPos:.3f}, {ROLLER.name} at {ROLLER.ActPos:.3f} "
              f"(decoupled: CoupleState {ROLLER.NcToPlc.CoupleState}, MC_GearIn Busy {self.gear_in.Busy}), "
              f"{FEED.name} at {FEED.ActPos:.3f}")
        self.check(all(ax.Status.NotMoving for ax in AXES), "everything stands")
        self.check(ROLLER.NcToPlc.CoupleState == 0 and not self.gear_in.Busy, f"{ROLLER.name} decoupled")
        self.check(math.isclose(ROLLER.ActPos, ratio * CONVEYOR.ActPos + self.distance, abs_tol=0.02),
                   f"{ROLLER.name} = 1/2 {CONVEYOR.name} + the correction")
        if self.failed:
            print(f"{len(self.failed)} check(s) failed")
            raise SystemExit(1)
        print("all checks passed")
        raise SystemExit(0)
