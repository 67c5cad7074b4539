"""The pure decoders the fuzz targets exercise, on hostile input (no atheris needed): replies
(parse_reply, and a hostile reply failing its command with 0x706), PLCTONC frames, liveliness keys and
client ids. A finding of a fuzz target that got fixed gets its test here."""
from __future__ import annotations

from types import SimpleNamespace
from typing import Any

import msgpack
import numpy as np
import pytest

from nc_schema import (
    PLC_AXIS_RECORD_DTYPE, PLC_FRAME_HEADER_DTYPE, PLCTONC_DTYPE, ErrorCodes, Keys, encode_plc_frame, make_reply,
    pack, parse_reply,
)
from nc_server.server.config import ZenohSettings
from nc_server.server.transport import Transport, decode_plctonc, liveliness_client
from plc_client.runtime import ZenohPort

INVALID = int(ErrorCodes.ADSERR_DEVICE_INVALIDDATA)  # type: ignore[attr-defined]


# ---- replies (found by fuzz_client: a reply {"cycle": {}} or {"error": "x"} raised in the blocks) -----------
@pytest.mark.parametrize("reply", [
    {"id": 1, "cmd": "Reset", "error": 0, "text": "", "cycle": 5, "CmdNo": 3},
    make_reply(7, "Info", 0, "", 9, value={"axes": []}),
    make_reply(None, None, 0x706, "bad", 0),
])
def test_parse_reply_accepts_what_the_nc_sends(reply: dict[str, Any]) -> None:
    assert parse_reply(pack(reply)) == reply


@pytest.mark.parametrize("reply", [
    {"error": "x", "cycle": 1}, {"error": None, "cycle": 1}, {"error": 0, "cycle": {}}, {"error": 0},
    {"cycle": 1}, {"error": 1.5, "cycle": 1}, {"error": True, "cycle": 1}, {"error": -1, "cycle": 1},
    {"error": 2**32, "cycle": 1}, {"error": 0, "cycle": -3}, {"error": 0, "cycle": 1, "CmdNo": "7"},
    {"error": 0, "cycle": 1, "CmdNo": 70000}, {"error": 0, "cycle": 1, "CmdNo": None},
    {"error": 0, "cycle": 1, "text": 5}, [0, 1], "reply", 3,
])
def test_parse_reply_refuses_what_the_blocks_cannot_act_on(reply: Any) -> None:
    with pytest.raises(ValueError):
        parse_reply(msgpack.packb(reply))


@pytest.mark.parametrize("raw", [b"", b"\xc1", b"\x81", b"\xdf\xff\xff\xff\xff"])
def test_parse_reply_refuses_non_msgpack(raw: bytes) -> None:
    with pytest.raises(ValueError):
        parse_reply(raw)


class _Session:
    """``get`` answers with one reply carrying ``payload`` (the reply channel ZenohPort polls)."""

    def __init__(self, payload: bytes) -> None:
        self.payload = payload

    def get(self, key: str, handler: Any, **kw: Any) -> Any:
        replies = [SimpleNamespace(ok=SimpleNamespace(payload=SimpleNamespace(to_bytes=lambda: self.payload)))]

        def try_recv() -> Any:
            if replies:
                return replies.pop()
            raise RuntimeError("channel is empty and closed")
        return SimpleNamespace(try_recv=try_recv)


@pytest.mark.parametrize("reply", [{"id": 1, "error": "x", "cycle": 1}, {"id": 1, "error": 0, "cycle": {}},
                                   {"id": 1, "error": 0, "cycle": 2, "CmdNo": [1]}])
def test_a_hostile_reply_fails_the_command_with_0x706(reply: dict[str, Any]) -> None:
    link = SimpleNamespace(ready=True, session=_Session(msgpack.packb(reply)), keys=Keys("nc1"))
    port = ZenohPort("plc1", {"nc1": link})  # type: ignore[dict-item]
    p = port.send("nc1", 1, "Reset")
    port.poll()
    assert p.done and p.reply is None and p.error == INVALID


def test_a_good_reply_is_delivered() -> None:
    link = SimpleNamespace(ready=True, session=_Session(pack(make_reply(1, "Reset", 0, "", 4))), keys=Keys("nc1"))
    port = ZenohPort("plc1", {"nc1": link})  # type: ignore[dict-item]
    p = port.send("nc1", 1, "Reset")
    port.poll()
    assert p.done and p.error == 0 and p.reply["cycle"] == 4  # type: ignore[index]


