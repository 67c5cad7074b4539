"""ZenohPort and the PLC runtime's frames without a network: replies through channels polled by the
cycle (nothing of ours on zenoh's threads), the frame key a client takes, the PLCTONC encoding."""
from __future__ import annotations

import time
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest
import zenoh
from zenoh.handlers import Callback

from nc_schema import FRAME_PERIODS_MS, IDLE_VIEW_PERIOD_MS, MAX_VIEW_AXES, VIEW_PERIODS_MS, view_period_ms, ErrorCodes, parse_view_select, Keys, encode_plc_frame, frame_period_ms, pack
from plc_client import AXIS_REF
from plc_client.runtime import PlcRuntime, ZenohPort, _NcLink, plc_frame


class _Closed(Exception):
    pass


class FakeChannel:
    """What ``session.get(key, FifoChannel(n))`` returns: try_recv() -> reply | None, raises once closed."""

    def __init__(self) -> None:
        self.replies: list[Any] = []
        self.closed = False

    def try_recv(self) -> Any:
        if self.replies:
            return self.replies.pop(0)
        if self.closed:
            raise _Closed("channel is empty and closed")
        return None


def FakeReply(payload: bytes | None) -> SimpleNamespace:
    """A zenoh Reply: ``ok`` None for an error reply, else a sample whose payload has to_bytes()."""
    if payload is None:
        return SimpleNamespace(ok=None)
    return SimpleNamespace(ok=SimpleNamespace(payload=SimpleNamespace(to_bytes=lambda: payload)))


class FakeSession:
    def __init__(self) -> None:
        self.gets: list[tuple[str, Any, FakeChannel]] = []

    def get(self, key: str, handler: Any, **kw: Any) -> FakeChannel:
        ch = FakeChannel()
        self.gets.append((key, handler, ch))
        return ch


def _port() -> tuple[ZenohPort, FakeSession]:
    link = _NcLink("nc1", "tcp/127.0.0.1:1", "t1", 1000)
    link.session = FakeSession()  # type: ignore[assignment]
    link.ready = True
    return ZenohPort("t1", {"nc1": link}), link.session  # type: ignore[return-value]


def test_replies_come_through_a_channel_polled_by_the_cycle() -> None:
    port, session = _port()
    p = port.send("nc1", 1, "Claim")
    key, handler, ch = session.gets[0]
    # no Python callable handed to zenoh: nothing of ours runs on its receive thread
    assert not isinstance(handler, Callback) and not callable(handler)
    assert port.poll() == [] and not p.done
    ch.replies.append(FakeReply(pack({"id": p.id, "error": 0, "cycle": 7})))
    ch.replies.append(FakeReply(pack({"id": p.id, "error": 0x723})))  # a second reply is ignored
    port.poll()
    assert p.done and p.error == 0 and p.reply["cycle"] == 7
    port.poll()
    assert p.error == 0


@pytest.mark.parametrize("reply, code", [(None, ErrorCodes.ADSERR_CLIENT_SYNCTIMEOUT),
                                         (b"\xc1not msgpack", ErrorCodes.ADSERR_DEVICE_INVALIDDATA),
                                         (pack([1, 2]), ErrorCodes.ADSERR_DEVICE_INVALIDDATA)])
def test_error_and_bad_replies(reply: bytes | None, code: int) -> None:
    port, session = _port()
    p = port.send("nc1", 2, "Info")
    session.gets[0][2].replies.append(FakeReply(reply))
    port.poll()
    assert p.done and p.error == code


def test_a_query_ending_without_reply_is_0x745() -> None:
    port, session = _port()
    p = port.send("nc1", 3, "Claim")
    port.poll()
    assert not p.done
    session.gets[0][2].closed = True
    port.poll()
    assert p.done and p.error == ErrorCodes.ADSERR_CLIENT_SYNCTIMEOUT
    assert port._inflight == []


def test_view_period_follows_the_plc_cycle_and_a_view_of_none_is_slow() -> None:
    assert [view_period_ms(c) for c in (0.010, 0.007, 0.004, 0.002, 0.0019, 0.001, 0.2, 5.0)] == \
        [10, 5, 2, 2, 0, 0, 100, max(VIEW_PERIODS_MS)]
    rt = PlcRuntime(None, {"nc1": "tcp/127.0.0.1:1"}, cycle_time=0.01, client_id="t8")
    link = rt.links["nc1"]
    assert rt.frame_period_ms == 10 and link.view_period == 10
    # no axes: a view of none at the slowest period (its frames only show the NC is there) ...
    assert link._view_token_keys() == [f"nc/nc1/select/t8/{IDLE_VIEW_PERIOD_MS}ms/none"] == ["nc/nc1/select/t8/100ms/none"]
    # ... an axis bound: the client's period
    link.select([3, 1])
    assert link._view_token_keys() == ["nc/nc1/select/t8/10ms/1,3"]
    link.select([])
    assert link._view_token_keys() == ["nc/nc1/select/t8/100ms/none"]


