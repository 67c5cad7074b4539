"""Requests run between cycles, in the time the cycle leaves (NcServer.idle / cycle), without zenoh."""
from __future__ import annotations

import errno
import threading
import time
from pathlib import Path
from typing import Callable

import msgpack
import pytest

from nc_server.core import NcCore
from nc_server.server import app as A
from nc_server.server import retain as R
from nc_server.server import transport as T
from nc_server.server.app import NcServer, query_reserve
from nc_server.server.config import load_config


class FakeQuery:
    """What the server uses of a zenoh query: key_expr, payload (``len``, ``to_bytes``), reply, drop."""

    def __init__(self, key: str, msg: dict, sent: list) -> None:
        self.key_expr = key
        self.payload = _Payload(msgpack.packb(msg))
        self.sent = sent
        self.dropped = False

    def reply(self, key: str, payload: bytes, **kw: object) -> None:
        assert not self.dropped and key == self.key_expr
        self.sent.append((payload, kw))

    def drop(self) -> None:
        self.dropped = True


class _Payload:
    def __init__(self, data: bytes) -> None:
        self.data = data

    def __len__(self) -> int:
        return len(self.data)

    def to_bytes(self) -> bytes:
        return self.data


@pytest.fixture
def server(tmp_path: Path):  # type: ignore[no-untyped-def]
    SENT.clear()
    conf = tmp_path / "nc.toml"
    conf.write_text('[nc]\nname = "nc1"\nrealtime = "off"\n[zenoh]\nlisten = ["tcp/127.0.0.1:9"]\n'
                    '[[axis]]\nAxisId = 1\n[[axis]]\nAxisId = 2\n')
    cfg = load_config(conf)  # (zenoh is never opened: cycle() and idle() are called directly)
    srv = NcServer(cfg, NcCore(list(cfg.axes), cfg.cycle_time))
    try:
        yield srv
    finally:
        srv.frames.close()


SENT: list = []


def _queue(srv: NcServer, n: int) -> None:
    for k in range(n):
        srv.transport.queries.append(FakeQuery("nc/nc1/axis/1/cmd/read/t", {"id": k, "client": "t", "cmd": "Info"}, SENT))


def _flush(srv: NcServer) -> None:
    """What the I/O thread does with the replies handed over (not started here): send them, or hold them
    (the retain file), and send the held ones whose commit settled."""
    while not srv.io.q.empty():
        for entry in srv.io.q.get_nowait():
            srv.io._reply(*entry)
    srv.io._release_held()


def _replies(srv: NcServer) -> int:
    _flush(srv)
    n = len(SENT)
    SENT.clear()
    return n


def test_a_request_that_would_not_fit_before_the_deadline_waits(server: NcServer,
                                                                monkeypatch: pytest.MonkeyPatch) -> None:
    # the wait limit is moved by hand below: a loaded machine's preemption between two calls must not do it
    monkeypatch.setattr(A, "QUERY_MAX_WAIT_NS", 10_000_000_000)
    monkeypatch.setattr(A, "QUERY_SPIN_WAIT_NS", 10**12)  # (the spin's use: its own test)
    # nor must the call's budget stop the forced one's call before it tries (and puts back) the next: that is the check
    monkeypatch.setattr(A, "QUERY_BUDGET_NS", 10**12)
    _queue(server, 1)
    _run_all(server)  # (a first request warms the path up: cold, it took longer than QUERY_BUDGET_NS)
    _replies(server)
    _queue(server, 3)
    server._reserve_ns = 400_000  # requests cost 0.4 ms lately
    soon = time.monotonic_ns() + 300_000
    server.idle(soon, after_work=False)  # a slice: 0.3 ms left, nothing fits
    assert len(server.transport.queries) == 3 and _replies(server) == 0
    server.idle(time.monotonic_ns() + 300_000, after_work=True)  # right after the work: still does not fit
    assert len(server.transport.queries) == 3 and _replies(server) == 0
    assert server._waiting_since is not None
    server._waiting_since -= A.QUERY_MAX_WAIT_NS + 1  # ... and it has waited that long by now:
    server.idle(time.monotonic_ns() + 300_000, after_work=False)  # not in a slice,
    assert len(server.transport.queries) == 3 and _replies(server) == 0
    server.idle(time.monotonic_ns() + 300_000, after_work=True)  # but right after the work, one runs anyway
    assert len(server.transport.queries) == 2 and _replies(server) == 1
    assert server._waiting_since is not None and time.monotonic_ns() - server._waiting_since < A.QUERY_MAX_WAIT_NS
    # plenty of time: the rest, in order (a slice stops after QUERY_BUDGET_NS: on a loaded machine one request
    # can take all of it, so slices until none is left, as the cycle loop's idle time gives them)
    for _ in range(10):
        server.idle(time.monotonic_ns() + 5_000_000_000, after_work=False)
        if not server.transport.queries:
            break
    assert len(server.transport.queries) == 0 and _replies(server) == 2
    assert server._waiting_since is None


def test_a_request_put_back_keeps_its_place(server: NcServer) -> None:
    _queue(server, 3)
    first = server.transport.queries[0]
    server._reserve_ns = 400_000
    server.idle(time.monotonic_ns() + 100_000, after_work=False)
    assert server.transport.queries[0] is first and len(server.transport.queries) == 3
    SENT.clear()
    _run_all(server)
    _flush(server)
    ids = [msgpack.unpackb(p, strict_map_key=False)["id"] for p, _ in SENT]
    assert ids == [0, 1, 2]


