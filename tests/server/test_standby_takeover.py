"""The hot standby's takeover and role changes in one process (no zenoh; docs/standby.md): what reaches the drives
at a takeover, the epoch of a retake after a demotion, the confirmation of a new epoch by the drive hosts, the
declarations' failures, the status read from another thread, the logs of a lower epoch."""
from __future__ import annotations

import logging
import pickle
import time
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

import nc_server.core  # noqa: F401  (before nc_server.drives: circular import otherwise)
from nc_server.drives.sim import SimDrive
from nc_server.server.config import Redundancy
from nc_server.server.replication import FINGERPRINT, STAMP, RecordingDrive, stamp
from nc_server.server.standby import START_GRACE_S, HotStandby

from test_replication import Active  # noqa: E402 (tests/server on sys.path)
from znc_testing.fake_zenoh import FakeSub

DT = 0.001  # (Active's cycle)
TAKEOVER = 15


class FakeLink:
    """What the standby sees of a remote drive link (drive_links): the epochs, the mute flag."""

    def __init__(self) -> None:
        self.epoch = 0
        self.host_epoch = 0
        self.input_epoch = 0
        self.received = 0
        self.takeover_limit_ms = 0.0
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


def active(hs: HotStandby, epoch: int) -> None:
    hs.role, hs.epoch, hs.highest, hs.synced_once = "active", epoch, epoch, True
    hs.follower.waiting = False


def test_a_demoted_nc_retakes_only_after_the_grace_and_with_its_own_epoch() -> None:
    # A froze past its standby's limit; B took over; A resumed, demoted itself and sees neither B's token nor its
    # logs (its session reconnects slowly, or the link B->A is cut): with a new epoch of the same count as B's it
    # could win the tie and the drive hosts would follow its second-old state
    act, hs, drive = pair()
    e = 5 << 16 | 7
    active(hs, e)
    hs.peer_in_step = True
    hs._peer_limits["a"] = (0.030, time.monotonic())
    assert hs.after_stall(0.5)
    assert hs.role == "standby" and not hs.synced_once and hs._grace >= START_GRACE_S
    t = time.monotonic()
    hs._started = hs._last_log = t
    assert not hs._lost(t + 0.2) and not hs._lost(t + START_GRACE_S - 0.01)
    assert hs._lost(t + START_GRACE_S + 0.01)
    hs._become_active(t + START_GRACE_S + 0.01)
    assert hs.role == "active" and hs.epoch == e  # its own epoch: the hosts take it only if nobody took over
    # B had taken over (count 6): the hosts refuse A's outputs and their inputs show B's epoch: A steps down
    drive.link.host_epoch = drive.link.input_epoch = 6 << 16 | 1
    assert hs.before_cycle(time.monotonic())
    assert hs.role == "standby"


def test_an_active_nc_whose_epoch_no_drive_host_confirms_steps_down() -> None:
    act, hs, drive = pair()
    hs.synced_once, hs.follower.waiting = True, False
    hs._become_active(time.monotonic(), first=True)
    e, lk = hs.epoch, drive.link
    lk.input_epoch = 1  # (inputs of an older epoch: the hosts have not taken this NC's outputs yet)
    assert not hs.before_cycle(time.monotonic())
    limit = hs._confirm_cycles()
    assert limit >= 1000  # (LIMIT_CAP_S at 1 ms cycles: a loaded machine delays the round trip)
    for _ in range(limit):
        lk.received += 1
        assert not hs.before_cycle(time.monotonic())
    for _ in range(10):  # no new inputs: nothing to judge
        assert not hs.before_cycle(time.monotonic())
    lk.received += 1
    assert hs.before_cycle(time.monotonic()) and hs.role == "standby"
    # the same, confirmed in time: active for good
    act, hs, drive = pair()
    hs.synced_once, hs.follower.waiting = True, False
    hs._become_active(time.monotonic(), first=True)
    lk = drive.link
    for i in range(3 * limit):
        lk.received += 1
        lk.input_epoch = hs.epoch if i >= 3 else 0
        assert not hs.before_cycle(time.monotonic())
    assert hs.role == "active" and hs._unconfirmed is None


def test_the_status_read_by_another_thread_only_reads() -> None:
    # status() runs in the I/O thread too (the stats): the detector's gaps and the peers' statuses are the cycle
    # thread's (a deque changed while iterated: RuntimeError in the cycle thread, the end of its loop)
    act, hs, drive = pair()

    def boom(*_: Any) -> Any:
        raise AssertionError("touched outside the cycle thread")

    hs.before_cycle(time.monotonic())  # (the cycle thread computes the limit)
    published = hs._limit
    hs.detector.limit = boom  # type: ignore[method-assign]
    hs._status_sub = SimpleNamespace(try_recv=boom)
    st = hs.status()
    assert st["takeover_limit_cycles"] == published
    hs.role = "active"
    assert hs.status()["role"] == "active"


