"""Fuzz target: AMS/TCP bytes through ``nc_ads.ams.FrameAssembler`` and the ADS server's dispatch
(``nc_ads.server.Dispatcher.handle`` and the notification batching ``collect``) with a ``FakeDevice``.

One input is a mode byte and then either
* RAW: the bytes as they would arrive on a TCP connection, cut into reads at sizes taken from the
  input's own first bytes; or
* BUILT: a sequence of well-formed frames (command, AMS port, index group from a list of interesting
  ones, offset, lengths and data from the input), so the fuzzer reaches the device, symbol, sum and
  notification paths, then the rest of the input as raw bytes.

Checks:
* the assembler raises only ``FrameError``, and cutting the stream differently gives the same packets
  (and the same error);
* ``Dispatcher.handle`` never raises and logs no exception; a reply has the response flags, the
  request's command and invoke id, swapped addresses; without an AMS error its data decodes as the
  command's response; Read/ReadWrite replies carry at most the requested length; the reply frame
  goes through the assembler unchanged;
* every notification frame decodes, each sample has exactly its subscription's length and comes
  from the address it was subscribed on.

Run: ``python -m tests.fuzz.fuzz_ads [libFuzzer args] [CORPUS_DIR | CRASH_FILE ...]``.
"""
from __future__ import annotations

import struct

from tests.fuzz._runner import ExceptionLog, Finding, Reader, Writer, instrument, main

with instrument():
    from nc_ads import ams
    from nc_ads.ams import AmsAddr, AmsPacket, Command, FrameAssembler, FrameError
    from nc_ads.server import Dispatcher, Session, WritePolicy
    from nc_ads.testing import FakeDevice

NETID = "5.80.201.232.1.1"
CLIENT = AmsAddr("10.1.2.3.1.1", 30000)
RAW, BUILT = 0, 1
COMMANDS = (1, 2, 3, 4, 5, 6, 7, 8, 9, 0, 10)
PORTS = (501, 500, 851)
GROUPS = (0x4001, 0x4002, 0x4101, 0x4201, 0x4999, 0xF003, 0xF004, 0xF005, 0xF006, 0xF009, 0xF080, 0xF081,
          0xF082, 0xF007, 0x0)
NAMES = (b"MAIN.fVelo\0", b"main.stState\0", b"GVL.v3\0", b"MAIN.sName\0", b"nope\0", b"")
LOG = ExceptionLog.install()


def chunks(r: Reader, data: bytes) -> list[bytes]:
    out, pos = [], 0
    while pos < len(data):
        n = 1 + r.u8() % 64 if r.left() else len(data) - pos
        out.append(data[pos:pos + n])
        pos += n
    return out


def assemble(pieces: list[bytes]) -> tuple[list[AmsPacket], str | None]:
    fa, got = FrameAssembler(), []
    try:
        for p in pieces:
            got += fa.feed(p)
    except FrameError as exc:
        return got + exc.packets, str(exc)
    return got, None


def build_frames(r: Reader) -> bytes:
    frames = []
    for _ in range(r.u8() % 8):
        cmd = r.pick(COMMANDS)
        port = r.pick(PORTS)
        group = r.pick(GROUPS)
        offset = r.u32() % 4096 if r.u8() & 1 else r.u8()
        length = r.u16() % 2048
        name = r.pick(NAMES)
        blob = r.blob()
        if cmd == Command.READ:
            data = ams.ReadRequest(group, offset, length).encode()
        elif cmd == Command.WRITE:
            data = ams.WriteRequest(group, offset, blob).encode()
        elif cmd == Command.READ_WRITE:
            if group in (ams.IG_SUMUP_READ, ams.IG_SUMUP_WRITE, ams.IG_SUMUP_READWRITE):
                offset = r.u16() % 520
            data = ams.ReadWriteRequest(group, offset, length, name + blob if r.u8() & 1 else blob).encode()
        elif cmd == Command.ADD_DEVICE_NOTIFICATION:
            data = ams.AddNotificationRequest(group, offset, length, r.u8() % 6, r.u32(), r.u32()).encode()
        elif cmd == Command.DEL_DEVICE_NOTIFICATION:
            data = ams.DelNotificationRequest(r.u8()).encode()
        elif cmd == Command.WRITE_CONTROL:
            data = ams.WriteControlRequest(r.u16(), r.u16(), blob).encode()
        else:
            data = blob
        net_id = NETID if r.u8() % 8 else "1.2.3.4.5.6"
        flags = ams.FLAGS_REQUEST if r.u8() % 8 else r.u16()
        frames.append(AmsPacket.build(AmsAddr(net_id, port), CLIENT, cmd, data, state_flags=flags,
                                      invoke_id=r.u32()).encode())
    return b"".join(frames)


