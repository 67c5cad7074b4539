"""NCTOPLC fields a servo axis fills, from the simulated drive (issue 17, "every field a servo axis fills is
live"): the torque model (nc_server/drives/mechanics.py), the drive's I/O and device state
(nc_server/core/drive_monitor.py), SvbEntries/SafEntries and AxisModeConfirmation."""
from __future__ import annotations

import math

import numpy as np
import pytest

from nc_schema import ErrorCodes as E, StateDWord
import nc_server.core  # noqa: F401  (first: nc_server.drives imports the core)
from nc_server.drives.sim import SimDrive
from znc_testing.nc_core import ALL_ENABLES, cmd, make_core, power, powered, run_until, snapshot

CT = 0.001
MECH = dict(SimLoadInertia=0.002, SimViscousFriction=0.004, SimCoulombFriction=0.3, SimRatedTorque=2.0)
TORQUE = ("SetTorque", "ActTorque", "SetTorqueDerivative", "ActTorqueDerivative", "TorqueOffset")
IO_INVALID, DELAYED, DEVICE = (int(StateDWord.IoDataInvalid), int(StateDWord.ErrorPropagationDelayed),
                               int(StateDWord.DriveDeviceError))


def _torque(v: float, a: float, p: dict = MECH) -> float:
    """The model in % of the rated torque."""
    t = p["SimLoadInertia"] * a + p["SimViscousFriction"] * v + p["SimCoulombFriction"] * np.sign(v)
    return 100.0 * t / p["SimRatedTorque"]


def _ext_torque(core, i: int, value: float) -> None:
    rec = core.plctonc[i].copy()
    rec["ExtTorque"] = value
    core.set_plctonc(i, rec)


def _fields(core, i: int = 0) -> dict[str, float]:
    r = core.nctoplc[i]
    return {k: float(r[k]) for k in TORQUE}


def test_set_and_act_torque_follow_the_model_in_percent_with_derivatives():
    core = powered(AxisVeloMax=2000.0, **MECH)
    assert _fields(core) == dict.fromkeys(TORQUE, 0.0)  # at rest: no torque (Coulomb is sign(v): 0)
    assert cmd(core, "MoveAbsolute", Position=300.0, Velocity=1000.0)["error"] == 0
    prev = _fields(core)
    seen_acc = seen_const = False
    for _ in range(600):
        core.step()
        r, f = core.nctoplc[0], _fields(core)
        assert f["SetTorque"] == pytest.approx(_torque(float(r["SetVelo"]), float(r["SetAcc"])), abs=1e-9)
        assert f["ActTorque"] == pytest.approx(_torque(float(r["ActVelo"]), float(r["ActAcc"])), abs=1e-9)
        assert f["SetTorqueDerivative"] == pytest.approx((f["SetTorque"] - prev["SetTorque"]) / CT, abs=1e-6)
        assert f["ActTorqueDerivative"] == pytest.approx((f["ActTorque"] - prev["ActTorque"]) / CT, abs=1e-6)
        seen_acc |= float(r["SetAcc"]) > 4000.0
        if abs(float(r["SetVelo"]) - 1000.0) < 1e-6 and abs(float(r["SetAcc"])) < 1e-6:
            # at constant velocity: viscous + Coulomb only, (0.004 * 1000 + 0.3) / 2 N*m = 215 %
            assert f["SetTorque"] == pytest.approx(215.0, abs=1e-3)
            seen_const = True
        prev = f
    assert seen_acc and seen_const


def test_defaults_a_small_servo():
    core = powered()
    cmd(core, "MoveVelocity", Velocity=500.0, Direction=1)
    run_until(core, lambda: float(core.nctoplc[0]["SetVelo"]) == 500.0)
    core.step()
    # 1e-4 N*m*s/u * 500 u/s + 0.02 N*m of 1 N*m rated
    assert float(core.nctoplc[0]["SetTorque"]) == pytest.approx(7.0)


def test_ext_torque_is_the_torque_offset_in_set_torque_only_clipped_and_kept_when_not_finite():
    core = powered(**MECH)
    _ext_torque(core, 0, 12.5)
    core.step()
    f = _fields(core)
    assert f["TorqueOffset"] == 12.5 and f["SetTorque"] == 12.5 and f["ActTorque"] == 0.0
    assert f["SetTorqueDerivative"] == pytest.approx(12.5 / CT)
    core.step()
    assert _fields(core)["SetTorqueDerivative"] == 0.0
    for bad in (math.nan, math.inf, -math.inf):
        _ext_torque(core, 0, bad)
        core.step()
        assert _fields(core)["TorqueOffset"] == 12.5 and _fields(core)["SetTorque"] == 12.5, bad
    _ext_torque(core, 0, 5000.0)
    core.step()
    assert _fields(core)["TorqueOffset"] == 1000.0
    _ext_torque(core, 0, -1e9)
    core.step()
    assert _fields(core)["TorqueOffset"] == -1000.0 and _fields(core)["SetTorque"] == -1000.0


