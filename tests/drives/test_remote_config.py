"""The remote drive backend's options, slots, wire codec and link bookkeeping (no processes; the processes:
test_remote_process.py)."""
from __future__ import annotations

import numpy as np
import pytest

from nc_server.core.params import AxisParams, ConfigError
from nc_server.drives.base import DriveContext
from nc_server.drives.cia402.image import RxImage, TxImage
from nc_server.drives.remote import wire
from nc_server.drives.remote.config import DEFAULT_MAX_AGE, host_slots, link_endpoints, parse_options
from nc_server.drives.remote.drive import RemoteDrive
from nc_server.drives.remote.link import HostSlots, RemoteLink
from nc_server.server.config import ZenohSettings


@pytest.mark.parametrize("options, key, text", [
    ({"bogus": 1}, "drives.remote.bogus", "unknown key"),
    ({"max_age": 0}, "drives.remote.max_age", "1..100000"),
    ({"max_age": 2.5}, "drives.remote.max_age", "integer"),
    ({"max_age": True}, "drives.remote.max_age", "integer"),
    ({"sender": "fast"}, "drives.remote.sender", "'cycle', 'thread'"),
    ({"connect": ["tcp/nowhere"]}, "drives.remote.connect[0]", "invalid endpoint"),
    ({"connect": 7447}, "drives.remote.connect", "list of endpoints"),
    ({"lease_ms": 5}, "drives.remote.lease_ms", "100..3600000"),
])
def test_bad_backend_options_name_their_key(options: dict, key: str, text: str) -> None:
    with pytest.raises(ConfigError) as e:
        parse_options(options)
    assert e.value.key == key and text in e.value.message


def test_backend_defaults() -> None:
    o = parse_options({})
    assert (o.connect, o.max_age, o.sender, o.lease_ms) == ((), DEFAULT_MAX_AGE, "cycle", None)
    assert parse_options({"connect": "tcp/10.0.0.5:7447"}).connect == ("tcp/10.0.0.5:7447",)


@pytest.mark.parametrize("axes, key, text", [
    ([{}], "axis[0].Drive.host", "missing"),
    ([{"host": "a/b"}], "axis[0].Drive.host", "letters, digits"),
    ([{"host": ""}], "axis[0].Drive.host", "letters, digits"),
    ([{"host": "d1", "node_id": 2}], "axis[0].Drive.node_id", "unknown key"),
    ([{"host": "d1", "slot": -1}], "axis[0].Drive.slot", "0..4095"),
    ([{"host": "d1", "slot": 0}, {"host": "d1"}], "axis[1].Drive.slot", "all or none"),
    ([{"host": "d1", "slot": 0}, {"host": "d1", "slot": 0}], "axis[1].Drive.slot", "0..1, each once"),
    ([{"host": "d1", "slot": 1}], "axis[0].Drive.slot", "0..0"),
])
def test_bad_axis_options_name_their_key(axes: list, key: str, text: str) -> None:
    with pytest.raises(ConfigError) as e:
        host_slots(axes)
    assert e.value.key == key and text in e.value.message


def test_slots_by_order_or_explicit() -> None:
    hs = host_slots([{"host": "a"}, {"host": "b"}, {"host": "a"}], [10, 20, 30])
    assert hs == [HostSlots("a", (0, 2), (10, 30)), HostSlots("b", (1,), (20,))]
    hs = host_slots([{"host": "a", "slot": 1}, {"host": "a", "slot": 0}], [10, 20])
    assert hs == [HostSlots("a", (1, 0), (20, 10))]


def test_link_endpoints_follow_the_nc() -> None:
    o = parse_options({})
    assert link_endpoints(o, ZenohSettings(listen=("tcp/0.0.0.0:7447", "tcp/[::]:7448", "tcp/127.0.0.1:0"))) == \
        ("tcp/127.0.0.1:7447", "tcp/[::1]:7448")
    assert link_endpoints(o, ZenohSettings(mode="client", listen=(), connect=("tcp/router:7447",))) == \
        ("tcp/router:7447",)
    assert link_endpoints(parse_options({"connect": ["tcp/10.0.0.9:7450"]}), ZenohSettings()) == ("tcp/10.0.0.9:7450",)
    with pytest.raises(ConfigError, match="drives.remote.connect"):
        link_endpoints(o, ZenohSettings(listen=("tcp/127.0.0.1:0",)))


def test_from_config_refuses_bad_options_before_opening_anything() -> None:
    ctx = DriveContext("nc1", {"max_age": -3}, ZenohSettings())
    with pytest.raises(ConfigError, match=r"drives.remote.max_age"):
        RemoteDrive.from_config([AxisParams()], 0.001, [{"host": "d1"}], ctx)
    with pytest.raises(ConfigError, match=r"axis\[0\].Drive.host"):
        RemoteDrive.from_config([AxisParams()], 0.001, [{}], DriveContext("nc1", {}, ZenohSettings()))
    with pytest.raises(ConfigError, match=r"axis\[0\].Drive.mode"):
        RemoteDrive.from_config([AxisParams()], 0.001, [{"host": "d1", "mode": "pp"}],
                                DriveContext("nc1", {}, ZenohSettings()))


