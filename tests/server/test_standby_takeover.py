"""The hot standby's takeover and role changes in one process (no zenoh; docs/standby.md): what reaches the drives
at a takeover, the epoch of a retake after a demotion, the confirmation of a new epoch by the drive hosts, the
declarations' failures, the status read from another thread, the logs of a lower epoch."""
from __future__ import annotations

import pickle
import time
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

import nc_server.core  # noqa: F401  (before nc_server.drives: circular import otherwise)
from nc_server.drives.sim import SimDrive
from nc_server.server.config import Redundancy
from nc_server.server.replication import RecordingDrive
from nc_server.server.standby import START_GRACE_S, HotStandby

from test_replication import Active

DT = 0.001  # (Active's cycle)
TAKEOVER = 15


class FakeLink:
    """What the standby sees of a remote drive link (drive_links): the epochs, the mute flag."""

    def __init__(self) -> None:
        self.epoch = 0
        self.host_epoch = 0
        self.input_epoch = 0
        self.received = 0
        self.takeover_ms = 0.0
        self.mute = False


class LinkedSim(SimDrive):
    """A simulated drive behind a FakeLink: the set-points of axis 1 that went out (not muted) are noted in
    ``events`` (the drive side's view), like the declarations of the takeover."""

    def __init__(self, params: Any, cycle_time: float, events: list[tuple[str, float]]) -> None:
        super().__init__(params, cycle_time)
        self.link = FakeLink()
        self.events = events

    def step(self, enabled: np.ndarray, set_pos: np.ndarray, set_velo: np.ndarray, set_acc: np.ndarray) -> None:
        super().step(enabled, set_pos, set_velo, set_acc)
        if not self.link.mute:
            self.events.append(("out", float(set_pos[0])))


def pair(events: list[tuple[str, float]] | None = None) -> tuple[Active, HotStandby, LinkedSim]:
    """An Active core on a LinkedSim (the stand-in for the follower's core in step) and the HotStandby over it."""
    events = [] if events is None else events
    act = Active()
    drive = LinkedSim(act.core.params, act.core.cycle_time, events)
    act.core.drive = RecordingDrive(drive)
    act.rec.attach_drive(act.core.drive)
    transport = SimpleNamespace(instance="i1", serve=lambda: events.append(("serve", 0.0)))
    srv = SimpleNamespace(core=act.rec, handler=act.handler, claims=act.claims, transport=transport,
                          config=SimpleNamespace(name="nc1", cycle_time=DT),
                          became_active=lambda now, serve=True: None, became_standby=lambda: None)
    hs = HotStandby(srv, Redundancy(True, "standby", TAKEOVER, 10.0, "b"))  # type: ignore[arg-type]
    return act, hs, drive


def moving(act: Active) -> None:
    act.handler.client_alive("plc", 0.0)
    act.request("Claim", 1, 1)
    act.supply(7, ids=(1,))
    for _ in range(3):
        act.cycle()
    assert act.request("MoveAbsolute", 5, 1, Position=100.0, Velocity=50.0)["error"] == 0
    for _ in range(200):  # (at constant velocity)
        act.cycle()


def test_the_first_set_point_of_a_takeover_is_where_the_drives_extrapolated_to() -> None:
    # the active NC froze: the drives extrapolated its last set-point with its velocity (nc-drive-sim --extrapolate)
    # for the k cycles of silence; the takeover's catch-up steps over them at once. The drives must see no output
    # of the catch-up steps before the last (behind their target: a step back, then forward), and the takeover's
    # declarations (milliseconds) must not come before the first output
    events: list[tuple[str, float]] = []
    act, hs, drive = pair(events)
    moving(act)
    hs.synced_once, hs.follower.waiting = True, False
    last = [p for e, p in events if e == "out"][-1]
    v = float(act.core.nctoplc["SetVelo"][0])
    assert v > 10.0
    events.clear()
    now = time.monotonic()
    hs._last_log = now - 0.010  # 10 ms of silence: k = 10 catch-up cycles
    hs._become_active(now)
    assert hs.role == "active" and hs.catch_up == 10
    act.rec.step()  # the cycle's own step, then after_step (the log; the declarations)
    hs.after_step()
    outs = [p for e, p in events if e == "out"]
    assert len(outs) == 1, events  # only the takeover cycle's own set-point went out
    extrapolated = last + v * hs.catch_up * DT
    assert outs[0] >= extrapolated - 1e-6 * max(1.0, abs(extrapolated)), (outs[0], extrapolated)
    assert [e for e, _ in events] == ["out", "serve"]  # the declarations after the first set-point
    assert not hs._serve_pending
    assert not drive.link.mute
    # the drives go on from there, forward only
    for _ in range(5):
        act.rec.step()
        hs.after_step()
    outs = [p for e, p in events if e == "out"]
    assert all(b >= a for a, b in zip(outs, outs[1:])), outs


def test_a_muted_remote_link_takes_inputs_but_sends_nothing() -> None:
    from nc_server.drives.cia402.image import RxImage
    from nc_server.drives.remote.config import host_slots
    from nc_server.drives.remote.link import RemoteLink

    sent: list[bytes] = []
    link = RemoteLink("nc1", 1, host_slots([{"host": "d1"}], None), None)
    link._ready = True
    link._pubs = [SimpleNamespace(put=sent.append)]
    link._tx_subs = []
    link._live_sub = SimpleNamespace(try_recv=lambda: None)
    img = RxImage.zeros(1)
    link.exchange(img)
    assert len(sent) == 1
    link.mute = True
    link.exchange(img)
    assert len(sent) == 1
    link.mute = False
    link.exchange(img)
    assert len(sent) == 2
