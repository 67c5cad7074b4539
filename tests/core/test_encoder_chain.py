"""The simulated encoder chain (nc_server/drives/encoder.py): ActPos = +-(increments & mask) * scaling + offset,
its four parameters written only while the controller is disabled, the mask 2^k - 1, and the NC's hook for a
position that moved without motion."""
from __future__ import annotations

import pytest

from nc_schema import ErrorCodes as E
from nc_server.core import AxisConfig, AxisParams, NcCore
from znc_testing.nc_core import ALL_ENABLES, cmd, make_core, power, run_until, snapshot

SCALING, OFFSET, INVERSE, MASK = 1040, 1041, 1042, 1043


def approx(x: float) -> object:
    return pytest.approx(x, abs=1e-8)  # (_move_to settles within 1e-9 of its target)


def _act(core, i: int = 0) -> float:
    return float(core.nctoplc[i]["ActPos"])


def _write(core, number: int, value) -> dict:
    return cmd(core, "WriteParameter", ParameterNumber=number, Value=value)


def _move_to(core, pos: float) -> None:
    """Enable, move to ``pos`` and settle, disable again."""
    power(core, 0, ctrl=ALL_ENABLES)
    core.step()
    assert cmd(core, "MoveAbsolute", Position=pos, Velocity=500.0)["error"] == 0
    run_until(core, lambda: abs(_act(core) - pos) < 1e-9 and not core.axes.has_job[0])
    power(core, 0, ctrl=0)
    core.step()


def test_offset_shifts_act_pos_without_motion_and_the_axis_moves_on_from_there():
    core = make_core()
    core.step()
    assert _write(core, OFFSET, 10.0)["error"] == 0
    core.step()
    r = core.nctoplc[0]
    assert _act(core) == 10.0 and float(r["SetPos"]) == 10.0 and float(r["ActVelo"]) == 0.0
    assert float(r["PosDiff"]) == 0.0
    _move_to(core, 50.0)
    assert core.drive.encoder_count(0) == approx(40.0)  # 40 increments moved


def test_scaling_rescales_the_same_increments():
    core = make_core()
    _move_to(core, 100.0)
    assert _write(core, SCALING, 0.5)["error"] == 0
    core.step()
    assert _act(core) == approx(50.0) and float(core.nctoplc[0]["SetPos"]) == _act(core)
    _move_to(core, 60.0)  # 10 u at 0.5 u/inc: 20 increments
    assert core.drive.encoder_count(0) == approx(120.0)


def test_direction_inverse_mirrors_the_count():
    core = make_core()
    _move_to(core, 100.0)
    assert _write(core, INVERSE, True)["error"] == 0
    assert _write(core, OFFSET, 5.0)["error"] == 0
    core.step()
    assert _act(core) == approx(-95.0)
    _move_to(core, -80.0)  # 15 u forward is 15 increments backward
    assert core.drive.encoder_count(0) == approx(85.0)


def test_mask_restarts_the_count_and_counts_on_over_its_overflow():
    core = make_core()
    _move_to(core, 1000.0)
    assert _write(core, MASK, 255.0)["error"] == 0  # an 8-bit encoder: 1000 & 255 = 232
    core.step()
    assert _act(core) == approx(232.0) and core.drive.encoder_count(0) == approx(232.0)
    _move_to(core, 332.0)  # past the overflow at 256: ActPos goes on
    assert _act(core) == approx(332.0)
    assert core.drive.encoder_count(0) == approx(76.0)  # the hardware counter wrapped
    _move_to(core, -5.5)  # below 0: the hardware counter wraps back, the count goes on
    assert _act(core) == approx(-5.5)
    assert core.drive.encoder_count(0) == approx(250.5)  # not rounded
    # re-read with 32 bits: the count restarts at the motor's increments & mask, the 1000 + 100 - 337.5 = 762.5
    # increments it moved since the start (the 8-bit count had started at 232, not at 1000)
    assert _write(core, MASK, 4294967295.0)["error"] == 0
    core.step()
    assert _act(core) == approx(762.5)
    assert cmd(core, "ReadParameter", ParameterNumber=MASK)["Value"] == 4294967295.0


def test_mask_read_back_and_in_the_parameter_set():
    core = make_core()
    assert _write(core, MASK, 65535.0)["error"] == 0
    assert cmd(core, "ReadParameter", ParameterNumber=MASK)["Value"] == 65535.0
    assert cmd(core, "ReadParameterSet")["Value"]["nEncMaxIncrement"] == 65535


def test_chain_configured_at_start():
    core = NcCore([AxisConfig(1, "X", AxisParams(AxisEncoderOffset=7.0, AxisEncoderScalingFactor=0.1))])
    core.step()
    assert _act(core) == 7.0 and float(core.nctoplc[0]["SetPos"]) == 7.0


def test_the_mask_is_written_only_while_disabled():
    """(The other three encoder parameters were refused 0x4B42 while enabled already: test_param_table.)"""
    core = make_core()
    power(core, 0, ctrl=ALL_ENABLES)
    core.step()
    before = snapshot(core)
    assert _write(core, MASK, 255.0)["error"] == E.MC_AXIS_IS_ENABLED == 0x4B42
    assert snapshot(core) == before


@pytest.mark.parametrize("value", [0.0, 1000.0, 255.5, 4294967296.0, 8589934591.0, -1.0])
def test_a_mask_other_than_two_to_the_k_minus_one_is_refused_0x70b(value):
    core = make_core()
    core.step()
    before = snapshot(core)
    assert _write(core, MASK, value)["error"] == E.ADSERR_DEVICE_INVALIDPARM
    assert snapshot(core) == before


def test_masks_of_every_width_are_accepted():
    core = make_core()
    for k in (1, 8, 16, 24, 31, 32):
        assert _write(core, MASK, float(2 ** k - 1))["error"] == 0, k


def test_the_position_jump_hook_is_called_once_per_move_without_motion():
    core = make_core()
    _move_to(core, 100.0)
    calls: list[tuple[int, float]] = []
    core.position_jump_hooks.append(lambda i, jump: calls.append((i, jump)))
    assert _write(core, OFFSET, 3.0)["error"] == 0
    assert calls == [(0, 3.0)]
    assert _write(core, OFFSET, 3.0)["error"] == 0  # the same value: no jump
    assert _write(core, 1003, 900.0)["error"] == 0  # another parameter: no jump
    assert _write(core, SCALING, 0.5)["error"] == 0
    assert calls == [(0, 3.0), (0, approx(-50.0))]
    power(core, 0, ctrl=ALL_ENABLES)
    cmd(core, "MoveAbsolute", Position=80.0, Velocity=100.0)
    for _ in range(50):
        core.step()
    assert len(calls) == 2  # motion is no jump


def test_enabling_after_a_jump_moves_nothing():
    core = make_core()
    _move_to(core, 100.0)
    assert _write(core, OFFSET, -40.0)["error"] == 0
    power(core, 0, ctrl=ALL_ENABLES)
    for _ in range(50):
        core.step()
        assert float(core.nctoplc[0]["ActVelo"]) == 0.0 and _act(core) == approx(60.0)


def test_a_retained_position_shift_and_an_encoder_offset_add_up():
    core = make_core()
    core.step()
    assert cmd(core, "SetActualPosition", Position=100.0)["error"] == 0
    assert _write(core, OFFSET, 5.0)["error"] == 0
    core.step()
    assert _act(core) == 105.0