def test_failed_declarations_of_a_takeover_are_tried_again_while_the_nc_drives() -> None:
    events: list[tuple[str, float]] = []
    act, hs, drive = pair(events)
    moving(act)
    hs.synced_once, hs.follower.waiting = True, False
    fails = [RuntimeError("zenoh: declare failed"), RuntimeError("again")]
    unserved: list[int] = []

    def serve() -> None:
        if fails:
            raise fails.pop(0)
        events.append(("serve", 0.0))

    hs.srv.transport.serve = serve
    hs.srv.transport.unserve = lambda: unserved.append(1)
    events.clear()
    now = time.monotonic()
    hs._last_log = now - 0.005
    hs._become_active(now)
    for _ in range(3):  # the cycle goes on (no exception into the cycle thread); the third try succeeds
        act.rec.step()
        hs.after_step()
    assert hs.role == "active" and not hs._serve_pending and len(unserved) == 2
    assert [e for e, _ in events].count("serve") == 1
    assert [e for e, _ in events][-1] == "serve" and len([e for e, _ in events if e == "out"]) == 3
    assert hs.takeover_s > 0


def sample(epoch: int, cycle: int) -> bytes:
    lg = SimpleNamespace(epoch=epoch, cycle=cycle)
    return pickle.dumps([(epoch, cycle, pickle.dumps(lg))])


def test_logs_of_a_lower_epoch_do_not_reset_the_silence() -> None:
    # a zombie NC of an older epoch still sends logs: the standby must still judge the active NC's silence
    act, hs, drive = pair()
    hs.highest = 6 << 16
    hs.synced_once, hs.follower.waiting = True, False
    sub = FakeSub()
    hs._log_sub = sub
    hs.detector.restart(0.0)
    sub.put(sample(5 << 16, 10_000))
    hs._take_logs(1.0)
    assert hs.detector.last == 0.0 and hs.stale_logs == 1
    # one of the followed epoch: a sign of life
    hs.follower.apply = lambda lg: True  # type: ignore[method-assign]
    hs._declare_standby = lambda on: None  # type: ignore[method-assign]
    sub.put(sample(6 << 16, 10**9))
    hs._take_logs(1.5)
    assert hs.detector.last == 1.5


def test_the_silence_judged_is_capped_by_the_lease_like_the_published_limit() -> None:
    # a lease of 200 ms: the published limit is at most 200 ms (the active NC's tokens go then); the detector must
    # not wait longer than that (it waited up to LIMIT_CAP_S, 1 s, after long log gaps)
    act, hs, drive = pair()
    hs2 = HotStandby(SimpleNamespace(**{**vars(hs.srv), "config": SimpleNamespace(
        name="nc1", cycle_time=DT, zenoh=SimpleNamespace(lease_ms=200))}),
        Redundancy(True, "standby", TAKEOVER, 10.0, "b"))  # type: ignore[arg-type]
    d = hs2.detector
    d.restart(-20.0)
    d.log(-10.0)
    d.log(-9.4)  # a 600 ms gap 9.4 s ago: the limit would be 1 s
    d.log(0.0)
    d.silent(0.0)
    assert hs2._limit_cycles(0.0) == 200
    assert not d.silent(0.001 * 150) and not d.silent(0.001 * 151)
    d.silent(0.208)  # (a late cycle of the standby itself defers the judgement once)
    assert d.silent(0.209)


class TokenSub:
    """Liveliness events of ``nc/<nc>/ha/active/<node>`` as the standby takes them."""

    def __init__(self, *events: tuple[str, bool]) -> None:
        import zenoh
        self.queue = [SimpleNamespace(key_expr=f"nc/nc1/ha/active/{node}",
                                      kind=zenoh.SampleKind.PUT if up else zenoh.SampleKind.DELETE)
                      for node, up in events]

    def try_recv(self) -> Any:
        return self.queue.pop(0) if self.queue else None


