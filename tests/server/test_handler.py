"""Request handling: parsing errors, key identity and class checks, dedup, Claim/Release/Info/SetOverride (no zenoh)."""
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

KEYS = Keys("nc1")
KEY1 = "nc/nc1/axis/1/cmd/op/t"  # axis 1, class op, client "t"


def key(cmd: str, axis: int | None = 1, client: str = "t") -> str:
    """The command key of ``cmd`` (its class) from ``client``."""
    return KEYS.command_key(cmd, axis, client)


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


def call(h: RequestHandler, payload: bytes, key: str | None = None) -> dict[str, Any]:
    """Handle ``payload`` on ``key`` (default: the key of its command from client "t", or of its
    ``client`` field, on axis 1)."""
    if key is None:
        try:
            msg = msgpack.unpackb(payload, raw=False)
            cmd = msg.get("cmd") if isinstance(msg, dict) else None
            client = msg.get("client") if isinstance(msg, dict) else None
        except Exception:
            cmd = client = None
        ok = isinstance(client, str) and client.replace("-", "").replace("_", "").replace(".", "").isalnum()
        key = KEYS.command_key(cmd if isinstance(cmd, str) else "Reset", 1, client if ok else "t")
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


@pytest.mark.parametrize("bad", [
    "nc/nc1/foo/cmd/op/t", "nc/nc1/axis/1/cmd", "nc/nc1/cmd", "nc/nc1/axis/01/cmd/op/t", "nc/nc1/axis/+1/cmd/op/t",
    "nc/nc1/axis/x/cmd/op/t", "nc/nc1/axis/1/cmd/admin/t", "nc/nc1/axis/1/cmd/op/a b", "nc/nc1/axis/1/cmd/op/t/x",
    "nc/nc2/axis/1/cmd/op/t", "nc/nc1/axis//cmd/op/t", "nc/nc1/axis/1/cmd/op/", "nc/nc1/**",
])
def test_bad_keys(handler: RequestHandler, core: FakeCore, bad: str) -> None:
    r = call(handler, make_request("Reset", 1), key=bad)
    assert r["error"] == 0x4012 and r["text"], r
    assert core.calls == []


def test_axis_command_on_the_nc_key(handler: RequestHandler, core: FakeCore) -> None:
    r = call(handler, make_request("Reset", 2), key="nc/nc1/cmd/op/t")
    assert r["error"] == 0x4012 and "axis/<id>/cmd/op/t" in r["text"]
    assert core.calls == []


@pytest.mark.parametrize("cmd, args", [("Info", {}), ("ReadParameter", {"ParameterNumber": 1003}), ("Reset", {}),
                                       ("Claim", {})])
def test_unknown_axes_are_refused_for_every_command(handler: RequestHandler, core: FakeCore, cmd: str,
                                                    args: dict[str, Any]) -> None:
    """Regression: Info was answered on the keys of axes that do not exist, axis/01 taken as axis 1."""
    for axis_key in ("nc/nc1/axis/9", "nc/nc1/axis/0", "nc/nc1/axis/01", "nc/nc1/axis/001"):
        cls = KEYS.command_key(cmd, 1, "t").split("/cmd/")[1]
        r = call(handler, make_request(cmd, 1, **args), key=f"{axis_key}/cmd/{cls}")
        assert r["error"] == 0x4012 and r["id"] == 1, (axis_key, r)
    assert core.calls == [] and handler.claims.claims() == {}


@pytest.mark.parametrize("cmd, args, right", [
    ("WriteParameter", {"ParameterNumber": 1003, "Value": 1.0}, "eng"),
    ("SetActualPosition", {"Position": 1.0}, "eng"),
    ("SetActualPositionOnTheFly", {"ActualPosition": 1.0, "PreviousPosition": 0.0}, "eng"),
    ("SetReferenceFlag", {"ReferenceFlag": True}, "eng"),
    ("MoveAbsolute", {"Position": 1.0, "Velocity": 1.0}, "op"),
    ("Claim", {}, "op"),
    ("Reset", {}, "op"),
    ("ReadParameter", {"ParameterNumber": 1003}, "read"),
])
def test_a_command_on_another_class_key_is_refused(handler: RequestHandler, core: FakeCore, cmd: str,
                                                  args: dict[str, Any], right: str) -> None:
    handler.claims.client_alive("t")
    for cls in ("read", "op", "eng"):
        if cls == right:
            continue
        r = call(handler, make_request(cmd, 1, **args), key=f"nc/nc1/axis/1/cmd/{cls}/t")
        assert r["error"] == 0x723 and f"class {right!r}" in r["text"] and f"/cmd/{right}/t" in r["text"], r
    assert core.calls == [] and handler.claims.claims() == {} and handler.denied == 2
    assert call(handler, make_request(cmd, 2, **args), key=f"nc/nc1/axis/1/cmd/{right}/t")["error"] == 0


