"""Unit tests of nc-opcua's method handler and bridge without processes: the door's argument checks (nothing
reaches the NC for a refused input, no input ends in BadUnexpectedError) with a fake bridge, and the bridge's
handling of a session that vanishes while its command waits for the NC's reply, with a fake link."""
from __future__ import annotations

import asyncio
import math
import threading
import time
from types import SimpleNamespace
from typing import Any, Callable

import numpy as np
import pytest
from asyncua import ua

from nc_link import CommandError
from nc_link.door import NcDoor, default_plctonc
from nc_opcua.server import _NUMBER, _SESSION, DoorConfig, OpcuaDoor, _nid
from nc_link.users import User
from nc_schema import ErrorCodes
from nc_schema.frames import PLC_FRAME_HEADER_DTYPE

S = ua.StatusCodes
V = ua.VariantType


class FakeBridge:
    """Records what the door asks of the NC."""

    def __init__(self) -> None:
        self.calls: list[tuple[Any, ...]] = []
        self.params: dict[tuple[int, int], Any] = {}
        self.fail: Exception | None = None

    def _rec(self, *call: Any) -> None:
        if self.fail is not None:
            raise self.fail
        self.calls.append(call)

    def power(self, axis: int, sender: str, session: int, enable: bool, override: int) -> None:
        self._rec("Power", axis, sender, session, enable, override)

    def command(self, cmd: str, axis: int, sender: str, session: int, **args: Any) -> dict[str, Any]:
        self._rec(cmd, axis, sender, session, args)
        return {}

    def jog(self, axis: int, sender: str, session: int, direction: int, velocity: float, timeout: float) -> None:
        self._rec("Jog", axis, sender, session, direction, velocity, timeout)

    def jog_stop(self, axis: int, sender: str, session: int) -> None:
        self._rec("JogStop", axis, sender, session)


@pytest.fixture
def door() -> tuple[OpcuaDoor, FakeBridge]:
    d = OpcuaDoor(DoorConfig(connect="tcp/127.0.0.1:1", users={"eve": User("eve", "engineer", "scrypt$x")}))
    fb = FakeBridge()
    d.bridges["nc1"] = fb  # type: ignore[assignment]
    return d, fb


def call(d: OpcuaDoor, mname: str, *args: Any, parent: ua.NodeId | None = None) -> ua.CallMethodResult:
    session = SimpleNamespace(user=SimpleNamespace(name="eve"), **{_NUMBER: 7})

    async def run() -> ua.CallMethodResult:
        _SESSION.set(session)
        return await d._method(mname, "nc1", 1)(parent if parent is not None else _nid("nc1.1", d.idx), *args)
    return asyncio.run(run())