def test_a_token_that_went_and_came_back_is_no_takeover() -> None:
    # the router dropped the active NC's session in a long stall and it came back: the NC lives (found by the compose
    # scenario: a latched "token gone" took over from a live NC as soon as the standby was in step)
    act, hs, drive = pair()
    hs.synced_once, hs.follower.waiting = True, False
    hs.detector.restart(time.monotonic())
    hs._standby_sub = TokenSub()
    hs._active_sub = TokenSub(("a", False), ("a", True))
    hs._take_tokens()
    assert hs.active_token_seen and not hs._lost(time.monotonic())
    # gone for good: a takeover at once
    hs._active_sub = TokenSub(("a", False))
    hs._take_tokens()
    assert hs._lost(time.monotonic()) and hs._lost_why == "its token went"


I1, I2, I3, OWN = "00000000000000a1", "00000000000000a2", "00000000000000a3", "00000000000000ff"


class FakeDecl:
    def __init__(self, session: FakeSession, kind: str, key: str) -> None:
        self.session, self.kind, self.key = session, kind, key
        session.log.append(("declare", kind, key))

    def undeclare(self) -> None:
        self.session.log.append(("undeclare", self.kind, self.key))


class FakeSession:
    """Records the declarations and undeclarations of a zenoh session (liveliness tokens, queryables,
    publishers)."""

    def __init__(self) -> None:
        self.log: list[tuple[str, str, str]] = []
        self.fail_publishers = 0

    def liveliness(self) -> FakeSession:
        return self

    def declare_token(self, key: str) -> FakeDecl:
        return FakeDecl(self, "token", key)

    def declare_queryable(self, key: str, *a: Any, **k: Any) -> FakeDecl:
        return FakeDecl(self, "queryable", key)

    def declare_publisher(self, key: str, *a: Any, **k: Any) -> FakeDecl:
        if self.fail_publishers:
            self.fail_publishers -= 1
            raise RuntimeError("zenoh: declare failed")
        return FakeDecl(self, "publisher", key)

    def held(self, key: str) -> list[int]:
        """How many declarations of the token ``key`` this session held after each of its events."""
        n, out = 0, []
        for op, kind, k in self.log:
            if kind == "token" and k == key:
                n += 1 if op == "declare" else -1
            out.append(n)
        return out


def served_pair() -> tuple[Active, HotStandby, FakeSession, Any]:
    """pair() with a transport that declares like the real one (Transport.serve/unserve) on a FakeSession."""
    from nc_schema import Keys
    from nc_server.server.replication import HandlerState
    from nc_server.server.transport import Transport

    act, hs, drive = pair()
    fs = FakeSession()
    t = SimpleNamespace(session=fs, keys=Keys("nc1"), instance=OWN, queryable=None, token=None,
                        instance_token=None, stats_pub=None, claims_pub=None, queries=[])
    t.serve = lambda: Transport.serve(t)  # type: ignore[arg-type]
    t.unserve = lambda: Transport.unserve(t)  # type: ignore[arg-type]
    hs.srv.transport = t
    hs.srv.became_standby = t.unserve  # (NcServer.became_standby: transport.unserve())
    hs._session = fs  # type: ignore[assignment]
    hs.follower.handler_state = HandlerState(instance=I1)  # (the active NC's instance id, from its snapshot)
    return act, hs, fs, t


def in_step(hs: HotStandby) -> None:
    hs.synced_once, hs.follower.waiting = True, False
    hs._declare_standby(True)  # (what a log applied in step does)


def test_a_standby_in_step_holds_the_nc_tokens_through_its_takeover() -> None:
    # issue 21 (compose scenario): at a kill -9 of the active NC, nc/<nc>/alive went until the standby's
    # declarations: nc_link saw "NC gone" and the PLC runtime ended every block with 0x4B0F. A standby in step holds
    # the NC's token and the active NC's instance token itself (zenoh: the key lives while any session holds it)
    act, hs, fs, t = served_pair()
    moving(act)
    in_step(hs)
    alive, inst = "nc/nc1/alive", "nc/nc1/alive/" + I1
    assert fs.held(alive)[-1] == 1 and fs.held(inst)[-1] == 1
    assert "nc/nc1/alive/" + OWN not in [k for _, _, k in fs.log]  # (the standby's own id is no NC the clients see)
    for _ in range(3):  # more logs in step: nothing declared again
        hs._declare_standby(True)
    n = len(fs.log)
    now = time.monotonic()
    hs._last_log = now - 0.005
    hs._become_active(now)
    act.rec.step()
    hs.after_step()
    assert hs.role == "active" and not hs._serve_pending
    # held all along (never 0 after the first declaration), one declaration each: the transport took them over
    assert min(fs.held(alive)[fs.held(alive).index(1):]) == 1 and fs.held(alive)[-1] == 1
    assert min(fs.held(inst)[fs.held(inst).index(1):]) == 1 and fs.held(inst)[-1] == 1
    assert [e for e in fs.log[n:] if e[1] == "token" and e[2].startswith(alive)] == []
    assert t.token is not None and t.instance_token is not None and t.instance == I1
    assert hs._nc_token is None and hs._nc_inst_token is None
    assert ("declare", "queryable", "nc/nc1/**/cmd/*/*") in fs.log[n:]
    # replaced (demoted): the transport's go; out of step it holds none
    hs._become_standby(time.monotonic(), "test")
    assert fs.held(alive)[-1] == 0 and fs.held(inst)[-1] == 0
    assert hs._nc_token is None and t.token is None


