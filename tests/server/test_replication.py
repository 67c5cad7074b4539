"""Hot-standby replication, cycle by cycle, with two cores in one process (no zenoh): the active NC's core
behind a CoreRecorder, followers replaying its logs; digests, snapshot joins, re-syncs, the handler's state."""
from __future__ import annotations

import pickle
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

from nc_schema import PLCTONC_DTYPE, CmdState, Keys, make_request, unpack
from nc_server.core import AxisConfig, AxisParams, NcCore
from nc_server.core.params import param_number
from nc_server.server.claims import ClaimTable
from nc_server.server.handler import CycleInputs, PendingReply, RequestHandler
from nc_server.server.replication import (FINGERPRINT, STAMP, CycleLog, Follower, HandlerRecorder, HandlerState,
                                          ReplayDrive, CoreRecorder, SoftwareMismatch, install_handler,
                                          loads_plain, merge_handler, snapshot, state_digest)
from nc_server.server import replication

KEYS = Keys("nc1")


class Active:
    """The active NC's pure part: core (recorded), handler, cycle inputs, as nc-server wires them."""

    def __init__(self) -> None:
        params = AxisParams()
        self.core = NcCore([AxisConfig(1, "X", params), AxisConfig(2, "Y", params)], cycle_time=0.001)
        self.rec = CoreRecorder(self.core)
        self.claims = ClaimTable([1, 2], 0.5)
        self.handler = RequestHandler(self.rec, self.claims, KEYS)
        self.inputs = CycleInputs(self.rec, self.claims)
        self.hrec = HandlerRecorder(self.handler)
        self.now = 0.0
        self.frames: list[tuple[str, Any]] = []

    def request(self, cmd: str, rid: int, axis: int = 1, client: str = "plc", **args: Any) -> dict[str, Any]:
        """One request the way the server's cycle thread runs it (motion commands in two phases)."""
        got = self.handler.prepare(KEYS.command_key(cmd, axis, client), make_request(cmd, rid, client=client, **args),
                                   self.now)
        if isinstance(got, PendingReply):
            self.rec.set_preparing(got.axis_id, True)
            got = self.handler.plan(got)
            if isinstance(got, PendingReply):
                packed = self.handler.activate(got)
                assert packed is not None
                got = packed
            self.rec.set_preparing(axis, False)
        assert isinstance(got, bytes)
        return dict(unpack(got))

    def supply(self, control: int, ids: tuple[int, ...] = (1, 2), client: str = "plc") -> None:
        recs = np.zeros(len(ids), dtype=PLCTONC_DTYPE)
        recs["ControlDWord"] = control
        recs["Override"] = 1_000_000
        self.frames = [(client, SimpleNamespace(arrival=self.now, axis_ids=np.array(ids, dtype=np.uint32),
                                                plctonc=recs))]

    def cycle(self, nc_time_ns: int | None = None) -> CycleLog:
        self.now += 0.001
        for _, f in self.frames:
            f.arrival = self.now  # (a PLC frame every cycle)
        self.inputs.apply(self.frames, self.now)
        self.rec.step(nc_time_ns)
        return self.rec.take(self.hrec.take())

    def snapshot(self) -> bytes:
        return snapshot(self.rec, self.hrec.full())


def follower(active: Active) -> tuple[Follower, list[str]]:
    reasons: list[str] = []
    f = Follower(on_resync=reasons.append, on_handler=merge_handler)
    f.load(active.snapshot())
    return f, reasons


def same(a: NcCore, b: Any) -> None:
    assert b.cycle == a.cycle
    assert b.nctoplc.tobytes() == a.nctoplc.tobytes()
    assert b.ncjobs.tobytes() == a.ncjobs.tobytes()