REFUSED = [
    ("Power", [ua.Variant("false", V.String), ua.Variant(100.0, V.Double)], S.BadTypeMismatch, 0x706),
    ("Power", [ua.Variant(1, V.Int32), ua.Variant(100.0, V.Double)], S.BadTypeMismatch, 0x706),
    ("Power", [ua.Variant(True, V.Boolean), ua.Variant("nan", V.String)], S.BadTypeMismatch, 0x706),
    ("Power", [ua.Variant(True, V.Boolean), ua.Variant(math.nan, V.Double)], S.BadInvalidArgument, 0x706),
    ("Power", [ua.Variant(True, V.Boolean), ua.Variant(True, V.Boolean)], S.BadTypeMismatch, 0x706),
    ("WriteParameter", [ua.Variant("AxisVeloMax", V.String), ua.Variant("1e400", V.String)], S.BadTypeMismatch,
     0x706),
    ("WriteParameter", ["AxisVeloMax", 10 ** 400], S.BadInvalidArgument, 0x706),
    ("WriteParameter", [ua.Variant("AxisVeloMax", V.String), ua.Variant(math.inf, V.Double)], S.BadInvalidArgument,
     0x706),
    ("MoveVelocity", [ua.Variant(10.0, V.Double), ua.Variant(2 ** 40, V.Int64)], S.BadInvalidArgument, 0x4B05),
    ("MoveVelocity", [ua.Variant(10.0, V.Double), ua.Variant(2, V.Int32)], S.BadInvalidArgument, 0x4B05),
    ("MoveVelocity", [ua.Variant(10.0, V.Double), ua.Variant(True, V.Boolean)], S.BadTypeMismatch, 0x706),
    ("MoveVelocity", [ua.Variant(0.0, V.Double), ua.Variant(1, V.Int32)], S.BadInvalidArgument, 0x4221),
    ("JogStart", [ua.Variant(1, V.Int32), ua.Variant(-5.0, V.Double), ua.Variant(1.0, V.Double)],
     S.BadInvalidArgument, 0x4221),
    ("JogStart", [ua.Variant(4, V.Int32), ua.Variant(5.0, V.Double), ua.Variant(1.0, V.Double)],
     S.BadInvalidArgument, 0x4B05),
    ("MoveAbsolute", [ua.Variant(None), ua.Variant(10.0, V.Double)], S.BadTypeMismatch, 0x706),
    ("MoveAbsolute", [ua.Variant(1.0, V.Double), ua.Variant(-1.0, V.Double)], S.BadInvalidArgument, 0x4221),
    ("MoveRelative", [ua.Variant(1.0, V.Double), ua.Variant(0.0, V.Double)], S.BadInvalidArgument, 0x4221),
    ("MoveAbsolute", [ua.Variant(1.0, V.Double)], S.BadArgumentsMissing, 0x706),
    ("MoveAbsolute", [ua.Variant(1.0, V.Double)] * 3, S.BadTooManyArguments, 0x706),
    ("Home", [ua.Variant(math.inf, V.Double)], S.BadInvalidArgument, 0x706),
    ("Reset", [ua.Variant(1, V.Int32)], S.BadTooManyArguments, 0x706),
]


@pytest.mark.parametrize("mname,args,status,code", REFUSED)
def test_bad_arguments_are_refused_before_anything_is_sent(door: tuple[OpcuaDoor, FakeBridge], mname: str,
                                                            args: list[Any], status: int, code: int) -> None:
    d, fb = door
    r = call(d, mname, *args)
    assert r.StatusCode.value == status, (r.StatusCode, r.OutputArguments[1].Value)
    assert r.OutputArguments[0].Value == code and r.OutputArguments[1].Value
    assert fb.calls == []


def test_good_arguments_are_converted_and_sent(door: tuple[OpcuaDoor, FakeBridge]) -> None:
    d, fb = door
    for mname, args in (("Power", [ua.Variant(True, V.Boolean), ua.Variant(50, V.Int32)]),
                        ("MoveVelocity", [ua.Variant(10, V.Int32), ua.Variant(3, V.Int32)]),
                        ("JogStart", [ua.Variant(1, V.Int32), ua.Variant(0.0, V.Double), ua.Variant(1.0, V.Double)]),
                        ("Home", [ua.Variant(math.nan, V.Double)])):
        r = call(d, mname, *args)
        assert r.StatusCode.is_good(), (mname, r.OutputArguments[1].Value)
    assert fb.calls[0] == ("Power", 1, "opcua.eve", 7, True, 500000)
    assert fb.calls[1] == ("MoveVelocity", 1, "opcua.eve", 7, {"Velocity": 10.0, "Direction": 3})
    assert type(fb.calls[1][4]["Velocity"]) is float
    assert fb.calls[2] == ("Jog", 1, "opcua.eve", 7, 1, 0.0, 1.0)
    assert fb.calls[3] == ("Home", 1, "opcua.eve", 7, {})


@pytest.mark.parametrize("parent", [_nid("nc1.2", 0), _nid("garbage", 0), ua.NodeId(5, 0)])
def test_a_method_acts_only_on_its_own_axis(door: tuple[OpcuaDoor, FakeBridge], parent: ua.NodeId) -> None:
    d, fb = door
    r = call(d, "Halt", parent=parent)
    assert r.StatusCode.value == S.BadMethodInvalid
    assert fb.calls == []


