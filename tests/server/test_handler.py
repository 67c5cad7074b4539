"""Request handling: parsing errors, dedup, Claim/Release/Info/SetOverride (no zenoh)."""
from __future__ import annotations

from types import SimpleNamespace
from typing import Any

import msgpack
import numpy as np
import pytest

from nc_schema import PLCTONC_DTYPE, Keys, make_reply, make_request
from nc_server.core import AxisConfig, NcCore
from nc_server.server.claims import ZNC_CLIENT_LOST, ZNC_PLCTONC_TIMEOUT, ClaimTable
from nc_server.server.handler import CycleInputs, ReplyCache, RequestHandler

KEY1 = "nc/nc1/axis/1/cmd"


class FakeCore:
    """Records execute() calls; enough of NcCore for the handler."""

    def __init__(self) -> None:
        self.cycle = 10
        self.calls: list[tuple[str, int]] = []
        self.plctonc = np.zeros(2, dtype=PLCTONC_DTYPE)
        self.fail = False

    def index(self, axis_id: int) -> int:
        from nc_schema import NcError
        if axis_id not in (1, 2):
            raise NcError(0x4012, f"no axis {axis_id}")
        return axis_id - 1

    def execute(self, request: dict[str, Any], axis_id: int) -> dict[str, Any]:
        if self.fail:
            raise RuntimeError("boom")
        self.calls.append((request["cmd"], axis_id))
        return make_reply(request["id"], request["cmd"], 0, "", self.cycle + 1, cmd_no=len(self.calls))

    @staticmethod
    def default_plctonc() -> np.void:
        r = np.zeros((), dtype=PLCTONC_DTYPE)
        r["Override"] = 1_000_000
        return r[()]

    def set_plctonc(self, i: int, record: np.void) -> None:
        self.plctonc[i] = record

    def info(self) -> dict[str, Any]:
        return {"cycle_time": 0.001, "axes": [{"AxisId": 1}, {"AxisId": 2}]}


@pytest.fixture
def core() -> FakeCore:
    return FakeCore()


@pytest.fixture
def handler(core: FakeCore) -> RequestHandler:
    return RequestHandler(core, ClaimTable([1, 2], 0.5), Keys("nc1"), info_extra=lambda: {"timing": "SCHED_OTHER"})


def call(h: RequestHandler, payload: bytes, key: str = KEY1) -> dict[str, Any]:
    return msgpack.unpackb(h.handle(key, payload, now=1.0), raw=False, strict_map_key=False)


@pytest.mark.parametrize("payload, code", [
    (b"\xc1", 0x706),                                            # not msgpack
    (b"", 0x706),                                                # empty
    (msgpack.packb([1, 2, 3]), 0x706),                           # not a map
    (msgpack.packb({"cmd": "Reset"}), 0x706),                    # no id
    (msgpack.packb({"id": 1.5, "cmd": "Reset"}), 0x706),         # id of the wrong type
    (msgpack.packb({"id": 1, "cmd": "Fly"}), 0x701),             # unknown command
    (msgpack.packb({"id": 1, "cmd": "x" * 100_000}), 0x706),     # too large
    (make_request("MoveAbsolute", 1, Position=float("nan"), Velocity=1.0), 0x706),
    (make_request("MoveAbsolute", 1, Position="ten", Velocity=1.0), 0x706),
    (make_request("Reset", 1, Bogus=1), 0x706),                  # unknown field
    (msgpack.packb({"id": 1, "cmd": "Reset", "client": "no spaces"}), 0x706),
])
def test_bad_requests_are_answered(handler: RequestHandler, core: FakeCore, payload: bytes, code: int) -> None:
    r = call(handler, payload)
    assert r["error"] == code, r
    assert r["text"]
    assert core.calls == []


def test_bad_keys(handler: RequestHandler, core: FakeCore) -> None:
    assert call(handler, make_request("Reset", 1), key="nc/nc1/foo/cmd")["error"] == 0x4012
    r = call(handler, make_request("Reset", 2), key="nc/nc1/cmd")  # axis command on the NC key
    assert r["error"] == 0x4012 and "axis/<id>/cmd" in r["text"]
    assert core.calls == []


def test_request_id_is_echoed_on_errors(handler: RequestHandler) -> None:
    assert call(handler, make_request("MoveAbsolute", "abc", Position=1.0))["id"] == "abc"