def test_the_client_field_must_match_the_key(handler: RequestHandler, core: FakeCore) -> None:
    claims = handler.claims
    claims.client_alive("plc1")
    claims.client_alive("plc2")
    assert call(handler, make_request("Claim", 1), key=key("Claim", client="plc2"))["error"] == 0
    # plc1 cannot act as plc2: a request naming plc2 on plc1's key is refused, nothing runs
    for cmd, args in (("Release", {}), ("SetOverride", {"Override": 5.0}), ("MoveVelocity", {"Velocity": 1.0})):
        r = call(handler, make_request(cmd, 2, client="plc2", **args), key=key(cmd, client="plc1"))
        assert r["error"] == 0x723 and "'plc2'" in r["text"] and "'plc1'" in r["text"], r
    assert claims.holder(1) == "plc2" and core.calls == []
    # on its own key, plc1 is plc1: Release is refused because plc2 holds the axis
    r = call(handler, make_request("Release", 3), key=key("Release", client="plc1"))
    assert r["error"] == 0x723 and claims.holder(1) == "plc2"
    # the field may name the key's client
    assert call(handler, make_request("Release", 4, client="plc2"), key=key("Release", client="plc2"))["error"] == 0
    assert claims.holder(1) is None


def test_the_core_gets_the_keys_client(core: FakeCore) -> None:
    fc = FaultCore()
    h = RequestHandler(fc, ClaimTable([1, 2], 0.5), Keys("nc1"))
    call(h, make_request("MoveVelocity", 1, Velocity=1.0), key=key("MoveVelocity", client="plc7"))
    call(h, make_request("MoveVelocity", 2, client="plc8", Velocity=1.0), key=key("MoveVelocity", client="plc8"))
    assert fc.clients == ["plc7", "plc8"]


def test_roles_file_is_enforced(core: FakeCore) -> None:
    h = RequestHandler(core, ClaimTable([1, 2], 0.5), Keys("nc1"),
                       roles={"obs": "observer", "op1": "operator", "eng1": "engineer"})
    write = {"ParameterNumber": 1003, "Value": 1.0}
    assert call(h, make_request("ReadParameter", 1, ParameterNumber=1003), key=key("ReadParameter", client="obs"))["error"] == 0
    r = call(h, make_request("Reset", 2), key=key("Reset", client="obs"))
    assert r["error"] == 0x723 and "observer" in r["text"]
    assert call(h, make_request("Reset", 3), key=key("Reset", client="op1"))["error"] == 0
    r = call(h, make_request("WriteParameter", 4, **write), key=key("WriteParameter", client="op1"))
    assert r["error"] == 0x723 and "operator" in r["text"] and "engineer" in r["text"]
    assert call(h, make_request("WriteParameter", 5, **write), key=key("WriteParameter", client="eng1"))["error"] == 0
    r = call(h, make_request("Info", 6), key=key("Info", None, client="stranger"))
    assert r["error"] == 0x723 and "roles file" in r["text"]
    assert core.calls == [("ReadParameter", 1), ("Reset", 1), ("WriteParameter", 1)]
    with pytest.raises(ValueError):
        RequestHandler(core, ClaimTable([1], 0.5), Keys("nc1"), roles={"x": "admin"})