def test_an_unforeseen_failure_is_bad_internal_error_with_its_text(door: tuple[OpcuaDoor, FakeBridge]) -> None:
    d, fb = door
    fb.fail = RuntimeError("boom")
    r = call(d, "Halt")
    assert r.StatusCode.value == S.BadInternalError
    assert "boom" in r.OutputArguments[1].Value


# ---- the bridge: a session vanishing while its command waits for the NC ------------------------------------------
class FakeLink:
    """Records requests; ``during[cmd]`` runs while the NC 'takes' that command (before its reply)."""

    def __init__(self) -> None:
        self.sent: list[tuple[str, Any, str | None, dict[str, Any]]] = []
        self.during: dict[str, Callable[[], None]] = {}

    def request(self, cmd: str, axis: Any, sender: str | None = None, **args: Any) -> dict[str, Any]:
        self.sent.append((cmd, axis, sender, args))
        hook = self.during.pop(cmd, None)
        if hook is not None:
            hook()
        return {"cycle": 1}

    def declare_holder(self, client_id: str) -> tuple[Any, Any]:
        return SimpleNamespace(undeclare=lambda: None), SimpleNamespace(put=lambda data: None, undeclare=lambda: None)


@pytest.fixture
def bridge() -> tuple[NcDoor, FakeLink]:
    b = NcDoor("nc1", "tcp/127.0.0.1:1", "opcua")
    link = FakeLink()
    b.link = link  # type: ignore[assignment]
    return b, link


def test_power_of_a_session_gone_during_the_claim_is_released_not_supplied(bridge: tuple[NcDoor, FakeLink]) -> None:
    b, link = bridge
    seen: list[Any] = []
    link.during["Claim"] = lambda: (seen.append(b.agents["opcua.eve"]), b.session_gone(3))
    with pytest.raises(CommandError) as ei:
        b.power(1, "opcua.eve", 3, True, 1_000_000)
    assert ei.value.code == ErrorCodes.ZNC_CLIENT_LOST
    assert 1 not in seen[0].supplies  # never supplied: no Enable for a session that is gone
    assert [c[0] for c in link.sent][-1] == "Release"


def test_motion_of_a_session_gone_during_the_command_gets_the_loss_reaction(bridge: tuple[NcDoor, FakeLink]) -> None:
    b, link = bridge
    link.during["MoveVelocity"] = lambda: b.session_gone(4)
    with pytest.raises(CommandError):
        b.command("MoveVelocity", 2, "opcua.eve", 4, Velocity=10.0, Direction=1)
    assert 2 not in b.commanded
    assert link.sent[-1][:2] == ("SetExternalError", 2)
    assert link.sent[-1][3] == {"ErrorCode": ErrorCodes.ZNC_CLIENT_LOST}


def test_jog_of_a_session_gone_during_the_command_is_stopped(bridge: tuple[NcDoor, FakeLink]) -> None:
    b, link = bridge
    link.during["Jog"] = lambda: b.session_gone(5)
    with pytest.raises(CommandError):
        b.jog(3, "opcua.eve", 5, 1, 0.0, 5.0)
    assert 3 not in b.jogs and 3 not in b.commanded
    assert link.sent[-1][:2] == ("SetExternalError", 3)


def test_a_gone_session_is_refused_before_anything_is_sent(bridge: tuple[NcDoor, FakeLink]) -> None:
    b, link = bridge
    b.session_gone(6)
    link.sent.clear()
    for f in (lambda: b.command("MoveVelocity", 1, "opcua.eve", 6, Velocity=1.0, Direction=1),
              lambda: b.power(1, "opcua.eve", 6, True, 1_000_000),
              lambda: b.jog(1, "opcua.eve", 6, 1, 0.0, 5.0)):
        with pytest.raises(CommandError) as ei:
            f()
        assert ei.value.code == ErrorCodes.ZNC_CLIENT_LOST
    assert link.sent == [] and "opcua.eve" not in b.agents


