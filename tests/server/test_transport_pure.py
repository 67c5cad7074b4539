"""Pieces of the transport that need no network: the zenoh config."""
from __future__ import annotations

import json

from nc_server.server.config import ZenohSettings
from nc_server.server.transport import zenoh_config


def test_zenoh_config_is_explicit() -> None:
    c = zenoh_config(ZenohSettings("router", ("tcp/127.0.0.1:17447",), (), 750))
    assert json.loads(c.get_json("mode")) == "router"
    assert json.loads(c.get_json("listen/endpoints")) == ["tcp/127.0.0.1:17447"]
    assert json.loads(c.get_json("scouting/multicast/enabled")) is False
    assert json.loads(c.get_json("scouting/gossip/enabled")) is False
    assert json.loads(c.get_json("transport/link/tx/lease")) == 750


def test_nc_behind_a_router_retries_a_lost_connection_every_100_to_250_ms() -> None:
    """``--mode client --connect EP``: zenoh's default retry (1 s, doubling up to 4 s) made a
    router restart cost the NC seconds; the NC uses the PLC's 100-250 ms."""
    c = zenoh_config(ZenohSettings("client", (), ("tcp/127.0.0.1:17447",), 500))
    assert json.loads(c.get_json("connect/endpoints")) == ["tcp/127.0.0.1:17447"]
    retry = json.loads(c.get_json("connect/retry"))
    assert retry["period_init_ms"] == 100 and retry["period_max_ms"] == 250, retry
    assert retry["period_increase_factor"] == 1.5
    # a router NC without connect endpoints keeps zenoh's defaults there
    r = zenoh_config(ZenohSettings("router", ("tcp/127.0.0.1:17447",), (), 500))
    assert json.loads(r.get_json("connect/endpoints")) == []


def test_one_client_config_for_plc_tools_and_host_tests() -> None:
    """plc_client.runtime, nc_tools.common and tests/znc_testing/hostlib build their zenoh sessions with
    nc_schema.zenoh_config.client_config (one function; they differ only in lease and timeout)."""
    import nc_tools.common
    import plc_client.runtime
    from nc_schema import zenoh_config as zc

    assert plc_client.runtime.client_config is zc.client_config
    plc = zc.client_config("tcp/127.0.0.1:17447")
    tool = nc_tools.common.client_config("tcp/127.0.0.1:17447")
    for c in (plc, tool):
        assert json.loads(c.get_json("mode")) == "client"
        assert json.loads(c.get_json("listen/endpoints")) == []
        assert json.loads(c.get_json("scouting/multicast/enabled")) is False
        assert json.loads(c.get_json("connect/retry"))["period_max_ms"] == 250
    assert json.loads(plc.get_json("transport/link/tx/lease")) == 500
    assert json.loads(plc.get_json("connect/timeout_ms")) == 2000
    assert json.loads(tool.get_json("transport/link/tx/lease")) == 1000
    assert json.loads(tool.get_json("connect/timeout_ms")) == 0  # a tool says at once that nobody listens


def test_a_blocked_reply_closes_a_congested_link_after_half_a_second() -> None:
    """zenoh's default 5 s held every other client's replies back that long (one I/O thread sends them)."""
    from nc_server.router import router_config
    c = zenoh_config(ZenohSettings("router", ("tcp/127.0.0.1:17447",), (), 500))
    assert json.loads(c.get_json("transport/link/tx/queue/congestion_control/block/wait_before_close")) == 500_000
    r = router_config(["tcp/127.0.0.1:17448"])
    assert json.loads(r.get_json("transport/link/tx/queue/congestion_control/block/wait_before_close")) == 500_000


def test_decode_plctonc_accepts_and_refuses_what_decode_plc_frame_does() -> None:
    """The NC's PLCTONC decoder checks the frame itself (no structured arrays): the same frames as
    nc_schema.decode_plc_frame, and the same AxisIds and records, for valid frames and for every single-byte
    change of a header field, truncations and extensions."""
    import random

    import numpy as np

    from nc_schema import PLC_FRAME_HEADER_SIZE, PLCTONC_DTYPE, decode_plc_frame, encode_plc_frame
    from nc_server.server.transport import decode_plctonc

    rng = random.Random(5)
    recs = np.frombuffer(bytes(rng.randrange(256) for _ in range(3 * PLCTONC_DTYPE.itemsize)), dtype=PLCTONC_DTYPE)
    good = encode_plc_frame(9, [7, 3, 12], recs)
    cases = [good, good[:-1], good + b"\0", good[:PLC_FRAME_HEADER_SIZE], good[:PLC_FRAME_HEADER_SIZE - 1], b""]
    for k in range(PLC_FRAME_HEADER_SIZE):
        for v in (0, 1, 0xFF, good[k] ^ 0x40):
            cases.append(good[:k] + bytes([v]) + good[k + 1:])
    refused = 0
    for data in cases:
        try:
            _, expect = decode_plc_frame(data)
        except ValueError:
            refused += 1
            try:
                decode_plctonc(data, 1.0, 1 << 20)
            except ValueError:
                continue
            raise AssertionError(f"accepted a frame decode_plc_frame refuses: {data!r}")
        f = decode_plctonc(data, 1.0, 1 << 20)
        assert f.axis_ids.dtype == expect["AxisId"].dtype and f.axis_ids.tolist() == expect["AxisId"].tolist()
        assert f.plctonc.dtype == PLCTONC_DTYPE and f.plctonc.flags.c_contiguous
        assert f.plctonc.tobytes() == expect["PlcToNc"].tobytes()
    assert 0 < refused < len(cases)  # (both kinds were tried)
    f = decode_plctonc(good, 1.0, 1 << 20)
    assert f.axis_ids.tolist() == [7, 3, 12] and f.plctonc.tobytes() == recs.tobytes()


def test_a_plc_frame_whose_header_size_is_below_the_header_is_refused() -> None:
    """A HeaderSize below the header's own size would put the first records over the header (HeaderSize 0: the
    first AxisId read from the Magic): both decoders refuse it, even when the sizes add up."""
    import struct

    import numpy as np
    import pytest

    from nc_schema import PLC_FRAME_HEADER_SIZE, PLCTONC_DTYPE, decode_plc_frame, encode_plc_frame
    from nc_server.server.transport import decode_plctonc

    recs = np.zeros(2, dtype=PLCTONC_DTYPE)
    good = encode_plc_frame(9, [1, 2], recs)
    rs = (len(good) - PLC_FRAME_HEADER_SIZE) // 2
    hdr = bytearray(good[:PLC_FRAME_HEADER_SIZE])
    struct.pack_into("<H", hdr, 6, PLC_FRAME_HEADER_SIZE - 8)  # HeaderSize (offset 6, after Magic and Version)
    bad = bytes(hdr) + good[PLC_FRAME_HEADER_SIZE:][8:]  # 8 bytes shorter: the sizes add up
    assert len(bad) == PLC_FRAME_HEADER_SIZE - 8 + 2 * rs
    with pytest.raises(ValueError):
        decode_plc_frame(bad)
    with pytest.raises(ValueError):
        decode_plctonc(bad, 1.0, 1 << 20)