def test_a_standby_out_of_step_holds_no_nc_token() -> None:
    # waiting for a snapshot it cannot take over: clients must see "no NC" if the active NC goes then
    act, hs, fs, t = served_pair()
    in_step(hs)
    assert fs.held("nc/nc1/alive")[-1] == 1
    hs._resync("test")
    assert fs.held("nc/nc1/alive")[-1] == 0 and fs.held("nc/nc1/alive/" + I1)[-1] == 0
    assert fs.held("nc/nc1/ha/standby/b")[-1] == 0
    # in step again, from a snapshot of another instance (both NCs had gone): that instance's token
    from nc_server.server.replication import HandlerState
    hs.follower.handler_state = HandlerState(instance=I2)
    in_step(hs)
    assert fs.held("nc/nc1/alive")[-1] == 1 and fs.held("nc/nc1/alive/" + I2)[-1] == 1
    hs.follower.handler_state = HandlerState(instance=I3)
    hs._declare_standby(True)
    assert fs.held("nc/nc1/alive/" + I2)[-1] == 0 and fs.held("nc/nc1/alive/" + I3)[-1] == 1
    assert fs.held("nc/nc1/alive")[-1] == 1
    hs.close()
    assert fs.held("nc/nc1/alive")[-1] == 0 and fs.held("nc/nc1/alive/" + I3)[-1] == 0


def test_failed_declarations_of_a_takeover_keep_the_nc_tokens() -> None:
    # transport.serve() fails after some declarations: unserve() undoes them, but the NC's tokens stay held
    act, hs, fs, t = served_pair()
    moving(act)
    in_step(hs)
    fs.fail_publishers = 1
    now = time.monotonic()
    hs._last_log = now - 0.005
    hs._become_active(now)
    act.rec.step()
    hs.after_step()
    assert hs._serve_pending and t.queryable is None
    assert fs.held("nc/nc1/alive")[-1] == 1 and fs.held("nc/nc1/alive/" + I1)[-1] == 1
    act.rec.step()
    hs.after_step()
    assert not hs._serve_pending and t.token is not None
    for key in ("nc/nc1/alive", "nc/nc1/alive/" + I1):
        h = fs.held(key)
        assert min(h[h.index(1):]) == 1 and h[-1] == 1 and h.count(1) == len(h) - h.index(1)


def frame(epoch: int, cycle: int) -> bytes:
    from nc_schema import NCTOPLC_DTYPE, encode_frame
    rec = np.zeros(1, dtype=NCTOPLC_DTYPE)
    rec["AxisId"] = 1
    return encode_frame(cycle, cycle * 1_000_000, rec, epoch=epoch)


def frames_pair() -> tuple[Active, HotStandby, FakeSub, int]:
    """A standby in step following epoch ``e``, its gap history empty and past the warm-up (the limit is
    ``takeover_cycles``), its last log at t = 0; the frames' subscriber a FakeSub."""
    act, hs, drive = pair()
    e = 6 << 16
    hs.highest = e
    hs.synced_once, hs.follower.waiting = True, False
    frames = FakeSub()
    hs._frame_sub = frames
    hs.detector.restart(-10.0)  # (in step 10 s ago: past the warm-up, whose floor would be the limit)
    hs.detector.log(0.0)
    hs.detector.gaps.clear()  # (that first gap of 10 s would raise the limit to the cap)
    hs._last_log = 0.0
    return act, hs, frames, e


def take(hs: HotStandby, frames: FakeSub, t: float, data: bytes) -> bool:
    """A standby cycle at ``t`` (its own cycles on time) with a frame: lost?"""
    frames.put(data)
    hs._take_frame(t)
    hs.detector.silent(t - 0.001)
    return hs._lost(t)


