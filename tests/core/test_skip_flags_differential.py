"""The cycle's shortcuts against the plain computation, byte for byte (review of the issue-19 tail work).

Core A steps with the monitoring flags (``AxisTable.lag_clear``, ``windows_clear``, ``mon_clear``, ``end_watch``)
as the cycle keeps them; core B gets them forced to "unknown" before every step (the code before the flags). Both
get the same random commands (moves of the engine fuzz, parameter writes of the monitoring windows and limits,
stalls, resets, gearing, superposition, touch probe, stepper terminal errors, enables and override), and after
every cycle their NCTOPLC and NCJOBS must be the same bytes. Beside them two frame rings (1-4 slots, every
wrap-around): one given the change counts, one copying everything, must hold the same bytes.
"""
from __future__ import annotations

import random
from typing import Any

import pytest

from nc_schema import ControlDWord
from nc_schema import MC_AxisPara as P
from nc_server.core import AxisConfig, AxisParams, NcCore
from nc_server.server.frame_ring import FrameRing, ring_bytes
from test_engine_fuzz import random_command  # noqa: E402 (tests/core on sys.path)
from znc_testing.nc_core import ALL_ENABLES, cmd, power

WRITES = [("AxisMaxPosLagValue", [0.01, 0.5, 5.0]), ("AxisEnPositionLagMonitoring", [True, False]),
          ("AxisTargetPositionWindow", [0.001, 0.02, 5.0]), ("AxisTargetPositionMonitoringTime", [0.0, 0.02, 0.5]),
          ("AxisEnTargetPositionMonitoring", [True, False]), ("AxisEnInTargetTimeout", [True, False]),
          ("AxisInTargetTimeout", [0.01, 1.0]), ("AxisEnPositionRangeMonitoring", [True, False]),
          ("AxisEnMaxSoftPosLimit", [True, False]), ("AxisMaxSoftPosLimit", [10.0, 150.0])]


def make(variant: int) -> NcCore:
    if variant:
        q: dict[str, Any] = dict(AxisEnPositionLagMonitoring=False, AxisEnInTargetTimeout=True, AxisInTargetTimeout=0.01,
                                 AxisTargetPositionWindow=0.0001, AxisTargetPositionMonitoringTime=0.05)
        ps = [AxisParams(**q), AxisParams(**q), AxisParams(SimStepper=True, **q), AxisParams(**q)]
    else:
        ps = [AxisParams(AxisMaxPosLagValue=0.5, AxisMaxPosLagFilterTime=0.01), AxisParams(),
              AxisParams(SimStepper=True),
              AxisParams(AxisEnMaxSoftPosLimit=True, AxisMaxSoftPosLimit=150.0, AxisEnMinSoftPosLimit=True,
                         AxisMinSoftPosLimit=-150.0, AxisEnInTargetTimeout=True, AxisInTargetTimeout=0.05,
                         AxisEnPositionRangeMonitoring=True)]
    c = NcCore([AxisConfig(i + 1, f"A{i + 1}", p) for i, p in enumerate(ps)], 0.001)
    for i in range(4):
        power(c, i)
    c.step()
    return c


def forget(c: NcCore) -> None:
    a = c.axes
    a.lag_clear = a.windows_clear = a.mon_clear = False
    a.end_watch = True


SEEN_ERRORS: set[int] = set()
SEEDS = range(6)


@pytest.mark.parametrize("seed", SEEDS)
def test_flags_and_ring_counts_change_no_byte(seed: int) -> None:
    rng = random.Random(seed)
    a, b = make(seed % 2), make(seed % 2)
    n, slots = 4, 1 + seed % 4
    counted = FrameRing(bytearray(ring_bytes(n, slots)), n, slots, create=True)
    plain = FrameRing(bytearray(ring_bytes(n, slots)), n, slots, create=True)
    for it in range(100):
        ax = rng.randrange(1, n + 1)
        k = rng.randrange(14)
        req: tuple[str, dict[str, Any]] | None
        if k == 0:
            name, v = rng.choice(WRITES)
            req = ("WriteParameter", dict(ParameterNumber=int(P[name]), Value=rng.choice(v)))
        elif k == 1:
            req = ("SimStall", dict(Stall=rng.random() < 0.5))
        elif k == 2:
            req = ("Reset", {})
        elif k == 3:
            req = ("GearIn", dict(Master=1, RatioNumerator=1, RatioDenominator=rng.choice([1, 2])))
        elif k == 4:
            req = ("GearOut", {})
        elif k == 5:
            req = ("MoveSuperImposed", dict(Distance=5.0, VelocityDiff=50.0, VelocityProcess=100.0, Length=50.0))
        elif k == 6:
            req = ("TouchProbe", {})
        elif k == 7:
            req = ("SimProbeSignal", dict(Level=rng.random() < 0.5))
        elif k == 8:
            req = ("SimTerminalError", dict(StatusWord=rng.choice([0, 0, 0x10])))
        elif k == 9:
            ctrl = rng.choice([ALL_ENABLES, ALL_ENABLES & ~int(ControlDWord.FeedEnablePlus), int(ControlDWord.Enable), 0])
            ov = rng.choice([0, 500_000, 1_000_000])
            req = None
            for c in (a, b):
                power(c, ax - 1, ctrl, ov)
        else:
            req = random_command(rng, a)
            if req[0] == "override":
                for c in (a, b):
                    power(c, ax - 1, ALL_ENABLES, req[1]["value"])
                req = None
        if req:
            ra, rb = cmd(a, req[0], ax, **req[1]), cmd(b, req[0], ax, **req[1])
            assert ra["error"] == rb["error"], (req, ra, rb)
        for _ in range(rng.choice([1, 2, 3, 5, 20, 80, 300])):
            a.step()
            forget(b)
            b.step()
            assert a.nctoplc.tobytes() == b.nctoplc.tobytes(), (seed, it, "NCTOPLC differs")
            assert a.ncjobs.tobytes() == b.ncjobs.tobytes(), (seed, it, "NCJOBS differs")
            counted.write(a.cycle, 0, a.nctoplc, 0, a.ncjobs, a.plctonc, (a.records.version, a.plctonc_version))
            plain.write(a.cycle, 0, a.nctoplc, 0, a.ncjobs, a.plctonc)
            assert bytes(counted.mv) == bytes(plain.mv), (seed, it, "ring slots differ")
            SEEN_ERRORS.update(int(x) for x in a.nctoplc["ErrorCode"] if x)


def test_the_seeds_reached_the_monitoring_faults() -> None:
    """(runs after the seeds: the random commands must have faulted axes, or the monitoring paths went untried)"""
    if not SEEN_ERRORS:
        for seed in SEEDS:
            test_flags_and_ring_counts_change_no_byte(seed)
    assert SEEN_ERRORS & {0x4550, 0x435C}, f"no lag or in-target-timeout fault seen: {sorted(map(hex, SEEN_ERRORS))}"
