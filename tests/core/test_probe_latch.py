"""Touch probe building blocks: the SimDrive's probe input and latch (sensor pattern and commanded
signals, both directions, rising and falling, the first edge of a cycle only, exact positions), the
DriveABC defaults, and the pure window / trigger checks of nc_server.core.probe (MC_TouchProbe)."""
import math

import numpy as np
import pytest

from nc_schema import ErrorCodes, NcError
from nc_server.core import AxisParams, ConfigError
from nc_server.core.probe import check_trigger_input, in_window, modulo_position
from nc_server.drives.base import DriveABC
from nc_server.drives.sim import SimDrive

CT = 0.001
PATTERN = dict(SimProbePeriod=10.0, SimProbeOffset=2.0, SimProbeWidth=3.0)  # TRUE on [2, 5) + 10 k


def make_drive(n: int = 1, cycle_time: float = CT, **params) -> SimDrive:
    """Drives without lag (SimTimeConstant 0): each step reaches its set position exactly."""
    return SimDrive([AxisParams(SimTimeConstant=0.0, **params) for _ in range(n)], cycle_time)


def move(d: SimDrive, pos, enabled: bool = True) -> np.ndarray:
    """One cycle to ``pos`` (scalar or per axis); returns the actual positions before it."""
    prev = d.act_pos.copy()
    n = len(prev)
    d.step(np.full(n, enabled), np.broadcast_to(np.asarray(pos, dtype=float), (n,)).copy(), np.zeros(n), np.zeros(n))
    return prev


def latch(d: SimDrive, prev: np.ndarray, falling, rows=None):
    rows = np.arange(len(prev)) if rows is None else np.asarray(rows, dtype=np.intp)
    return d.latch_probe(rows, np.broadcast_to(np.asarray(falling, dtype=bool), (len(rows),)).copy(), prev[rows])


def at(d: SimDrive, pos: float) -> None:
    """Put the drive at ``pos`` (one step there, its edges discarded)."""
    move(d, pos)


# -- the sensor pattern -----------------------------------------------------------------------------
@pytest.mark.parametrize("pos,level", [
    (1.99, False), (2.0, True), (4.999, True), (5.0, False), (12.0, True), (-8.0, True), (-5.5, True), (-5.0, False),
    (-6.1, True), (-8.0001, False),
])
def test_pattern_level_follows_the_actual_position(pos, level):
    d = make_drive(**PATTERN)
    at(d, pos)
    assert d.probe_input()[0] == level


def test_pattern_width_zero_is_never_and_width_of_a_period_always_true():
    d = SimDrive([AxisParams(SimTimeConstant=0.0, SimProbePeriod=10.0, SimProbeWidth=0.0),
                  AxisParams(SimTimeConstant=0.0, SimProbePeriod=10.0, SimProbeWidth=10.0),
                  AxisParams(SimTimeConstant=0.0, SimProbePeriod=10.0, SimProbeWidth=25.0),
                  AxisParams(SimTimeConstant=0.0)], CT)
    for p in (0.0, -1e-20, 3.0, 9.999999, -123.4):  # (-1e-20 mod 10 rounds to 10 itself)
        at(d, p)
        assert d.probe_input().tolist() == [False, True, True, False]
    prev = move(d, 55.0)  # a fixed level has no edges
    for falling in (False, True):
        assert not latch(d, prev, falling)[0].any()


@pytest.mark.parametrize("a,b,falling,x", [
    (0.0, 20.0, False, 2.0),     # positive: the window [2, 5) is entered at its start
    (0.0, 20.0, True, 5.0),      # ... and left at its end
    (20.0, 0.0, False, 15.0),    # negative: [12, 15) is entered from above, at 15
    (20.0, 0.0, True, 12.0),     # ... and left at 12
    (3.0, 20.0, False, 12.0),    # starting inside a window: the next rising edge
    (3.0, 20.0, True, 5.0),
    (3.0, -20.0, False, -5.0),   # negative from inside [2, 5): leaves at 2, enters [-8, -5) at -5
    (3.0, -20.0, True, 2.0),
    (-31.0, -26.5, False, -28.0),  # negative positions, positive travel
    (-26.5, -31.0, True, -28.0),
])
def test_pattern_edge_is_latched_exactly_with_its_fraction(a, b, falling, x):
    d = make_drive(**PATTERN)
    at(d, a)
    prev = move(d, b)
    found, pos, frac = latch(d, prev, falling)
    assert found[0] and pos[0] == pytest.approx(x, abs=1e-12)
    assert frac[0] == pytest.approx((x - a) / (b - a), abs=1e-12)  # linear motion from a to b within the cycle
    assert 0.0 <= frac[0] <= 1.0


