"""AMS/TCP and ADS wire codec (pure: no sockets, no threads, no clocks except the FILETIME helper).

All integers little-endian. A frame on TCP is the 6-byte AMS/TCP header (u16 reserved = 0, u32 length of
what follows), the 32-byte AMS header and the ADS data (reference section 5.2/5.3, ads-bridge-notes 2):

    AMS header: 6B target net id, u16 target port, 6B source net id, u16 source port, u16 command id,
                u16 state flags, u32 data length, u32 error code, u32 invoke id

Each command's request and response is a frozen dataclass with `encode() -> bytes` and
`decode(data) -> instance`; `decode` raises `PayloadError` when the data does not have the command's
layout (wrong length, length fields that disagree with the data). `FrameAssembler` cuts a TCP byte stream
into `AmsPacket`s whatever the read boundaries are and raises `FrameError` for a stream it cannot follow
(non-zero reserved field, length below the 32-byte AMS header or above `MAX_FRAME_LENGTH`).

Sum commands (index groups 0xF080/0xF081/0xF082 through ReadWrite) are ADS payloads too, so their
sub-request/-response layouts live here as well (`decode_sum_*`, `encode_sum_*`).
"""
from __future__ import annotations

import struct
import time
from dataclasses import dataclass, field
from enum import IntEnum
from typing import Any, Protocol

AMS_TCP_PORT = 48898                 # 0xBF02
AMS_TCP_HEADER = struct.Struct("<HI")
AMS_HEADER = struct.Struct("<6sH6sHHHIII")
AMS_TCP_HEADER_SIZE = AMS_TCP_HEADER.size   # 6
AMS_HEADER_SIZE = AMS_HEADER.size           # 32

# Largest AMS/TCP length (AMS header + ADS data) accepted on receive. 4 MiB covers 500 sub-command sum
# reads of 8 KiB each; anything larger is treated as a broken or hostile stream (FrameError -> close).
MAX_FRAME_LENGTH = 4 * 1024 * 1024

# state flags
FLAG_RESPONSE = 0x0001
FLAG_ADS_COMMAND = 0x0004
FLAG_UDP = 0x0040
FLAGS_REQUEST = FLAG_ADS_COMMAND                   # 0x0004
FLAGS_RESPONSE = FLAG_ADS_COMMAND | FLAG_RESPONSE  # 0x0005

# transmission modes of AddDeviceNotification
TRANS_NOTRANS = 0
TRANS_CLIENTCYCLE = 1
TRANS_CLIENT1REQ = 2
TRANS_SERVERCYCLE = 3
TRANS_SERVERONCHA = 4

# reserved index groups (symbols, sum commands)
IG_SYM_HNDBYNAME = 0xF003
IG_SYM_VALBYNAME = 0xF004
IG_SYM_VALBYHND = 0xF005
IG_SYM_RELEASEHND = 0xF006
IG_SYM_INFOBYNAME = 0xF007
IG_SYM_INFOBYNAMEEX = 0xF009
IG_SUMUP_READ = 0xF080
IG_SUMUP_WRITE = 0xF081
IG_SUMUP_READWRITE = 0xF082

# ADS states (ReadState)
ADSSTATE_INVALID = 0
ADSSTATE_IDLE = 1
ADSSTATE_RESET = 2
ADSSTATE_INIT = 3
ADSSTATE_START = 4
ADSSTATE_RUN = 5
ADSSTATE_STOP = 6
ADSSTATE_ERROR = 11


class Command(IntEnum):
    INVALID = 0
    READ_DEVICE_INFO = 1
    READ = 2
    WRITE = 3
    READ_STATE = 4
    WRITE_CONTROL = 5
    ADD_DEVICE_NOTIFICATION = 6
    DEL_DEVICE_NOTIFICATION = 7
    DEVICE_NOTIFICATION = 8
    READ_WRITE = 9


class FrameError(ValueError):
    """The TCP byte stream cannot be cut into AMS frames (the connection must be closed).
    `packets`: the whole frames that came before the bad one in the same `feed` call (so the result does
    not depend on how the stream was cut into reads)."""

    def __init__(self, message: str, packets: list[AmsPacket] | None = None) -> None:
        super().__init__(message)
        self.packets: list[AmsPacket] = packets or []


class PayloadError(ValueError):
    """A frame's ADS data does not have its command's layout."""