def test_late_logs_of_an_active_nc_whose_frames_go_on_are_no_loss_up_to_the_cap() -> None:
    # bench/many_clients.py --standby: the logs (8 cycles a sample, every cycle) were 155-395 ms late through zenoh and
    # the router while the active NC ran on; the standby took over from its last log, behind the frames the clients
    # had seen: their Cycle went back (an NC restart for them). The active NC's frames going on are a sign of life.
    # Not for ever (review): the logs go CongestionControl.DROP, under load all may drop while the frames get through;
    # a standby forgiving that without a bound stays "in step" on a state seconds old (a later kill: a takeover from
    # it, a SetPos jump, the Cycle going back). Beyond the detector's cap it resyncs: out of step, no standby
    act, hs, frames, e = frames_pair()
    c0 = int(hs.core.cycle)
    lim, cap = hs.detector.limit(0.0), hs.detector.cap
    assert lim < 0.1 < cap
    assert not take(hs, frames, 0.0, frame(e, c0 + 1))  # (the first frame of an epoch: no progress seen yet)
    t, k = 0.0, 0
    while (k + 1) * 0.01 < cap - 0.005:  # the logs stop; the frames go on (every 10 ms of NC time)
        k += 1
        t = k * 0.01
        assert not take(hs, frames, t, frame(e, c0 + 10 * k)), (t, lim)
    assert t > 3 * lim and hs.frames_alive == 1 and hs._forgiving
    assert hs.status()["lag_cycles"] == 10 * k  # (the frames' Cycle less the core's: the logs stopped)
    assert hs.status()["in_step"] and hs.follower.resyncs == 0
    k += 3
    assert not take(hs, frames, k * 0.01, frame(e, c0 + 10 * k))  # past the cap: out of step, no takeover
    assert hs.follower.waiting and not hs.status()["in_step"]
    assert not hs._forgiving and hs._frame_alive < -1e8
    # the active NC is killed now (its token goes): no standby in step, no takeover from a state 0.5 s old
    hs._token_gone = True
    assert not take(hs, frames, k * 0.01 + 0.01, frame(e, c0 + 10 * k + 10))


def test_the_frames_cycle_running_ahead_of_the_logs_is_bounded_too() -> None:
    # logs come, but ever further behind the frames (all the newer ones dropped): the frame Cycle less the core's
    # beyond the cap is a resync too
    act, hs, frames, e = frames_pair()
    c0 = int(hs.core.cycle)
    take(hs, frames, 0.0, frame(e, c0 + 1))
    assert not take(hs, frames, 0.02, frame(e, c0 + 100))  # forgiven: 20 ms without a log
    hs._last_log = 0.02  # (a log just came, of an old cycle: the core did not move)
    assert not take(hs, frames, 0.03, frame(e, c0 + int(hs.detector.cap / DT) + 50))
    assert hs.follower.waiting and not hs.status()["in_step"]


def test_a_frame_cycle_that_stands_still_is_no_sign_of_life() -> None:
    act, hs, frames, e = frames_pair()
    c0 = int(hs.core.cycle)
    lim = hs.detector.limit(0.0)
    take(hs, frames, 0.0, frame(e, c0 + 1))
    assert not take(hs, frames, 0.01, frame(e, c0 + 10))  # forgiven
    for k in range(2, 100):  # the frames repeat the same Cycle (the NC's cycle frozen, its publisher not)
        t = k * 0.01
        if take(hs, frames, t, frame(e, c0 + 10)):
            assert lim - 0.011 < t - 0.01 <= lim + 0.02, (t, lim)
            break
    else:
        raise AssertionError("the Cycle stood still, no log came: no takeover")


def test_frames_of_a_lower_epoch_are_no_sign_of_life() -> None:
    act, hs, frames, e = frames_pair()
    c0 = int(hs.core.cycle)
    lim = hs.detector.limit(0.0)
    take(hs, frames, 0.0, frame(e, c0 + 1))
    assert not take(hs, frames, 0.01, frame(e, c0 + 10))  # forgiven
    take(hs, frames, 0.02, frame(e - 1, 5000))
    for k in range(3, 100):  # a zombie of a lower epoch: its Cycle goes on
        t = k * 0.01
        if take(hs, frames, t, frame(e - 1, 5000 + 10 * k)):
            assert lim - 0.011 < t - 0.01 <= lim + 0.02, (t, lim)
            break
    else:
        raise AssertionError("only a zombie's frames came, no log: no takeover")


