"""AXIS_REF.nc_epoch: one NC restart is one step; a liveliness token that flaps is none.

A restart shows on zenoh as the NC's liveliness token going and coming back
(``PlcTask.nc_token_gone`` / ``nc_token_back``, called by the runtime), its instance token with a new
id (``PlcTask.nc_instance_token``) and, mostly, its cycle counter going back in the frames. Evidence
(nc_schema.NcInstance) are the instance id and the frames; ``nc/<nc>/alive`` also goes and comes back
when a starved process's zenoh link is dropped for a lease while the same NC runs on, and so does the
instance token, with the same id. The scripted NC (plc_rig.ScriptNc) plays them in every order; the
rig (a real NcCore) the flap and a new instance id.
"""
from __future__ import annotations

import pytest

from znc_testing.plc_rig import Rig, ScriptNc, powered


def _restart_frames(nc: ScriptNc) -> None:
    """The new instance's frames: its cycle counter starts again."""
    nc.nc_cycle = 1


def test_token_first_then_cycle_back_counts_once(nc: ScriptNc) -> None:
    nc.cycle_once(3)
    nc.nc_token_gone("nc1")
    for _ in range(2):
        nc.step()  # no frame of the new instance yet: the old one's stays the newest
    nc.nc_token_back("nc1")
    assert nc.ax.nc_epoch == 0  # a token back is no evidence yet: the frames of which instance follow?
    _restart_frames(nc)
    nc.cycle_once(3)
    assert nc.ax.nc_epoch == 1


def test_cycle_back_first_then_token_counts_once(nc: ScriptNc) -> None:
    nc.cycle_once(3)
    nc.nc_token_gone("nc1")
    _restart_frames(nc)
    nc.cycle_once(2)  # a frame of the new instance before its token's return
    assert nc.ax.nc_epoch == 1
    nc.nc_token_back("nc1")
    nc.cycle_once(3)
    assert nc.ax.nc_epoch == 1


def test_cycle_back_without_token_events_counts_once(nc: ScriptNc) -> None:
    nc.cycle_once(3)
    _restart_frames(nc)
    nc.cycle_once(3)
    assert nc.ax.nc_epoch == 1


def test_token_back_with_the_cycle_going_on_is_no_restart(nc: ScriptNc) -> None:
    # a frozen NC, client or router (or a cut link): the token goes and returns, the frames go on
    nc.cycle_once(3)
    for _ in range(3):
        nc.nc_token_gone("nc1")
        nc.step()
        assert not nc.ax.Status.Valid  # unreachable: invalid at once
        nc.nc_token_back("nc1")
        nc.cycle_once(3)
        assert nc.ax.nc_epoch == 0 and nc.ax.Status.Valid


def test_two_restarts_count_two(nc: ScriptNc) -> None:
    for k in (1, 2):
        nc.cycle_once(3)
        nc.nc_token_gone("nc1")
        nc.nc_token_back("nc1")
        _restart_frames(nc)
        nc.cycle_once(3)
        assert nc.ax.nc_epoch == k
    # and a restart seen by its cycle counter alone after those
    nc.cycle_once(3)
    _restart_frames(nc)
    nc.cycle_once(1)
    assert nc.ax.nc_epoch == 3


A, B = "0123456789abcdef", "fedcba9876543210"  # instance ids


def test_a_new_instance_id_with_a_higher_cycle_is_one_restart(nc: ScriptNc) -> None:
    """The new instance's frames go on above the old one's last Cycle (it ran briefly): only its id tells."""
    nc.nc_instance_token("nc1", A)
    nc.cycle_once(3)
    nc.nc_token_gone("nc1")
    nc.nc_cycle += 500  # the new instance counted more cycles than the old one ran
    nc.nc_token_back("nc1")
    nc.nc_instance_token("nc1", B)
    nc.cycle_once(3)
    assert nc.ax.nc_epoch == 1
    for _ in range(3):  # its token flapping: the same id
        nc.nc_token_gone("nc1")
        nc.nc_token_back("nc1")
        nc.nc_instance_token("nc1", B)
        nc.cycle_once(2)
    assert nc.ax.nc_epoch == 1


def test_the_old_instances_frame_is_not_valid_under_the_new_epoch(nc: ScriptNc) -> None:
    """A token restart comes before the new instance's frames: the old instance's frame the task held must
    not count as valid data of epoch 1 (it did while its NC cycle had not stood still for stale_cycles)."""
    nc.nc_instance_token("nc1", A)
    nc.cycle_once(3)
    assert nc.ax.Status.Valid
    nc.nc_instance_token("nc1", B)
    nc._snapshot_all()  # a PLC cycle without a new frame
    assert nc.ax.nc_epoch == 1 and not nc.ax.Status.Valid
    nc.cycle_once(1)  # the new instance's first frame
    assert nc.ax.nc_epoch == 1 and nc.ax.Status.Valid


@pytest.mark.parametrize("stale_frame", [False, True])
def test_new_id_then_the_cycle_going_back_is_one_restart(nc: ScriptNc, stale_frame: bool) -> None:
    """Token first (epoch + 1), then the new instance's frames with the cycle gone back (after one frame of
    the old instance the client still held, ``stale_frame``): no second step."""
    nc.nc_instance_token("nc1", A)
    nc.cycle_once(3)
    nc.nc_instance_token("nc1", B)
    nc.cycle_once(2 if stale_frame else 0)
    assert nc.ax.nc_epoch == 1
    _restart_frames(nc)
    nc.cycle_once(3)
    assert nc.ax.nc_epoch == 1