# ---------------------------------------------------------------------------------------------------------
# addresses, header, packet

def netid_to_bytes(net_id: str) -> bytes:
    """'a.b.c.d.e.f' (six numbers 0..255) -> 6 bytes; ValueError otherwise."""
    parts = net_id.split(".")
    if len(parts) != 6:
        raise ValueError(f"AMS net id must have 6 parts, got {net_id!r}")
    try:
        values = [int(p, 10) for p in parts]
    except ValueError:
        raise ValueError(f"AMS net id parts must be decimal numbers: {net_id!r}") from None
    if any(not 0 <= v <= 255 or not p.isdigit() for v, p in zip(values, parts)):
        raise ValueError(f"AMS net id parts must be 0..255: {net_id!r}")
    return bytes(values)


def netid_from_bytes(raw: bytes) -> str:
    if len(raw) != 6:
        raise ValueError("AMS net id is 6 bytes")
    return ".".join(str(b) for b in raw)


@dataclass(frozen=True)
class AmsAddr:
    net_id: str
    port: int

    def __post_init__(self) -> None:
        netid_to_bytes(self.net_id)  # validates
        if not 0 <= self.port <= 0xFFFF:
            raise ValueError(f"AMS port must be 0..65535, got {self.port}")

    def __str__(self) -> str:
        return f"{self.net_id}:{self.port}"


@dataclass(frozen=True)
class AmsHeader:
    target: AmsAddr
    source: AmsAddr
    command: int
    state_flags: int
    data_length: int
    error_code: int = 0
    invoke_id: int = 0

    def encode(self) -> bytes:
        return AMS_HEADER.pack(netid_to_bytes(self.target.net_id), self.target.port,
                               netid_to_bytes(self.source.net_id), self.source.port,
                               self.command, self.state_flags, self.data_length,
                               self.error_code, self.invoke_id)

    @classmethod
    def decode(cls, raw: bytes) -> AmsHeader:
        if len(raw) != AMS_HEADER_SIZE:
            raise FrameError(f"AMS header is {AMS_HEADER_SIZE} bytes, got {len(raw)}")
        tn, tp, sn, sp, cmd, flags, dlen, err, inv = AMS_HEADER.unpack(raw)
        return cls(AmsAddr(netid_from_bytes(tn), tp), AmsAddr(netid_from_bytes(sn), sp),
                   cmd, flags, dlen, err, inv)

    @property
    def is_response(self) -> bool:
        return bool(self.state_flags & FLAG_RESPONSE)


@dataclass(frozen=True)
class AmsPacket:
    """One AMS frame. `header.data_length` is what the wire said (it may disagree with len(data) in a
    malformed frame); `build()` makes a consistent packet."""
    header: AmsHeader
    data: bytes = b""

    @classmethod
    def build(cls, target: AmsAddr, source: AmsAddr, command: int, data: bytes = b"", *,
              state_flags: int = FLAGS_REQUEST, error_code: int = 0, invoke_id: int = 0) -> AmsPacket:
        return cls(AmsHeader(target, source, int(command), state_flags, len(data), error_code,
                             invoke_id), bytes(data))

    def encode(self) -> bytes:
        """The whole TCP frame: AMS/TCP header + AMS header + data."""
        return (AMS_TCP_HEADER.pack(0, AMS_HEADER_SIZE + len(self.data)) + self.header.encode()
                + self.data)

    def reply(self, data: bytes = b"", error_code: int = 0) -> AmsPacket:
        """The response to this request: addresses swapped, same command and invoke id, flags 0x0005."""
        h = self.header
        return AmsPacket.build(h.source, h.target, h.command, data, state_flags=FLAGS_RESPONSE,
                               error_code=error_code, invoke_id=h.invoke_id)


def decode_frame(frame: bytes) -> AmsPacket:
    """One complete TCP frame (with its 6-byte AMS/TCP header) -> AmsPacket; FrameError if malformed."""
    if len(frame) < AMS_TCP_HEADER_SIZE + AMS_HEADER_SIZE:
        raise FrameError(f"frame of {len(frame)} bytes is shorter than the AMS headers")
    reserved, length = AMS_TCP_HEADER.unpack_from(frame)
    if reserved != 0:
        raise FrameError(f"AMS/TCP reserved field is 0x{reserved:04X}, not 0")
    if length != len(frame) - AMS_TCP_HEADER_SIZE:
        raise FrameError(f"AMS/TCP length {length} != {len(frame) - AMS_TCP_HEADER_SIZE} bytes")
    header = AmsHeader.decode(frame[AMS_TCP_HEADER_SIZE:AMS_TCP_HEADER_SIZE + AMS_HEADER_SIZE])
    return AmsPacket(header, bytes(frame[AMS_TCP_HEADER_SIZE + AMS_HEADER_SIZE:]))