def test_the_cycle_runs_one_request_only_when_no_idle_call_ran(server: NcServer) -> None:
    _queue(server, 3)
    server.cycle(time.monotonic_ns())  # no idle call since the start (the work fills the period)
    assert len(server.transport.queries) == 2 and _replies(server) == 1
    server._reserve_ns = 10**9
    server.idle(time.monotonic_ns(), after_work=False)  # ran, but nothing fitted
    server.cycle(time.monotonic_ns())  # an idle call ran: the cycle itself takes none
    assert len(server.transport.queries) == 2 and _replies(server) == 0


def test_every_request_is_answered_and_takes_effect_at_the_next_step(server: NcServer) -> None:
    sent: list = []
    q = FakeQuery("nc/nc1/axis/1/cmd/read/t", {"id": 1, "client": "t", "cmd": "Info"}, sent)
    server.transport.queries.append(q)
    c = server.core.cycle
    server.idle(None)
    assert sent == [] and not q.dropped  # the cycle thread never replies itself (a reply may block)
    _flush(server)
    (payload, kw), = sent
    rep = msgpack.unpackb(payload, strict_map_key=False)
    assert rep["error"] == 0 and rep["cycle"] == c + 1
    assert q.dropped  # finalized: the querier has its answer now


def test_the_reserve_follows_the_recent_costs_within_bounds() -> None:
    assert query_reserve([]) == A.QUERY_RESERVE_MAX_NS
    assert query_reserve([10_000] * 64) == A.QUERY_RESERVE_MIN_NS
    assert query_reserve([5_000_000] * 64) == A.QUERY_RESERVE_MAX_NS
    costs = [100_000] * 60 + [300_000] * 4  # the 98th percentile is a 300 us one
    assert query_reserve(costs) == 300_000
    assert query_reserve([100_000] * 63 + [300_000]) == 100_000


def test_a_reply_that_fails_is_counted_and_the_query_finalized(server: NcServer) -> None:
    class Gone(FakeQuery):
        def reply(self, key: str, payload: bytes, **kw: object) -> None:
            raise RuntimeError("querier gone")

    q = Gone("nc/nc1/axis/1/cmd/read/t", {"id": 1, "client": "t", "cmd": "Info"}, [])
    server.transport.queries.append(q)
    _queue(server, 1)
    _run_all(server)
    _flush(server)
    assert q.dropped and server.transport.reply_errors == 1
    assert _replies(server) == 1  # the next one is answered
    assert server.stats()["reply_errors"] == 1


def test_a_claims_holder_is_accepted_before_its_reply_goes_out(server: NcServer) -> None:
    """Requests run between cycles: the PLCTONC subscriber must know a new holder right away (a frame the
    client sends on the Claim's reply is decoded in the next idle slice, before the next cycle)."""
    server.claims.client_alive("t", time.monotonic())
    server.transport.queries.append(FakeQuery("nc/nc1/axis/1/cmd/op/t", {"id": 1, "client": "t", "cmd": "Claim"}, SENT))
    server.idle(None)
    assert "t" in server.transport.holders
    _flush(server)
    (payload, _), = SENT
    assert msgpack.unpackb(payload, strict_map_key=False)["error"] == 0


def test_liveliness_events_come_with_the_first_request_or_at_the_cycle_start(server: NcServer) -> None:
    """A slice without requests leaves the liveliness events queued (no poll per slice); a request takes them before
    it runs (a token declared before a Claim is seen first); the cycle start takes them in any case."""
    server.transport.liveliness_events.append(("t", True))
    server.idle(None)  # nothing to run
    assert list(server.transport.liveliness_events) == [("t", True)] and not server.claims.is_alive("t")
    _send(server, "t", 1, "Claim", cls="op")
    server.idle(None)
    assert [(r["cmd"], r["error"]) for r in _replies_of(server)] == [("Claim", 0)]
    assert server.claims.is_alive("t") and server.claims.holder(1) == "t"
    server.transport.liveliness_events.append(("t", False))  # its token goes: the next cycle reacts
    server.idle(None)
    assert server.claims.is_alive("t")
    server.cycle(time.monotonic_ns())
    assert not server.claims.is_alive("t") and server.claims.holder(1) is None


# ---- acknowledged means kept: replies held until the retain file holds their effect ------------------
@pytest.fixture
def retain_server(tmp_path: Path):  # type: ignore[no-untyped-def]
    """A server with a retain file, its first cycle run (the file applied); neither the retain thread nor
    the I/O thread is started: the tests run their steps (``_write_pending``, ``_flush``)."""
    SENT.clear()
    conf = tmp_path / "nc.toml"
    conf.write_text(f'[nc]\nname = "nc1"\nrealtime = "off"\nretain_file = "{tmp_path / "nc1.retain"}"\n'
                    '[zenoh]\nlisten = ["tcp/127.0.0.1:9"]\n[[axis]]\nAxisId = 1\nAxisEnDataPersistence = true\n'
                    '[[axis]]\nAxisId = 2\n')
    cfg = load_config(conf)
    srv = NcServer(cfg, NcCore(list(cfg.axes), cfg.cycle_time))
    assert srv.retain is not None
    srv.load_retain()
    srv.cycle(time.monotonic_ns())
    try:
        yield srv
    finally:
        srv.retain.stop()
        srv.frames.close()


