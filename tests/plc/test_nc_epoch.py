"""AXIS_REF.nc_epoch: one NC restart is one step, whichever sign of it the PLC sees first.

A restart shows twice on zenoh: the NC's liveliness token goes and comes back
(``PlcTask.nc_token_gone`` / ``nc_token_back``, called by the runtime) and its cycle counter goes
back in the frames. The scripted NC (plc_rig.ScriptNc) plays both in every order.
"""
from __future__ import annotations

from plc_rig import ScriptNc


def _restart_frames(nc: ScriptNc) -> None:
    """The new instance's frames: its cycle counter starts again."""
    nc.nc_cycle = 1


def test_token_first_then_cycle_back_counts_once(nc: ScriptNc) -> None:
    nc.cycle_once(3)
    nc.nc_token_gone("nc1")
    for _ in range(2):
        nc.step()  # no frame of the new instance yet: the old one's stays the newest
    nc.nc_token_back("nc1")
    assert nc.ax.nc_epoch == 1
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


def test_token_back_with_the_cycle_going_on_counts_once(nc: ScriptNc) -> None:
    # a frozen NC (or a cut link): the token goes and returns, the frames go on
    nc.cycle_once(3)
    nc.nc_token_gone("nc1")
    nc.nc_token_back("nc1")
    nc.cycle_once(3)
    assert nc.ax.nc_epoch == 1


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