def test_frames_behind_the_logs_are_no_sign_of_life() -> None:
    # a burst of frames queued in a stall, older than the newest log applied: their Cycle goes up from one to the
    # next, but shows nothing the logs did not; counted as alive they put the takeover off past the published limit
    act, hs, frames, e = frames_pair()
    for _ in range(300):
        act.cycle()
    c = int(hs.core.cycle)
    assert c >= 300
    lim = hs.detector.limit(0.0)
    take(hs, frames, 0.0, frame(e, 1))
    for k in range(1, 100):
        t = k * 0.005
        if take(hs, frames, t, frame(e, min(c, 1 + 10 * k))):
            assert lim - 0.006 < t <= lim + 0.02, (t, lim)
            break
    else:
        raise AssertionError("no takeover")
    assert hs.frames_alive == 0


def test_the_takeover_figures_count_from_the_last_sign_of_life_the_catch_up_from_the_last_log() -> None:
    act, hs, drive = pair()
    hs.settings = Redundancy(True, "standby", TAKEOVER, 100.0, "b")
    moving(act)
    hs.synced_once, hs.follower.waiting = True, False
    now = time.monotonic()
    hs._last_log = now - 0.050
    hs._frame_alive = now - 0.020  # (a frame beyond the logs 20 ms ago)
    hs._forgiving = True
    hs._frame_epoch, hs._frame_cycle = 7, 1234
    hs._become_active(now)
    assert hs.catch_up == 50  # (the core continues from the last log's state)
    assert hs._lost_at == now - 0.020
    assert hs._frame_alive < -1e8 and not hs._forgiving and hs._frame_epoch == hs._frame_cycle == -1
    act.rec.step()
    hs.after_step()
    assert 0.020 <= hs.takeover_s < 0.5 and abs(hs.detect_s - 0.020) < 1e-9


class OpenSession(FakeSession):
    """A FakeSession open() can declare everything on."""

    def declare_subscriber(self, key: str, *a: Any, **k: Any) -> Any:
        FakeDecl(self, "subscriber", key)
        return FakeSub()

    def get(self, *a: Any, **k: Any) -> Any:
        return None


def test_the_frames_view_token_is_held_only_while_standby() -> None:
    # (review) the active NC held it too: its own publisher sent it the header view every 10 ms for nothing
    view = "nc/nc1/select/ha-b/10ms/none"
    for start in ("active", "standby"):
        act, hs, fs, t = served_pair()
        s2 = OpenSession()
        hs.settings = Redundancy(True, start, TAKEOVER, 10.0, "b")
        hs.open(s2)  # type: ignore[arg-type]
        assert ("subscriber", "nc/nc1/view/ha-b") in [(k, key) for _, k, key in s2.log]
        assert s2.held(view)[-1:] == ([0] if start == "active" else [1]), (start, s2.log)
        if start == "active":
            continue
        # a takeover: the token goes with the declarations after the first set-point; a demotion declares it again
        in_step(hs)
        hs._become_active(time.monotonic())
        assert s2.held(view)[-1] == 1
        act.rec.step()
        hs.after_step()
        assert hs.role == "active" and not hs._serve_pending and s2.held(view)[-1] == 0
        hs._become_standby(time.monotonic(), "test")
        assert s2.held(view)[-1] == 1
        hs.close()
        assert s2.held(view)[-1] == 0


def test_a_node_name_too_long_for_the_frames_view_is_a_config_error() -> None:
    from nc_server.server.config import NODE_MAX, ConfigError, _redundancy
    assert _redundancy({"redundancy": {"node": "n" * NODE_MAX}}).node == "n" * NODE_MAX
    with pytest.raises(ConfigError, match="ha-<node>"):
        _redundancy({"redundancy": {"node": "n" * (NODE_MAX + 1)}})


def test_only_the_logs_replayed_are_unpickled() -> None:
    # the active NC receives its own log samples (8 logs each, every cycle) and a standby in step the repeats: both are
    # judged by the (epoch, cycle) beside each pickled log; unpickling them all cost most of a 1 ms cycle
    act, hs, drive = pair()
    junk = b"not a pickle"
    hs.role, hs.epoch, hs.highest = "active", 6 << 16, 6 << 16
    sub = FakeSub()
    hs._log_sub = sub
    sub.put(stamp(pickle.dumps([(6 << 16, c, junk) for c in range(10, 18)])))  # its own: never unpickled
    hs._take_logs(1.0)
    assert hs.role == "active"
    demoted: list[str] = []
    hs._become_standby = lambda now, why: demoted.append(why)  # type: ignore[method-assign]
    sub.put(stamp(pickle.dumps([(7 << 16, 20, junk)])))  # a higher epoch's: demotes on its header alone
    hs._take_logs(1.1)
    assert demoted and hs.highest == 7 << 16
    # a standby in step at cycle 100: the repeats (cycle <= 100) are not unpickled, the next log is, and applied
    hs.role, hs.epoch = "standby", 0
    hs.synced_once, hs.follower.waiting = True, False
    hs.follower.core = SimpleNamespace(cycle=100)  # type: ignore[assignment]
    applied: list[int] = []
    hs.follower.apply = lambda lg: applied.append(lg.cycle) or False  # type: ignore[method-assign]
    sub.put(stamp(pickle.dumps([(7 << 16, c, junk) for c in range(94, 101)]
                               + [(7 << 16, 101, pickle.dumps(SimpleNamespace(epoch=7 << 16, cycle=101)))])))
    hs._take_logs(1.2)
    assert applied == [101] and hs.logs_in == 1
    # a log that is not what its header says is unusable (the rest of the sample too), nothing applied
    sub.put(stamp(pickle.dumps([(7 << 16, 102, pickle.dumps(SimpleNamespace(epoch=7 << 16, cycle=105))),
                                (7 << 16, 103, pickle.dumps(SimpleNamespace(epoch=7 << 16, cycle=103)))])))
    hs._take_logs(1.3)
    assert applied == [101]