def _write_pending(srv: NcServer) -> None:
    """What the retain thread does with the snapshot handed over (and its wake-up of the I/O thread)."""
    k = srv.retain
    assert k is not None
    snap = k.take_pending()
    assert snap is not None
    k._write(snap)


def _run_all(srv: NcServer) -> None:
    """Idle slices until every queued request ran (a slice stops after QUERY_BUDGET_NS: a loaded machine)."""
    while srv.transport.queries:
        srv.idle(None)


def _send(srv: NcServer, client: str, rid: int, cmd: str, axis: int = 1, cls: str = "eng", **args: object) -> None:
    srv.transport.queries.append(FakeQuery(f"nc/nc1/axis/{axis}/cmd/{cls}/{client}",
                                           {"id": rid, "client": client, "cmd": cmd, **args}, SENT))


def _sent() -> list[tuple[str, int, int]]:
    """(cmd, id, error) of the replies sent so far (then forgotten)."""
    out = [(r["cmd"], r["id"], r["error"]) for r in (msgpack.unpackb(p, strict_map_key=False) for p, _ in SENT)]
    SENT.clear()
    return out


def _file_velo_max(tmp_path: Path) -> float | None:
    d = R.parse_retain((tmp_path / "nc1.retain").read_bytes(), "nc1", [1, 2])
    a = d.axes.get(1)
    return None if a is None or "AxisVeloMax" not in a.params else float(a.params["AxisVeloMax"][0])


def test_a_write_is_answered_once_the_retain_file_holds_it(retain_server: NcServer, tmp_path: Path) -> None:
    srv = retain_server
    _send(srv, "a", 1, "WriteParameter", ParameterNumber=1003, Value=400.0)
    _send(srv, "b", 1, "Info", axis=2, cls="read")
    _send(srv, "a", 2, "Info", cls="read")  # the same client's next reply is not held behind its write
    _run_all(srv)
    _flush(srv)
    assert _sent() == [("Info", 1, 0), ("Info", 2, 0)]
    assert not (tmp_path / "nc1.retain").exists() or _file_velo_max(tmp_path) is None
    assert srv.retain.committed == 1 and srv.retain.settled == 0
    _write_pending(srv)
    assert _file_velo_max(tmp_path) == 400.0 and srv.retain.durable == 1
    _flush(srv)  # (the retain thread's wake-up: an empty batch)
    assert _sent() == [("WriteParameter", 1, 0)]
    assert not srv.io.held and srv.io.replies_held == 1 and srv.io.replies_not_kept == 0
    assert (srv.stats()["replies_held"], srv.stats()["replies_not_kept"]) == (1, 0)


def test_writes_in_flight_share_one_file_write(retain_server: NcServer, tmp_path: Path) -> None:
    srv = retain_server
    writes = srv.retain.writes
    for rid, (axis, value) in enumerate(((1, 400.0), (2, 300.0), (1, 410.0)), start=1):
        _send(srv, f"w{rid}", rid, "WriteParameter", axis=axis, ParameterNumber=1003, Value=value)
        _run_all(srv)  # one request per slice: three commits while the retain thread is busy
    _flush(srv)
    assert _sent() == [] and srv.retain.committed == 3
    _write_pending(srv)  # the newest snapshot holds all three
    _flush(srv)
    assert sorted(_sent()) == [("WriteParameter", 1, 0), ("WriteParameter", 2, 0), ("WriteParameter", 3, 0)]
    assert srv.retain.writes == writes + 1 and _file_velo_max(tmp_path) == 410.0


def test_a_refused_write_is_not_held(retain_server: NcServer) -> None:
    srv = retain_server
    _send(srv, "a", 1, "WriteParameter", ParameterNumber=1003, Value=-5.0)  # out of range: an error reply
    _run_all(srv)
    _flush(srv)
    (cmd, rid, error), = _sent()
    assert error != 0 and srv.retain.committed == 0


def test_a_refusal_given_again_from_the_cache_stays_a_refusal(retain_server: NcServer,
                                                               monkeypatch: pytest.MonkeyPatch) -> None:
    """A retry of a refused write gets its cached refusal, never 0x4002 "applied" (it was not)."""
    srv = retain_server
    monkeypatch.setattr(srv.retain, "writing_disabled", True)  # whatever is held comes back "not kept"
    for _ in range(2):  # the request, then its retry with the same id (the reply cache)
        _send(srv, "a", 1, "WriteParameter", ParameterNumber=1003, Value=-5.0)  # out of range: an error reply
        _run_all(srv)
        snap = srv.retain.take_pending()  # (a retry's cached reply may be held for a snapshot)
        if snap is not None:
            srv.retain._write(snap)
        _flush(srv)
    (_, _, first), (_, _, again) = _sent()
    assert first == again and first not in (0, 0x4002)


def test_a_write_the_file_cannot_keep_is_answered_with_0x4002(retain_server: NcServer,
                                                               monkeypatch: pytest.MonkeyPatch) -> None:
    srv = retain_server

    def full(_p: object, _d: bytes) -> bool:
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(R, "write_atomic", full)
    _send(srv, "a", 1, "WriteParameter", ParameterNumber=1003, Value=400.0)
    _run_all(srv)
    _flush(srv)
    assert _sent() == []
    _write_pending(srv)
    _flush(srv)
    (payload, _), = SENT
    r = msgpack.unpackb(payload, strict_map_key=False)
    assert (r["cmd"], r["id"], r["error"]) == ("WriteParameter", 1, 0x4002) and "retain" in r["text"]
    assert srv.io.replies_not_kept == 1 and srv.retain.settled == 1 and srv.retain.durable == 0


