"""What an ADS server serves: the `AdsDevice` interface (one device per AMS port or shared by several).

Threading: `read_state`, `read`, `write` and `read_write` are called from the server's worker threads
(or on its event loop where `nonblocking(group, offset, write)` says they never block); they may block, bounded
by their own timeout (well inside pyads's default 5 s).
`sample` is called on the event loop and must not block. Every failure is an `AdsError` (its code becomes
the ADS result); any other exception is logged by the server and answered with 0x700.
"""
from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable, Mapping
from dataclasses import dataclass


@dataclass(frozen=True)
class AdsSource:
    """Who sent a request: AMS source address, TCP peer "ip:port", the server's connection id, and
    whether the server's write policy lets it write (`may_write`; a device refuses writes with 0x723
    when False, or where it sees fit)."""
    net_id: str
    port: int
    peer: str
    conn_id: int
    may_write: bool


@dataclass(frozen=True)
class Symbol:
    """One entry of a device's symbol table: a name maps onto (index group, index offset, size in bytes).
    `type_name` is the IEC type as TwinCAT spells it ("LREAL", "UDINT", "ST_Foo", ...)."""
    group: int
    offset: int
    size: int
    type_name: str
    comment: str = ""


class AdsDevice(ABC):
    """One ADS device (e.g. the NC on ports 500/501). See the module doc for the threading rules."""

    name: str = "zenoh-nc"                          # ReadDeviceInfo name (<= 15 chars, ASCII)
    version: tuple[int, int, int] = (3, 1, 0)       # major, minor, build

    @abstractmethod
    def read_state(self) -> tuple[int, int]:
        """(ads_state, device_state); ads_state 5 (RUN) while the device is usable."""

    @abstractmethod
    def read(self, group: int, offset: int, length: int, src: AdsSource) -> bytes:
        """At most `length` bytes at (group, offset); raises AdsError. `length` is what the client asked
        (any u32: check it against the object's size before allocating, 0x705 if wrong). The server
        never sends more than `length` bytes (pitfall 2), it truncates a longer answer and logs it."""

    @abstractmethod
    def write(self, group: int, offset: int, data: bytes, src: AdsSource) -> None:
        """Write `data` at (group, offset); raises AdsError (0x723 when not src.may_write)."""

    def read_write(self, group: int, offset: int, length: int, data: bytes, src: AdsSource) -> bytes:
        """ADS ReadWrite: default 0x701 (service not supported)."""
        from nc_ads.errors import ADSERR_DEVICE_SRVNOTSUPP, AdsError
        raise AdsError(ADSERR_DEVICE_SRVNOTSUPP)

    @abstractmethod
    def sample(self, group: int, offset: int, length: int) -> bytes:
        """Non-blocking read from the device's cyclic image, for notifications (called on the event
        loop). AdsError if (group, offset) cannot be notified: AddDeviceNotification then fails with
        that code. The server pads/truncates the result to `length` (pitfall 4)."""

    def nonblocking(self, group: int, offset: int, write: bool = False) -> bool:
        """True if the request on (group, offset) never blocks (e.g. a read answered from the cyclic
        image): the server then calls it on its event loop instead of the worker pool, which saves a
        thread hop (0.1 ms against 0.5-0.9 ms per read on the loaded 2-core machine, bench/ads_server.py).
        `write` is False for an ADS Read, True for a Write or ReadWrite (a device whose reads of an object
        come from memory but whose writes send commands says True only for `write=False`).
        Must be cheap and must not raise. Default False (everything goes to the pool)."""
        return False

    def add_change_listener(self, cb: Callable[[], None]) -> None:
        """Register cb(), called from any thread (must be cheap) when a new cyclic image arrived.
        Default: no listener (the server then samples on its tick only)."""

    def symbols(self) -> Mapping[str, Symbol]:
        """Symbol table for 0xF003/0xF005/0xF006/0xF009 and sum commands by name; default empty."""
        return {}

    def connection_closed(self, conn_id: int) -> None:
        """A TCP connection ended: free what it claimed (called from a worker thread)."""

    def close(self) -> None:
        """Release the device's resources. Called by the device's owner (nc-ads's cli) after the server
        closed; the server itself never closes devices it was given."""