class FrameAssembler:
    """TCP reassembly: `feed(chunk)` returns every packet completed by the bytes so far (any split or
    merge of frames over reads). A bad frame raises `FrameError` (with the packets before it in
    `.packets`); after that the stream is lost: every later feed raises too (with no packets)."""

    def __init__(self, max_length: int = MAX_FRAME_LENGTH) -> None:
        self._buf = bytearray()
        self._max = max_length
        self._broken: FrameError | None = None

    @property
    def pending(self) -> int:
        """Bytes buffered that do not yet make a whole frame."""
        return len(self._buf)

    def feed(self, chunk: bytes) -> list[AmsPacket]:
        if self._broken is not None:
            raise self._broken
        self._buf += chunk
        out: list[AmsPacket] = []
        buf = self._buf
        pos = 0
        try:
            while len(buf) - pos >= AMS_TCP_HEADER_SIZE:
                reserved, length = AMS_TCP_HEADER.unpack_from(buf, pos)
                if reserved != 0:
                    raise FrameError(f"AMS/TCP reserved field is 0x{reserved:04X}, not 0")
                if length < AMS_HEADER_SIZE:
                    raise FrameError(f"AMS/TCP length {length} is shorter than the AMS header")
                if length > self._max:
                    raise FrameError(f"AMS/TCP length {length} exceeds the limit of {self._max}")
                end = pos + AMS_TCP_HEADER_SIZE + length
                if len(buf) < end:
                    break
                start = pos + AMS_TCP_HEADER_SIZE
                header = AmsHeader.decode(bytes(buf[start:start + AMS_HEADER_SIZE]))
                out.append(AmsPacket(header, bytes(buf[start + AMS_HEADER_SIZE:end])))
                pos = end
        except FrameError as exc:
            self._broken = FrameError(str(exc))
            self._buf = bytearray()
            raise FrameError(str(exc), out) from None
        del buf[:pos]
        return out


# ---------------------------------------------------------------------------------------------------------
# FILETIME (100 ns since 1601-01-01 UTC)

FILETIME_UNIX_EPOCH = 116444736000000000


def filetime_from_unix(t: float) -> int:
    return FILETIME_UNIX_EPOCH + int(round(t * 10_000_000))


def unix_from_filetime(ft: int) -> float:
    return (ft - FILETIME_UNIX_EPOCH) / 10_000_000


def filetime_now() -> int:
    return FILETIME_UNIX_EPOCH + time.time_ns() // 100


# ---------------------------------------------------------------------------------------------------------
# command payloads

_U32 = struct.Struct("<I")
_U32x2 = struct.Struct("<II")
_U32x3 = struct.Struct("<III")
_U32x4 = struct.Struct("<IIII")


def _need(data: bytes, n: int, what: str, exact: bool = True) -> None:
    if (len(data) != n) if exact else (len(data) < n):
        raise PayloadError(f"{what}: {len(data)} bytes, expected {'' if exact else 'at least '}{n}")


@dataclass(frozen=True)
class Empty:
    """Request of ReadDeviceInfo and ReadState (no data)."""

    def encode(self) -> bytes:
        return b""

    @classmethod
    def decode(cls, data: bytes) -> Empty:
        _need(data, 0, "request without data")
        return cls()


@dataclass(frozen=True)
class ResultOnly:
    """Response of Write, WriteControl and DelDeviceNotification."""
    result: int = 0

    def encode(self) -> bytes:
        return _U32.pack(self.result)

    @classmethod
    def decode(cls, data: bytes) -> ResultOnly:
        _need(data, 4, "result")
        return cls(_U32.unpack(data)[0])