def test_position_and_reference_flag_are_answered_once_kept(retain_server: NcServer, tmp_path: Path) -> None:
    srv = retain_server
    _send(srv, "a", 1, "SetActualPosition", cls="eng", Position=12.5)
    _send(srv, "a", 2, "SetReferenceFlag", cls="eng", ReferenceFlag=True)
    _run_all(srv)
    _flush(srv)
    assert _sent() == []
    _write_pending(srv)
    a = R.parse_retain((tmp_path / "nc1.retain").read_bytes(), "nc1", [1, 2]).axes[1]
    assert a.position == 12.5 and a.homed
    _flush(srv)
    assert _sent() == [("SetActualPosition", 1, 0), ("SetReferenceFlag", 2, 0)]


def test_position_and_reference_flag_of_an_axis_not_persisted_are_answered_at_once(retain_server: NcServer) -> None:
    """Axis 2 has AxisEnDataPersistence FALSE: the file never holds its position or homed flag, so its replies
    must not wait for a write (and claim a keeping that never happens)."""
    srv = retain_server
    for rid, cmd, args in ((1, "SetActualPosition", {"Position": 3.0}),
                           (2, "SetActualPositionOnTheFly", {"ActualPosition": 4.0, "PreviousPosition": 3.0}),
                           (3, "SetReferenceFlag", {"ReferenceFlag": True})):
        _send(srv, "a", rid, cmd, axis=2, **args)
    _run_all(srv)
    _flush(srv)
    assert _sent() == [("SetActualPosition", 1, 0), ("SetActualPositionOnTheFly", 2, 0), ("SetReferenceFlag", 3, 0)]
    assert srv.retain.committed == 0 and not srv.io.held and srv.io.replies_held == 0


def test_while_the_nc_does_not_write_its_file_a_write_is_answered_with_0x4002(retain_server: NcServer) -> None:
    srv = retain_server
    srv.retain.writing_disabled = True  # (a refused file it could not rename: see retain.py)
    _send(srv, "a", 1, "WriteParameter", ParameterNumber=1003, Value=400.0)
    _run_all(srv)
    _write_pending(srv)
    _flush(srv)
    assert _sent() == [("WriteParameter", 1, 0x4002)]
    assert srv.core.params[0].AxisVeloMax == 400.0  # applied, not kept


def test_a_stalled_write_gives_0x4002_after_the_cap_and_holds_nothing_else(
        retain_server: NcServer, monkeypatch: pytest.MonkeyPatch) -> None:
    """The retain thread and the I/O thread running, the file's write hangs (a dead disk): the cycle thread
    never waits, the client's other replies go out at once, the write's reply is 0x4002 after HOLD_MAX."""
    srv = retain_server
    hung = threading.Event()
    release = threading.Event()

    def stalled(_p: object, _d: bytes) -> bool:
        hung.set()
        release.wait(30)
        raise OSError(errno.EIO, "Input/output error")

    monkeypatch.setattr(R, "write_atomic", stalled)
    srv.retain.start()
    srv.io.start()
    try:
        _send(srv, "a", 1, "WriteParameter", ParameterNumber=1003, Value=400.0)
        t0 = time.monotonic()
        _run_all(srv)
        # the cycle thread hands over and goes on (no I/O there): a wait for the hung write takes 30 s (one
        # capped at HOLD_MAX would send the write's reply before the Infos below); 5 s: a loaded machine
        assert time.monotonic() - t0 < 5.0
        assert hung.wait(5), "the retain thread never started the write"
        for rid in range(2, 12):  # the cycle goes on taking the same client's requests while the write hangs
            _send(srv, "a", rid, "Info", cls="read")
            t1 = time.monotonic()
            srv.cycle(time.monotonic_ns())
            _run_all(srv)
            assert time.monotonic() - t1 < 5.0  # (a wait for the write: 30 s, or HOLD_MAX and its reply first)
        _wait(lambda: len(SENT) >= 10, 5.0, "the Info replies")
        assert _sent() == [("Info", rid, 0) for rid in range(2, 12)]  # not held behind the hung write
        _wait(lambda: len(SENT) >= 1, T.HOLD_MAX + 5.0, "the write's reply")
        took = time.monotonic() - t0
        (payload, _), = SENT
        r = msgpack.unpackb(payload, strict_map_key=False)
        assert (r["cmd"], r["id"], r["error"]) == ("WriteParameter", 1, 0x4002) and "within the time" in r["text"]
        assert took >= T.HOLD_MAX - 0.05 and srv.io.replies_not_kept == 1 and not srv.io.held
        assert srv.retain.settled == 0 and srv.core.params[0].AxisVeloMax == 400.0  # applied, still not settled
    finally:
        release.set()
        srv.io.stop()


def _wait(cond: Callable[[], bool], timeout: float, what: str) -> None:
    end = time.monotonic() + timeout
    while not cond():
        assert time.monotonic() < end, f"{what}: not sent within {timeout} s"
        time.sleep(0.01)