def test_frame_key_follows_the_plc_cycle() -> None:
    k = Keys("nc1")
    assert frame_period_ms(0.010) == 5 and frame_period_ms(0.004) == 2 and frame_period_ms(0.003) is None
    assert frame_period_ms(0.2) == 100 and frame_period_ms(5.0) == max(FRAME_PERIODS_MS)
    rt = PlcRuntime(None, {"nc1": "tcp/127.0.0.1:1"}, cycle_time=0.01, client_id="t2")
    assert rt.links["nc1"].frame_key == k.frame_every(5) == "nc/nc1/frame/5ms"
    rt = PlcRuntime(None, {"nc1": "tcp/127.0.0.1:1"}, cycle_time=0.001, client_id="t3")
    assert rt.links["nc1"].frame_key == k.frame and rt.frame_period_ms is None
    rt = PlcRuntime(None, {"nc1": "tcp/127.0.0.1:1"}, cycle_time=0.01, client_id="t4", frame_period=0)
    assert rt.links["nc1"].frame_key == k.frame
    with pytest.raises(ValueError):
        PlcRuntime(None, {"nc1": "tcp/127.0.0.1:1"}, cycle_time=0.01, client_id="t5", frame_period=3)
    # the view (issue 19) takes the longest period of at most one cycle (one frame per cycle on average) (0: every NC cycle); whole frames only with view=False
    assert [PlcRuntime(None, {"nc1": "tcp/127.0.0.1:1"}, cycle_time=c, client_id="t6", frame_period=f)
            .links["nc1"].view_period for c, f in ((0.01, None), (0.001, None), (0.01, 0), (0.2, 20))] == [10, 0, 0, 20]
    assert PlcRuntime(None, {"nc1": "tcp/127.0.0.1:1"}, client_id="t7", view=False).links["nc1"].view_period is None


def test_the_view_lists_the_tasks_axes_of_each_nc() -> None:
    """The view token names the AxisIds this task's AXIS_REFs use on that NC, updated when one is bound later (at the
    next cycle's frame intake); more axes than one token may list take several tokens."""
    rt = PlcRuntime(None, {"nc1": "tcp/127.0.0.1:1", "nc2": "tcp/127.0.0.1:2"}, client_id="t8",
                    axes=[AXIS_REF("nc1", 3), AXIS_REF("nc2", 1), AXIS_REF("nc1", 2), AXIS_REF("nc1", 3)])
    assert rt.links["nc1"].view_axes == (2, 3) and rt.links["nc2"].view_axes == (1,)
    rt.axis("nc2", 9)
    assert rt.links["nc2"].view_axes == (1,)  # (applied with the next frames taken)
    rt._take_frames()
    assert rt.links["nc2"].view_axes == (1, 9) and rt.links["nc1"].view_axes == (2, 3)
    for a in range(100, 100 + MAX_VIEW_AXES):  # more axes of one NC than one token lists: two tokens
        rt.axis("nc1", a)
    rt._take_frames()
    link = rt.links["nc1"]
    assert link.view_axes == (2, 3, *range(100, 100 + MAX_VIEW_AXES))
    keys = link._view_token_keys()
    assert len(keys) == 2 and all(parse_view_select(k) is not None for k in keys)
    parsed = [parse_view_select(k) for k in keys]
    assert tuple(a for p in parsed if p is not None for a in p[3]) == link.view_axes


def test_plc_frame_is_encode_plc_frame_byte_for_byte() -> None:
    axes = [AXIS_REF("nc1", a) for a in (7, 1, 65535)]
    rng = np.random.default_rng(1)
    for ax in axes:
        ax._plctonc[:] = np.frombuffer(rng.integers(0, 256, ax._plctonc.nbytes, dtype=np.uint8).tobytes(),
                                       dtype=ax._plctonc.dtype)
    for cycle in (0, 1, 2**40 + 3):
        ref = encode_plc_frame(cycle, [a.axis_id for a in axes], np.concatenate([a._plctonc for a in axes]))
        assert plc_frame(cycle, axes) == ref
    assert plc_frame(5, []) == encode_plc_frame(5, [], np.zeros(0, dtype=axes[0]._plctonc.dtype))


def test_real_zenoh_channel_semantics() -> None:
    """What _collect relies on: try_recv() None while open, raises once the query ended."""
    c = zenoh.Config()
    c.insert_json5("mode", '"peer"')
    c.insert_json5("listen/endpoints", "[]")
    c.insert_json5("connect/endpoints", "[]")
    c.insert_json5("scouting/multicast/enabled", "false")
    c.insert_json5("scouting/gossip/enabled", "false")
    with zenoh.open(c) as s:
        rx = s.get("test/nobody/here", zenoh.handlers.FifoChannel(4), timeout=0.05)
        deadline = time.monotonic() + 30.0
        while True:
            try:
                assert rx.try_recv() is None
            except zenoh.ZError:
                break
            assert time.monotonic() < deadline, "the channel of a query without replies never closed"
            time.sleep(0.01)