@dataclass(frozen=True)
class ReadDeviceInfoResponse:
    result: int = 0
    major: int = 0
    minor: int = 0
    build: int = 0
    name: str = ""

    def encode(self) -> bytes:
        raw = self.name.encode("ascii", "replace")[:15]
        return struct.pack("<IBBH16s", self.result, self.major, self.minor, self.build, raw)

    @classmethod
    def decode(cls, data: bytes) -> ReadDeviceInfoResponse:
        _need(data, 24, "ReadDeviceInfo response")
        res, ma, mi, bu, raw = struct.unpack("<IBBH16s", data)
        return cls(res, ma, mi, bu, raw.split(b"\0", 1)[0].decode("ascii", "replace"))


@dataclass(frozen=True)
class ReadRequest:
    group: int
    offset: int
    length: int

    def encode(self) -> bytes:
        return _U32x3.pack(self.group, self.offset, self.length)

    @classmethod
    def decode(cls, data: bytes) -> ReadRequest:
        _need(data, 12, "Read request")
        return cls(*_U32x3.unpack(data))


@dataclass(frozen=True)
class DataResponse:
    """Response of Read and ReadWrite: result, u32 length, data. The length field is there even on an
    error (pitfall 1: AdsLib always reads 8 bytes)."""
    result: int = 0
    data: bytes = b""

    def encode(self) -> bytes:
        return _U32x2.pack(self.result, len(self.data)) + self.data

    @classmethod
    def decode(cls, data: bytes) -> DataResponse:
        _need(data, 8, "Read response", exact=False)
        res, n = _U32x2.unpack_from(data)
        _need(data, 8 + n, "Read response")
        return cls(res, bytes(data[8:]))


ReadResponse = ReadWriteResponse = DataResponse


@dataclass(frozen=True)
class WriteRequest:
    group: int
    offset: int
    data: bytes

    def encode(self) -> bytes:
        return _U32x3.pack(self.group, self.offset, len(self.data)) + self.data

    @classmethod
    def decode(cls, data: bytes) -> WriteRequest:
        _need(data, 12, "Write request", exact=False)
        g, o, n = _U32x3.unpack_from(data)
        _need(data, 12 + n, "Write request")
        return cls(g, o, bytes(data[12:]))


@dataclass(frozen=True)
class ReadStateResponse:
    result: int = 0
    ads_state: int = ADSSTATE_RUN
    device_state: int = 0

    def encode(self) -> bytes:
        return struct.pack("<IHH", self.result, self.ads_state, self.device_state)

    @classmethod
    def decode(cls, data: bytes) -> ReadStateResponse:
        _need(data, 8, "ReadState response")
        return cls(*struct.unpack("<IHH", data))


@dataclass(frozen=True)
class WriteControlRequest:
    ads_state: int
    device_state: int
    data: bytes = b""

    def encode(self) -> bytes:
        return struct.pack("<HHI", self.ads_state, self.device_state, len(self.data)) + self.data

    @classmethod
    def decode(cls, data: bytes) -> WriteControlRequest:
        _need(data, 8, "WriteControl request", exact=False)
        a, d, n = struct.unpack_from("<HHI", data)
        _need(data, 8 + n, "WriteControl request")
        return cls(a, d, bytes(data[8:]))


@dataclass(frozen=True)
class AddNotificationRequest:
    """max_delay and cycle_time in 100 ns units (pitfall 6)."""
    group: int
    offset: int
    length: int
    trans_mode: int
    max_delay: int
    cycle_time: int

    _S = struct.Struct("<IIIIII16s")

    def encode(self) -> bytes:
        return self._S.pack(self.group, self.offset, self.length, self.trans_mode, self.max_delay,
                            self.cycle_time, b"\0" * 16)

    @classmethod
    def decode(cls, data: bytes) -> AddNotificationRequest:
        _need(data, 40, "AddDeviceNotification request")
        return cls(*cls._S.unpack(data)[:6])


@dataclass(frozen=True)
class AddNotificationResponse:
    result: int = 0
    handle: int = 0

    def encode(self) -> bytes:
        return _U32x2.pack(self.result, self.handle)

    @classmethod
    def decode(cls, data: bytes) -> AddNotificationResponse:
        _need(data, 8, "AddDeviceNotification response")
        return cls(*_U32x2.unpack(data))


@dataclass(frozen=True)
class DelNotificationRequest:
    handle: int

    def encode(self) -> bytes:
        return _U32.pack(self.handle)

    @classmethod
    def decode(cls, data: bytes) -> DelNotificationRequest:
        _need(data, 4, "DelDeviceNotification request")
        return cls(_U32.unpack(data)[0])