# ---- motion commands prepared between cycles (SVB), activated at the next cycle's start (SAF) --------------
def _enable(srv: NcServer, *rows: int) -> None:
    rec = srv.core.default_plctonc()
    rec["ControlDWord"] = 7  # Enable, FeedEnablePlus, FeedEnableMinus
    for i in rows:
        srv.core.set_plctonc(i, rec)
    srv.cycle(time.monotonic_ns())


def _move(srv: NcServer, rid: int, axis: int = 1, client: str = "t", cmd: str = "MoveAbsolute", **args: object) -> None:
    _send(srv, client, rid, cmd, axis=axis, cls="op",
          **(({"Position": 100.0, "Velocity": 200.0} if cmd == "MoveAbsolute" else {}) | args))


def _replies_of(srv: NcServer) -> list[dict]:
    _flush(srv)
    out = [msgpack.unpackb(p, strict_map_key=False) for p, _ in SENT]
    SENT.clear()
    return out


def test_a_move_is_prepared_between_cycles_and_answered_after_the_cycle_that_activates_it(server: NcServer) -> None:
    _enable(server, 0)
    _move(server, 1)
    c = server.core.cycle
    server.idle(None)
    assert _replies_of(server) == [] and server.prepared == 1  # prepared, not activated
    assert not server.core.axes.has_job[0]
    server.cycle(time.monotonic_ns())
    (r,), = [_replies_of(server)]
    assert r["error"] == 0 and r["cycle"] == c + 1 == server.core.cycle  # the frame of this cycle shows it
    assert int(server.core.nctoplc[0]["CmdNo"]) == r["CmdNo"] and server.core.axes.has_job[0]
    assert server.stats()["requests_prepared"] == 1


def test_a_move_whose_activation_fits_in_the_gap_of_its_plan_is_activated_and_answered_there(server: NcServer) -> None:
    """The same effect as at the cycle's start (the next step is the one it was planned for; that cycle's PLCTONC and
    watchdog apply to it as to any command run between cycles), the reply a cycle sooner."""
    _enable(server, 0)
    _move(server, 1)
    c = server.core.cycle
    server.idle(time.monotonic_ns() + 10**9)  # a gap with time enough for the plan and the activation
    (r,), = [_replies_of(server)]
    assert r["error"] == 0 and r["cycle"] == c + 1 and server.core.axes.has_job[0] and server.activated_at_once == 1
    assert server.prepared == 1 and not server._pending and not server._pending_axes
    server.cycle(time.monotonic_ns())
    assert _replies_of(server) == [] and server.core.cycle == r["cycle"]  # the frame of that cycle shows it
    assert int(server.core.nctoplc[0]["CmdNo"]) == r["CmdNo"] and int(server.core.nctoplc[0]["SvbEntries"]) == 0
    assert server._class_costs["activate"] and server.stats()["requests_activated_at_once"] == 1


def test_a_move_whose_prediction_fails_in_the_gap_of_its_plan_is_refused_after_a_bounded_number_of_plans(
        server: NcServer, monkeypatch: pytest.MonkeyPatch) -> None:
    """A failed activation in the gap counts as one at a cycle start: planned again at most MAX_REPREPARE times,
    then refused 0x4220, and the axis's later requests run; never planned again in every gap, unanswered."""
    _enable(server, 0)
    monkeypatch.setattr(server.core, "holds", lambda p: False)
    _move(server, 1)
    _move(server, 2, cmd="Halt")  # (the axis's next request: waits for the move's answer, then runs)
    got: list[dict] = []
    for _ in range(10):
        server.idle(time.monotonic_ns() + 10**9)  # gaps with time enough for the plan and the activation
        server.cycle(time.monotonic_ns())
        got += _replies_of(server)
    assert [(r["id"], r["error"]) for r in got] == [(1, 0x4220), (2, 0x4220)]  # (the Halt's prediction fails too)
    assert server.prepared_again == 2 * A.MAX_REPREPARE and server.not_activated == 2
    assert server.activated_at_once == 0 and not server.core.axes.has_job[0]
    assert not server._pending and not server._pending_axes and not server._prepared_again and not server._first_seen
    assert not server.transport.queries


def test_a_request_waiting_for_its_axis_is_not_overtaken_when_the_axis_is_freed_in_the_gap(
        server: NcServer, monkeypatch: pytest.MonkeyPatch) -> None:
    """A1's plan does not fit; A2 (axis 1) waits in ``later``; the plan reserve then drops, and B's (axis 2) plan
    call plans and activates A1 in the gap, freeing axis 1 in the middle of the call: A3 on axis 1, taken after that
    in the same call, must still wait behind A2 (each axis's replies in the order sent)."""
    monkeypatch.setattr(A, "QUERY_BUDGET_NS", 10**12)  # (the call must go on to A3 after the two plans, loaded or not)
    _enable(server, 0, 1)
    server._class_reserve["plan"] = 10**9  # (planning is dear lately: no gap fits it)
    _move(server, 1)                       # A1
    server.idle(time.monotonic_ns() + 10**8, after_work=False)
    assert server.prepared == 1 and server._pending[0][1].prepared is None and _replies_of(server) == []
    _move(server, 2, Position=50.0)        # A2: waits for A1 (later)
    _move(server, 3, axis=2)               # B: its plan call plans A1 first
    _move(server, 4, cmd="Halt")           # A3
    prepare = server.handler.prepare

    def prepare_then_cheap(key: str, payload: bytes, now: float):  # type: ignore[no-untyped-def]
        out = prepare(key, payload, now)
        if "/axis/2/" in key:
            server._class_reserve["plan"] = 0  # planning is cheap again (before B's plan call)
        return out

    monkeypatch.setattr(server.handler, "prepare", prepare_then_cheap)
    got: list[dict] = []
    for _ in range(20):
        server.idle(time.monotonic_ns() + 10**9, after_work=False)
        got += _replies_of(server)
        server.cycle(time.monotonic_ns())
        got += _replies_of(server)
        if len(got) == 4:
            break
    assert server.activated_at_once >= 1  # (A1 at least: the case this is about)
    assert all(r["error"] == 0 for r in got), got
    assert [r["id"] for r in got if r["id"] != 3] == [1, 2, 4] and 3 in [r["id"] for r in got]


