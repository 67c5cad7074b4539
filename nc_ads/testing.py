"""`FakeDevice`: an in-memory AdsDevice for the server's tests and fuzz target (not used by nc-ads).

Its table (all little-endian):
- 0x4001/0x01  UDINT axis id (1), read-only
- 0x4001/0x02  STRING(31) name, 32 bytes, read/write (shorter writes allowed: the rest is zeroed)
- 0x4001/0x27  LREAL MaxVelocity (1234.5), read/write
- 0x4101/0x00  256-byte state struct, read-only; `step()` increments the LREAL at byte 16 (SetPos)
- 0x4101/0x0A  LREAL SetPos (the same value), read-only
- 0x4002/8*i   LREAL GVL.v<i> = 1.5*i, i in 0..n_values-1 (default N_VALUES = 600), read/write
- ReadWrite 0x4201/any: returns the written bytes reversed (at most the read length)
Other groups -> 0x702, other offsets -> 0x703, wrong sizes -> 0x705, read-only -> 0x704, writes from a
source without `may_write` -> 0x723. `errors[(group, offset)] = code` makes reads/writes there fail with
that code (e.g. an NC code 0x4358); `delays[(group, offset)] = s` makes them block s seconds;
`crash_groups` makes reads there raise RuntimeError (the server must answer 0x700).
`nonblocking()` is True except where a delay is set, `inline_off` is True, or for writes
(`write=True`) when `inline_writes_off` is True.
Symbols: MAIN.fVelo (0x4001/0x27), MAIN.nAxisId, MAIN.sName, MAIN.stState (256 B), GVL.v<i>.
"""
from __future__ import annotations

import struct
import threading
import time
from collections.abc import Callable, Mapping

from nc_ads.device import AdsDevice, AdsSource, Symbol
from nc_ads.errors import (
    ADSERR_DEVICE_ACCESSDENIED, ADSERR_DEVICE_INVALIDACCESS, ADSERR_DEVICE_INVALIDGRP,
    ADSERR_DEVICE_INVALIDOFFSET, ADSERR_DEVICE_INVALIDSIZE, AdsError,
)

N_VALUES = 600
STATE_SIZE = 256


