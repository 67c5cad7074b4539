"""Client loss reactions, the NC's own stalls and HandOver, on a real NcCore through nc-server's
handler and cycle inputs (pure: NC time is passed in; no zenoh, no clock)."""
from __future__ import annotations

from typing import Any

import msgpack
import numpy as np
import pytest

from nc_schema import PLCTONC_DTYPE, Keys, make_request
from nc_server.core import AxisConfig, AxisParams, NcCore
from nc_server.server.claims import ZNC_CLIENT_LOST, ZNC_PLCTONC_TIMEOUT, ClaimTable
from nc_server.server.handler import ZNC_NC_STALLED, CycleInputs, RequestHandler
from znc_testing import done, step_until

DT = 0.001
ENABLE_ALL = 0x7


class Frame:
    def __init__(self, arrival: float, ids: list[int], control: int = ENABLE_ALL) -> None:
        self.arrival = arrival
        self.axis_ids = np.array(ids, dtype=np.uint32)
        self.plctonc = np.zeros(len(ids), dtype=PLCTONC_DTYPE)
        self.plctonc["ControlDWord"] = control
        self.plctonc["Override"] = 1_000_000


class Rig:
    """One NcCore behind nc-server's RequestHandler and CycleInputs, stepped with explicit NC time."""

    def __init__(self, reactions: list[str], watchdog: float = 0.5) -> None:
        params = AxisParams(AxisVeloMax=500.0, AxisAcc=5000.0, AxisDec=5000.0, AxisJerk=50000.0)
        self.core = NcCore([AxisConfig(i + 1, params=params) for i in range(len(reactions))], DT)
        self.claims = ClaimTable(list(range(1, len(reactions) + 1)), watchdog)
        self.keys = Keys("nc1")
        self.h = RequestHandler(self.core, self.claims, self.keys)
        self.inputs = CycleInputs(self.core, self.claims, reactions)
        self.feeds: dict[str, tuple[list[int], int]] = {}  # client -> (axes, ControlDWord) sent every cycle
        self.faults: list[tuple[int, int]] = []
        self._rid = 0

    @property
    def now(self) -> float:
        return self.core.cycle * DT

    def cmd(self, client: str, cmd: str, axis: int, **args: Any) -> dict[str, Any]:
        self._rid += 1
        rep = self.h.handle(self.keys.command_key(cmd, axis, client), make_request(cmd, self._rid, client, **args),
                            self.now)
        return msgpack.unpackb(rep, raw=False, strict_map_key=False)

    def ok(self, client: str, cmd: str, axis: int, **args: Any) -> dict[str, Any]:
        r = self.cmd(client, cmd, axis, **args)
        assert r["error"] == 0, r
        return r

    def join(self, client: str, axes: list[int] = (), control: int = ENABLE_ALL) -> None:
        """Token present; claims ``axes`` and feeds enabling PLCTONC for them every cycle."""
        self.h.client_alive(client)
        for a in axes:
            self.ok(client, "Claim", a)
        if axes:
            self.feeds[client] = (list(axes), control)

    def run(self, cycles: int) -> None:
        for _ in range(cycles):
            now = self.now
            frames = [(c, Frame(now, axes, ctl)) for c, (axes, ctl) in self.feeds.items()]
            self.faults += self.inputs.apply(frames, now)
            self.core.step()

    def run_until(self, pred: Any, limit: int = 20000) -> int:
        """Cycles until ``pred()``, asked before the first one too (0: already true)."""
        if done(pred()):
            return 0
        return step_until(lambda: self.run(1), pred, limit - 1)

    def gone(self, client: str) -> None:
        self.feeds.pop(client, None)
        self.h.client_gone(client, self.now)

    def enabled(self, axis: int) -> bool:
        return bool(self.core.axes.enabled[axis - 1])

    def error(self, axis: int) -> int:
        return int(self.core.axes.error[axis - 1])

    def velo(self, axis: int) -> float:
        return float(self.core.nctoplc[axis - 1]["SetVelo"])

    def standing(self, axis: int) -> bool:
        return not bool(self.core.moving[axis - 1])


