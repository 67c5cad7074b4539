"""The cycle's output in shared memory: a ring of frame slots that the frame publisher reads.

The cycle thread writes each cycle's status frame (the bytes of ``nc/<nc>/frame``) and the applied
PLCTONC records into the next slot and bumps the ring's sequence number; the publisher
(:mod:`.publisher`, by default a child process with its own interpreter and GIL) wakes on an
eventfd, copies the newest slot out and publishes it. The cycle signals that eventfd only for a frame
the publisher has work for: one whose NcTimeNs reached the header's WakeAtNs (which the publisher sets
to its next due put: 0 while something is put every frame), the NC's last frame, or one whose NC time
went back. The cycle never waits for the publisher: a
publisher that falls behind skips to the newest slot (counted), one that is gone costs the cycle
nothing.

Layout (little endian), pure and testable on any buffer (``bytearray`` in tests, an ``mmap`` of a
memfd in the server):

* header, :data:`HEADER_SIZE` bytes: Magic u32, Version u16, Slots u16, SlotSize u32, pad u32,
  Newest u64 (sequence number of the newest complete slot, 0 = none yet), Stop u32, pad u32;
  then the publisher's counters (written by the publisher only): Sent u64, Dropped u64,
  PutErrors u64, Ready u32 (1 once its publishers are declared), pad u32; Published u64 (the sequence
  number of the last slot the active publisher put: a standby publisher promoted after it died goes
  on with the newest slot after it, skipping, and counting as dropped, the ones in between), MaxAgeNs u64
  (written by the NC: the fence of a hot-standby NC, 0 = none; the publisher drops a frame whose NcTimeNs is
  older than that, docs/standby.md), Fenced u64 (frames so dropped, by the publisher), WakeAtNs u64 (written by
  the publisher: the NC time of its next due put, 0 = every frame; the cycle signals the eventfd only for a frame
  at or after it), then padding;
* ``Slots`` slots of ``SlotSize`` bytes: Seq u64 (0 while being written), FrameLen u32,
  PlcLen u32, then the frame bytes, then the PLCTONC bytes.

A slot is overwritten ``Slots`` cycles after it was written; the reader checks the slot's Seq
before and after copying (a seqlock) and retries with the newest slot if it changed meanwhile.
"""
from __future__ import annotations

import collections
import struct
from dataclasses import dataclass

import numpy as np

from nc_schema import (
    FRAME_HEADER_SIZE, NCJOBS_SIZE, NCTOPLC_SIZE, PLCTONC_SIZE, FrameFlags, frame_stamp, pack_frame_header_into,
)

__all__ = ["FrameRing", "RingCounters", "RING_SLOTS", "HEADER_SIZE", "slot_size_for"]

RING_MAGIC = 0x4E435247  # "GRCN"
RING_VERSION = 5  # (4: the frame header of protocol 5, 40 bytes; 5: WakeAtNs)
#: Slots in the ring: the publisher has RING_SLOTS - 1 cycles to copy a slot out.
RING_SLOTS = 16
HEADER_SIZE = 128
_SLOT_HEAD = struct.Struct("<QII")
_HEAD = struct.Struct("<IHHII")
_U64 = struct.Struct("<Q")
_U32 = struct.Struct("<I")
_OFF_NEWEST = 16
_OFF_STOP = 24
_OFF_SENT = 32
_OFF_DROPPED = 40
_OFF_PUT_ERRORS = 48
_OFF_READY = 56
_OFF_PUBLISHED = 64
_OFF_MAX_AGE = 72
_OFF_FENCED = 80
_OFF_WAKE_AT = 88
def slot_size_for(n_axes: int) -> int:
    """Bytes of one slot for ``n_axes`` axes (frame with job records + PLCTONC), 64-byte aligned."""
    frame = FRAME_HEADER_SIZE + n_axes * (NCTOPLC_SIZE + NCJOBS_SIZE)
    size = _SLOT_HEAD.size + frame + n_axes * PLCTONC_SIZE
    return (size + 63) // 64 * 64


def ring_bytes(n_axes: int, slots: int = RING_SLOTS) -> int:
    """Total size of a ring for ``n_axes`` axes [bytes]."""
    return HEADER_SIZE + slots * slot_size_for(n_axes)


@dataclass(frozen=True)
class RingCounters:
    """The publisher's counters as the ring holds them."""

    sent: int
    dropped: int
    put_errors: int
    ready: bool


#: byte views of the arrays written last (the NC's nctoplc / ncjobs / plctonc: the same arrays every cycle);
#: making a memoryview of a structured array costs more than copying 64 records
_byte_views: collections.OrderedDict[int, tuple[np.ndarray, memoryview]] = collections.OrderedDict()


def _as_bytes(a: np.ndarray) -> memoryview | bytes:
    if not a.flags.c_contiguous:
        return a.tobytes()
    hit = _byte_views.get(id(a))
    if hit is None or hit[0] is not a:
        hit = _byte_views[id(a)] = (a, a.view(np.uint8).data.cast("B"))
        while len(_byte_views) > 8:
            _byte_views.popitem(last=False)
    return hit[1]


