"""AXIS_REF.nc_epoch: one NC restart is one step; a liveliness token that flaps is none.

A restart shows on zenoh as the NC's liveliness token going and coming back
(``PlcTask.nc_token_gone`` / ``nc_token_back``, called by the runtime) and its cycle counter going
back in the frames; only the frames are evidence (nc_schema.NcInstance): the token also goes and
comes back when a starved process's zenoh link is dropped for a lease while the same NC runs on.
The scripted NC (plc_rig.ScriptNc) plays both in every order; the rig (a real NcCore) the flap.
"""
from __future__ import annotations

from plc_rig import Rig, ScriptNc, powered


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
        rig.run_until(lambda: pw.Status and not pw.Error, 50)
        assert ax.nc_epoch == 0 and plc.claim_state(ax).state == "held"
        assert int(ax.NcToPlc["ErrorCode"]) == 0
    assert "Claim" not in sent