def moving_rig(reaction: str, commander: str = "a") -> Rig:
    """Axis 1 held by 'a' with ``reaction``, moving at 100 u/s commanded by ``commander``."""
    r = Rig([reaction])
    r.join("a", [1])
    if commander != "a":
        r.join(commander)
    r.run(5)
    assert r.enabled(1)
    r.ok(commander, "MoveVelocity", 1, Velocity=100.0)
    r.run(100)
    assert abs(r.velo(1) - 100.0) < 1e-6
    return r


@pytest.mark.parametrize("how", ["killed", "frozen"])
def test_stop_disable_stops_then_disables(how: str) -> None:
    r = moving_rig("stop_disable")
    code = ZNC_CLIENT_LOST if how == "killed" else ZNC_PLCTONC_TIMEOUT
    if how == "killed":
        r.gone("a")
    else:
        r.feeds.pop("a")  # silent, token still there: the watchdog
    r.run_until(lambda: r.faults)
    assert r.faults == [(1, code)] and r.error(1) == code and r.claims.holder(1) is None
    assert r.enabled(1) and abs(r.velo(1)) > 0  # the stop ramp runs enabled
    r.run_until(lambda: r.standing(1))
    r.run(2)
    assert not r.enabled(1)


def test_stop_keeps_the_axis_enabled_holding_position() -> None:
    r = moving_rig("stop")
    r.gone("a")
    r.run_until(lambda: r.faults)
    assert r.faults == [(1, ZNC_CLIENT_LOST)] and r.claims.holder(1) is None
    r.run_until(lambda: r.standing(1))
    pos = float(r.core.nctoplc[0]["SetPos"])
    r.run(500)
    assert r.enabled(1) and r.error(1) == ZNC_CLIENT_LOST
    assert float(r.core.nctoplc[0]["SetPos"]) == pos
    # a new holder takes it over with its own PLCTONC
    r.join("c", [1], control=0)
    r.run(3)
    assert not r.enabled(1)


def test_keep_others_lets_another_live_clients_motion_run_then_disables() -> None:
    r = Rig(["keep_others"])
    r.join("a", [1])
    r.join("b")
    r.run(5)
    r.ok("b", "MoveAbsolute", 1, Position=50.0, Velocity=100.0)
    r.run(50)
    r.gone("a")
    r.run(5)
    assert r.faults == [] and r.error(1) == 0 and r.claims.holder(1) is None
    assert r.enabled(1) and 1 - 1 in r.inputs.kept
    r.run_until(lambda: r.standing(1))
    assert abs(float(r.core.nctoplc[0]["SetPos"]) - 50.0) < 1e-9  # the motion ended where b wanted
    r.run(3)
    assert not r.enabled(1) and not r.inputs.kept and r.faults == []


def test_keep_others_keeps_nothing_when_somebody_claims_meanwhile() -> None:
    r = Rig(["keep_others"])
    r.join("a", [1])
    r.join("b")
    r.run(5)
    r.ok("b", "MoveAbsolute", 1, Position=20.0, Velocity=100.0)
    r.run(20)
    r.gone("a")
    r.run(5)
    r.join("b", [1])  # b claims and supplies it now
    r.run_until(lambda: r.standing(1))
    r.run(50)
    assert r.enabled(1) and not r.inputs.kept and r.claims.holder(1) == "b"


def test_keep_others_stops_the_lost_clients_own_motion_as_stop_disable() -> None:
    r = moving_rig("keep_others")  # a's own motion
    r.gone("a")
    r.run_until(lambda: r.faults)
    assert r.faults == [(1, ZNC_CLIENT_LOST)]
    r.run_until(lambda: r.standing(1))
    r.run(2)
    assert not r.enabled(1)