def test_plctonc_is_published_by_one_thread_at_a_time(bridge: tuple[NcDoor, FakeLink]) -> None:
    b, _ = bridge
    ag = b.agent("opcua.eve", 1)
    ag.supplies.start(1, default_plctonc(True, 1_000_000), 1, 0)
    busy = threading.Lock()
    overlaps: list[int] = []
    cycles: list[int] = []

    def put(data: bytes) -> None:
        if not busy.acquire(blocking=False):
            overlaps.append(1)
            return
        try:
            cycles.append(int(np.frombuffer(data[:PLC_FRAME_HEADER_DTYPE.itemsize], PLC_FRAME_HEADER_DTYPE)[0]["PlcCycle"]))
            time.sleep(0.002)
        finally:
            busy.release()

    ag.pub = SimpleNamespace(put=put, undeclare=lambda: None)
    start = threading.Barrier(2)

    def publish() -> None:
        start.wait()
        for _ in range(30):
            b._publish(ag)
    ts = [threading.Thread(target=publish) for _ in range(2)]
    for t in ts:
        t.start()
    for t in ts:
        t.join(30)
    assert overlaps == []
    assert cycles == sorted(cycles) and len(set(cycles)) == len(cycles) == 60


# ---- password checks -------------------------------------------------------------------------------------------
def test_password_checks_cost_the_same_for_unknown_names_and_are_cached(monkeypatch: pytest.MonkeyPatch) -> None:
    import hashlib

    from nc_link import users as users_mod
    from nc_opcua.server import _Users
    monkeypatch.setattr(users_mod, "_N", 2 ** 4)  # cheap hashes for the test (the parameters are stored)
    real = hashlib.scrypt
    runs: list[int] = []

    def counting(*a: Any, **k: Any) -> bytes:
        runs.append(int(k["n"]))
        return real(*a, **k)
    alice = users_mod.User("alice", "operator", users_mod.hash_password("alice-pw"))
    monkeypatch.setattr(users_mod.hashlib, "scrypt", counting)
    um = _Users({"alice": alice}, anonymous=False)

    def scrypts(name: str, pw: str) -> tuple[bool, list[int]]:
        runs.clear()
        ok = um.get_user(None, username=name, password=pw) is not None
        return ok, list(runs)
    assert scrypts("alice", "wrong") == (False, [2 ** 4])
    assert scrypts("mallory", "x") == (False, [2 ** 4])  # unknown: the same scrypt, the same cost
    assert scrypts("alice", "alice-pw") == (True, [2 ** 4])
    assert scrypts("alice", "alice-pw") == (True, [])  # remembered: no scrypt
    assert scrypts("alice", "alice-pwx") == (False, [2 ** 4])  # a wrong one is never taken from the cache
    assert scrypts("alice", "alice-pw") == (True, [])


def test_a_precheck_on_a_worker_thread_leaves_asyncuas_check_without_scrypt(monkeypatch: pytest.MonkeyPatch) -> None:
    """The login's scrypt runs in Verifier.precheck (a worker thread, before asyncua's ActivateSession); the
    synchronous get_user on the event loop then costs no scrypt, for a success and for a refusal."""
    import hashlib

    from asyncua.server import uaprocessor

    from nc_link import users as users_mod
    from nc_opcua.server import _install_async_login, _Users
    monkeypatch.setattr(users_mod, "_N", 2 ** 4)
    real = hashlib.scrypt
    runs: list[int] = []

    def counting(*a: Any, **k: Any) -> bytes:
        runs.append(int(k["n"]))
        return real(*a, **k)
    alice = users_mod.User("alice", "operator", users_mod.hash_password("alice-pw"))
    monkeypatch.setattr(users_mod.hashlib, "scrypt", counting)
    um = _Users({"alice": alice}, anonymous=False)
    for name, pw, ok in (("alice", "alice-pw", True), ("alice", "wrong", False), ("mallory", "x", False)):
        runs.clear()
        assert um.verifier.precheck(name, pw) is ok and len(runs) == 1
        runs.clear()
        assert (um.get_user(None, username=name, password=pw) is not None) is ok and runs == []
    runs.clear()
    assert um.get_user(None, username="alice", password="wrong") is None and len(runs) == 1  # remembered once only
    _install_async_login()
    assert getattr(uaprocessor.UaProcessor, "_znc_async_login", False)