def test_cycle_back_then_the_new_id_is_one_restart(nc: ScriptNc) -> None:
    nc.nc_instance_token("nc1", A)
    nc.cycle_once(3)
    _restart_frames(nc)
    nc.cycle_once(2)
    assert nc.ax.nc_epoch == 1
    nc.nc_instance_token("nc1", B)
    nc.cycle_once(2)
    assert nc.ax.nc_epoch == 1


def test_a_new_instance_id_forgets_the_claim(rig: Rig) -> None:
    """The defect: a new NC instance whose Cycle went on above the old one's last (the rig's NcCore runs on,
    as frames of such an instance look). Before, the PLC kept its 'held' claim, which the new NC would not
    know; now the claim is forgotten and MC_Power claims again."""
    ax, pw, _ = powered(rig)
    plc = ax.task
    plc.nc_instance_token("nc1", A)
    rig.run(2)
    sent: list[str] = []
    orig = plc.port.send
    plc.port.send = lambda *a, **k: sent.append(a[2]) or orig(*a, **k)
    plc.nc_instance_token("nc1", B)
    assert ax.nc_epoch == 1 and plc.claim_state(ax).state != "held"
    rig.run_until(lambda: "Claim" in sent and plc.claim_state(ax).state == "held", 50)
    assert ax.nc_epoch == 1


def test_a_flapping_token_keeps_the_claim_and_the_epoch(rig: Rig) -> None:
    """The NC's token goes (a dropped zenoh link) and comes back while the same NcCore runs on.
    Before: every return counted as a restart (claims forgotten, MC_Power claimed again; nc-ads
    dropped its PLCTONC supply on it, so the NC's watchdog stopped the axis)."""
    ax, pw, _ = powered(rig)
    plc = ax.task
    sent: list[str] = []
    orig = plc.port.send
    plc.port.send = lambda *a, **k: sent.append(a[2]) or orig(*a, **k)
    for _ in range(3):
        plc.nc_token_gone("nc1")
        rig.run(1)
        assert not ax.Status.Valid and pw.Error  # unreachable: invalid at once (0x4B0F)
        rig.run(3)
        plc.nc_token_back("nc1")
        plc.nc_instance_token("nc1", A)  # its instance token, back with the same id
        rig.run_until(lambda: pw.Status and not pw.Error, 50)
        assert ax.nc_epoch == 0 and plc.claim_state(ax).state == "held"
        assert int(ax.NcToPlc["ErrorCode"]) == 0
    assert "Claim" not in sent


# ---- the frames' Epoch (protocol 5, a hot-standby pair: nc_schema.NcInstance.take) ------------------------------
E1, E2 = (1 << 16) | 0x1234, (2 << 16) | 0x0042


def test_a_takeover_with_the_cycle_going_on_is_no_restart_and_the_old_nodes_frames_are_dropped(nc: ScriptNc) -> None:
    """The standby takes over (a higher epoch, the Cycle count continuing): no restart. The old active node, back
    after a link cut, publishes its own frames (its Cycle behind, its own set-points) until it sees the higher
    epoch: dropped, the axis keeps the active node's data, no restart."""
    nc.nc_instance_token("nc1", A)
    nc.frame_epoch = E1
    nc.rec["SetPos"] = 1.0
    nc.cycle_once(3)
    nc.frame_epoch = E2
    nc.rec["SetPos"] = 2.0
    nc.cycle_once(3)
    assert nc.ax.nc_epoch == 0 and nc.ax.NcToPlc.SetPos == 2.0 and nc.ax.Status.Valid
    good = nc.nc_cycle - 10
    nc.frame_epoch, nc.nc_cycle = E1, nc.nc_cycle - 200  # the old node: its Cycle behind, its plan elsewhere
    nc.rec["SetPos"] = 99.0
    nc.cycle_once(2)
    assert nc.ax.nc_epoch == 0 and nc.ax.NcToPlc.SetPos == 2.0 and nc.ax.Status.NcCycleCounter == good
    inst = nc._instances["nc1"]
    assert inst.stale_frames == 2 and inst.epoch == E2 and inst.epoch_rises == 2  # (0 -> E1 -> E2)
    nc.frame_epoch, nc.nc_cycle = E2, good + 30  # the active node's frames again
    nc.rec["SetPos"] = 3.0
    nc.cycle_once(1)
    assert nc.ax.nc_epoch == 0 and nc.ax.NcToPlc.SetPos == 3.0 and nc.ax.Status.Valid


def test_a_restarted_pair_at_epoch_0_is_one_restart_and_followed(nc: ScriptNc) -> None:
    nc.nc_instance_token("nc1", A)
    nc.frame_epoch = E2
    nc.cycle_once(3)
    nc.nc_instance_token("nc1", B)  # the whole pair restarted: a new instance at epoch 0
    nc.frame_epoch = 0
    _restart_frames(nc)
    nc.rec["SetPos"] = 5.0
    nc.cycle_once(2)
    assert nc.ax.nc_epoch == 1 and nc.ax.NcToPlc.SetPos == 5.0 and nc.ax.Status.Valid
    assert nc._instances["nc1"].epoch == 0
