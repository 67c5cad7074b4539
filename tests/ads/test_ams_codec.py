"""nc_ads.ams: the pure codec (round trips of every command, malformed payloads, TCP reassembly)."""
from __future__ import annotations

import itertools
import random
import struct

import pytest

from nc_ads import ams
from nc_ads.ams import AmsAddr, AmsHeader, AmsPacket, Command, FrameAssembler, FrameError, PayloadError

SRV = AmsAddr("5.80.201.232.1.1", 501)
CLI = AmsAddr("127.0.0.1.1.1", 30000)

REQUESTS = [
    (Command.READ_DEVICE_INFO, ams.Empty()),
    (Command.READ, ams.ReadRequest(0x4101, 0, 256)),
    (Command.WRITE, ams.WriteRequest(0x4001, 0x27, struct.pack("<d", 12.5))),
    (Command.WRITE, ams.WriteRequest(0x4001, 0x27, b"")),
    (Command.READ_STATE, ams.Empty()),
    (Command.WRITE_CONTROL, ams.WriteControlRequest(5, 0, b"xy")),
    (Command.ADD_DEVICE_NOTIFICATION, ams.AddNotificationRequest(0x4101, 0, 256, 4, 0, 100000)),
    (Command.DEL_DEVICE_NOTIFICATION, ams.DelNotificationRequest(0xFFFFFFFF)),
    (Command.READ_WRITE, ams.ReadWriteRequest(0xF003, 0, 4, b"MAIN.fVelo\0")),
    (Command.DEVICE_NOTIFICATION, ams.DeviceNotification(
        (ams.Stamp(ams.filetime_from_unix(1.7e9), (ams.Sample(1, b"a" * 8), ams.Sample(2, b""))),
         ams.Stamp(5, ())))),
]
RESPONSES = [
    (Command.READ_DEVICE_INFO, ams.ReadDeviceInfoResponse(0, 3, 1, 4024, "FakeNC")),
    (Command.READ, ams.DataResponse(0, b"\x01" * 256)),
    (Command.READ, ams.DataResponse(0x702, b"")),
    (Command.WRITE, ams.ResultOnly(0x4358)),
    (Command.READ_STATE, ams.ReadStateResponse(0, 5, 0)),
    (Command.WRITE_CONTROL, ams.ResultOnly(0x701)),
    (Command.ADD_DEVICE_NOTIFICATION, ams.AddNotificationResponse(0, 77)),
    (Command.DEL_DEVICE_NOTIFICATION, ams.ResultOnly(0x714)),
    (Command.READ_WRITE, ams.DataResponse(0, b"\x07\0\0\0")),
]


@pytest.mark.parametrize("cmd,req", REQUESTS, ids=lambda v: type(v).__name__ if not isinstance(v, int) else str(v))
def test_every_request_round_trips(cmd: int, req: object) -> None:
    assert ams.decode_request(cmd, req.encode()) == req
    pkt = AmsPacket.build(SRV, CLI, cmd, req.encode(), invoke_id=42)
    (back,) = FrameAssembler().feed(pkt.encode())
    assert back == pkt and back.header.data_length == len(req.encode())


@pytest.mark.parametrize("cmd,resp", RESPONSES, ids=lambda v: type(v).__name__ if not isinstance(v, int) else str(v))
def test_every_response_round_trips(cmd: int, resp: object) -> None:
    assert ams.decode_response(cmd, resp.encode()) == resp


def test_wire_layouts_are_the_documented_ones() -> None:
    assert ams.ReadRequest(1, 2, 3).encode() == struct.pack("<III", 1, 2, 3)
    assert ams.DataResponse(0x702).encode() == struct.pack("<II", 0x702, 0)  # pitfall 1: length field
    assert len(ams.AddNotificationRequest(1, 2, 3, 4, 5, 6).encode()) == 40
    assert ams.ReadDeviceInfoResponse(0, 3, 1, 4024, "x" * 40).encode()[8:] == b"x" * 15 + b"\0"
    h = AmsHeader(SRV, CLI, 2, 4, 12, 0, 9).encode()
    assert h == bytes([5, 80, 201, 232, 1, 1]) + struct.pack("<H", 501) + bytes([127, 0, 0, 1, 1, 1]) \
        + struct.pack("<HHHIII", 30000, 2, 4, 12, 0, 9)
    frame = AmsPacket.build(SRV, CLI, 2, b"abc").encode()
    assert frame[:6] == struct.pack("<HI", 0, 35)


