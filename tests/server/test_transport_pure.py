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
