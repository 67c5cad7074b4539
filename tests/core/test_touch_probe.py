"""The touch probe through the NC (MC_TouchProbe / MC_AbortTrigger, TcMC 4.21, 4.22, 6.3; SimProbeSignal).

Cycle-stepped NcCore tests of the probe stage on simulated drives: a sensor pattern on the drive
position (SimProbePeriod 10, SimProbeOffset 2, SimProbeWidth 3: TRUE on [2, 5) + 10 k) passed with
MoveVelocity in both directions, rising and falling edges; the NCJOBS probe slot (ProbeCmdNo,
ProbeState, ProbeCounter, RecordedPosition, RecordedTimeNs), NCTOPLC TouchProbeState (bit 0 armed,
bit 1 valid) and TouchProbeCounter, StateDWord.ExternalLatchValid and StateDWord3 bit 0 (the
input's level); WindowOnly windows (absolute, modulo, wrapping), ModuloPositions; MC_AbortTrigger,
a replacing MC_TouchProbe, MC_Reset (0x4B0C); commanded mid-cycle signals (SimProbeSignal) on an
axis without a pattern; the refusals 0x4251, 0x4B06 and 0x4B0B.

Velocities of 100 u/s (0.1 u per 1 ms cycle: at most one pattern edge per cycle); the drive keeps
its default lag (SimTimeConstant 1 ms): the latch interpolates the actual positions.
"""
from __future__ import annotations

import pytest

from nc_schema import CmdState, ErrorCodes as E, StateDWord
from znc_testing import step_until
from znc_testing.nc_core import cmd, power, powered, snapshot

CT = 0.001
DT_NS = 1_000_000
ACTIVE, DONE, ABORTED, ERROR = (int(CmdState.ACTIVE), int(CmdState.DONE), int(CmdState.ABORTED),
                                int(CmdState.ERROR))
PATTERN = dict(SimProbePeriod=10.0, SimProbeOffset=2.0, SimProbeWidth=3.0)
LATCH_VALID = int(StateDWord.ExternalLatchValid)
ARMED, VALID = 1, 2


# -- helpers ------------------------------------------------------------------------------------------
def probe(core, i=0):
    j = core.ncjobs[i]
    return (int(j["ProbeCmdNo"]), int(j["ProbeState"]), int(j["ProbeCounter"]), float(j["RecordedPosition"]),
            int(j["RecordedTimeNs"]))


def tp_state(core, i=0):
    return int(core.nctoplc[i]["TouchProbeState"])


def dword(core, i=0):
    return int(core.nctoplc[i]["StateDWord"])


def level_at(x):
    return ((x - 2.0) % 10.0) < 3.0


class Cycles:
    """Per cycle: (previous ActPos, ActPos, previous NC time, NC time, StateDWord3)."""

    def __init__(self, core, i=0):
        self.core, self.i, self.rows = core, i, []

    def step(self):
        c = self.core
        a, t0 = float(c.nctoplc[self.i]["ActPos"]), c.nc_time_ns
        c.step()
        self.rows.append((a, float(c.nctoplc[self.i]["ActPos"]), t0, c.nc_time_ns,
                          int(c.nctoplc[self.i]["StateDWord3"])))

    def until_state_not(self, st, max_cycles=5000):
        step_until(self.step, lambda: probe(self.core, self.i)[1] != st, max_cycles, f"a probe state other than {st}")

    def run(self, n):
        for _ in range(n):
            self.step()


def moving(v, start=0.0, **params):
    """An axis with the sensor pattern at ``start``, then MoveVelocity ``v``. The pattern lies on the
    drive position: a ``start`` on the period (10) is set with SetActualPosition (NC = drive + start,
    the edges at the same NC positions), any other is driven to (MoveAbsolute)."""
    core = powered(1, **{**PATTERN, **params})
    if start and start % 10.0 == 0.0:
        assert cmd(core, "SetActualPosition", Position=start)["error"] == 0
        core.step()
    elif start:
        assert cmd(core, "MoveAbsolute", Position=start, Velocity=100.0)["error"] == 0
        while int(core.nctoplc[0]["CmdState"]) == ACTIVE or abs(float(core.nctoplc[0]["ActPos"]) - start) > 1e-9:
            core.step()
    assert cmd(core, "MoveVelocity", Velocity=abs(v), Direction=1 if v > 0 else 3)["error"] == 0
    return core