@pytest.mark.parametrize("reaction", ["stop_disable", "stop", "keep_others"])
def test_a_lost_commanders_motion_on_another_clients_axis_stops_with_0x8F01(reaction: str) -> None:
    """'b' holds and supplies axis 1, 'a' (no claim) commanded its motion and is lost: the axis stops
    with 0x8F01 so every client sees why; b's PLCTONC stays, the axis stays enabled."""
    r = Rig([reaction])
    r.join("b", [1])
    r.join("a")
    r.run(5)
    r.ok("a", "MoveVelocity", 1, Velocity=100.0)
    r.run(100)
    r.gone("a")
    r.run(1)
    assert r.faults == [(1, ZNC_CLIENT_LOST)] and r.claims.holder(1) == "b"
    r.run_until(lambda: r.standing(1))
    r.run(10)
    assert r.enabled(1) and r.error(1) == ZNC_CLIENT_LOST


def test_a_lost_commanders_buffered_motion_stops_the_axis() -> None:
    r = Rig(["stop_disable"])
    r.join("b", [1])
    r.join("a")
    r.run(5)
    r.ok("b", "MoveAbsolute", 1, Position=30.0, Velocity=100.0)
    r.ok("a", "MoveAbsolute", 1, Position=60.0, Velocity=100.0, BufferMode=1)
    r.run(10)
    r.gone("a")
    r.run(1)
    assert r.faults == [(1, ZNC_CLIENT_LOST)]


def test_a_lost_commanders_superposition_stops_the_axis() -> None:
    r = Rig(["stop_disable"])
    r.join("b", [1])
    r.join("a")
    r.run(5)
    r.ok("b", "MoveVelocity", 1, Velocity=50.0)
    r.run(100)
    r.ok("a", "MoveSuperImposed", 1, Mode=4, Distance=10.0, VelocityDiff=20.0, Acceleration=100.0,
         Deceleration=100.0, Jerk=1000.0, Length=1000.0, VelocityProcess=50.0)
    r.run(5)
    assert r.core.commanders(0) == {"a", "b"}
    r.gone("a")
    r.run(1)
    assert r.faults == [(1, ZNC_CLIENT_LOST)]


def test_a_lost_clients_stop_is_left_alone() -> None:
    """An MC_Stop of the lost client is already a stop: nothing more (the lock stays until Reset)."""
    r = Rig(["stop_disable"])
    r.join("b", [1])
    r.join("a")
    r.run(5)
    r.ok("b", "MoveVelocity", 1, Velocity=50.0)
    r.run(100)
    r.ok("a", "Stop", 1)
    r.run(2)
    r.gone("a")
    r.run(2)
    assert r.faults == [] and r.error(1) == 0


def test_a_lost_client_that_commanded_nothing_changes_nothing() -> None:
    r = Rig(["stop_disable"])
    r.join("b", [1])
    r.join("a")
    r.run(5)
    r.ok("b", "MoveVelocity", 1, Velocity=50.0)
    r.run(100)
    r.gone("a")
    r.run(10)
    assert r.faults == [] and abs(r.velo(1) - 50.0) < 1e-6


# ---- the NC's own stall -------------------------------------------------------------------------
def test_nc_stall_stops_moving_axes_with_its_own_code_and_blames_no_client() -> None:
    r = Rig(["stop_disable", "stop_disable"])
    r.join("a", [1, 2])
    r.run(5)
    r.ok("a", "MoveVelocity", 1, Velocity=100.0)
    r.run(50)
    # frozen 0.8 s: the cycle thread's first run after it (app.NcServer._tick) does this
    stall_start = r.now
    r.core.cycle += 800  # (NC time jumps; the core is not stepped meanwhile)
    r.claims.grace(r.now, since=stall_start)
    assert r.inputs.nc_stalled(0.8) == [(1, ZNC_NC_STALLED)]
    r.h.client_gone("a", r.now + 0.004)  # its zenoh dropped the link to the frozen NC ...
    r.run(3)
    r.h.client_alive("a")                # ... and reconnected
    r.run(600)
    assert r.error(1) == ZNC_NC_STALLED and r.error(2) == 0
    assert r.claims.holder(1) == "a" and r.enabled(1) and r.enabled(2)
    assert [f for f in r.faults if f[1] in (ZNC_CLIENT_LOST, ZNC_PLCTONC_TIMEOUT)] == []