@pytest.mark.parametrize("how", ["disabled", "device error", "invalid io"])
def test_a_drive_delivering_no_torque_shows_zero_in_every_torque_field(how):
    # "device error" on SimDrive, whose injected hardware error holds the motor at once: a CiA 402 drive (the
    # default, cia402-sim) brakes itself on its quick-stop ramp and shows that braking torque as ActTorque until it
    # stands (tests/drives/test_cia402_core.py)
    core = powered(drive_cls=SimDrive if how == "device error" else None, **MECH)
    _ext_torque(core, 0, 20.0)
    cmd(core, "MoveVelocity", Velocity=300.0, Direction=1)
    for _ in range(50):
        core.step()
    assert all(v != 0.0 for k, v in _fields(core).items() if k != "ActTorqueDerivative")
    if how == "disabled":
        power(core, 0, ctrl=0)
    elif how == "device error":
        core.drive.set_device_error(0, True)
    else:
        core.drive.set_io_invalid(0, True)
    core.step()
    f = _fields(core)
    assert (f["SetTorque"], f["ActTorque"], f["TorqueOffset"]) == (0.0, 0.0, 0.0), f
    for _ in range(5):
        core.step()
    assert _fields(core) == dict.fromkeys(TORQUE, 0.0)


def test_the_model_does_not_limit_motion():
    """A load 1000 x heavier: the same set-points and actual positions, bit for bit (the torque is reported,
    never a limit)."""
    light, heavy = powered(**MECH), powered(SimLoadInertia=2.0, SimRatedTorque=0.001)
    for core in (light, heavy):
        cmd(core, "MoveAbsolute", Position=200.0, Velocity=800.0)
    for _ in range(500):
        light.step()
        heavy.step()
        assert light.nctoplc[0]["ActPos"] == heavy.nctoplc[0]["ActPos"]
        assert light.nctoplc[0]["SetPos"] == heavy.nctoplc[0]["SetPos"]
    assert float(heavy.nctoplc[0]["SetTorque"]) != float(light.nctoplc[0]["SetTorque"])


def test_the_model_rests_after_two_steps_without_any_drive_delivering_torque():
    core = powered(2, **MECH)
    cmd(core, "MoveVelocity", Velocity=300.0, Direction=1)
    for _ in range(30):
        core.step()
    for i in range(2):
        power(core, i, ctrl=0)
    core.step()  # the fields fall to 0 (derivatives: the fall)
    assert float(core.nctoplc[0]["SetTorqueDerivative"]) < 0
    core.step()  # the derivatives to 0
    assert core.nctoplc[["SetTorqueDerivative", "ActTorqueDerivative"]].tolist() == [(0.0, 0.0)] * 2
    # at rest: no numpy work at all (these would fail at the first use)
    m = core.drive.mechanics
    m.inertia = m.viscous = m.coulomb = None
    m.fields = None
    before = core.nctoplc.copy()
    for _ in range(5):
        core.step()
    assert core.nctoplc[list(TORQUE)].tolist() == before[list(TORQUE)].tolist()
    assert core.drive.torque_fields() is None


def test_one_axis_delivering_keeps_the_others_at_zero():
    core = powered(2, **MECH)
    power(core, 1, ctrl=0)
    _ext_torque(core, 1, 30.0)
    cmd(core, "MoveVelocity", Velocity=300.0, Direction=1)
    for _ in range(30):
        core.step()
    assert float(core.nctoplc[0]["SetTorque"]) > 0
    assert [float(core.nctoplc[1][k]) for k in TORQUE] == [0.0] * 5


def test_svb_and_saf_entries_count_the_buffered_and_the_running_command():
    core = powered()
    r = core.nctoplc[0]
    assert (int(r["SvbEntries"]), int(r["SafEntries"])) == (0, 0)
    assert cmd(core, "MoveAbsolute", Position=20.0, Velocity=200.0)["error"] == 0
    core.step()
    assert (int(r["SvbEntries"]), int(r["SafEntries"])) == (0, 1)
    assert cmd(core, "MoveAbsolute", Position=0.0, Velocity=200.0, BufferMode=1)["error"] == 0
    core.step()
    assert (int(r["SvbEntries"]), int(r["SafEntries"])) == (1, 1)
    run_until(core, lambda: int(core.nctoplc[0]["SvbEntries"]) == 0)
    for _ in range(5):
        core.step()
    assert int(r["SafEntries"]) == 1 and float(r["SetVelo"]) < 0  # the buffered one runs now
    run_until(core, lambda: int(core.nctoplc[0]["SafEntries"]) == 0)
    assert float(r["SetVelo"]) == 0.0