@pytest.mark.parametrize("a,b,falling", [
    (0.0, 1.9, False), (0.0, 4.9, True), (2.5, 4.9, False), (2.5, 4.9, True), (6.0, 11.9, False),
    (20.0, 15.1, False), (14.0, 12.1, True), (11.0, 5.1, False), (11.0, 5.1, True),
])
def test_no_pattern_edge_no_latch(a, b, falling):
    d = make_drive(**PATTERN)
    at(d, a)
    found, pos, frac = latch(d, move(d, b), falling)
    assert not found[0] and math.isnan(pos[0]) and math.isnan(frac[0])


@pytest.mark.parametrize("a,b,falling,x", [
    (0.0, 100.0, False, 2.0), (0.0, 100.0, True, 5.0), (100.0, 0.0, False, 95.0), (100.0, 0.0, True, 92.0),
])
def test_only_the_first_edge_of_a_cycle_counts(a, b, falling, x):
    d = make_drive(**PATTERN)  # ten windows passed in one cycle
    at(d, a)
    found, pos, _ = latch(d, move(d, b), falling)
    assert found[0] and pos[0] == pytest.approx(x)


def test_an_edge_reached_at_the_end_of_a_cycle_counts_once():
    d = make_drive(**PATTERN)
    at(d, 0.0)
    found, pos, frac = latch(d, move(d, 2.0), False)  # positive: reaching 2 enters the window
    assert found[0] and pos[0] == 2.0 and frac[0] == 1.0 and d.probe_input()[0]
    assert not latch(d, move(d, 4.0), False)[0][0]  # not again from 2
    at(d, 20.0)
    assert not latch(d, move(d, 15.0), False)[0][0] and not d.probe_input()[0]  # 15 itself is outside
    found, pos, frac = latch(d, move(d, 14.0), False)  # negative: the edge at the very start
    assert found[0] and pos[0] == 15.0 and frac[0] == 0.0 and d.probe_input()[0]


@pytest.mark.parametrize("offset,a,b,falling", [
    (1.3, 11.2, 12.0, False),                # (11.2 - 1.3) / 3.3 rounds below 3: the edge at 11.2 is behind
    (0.3, 119.09999999999998, 118.0, True),  # the edge at 119.1 = 0.3 + 36 * 3.3 is one ulp above a
])
def test_rounding_never_latches_an_edge_behind_the_start(offset, a, b, falling):
    d = make_drive(SimProbePeriod=3.3, SimProbeOffset=offset, SimProbeWidth=1.0)
    at(d, a)
    found, pos, _ = latch(d, move(d, b), falling)
    assert not found[0] and math.isnan(pos[0])


def test_pattern_latch_against_a_sampled_reference():
    """Random patterns and moves: the latched edge is the first sampled level change of its kind."""
    rng = np.random.default_rng(7)
    for _ in range(300):
        period = float(rng.uniform(0.5, 10.0))
        width = float(rng.uniform(0.05, 0.95)) * period
        offset = float(rng.uniform(-20.0, 20.0))
        a, b = (float(v) for v in rng.uniform(-50.0, 50.0, 2))
        falling = bool(rng.integers(2))
        d = make_drive(SimProbePeriod=period, SimProbeOffset=offset, SimProbeWidth=width)
        at(d, a)
        found, pos, frac = latch(d, move(d, b), falling)
        s = np.linspace(a, b, 200_001)
        level = np.mod(s - offset, period) < width
        change = np.flatnonzero(level[1:] != level[:-1])
        want = change[level[change + 1] != falling]
        assert found[0] == bool(len(want)), (a, b, period, width, offset, falling)
        if len(want):
            step = abs(b - a) / 200_000
            assert abs(pos[0] - s[want[0] + 1]) <= step * 1.000001 + 1e-9
            assert frac[0] == pytest.approx((pos[0] - a) / (b - a), abs=1e-12)
            phase = np.mod(pos[0] - offset, period)  # the latched position is a window boundary
            assert min(phase, period - phase, abs(phase - width)) < 1e-9