def test_an_activation_in_the_gap_does_not_overtake_an_earlier_command_waiting_for_the_cycle_start(
        server: NcServer, monkeypatch: pytest.MonkeyPatch) -> None:
    """A GearIn (slave 2, master 1) planned but left for the cycle start (its activation did not fit), then a move of
    its master whose activation would fit: nothing is activated in the gap while an earlier command waits, so both
    take effect in the same step, in the order sent, and the GearIn is not planned again (its prediction of the
    master would have failed after the move's activation)."""
    monkeypatch.setattr(A, "QUERY_BUDGET_NS", 10**12)
    _enable(server, 0, 1)
    server._class_reserve["activate"] = 10**12  # (the first plan's activation does not fit)
    plan = server.handler.plan
    plans: list[object] = []

    def cheap_from_the_second(pending):  # type: ignore[no-untyped-def]
        plans.append(pending)
        if len(plans) == 2:
            server._class_reserve["activate"] = 0  # (from the second plan on, an activation would fit)
        return plan(pending)

    monkeypatch.setattr(server.handler, "plan", cheap_from_the_second)
    _move(server, 1, axis=2, cmd="GearIn", Master=1, RatioNumerator=1, RatioDenominator=2)
    _move(server, 2)  # the master moves
    c = server.core.cycle
    server.idle(time.monotonic_ns() + 10**9, after_work=False)
    assert _replies_of(server) == [] and server.activated_at_once == 0 and server.prepared == 2
    server.cycle(time.monotonic_ns())
    got = _replies_of(server)
    assert [(r["id"], r["error"], r["cycle"]) for r in got] == [(1, 0, c + 1), (2, 0, c + 1)], got
    assert server.prepared_again == 0


def test_a_hot_standby_pairs_active_nc_never_activates_in_the_gap(tmp_path: Path) -> None:
    """Its replies follow the cycle's log to the standby: a command prepared in a gap is activated at the cycle's
    start, however much time the gap has."""
    conf = tmp_path / "nc.toml"
    conf.write_text('[nc]\nname = "nc1"\nrealtime = "off"\n[zenoh]\nlisten = ["tcp/127.0.0.1:9"]\n'
                    '[redundancy]\nenabled = true\nstart = "active"\nnode = "a"\n[[axis]]\nAxisId = 1\n')
    cfg = load_config(conf)  # (zenoh is never opened)
    srv = NcServer(cfg, NcCore(list(cfg.axes), cfg.cycle_time))
    try:
        ha = srv.ha
        assert ha is not None
        ha.role = "active"
        ha.before_cycle = lambda now: False  # type: ignore[method-assign]
        ha.after_step = lambda: None  # type: ignore[method-assign]
        ha.after_stall = lambda gap: False  # type: ignore[method-assign]
        SENT.clear()
        _enable(srv, 0)
        _move(srv, 1)
        srv.idle(time.monotonic_ns() + 10**9)  # time enough for the plan and the activation
        assert _replies_of(srv) == [] and srv.prepared == 1 and srv.activated_at_once == 0
        assert srv._pending and srv._pending[0][1].prepared is not None and not srv.core.axes.has_job[0]
        srv.cycle(time.monotonic_ns())
        (r,) = _replies_of(srv)
        assert r["error"] == 0 and r["cycle"] == srv.core.cycle and srv.core.axes.has_job[0]
        assert srv.activated_at_once == 0
    finally:
        srv.frames.close()


def test_a_move_whose_activation_does_not_fit_in_the_gap_waits_for_the_cycle_start(server: NcServer) -> None:
    _enable(server, 0)
    _move(server, 1)
    server._class_reserve["activate"] = 10**9  # (its recent cost: more than any gap)
    server.idle(time.monotonic_ns() + 10**8)
    assert _replies_of(server) == [] and server.prepared == 1 and server.activated_at_once == 0
    assert not server.core.axes.has_job[0]
    server.cycle(time.monotonic_ns())
    (r,), = [_replies_of(server)]
    assert r["error"] == 0 and r["cycle"] == server.core.cycle and server.core.axes.has_job[0]