class FakeDevice(AdsDevice):
    name = "FakeNC"
    version = (3, 1, 4024)

    def __init__(self, n_values: int = N_VALUES) -> None:
        self.lock = threading.Lock()
        # (group, offset) -> [bytearray value, writable]
        self.mem: dict[tuple[int, int], list] = {
            (0x4001, 0x01): [bytearray(struct.pack("<I", 1)), False],
            (0x4001, 0x02): [bytearray(b"Axis 1".ljust(32, b"\0")), True],
            (0x4001, 0x27): [bytearray(struct.pack("<d", 1234.5)), True],
            (0x4101, 0x00): [bytearray(STATE_SIZE), False],
        }
        for i in range(n_values):
            self.mem[(0x4002, 8 * i)] = [bytearray(struct.pack("<d", 1.5 * i)), True]
        self.groups = {g for g, _ in self.mem} | {0x4201}
        self.errors: dict[tuple[int, int], int] = {}
        self.delays: dict[tuple[int, int], float] = {}
        self.crash_groups: set[int] = set()
        self.inline_off = False   # True: every read/write goes through the server's worker pool
        self.inline_writes_off = False   # True: writes/read-writes go through the pool, reads may not
        self.ads_state = (5, 0)
        self.closed_conns: list[int] = []
        self.writes: list[tuple[int, int, bytes, AdsSource]] = []
        self._listeners: list[Callable[[], None]] = []
        self._symbols: dict[str, Symbol] = {
            "MAIN.fVelo": Symbol(0x4001, 0x27, 8, "LREAL", "max velocity"),
            "MAIN.nAxisId": Symbol(0x4001, 0x01, 4, "UDINT"),
            "MAIN.sName": Symbol(0x4001, 0x02, 32, "STRING(31)"),
            "MAIN.stState": Symbol(0x4101, 0x00, STATE_SIZE, "NCAXISSTATE_ONLINESTRUCT"),
        }
        for i in range(n_values):
            self._symbols[f"GVL.v{i}"] = Symbol(0x4002, 8 * i, 8, "LREAL")

    # -- test controls ----------------------------------------------------------------------------
    def set_pos(self, value: float) -> None:
        with self.lock:
            self.mem[(0x4101, 0)][0][16:24] = struct.pack("<d", value)
        for cb in list(self._listeners):
            cb()

    def pos(self) -> float:
        with self.lock:
            return struct.unpack_from("<d", self.mem[(0x4101, 0)][0], 16)[0]

    def step(self) -> None:
        self.set_pos(self.pos() + 1.0)

    def value(self, group: int, offset: int) -> bytes:
        with self.lock:
            return bytes(self.mem[(group, offset)][0])

    # -- AdsDevice -----------------------------------------------------------------------------------
    def read_state(self) -> tuple[int, int]:
        return self.ads_state

    def _cell(self, group: int, offset: int) -> list:
        if group in self.crash_groups:
            raise RuntimeError("FakeDevice crash (test)")
        code = self.errors.get((group, offset))
        if code is not None:
            raise AdsError(code)
        if group == 0x4101 and offset == 0x0A:
            return [self.mem[(0x4101, 0)][0][16:24], False]
        if group not in self.groups:
            raise AdsError(ADSERR_DEVICE_INVALIDGRP)
        cell = self.mem.get((group, offset))
        if cell is None:
            raise AdsError(ADSERR_DEVICE_INVALIDOFFSET)
        return cell

    def _delay(self, group: int, offset: int) -> None:
        delay = self.delays.get((group, offset))
        if delay:
            time.sleep(delay)   # outside the lock: other requests go on meanwhile

    def read(self, group: int, offset: int, length: int, src: AdsSource) -> bytes:
        self._delay(group, offset)
        with self.lock:
            value, _ = self._cell(group, offset)
            if length > len(value):
                raise AdsError(ADSERR_DEVICE_INVALIDSIZE)
            return bytes(value[:length])

    def write(self, group: int, offset: int, data: bytes, src: AdsSource) -> None:
        if not src.may_write:
            raise AdsError(ADSERR_DEVICE_ACCESSDENIED)
        self._delay(group, offset)
        with self.lock:
            cell = self._cell(group, offset)
            if not cell[1]:
                raise AdsError(ADSERR_DEVICE_INVALIDACCESS)
            if len(data) > len(cell[0]) or (len(data) != len(cell[0]) and (group, offset) != (0x4001, 0x02)):
                raise AdsError(ADSERR_DEVICE_INVALIDSIZE)
            cell[0][:len(data)] = data
            cell[0][len(data):] = bytes(len(cell[0]) - len(data))
            self.writes.append((group, offset, bytes(data), src))
        for cb in list(self._listeners):
            cb()

    def read_write(self, group: int, offset: int, length: int, data: bytes, src: AdsSource) -> bytes:
        if group == 0x4201:
            return bytes(reversed(data))[:length]
        with self.lock:
            self._cell(group, offset)
        raise AdsError(ADSERR_DEVICE_INVALIDACCESS)

    def nonblocking(self, group: int, offset: int, write: bool = False) -> bool:
        if write and self.inline_writes_off:
            return False
        return (group, offset) not in self.delays and not self.inline_off

    def sample(self, group: int, offset: int, length: int) -> bytes:
        if group == 0x4201:
            raise AdsError(ADSERR_DEVICE_INVALIDACCESS)
        with self.lock:   # never blocks: no delay here
            value, _ = self._cell(group, offset)
            return bytes(value)

    def add_change_listener(self, cb: Callable[[], None]) -> None:
        self._listeners.append(cb)

    def symbols(self) -> Mapping[str, Symbol]:
        return self._symbols

    def connection_closed(self, conn_id: int) -> None:
        with self.lock:
            self.closed_conns.append(conn_id)