def test_a_follower_steps_with_the_active_core_cycle_by_cycle() -> None:
    act = Active()
    act.handler.client_alive("plc", 0.0)
    f0, reasons = follower(act)  # joins before anything happened
    assert isinstance(f0.core.drive, ReplayDrive)
    assert act.request("Claim", 1, 1)["error"] == 0 and act.request("Claim", 2, 2)["error"] == 0
    act.supply(7)
    late: Follower | None = None
    script: dict[int, tuple[str, int, dict[str, Any]]] = {
        3: ("MoveAbsolute", 1, {"Position": 40.0, "Velocity": 200.0, "Acceleration": 2000.0, "Deceleration": 2000.0,
                                "Jerk": 20000.0}),
        5: ("GearIn", 2, {"Master": 1, "RatioNumerator": 1, "RatioDenominator": 2}),
        150: ("MoveAbsolute", 1, {"Position": 10.0, "Velocity": 100.0, "BufferMode": 1}),  # buffered behind
        160: ("SetOverride", 1, {"Override": 50.0}),
        200: ("WriteParameter", 1, {"ParameterNumber": param_number("AxisVeloMax"), "Value": 5000.0}),
    }
    rid = 10
    cmd_nos: dict[str, int] = {}
    for k in range(1, 900):
        if k in script:
            cmd, axis, args = script[k]
            rid += 1
            r = act.request(cmd, rid, axis, **args)
            assert r["error"] == 0, r
            cmd_nos[f"{cmd}{k}"] = r.get("CmdNo", 0)
        log = act.cycle()
        assert f0.apply(log), reasons
        if k == 100:  # a second standby joins mid-move, from a snapshot of this cycle
            late, late_reasons = follower(act)
        elif late is not None:
            assert late.apply(log), late_reasons
        same(act.core, f0.core)
        assert state_digest(f0.core) == log.digest
    assert late is not None
    same(act.core, late.core)
    assert abs(float(act.core.nctoplc[0]["SetPos"]) - 10.0) < 1e-9  # both moves ran to their ends
    assert f0.resyncs == 1 and f0.diverged == 0 and not reasons and f0.lag == 0


def test_watchdog_faults_are_replayed() -> None:
    act = Active()
    act.handler.client_alive("plc", 0.0)
    assert act.request("Claim", 1, 1)["error"] == 0
    act.supply(7, ids=(1,))
    f, reasons = follower(act)
    act.request("MoveVelocity", 2, 1, Velocity=50.0, Acceleration=1000.0, Deceleration=1000.0, Jerk=10000.0)
    for _ in range(50):
        assert f.apply(act.cycle())
    act.frames = []  # the PLC stops sending: 0x8F02 after the watchdog timeout, the axis stops
    for _ in range(800):
        assert f.apply(act.cycle()), reasons
    assert int(act.core.nctoplc[0]["ErrorCode"]) != 0 and act.claims.holder(1) is None
    same(act.core, f.core)


def test_a_gap_or_a_different_digest_asks_for_a_snapshot() -> None:
    act = Active()
    act.handler.client_alive("plc", 0.0)
    act.request("Claim", 1, 1)
    act.supply(7, ids=(1,))
    f, reasons = follower(act)
    assert f.apply(act.cycle())
    act.cycle()  # lost on the way
    assert not f.apply(act.cycle()) and f.waiting and "follower is at" in reasons[-1]
    assert not f.apply(act.cycle())  # waiting: logs are skipped until a snapshot comes
    f.load(act.snapshot())
    log = act.cycle()
    log.digest ^= 1  # the active NC's state differs from the replay's
    assert not f.apply(log) and f.diverged == 1 and "digest" in reasons[-1]
    f.load(act.snapshot())
    act.request("MoveRelative", 2, 1, Distance=1.0, Velocity=10.0)
    for _ in range(30):
        assert f.apply(act.cycle())
    same(act.core, f.core)
    assert f.resyncs == 3


def test_a_log_older_than_the_snapshot_is_skipped() -> None:
    act = Active()
    old = act.cycle()
    f, reasons = follower(act)
    assert not f.apply(old) and not f.waiting and not reasons
    assert f.apply(act.cycle())


def test_after_a_takeover_a_repeated_request_gets_the_replicated_reply() -> None:
    act = Active()
    act.handler.client_alive("plc", 0.0)
    act.request("Claim", 1, 1)
    act.supply(7, ids=(1,))
    f, _ = follower(act)
    assert f.apply(act.cycle())
    first = act.request("MoveRelative", 77, 1, Distance=5.0, Velocity=100.0)
    assert first["error"] == 0 and first["CmdNo"] == 1
    for _ in range(20):
        assert f.apply(act.cycle())
    # the active NC is gone; the standby's handler starts from the replicated state
    assert isinstance(f.handler_state, HandlerState)
    claims = ClaimTable([1, 2], 0.5)
    h = RequestHandler(f.core, claims, KEYS)
    install_handler(h, f.handler_state)
    assert claims.holder(1) == "plc" and h.last_command[1][1] == "MoveRelative"
    again = unpack(h.handle(KEYS.command_key("MoveRelative", 1, "plc"),
                            make_request("MoveRelative", 77, client="plc", Distance=5.0, Velocity=100.0), 1.0))
    assert dict(again) == first and h.cache.hits == 1
    assert int(f.core.queues[0].newest) == first["CmdNo"]  # not executed a second time