def test_dedup_by_client_and_id(handler: RequestHandler, core: FakeCore) -> None:
    req = make_request("MoveRelative", 7, client="plc1", Distance=1.0, Velocity=1.0)
    first = handler.handle(KEY1, req, 1.0)
    core.cycle += 5
    second = handler.handle(KEY1, req, 2.0)
    assert first == second  # the cached reply, byte for byte
    assert core.calls == [("MoveRelative", 1)]
    # Another client, or another id, is executed.
    handler.handle(KEY1, make_request("MoveRelative", 7, client="plc2", Distance=1.0, Velocity=1.0), 3.0)
    handler.handle(KEY1, make_request("MoveRelative", 8, client="plc1", Distance=1.0, Velocity=1.0), 3.0)
    assert len(core.calls) == 3
    # Anonymous requests are not deduplicated (tools reuse ids like 1).
    anon = make_request("Reset", 1)
    handler.handle(KEY1, anon, 4.0)
    handler.handle(KEY1, anon, 4.0)
    assert len(core.calls) == 5
    # A client whose session ended may restart its ids.
    handler.cache.forget_client("plc1")
    handler.handle(KEY1, req, 5.0)
    assert len(core.calls) == 6


def test_reply_cache_is_lru() -> None:
    c = ReplyCache(maxsize=2)
    c.put("a", 1, b"1")
    c.put("a", 2, b"2")
    assert c.get("a", 1) == b"1"  # refreshes 1
    c.put("a", 3, b"3")           # evicts 2
    assert c.get("a", 2) is None and c.get("a", 1) == b"1" and c.get("a", 3) == b"3"


def test_claim_release_override(handler: RequestHandler, core: FakeCore) -> None:
    claims = handler.claims
    r = call(handler, make_request("Claim", 1, client="a"))
    assert r["error"] == 0x723 and "liveliness" in r["text"]
    claims.client_alive("a")
    claims.client_alive("b")
    assert call(handler, make_request("Claim", 2, client="a"))["Value"] == "a"
    r = call(handler, make_request("Claim", 3, client="b"))
    assert r["error"] == 0x723 and "'a'" in r["text"]
    assert call(handler, make_request("Claim", 4))["error"] == 0x706  # no client id
    assert call(handler, make_request("Claim", 5, client="a"), key="nc/nc1/axis/9/cmd")["error"] == 0x4012
    # SetOverride: the holder, or anyone while unclaimed.
    assert call(handler, make_request("SetOverride", 6, client="b", Override=50.0))["error"] == 0x723
    assert call(handler, make_request("SetOverride", 7, Override=50.0))["error"] == 0x723
    assert call(handler, make_request("SetOverride", 8, client="a", Override=50.0))["error"] == 0
    assert call(handler, make_request("SetOverride", 9, Override=50.0), key="nc/nc1/axis/2/cmd")["error"] == 0
    # Release by another client is refused; by the holder it applies the default PLCTONC.
    core.plctonc[0]["ControlDWord"] = 7
    assert call(handler, make_request("Release", 10, client="b"))["error"] == 0x723
    assert call(handler, make_request("Release", 11, client="a"))["error"] == 0
    assert int(core.plctonc[0]["ControlDWord"]) == 0 and int(core.plctonc[0]["Override"]) == 1_000_000
    assert call(handler, make_request("Claim", 12, client="b"))["error"] == 0


def test_info(handler: RequestHandler) -> None:
    handler.claims.client_alive("a")
    call(handler, make_request("Claim", 1, client="a"))
    for key in ("nc/nc1/cmd", KEY1):
        r = call(handler, make_request("Info", 2), key=key)
        assert r["error"] == 0
        v = r["Value"]
        assert v["name"] == "nc1" and v["timing"] == "SCHED_OTHER" and v["claims"] == {1: "a"}
        assert v["clients"] == ["a"] and len(v["axes"]) == 2


def test_internal_error_becomes_a_reply(handler: RequestHandler, core: FakeCore) -> None:
    core.fail = True
    r = call(handler, make_request("Reset", 1))
    assert r["error"] == 0x4000 and "boom" in r["text"]
    assert handler.internal_errors == 1