def test_unusable_logs_are_counted_and_warned_at_most_every_5_s(caplog: pytest.LogCaptureFixture) -> None:
    # a peer of another release sends logs this release cannot read, 1000 a second: counted (ha status), nothing
    # applied, a warning every 5 s rather than one per sample
    act, hs, drive = pair()
    hs.role, hs.epoch, hs.highest = "standby", 0, 7 << 16
    hs.synced_once, hs.follower.waiting = True, False
    hs.follower.core = SimpleNamespace(cycle=100)  # type: ignore[assignment]
    applied: list[int] = []
    hs.follower.apply = lambda lg: applied.append(lg.cycle) or False  # type: ignore[method-assign]
    sub = FakeSub()
    hs._log_sub = sub
    with caplog.at_level(logging.WARNING, logger="nc_server"):
        for k in range(50):
            # (this software's stamp: a sample that is not a pickle, a log that is not one)
            sub.put(stamp(b"\x80\x05 a broken payload" if k % 2 else pickle.dumps([(7 << 16, 101 + k, b"junk")])))
            hs._take_logs(1.0 + k * 0.001)
        sub.put(stamp(pickle.dumps([(7 << 16, 200, b"junk")])))
        hs._take_logs(6.5)
    assert applied == [] and hs.unusable_logs == 51 and hs.status()["unusable_logs"] == 51
    assert len([r for r in caplog.records if "unusable ha log" in r.getMessage()]) == 2


def test_logs_of_other_nc_software_are_refused_unread_and_no_snapshot_is_asked(
        caplog: pytest.LogCaptureFixture) -> None:
    # a rolling upgrade: the active NC runs other NC software; its logs are never unpickled (their layout may differ:
    # a crash or a wrong state), their epochs still count, the refusal is one warning with both fingerprints and the
    # ha status says it; the standby never gets in step, so without an active NC it behaves as one that never did
    act, hs, drive = pair()
    other = "ab" * 32
    asked: list[float] = []
    hs._session = object()  # type: ignore[assignment]
    hs._ask_snapshot = asked.append  # type: ignore[method-assign]
    sub = FakeSub()
    hs._log_sub = sub
    boom = pickle.dumps(SimpleNamespace())[:-1] + b"\xff"  # (would raise if unpickled)
    t = time.monotonic()
    hs._started = hs._last_log = t
    hs.active_token_seen = True
    with caplog.at_level(logging.WARNING, logger="nc_server"):
        for k in range(40):
            body = pickle.dumps([(7 << 16, 100 + k, boom)])
            sub.put(b"zncR" + bytes.fromhex(other) + body if k >= 20 else body)  # (unstamped: a release before it)
            hs._take_logs(t + k * 0.001)
            hs._take_snapshot(t + 5.0 + k)  # (long past SNAPSHOT_RETRY_S: no snapshot of it is asked for)
    assert hs.highest == 7 << 16 and hs.logs_in == 0 and hs.unusable_logs == 0 and asked == []
    assert hs.follower.waiting and hs.follower.core is None and not hs.synced_once
    st = hs.status()
    assert not st["in_step"] and st["software"] == FINGERPRINT[:12]
    assert FINGERPRINT[:12] in st["refused"] and other[:12] in st["refused"]
    warned = [r.getMessage() for r in caplog.records if "same NC software" in r.getMessage()]
    assert len(warned) == 2 and other[:12] in warned[-1] and FINGERPRINT[:12] in warned[-1]  # (one per peer software)
    # the active NC's token goes: no takeover before START_GRACE_S after its last log, then one with its own state
    hs.active_token_seen = False
    last = t + 0.039
    assert not hs._lost(last + START_GRACE_S - 0.01)
    assert hs._lost(last + START_GRACE_S + 0.01)
    assert hs.follower.handler_state is None  # (nothing replicated to install)
    # an active NC of this software again (the peer upgraded): its logs are taken, a snapshot is asked for again
    sub.put(stamp(pickle.dumps([(7 << 16, 300, pickle.dumps(SimpleNamespace(epoch=7 << 16, cycle=300)))])))
    hs._take_logs(t + 60.0)
    hs._take_snapshot(t + 60.0)
    assert hs.logs_in == 1 and asked == [t + 60.0]


