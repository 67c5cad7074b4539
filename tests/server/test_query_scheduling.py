"""Requests run between cycles, in the time the cycle leaves (NcServer.idle / cycle), without zenoh."""
from __future__ import annotations

import time
from pathlib import Path

import msgpack
import pytest

from nc_server.core import NcCore
from nc_server.server import app as A
from nc_server.server.app import NcServer, query_reserve
from nc_server.server.config import load_config


class FakeQuery:
    """What the server reads of a zenoh query: key_expr and payload (``len``, ``to_bytes``)."""

    def __init__(self, key: str, msg: dict) -> None:
        self.key_expr = key
        self.payload = _Payload(msgpack.packb(msg))


class _Payload:
    def __init__(self, data: bytes) -> None:
        self.data = data

    def __len__(self) -> int:
        return len(self.data)

    def to_bytes(self) -> bytes:
        return self.data


@pytest.fixture
def server(tmp_path: Path):  # type: ignore[no-untyped-def]
    conf = tmp_path / "nc.toml"
    conf.write_text('[nc]\nname = "nc1"\nrealtime = "off"\n[zenoh]\nlisten = ["tcp/127.0.0.1:9"]\n'
                    '[[axis]]\nAxisId = 1\n[[axis]]\nAxisId = 2\n')
    cfg = load_config(conf)  # (zenoh is never opened: cycle() and idle() are called directly)
    srv = NcServer(cfg, NcCore(list(cfg.axes), cfg.cycle_time))
    try:
        yield srv
    finally:
        srv.frames.close()


def _queue(srv: NcServer, n: int) -> None:
    for k in range(n):
        srv.transport.queries.append(FakeQuery("nc/nc1/axis/1/cmd/read/t", {"id": k, "client": "t", "cmd": "Info"}))


def _replies(srv: NcServer) -> int:
    n = 0
    while not srv.io.q.empty():
        n += len(srv.io.q.get_nowait())
    return n


def test_a_request_that_would_not_fit_before_the_deadline_waits(server: NcServer) -> None:
    _queue(server, 3)
    server._reserve_ns = 400_000  # requests cost 0.4 ms lately
    soon = time.monotonic_ns() + 300_000
    server.idle(soon, after_work=False)  # a slice: 0.3 ms left, nothing fits
    assert len(server.transport.queries) == 3 and _replies(server) == 0
    server.idle(time.monotonic_ns() + 300_000, after_work=True)  # right after the work: one always runs
    assert len(server.transport.queries) == 2 and _replies(server) == 1
    server.idle(time.monotonic_ns() + 50_000_000, after_work=False)  # plenty of time: the rest
    assert len(server.transport.queries) == 0 and _replies(server) == 2


def test_the_cycle_runs_one_request_only_when_no_idle_call_ran(server: NcServer) -> None:
    _queue(server, 3)
    server.cycle(time.monotonic_ns())  # no idle call since the start (the work fills the period)
    assert len(server.transport.queries) == 2 and _replies(server) == 1
    server._reserve_ns = 10**9
    server.idle(time.monotonic_ns(), after_work=False)  # ran, but nothing fitted
    server.cycle(time.monotonic_ns())  # an idle call ran: the cycle itself takes none
    assert len(server.transport.queries) == 2 and _replies(server) == 0


def test_every_request_is_answered_and_takes_effect_at_the_next_step(server: NcServer) -> None:
    server.transport.queries.append(FakeQuery("nc/nc1/axis/1/cmd/read/t", {"id": 1, "client": "t", "cmd": "Info"}))
    c = server.core.cycle
    server.idle(None)
    (q, payload), = server.io.q.get_nowait()
    rep = msgpack.unpackb(payload, strict_map_key=False)
    assert rep["error"] == 0 and rep["cycle"] == c + 1


def test_the_reserve_follows_the_recent_costs_within_bounds() -> None:
    assert query_reserve([]) == A.QUERY_RESERVE_MAX_NS
    assert query_reserve([10_000] * 64) == A.QUERY_RESERVE_MIN_NS
    assert query_reserve([5_000_000] * 64) == A.QUERY_RESERVE_MAX_NS
    costs = [100_000] * 57 + [300_000] * 7  # the 90th percentile is a 300 us one
    assert query_reserve(costs) == 300_000
    assert query_reserve([100_000] * 60 + [300_000] * 4) == 100_000