def test_a_later_request_on_the_same_axis_waits_for_the_activation_others_do_not(server: NcServer) -> None:
    _enable(server, 0, 1)
    _move(server, 1)                     # axis 1
    _move(server, 2, cmd="Halt")         # axis 1 again: after the move's activation
    _move(server, 3, axis=2)             # axis 2: prepared now
    server.transport.queries.append(FakeQuery("nc/nc1/cmd/read/t", {"id": 4, "client": "t", "cmd": "Info"}, SENT))
    for _ in range(100):  # (a call stops after QUERY_BUDGET_NS: a loaded machine may need several)
        server.idle(None)
        if server.prepared == 2 and len(server.transport.queries) == 1:
            break
    assert [(r["cmd"], r["id"]) for r in _replies_of(server)] == [("Info", 4)]
    assert len(server.transport.queries) == 1 and server.prepared == 2
    server.cycle(time.monotonic_ns())
    assert sorted((r["cmd"], r["id"], r["error"]) for r in _replies_of(server)) == [
        ("MoveAbsolute", 1, 0), ("MoveAbsolute", 3, 0)]
    _run_all(server)  # the Halt now, from the move's state
    server.cycle(time.monotonic_ns())
    (r,) = _replies_of(server)
    assert (r["cmd"], r["id"], r["error"], r["cycle"]) == ("Halt", 2, 0, server.core.cycle)
    assert server.core.queues[0].active is not None and server.core.queues[0].active.kind.name == "Halt"


def test_a_retry_of_a_prepared_command_gets_its_reply_once(server: NcServer) -> None:
    _enable(server, 0)
    _move(server, 1)
    _move(server, 1)  # the same id again (a retry) before the activation
    server.idle(None)
    server.cycle(time.monotonic_ns())
    server.idle(None)
    server.cycle(time.monotonic_ns())
    a, b = _replies_of(server)
    assert a == b and a["error"] == 0 and server.prepared == 1 and server.handler.cache.hits == 1


def test_a_prediction_broken_at_the_cycle_start_is_prepared_again_and_refused_with_its_code(
        server: NcServer) -> None:
    _enable(server, 0)
    _move(server, 1)
    server.idle(None)
    server.core.fault(0, 0x8F02)  # (what the watchdog at the cycle start does)
    server.cycle(time.monotonic_ns())
    assert _replies_of(server) == [] and server.prepared_again == 1  # not activated stale
    server.idle(None)  # prepared again: the axis is in error now
    (r,) = _replies_of(server)
    assert r["error"] != 0 and not server.core.axes.has_job[0] and server.not_activated == 0
    # answered: its re-plan count goes with it (keyed by id(query): a later query with that id must not inherit it)
    assert not server._prepared_again and not server._pending and not server._pending_axes


def test_a_command_whose_prediction_keeps_failing_is_refused_after_a_bounded_number_of_preparations(
        server: NcServer, monkeypatch: pytest.MonkeyPatch) -> None:
    _enable(server, 0)
    monkeypatch.setattr(server.core, "holds", lambda p: False)
    _move(server, 1)
    for _ in range(A.MAX_REPREPARE + 1):
        server.idle(None)
        server.cycle(time.monotonic_ns())
    (r,) = _replies_of(server)
    assert (r["id"], r["error"]) == (1, 0x4220) and not server.core.axes.has_job[0]
    assert server.prepared == 1 and server.prepared_again == A.MAX_REPREPARE and server.not_activated == 1
    assert not server.transport.queries and not server._pending and not server._first_seen


def test_a_prepared_command_across_a_long_stall_is_refused(server: NcServer) -> None:
    _enable(server, 0)
    _move(server, 1)
    server.idle(None)
    server._prev_tick -= server.config.watchdog_timeout + 1.0  # the cycle thread stood still that long
    server.cycle(time.monotonic_ns())
    (r,) = _replies_of(server)
    assert r["error"] == 0x4B0F and not server.core.axes.has_job[0]