def check_event(cyc, x):
    """The event at ``x`` lies within the last cycle's travel and RecordedTimeNs is the interpolated
    instant of the latch: previous cycle's time + (x - a) / (b - a) x cycle."""
    a, b, t0, t1, _ = cyc.rows[-1]
    assert min(a, b) <= x <= max(a, b)
    rec_ns = probe(cyc.core, cyc.i)[4]
    assert t0 <= rec_ns <= t1
    assert rec_ns == pytest.approx(t0 + (x - a) / (b - a) * DT_NS, abs=1.0)


# -- pattern edges through the NC ------------------------------------------------------------------------
@pytest.mark.parametrize("v,start,edge,x", [
    (100.0, 0.0, 0, 2.0),     # positive: [2, 5) entered at 2
    (100.0, 0.0, 1, 5.0),     # ... left at 5
    (-100.0, 30.0, 0, 25.0),  # negative: [22, 25) entered from above at 25
    (-100.0, 30.0, 1, 22.0),  # ... left at 22
    (100.0, 3.0, 0, 12.0),    # starting inside a window: the next rising edge
])
def test_pattern_edge_is_recorded_exactly(v, start, edge, x):
    core = moving(v, start)
    r = cmd(core, "TouchProbe", Edge=edge)
    assert r["error"] == 0 and r["CmdNo"] > 0
    assert probe(core)[:3] == (r["CmdNo"], ACTIVE, 0)  # at once
    cyc = Cycles(core)
    cyc.step()
    assert tp_state(core) == ARMED and not dword(core) & LATCH_VALID
    cyc.until_state_not(ACTIVE)
    no, st, cnt, pos, _ = probe(core)
    assert (no, st, cnt) == (r["CmdNo"], DONE, 1)
    assert pos == pytest.approx(x, abs=1e-9)
    check_event(cyc, x)
    assert int(core.nctoplc[0]["TouchProbeCounter"]) == 1
    assert tp_state(core) == VALID and dword(core) & LATCH_VALID
    # the input's level follows the actual position every cycle (StateDWord3 bit 0)
    for a, b, _, _, s3 in cyc.rows:
        assert bool(s3 & 1) == level_at(b)
    # the recorded event stays; no further latches; the axis moves on
    cyc.run(300)
    assert probe(core)[1:4] == (DONE, 1, pos)
    assert tp_state(core) == VALID and dword(core) & LATCH_VALID
    assert any(s3 & 1 for *_, s3 in cyc.rows) and any(not s3 & 1 for *_, s3 in cyc.rows)


def test_counter_counts_each_recorded_position():
    core = moving(100.0)
    cyc = Cycles(core)
    positions = []
    for k in range(1, 4):
        r = cmd(core, "TouchProbe")
        core.step()
        assert tp_state(core) == ARMED and not dword(core) & LATCH_VALID  # the new cycle: not valid
        cyc.until_state_not(ACTIVE)
        no, st, cnt, pos, ns = probe(core)
        assert (no, st, cnt) == (r["CmdNo"], DONE, k)
        assert int(core.nctoplc[0]["TouchProbeCounter"]) == k
        positions.append(pos)
        check_event(cyc, pos)
    assert positions == pytest.approx([2.0, 12.0, 22.0], abs=1e-9)