def test_reply_swaps_addresses_and_sets_response_flag() -> None:
    req = AmsPacket.build(SRV, CLI, Command.READ, b"", invoke_id=1234)
    rep = req.reply(b"xyz", error_code=7)
    assert rep.header.target == CLI and rep.header.source == SRV
    assert rep.header.state_flags == 0x0005 and rep.header.invoke_id == 1234
    assert rep.header.command == Command.READ and rep.header.error_code == 7 and rep.data == b"xyz"
    assert rep.header.is_response and not req.header.is_response


@pytest.mark.parametrize("cls,data", [
    (ams.ReadRequest, b"\0" * 11), (ams.ReadRequest, b"\0" * 13),
    (ams.WriteRequest, struct.pack("<III", 1, 2, 8) + b"\0" * 7),
    (ams.WriteRequest, struct.pack("<III", 1, 2, 8) + b"\0" * 9),
    (ams.WriteRequest, b"\0" * 5),
    (ams.ReadWriteRequest, struct.pack("<IIII", 1, 2, 3, 4) + b"\0"),
    (ams.ReadWriteRequest, b"\0" * 15),
    (ams.AddNotificationRequest, b"\0" * 39),
    (ams.DelNotificationRequest, b"\0" * 3),
    (ams.WriteControlRequest, struct.pack("<HHI", 5, 0, 2) + b"x"),
    (ams.Empty, b"\0"),
    (ams.DataResponse, struct.pack("<II", 0, 4) + b"abc"),
    (ams.DeviceNotification, struct.pack("<II", 4, 1)),
    (ams.DeviceNotification, struct.pack("<II", 24, 1) + struct.pack("<QI", 0, 1) + struct.pack("<II", 1, 9)),
    (ams.DeviceNotification, struct.pack("<II", 4, 0) + b"junk"),
])
def test_malformed_payloads_raise_payload_error(cls: type, data: bytes) -> None:
    with pytest.raises(PayloadError):
        cls.decode(data)


@pytest.mark.parametrize("bad", ["1.2.3.4.5", "1.2.3.4.5.6.7", "1.2.3.4.5.256", "a.b.c.d.e.f", "1.2.3.4.5.-1",
                                 "1.2.3.4.5. 6", ""])
def test_bad_net_ids_are_refused(bad: str) -> None:
    with pytest.raises(ValueError):
        ams.netid_to_bytes(bad)
    with pytest.raises(ValueError):
        AmsAddr(bad, 1)


def test_net_id_and_port_range() -> None:
    assert ams.netid_from_bytes(ams.netid_to_bytes("192.168.0.1.1.1")) == "192.168.0.1.1.1"
    with pytest.raises(ValueError):
        AmsAddr("1.2.3.4.1.1", 65536)


def test_filetime() -> None:
    assert ams.filetime_from_unix(0) == 116444736000000000
    assert ams.unix_from_filetime(ams.filetime_from_unix(1.25e9)) == pytest.approx(1.25e9)
    import time
    assert abs(ams.unix_from_filetime(ams.filetime_now()) - time.time()) < 5


def test_sum_payloads_round_trip() -> None:
    reads = [ams.SumReadItem(0x4001, 0x27, 8), ams.SumReadItem(0x4101, 0, 256)]
    assert ams.decode_sum_read(2, ams.encode_sum_read(reads)) == reads
    writes = [ams.SumWriteItem(1, 2, b"abc"), ams.SumWriteItem(3, 4, b""), ams.SumWriteItem(5, 6, b"z")]
    assert ams.decode_sum_write(3, ams.encode_sum_write(writes)) == writes
    rws = [ams.SumReadWriteItem(0xF003, 0, 4, b"MAIN.x\0"), ams.SumReadWriteItem(1, 1, 8, b"")]
    assert ams.decode_sum_read_write(2, ams.encode_sum_read_write(rws)) == rws
    assert ams.decode_sum_results(ams.encode_sum_results([0, 0x702])) == [0, 0x702]
    res = [(0, b"ab"), (0x703, b""), (0, b"x")]
    assert ams.decode_sum_read_write_response(3, ams.encode_sum_read_write_response(res)) == res
    # sum read reply: results, then every sub-read at its requested length (short padded, errors zeroed)
    out = ams.encode_sum_read_response([(0, b"ab"), (0x702, b"zz"), (0, b"12345")], [4, 2, 3])
    assert out == struct.pack("<III", 0, 0x702, 0) + b"ab\0\0" + b"\0\0" + b"123"
    with pytest.raises(PayloadError):
        ams.decode_sum_read(2, b"\0" * 23)
    with pytest.raises(PayloadError):
        ams.decode_sum_write(1, struct.pack("<III", 1, 2, 5) + b"abcd")
    with pytest.raises(PayloadError):
        ams.decode_sum_read_write(1, struct.pack("<IIII", 1, 2, 5, 3) + b"abcd")


