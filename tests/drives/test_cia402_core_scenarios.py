"""A representative subset of the core's scenario tests (tests/core), run again with the ``cia402-sim`` drives
(Cia402SimDrive): NcCore's default drive is pinned to it for the module (an autouse fixture; since issue 20's
follow-up cia402-sim is NcCore's default anyway, so tests/core runs on it too), the tests themselves are the
unchanged functions of their modules, collected here under the same names.

Not rerun here, on purpose (their expectations differ with a CiA 402 drive; in tests/core they run on ``SimDrive``,
pinned there):

* test_drive_fields.py::test_a_device_error_on_an_enabled_axis_is_0x4650_at_once -- the drive stops itself (no
  NC ramp) and, the cause gone, still needs its fault reset: after ``set_device_error(0, False)`` the first
  MC_Reset acknowledges the drive, the axis follows again two cycles later (not in the same cycle).
* test_drive_fields.py::test_a_drive_delivering_no_torque_shows_zero_in_every_torque_field[device error] -- a
  CiA 402 drive brakes itself on its quick-stop ramp after a fault: ActTorque shows its braking torque (0x6077)
  until it stands (SetTorque and TorqueOffset are 0 at once, as before).

(The touch probe and the stepper terminal work on Cia402SimDrive now: tests/drives/test_touch_probe_cia402.py,
tests/core/test_touch_probe.py and the stepper tests of tests/core run on it as the default drive.)
"""
from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import ModuleType
from typing import Iterator

import pytest

import nc_server.core  # noqa: F401  (first: nc_server.drives imports the core, which imports drives.base)
import nc_server.core.nc as nc_module
from nc_server.drives.cia402.sim import Cia402SimDrive

CORE = Path(__file__).resolve().parent.parent / "core"


def _load(name: str) -> ModuleType:
    spec = importlib.util.spec_from_file_location(f"cia402_rerun_{name}", CORE / f"{name}.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


@pytest.fixture(autouse=True)
def cia402_default_drive(monkeypatch: pytest.MonkeyPatch) -> Iterator[None]:
    """NcCore builds Cia402SimDrive when given no drive."""
    monkeypatch.setattr(nc_module, "default_drive", Cia402SimDrive)
    yield


def test_the_swap_is_in_effect() -> None:
    from znc_testing.nc_core import powered
    core = powered()
    assert isinstance(core.drive, Cia402SimDrive)


_jog_home = _load("test_engine_jog_home")
test_homing_sequence = _jog_home.test_homing_sequence
test_homing_with_the_cam_occupied_at_start_leaves_it_first = \
    _jog_home.test_homing_with_the_cam_occupied_at_start_leaves_it_first
test_continuous_jog_runs_at_its_velocity_until_halt = _jog_home.test_continuous_jog_runs_at_its_velocity_until_halt
test_inching_moves_by_the_distance = _jog_home.test_inching_moves_by_the_distance
test_stop_during_homing_aborts_it_and_the_axis_is_not_homed = \
    _jog_home.test_stop_during_homing_aborts_it_and_the_axis_is_not_homed

_fields = _load("test_drive_fields")
test_set_and_act_torque_follow_the_model_in_percent_with_derivatives = \
    _fields.test_set_and_act_torque_follow_the_model_in_percent_with_derivatives
test_invalid_io_data_warn_three_cycles_then_0x4655_and_the_values_hold = \
    _fields.test_invalid_io_data_warn_three_cycles_then_0x4655_and_the_values_hold
test_io_data_valid_again_within_the_delay_is_no_error = _fields.test_io_data_valid_again_within_the_delay_is_no_error
test_a_device_error_on_a_disabled_axis_shows_the_bit_and_a_start_is_refused_0x4225 = \
    _fields.test_a_device_error_on_a_disabled_axis_shows_the_bit_and_a_start_is_refused_0x4225
test_the_model_rests_after_two_steps_without_any_drive_delivering_torque = \
    _fields.test_the_model_rests_after_two_steps_without_any_drive_delivering_torque
test_one_axis_delivering_keeps_the_others_at_zero = _fields.test_one_axis_delivering_keeps_the_others_at_zero


@pytest.mark.parametrize("how", ["disabled", "invalid io"])  # (not "device error": see the module docstring)
def test_a_drive_delivering_no_torque_shows_zero_in_every_torque_field(how: str) -> None:
    _fields.test_a_drive_delivering_no_torque_shows_zero_in_every_torque_field(how)

_encoder = _load("test_encoder_chain")
for _name in dir(_encoder):
    if _name.startswith("test_"):
        globals()[_name] = getattr(_encoder, _name)

_states = _load("test_state_machine")
for _name in dir(_states):
    if _name.startswith("test_"):
        globals()[_name] = getattr(_states, _name)

_stops = _load("test_stop_dynamics")
for _name in dir(_stops):
    if _name.startswith("test_"):
        globals()[_name] = getattr(_stops, _name)

_profiles = _load("test_profiles")
for _name in dir(_profiles):
    if _name.startswith("test_"):
        globals()[_name] = getattr(_profiles, _name)

_monitoring = _load("test_modulo_and_monitoring")
for _name in dir(_monitoring):
    if _name.startswith("test_"):
        globals()[_name] = getattr(_monitoring, _name)