def test_a_standby_in_step_goes_out_of_step_on_logs_of_other_software() -> None:
    act, hs, drive = pair()
    hs.role, hs.epoch, hs.highest = "standby", 0, 7 << 16
    hs.synced_once, hs.follower.waiting = True, False
    hs.follower.core = SimpleNamespace(cycle=100)  # type: ignore[assignment]
    lost: list[str] = []
    hs.follower.on_resync = lost.append
    sub = FakeSub()
    hs._log_sub = sub
    sub.put(b"zncR" + bytes(32) + pickle.dumps([(7 << 16, 101, b"junk")]))
    hs._take_logs(1.0)
    assert hs.follower.waiting and lost and "000000000000" in lost[0] and hs.logs_in == 0
    assert not hs._lost(100.0)  # (out of step: never a takeover from its replicated state)


def test_a_foreign_active_of_a_higher_epoch_from_a_low_cycle_is_refused_not_taken_for_repeats(
        caplog: pytest.LogCaptureFixture) -> None:
    # the peer restarted with other software and took over (a higher epoch, its cycles from 10): all its cycles are
    # <= this in-step standby's 100; the stamp is checked before the repeat filter: out of step, refused, no token
    act, hs, drive = pair()
    hs.role, hs.epoch, hs.highest = "standby", 0, 6 << 16
    hs.synced_once, hs.follower.waiting = True, False
    hs.follower.core = SimpleNamespace(cycle=100)  # type: ignore[assignment]
    asked: list[float] = []
    hs._session = object()  # type: ignore[assignment]
    hs._ask_snapshot = asked.append  # type: ignore[method-assign]
    sub = FakeSub()
    hs._log_sub = sub
    with caplog.at_level(logging.WARNING, logger="nc_server"):
        for k in range(50):
            sub.put(b"zncR" + bytes.fromhex("ab" * 32) + pickle.dumps([(7 << 16, 10 + k, b"x")]))
            hs._take_logs(1.0 + k * 0.001)
    assert hs.follower.waiting and "abababababab" in hs.refused and hs.highest == 7 << 16
    assert not hs.status()["in_step"] and hs.logs_in == 0
    assert not hs._lost(1000.0)  # (a formerly in-step standby refused: never a takeover from its stale state)
    out = [r.getMessage() for r in caplog.records if "out of step" in r.getMessage()]
    assert len(out) == 1 and "no snapshot asked for" in out[0] and "asking" not in out[0]


def test_a_refusing_standby_that_takes_over_is_refused_no_more() -> None:
    act, hs, drive = pair()
    hs._log_sub = sub = FakeSub()
    sub.put(b"zncR" + bytes.fromhex("cd" * 32) + pickle.dumps([(7 << 16, 10, b"x")]))
    hs._take_logs(1.0)
    assert hs.refused and hs.status()["refused"]
    hs._become_active(time.monotonic())
    assert hs.role == "active" and hs.status()["refused"] == "" and hs._foreign == ""


@pytest.mark.parametrize("batch", [[(1, 1, 8 << 30)], [(True, 1, b"x")], [(1, 1.5, b"x")], [(1, 1, "x")],
                                   [(1, 1)], {"a": 1}, [(1, 1, b"")] * 65])
@pytest.mark.parametrize("foreign", [False, True])
def test_a_sample_whose_headers_are_not_int_int_bytes_is_unusable(batch: Any, foreign: bool) -> None:
    # (bytes(8 << 30) of a 30-byte sample allocated 8 GiB: nothing is converted)
    act, hs, drive = pair()
    hs.role, hs.highest = "standby", 1
    hs._log_sub = sub = FakeSub()
    sub.put((b"zncR" + bytes(32) if foreign else STAMP) + pickle.dumps(batch))
    hs._take_logs(1.0)
    assert hs.unusable_logs == 1 and hs.highest == 1 and not hs.refused