def test_the_core_part_waits_for_a_gap_it_fits_and_is_forced_after_the_wait_limit(
        server: NcServer, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(A, "QUERY_MAX_WAIT_NS", 10_000_000_000)  # (moved by hand below)
    monkeypatch.setattr(A, "QUERY_SPIN_WAIT_NS", 10**12)
    _enable(server, 0)
    server._class_reserve["plan"] = 400_000  # planning costs 0.4 ms lately
    _move(server, 1)
    server.idle(time.monotonic_ns() + 300_000, after_work=True)  # parsed and checked; its plan does not fit
    assert server.prepared == 1 and server._pending and server._pending[0][1].prepared is None
    server.cycle(time.monotonic_ns())  # nothing to activate yet: the axis waits, nothing answered
    assert _replies_of(server) == [] and not server.core.axes.has_job[0] and server._pending_axes == {1}
    # the frame of this cycle shows the command in preparation (SvbEntries), no job executing (SafEntries)
    assert (int(server.core.nctoplc[0]["SvbEntries"]), int(server.core.nctoplc[0]["SafEntries"])) == (1, 0)
    assert int(server.core.nctoplc[1]["SvbEntries"]) == 0
    assert server._plan_waiting_since is not None
    server._plan_waiting_since -= A.QUERY_MAX_WAIT_NS + 1  # ... it has waited that long by now:
    server.idle(time.monotonic_ns() + 300_000, after_work=False)  # not in a slice,
    assert server._pending[0][1].prepared is None
    server.idle(time.monotonic_ns() + 300_000, after_work=True)  # but right after the work it is planned anyway
    assert server._pending[0][1].prepared is not None and server.forced == 1
    server.cycle(time.monotonic_ns())
    (r,) = _replies_of(server)
    assert r["error"] == 0 and r["cycle"] == server.core.cycle and server.core.axes.has_job[0]
    assert not server._pending and not server._pending_axes
    assert (int(server.core.nctoplc[0]["SvbEntries"]), int(server.core.nctoplc[0]["SafEntries"])) == (0, 1)


def test_every_job_command_runs_in_steps() -> None:
    from nc_server.server.handler import TWO_PHASE
    assert {"MoveAbsolute", "MoveRelative", "MoveVelocity", "Halt", "Stop", "Home", "GearIn"} <= TWO_PHASE
    assert not TWO_PHASE & {"NewPos", "ReadParameter", "Reset", "SetOverride", "Claim", "WriteParameter"}


def test_a_request_that_waited_may_use_the_spin_but_not_its_margin(server: NcServer,
                                                                   monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(A, "QUERY_MAX_WAIT_NS", 10_000_000_000)
    monkeypatch.setattr(A, "QUERY_SPIN_WAIT_NS", 10_000_000_000)  # (moved by hand below)
    server.loop.stats.spin_ns = 200_000
    _queue(server, 1)
    server._reserve_ns = 400_000
    server.idle(time.monotonic_ns() + 300_000, after_work=False)  # 0.3 ms before the spin: does not fit
    assert len(server.transport.queries) == 1 and server._waiting_since is not None
    monkeypatch.setattr(A, "QUERY_SPIN_WAIT_NS", 0)  # it waited long enough to use the spin (0.2 ms):
    server.idle(time.monotonic_ns() + 100_000, after_work=False)  # 0.1 + 0.2 - 0.05 ms: still not
    assert len(server.transport.queries) == 1
    server.idle(time.monotonic_ns() + 300_000, after_work=False)  # 0.3 + 0.2 - 0.05 ms: it fits
    assert not server.transport.queries and _replies(server) == 1


def _hold(srv: NcServer, client: str, row: int) -> None:
    """``client`` is alive and holds axis row ``row`` (Claim), and sends an enabling PLCTONC for it."""
    srv.handler.client_alive(client, time.monotonic())
    _send(srv, client, 900 + row, "Claim", axis=row + 1, cls="op")
    _run_all(srv)
    _feed(srv, client, row, 100.0)
    srv.cycle(time.monotonic_ns())
    _replies_of(srv)


def _feed(srv: NcServer, client: str, row: int, override: float) -> None:
    """A PLCTONC frame of ``client`` for axis row ``row`` (enabled, ``override`` %) in the transport's inbox."""
    import numpy as np
    from nc_schema import PLCTONC_DTYPE
    rec = np.zeros(1, dtype=PLCTONC_DTYPE)
    rec["ControlDWord"] = 7
    rec["Override"] = int(override * 10_000)
    srv.transport.plc_inbox[client] = T.PlcFrame(time.monotonic(), np.array([row + 1], dtype=np.uint32), rec)


def test_a_new_override_between_preparation_and_activation_does_not_refuse_the_command(server: NcServer) -> None:
    """A PLC whose override changes every cycle (a ramp, a slider): its frame that arrives after the preparation
    is applied after the activation, as to a command executed between cycles, and the running job follows it."""
    _hold(server, "plc", 0)
    for k in range(5):
        _move(server, 10 + k, client="plc", cmd="MoveVelocity", Velocity=10.0 + k)
        server.idle(None)
        _feed(server, "plc", 0, 90.0 - k)  # the next PLC frame: another override
        server.cycle(time.monotonic_ns())
        (r,) = _replies_of(server)
        assert (r["id"], r["error"]) == (10 + k, 0), r
    assert server.prepared_again == 0 and server.not_activated == 0


def test_a_move_of_a_client_lost_before_its_activation_is_stopped_by_the_loss_reaction(
        server: NcServer, monkeypatch: pytest.MonkeyPatch) -> None:
    """Client c commands a move on axis 1 (held by plc) and goes away before the activating cycle: the move is
    activated and the watchdog of the same cycle reacts to c's loss as to any running command of a lost client."""
    # (a loaded machine may pause this test longer than STALL_GRACE between its calls: an NC stall, after which
    # nobody is blamed; not the case here)
    monkeypatch.setattr(A, "STALL_GRACE", 60.0)
    _hold(server, "plc", 0)
    server.handler.client_alive("c", time.monotonic())
    _move(server, 1, client="c", cmd="MoveVelocity", Velocity=50.0)
    server.idle(None)
    assert server.prepared == 1 and not server.core.axes.has_job[0]
    server.handler.client_gone("c", time.monotonic())  # its token went: the next cycle's watchdog reacts
    _feed(server, "plc", 0, 100.0)
    server.cycle(time.monotonic_ns())
    (r,) = _replies_of(server)
    assert r["error"] == 0
    q = server.core.queues[0]
    # the endless move does not go on: it was stopped (a stop job or the axis's error), not left running
    assert q.active is None or q.active.kind.name != "MoveVelocity", q.active


def test_odd_key_classes_share_one_cost_class(server: NcServer) -> None:
    """A flood of requests on made-up classes neither grows the class tables nor takes a real class's reserve."""
    assert A.key_class("nc/nc1/axis/1/cmd/op/t") == "op" and A.key_class("nc/nc1/cmd/zz/t") == "?"
    for k in range(A.QUERY_COST_EVERY * 20):
        server._cost(A.key_class(f"nc/nc1/axis/1/cmd/junk{k}/t"), 1_000_000)
    assert set(server._class_costs) == {"read", "op", "eng", "plan", "activate", "?"}
    assert set(server._class_reserve) == {"?"}