def test_motion_commands_queued_across_a_stall_are_refused_with_0x4B0F() -> None:
    r = Rig(["stop_disable"])
    r.join("a", [1])
    r.run(5)
    key = r.keys.command_key("MoveVelocity", 1, "a")
    rep = msgpack.unpackb(r.h.handle_after_stall(key, make_request("MoveVelocity", 77, "a", Velocity=1.0), r.now),
                          strict_map_key=False)
    assert rep["error"] == 0x4B0F and rep["id"] == 77 and rep["cmd"] == "MoveVelocity" and "stalled" in rep["text"]
    assert r.core.queues[0].active is None
    # not cached: the same request later runs
    assert msgpack.unpackb(r.h.handle(key, make_request("MoveVelocity", 77, "a", Velocity=1.0), r.now),
                           strict_map_key=False)["error"] == 0
    # a stop, a claim, a malformed request: handled as usual
    for cmd, payload, code in (("Stop", make_request("Stop", 78, "a"), 0), ("Claim", make_request("Claim", 79, "a"), 0),
                               ("Stop", b"\xc1", 0x706)):
        rep = msgpack.unpackb(r.h.handle_after_stall(r.keys.command_key(cmd, 1, "a"), payload, r.now), strict_map_key=False)
        assert rep["error"] == code, rep


# ---- hand-over ----------------------------------------------------------------------------------
def test_hand_over_keeps_the_axis_enabled_and_moves_the_rights() -> None:
    r = Rig(["stop_disable"])
    r.join("a", [1])
    r.join("b")
    r.run(5)
    r.ok("a", "MoveVelocity", 1, Velocity=100.0)
    r.run(50)
    r.feeds["b"] = ([1], ENABLE_ALL)  # b publishes for the axis before (ignored: not its holder)
    assert r.ok("a", "HandOver", 1, To="b")["Value"] == "b"
    r.feeds["a"] = ([1], 0)  # a's frames (disabling) no longer count
    for _ in range(200):
        r.run(1)
        assert r.enabled(1) and r.error(1) == 0
    assert r.claims.holder(1) == "b" and abs(r.velo(1) - 100.0) < 1e-6
    # the holder's rights are b's now
    for cmd, args in (("Release", {}), ("SetOverride", {"Override": 50.0}), ("HandOver", {"To": "a"})):
        assert r.cmd("a", cmd, 1, **args)["error"] == 0x723, cmd
    r.ok("b", "SetOverride", 1, Override=50.0)
    r.feeds["b"] = ([1], 0)
    r.run(3)
    r.run_until(lambda: not r.enabled(1))


def test_hand_over_to_a_silent_client_faults_after_the_watchdog() -> None:
    r = Rig(["stop_disable"], watchdog=0.2)
    r.join("a", [1])
    r.join("b")
    r.run(5)
    t0 = r.now
    r.ok("a", "HandOver", 1, To="b")
    r.feeds.pop("a")
    r.run_until(lambda: r.faults)
    assert r.faults == [(1, ZNC_PLCTONC_TIMEOUT)]
    assert 0.2 < r.now - t0 < 0.2 + 5 * DT


def test_hand_over_refused() -> None:
    r = Rig(["stop_disable"])
    r.join("a", [1])
    r.join("b")
    assert r.cmd("b", "HandOver", 1, To="b")["error"] == 0x723   # b does not hold it
    assert r.cmd("a", "HandOver", 1, To="ghost")["error"] == 0x723  # no token
    assert r.cmd("a", "HandOver", 1, To="x y")["error"] == 0x706
    assert r.cmd("a", "HandOver", 1)["error"] == 0x706               # To is required
    assert r.claims.holder(1) == "a"
