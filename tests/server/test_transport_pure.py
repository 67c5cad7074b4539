"""Pieces of the transport that need no network: frame encoding, zenoh config."""
from __future__ import annotations

import json

import numpy as np
import pytest

from nc_schema import FRAME_HEADER_DTYPE, NCTOPLC_DTYPE, decode_frame, encode_frame
from nc_server.server.config import ZenohSettings
from nc_server.server.transport import encode_frame_fast, zenoh_config


@pytest.mark.parametrize("n, flags", [(0, 0), (1, 1), (4, 0), (256, 1)])
def test_fast_frame_is_byte_identical(n: int, flags: int) -> None:
    rng = np.random.default_rng(n)
    recs = np.frombuffer(rng.integers(0, 256, n * NCTOPLC_DTYPE.itemsize, dtype=np.uint8).tobytes(),
                         dtype=NCTOPLC_DTYPE)
    cycle, t = 2**40 + 17, 1_763_900_000_123_456_789
    fast = encode_frame_fast(cycle, t, recs, flags)
    assert fast == encode_frame(cycle, t, recs, flags)
    # independent reference: the header filled field by field through the numpy dtype
    ref = np.zeros((), dtype=FRAME_HEADER_DTYPE)
    ref["Magic"], ref["Version"], ref["HeaderSize"] = 0x314E435A, 1, 32
    ref["Cycle"], ref["NcTimeNs"], ref["AxisCount"], ref["RecordSize"], ref["Flags"] = cycle, t, n, 256, flags
    assert fast[:32] == ref.tobytes()
    h, out, _ = decode_frame(fast)
    assert int(h["Cycle"]) == cycle and int(h["AxisCount"]) == n and int(h["Flags"]) == flags
    assert out.tobytes() == recs.tobytes()


@pytest.mark.parametrize("n", [0, 3, 1024])
def test_fast_frame_with_job_records_is_byte_identical(n: int) -> None:
    from nc_schema import NCJOBS_DTYPE
    rng = np.random.default_rng(n)
    recs = np.zeros(n, dtype=NCTOPLC_DTYPE)
    jobs = np.zeros(n, dtype=NCJOBS_DTYPE)
    for k in range(3):  # the same arrays again (their byte views are kept), changed in place meanwhile
        recs.view(np.uint8)[:] = rng.integers(0, 256, recs.nbytes, dtype=np.uint8)
        jobs.view(np.uint8)[:] = rng.integers(0, 256, jobs.nbytes, dtype=np.uint8)
        assert encode_frame_fast(k, 10**18 + k, recs, 1, jobs) == encode_frame(k, 10**18 + k, recs, 1, jobs)
        assert encode_frame_fast(k, k, recs, 3) == encode_frame(k, k, recs, 3)
    part = np.zeros(2 * n, dtype=NCTOPLC_DTYPE)[::2]  # not contiguous
    assert encode_frame_fast(1, 2, part, 0, jobs) == encode_frame(1, 2, part, 0, jobs)


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
    """plc_client.runtime, nc_tools.common and tests/hosts/hostlib build their zenoh sessions with
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