def test_no_movement_no_latch_and_unarmed_rows_are_not_evaluated():
    d = make_drive(3, **PATTERN)
    at(d, 3.0)
    found, pos, frac = latch(d, move(d, 3.0), [False, True, False])  # standing inside a window
    assert not found.any() and np.isnan(pos).all() and np.isnan(frac).all()
    prev = move(d, [20.0, 20.0, 3.0])
    found, pos, frac = latch(d, prev, [True], rows=[1])  # only the armed row is answered
    assert found.tolist() == [True] and pos.tolist() == [5.0] and len(frac) == 1
    empty = latch(d, prev, [], rows=[])
    assert [len(v) for v in empty] == [0, 0, 0]


def test_rows_are_vectorized_with_their_own_edges_and_parameters():
    d = SimDrive([AxisParams(SimTimeConstant=0.0, **PATTERN),
                  AxisParams(SimTimeConstant=0.0, SimProbePeriod=4.0, SimProbeOffset=-1.0, SimProbeWidth=1.0),
                  AxisParams(SimTimeConstant=0.0),
                  AxisParams(SimTimeConstant=0.0, **PATTERN)], CT)
    at(d, [0.0, 0.0, 0.0, 30.0])
    prev = move(d, [10.0, -10.0, 10.0, 20.0])
    found, pos, frac = d.latch_probe(np.array([3, 0, 1, 2]), np.array([False, True, True, False]), prev[[3, 0, 1, 2]])
    # axis 3 negative from 30: enters [22, 25) at 25; axis 0 leaves [2, 5) at 5; axis 1 windows [-1, 0) + 4 k,
    # negative from 0: leaves [-1, 0) at -1; axis 2 has no sensor
    assert found.tolist() == [True, True, True, False]
    assert pos[:3].tolist() == [25.0, 5.0, -1.0] and frac[:3] == pytest.approx([0.5, 0.5, 0.1])


# -- commanded signals (axes without a pattern) --------------------------------------------------------
def test_probe_signal_mid_cycle_latches_the_interpolated_position():
    d = make_drive()
    at(d, 0.0)
    d.set_probe_signal(0, True, 0.25 * CT)
    assert not d.probe_input()[0]  # it takes effect in the next stepped cycle
    prev = move(d, 10.0)
    assert d.probe_input()[0]
    assert not latch(d, prev, True)[0][0]
    found, pos, frac = latch(d, prev, False)
    assert found[0] and frac[0] == pytest.approx(0.25) and pos[0] == pytest.approx(2.5)
    d.set_probe_signal(0, False, 0.5 * CT)
    prev = move(d, 0.0)  # negative
    found, pos, frac = latch(d, prev, True)
    assert found[0] and frac[0] == pytest.approx(0.5) and pos[0] == pytest.approx(5.0) and not d.probe_input()[0]
    prev = move(d, 7.0)  # no new event: the edges were of the last cycle only
    assert not latch(d, prev, True)[0][0] and not latch(d, prev, False)[0][0]


def test_probe_signals_of_one_cycle_first_edge_and_no_edge_for_the_same_level():
    d = make_drive()
    at(d, 0.0)
    d.set_probe_signal(0, False, 0.1 * CT)  # already FALSE: no edge
    d.set_probe_signal(0, True, 0.8 * CT)   # (the calls need not be in time order)
    d.set_probe_signal(0, False, 0.6 * CT)
    d.set_probe_signal(0, True, 0.2 * CT)
    prev = move(d, 10.0)
    found, pos, frac = latch(d, prev, False)
    assert found[0] and frac[0] == pytest.approx(0.2) and pos[0] == pytest.approx(2.0)  # the first rising edge
    found, pos, frac = latch(d, prev, True)
    assert found[0] and frac[0] == pytest.approx(0.6) and pos[0] == pytest.approx(6.0)
    assert d.probe_input()[0]  # the last level persists
    d.set_probe_signal(0, True, 0.0)  # TRUE again: no edge
    assert not latch(d, move(d, 20.0), False)[0][0] and d.probe_input()[0]