def test_with_the_real_core_duplicate_move_runs_once() -> None:
    core = NcCore([AxisConfig(1, "X")], cycle_time=0.001)
    claims = ClaimTable([1], 0.5)
    h = RequestHandler(core, claims, Keys("nc1"))
    claims.client_alive("plc")
    assert call(h, make_request("Claim", 1, client="plc"))["error"] == 0
    rec = core.default_plctonc()
    rec["ControlDWord"] = 7
    core.set_plctonc(0, rec)
    core.step()
    req = make_request("MoveRelative", 2, client="plc", Distance=5.0, Velocity=100.0)
    r1 = call(h, req)
    core.step()
    r2 = call(h, req)
    assert r1 == r2 and r1["error"] == 0 and r1["CmdNo"] == 1
    for _ in range(2000):
        core.step()
    assert abs(float(core.nctoplc[0]["SetPos"]) - 5.0) < 1e-9
    assert int(core.nctoplc[0]["CmdNo"]) == 1


def test_claim_takes_pending_liveliness_events_before_refusing() -> None:
    """A client's token event that arrived just before its Claim must not cause a 0x723."""
    core = NcCore([AxisConfig(1)], 0.001)
    claims = ClaimTable([1], 0.5)
    pending = ["plc-a"]  # events the server has not applied yet

    def refresh() -> None:
        while pending:
            claims.client_alive(pending.pop())

    h = RequestHandler(core, claims, Keys("nc1"), refresh_liveliness=refresh)
    rep = msgpack.unpackb(h.handle("nc/nc1/axis/1/cmd", msgpack.packb({"id": 1, "client": "plc-a", "cmd": "Claim"}),
                                   0.0), strict_map_key=False)
    assert rep["error"] == 0 and claims.holder(1) == "plc-a"


class FaultCore(FakeCore):
    """FakeCore that also records fault() calls and the client of each executed request."""

    def __init__(self) -> None:
        super().__init__()
        self.faults: list[tuple[int, int]] = []
        self.clients: list[str] = []

    def fault(self, i: int, code: int) -> None:
        self.faults.append((i, code))

    def execute(self, request: dict[str, Any], axis_id: int) -> dict[str, Any]:
        self.clients.append(request["client"])
        return super().execute(request, axis_id)


def frame(arrival: float, ids: list[int], control: int) -> Any:
    recs = np.zeros(len(ids), dtype=PLCTONC_DTYPE)
    recs["ControlDWord"] = control
    return SimpleNamespace(arrival=arrival, axis_ids=np.array(ids, dtype=np.uint32), plctonc=recs)


def test_core_execute_gets_the_requests_client() -> None:
    core = FaultCore()
    h = RequestHandler(core, ClaimTable([1, 2], 0.5), Keys("nc1"))
    call(h, make_request("MoveVelocity", 1, client="plc1", Velocity=1.0))
    call(h, make_request("Reset", 2))
    assert core.clients == ["plc1", ""]


def test_cycle_inputs_apply_holders_frames_then_watchdog() -> None:
    core = FaultCore()
    claims = ClaimTable([1, 2], 0.5)
    h = RequestHandler(core, claims, Keys("nc1"))
    inputs = CycleInputs(core, claims)
    h.client_alive("a")
    h.client_alive("b")
    claims.claim(1, "a", 1.0)
    # a frame older than the claim, a non-holder's frame, unknown ids: not applied, not armed
    assert inputs.apply([("a", frame(0.5, [1], 7)), ("b", frame(1.1, [1, 2], 5)),
                         ("a", frame(1.1, [0, 99], 5))], now=1.1) == []
    assert core.plctonc["ControlDWord"].tolist() == [0, 0]
    assert inputs.apply([("a", frame(1.2, [2, 1], 7))], now=1.2) == []  # only axis 1 is a's
    assert core.plctonc["ControlDWord"].tolist() == [7, 0]
    assert inputs.apply([], now=1.7) == [] and inputs.apply([], now=1.71) == [(1, ZNC_PLCTONC_TIMEOUT)]
    assert core.faults == [(0, ZNC_PLCTONC_TIMEOUT)] and inputs.faults == 1
    assert int(core.plctonc["ControlDWord"][0]) == 0 and claims.holder(1) is None
    # client gone: 0x8F01 at the next watchdog, and its cached replies are dropped
    claims.claim(2, "b", 2.0)
    h.handle("nc/nc1/axis/2/cmd", make_request("Reset", 5, client="b"), 2.0)
    assert len(h.cache) == 1
    h.client_gone("b")
    assert len(h.cache) == 0
    assert inputs.watchdog(2.1) == [(2, ZNC_CLIENT_LOST)] and core.faults[-1] == (1, ZNC_CLIENT_LOST)