def test_wire_round_trip_and_slot_order() -> None:
    rx = RxImage.zeros(3)
    rx.target_position[:] = [1.5, 2.5, 3.5]
    rx.controlword[:] = [6, 7, 15]
    rx.cycle = 42
    m = wire.decode_rx(wire.encode_rx(rx, np.array([2, 0]), np.array([3, 1])))
    assert m.image.target_position.tolist() == [3.5, 1.5] and m.image.controlword.tolist() == [15, 6]
    assert m.ids.tolist() == [3, 1] and m.image.cycle == 42 and m.epoch == 0
    tx = TxImage.zeros(2)
    tx.position_actual[:] = [5.0, -6.25]
    tx.error_code[:] = [0, 0x8130]
    t = wire.decode_tx(wire.encode_tx(tx, 7, 42))
    assert t.image.position_actual.tolist() == [5.0, -6.25] and t.image.error_code.tolist() == [0, 0x8130]
    assert (t.cycle, t.rx_cycle) == (7, 42)


@pytest.mark.parametrize("payload", [b"", b"\xc1", b"\x93\x01\x02\x03",
                                     wire._packer.pack({"v": 2, "n": 0}),
                                     wire._packer.pack({"v": 1, "n": 2, "cycle": 1, "sw": b"\x00"})])
def test_malformed_messages_are_wire_errors(payload: bytes) -> None:
    with pytest.raises(wire.WireError):
        wire.decode_tx(payload)
    with pytest.raises(wire.WireError):
        wire.decode_rx(payload)


def test_link_without_session_ages_inputs_and_reports_no_host() -> None:
    link = RemoteLink("nc1", 2, [HostSlots("d1", (0, 1), (1, 2))], None)
    try:
        rx = RxImage.zeros(2)
        a = link.exchange(rx)
        b = link.exchange(rx)
        assert b.age.tolist() == [0, 0] and not b.alive.any(), "a host never heard from: not alive, data not aged"
        link._seen_rows[:] = 1
        c = link.exchange(rx)
        assert c.age.tolist() == [1, 1] and b.age.tolist() == [0, 0], "an image handed out is not changed later"
    finally:
        link.close()
    with pytest.raises(ValueError, match="rows 0..1"):
        RemoteLink("nc1", 2, [HostSlots("d1", (0,), (1,))], None)


def _tx_payload(**over: object) -> bytes:
    tx = TxImage.zeros(2)
    m = wire.msgpack.unpackb(wire.encode_tx(tx, 7, 42))
    m.update(over)
    return bytes(wire._packer.pack(m))


_NAN2 = np.array([0.0, np.nan]).astype("<f8").tobytes()
_INF2 = np.array([np.inf, 0.0]).astype("<f8").tobytes()


@pytest.mark.parametrize("over", [
    {"rx_cycle": 2 ** 64 - 1}, {"rx_cycle": 2 ** 63}, {"rx_cycle": -1}, {"cycle": True}, {"cycle": -5},
    {"cycle": 1.5}, {"n": True}, {"pa": _NAN2}, {"va": _INF2}, {"ta": _NAN2}, {"pp": _INF2},
])
def test_tx_counters_out_of_range_and_floats_not_finite_are_wire_errors(over: dict) -> None:
    with pytest.raises(wire.WireError):
        wire.decode_tx(_tx_payload(**over))


@pytest.mark.parametrize("over", [
    {"cycle": 2 ** 63}, {"cycle": False}, {"epoch": -1}, {"epoch": 2 ** 64 - 1},
    {"tp": np.array([np.nan]).astype("<f8").tobytes()}, {"tv": np.array([-np.inf]).astype("<f8").tobytes()},
])
def test_rx_counters_out_of_range_and_floats_not_finite_are_wire_errors(over: dict) -> None:
    """The host refuses such outputs (host.py: a WireError is a refused message): NaN never reaches a motor."""
    rx = RxImage.zeros(1)
    m = wire.msgpack.unpackb(wire.encode_rx(rx, None, np.array([1])))
    m.update(over)
    with pytest.raises(wire.WireError):
        wire.decode_rx(wire._packer.pack(m))
    assert wire.decode_rx(wire.encode_rx(rx, None, np.array([1]))).image.cycle == 0  # (the unchanged one is fine)


class _Sample:
    def __init__(self, payload: bytes) -> None:
        self.payload = self
        self._b = payload

    def to_bytes(self) -> bytes:
        return self._b


class _Sub:
    def __init__(self, payloads: list[bytes]) -> None:
        self.payloads = payloads

    def try_recv(self) -> _Sample | None:
        return _Sample(self.payloads.pop(0)) if self.payloads else None


def test_a_malformed_host_message_is_counted_never_raised_into_the_cycle(monkeypatch: pytest.MonkeyPatch) -> None:
    link = RemoteLink("nc1", 2, [HostSlots("d1", (0, 1), (1, 2))], None)
    try:
        link._tx_subs = [_Sub([_tx_payload(rx_cycle=2 ** 64 - 1)])]
        link._take_inputs(4)
        assert link.malformed == 1 and link.received == 0
        good = TxImage.zeros(2)
        good.position_actual[:] = [1.0, 2.0]
        link._tx_subs = [_Sub([_tx_payload(pa=np.array([np.nan, 1.0]).astype("<f8").tobytes()),
                               wire.encode_tx(good, 8, 1)])]
        link._take_inputs(5)  # (the link's per-cycle read; one message per host and cycle)
        assert link.malformed == 2 and not np.isnan(link._tx.position_actual).any()
        link._take_inputs(6)
        t = link._tx
        assert link.received == 1 and t.position_actual.tolist() == [1.0, 2.0]

        def boom(payload: bytes) -> None:
            raise RuntimeError("a bug in a decoder")
        monkeypatch.setattr(wire, "decode_tx_columns", boom)
        link._tx_subs = [_Sub([wire.encode_tx(good, 9, 2)])]
        link._take_inputs(7)
        assert link.malformed == 3
    finally:
        link.close()