def test_probe_signal_same_offset_last_call_wins_and_offset_zero_is_the_start():
    d = make_drive()
    at(d, 4.0)
    d.set_probe_signal(0, True, 0.0)
    d.set_probe_signal(0, False, 0.0)  # replaces the first: no zero-width pulse
    prev = move(d, 8.0)
    assert not latch(d, prev, False)[0][0] and not latch(d, prev, True)[0][0] and not d.probe_input()[0]
    d.set_probe_signal(0, True, 0.0)
    found, pos, frac = latch(d, move(d, 12.0), False)
    assert found[0] and frac[0] == 0.0 and pos[0] == 8.0


def test_probe_signal_at_standstill_and_on_a_disabled_drive():
    d = make_drive(2)
    at(d, [5.0, -3.0])
    d.set_probe_signal(1, True, 0.9 * CT)
    prev = move(d, [50.0, 50.0], enabled=False)  # disabled: holds its position, the input still switches
    found, pos, frac = latch(d, prev, False)
    assert found.tolist() == [False, True] and pos[1] == -3.0 and frac[1] == pytest.approx(0.9)
    assert d.probe_input().tolist() == [False, True]


@pytest.mark.parametrize("offset", [-1e-12, CT, 2 * CT, math.nan, math.inf])
def test_probe_signal_offset_out_of_range_is_a_value_error(offset):
    d = make_drive()
    with pytest.raises(ValueError):
        d.set_probe_signal(0, True, offset)
    assert not latch(d, move(d, 1.0), False)[0][0]  # nothing was queued


def test_probe_signal_refused_on_a_pattern_axis_and_for_no_axis():
    d = make_drive(**PATTERN)
    with pytest.raises(NotImplementedError):
        d.set_probe_signal(0, True, 0.0)
    for index in (-1, 1):
        with pytest.raises(IndexError):
            d.set_probe_signal(index, True, 0.0)


def test_configure_picks_up_the_probe_parameters():
    p = AxisParams(SimTimeConstant=0.0)
    d = SimDrive([p], CT)
    d.set_probe_signal(0, True, 0.0)
    at(d, 3.0)
    assert d.probe_input()[0]  # commanded
    d.configure(0, AxisParams(SimTimeConstant=0.0, SimProbePeriod=10.0, SimProbeOffset=2.0, SimProbeWidth=1.0))
    assert not d.probe_input()[0]  # the pattern decides now: 3 is outside [2, 3)
    found, pos, _ = latch(d, move(d, 12.5), False)
    assert found[0] and pos[0] == 12.0
    d.configure(0, p)  # no sensor again: the commanded level starts FALSE
    assert not d.probe_input()[0]
    d.set_probe_signal(0, True, 0.0)


def test_probe_parameters_are_validated_axis_parameters():
    p = AxisParams.from_mapping({"SimProbePeriod": 360, "SimProbeOffset": -12.5, "SimProbeWidth": 0.5})
    assert (p.SimProbePeriod, p.SimProbeOffset, p.SimProbeWidth) == (360.0, -12.5, 0.5)
    assert AxisParams().SimProbePeriod == 0.0 and AxisParams().SimProbeWidth == 0.0
    assert AxisParams.kind("SimProbeOffset") == "real"
    for key, value in (("SimProbePeriod", -1.0), ("SimProbeWidth", -0.1), ("SimProbeOffset", math.inf),
                       ("SimProbePeriod", True)):
        with pytest.raises(ConfigError, match=f"axis.{key}"):
            AxisParams.from_mapping({key: value})


def test_drive_abc_defaults_have_no_latch_hardware():
    class Bare(DriveABC):
        def configure(self, index, params):
            pass

        def step(self, enabled, set_pos, set_velo, set_acc):
            self.act_pos = set_pos.copy()

    d = Bare([AxisParams(), AxisParams()], CT)
    d.step(np.ones(2, bool), np.array([10.0, -10.0]), np.zeros(2), np.zeros(2))
    assert d.probe_input().tolist() == [False, False]
    found, pos, frac = d.latch_probe(np.array([0, 1]), np.array([False, True]), np.zeros(2))
    assert not found.any() and np.isnan(pos).all() and np.isnan(frac).all()
    with pytest.raises(NotImplementedError, match="no simulated probe input"):
        d.set_probe_signal(0, True, 0.0)


