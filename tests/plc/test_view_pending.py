"""An axis bound while the PLC runs and its client's view (issue 19): the NC's view frames say which axes they
were cut for (their attachment). An axis outside them is not yet in the view (the NC has not seen the new
token): no data, ``pending``, and a block called on it waits, its call not evaluated, for at most the task's
command_timeout. An axis inside them that the frame lacks is not on that NC: 0x4012."""
from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from nc_schema import NCTOPLC_DTYPE, ErrorCodes, encode_frame, parse_view_axes, view_axes_text
from plc_client import AXIS_REF, MC_ReadStatus, MC_Reset, PlcTask
from plc_client.port import CommandPort

IDLE = 0x1 | 0x2 | 0x8  # (operational, homed, not moving): a valid axis's StateDWord


class _Port(CommandPort):
    def __init__(self) -> None:
        super().__init__("t")
        self.sent: list[bytes] = []

    def _transmit(self, pending: Any, payload: bytes) -> None:
        self.sent.append(payload)


def _task() -> tuple[PlcTask, _Port]:
    t = PlcTask(None, client_id="t")
    port = t.port = _Port()
    t._take_frames = lambda: None  # type: ignore[method-assign]
    return t, port


def _recs(ids: list[int]) -> np.ndarray:
    recs = np.zeros(len(ids), dtype=NCTOPLC_DTYPE)
    recs["AxisId"] = ids
    recs["StateDWord"] = IDLE
    return recs


@pytest.mark.parametrize("as_bytes", [False, True])
def test_an_axis_outside_the_view_waits_one_inside_it_but_absent_is_0x4012(as_bytes: bool) -> None:
    t, port = _task()
    a2 = t.axis("nc1", 2)
    cycle = 10

    def frame(ids: list[int], covers: set[int] | None) -> None:
        nonlocal cycle
        cycle += 1
        c = None if covers is None else frozenset(covers)
        if as_bytes:
            t._set_frame_bytes("nc1", encode_frame(cycle, cycle * 1000, _recs(ids)), c)
        else:
            t._set_frame("nc1", cycle, _recs(ids), None, c)

    frame([2], {2})
    t.step()
    assert a2.Status.Valid and not a2.pending and not a2.missing
    # bound while running: the frames do not cover it yet
    a9 = t.axis("nc1", 9)
    reset = MC_Reset()
    status = MC_ReadStatus()
    t._call = lambda plc: (reset(Axis=a9, Execute=True), status(Axis=a9, Enable=True))
    for _ in range(3):
        frame([2], {2})
        t.step()
        assert a9.pending and not a9.missing and not a9.Status.Valid
        # the calls wait: no output, nothing sent
        assert not (reset.Busy or reset.Error or status.Busy or status.Error or status.Valid)
        assert port.sent == []
    # the view now has it: the edge is taken at this call, the command goes out
    frame([2, 9], {2, 9})
    t.step()
    assert a9.Status.Valid and not a9.pending
    assert reset.Busy and not reset.Error and len(port.sent) == 1
    assert status.Valid and not status.Error
    # covered but absent: the NC has no such axis
    a7 = t.axis("nc1", 7)
    ping = MC_Reset()
    t._call = lambda plc: ping(Axis=a7, Execute=True)
    frame([2, 9], {2, 9, 7})
    t.step()
    assert a7.missing and not a7.pending
    assert ping.Error and ping.ErrorID == ErrorCodes.NC_AXIS_ID_NOT_ALLOWED


def test_the_wait_ends_after_command_timeout_as_stale_data() -> None:
    t, port = _task()
    t._set_frame("nc1", 1, _recs([2]), None, frozenset({2}))
    t.step()
    a9 = t.axis("nc1", 9)
    reset = MC_Reset()
    t._call = lambda plc: reset(Axis=a9, Execute=True)
    t._set_frame("nc1", 2, _recs([2]), None, frozenset({2}))
    t.step()
    assert a9.pending and not reset.Busy and not reset.Error
    a9._pending_until = 0.0  # (command_timeout has passed since the binding)
    t._set_frame("nc1", 3, _recs([2]), None, frozenset({2}))
    t.step()
    assert not a9.pending and not a9.missing
    assert reset.Error and reset.ErrorID == ErrorCodes.MC_NO_NC_CYCLE_UPDATE and port.sent == []


def test_a_whole_frame_without_the_axis_is_0x4012_at_once() -> None:
    """Whole frames (covers None) list every axis of the NC: one they lack is not there."""
    t, _ = _task()
    a9 = t.axis("nc1", 9)
    t._set_frame("nc1", 1, _recs([2]), None, None)
    t.step()
    assert a9.missing and not a9.pending


@pytest.mark.parametrize("ids", [[], [1], [3, 1, 2, 3], list(range(1, 700))])
def test_view_attachment_round_trip(ids: list[int]) -> None:
    text = view_axes_text(ids)
    assert parse_view_axes(text.encode()) == frozenset(ids)
    assert parse_view_axes(text) == frozenset(ids)


@pytest.mark.parametrize("bad", [b"", b"x", b"1,,2", b"1,70000", b"-1", b"\xff", b"none,1"])
def test_view_attachment_malformed_is_none(bad: bytes) -> None:
    assert parse_view_axes(bad) is None