# -- windows -----------------------------------------------------------------------------------------
@pytest.mark.parametrize("first,last,want", [
    (20.0, 30.0, 22.0),   # 2 and 12 are rejected
    (12.0, 12.0, 12.0),   # boundaries included
    (25.0, 60.0, 32.0),
])
def test_absolute_window_rejects_edges_outside_and_stays_armed(first, last, want):
    core = moving(100.0)
    cmd(core, "TouchProbe", WindowOnly=True, FirstPosition=first, LastPosition=last)
    cyc = Cycles(core)
    seen = 0
    while probe(core)[1] == ACTIVE:
        cyc.step()
        b = cyc.rows[-1][1]
        if probe(core)[1] == ACTIVE:
            assert tp_state(core) == ARMED and probe(core)[2] == 0  # rejected: still armed, not counted
            seen += level_at(b) and not level_at(cyc.rows[-1][0])
    assert seen == round((want - 2.0) / 10.0)  # the rejected rising edges
    assert probe(core)[1:4] == (DONE, 1, pytest.approx(want, abs=1e-9))
    check_event(cyc, want)


@pytest.mark.parametrize("armed", [False, True])
def test_absolute_window_first_above_last_is_refused(armed):
    """Absolute positions: FirstPosition > LastPosition would be an empty window (TcMC shows wrapping
    windows for modulo positions only): refused 0x4B06, nothing changes (an armed latch stays armed)."""
    core = moving(100.0)
    if armed:
        cmd(core, "TouchProbe", Edge=1)
        core.step()
    snap = snapshot(core)
    r = cmd(core, "TouchProbe", WindowOnly=True, FirstPosition=30.0, LastPosition=20.0)
    assert r["error"] == int(E.MC_PARAMETER_NOT_CORRECT), r
    assert snapshot(core) == snap
    # the same numbers as modulo positions wrap and are accepted
    assert cmd(core, "TouchProbe", WindowOnly=True, FirstPosition=30.0, LastPosition=20.0,
               ModuloPositions=True)["error"] == 0


MOD = dict(Modulo=True, AxisEncoderModuloValue=100.0)