def check_reply(req: AmsPacket, rep: AmsPacket | None) -> None:
    h = req.header
    if rep is None:
        if not (h.is_response or h.command == Command.DEVICE_NOTIFICATION):
            raise Finding(f"no reply to command {h.command} flags 0x{h.state_flags:X}")
        return
    rh = rep.header
    if (rh.state_flags, rh.command, rh.invoke_id, rh.target, rh.source) != (
            ams.FLAGS_RESPONSE, h.command, h.invoke_id, h.source, h.target):
        raise Finding(f"reply header {rh} to {h}")
    if rh.data_length != len(rep.data):
        raise Finding("reply data length field wrong")
    got, err = assemble([rep.encode()])
    if err or got != [rep]:
        raise Finding(f"reply frame does not reassemble: {err}")
    if rh.error_code:
        if rep.data:
            raise Finding("AMS error reply with data")
        return
    resp = ams.decode_response(h.command, rep.data)   # PayloadError here is a finding
    if h.command in (Command.READ, Command.READ_WRITE) and resp.result == 0:
        asked = struct.unpack_from("<I", req.data, 8)[0]
        if len(resp.data) > asked:
            raise Finding(f"reply of {len(resp.data)} bytes to a request of {asked}")


def test_one(data: bytes) -> None:
    r = Reader(data)
    mode = r.u8() % 2
    stream = build_frames(r) + r.take(r.left()) if mode == BUILT else r.take(r.left())
    r2 = Reader(stream[:16])
    pieces = chunks(r2, stream)
    whole, err_whole = assemble([stream])
    split, err_split = assemble(pieces)
    if whole != split or (err_whole is None) != (err_split is None):
        raise Finding(f"reassembly depends on the cuts: {len(whole)}/{err_whole} vs {len(split)}/{err_split}")
    dev = FakeDevice(n_values=8)   # small: a fresh device per input stays cheap
    d = Dispatcher({500: dev, 501: dev}, NETID, WritePolicy(None if data[-1:] != b"\x07" else []),
                   strict_netid=not data[-1:] == b"\x05", tick_s=0.01)
    d.clock = lambda: 0.0
    s = Session(1, "127.0.0.1:40000")
    for tick, pkt in enumerate(whole, start=1):
        rep = d.handle(pkt, s)
        LOG.check(f"handling {pkt.header}")
        check_reply(pkt, rep)
        for frame in d.collect(s, tick, 1.0, 0):
            n = ams.DeviceNotification.decode(ams.decode_frame(frame).data)
            src = ams.decode_frame(frame).header.source
            for st in n.stamps:
                for smp in st.samples:
                    sub = s.subs.get(smp.handle)
                    if sub is None or len(smp.data) != sub.length or sub.server != src:
                        raise Finding(f"sample {smp.handle} of {len(smp.data)} bytes from {src}: {sub}")
        LOG.check("collecting notifications")


def seeds() -> list[bytes]:
    out = []

    def frame(cmd: int, data: bytes, port: int = 501) -> bytes:
        return AmsPacket.build(AmsAddr(NETID, port), CLIENT, cmd, data, invoke_id=1).encode()

    out.append(Writer().u8(RAW).raw(frame(Command.READ, ams.ReadRequest(0x4001, 0x27, 8).encode())).bytes())
    out.append(Writer().u8(RAW).raw(frame(Command.READ_STATE, b"") + frame(Command.READ_DEVICE_INFO, b"", 500)).bytes())
    out.append(Writer().u8(RAW).raw(frame(Command.READ_WRITE, ams.ReadWriteRequest(
        0xF080, 2, 24, ams.encode_sum_read([ams.SumReadItem(0x4002, 0, 8), ams.SumReadItem(0x4001, 0x27, 8)])).encode()))
        .bytes())
    out.append(Writer().u8(RAW).raw(frame(Command.ADD_DEVICE_NOTIFICATION, ams.AddNotificationRequest(
        0x4101, 0, 256, 3, 0, 100000).encode()) + frame(Command.DEL_DEVICE_NOTIFICATION, struct.pack("<I", 1))).bytes())
    out.append(Writer().u8(RAW).raw(b"\xff" * 40).bytes())
    w = Writer().u8(BUILT).u8(3)
    for cmd, group, name in ((Command.READ_WRITE, 0xF003, b"MAIN.fVelo\0"), (Command.READ, 0xF005, b""),
                             (Command.ADD_DEVICE_NOTIFICATION, 0xF005, b"")):
        # the fields in build_frames' order: command, port, group, offset (selector, value), length, name, blob,
        # the command's own fields, net id selector, flags selector, invoke id
        w.index(COMMANDS, cmd).index(PORTS, 501).index(GROUPS, group).u8(0).u8(1).u16(8).index(NAMES, name)
        w.blob(b"")
        if cmd == Command.READ_WRITE:
            w.u8(1)
        if cmd == Command.ADD_DEVICE_NOTIFICATION:
            w.u8(4).u32(0).u32(1)
        w.u8(1).u8(1).u32(7)
    out.append(w.bytes())
    return out


if __name__ == "__main__":
    main("ads", test_one, seeds)