def test_a_login_flood_is_refused_when_full_and_never_delays_a_stop(door: tuple[OpcuaDoor, FakeBridge],
                                                                    monkeypatch: pytest.MonkeyPatch) -> None:
    """Password checks run on their own 2 threads behind a bound of 8 (more: LoginsBusy, which the ActivateSession
    hook answers with BadTooManyOperations); NC commands on their own threads: a Stop completes while every
    password thread and asyncio's default executor are blocked."""
    from nc_link.users import LoginsBusy
    d, fb = door
    release = threading.Event()
    started: list[str] = []

    def slow(name: str, pw: str) -> bool:  # a scrypt that takes as long as the test wants
        started.append(name)
        release.wait(30)
        return False
    monkeypatch.setattr(d._users.verifier, "precheck", slow)
    session = SimpleNamespace(user=SimpleNamespace(name="eve"), **{_NUMBER: 7})

    async def run() -> tuple[int, int, Any]:
        _SESSION.set(session)
        loop = asyncio.get_running_loop()
        blockers = [loop.run_in_executor(None, release.wait, 30) for _ in range(40)]  # default executor full
        logins = [asyncio.ensure_future(d._users.gate.precheck(f"u{i}", "x")) for i in range(20)]
        await asyncio.sleep(0.05)
        refused = sum(1 for t in logins if t.done() and isinstance(t.exception(), LoginsBusy))
        stop = await asyncio.wait_for(d._method("Stop", "nc1", 1)(_nid("nc1.1", d.idx)), 20)
        running = len(started)
        release.set()
        await asyncio.gather(*logins, *blockers, return_exceptions=True)
        return refused, running, stop
    try:
        refused, running, stop = asyncio.run(run())
    finally:
        release.set()
    assert refused == 12 and running <= 2  # 8 admitted, at most 2 of them running
    assert stop.StatusCode.is_good() and fb.calls == [("Stop", 1, "opcua.eve", 7, {})]


# ---- parameter refresh -----------------------------------------------------------------------------------------
def test_a_parameter_refresh_is_throttled_shared_and_ends_at_an_unreachable_nc(bridge: tuple[NcDoor, FakeLink],
                                                                             monkeypatch: pytest.MonkeyPatch) -> None:
    """RefreshParameters / the page's Refresh: one ReadParameter per parameter at most once per REFRESH_INTERVAL
    per axis (concurrent refreshes share it), and the first 0x707/0x719 ends it."""
    from nc_link import door as door_mod
    b, link = bridge

    def reads(axis: int) -> int:
        return sum(1 for s in link.sent if s[0] == "ReadParameter" and s[1] == axis)
    got = b.read_parameters(1, [1, 2, 3], refresh=True)
    assert reads(1) == 3 and set(got) == {1, 2, 3}
    for _ in range(5):  # an observer pressing Refresh again and again
        b.read_parameters(1, [1, 2, 3], refresh=True)
    assert reads(1) == 3
    ts = [threading.Thread(target=b.read_parameters, args=(2, [1, 2, 3], True)) for _ in range(4)]
    for t in ts:
        t.start()
    for t in ts:
        t.join(30)
    assert reads(2) == 3  # four at once: one refresh
    monkeypatch.setattr(door_mod, "REFRESH_INTERVAL", 0.0)
    b.read_parameters(1, [1, 2, 3], refresh=True)
    assert reads(1) == 6  # the interval passed: read again

    def unreachable(cmd: str, axis: Any, sender: str | None = None, **args: Any) -> dict[str, Any]:
        link.sent.append((cmd, axis, sender, args))
        raise CommandError(0x707, "NC not reachable")
    link.request = unreachable  # type: ignore[method-assign]
    got = b.read_parameters(3, list(range(1, 69)), refresh=True)
    assert reads(3) == 1 and list(got) == [1] and isinstance(got[1], CommandError) and got[1].code == 0x707