# ---- PLCTONC decode (factored out of Transport._on_plctonc for the fuzz target) --------------------------
MAX = PLC_FRAME_HEADER_DTYPE.itemsize + 4 * PLC_AXIS_RECORD_DTYPE.itemsize


def _frame(ids: list[int]) -> bytes:
    recs = np.zeros(len(ids), dtype=PLCTONC_DTYPE)
    recs["Override"] = 1_000_000
    recs["ControlDWord"] = 7
    return encode_plc_frame(3, ids, recs)


def test_decode_plctonc_keeps_its_behaviour() -> None:
    f = decode_plctonc(_frame([2, 1]), 12.5, MAX)
    assert f.arrival == 12.5 and f.axis_ids.tolist() == [2, 1]
    assert f.plctonc["ControlDWord"].tolist() == [7, 7] and f.plctonc.dtype == PLCTONC_DTYPE
    assert decode_plctonc(_frame([]), 0.0, MAX).axis_ids.size == 0


@pytest.mark.parametrize("payload", [_frame([1, 1]), _frame([1, 2, 3, 4, 5]), _frame([1])[:-1], _frame([1]) + b"\0",
                                     b"", b"\0" * 24, b"PPC1" + b"\0" * 20])
def test_decode_plctonc_refuses_with_value_error(payload: bytes) -> None:
    with pytest.raises(ValueError):
        decode_plctonc(payload, 0.0, MAX)


# ---- liveliness keys ---------------------------------------------------------------------------------------
KEYS = Keys("nc1")


@pytest.mark.parametrize("key, client", [
    ("nc/nc1/client/plc1", "plc1"), ("nc/nc1/client/a.b-c_D9", "a.b-c_D9"), ("nc/nc1/client/" + "x" * 64, "x" * 64),
    ("nc/nc1/client/" + "x" * 65, None), ("nc/nc1/client/pl c", None), ("nc/nc1/client/plc\u00e9", None),
    ("nc/nc1/client/", None), ("nc/nc2/client/plc1", None), ("nc/nc1/clients/plc1", None),
    ("nc/nc1/client/a/b", None), ("plc1", None), ("", None), ("nc/nc1/axis/1/client/plc1", None),
])
def test_liveliness_client(key: str, client: str | None) -> None:
    assert liveliness_client(KEYS, key) == client


def test_a_token_with_an_invalid_client_id_is_ignored() -> None:
    t = Transport(ZenohSettings(), KEYS, [1, 2])

    def sample(key: str, kind: Any) -> Any:
        return SimpleNamespace(key_expr=key, kind=kind)

    import zenoh
    t._on_liveliness(sample("nc/nc1/client/plc1", zenoh.SampleKind.PUT))
    t._on_liveliness(sample("nc/nc1/client/pl\u00e9", zenoh.SampleKind.PUT))
    t._on_liveliness(sample("nc/nc1/client/plc1", zenoh.SampleKind.DELETE))
    assert t.pop_liveliness() == [("plc1", True), ("plc1", False)]
    assert t.liveliness_ignored == 1


# ---- client ids and NC names (found by fuzz_keys: "plc1\n" passed check_client_id, its keys did not parse) ----
@pytest.mark.parametrize("bad", ["plc1\n", "nc1\n", "\nplc1", "plc1\r", "plc1\n\n", "x" * 64 + "\n"])
def test_a_trailing_newline_is_not_part_of_a_valid_id(bad: str) -> None:
    from nc_schema import check_client_id
    with pytest.raises(ValueError):
        check_client_id(bad)
    with pytest.raises(ValueError):
        Keys(bad)
    assert liveliness_client(KEYS, f"nc/nc1/client/{bad}") is None


def test_every_valid_client_id_makes_keys_that_parse_back() -> None:
    for client in ("plc1", "a", "x" * 64, "A.b-c_9"):
        key = KEYS.command_key("Reset", 1, client)
        assert KEYS.parse_cmd_key(key) == (1, "op", client)
        assert liveliness_client(KEYS, KEYS.client_alive(client)) == client