def test_a_snapshot_keeps_the_cores_array_views() -> None:
    """The core keeps views (columns of one table, the job records' byte view); a snapshot keeps them views,
    else the follower's core would write one copy and read another."""
    act = Active()
    f, _ = follower(act)
    core = f.core
    assert np.shares_memory(core.sp_dw, core.sp_words) and np.shares_memory(core.axis_state, core.sp_words)
    assert isinstance(core.records._bytes, memoryview)
    assert np.shares_memory(np.frombuffer(core.records._bytes, dtype=np.uint8), core.ncjobs)


@pytest.mark.parametrize("bad", ["step", "nothing"])
def test_a_replay_that_does_not_fit_the_drive_tape_is_a_resync(bad: str) -> None:
    act = Active()
    f, reasons = follower(act)
    log = act.cycle()
    if bad == "step":
        log.drive = []  # the core's drive step finds nothing on the tape
    else:
        log.drive = log.drive + log.drive  # a call left over
    assert not f.apply(log) and f.waiting and reasons


def test_a_follower_that_took_over_is_followed_in_turn() -> None:
    """A standby that took over (its core from a snapshot, the real drives now) is followed by the next standby
    from a snapshot of its own: the snapshot of a snapshot keeps every array alias (the digests agree)."""
    from nc_server.drives.sim import SimDrive
    from nc_server.server.replication import RecordingDrive
    act = Active()
    act.handler.client_alive("plc", 0.0)
    f, _ = follower(act)
    act.request("Claim", 1, 1)
    act.supply(7, ids=(1,))
    for _ in range(3):
        assert f.apply(act.cycle())
    assert act.request("MoveAbsolute", 5, 1, Position=20.0, Velocity=50.0)["error"] == 0
    for _ in range(50):
        assert f.apply(act.cycle())
    core = f.core
    core.drive = RecordingDrive(SimDrive(core.params, core.cycle_time))  # the takeover: real drives
    rec = CoreRecorder(core)
    rec.attach_drive(core.drive)
    reasons: list[str] = []
    g = Follower(on_resync=reasons.append, on_handler=merge_handler)
    g.load(snapshot(rec))
    for _ in range(100):
        rec.step()
        assert g.apply(rec.take()), reasons
    same(core, g.core)


def test_a_slave_of_a_master_on_another_nc_is_replicated() -> None:
    """The remote master's samples (coupling across NCs) are a recorded input: the standby's slave follows the
    same samples at the same cycles, digests equal, and a snapshot carries the master's sample history."""
    from nc_server.core import MasterSample
    from znc_testing.nc_core import cmd, powered

    master = powered(1)
    act = Active()
    act.core.configure_remote("nc1", [("ncm", 1)], 0.05)
    act.handler.client_alive("plc", 0.0)
    f0, reasons = follower(act)
    assert act.request("Claim", 1, 1)["error"] == 0 and act.request("Claim", 2, 2)["error"] == 0
    act.supply(7)
    t = 1_700_000_000_000_000_000
    late: Follower | None = None
    late_reasons: list[str] = []
    for k in range(1, 600):
        t += 1_000_000
        if k == 20:
            assert cmd(master, "MoveAbsolute", 1, Position=30.0, Velocity=150.0, Acceleration=1500.0,
                       Deceleration=1500.0, Jerk=15000.0)["error"] == 0
        master.step(t)
        r = master.nctoplc[0]
        if k % 3 != 0:  # (late and bunched, as over a network)
            act.rec.set_remote_samples([MasterSample("ncm", 1, master.cycle, master.nc_time_ns, float(r["SetPos"]),
                                                     float(r["SetVelo"]), float(r["SetAcc"]), float(r["SetJerk"]))])
        if k == 10:
            g = act.request("GearIn", 100, 2, Master=1, MasterNc="ncm", RatioNumerator=1, RatioDenominator=2)
            assert g["error"] == 0, g
        log = act.cycle(t + 300_000)
        assert f0.apply(log), reasons
        if k == 150:  # joins mid-coupling from a snapshot
            late, late_reasons = follower(act)
        elif late is not None:
            assert late.apply(log), late_reasons
        same(act.core, f0.core)
    assert late is not None
    same(act.core, late.core)
    slave = act.core.nctoplc[1]
    assert abs(float(slave["SetPos"]) - 15.0) < 0.05 and float(slave["SetVelo"]) == 0.0  # about half the master's 30
    assert f0.diverged == 0 and not reasons and not late_reasons