@dataclass(frozen=True)
class ReadWriteRequest:
    group: int
    offset: int
    read_length: int
    data: bytes

    def encode(self) -> bytes:
        return _U32x4.pack(self.group, self.offset, self.read_length, len(self.data)) + self.data

    @classmethod
    def decode(cls, data: bytes) -> ReadWriteRequest:
        _need(data, 16, "ReadWrite request", exact=False)
        g, o, rl, wl = _U32x4.unpack_from(data)
        _need(data, 16 + wl, "ReadWrite request")
        return cls(g, o, rl, bytes(data[16:]))


@dataclass(frozen=True)
class Sample:
    handle: int
    data: bytes


@dataclass(frozen=True)
class Stamp:
    timestamp: int                       # FILETIME
    samples: tuple[Sample, ...] = ()


@dataclass(frozen=True)
class DeviceNotification:
    """Command 8, server -> client: u32 length (of what follows), u32 stamps, per stamp {u64 FILETIME,
    u32 samples, per sample {u32 handle, u32 size, data}}."""
    stamps: tuple[Stamp, ...] = field(default_factory=tuple)

    def encode(self) -> bytes:
        parts = [_U32.pack(len(self.stamps))]
        for st in self.stamps:
            parts.append(struct.pack("<QI", st.timestamp, len(st.samples)))
            for s in st.samples:
                parts.append(_U32x2.pack(s.handle, len(s.data)))
                parts.append(s.data)
        body = b"".join(parts)
        return _U32.pack(len(body)) + body

    @classmethod
    def decode(cls, data: bytes) -> DeviceNotification:
        _need(data, 8, "DeviceNotification", exact=False)
        length, n_stamps = _U32x2.unpack_from(data)
        _need(data, 4 + length, "DeviceNotification")
        pos = 8
        stamps = []
        for _ in range(n_stamps):
            if len(data) < pos + 12:
                raise PayloadError("DeviceNotification: stamp header truncated")
            ts, n_samples = struct.unpack_from("<QI", data, pos)
            pos += 12
            samples = []
            for _ in range(n_samples):
                if len(data) < pos + 8:
                    raise PayloadError("DeviceNotification: sample header truncated")
                h, size = _U32x2.unpack_from(data, pos)
                pos += 8
                if len(data) < pos + size:
                    raise PayloadError("DeviceNotification: sample data truncated")
                samples.append(Sample(h, bytes(data[pos:pos + size])))
                pos += size
            stamps.append(Stamp(ts, tuple(samples)))
        if pos != len(data):
            raise PayloadError(f"DeviceNotification: {len(data) - pos} trailing bytes")
        return cls(tuple(stamps))


class _PayloadClass(Protocol):
    """A payload dataclass as REQUESTS/RESPONSES hold it (the class itself): ``decode`` makes one."""

    def decode(self, data: bytes) -> Any: ...


class _ResponseClass(_PayloadClass, Protocol):
    """A response class: the one made with only ``result`` is the response carrying that error."""

    def __call__(self, *, result: int = ...) -> Any: ...


REQUESTS: dict[int, _PayloadClass] = {
    Command.READ_DEVICE_INFO: Empty,
    Command.READ: ReadRequest,
    Command.WRITE: WriteRequest,
    Command.READ_STATE: Empty,
    Command.WRITE_CONTROL: WriteControlRequest,
    Command.ADD_DEVICE_NOTIFICATION: AddNotificationRequest,
    Command.DEL_DEVICE_NOTIFICATION: DelNotificationRequest,
    Command.DEVICE_NOTIFICATION: DeviceNotification,
    Command.READ_WRITE: ReadWriteRequest,
}

RESPONSES: dict[int, _ResponseClass] = {
    Command.READ_DEVICE_INFO: ReadDeviceInfoResponse,
    Command.READ: DataResponse,
    Command.WRITE: ResultOnly,
    Command.READ_STATE: ReadStateResponse,
    Command.WRITE_CONTROL: ResultOnly,
    Command.ADD_DEVICE_NOTIFICATION: AddNotificationResponse,
    Command.DEL_DEVICE_NOTIFICATION: ResultOnly,
    Command.READ_WRITE: DataResponse,
}