def test_arbitration_map(core: FakeCore) -> None:
    h = RequestHandler(core, ClaimTable([1, 2], 0.5), Keys("nc1"))
    h.client_alive("plc1")
    h.client_alive("idle")
    call(h, make_request("Claim", 1), key=key("Claim", 1, "plc1"))
    call(h, make_request("ReadParameter", 2, ParameterNumber=1), key=key("ReadParameter", 2, "plc1"))
    call(h, make_request("MoveVelocity", 3, Velocity=1.0), key=key("MoveVelocity", 2, "plc1"))
    call(h, make_request("ReadParameter", 4, ParameterNumber=1), key=key("ReadParameter", 1, "status"))
    call(h, make_request("WriteParameter", 5, ParameterNumber=1003, Value=1.0), key=key("WriteParameter", 1, "eng1"))
    core.cycle = 20
    call(h, make_request("Reset", 6), key=key("Reset", 2, "eng1"))
    call(h, make_request("Claim", 7), key=key("Claim", 2, "nobody"))  # refused (no token): not a last command
    a = h.arbitration()
    assert a["cycle"] == 20 and a["claims"] == {1: "plc1"}
    assert a["clients"] == {
        "eng1": {"alive": False, "role": "engineer", "role_source": "seen"},
        "idle": {"alive": True, "role": None, "role_source": "seen"},
        "nobody": {"alive": False, "role": "operator", "role_source": "seen"},
        "plc1": {"alive": True, "role": "operator", "role_source": "seen"},
        "status": {"alive": False, "role": "observer", "role_source": "seen"},
    }
    assert a["last_command"] == {1: {"client": "eng1", "cmd": "WriteParameter", "cycle": 11},
                                 2: {"client": "eng1", "cmd": "Reset", "cycle": 21}}
    info = call(h, make_request("Info", 8), key=key("Info", None, "status"))["Value"]
    assert info["arbitration"]["last_command"] == {1: {"client": "eng1", "cmd": "WriteParameter", "cycle": 11},
                                                   2: {"client": "eng1", "cmd": "Reset", "cycle": 21}}
    # with a roles file the role is the file's (None: unlisted)
    h2 = RequestHandler(core, ClaimTable([1, 2], 0.5), Keys("nc1"), roles={"plc1": "operator"})
    h2.client_alive("plc1")
    h2.client_alive("ghost")
    assert h2.arbitration()["clients"] == {"ghost": {"alive": True, "role": None, "role_source": "roles"},
                                           "plc1": {"alive": True, "role": "operator", "role_source": "roles"}}


def test_seen_clients_are_bounded(core: FakeCore) -> None:
    from nc_server.server.handler import MAX_SEEN
    h = RequestHandler(core, ClaimTable([1, 2], 0.5), Keys("nc1"))
    h.client_alive("keep")
    call(h, make_request("Info", 1), key=key("Info", None, "keep"))
    for n in range(MAX_SEEN + 50):
        call(h, make_request("Info", 1), key=key("Info", None, f"c{n}"))
    assert len(h.seen) == MAX_SEEN and "keep" in h.seen and f"c{MAX_SEEN + 49}" in h.seen


def test_request_id_is_echoed_on_errors(handler: RequestHandler) -> None:
    assert call(handler, make_request("MoveAbsolute", "abc", Position=1.0))["id"] == "abc"