# -- the window (WindowOnly) -----------------------------------------------------------------------
@pytest.mark.parametrize("pos,first,last,inside", [
    (5.0, 0.0, 10.0, True), (0.0, 0.0, 10.0, True), (10.0, 0.0, 10.0, True),
    (-1e-9, 0.0, 10.0, False), (10.000001, 0.0, 10.0, False),
    (-5.0, -10.0, -2.0, True), (365.0, 0.0, 10.0, False),  # absolute: no repetition
    (3.0, 3.0, 3.0, True),
    (5.0, 10.0, 0.0, False), (15.0, 10.0, 0.0, False), (-5.0, 10.0, 0.0, False),  # first > last: empty
    (math.nan, -math.inf, math.inf, False),
])
def test_absolute_window(pos, first, last, inside):
    assert in_window(pos, first, last, False, 360.0) is inside


@pytest.mark.parametrize("pos,first,last,inside", [
    (370.0, 0.0, 20.0, True), (-350.0, 0.0, 20.0, True), (-340.0, 0.0, 20.0, True), (-339.0, 0.0, 20.0, False),
    (720.0 + 20.0, 0.0, 20.0, True), (360.0, 0.0, 20.0, True), (359.5, 0.0, 20.0, False),
    # first > last: the window wraps through 0 (TcMC figure B)
    (-10.0, 350.0, 10.0, True), (5.0, 350.0, 10.0, True), (355.0, 350.0, 10.0, True), (180.0, 350.0, 10.0, False),
    (350.0, 350.0, 10.0, True), (10.0, 350.0, 10.0, True), (349.99, 350.0, 10.0, False), (10.01, 350.0, 10.0, False),
    (-1e-20, 350.0, 10.0, True), (-1e-20, 0.0, 5.0, True), (-1e-20, 1.0, 5.0, False),
    (-725.0, 350.0, 10.0, True), (math.nan, 350.0, 10.0, False),
])
def test_modulo_window(pos, first, last, inside):
    assert in_window(pos, first, last, True, 360.0) is inside


def test_modulo_position_and_bad_period():
    assert modulo_position(-10.0, 360.0) == 350.0 and modulo_position(-1e-20, 360.0) == 0.0
    assert modulo_position(725.5, 360.0) == pytest.approx(5.5)
    for period in (0.0, -360.0, math.nan, math.inf):
        with pytest.raises(ValueError):
            in_window(1.0, 0.0, 10.0, True, period)
    assert in_window(1.0, 0.0, 10.0, False, 0.0)  # absolute: the period does not matter


# -- the trigger input (MC_InputRef) -----------------------------------------------------------------------
@pytest.mark.parametrize("encoder_id,touch_probe,edge", [
    (1, 1, 0), (255, 1, 1), (np.uint32(7), np.int64(1), np.int8(1)),  # (decoded records give numpy integers)
])
def test_valid_trigger_input(encoder_id, touch_probe, edge):
    check_trigger_input(encoder_id, touch_probe, edge)


@pytest.mark.parametrize("encoder_id,touch_probe,edge,field", [
    (0, 1, 0, "EncoderID"), (256, 1, 0, "EncoderID"), (-1, 1, 0, "EncoderID"), (True, 1, 0, "EncoderID"),
    (1.0, 1, 0, "EncoderID"),
    (1, 2, 0, "TouchProbe"), (1, 3, 0, "TouchProbe"), (1, 4, 0, "TouchProbe"), (1, 0, 0, "TouchProbe"),
    (1, 10, 0, "PlcEvent"), (1, True, 0, "TouchProbe"),
    (1, 1, 2, "Edge"), (1, 1, -1, "Edge"), (1, 1, True, "Edge"), (1, 1, 0.0, "Edge"),
])
def test_invalid_trigger_input_is_0x4b0b(encoder_id, touch_probe, edge, field):
    with pytest.raises(NcError) as exc:
        check_trigger_input(encoder_id, touch_probe, edge)
    assert exc.value.code == 0x4B0B == ErrorCodes.MC_TRIGGER_INPUT_INVALID
    assert field in exc.value.detail