def _stream() -> tuple[bytes, list[AmsPacket]]:
    pkts = [AmsPacket.build(SRV, CLI, Command.READ, ams.ReadRequest(0x4001, 0x27, 8).encode(), invoke_id=1),
            AmsPacket.build(SRV, CLI, Command.READ_STATE, b"", invoke_id=2),
            AmsPacket.build(SRV, CLI, Command.WRITE, ams.WriteRequest(0x4001, 2, b"q" * 40).encode(), invoke_id=3)]
    return b"".join(p.encode() for p in pkts), pkts


def test_reassembly_at_every_single_split() -> None:
    data, pkts = _stream()
    for cut in range(len(data) + 1):
        fa = FrameAssembler()
        got = fa.feed(data[:cut]) + fa.feed(data[cut:])
        assert got == pkts, cut
        assert fa.pending == 0


def test_reassembly_at_every_pair_of_splits() -> None:
    data, pkts = _stream()
    for a, b in itertools.combinations(range(len(data) + 1), 2):
        fa = FrameAssembler()
        assert fa.feed(data[:a]) + fa.feed(data[a:b]) + fa.feed(data[b:]) == pkts, (a, b)


def test_reassembly_byte_by_byte_and_random_chunks() -> None:
    data, pkts = _stream()
    fa = FrameAssembler()
    got: list[AmsPacket] = []
    for i in range(len(data)):
        got += fa.feed(data[i:i + 1])
    assert got == pkts
    rng = random.Random(7)
    big = data * 50
    for _ in range(50):
        fa, got, pos = FrameAssembler(), [], 0
        while pos < len(big):
            n = rng.randint(0, 300)
            got += fa.feed(big[pos:pos + n])
            pos += n
        assert got == pkts * 50


def test_partial_frame_waits() -> None:
    data, pkts = _stream()
    fa = FrameAssembler()
    assert fa.feed(data[:5]) == [] and fa.pending == 5


@pytest.mark.parametrize("head,why", [
    (struct.pack("<HI", 1, 32), "reserved"),
    (struct.pack("<HI", 0, 31), "shorter"),
    (struct.pack("<HI", 0, 0), "shorter"),
    (struct.pack("<HI", 0, ams.MAX_FRAME_LENGTH + 1), "exceeds"),
    (struct.pack("<HI", 0, 0xFFFFFFFF), "exceeds"),
])
def test_unframeable_streams_raise_and_stay_broken(head: bytes, why: str) -> None:
    data, pkts = _stream()
    fa = FrameAssembler()
    with pytest.raises(FrameError, match=why) as err:
        fa.feed(data + head)
    assert err.value.packets == pkts        # the whole frames before the bad one
    with pytest.raises(FrameError) as err:
        fa.feed(data)
    assert err.value.packets == []


def test_max_length_frame_accepted() -> None:
    fa = FrameAssembler(max_length=32 + 100)
    p = AmsPacket.build(SRV, CLI, Command.WRITE, b"x" * 100)
    assert fa.feed(p.encode()) == [p]
    with pytest.raises(FrameError):
        FrameAssembler(max_length=32 + 99).feed(p.encode())


def test_header_data_length_mismatch_is_kept_for_the_server() -> None:
    # the frame is cut by the AMS/TCP length; a disagreeing AMS data length is the server's to refuse
    p = AmsPacket(AmsHeader(SRV, CLI, Command.READ, 4, 99, 0, 1), b"\0" * 12)
    (back,) = FrameAssembler().feed(p.encode())
    assert back.header.data_length == 99 and len(back.data) == 12


def test_decode_frame() -> None:
    p = AmsPacket.build(SRV, CLI, Command.READ_STATE, b"", invoke_id=5)
    assert ams.decode_frame(p.encode()) == p
    for bad in (p.encode()[:-1] + b"", b"\0" * 10, b"\1" + p.encode()[1:]):
        with pytest.raises(FrameError):
            ams.decode_frame(bad)
