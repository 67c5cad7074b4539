"""nc_link without a network: the NC's events and restart rule as the link reports them, a door's supplies,
the blocking command's error codes."""
from __future__ import annotations

from types import SimpleNamespace
from typing import Any

import pytest
import zenoh

from nc_link import CommandError, LinkEvent, NcLink, Supplies
from nc_link.link import ALIVE, BACK, GONE, RESTART
from nc_schema import ErrorCodes, Keys, pack

A, B = "0123456789abcdef", "fedcba9876543210"


class _Channel:
    def __init__(self, *items: Any) -> None:
        self.items = list(items)

    def try_recv(self) -> Any:
        return self.items.pop(0) if self.items else None


def _ev(key: str, kind: Any = zenoh.SampleKind.PUT) -> SimpleNamespace:
    return SimpleNamespace(key_expr=key, kind=kind)


def _link() -> NcLink:
    link = NcLink("nc1", "tcp/127.0.0.1:9", "door1")
    link.alive_sub, link.instance_sub = _Channel(), _Channel()
    return link


def test_liveliness_gone_back_and_restarts_once_whichever_evidence_comes_first() -> None:
    link, k = _link(), Keys("nc1")
    link.alive_sub.items += [_ev(k.alive), _ev(k.alive, zenoh.SampleKind.DELETE), _ev(k.alive)]
    link.instance_sub.items += [_ev(k.alive_instance(A))]
    assert link.take_events() == [LinkEvent(ALIVE), LinkEvent(GONE), LinkEvent(BACK)]  # the first id: adopted
    # the same id back, a malformed one, another NC's: nothing
    link.instance_sub.items += [_ev(k.alive_instance(A)), _ev("nc/nc1/alive/NOT-AN-ID"),
                                _ev(Keys("nc2").alive_instance(B))]
    assert link.take_events() == [] and link.restarts == 0
    assert link.follow_frame(100, 0) == (True, None)
    link.instance_sub.items += [_ev(k.alive_instance(B))]
    (ev,) = link.take_events()
    assert ev.kind == RESTART and B in ev.why and link.restarts == 1
    assert link.follow_frame(1, 0) == (True, None) and link.restarts == 1  # the new instance's first frame: counted once
    assert link.follow_frame(0, 0)[1] is not None and link.restarts == 2  # the cycle going back again: another one


def test_take_claims_reads_the_map_and_ignores_garbage() -> None:
    link = _link()
    sample = lambda b: SimpleNamespace(payload=SimpleNamespace(to_bytes=lambda: b))  # noqa: E731
    link.claims_sub = _Channel(sample(pack({"cycle": 9, "claims": {"1": "door1", 2: "plc1"}})), sample(b"\xc1"))
    assert link.take_claims() == (9, {1: "door1", 2: "plc1"})
    assert link.take_claims() is None and link.take_claims() is None


def test_supplies_machine() -> None:
    s = Supplies()
    rec = bytearray(128)
    rec[0] = 0x7  # Enable and feed enables
    s.start(1, rec, owner=5, claim_cycle=10)
    s.start(2, bytearray(128), owner=6, claim_cycle=10)
    assert s.owned_by(5) == [(1, True)] and s.owned_by(6) == [(2, False)]
    assert s.change(1, lambda r: r.__setitem__(4, 1), owner=6) == 5 and s.owned_by(6) == [(1, True), (2, False)]
    assert s.change(3, lambda r: None, owner=6) is None
    assert s.disable(1, owner=6, periods=1)
    assert s.due() == ([(1, bytes(s.axes[1].record)), (2, bytes(128))], [])
    assert s.due()[1] == [1] and s.axes[1].record[0] == 0  # enables off, then released with the next period
    assert s.end_lost(10, {}, "door1") == []  # a map of the claim's own cycle cannot tell
    assert s.end_lost(11, {1: "door1"}, "door1") == [2]
    assert s.take(1, owner=5) is None and s.take(1, owner=6) is not None and not s
    s.start(4, bytearray(128), 1, 0)
    assert s.end_all() == [4] and not s


class _Session:
    def __init__(self, replies: list[Any]) -> None:
        self.replies = replies

    def get(self, key: str, **kw: Any) -> list[Any]:
        return self.replies


