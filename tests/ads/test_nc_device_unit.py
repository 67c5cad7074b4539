"""NcDevice without zenoh: which requests run on the server's loop (`nonblocking`), and what stale frames do."""
from __future__ import annotations

import struct
import time
from typing import Any

import numpy as np
import pytest

from nc_ads.device import AdsSource
from nc_ads.errors import AdsError
from nc_ads.nc_device import IO_NCTOPLC, NcDevice, parse_frame
from nc_schema import NCTOPLC_DTYPE, encode_frame

SRC = AdsSource("127.0.0.1.1.1", 30000, "127.0.0.1:5000", 1, True)


def _device(role: str = "engineer", age: float = 0.0) -> tuple[NcDevice, list[tuple[str, Any]]]:
    dev = NcDevice("nc1", "tcp/127.0.0.1:9", role=role)   # never started: no session
    recs = np.zeros(2, dtype=NCTOPLC_DTYPE)
    recs["AxisId"] = [1, 2]
    dev._image = parse_frame(encode_frame(7, 0, recs), time.monotonic() - age)
    sent: list[tuple[str, Any]] = []

    def command(cmd: str, axis: int | None, **args: Any) -> dict[str, Any]:
        sent.append((cmd, axis))
        return {"error": 0, "Value": 1.0, "CmdNo": 3}
    dev._command = command  # type: ignore[method-assign]
    return dev, sent


def test_nonblocking_reads_from_the_frame_only() -> None:
    dev, _ = _device()
    assert dev.nonblocking(0x1100, 0x03) and dev.nonblocking(0x4101, 0) and dev.nonblocking(0x4102, 0x10002)
    assert dev.nonblocking(0x4301, IO_NCTOPLC)
    # the applied PLCTONC of an axis is subscribed on first read, which may wait: the pool, then the loop
    assert not dev.nonblocking(0x4301, 0)
    dev._applied_latest[1] = bytes(128)
    assert dev.nonblocking(0x4301, 0) and not dev.nonblocking(0x4302, 0x21)
    # writes, parameters (a query), functions: never on the loop
    for g, o in ((0x4101, 0), (0x4301, 0), (0x4301, 0x01), (0x1100, 0x03)):
        assert not dev.nonblocking(g, o, write=True)
    assert not dev.nonblocking(0x4001, 0x27) and not dev.nonblocking(0x4201, 0x01)
    assert not dev.nonblocking(0x4401, 0) and not dev.nonblocking(0xF080, 3)


def test_stale_frames_fail_at_once_and_send_nothing() -> None:
    dev, sent = _device(age=1.5)  # the newest frame is older than stale_after (1 s): the NC gone or frozen
    for call in (lambda: dev.read(0x4101, 0, 256, SRC), lambda: dev.read(0x4301, IO_NCTOPLC, 256, SRC),
                 lambda: dev.read(0x1100, 0x03, 4, SRC), lambda: dev.read(0x4001, 0x27, 8, SRC),
                 lambda: dev.write(0x4001, 0x27, struct.pack("<d", 2.0), SRC),
                 lambda: dev.write(0x4201, 0x01, b"", SRC), lambda: dev.write(0x4301, 0x01, struct.pack("<I", 7), SRC)):
        with pytest.raises(AdsError) as e:
            call()
        assert e.value.code == 0x707
    assert sent == [] and dev.read_state()[0] == 11
    dev, sent = _device(age=0.5)  # younger than stale_after (raised from 0.5 s: late frames on a loaded machine)
    assert dev.read(0x4001, 0x27, 8, SRC) == struct.pack("<d", 1.0)
    dev.write(0x4201, 0x01, b"", SRC)
    assert sent == [("ReadParameter", 1), ("Reset", 1)] and dev.read_state()[0] == 5
    with pytest.raises(AdsError) as e:
        dev.write(0x4209, 0x01, b"", SRC)   # an axis the NC does not have: 0x702, not sent
    assert e.value.code == 0x702 and len(sent) == 2


def test_no_frame_yet_is_0x707_everywhere() -> None:
    dev, sent = _device()
    dev._image = None
    for call in (lambda: dev.read(0x4001, 0x27, 8, SRC), lambda: dev.write(0x4201, 0x01, b"", SRC),
                 lambda: dev.read(0x4101, 0, 256, SRC), lambda: dev.sample(0x4101, 0, 256)):
        with pytest.raises(AdsError) as e:
            call()
        assert e.value.code == 0x707
    assert sent == []


class _Channel:
    """A zenoh FifoChannel stand-in: ``try_recv`` pops queued samples, then None."""

    def __init__(self) -> None:
        self.queue: list[Any] = []

    def try_recv(self) -> Any:
        return self.queue.pop(0) if self.queue else None


def test_a_new_instance_token_ends_the_supply_the_same_one_does_not() -> None:
    """The NC process's instance token: another id is a restart (the new NC does not know nc-ads's claims:
    supplying them on was the defect when the new Cycle went on above the old one's), the same id coming
    back after a dropped link is none; a malformed or another NC's token is ignored."""
    import zenoh

    from nc_ads.nc_device import _Supply
    from nc_schema import Keys

    dev, _ = _device()
    dev._alive, dev._instance_sub, dev._claims_sub = _Channel(), _Channel(), _Channel()
    put = lambda key: type("S", (), {"key_expr": key, "kind": zenoh.SampleKind.PUT})()  # noqa: E731
    a, b = "0123456789abcdef", "fedcba9876543210"
    dev._instance_sub.queue += [put(Keys("nc1").alive_instance(a))]
    dev._take_events()
    dev._supplies[1] = _Supply(bytearray(128), conn_id=1, claim_cycle=7)
    for key in (Keys("nc1").alive_instance(a), "nc/nc1/alive/NOT-AN-ID", Keys("nc2").alive_instance(b)):
        dev._instance_sub.queue.append(put(key))
        dev._take_events()
        assert 1 in dev._supplies and dev.restarts == 0, key
    dev._instance_sub.queue.append(put(Keys("nc1").alive_instance(b)))
    dev._take_events()
    assert dev._supplies == {} and dev.restarts == 1