def test_a_touch_probe_armed_again_is_replayed() -> None:
    """MC_TouchProbe tells the drive of each arming (drive.arm_probe, on the tape); a re-arming with the same edge,
    the simulated signal and the latch are replayed cycle by cycle (default drive: cia402-sim)."""
    act = Active()
    act.handler.client_alive("plc", 0.0)
    f, reasons = follower(act)
    assert act.request("Claim", 1, 1)["error"] == 0
    rid = 10
    armings = 0
    for k in range(1, 40):
        if k in (3, 5):
            rid += 1
            assert act.request("TouchProbe", rid, 1, Edge=0)["error"] == 0
        elif k == 20:
            rid += 1
            assert act.request("SimProbeSignal", rid, 1, Level=True, Offset=0.0002)["error"] == 0
        log = act.cycle()
        armings += sum(c.name == "arm_probe" for c in log.drive)
        assert f.apply(log), reasons
        same(act.core, f.core)
    assert armings == 2
    assert int(act.core.ncjobs[0]["ProbeCounter"]) == 1 and int(act.core.ncjobs[0]["ProbeState"]) == int(CmdState.DONE)
    assert f.diverged == 0 and not reasons


def test_a_drive_state_unchanged_by_a_call_is_logged_once() -> None:
    # the state after each drive call of a cycle: an array the call left as it was is the object of the call before
    # (pickled once); one it changed, in place or not, is a copy of its new values; none is the drive's own object
    from nc_server.server.replication import DRIVE_STATE, RecordingDrive

    class Drive:
        def __init__(self) -> None:
            for k, s in enumerate(DRIVE_STATE):
                setattr(self, s, np.full(4, float(k)) if s != "faulty" else False)
            self.act_pos[:] = [1.0, np.nan, -0.0, 2.0]

        def step(self) -> None:
            pass

        def terminal_status(self) -> None:
            self.act_pos[1] = 5.0  # (in place)

        def torque_fields(self) -> None:
            self.act_velo = self.act_velo + 1.0  # (a new array)

        def probe_input(self) -> np.ndarray:
            return np.zeros(4, dtype=bool)

    inner = Drive()
    rd = RecordingDrive(inner)
    rd.step()
    rd.probe_input()
    rd.terminal_status()
    rd.torque_fields()
    t = rd.tape
    assert all(a is b for a, b in zip(t[0].state, t[1].state))  # (NaN and -0.0 compared by their bytes)
    pos, velo = DRIVE_STATE.index("act_pos"), DRIVE_STATE.index("act_velo")
    assert t[2].state[pos] is not t[1].state[pos] and t[2].state[pos][1] == 5.0 and np.isnan(t[1].state[pos][1])
    assert t[3].state[velo] is not t[2].state[velo] and t[3].state[velo][0] == 2.0 and t[2].state[velo][0] == 1.0
    assert all(x is not getattr(inner, s) for c in t for s, x in zip(DRIVE_STATE, c.state) if isinstance(x, np.ndarray))
    back = pickle.loads(pickle.dumps(t))
    for a, b in zip(t, back):
        for x, y in zip(a.state, b.state):
            assert np.array_equal(x, y, equal_nan=True) if isinstance(x, np.ndarray) else x == y


def test_a_replay_drive_sets_only_what_a_call_changed_and_never_the_logs_objects() -> None:
    # the log shares the unchanged values of consecutive calls (one object): the replay drive sets those once per
    # tape; what it sets are copies (the log's objects never become the drive's); a new tape sets everything
    from nc_server.server.replication import DRIVE_STATE, DriveCall

    base = tuple(np.full(3, float(k)) if s != "faulty" else False for k, s in enumerate(DRIVE_STATE))
    pos = DRIVE_STATE.index("act_pos")
    moved = tuple(np.array([9.0, 9.0, 9.0]) if k == pos else v for k, v in enumerate(base))
    rd = ReplayDrive(base, np.zeros(3, dtype=bool), 0.001)
    rd.feed([DriveCall("step", None, base), DriveCall("terminal_status", None, base),
             DriveCall("torque_fields", None, moved)])
    rd.step()
    first = {s: getattr(rd, s) for s in DRIVE_STATE}
    assert all(first[s] is not v for s, v in zip(DRIVE_STATE, base) if isinstance(v, np.ndarray))
    rd.terminal_status()
    assert all(getattr(rd, s) is first[s] for s in DRIVE_STATE)  # (the same values: not set again)
    rd.torque_fields()
    assert rd.act_pos is not first["act_pos"] and rd.act_pos is not moved[pos] and rd.act_pos[0] == 9.0
    assert first["act_pos"][0] == 0.0  # (the earlier object, kept by the core as prev_act_pos, untouched)
    assert rd.pending() == 0
    rd.feed([DriveCall("step", None, base)])
    rd.step()
    assert all(getattr(rd, s) is not first[s] for s, v in zip(DRIVE_STATE, base) if isinstance(v, np.ndarray))