def _ok(payload: bytes) -> SimpleNamespace:
    return SimpleNamespace(ok=SimpleNamespace(payload=SimpleNamespace(to_bytes=lambda: payload)))


@pytest.mark.parametrize("replies, code", [
    ([_ok(pack({"id": 1, "error": 0x723, "cycle": 1, "text": "held by plc1"}))], 0x723),
    ([SimpleNamespace(ok=None)], ErrorCodes.ADSERR_DEVICE_NOTREADY),
    ([_ok(b"\xc1")], ErrorCodes.ADSERR_DEVICE_INVALIDDATA),
    ([], ErrorCodes.ADSERR_DEVICE_NOTREADY),  # ended at once without a reply: no route or denied
])
def test_request_error_codes(replies: list[Any], code: int) -> None:
    link = _link()
    link.session = _Session(replies)  # type: ignore[assignment]
    with pytest.raises(CommandError) as ei:
        link.request("Claim", 1)
    assert ei.value.code == code


def test_request_without_session_is_not_ready_and_a_reply_is_returned() -> None:
    link = _link()
    with pytest.raises(CommandError) as ei:
        link.request("Info", None)
    assert ei.value.code == ErrorCodes.ADSERR_DEVICE_NOTREADY
    link.session = _Session([_ok(pack({"id": 1, "error": 0, "cycle": 3}))])  # type: ignore[assignment]
    assert link.request("Info", None)["cycle"] == 3


# ---- the epoch (protocol 5): frames of a lower epoch than the highest seen are dropped and counted --------------
E1, E2 = (1 << 16) | 0x1234, (2 << 16) | 0x0042


def test_follow_frame_drops_a_lower_epoch_counts_it_and_sees_no_restart() -> None:
    link, k = _link(), Keys("nc1")
    link.instance_sub.items += [_ev(k.alive_instance(A))]
    link.take_events()
    assert link.follow_frame(1000, E1) == (True, None)
    assert link.follow_frame(1001, E2) == (True, None)  # the takeover: taken at once, the Cycle continues
    assert link.follow_frame(980, E1) == (False, None)  # the old active NC after a link cut: its Cycle behind
    assert link.follow_frame(1002, E2) == (True, None)
    assert link.stats() == {"restarts": 0, "epoch": E2, "stale_epoch_frames": 1, "epoch_rises": 1, "epoch_falls": 0}
    # the pair restarted (a new instance, epoch 0): its token opens the epoch, its first frame is taken, one restart
    link.instance_sub.items += [_ev(k.alive_instance(B))]
    assert [e.kind for e in link.take_events()] == [RESTART]
    assert link.follow_frame(3, 0) == (True, None)
    assert link.stats()["epoch"] == 0 and link.restarts == 1 and link.stats()["epoch_falls"] == 1


def test_a_door_keeps_the_image_of_the_highest_epoch() -> None:
    """NcDoor (nc-ads's, nc-opcua's link): a frame of a lower epoch does not replace the image and ends no
    supplies (no restart)."""
    import numpy as np

    from nc_link.door import NcDoor
    from nc_schema import NCTOPLC_DTYPE, encode_frame

    door = NcDoor("nc1", "tcp/127.0.0.1:9", "door1")
    restarts: list[int] = []
    door.on_restart.append(lambda: restarts.append(1))
    link = door.link
    link.alive_sub, link.instance_sub, link.claims_sub = _Channel(), _Channel(), _Channel()

    def frame(cycle: int, epoch: int, set_pos: float) -> SimpleNamespace:
        recs = np.zeros(1, dtype=NCTOPLC_DTYPE)
        recs["AxisId"], recs["SetPos"] = 1, set_pos
        data = encode_frame(cycle, cycle, recs, epoch=epoch)
        return SimpleNamespace(payload=SimpleNamespace(to_bytes=lambda: data))

    for f, cycle in ((frame(500, E1, 1.0), 500), (frame(501, E2, 2.0), 501), (frame(400, E1, 9.0), 501)):
        link.frames = _Channel(f)
        door._step()
        assert door.image is not None and door.image.cycle == cycle
    assert restarts == [] and link.stats()["stale_epoch_frames"] == 1
    assert np.frombuffer(door.image.records[1], dtype=NCTOPLC_DTYPE)["SetPos"][0] == 2.0