def test_dedup_by_key_client_and_id(handler: RequestHandler, core: FakeCore) -> None:
    req = make_request("MoveRelative", 7, Distance=1.0, Velocity=1.0)
    first = handler.handle(key("MoveRelative", client="plc1"), req, 1.0)
    core.cycle += 5
    second = handler.handle(key("MoveRelative", client="plc1"), req, 2.0)
    assert first == second  # the cached reply, byte for byte
    assert core.calls == [("MoveRelative", 1)]
    # Another client (the key's), or another id, is executed.
    handler.handle(key("MoveRelative", client="plc2"), req, 3.0)
    handler.handle(key("MoveRelative", client="plc1"), make_request("MoveRelative", 8, Distance=1.0, Velocity=1.0), 3.0)
    assert len(core.calls) == 3
    # Another client cannot fill plc1's cache entries: a request naming plc1 on plc2's key is refused.
    assert call(handler, make_request("MoveRelative", 9, client="plc1", Distance=1.0, Velocity=1.0),
                key=key("MoveRelative", client="plc2"))["error"] == 0x723
    assert call(handler, make_request("MoveRelative", 9, Distance=1.0, Velocity=1.0),
                key=key("MoveRelative", client="plc1"))["error"] == 0
    assert len(core.calls) == 4
    # Reads are never cached: the same id reads afresh.
    handler.handle(key("ReadParameter", client="plc1"), make_request("ReadParameter", 7, ParameterNumber=1), 4.0)
    handler.handle(key("ReadParameter", client="plc1"), make_request("ReadParameter", 7, ParameterNumber=1), 4.0)
    assert len(core.calls) == 6
    # A client whose session ended may restart its ids.
    handler.cache.forget_client("plc1")
    handler.handle(key("MoveRelative", client="plc1"), req, 5.0)
    assert len(core.calls) == 7


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
    assert call(handler, make_request("Claim", 5, client="a"), key="nc/nc1/axis/9/cmd/op/a")["error"] == 0x4012
    # SetOverride: the holder, or anyone while unclaimed.
    assert call(handler, make_request("SetOverride", 6, client="b", Override=50.0))["error"] == 0x723
    assert call(handler, make_request("SetOverride", 7, Override=50.0))["error"] == 0x723
    assert call(handler, make_request("SetOverride", 8, client="a", Override=50.0))["error"] == 0
    assert call(handler, make_request("SetOverride", 9, Override=50.0), key="nc/nc1/axis/2/cmd/op/t")["error"] == 0
    # Release by another client is refused; by the holder it applies the default PLCTONC.
    core.plctonc[0]["ControlDWord"] = 7
    assert call(handler, make_request("Release", 10, client="b"))["error"] == 0x723
    assert call(handler, make_request("Release", 11, client="a"))["error"] == 0
    assert int(core.plctonc[0]["ControlDWord"]) == 0 and int(core.plctonc[0]["Override"]) == 1_000_000
    assert call(handler, make_request("Claim", 12, client="b"))["error"] == 0


def test_info(handler: RequestHandler) -> None:
    handler.claims.client_alive("a")
    call(handler, make_request("Claim", 1, client="a"))
    for k in ("nc/nc1/cmd/read/t", "nc/nc1/axis/1/cmd/read/t"):
        r = call(handler, make_request("Info", 2), key=k)
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
    rep = msgpack.unpackb(h.handle("nc/nc1/axis/1/cmd/op/plc-a", msgpack.packb({"id": 1, "client": "plc-a", "cmd": "Claim"}),
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
    h.handle("nc/nc1/axis/2/cmd/op/b", make_request("Reset", 5, client="b"), 2.0)
    assert len(h.cache) == 1
    h.client_gone("b")
    assert len(h.cache) == 0
    assert inputs.watchdog(2.1) == [(2, ZNC_CLIENT_LOST)] and core.faults[-1] == (1, ZNC_CLIENT_LOST)


def test_every_access_denied_names_the_rule_that_refused(core: FakeCore) -> None:
    """0x723 texts say which rule refused (role, class key, client id, liveliness, claim holder), and
    none says the axis is claimed when nobody holds it."""
    claims = ClaimTable([1, 2], 0.5)
    h = RequestHandler(core, claims, Keys("nc1"), roles={"obs": "observer", "op1": "operator", "op2": "operator"})
    texts = {}
    texts["role"] = call(h, make_request("Reset", 1), key=key("Reset", client="obs"))
    texts["roles file"] = call(h, make_request("Reset", 2), key=key("Reset", client="nobody"))
    texts["class key"] = call(h, make_request("Reset", 3), key=KEYS.axis_cmd(1, "eng", "op1"))
    texts["client id"] = call(h, make_request("Reset", 4, client="op2"), key=key("Reset", client="op1"))
    texts["liveliness"] = call(h, make_request("Claim", 5), key=key("Claim", client="op1"))
    claims.client_alive("op1")
    claims.client_alive("op2")
    assert call(h, make_request("Claim", 6), key=key("Claim", client="op1"))["error"] == 0
    texts["claim"] = call(h, make_request("Claim", 7), key=key("Claim", client="op2"))
    for rule, r in texts.items():
        assert r["error"] == 0x723, (rule, r)
        assert f"{rule.split()[0]}" in r["text"], (rule, r["text"])
        if rule != "claim":
            assert "claimed" not in r["text"] and "held by" not in r["text"], (rule, r["text"])
    assert "'op1'" in texts["claim"]["text"] and "held by" in texts["claim"]["text"]  # who holds it
    assert "observer" in texts["role"]["text"] and "'op'" in texts["role"]["text"]  # the role and the class