def decode_request(command: int, data: bytes):
    """ADS data of a request -> its dataclass; PayloadError if malformed, KeyError if unknown command."""
    return REQUESTS[command].decode(data)


def decode_response(command: int, data: bytes):
    return RESPONSES[command].decode(data)


def error_response(command: int, code: int):
    """The response of `command` carrying only the error `code`, in that command's layout."""
    cls = RESPONSES[command]
    return cls(result=code)


# ---------------------------------------------------------------------------------------------------------
# sum commands (ReadWrite on 0xF080 / 0xF081 / 0xF082, index offset = number of sub-commands)

@dataclass(frozen=True)
class SumReadItem:
    group: int
    offset: int
    length: int


@dataclass(frozen=True)
class SumWriteItem:
    group: int
    offset: int
    data: bytes


@dataclass(frozen=True)
class SumReadWriteItem:
    group: int
    offset: int
    read_length: int
    data: bytes


def encode_sum_read(items: list[SumReadItem]) -> bytes:
    return b"".join(_U32x3.pack(i.group, i.offset, i.length) for i in items)


def decode_sum_read(count: int, data: bytes) -> list[SumReadItem]:
    _need(data, 12 * count, "sum read request")
    return [SumReadItem(*_U32x3.unpack_from(data, 12 * k)) for k in range(count)]


def encode_sum_read_response(results: list[tuple[int, bytes]], lengths: list[int]) -> bytes:
    """n x u32 result, then every sub-read's data padded/truncated to its requested length (zeros on an
    error), the layout TwinCAT uses and pyads's adsSumRead walks."""
    head = b"".join(_U32.pack(r) for r, _ in results)
    body = b"".join((d[:n] + b"\0" * (n - len(d))) if r == 0 else b"\0" * n
                    for (r, d), n in zip(results, lengths))
    return head + body


def encode_sum_write(items: list[SumWriteItem]) -> bytes:
    return (b"".join(_U32x3.pack(i.group, i.offset, len(i.data)) for i in items)
            + b"".join(i.data for i in items))


def decode_sum_write(count: int, data: bytes) -> list[SumWriteItem]:
    _need(data, 12 * count, "sum write request", exact=False)
    heads = [_U32x3.unpack_from(data, 12 * k) for k in range(count)]
    pos = 12 * count
    total = pos + sum(n for _, _, n in heads)
    _need(data, total, "sum write request")
    items = []
    for g, o, n in heads:
        items.append(SumWriteItem(g, o, bytes(data[pos:pos + n])))
        pos += n
    return items


def encode_sum_results(results: list[int]) -> bytes:
    return b"".join(_U32.pack(r) for r in results)


def decode_sum_results(data: bytes) -> list[int]:
    if len(data) % 4:
        raise PayloadError("sum results: length not a multiple of 4")
    return [r for (r,) in _U32.iter_unpack(data)]


def encode_sum_read_write(items: list[SumReadWriteItem]) -> bytes:
    return (b"".join(_U32x4.pack(i.group, i.offset, i.read_length, len(i.data)) for i in items)
            + b"".join(i.data for i in items))


def decode_sum_read_write(count: int, data: bytes) -> list[SumReadWriteItem]:
    _need(data, 16 * count, "sum read-write request", exact=False)
    heads = [_U32x4.unpack_from(data, 16 * k) for k in range(count)]
    pos = 16 * count
    total = pos + sum(wl for *_, wl in heads)
    _need(data, total, "sum read-write request")
    items = []
    for g, o, rl, wl in heads:
        items.append(SumReadWriteItem(g, o, rl, bytes(data[pos:pos + wl])))
        pos += wl
    return items


def encode_sum_read_write_response(results: list[tuple[int, bytes]]) -> bytes:
    """n x (u32 result, u32 length), then each sub-command's data of that length."""
    return (b"".join(_U32x2.pack(r, len(d)) for r, d in results) + b"".join(d for _, d in results))


def decode_sum_read_write_response(count: int, data: bytes) -> list[tuple[int, bytes]]:
    _need(data, 8 * count, "sum read-write response", exact=False)
    heads = [_U32x2.unpack_from(data, 8 * k) for k in range(count)]
    pos = 8 * count
    _need(data, pos + sum(n for _, n in heads), "sum read-write response")
    out = []
    for r, n in heads:
        out.append((r, bytes(data[pos:pos + n])))
        pos += n
    return out