class FrameRing:
    """A frame ring over ``buf`` (writable, at least :func:`ring_bytes` long).

    Args:
        buf: the shared buffer.
        n_axes: axes per frame (fixes the slot size).
        slots: number of slots.
        create: write a fresh header (the writer); False: check the existing one (the reader).

    Raises:
        ValueError: the buffer is too small, or (reader) its header is not a ring of this layout.
    """

    def __init__(self, buf: memoryview | bytearray, n_axes: int, slots: int = RING_SLOTS, create: bool = False) -> None:
        self.mv = memoryview(buf).cast("B") if not isinstance(buf, memoryview) or buf.format != "B" else buf
        self.n_axes = int(n_axes)
        self.slots = int(slots)
        self.slot_size = slot_size_for(self.n_axes)
        if len(self.mv) < HEADER_SIZE + self.slots * self.slot_size:
            raise ValueError(f"frame ring: buffer of {len(self.mv)} bytes, {ring_bytes(self.n_axes, self.slots)} needed")
        if create:
            self.mv[:HEADER_SIZE] = bytes(HEADER_SIZE)
            _HEAD.pack_into(self.mv, 0, RING_MAGIC, RING_VERSION, self.slots, self.slot_size, 0)
        else:
            magic, version, slots_, size, _ = _HEAD.unpack_from(self.mv, 0)
            if (magic, version, slots_, size) != (RING_MAGIC, RING_VERSION, self.slots, self.slot_size):
                raise ValueError("frame ring: the shared buffer holds no ring of this layout")
        self.seq = _U64.unpack_from(self.mv, _OFF_NEWEST)[0]
        self._last_read = self.seq
        #: per slot, the (array, version) whose job records / PLCTONC it holds (write(): versions given)
        self._held: list[list[tuple[np.ndarray, int] | None]] = [[None, None] for _ in range(self.slots)]

    def release(self) -> None:
        """Drop the view (before the underlying mmap is closed)."""
        self.mv.release()

    # ---- writer (the cycle thread) ------------------------------------------------------------
    def write(self, cycle: int, nc_time_ns: int, records: np.ndarray, flags: int = 0,
              jobs: np.ndarray | None = None, plctonc: np.ndarray | None = None,
              versions: tuple[int, int] | None = None, epoch: int = 0) -> int:
        """Write one cycle's frame (``nc_schema.encode_frame`` byte for byte) and PLCTONC; its sequence number.

        Args:
            epoch: the NC's epoch (its hot-standby pair's, 0 without redundancy), in the frame header.
            versions: the change counts of ``jobs`` and ``plctonc`` (``JobRecords.version``,
                ``NcCore.plctonc_version``): a slot that holds the same array at the same count already
                keeps those bytes (the same bytes: no copy). None: both copied.

        Raises:
            ValueError: more axes than the ring was made for.
        """
        n = len(records)
        if n > self.n_axes:
            raise ValueError(f"frame ring: {n} axes, made for {self.n_axes}")
        seq = self.seq + 1
        mv = self.mv
        held = self._held[seq % self.slots]
        off = HEADER_SIZE + (seq % self.slots) * self.slot_size
        _U64.pack_into(mv, off, 0)  # being written
        p = off + _SLOT_HEAD.size
        p += pack_frame_header_into(mv, p, cycle, nc_time_ns, n, flags, jobs is not None, epoch)
        rb = _as_bytes(records)
        mv[p:p + len(rb)] = rb
        p += len(rb)
        if jobs is not None:
            jb = _as_bytes(jobs)
            p = self._put(held, 0, jobs, versions[0] if versions is not None else None, jb, p)
        else:
            held[0] = held[1] = None  # (what follows the records moved)
        flen = p - off - _SLOT_HEAD.size
        plen = 0
        if plctonc is not None:
            pb = _as_bytes(plctonc)
            plen = len(pb)
            self._put(held, 1, plctonc, versions[1] if versions is not None else None, pb, p)
        else:
            held[1] = None
        _SLOT_HEAD.pack_into(mv, off, seq, flen, plen)
        _U64.pack_into(mv, _OFF_NEWEST, seq)
        self.seq = seq
        return seq

    def _put(self, held: list[tuple[np.ndarray, int] | None], k: int, arr: np.ndarray, version: int | None,
             data: memoryview | bytes, p: int) -> int:
        """Copy ``data`` (of ``arr`` at ``version``) to ``p`` unless the slot holds it there already; returns
        the end. (A slot is only ever written here, at the same offsets for the same layout: the bytes it
        holds for the same array at the same version are the bytes a copy would write.)"""
        end = p + len(data)
        h = held[k]
        if version is None or h is None or h[0] is not arr or h[1] != version or not arr.flags.c_contiguous:
            self.mv[p:end] = data
            held[k] = (arr, version) if version is not None else None
        return end

    @property
    def wake_at(self) -> int:
        """WakeAtNs: the NC time [ns] from which on the publisher wants to be signalled (0: every frame)."""
        return _U64.unpack_from(self.mv, _OFF_WAKE_AT)[0]

    def set_wake_at(self, ns: int) -> None:
        """Set WakeAtNs (the publisher only): the NC time of its next due put; 0: signal every frame."""
        _U64.pack_into(self.mv, _OFF_WAKE_AT, min(max(0, int(ns)), (1 << 64) - 1))

    def request_stop(self) -> None:
        """Ask the publisher to publish what is there and end."""
        _U32.pack_into(self.mv, _OFF_STOP, 1)

    def set_max_age(self, ns: int) -> None:
        """The fence: the publisher puts no frame whose NcTimeNs is more than ``ns`` older than its clock
        (CLOCK_REALTIME); 0: no fence. A hot-standby NC sets its takeover time: a frame written before the NC
        froze for longer than that may have been superseded by the standby's, and never goes out after it."""
        _U64.pack_into(self.mv, _OFF_MAX_AGE, max(0, int(ns)))

    # ---- reader (the publisher) ---------------------------------------------------------------
    @property
    def max_age_ns(self) -> int:
        return _U64.unpack_from(self.mv, _OFF_MAX_AGE)[0]

    def stale(self, frame: bytes, now_ns: int) -> bool:
        """Whether ``frame`` is beyond the fence at ``now_ns`` (CLOCK_REALTIME): older than MaxAgeNs, and not the NC's
        last frame (flag ShuttingDown, which always goes out)."""
        max_age = self.max_age_ns
        if not max_age:
            return False
        _, nc_time_ns, flags = frame_stamp(frame)
        return not flags & int(FrameFlags.ShuttingDown) and now_ns - nc_time_ns > max_age

    @property
    def fenced(self) -> int:
        """Frames the publisher dropped as older than the fence."""
        return _U64.unpack_from(self.mv, _OFF_FENCED)[0]

    def count_fenced(self) -> None:
        """Note one frame dropped as older than the fence (the publisher only)."""
        _U64.pack_into(self.mv, _OFF_FENCED, self.fenced + 1)

    @property
    def stop_requested(self) -> bool:
        return bool(_U32.unpack_from(self.mv, _OFF_STOP)[0])

    @property
    def newest(self) -> int:
        return _U64.unpack_from(self.mv, _OFF_NEWEST)[0]

    def _read_slot(self, seq: int) -> tuple[bytes, bytes | None] | None:
        """Slot ``seq``'s (frame bytes, PLCTONC bytes or None); None if it was overwritten (meanwhile)."""
        mv = self.mv
        off = HEADER_SIZE + (seq % self.slots) * self.slot_size
        s1, flen, plen = _SLOT_HEAD.unpack_from(mv, off)
        if s1 != seq:
            return None
        p = off + _SLOT_HEAD.size
        frame = bytes(mv[p:p + flen])
        plc = bytes(mv[p + flen:p + flen + plen]) if plen else None
        if _U64.unpack_from(mv, off)[0] != seq:
            return None
        return frame, plc

    def read_newest(self) -> tuple[int, bytes, bytes | None, int] | None:
        """The newest slot not read yet: (seq, frame bytes, PLCTONC bytes or None, slots skipped); None
        when nothing new."""
        for _ in range(8):
            seq = _U64.unpack_from(self.mv, _OFF_NEWEST)[0]
            if seq == self._last_read:
                return None
            got = self._read_slot(seq)
            if got is None:
                continue  # overwritten meanwhile: take the newest again
            skipped = max(0, seq - self._last_read - 1)
            self._last_read = seq
            return seq, got[0], got[1], skipped
        return None

    def published_frame(self) -> bytes | None:
        """The frame of the last slot published (by an earlier publisher), if it is still in the ring."""
        seq = _U64.unpack_from(self.mv, _OFF_PUBLISHED)[0]
        got = self._read_slot(seq) if seq else None
        return None if got is None else got[0]

    def resume_after_published(self) -> None:
        """Read on after the last slot published (by this or an earlier publisher): a standby publisher
        promoted when the active one died puts the newest frame if it is newer than that one, never an
        older one (unless that one died within its put: then its frame goes out again); the slots written
        in between are skipped (counted as dropped)."""
        self._last_read = _U64.unpack_from(self.mv, _OFF_PUBLISHED)[0]

    def set_published(self, seq: int) -> None:
        """Note that slot ``seq`` has been put (the active publisher only)."""
        _U64.pack_into(self.mv, _OFF_PUBLISHED, seq)

    def set_counters(self, sent: int, dropped: int, put_errors: int, ready: bool) -> None:
        """Store the publisher's counters (the publisher only)."""
        _U64.pack_into(self.mv, _OFF_SENT, sent)
        _U64.pack_into(self.mv, _OFF_DROPPED, dropped)
        _U64.pack_into(self.mv, _OFF_PUT_ERRORS, put_errors)
        _U32.pack_into(self.mv, _OFF_READY, 1 if ready else 0)

    def counters(self) -> RingCounters:
        mv = self.mv
        return RingCounters(_U64.unpack_from(mv, _OFF_SENT)[0], _U64.unpack_from(mv, _OFF_DROPPED)[0],
                            _U64.unpack_from(mv, _OFF_PUT_ERRORS)[0], bool(_U32.unpack_from(mv, _OFF_READY)[0]))