def _unpickled() -> None:
    raise AssertionError("a snapshot of other NC software was unpickled")


class _Trap:
    def __reduce__(self) -> tuple[Any, ...]:
        return (_unpickled, ())


@pytest.mark.parametrize("peer", ["ab" * 32, ""])
def test_a_snapshot_of_other_nc_software_is_refused_before_it_is_unpickled(peer: str) -> None:
    """A pair runs one NC software: a snapshot stamped with another fingerprint (or none: a release before the
    stamp) is refused with both fingerprints, and nothing of it is unpickled (its pickle would raise)."""
    act = Active()
    good = act.snapshot()
    assert good.startswith(STAMP) and len(FINGERPRINT) == 64
    trap = pickle.dumps((NcCore, pickle.dumps(_Trap())))
    with pytest.raises(AssertionError):  # (the trap works when it is loaded)
        pickle.loads(pickle.loads(trap)[1])
    data = (b"zncR" + bytes.fromhex(peer) if peer else b"") + trap
    f = Follower()
    with pytest.raises(SoftwareMismatch) as exc:
        f.load(data)
    assert FINGERPRINT[:12] in str(exc.value) and (peer[:12] or "unstamped") in str(exc.value)
    assert exc.value.theirs == peer and f.waiting and f.core is None and f.resyncs == 0
    # the same snapshot body behind this software's stamp is loaded (and this one springs the trap)
    f.load(good)
    assert not f.waiting and f.core.cycle == act.core.cycle
    with pytest.raises(AssertionError):
        Follower().load(STAMP + data[len(data) - len(trap):])


def test_the_fingerprint_reads_crlf_as_lf_and_never_fails(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A Windows checkout (CRLF) pairs with a Linux one; an install without sources gets a fingerprint, no crash at
    import: a module's .pyc beside it stands for its missing .py (never __pycache__'s), unreadable files and a listing
    that fails fall back to the version."""
    lf, crlf = tmp_path / "lf.py", tmp_path / "crlf.py"
    lf.write_bytes(b"a = 1\nb = 2\n")
    crlf.write_bytes(b"a = 1\r\nb = 2\r\n")
    fps = []
    for p in (lf, crlf, tmp_path / "missing.py"):
        monkeypatch.setattr(replication, "_fingerprint_files", lambda p=p: [("x/m.py", p)])
        fps.append(replication._fingerprint())
    assert fps[0] == fps[1] != fps[2]

    def broken() -> list[tuple[str, Path]]:
        raise FileNotFoundError("no sources")
    monkeypatch.setattr(replication, "_fingerprint_files", broken)
    assert len(replication._fingerprint()) == 64
    pkg = tmp_path / "pkg"
    (pkg / "__pycache__").mkdir(parents=True)
    for n in ("a.py", "b.pyc", "a.pyc", "__pycache__/a.cpython-311.pyc", "__pycache__/c.cpython-311.pyc"):
        (pkg / n).write_bytes(b"")
    assert [p.name for p in replication._modules(pkg)] == ["a.py", "b.pyc"]


def test_a_bounded_plain_unpickle_does_not_allocate_what_a_pickle_claims() -> None:
    """A 12-byte pickle of a BINBYTES8 claiming 8 GiB: refused before anything is allocated; builtins only."""
    bomb = b"\x80\x05\x8e" + (8 << 30).to_bytes(8, "little") + b"x"
    with pytest.raises(ValueError, match="bytes8"):
        loads_plain(bomb, bounded=True)
    assert loads_plain(pickle.dumps([(1, 2, b"x")]), bounded=True) == [(1, 2, b"x")]
    with pytest.raises(pickle.UnpicklingError):
        loads_plain(pickle.dumps(_Trap()), bounded=True)