# ---- the drive's I/O and device state -------------------------------------------------------------------

def _dw(core, i: int = 0) -> int:
    return int(core.nctoplc[i]["StateDWord"])


@pytest.mark.parametrize("enabled", [True, False])
def test_invalid_io_data_warn_three_cycles_then_0x4655_and_the_values_hold(enabled):
    core = powered() if enabled else make_core()
    if enabled:
        cmd(core, "MoveVelocity", Velocity=100.0, Direction=1)
    for _ in range(50):
        core.step()
    held = core.nctoplc[0][["ActPos", "ActVelo", "ActAcc"]].tolist()
    core.drive.set_io_invalid(0, True)
    for k in range(3):
        core.step()
        assert _dw(core) & IO_INVALID and _dw(core) & DELAYED, k
        assert int(core.nctoplc[0]["ErrorCode"]) == 0
        assert core.nctoplc[0][["ActPos", "ActVelo", "ActAcc"]].tolist() == held
    core.step()
    assert int(core.nctoplc[0]["ErrorCode"]) == E.NC_DRIVE_IO_DATA_INVALID == 0x4655
    assert _dw(core) & IO_INVALID and not _dw(core) & DELAYED
    # the error comes back after a reset while the data stay invalid
    assert cmd(core, "Reset")["error"] == 0
    run_until(core, lambda: not core.axes.traj_on[0], 10_000)
    cmd(core, "Reset")
    core.step()
    assert int(core.nctoplc[0]["ErrorCode"]) == 0x4655
    # valid again: the bits go, a reset clears the error for good
    core.drive.set_io_invalid(0, False)
    core.step()
    assert not _dw(core) & (IO_INVALID | DELAYED)
    cmd(core, "Reset")
    for _ in range(5):
        core.step()
    assert int(core.nctoplc[0]["ErrorCode"]) == 0


def test_io_data_valid_again_within_the_delay_is_no_error():
    core = powered()
    core.drive.set_io_invalid(0, True)
    for _ in range(3):
        core.step()
    core.drive.set_io_invalid(0, False)
    for _ in range(5):
        core.step()
        assert not _dw(core) & (IO_INVALID | DELAYED) and int(core.nctoplc[0]["ErrorCode"]) == 0
    core.drive.set_io_invalid(0, True)  # the count starts again
    for _ in range(3):
        core.step()
    assert int(core.nctoplc[0]["ErrorCode"]) == 0


def test_a_device_error_on_an_enabled_axis_is_0x4650_at_once():
    # on SimDrive, whose injected error vanishes by itself and is judged by the NC at once: a CiA 402 drive (the
    # default, cia402-sim) stays in Fault until a fault reset, which takes the link's latency (0x4650 is back
    # within max_age + 4 cycles after a refused MC_Reset, not in the next cycle; tests/drives/test_cia402_core.py)
    core = powered(drive_cls=SimDrive)
    cmd(core, "MoveVelocity", Velocity=100.0, Direction=1)
    for _ in range(20):
        core.step()
    core.drive.set_device_error(0, True)
    core.step()
    assert int(core.nctoplc[0]["ErrorCode"]) == E.NC_DRIVE_NOT_READY == 0x4650
    assert _dw(core) & DEVICE and not _dw(core) & int(StateDWord.ControlLoopClosed)
    run_until(core, lambda: not core.axes.traj_on[0], 10_000)
    cmd(core, "Reset")
    core.step()
    assert int(core.nctoplc[0]["ErrorCode"]) == 0x4650  # back while the condition lasts
    core.drive.set_device_error(0, False)
    cmd(core, "Reset")
    core.step()
    assert int(core.nctoplc[0]["ErrorCode"]) == 0 and not _dw(core) & DEVICE
    assert _dw(core) & int(StateDWord.Operational)


def test_a_device_error_on_a_disabled_axis_shows_the_bit_and_a_start_is_refused_0x4225():
    core = make_core()
    core.drive.set_device_error(0, True)
    for _ in range(3):
        core.step()
    assert _dw(core) & DEVICE and int(core.nctoplc[0]["ErrorCode"]) == 0
    power(core, 0, ctrl=ALL_ENABLES)  # the enable and the start in one PLC cycle
    before = snapshot(core)
    r = cmd(core, "MoveAbsolute", Position=10.0, Velocity=10.0)
    assert r["error"] == E.NC_DRIVE_NOT_READY_AT_START == 0x4225
    assert snapshot(core) == before


def test_nothing_to_monitor_costs_one_flag():
    core = powered()
    cmd(core, "MoveVelocity", Velocity=100.0, Direction=1)
    core.drive_monitor.run = None  # would fail if called
    for _ in range(20):
        core.step()
    assert not core.drive_monitor.active