@pytest.mark.parametrize("first,last,edge,want", [
    (40.0, 50.0, 0, 42.0),   # 252 .. 332 rejected (52 .. 32 mod 100), 342 -> 42
    (95.0, 5.0, 0, 2.0),     # wraps through 0: 252 .. 292 rejected, 302 -> 2
    (95.0, 5.0, 1, 95.0),    # falling: 255 .. 285 rejected, 295 -> 95 (boundary)
    (0.0, 100.0, 0, 52.0),   # the whole cycle
])
def test_modulo_window_and_modulo_recorded_position(first, last, edge, want):
    core = moving(100.0, 250.0, **MOD)
    cmd(core, "TouchProbe", Edge=edge, WindowOnly=True, FirstPosition=first, LastPosition=last, ModuloPositions=True)
    cyc = Cycles(core)
    cyc.until_state_not(ACTIVE)
    assert probe(core)[1:3] == (DONE, 1)
    assert probe(core)[3] == pytest.approx(want, abs=1e-9)
    turns = (cyc.rows[-1][1] // 100.0) * 100.0
    x = want + turns if want + turns >= cyc.rows[-1][0] - 1e-9 else want + turns + 100.0
    check_event(cyc, x)


def test_modulo_positions_without_window_records_the_modulo_position():
    core = moving(-100.0, 250.0, **MOD)
    cmd(core, "TouchProbe", ModuloPositions=True, Edge=1)  # negative: leaves [242, 245) at 242
    cyc = Cycles(core)
    cyc.until_state_not(ACTIVE)
    assert probe(core)[3] == pytest.approx(42.0, abs=1e-9)
    check_event(cyc, 242.0)
    # an absolute one on the same axis records the absolute position
    cmd(core, "TouchProbe", Edge=1)
    cyc.until_state_not(ACTIVE)
    assert probe(core)[3] == pytest.approx(232.0, abs=1e-9)


# -- abort, replace, reset ---------------------------------------------------------------------------
def test_abort_trigger_disarms():
    core = moving(100.0)
    r = cmd(core, "TouchProbe", Edge=1)
    core.step()
    assert cmd(core, "AbortTrigger")["error"] == 0
    assert probe(core)[:3] == (r["CmdNo"], ABORTED, 0)  # at once
    for _ in range(200):  # edges at 5, 15: not recorded
        core.step()
    assert probe(core)[1:3] == (ABORTED, 0) and tp_state(core) == 0 and not dword(core) & LATCH_VALID
    assert int(core.nctoplc[0]["TouchProbeCounter"]) == 0
    # after a recorded position MC_AbortTrigger clears ExternalLatchValid (the slot keeps DONE)
    cmd(core, "TouchProbe")
    while probe(core)[1] == ACTIVE:
        core.step()
    assert dword(core) & LATCH_VALID
    assert cmd(core, "AbortTrigger")["error"] == 0
    core.step()
    assert probe(core)[1:3] == (DONE, 1) and tp_state(core) == 0 and not dword(core) & LATCH_VALID
    # none armed: changes nothing
    snap = snapshot(core)
    assert cmd(core, "AbortTrigger")["error"] == 0
    assert snapshot(core) == snap


def test_second_touch_probe_replaces_the_first():
    core = moving(100.0)
    first = cmd(core, "TouchProbe", Edge=0, WindowOnly=True, FirstPosition=50.0, LastPosition=60.0)
    for _ in range(5):
        core.step()
    second = cmd(core, "TouchProbe", Edge=1)
    assert second["error"] == 0 and second["CmdNo"] != first["CmdNo"]
    assert probe(core)[:2] == (second["CmdNo"], ACTIVE)  # the slot shows the new one (the first: ABORTED)
    while probe(core)[1] == ACTIVE:
        core.step()
    assert probe(core)[1:4] == (DONE, 1, pytest.approx(5.0, abs=1e-9))  # its edge and no window


def test_reset_while_armed_ends_it_with_latch_disabled():
    core = powered(1, **PATTERN)
    r = cmd(core, "TouchProbe")
    core.step()
    assert cmd(core, "Reset")["error"] == 0
    core.step()
    assert probe(core)[:2] == (r["CmdNo"], ERROR)
    assert int(core.probe.error[0]) == int(E.MC_LATCH_DISABLED)  # (0x4B0C: no ErrorId field on the wire)
    assert tp_state(core) == 0
    # disarmed: a move over the pattern records nothing
    cmd(core, "MoveVelocity", Velocity=100.0)
    for _ in range(100):
        core.step()
    assert probe(core)[1:3] == (ERROR, 0)


def test_disable_leaves_the_latch_armed_and_reset_ends_it_with_0x4b0c():
    """The documented choice (structs.json ProbeState): Enable FALSE does not disarm the latch (a probe
    can record an axis moved with its controller off); MC_Reset does, ERROR 0x4B0C in ProbeErrorId."""
    core = powered(1, **PATTERN)
    cmd(core, "TouchProbe")
    core.step()
    power(core, ctrl=0)
    core.step()
    assert probe(core)[1] == ACTIVE and tp_state(core) & 1
    cmd(core, "Reset")
    core.step()
    assert probe(core)[1] == ERROR and int(core.ncjobs[0]["ProbeErrorId"]) == 0x4B0C and not tp_state(core) & 1


def test_newest_cmd_no_shows_the_probe_number():
    core = powered(1, **PATTERN)
    r = cmd(core, "TouchProbe")
    core.step()
    assert int(core.ncjobs[0]["NewestCmdNo"]) == r["CmdNo"] == probe(core)[0]


# -- commanded signals (SimProbeSignal) -------------------------------------------------------------------
@pytest.mark.parametrize("offset", [0.0, 0.0004, 0.000999])
def test_sim_probe_signal_mid_cycle_records_the_interpolated_position(offset):
    core = powered(1)  # no pattern
    assert cmd(core, "MoveVelocity", Velocity=100.0)["error"] == 0
    for _ in range(300):
        core.step()
    r = cmd(core, "TouchProbe")
    core.step()
    assert int(core.nctoplc[0]["StateDWord3"]) & 1 == 0
    assert cmd(core, "SimProbeSignal", Level=True, Offset=offset)["error"] == 0
    cyc = Cycles(core)
    cyc.step()
    a, b, t0, t1, s3 = cyc.rows[-1]
    assert s3 & 1
    no, st, cnt, pos, ns = probe(core)
    assert (no, st, cnt) == (r["CmdNo"], DONE, 1)
    assert pos == pytest.approx(a + offset / CT * (b - a), abs=1e-9)
    assert ns == pytest.approx(t0 + offset * 1e9, abs=1.0)
    # a falling edge for a falling-edge cycle; the level stays low afterwards
    cmd(core, "TouchProbe", Edge=1)
    cyc.step()
    assert probe(core)[1] == ACTIVE and cyc.rows[-1][4] & 1  # the level stays high: no edge
    cmd(core, "SimProbeSignal", Level=False, Offset=0.0005)
    cyc.step()
    a, b, t0, *_ = cyc.rows[-1]
    assert probe(core)[1:4] == (DONE, 2, pytest.approx(0.5 * (a + b), abs=1e-9))
    assert not cyc.rows[-1][4] & 1
    cyc.step()
    assert not cyc.rows[-1][4] & 1


def test_sim_probe_signal_of_the_wrong_kind_is_no_event():
    core = powered(1)
    cmd(core, "TouchProbe", Edge=1)  # falling
    cmd(core, "SimProbeSignal", Level=True, Offset=0.0002)  # rising
    core.step()
    assert probe(core)[1] == ACTIVE
    # a pulse within one cycle: its falling edge counts
    cmd(core, "SimProbeSignal", Level=False, Offset=0.0003)
    core.step()
    assert probe(core)[1] == DONE


def test_sim_probe_signal_refusals():
    core = powered(2, **PATTERN)
    snap = snapshot(core)
    assert cmd(core, "SimProbeSignal", Level=True, Offset=0.0)["error"] == int(E.NC_FUNCTION_NOT_SUPPORTED)
    assert snapshot(core) == snap
    plain = powered(1)
    for off in (-1e-6, CT, 0.5):
        assert cmd(plain, "SimProbeSignal", Level=True, Offset=off)["error"] == int(E.MC_PARAMETER_NOT_CORRECT)
    cmd(plain, "TouchProbe")
    plain.step()
    assert probe(plain)[1] == ACTIVE and not int(plain.nctoplc[0]["StateDWord3"]) & 1


@pytest.mark.parametrize("args", [
    dict(EncoderID=0), dict(EncoderID=256), dict(TouchProbe=2), dict(TouchProbe=4), dict(TouchProbe=10),
    dict(TouchProbe=0), dict(Edge=5), dict(Edge=-1), dict(Edge=2),
])
@pytest.mark.parametrize("armed", [False, True])
def test_invalid_trigger_input_is_refused_and_changes_nothing(args, armed):
    core = moving(100.0)
    if armed:
        cmd(core, "TouchProbe", Edge=1)
        core.step()
    snap = snapshot(core)
    r = cmd(core, "TouchProbe", **args)
    assert r["error"] == int(E.MC_TRIGGER_INPUT_INVALID), r
    assert snapshot(core) == snap


def test_several_axes_latch_independently():
    """Three axes armed at once (rising, falling, a window), at different velocities and directions:
    each records its own edge in its own cycle."""
    core = powered(3, **PATTERN)
    for axis, v in ((1, 100.0), (2, 70.0), (3, -100.0)):
        assert cmd(core, "MoveVelocity", axis=axis, Velocity=abs(v), Direction=1 if v > 0 else 3)["error"] == 0
    cmd(core, "TouchProbe", axis=1, Edge=0)
    cmd(core, "TouchProbe", axis=2, Edge=1)
    cmd(core, "TouchProbe", axis=3, Edge=0, WindowOnly=True, FirstPosition=-30.0, LastPosition=-10.0)
    for _ in range(600):
        core.step()
    want = [2.0, 5.0, -15.0]  # axis 3 negative: [-18, -15) entered at -15; -5 outside the window
    for i, x in enumerate(want):
        assert probe(core, i)[1:4] == (DONE, 1, pytest.approx(x, abs=1e-9))
    assert tp_state(core, 0) == tp_state(core, 1) == tp_state(core, 2) == VALID
