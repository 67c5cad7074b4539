"""The frame ring (pure): what the cycle writes is, byte for byte, what the publisher reads and puts."""
from __future__ import annotations

import numpy as np
import pytest

from nc_schema import (
    FRAME_HEADER_DTYPE, NCJOBS_DTYPE, NCTOPLC_DTYPE, PLCTONC_DTYPE, FrameFlags, decode_frame, encode_frame,
)
from nc_server.server.frame_ring import HEADER_SIZE, FrameRing, ring_bytes


def _random(dtype: np.dtype, n: int, rng: np.random.Generator) -> np.ndarray:
    a = np.zeros(n, dtype=dtype)
    a.view(np.uint8)[:] = rng.integers(0, 256, a.nbytes, dtype=np.uint8)
    return a


def _pair(n: int, slots: int = 4) -> tuple[FrameRing, FrameRing]:
    buf = bytearray(ring_bytes(n, slots))
    w = FrameRing(buf, n, slots, create=True)
    return w, FrameRing(buf, n, slots)


@pytest.mark.parametrize("n, flags", [(0, 0), (1, 1), (4, 0), (256, 1)])
def test_frames_are_byte_identical_to_encode_frame(n: int, flags: int) -> None:
    rng = np.random.default_rng(n)
    w, r = _pair(n)
    recs, jobs, plc = _random(NCTOPLC_DTYPE, n, rng), _random(NCJOBS_DTYPE, n, rng), _random(PLCTONC_DTYPE, n, rng)
    cycle, t = 2**40 + 17, 1_763_900_000_123_456_789
    for k in range(3):  # the same arrays again (their byte views are kept), changed in place meanwhile
        recs.view(np.uint8)[:] = rng.integers(0, 256, recs.nbytes, dtype=np.uint8)
        seq = w.write(cycle + k, t + k, recs, flags, jobs, plc)
        got = r.read_newest()
        assert got is not None and got[0] == seq and got[3] == 0
        assert got[1] == encode_frame(cycle + k, t + k, recs, flags, jobs)
        assert got[2] == plc.tobytes() or (n == 0 and got[2] is None)
        assert r.read_newest() is None  # nothing new
    w.write(1, 2, recs, flags)  # without job records
    got = r.read_newest()
    assert got is not None and got[1] == encode_frame(1, 2, recs, flags) and got[2] is None
    # independent reference for the header: filled field by field through the numpy dtype
    ref = np.zeros((), dtype=FRAME_HEADER_DTYPE)
    ref["Magic"], ref["Version"], ref["HeaderSize"] = 0x314E435A, 1, 40  # (40: protocol 5's header, Epoch)
    ref["Cycle"], ref["NcTimeNs"], ref["AxisCount"], ref["RecordSize"], ref["Flags"] = 1, 2, n, 256, flags
    assert got[1][:40] == ref.tobytes()
    w.write(3, 4, recs, flags, epoch=(5 << 16) | 6)  # a hot-standby NC's epoch in the header
    got = r.read_newest()
    assert got is not None and got[1] == encode_frame(3, 4, recs, flags, epoch=(5 << 16) | 6)
    h, out, _ = decode_frame(got[1])
    assert out.tobytes() == recs.tobytes()


def test_a_non_contiguous_array_is_copied() -> None:
    w, r = _pair(3)
    part = np.zeros(6, dtype=NCTOPLC_DTYPE)[::2]
    part["SetPos"] = [1.0, 2.0, 3.0]
    w.write(5, 6, part)
    got = r.read_newest()
    assert got is not None and got[1] == encode_frame(5, 6, part)


def test_a_reader_that_fell_behind_takes_the_newest_and_counts_the_skipped() -> None:
    w, r = _pair(2, slots=4)
    recs = np.zeros(2, dtype=NCTOPLC_DTYPE)
    for k in range(1, 11):
        w.write(k, k, recs)
    got = r.read_newest()
    assert got is not None and got[0] == 10 and got[3] == 9
    assert decode_frame(got[1])[0]["Cycle"] == 10


def test_a_slot_overwritten_while_read_is_not_returned_torn() -> None:
    """The seqlock: a slot whose Seq changed (being rewritten) is not taken; the newest complete one is."""
    w, r = _pair(1, slots=2)
    recs = np.zeros(1, dtype=NCTOPLC_DTYPE)
    w.write(1, 1, recs)
    # a writer that was interrupted half-way through slot 2: Seq 0 in the slot, Newest not yet bumped
    off = HEADER_SIZE + (2 % 2) * w.slot_size
    w.mv[off:off + 8] = bytes(8)
    got = r.read_newest()
    assert got is not None and got[0] == 1 and decode_frame(got[1])[0]["Cycle"] == 1


def test_a_reader_refuses_a_buffer_without_a_ring() -> None:
    with pytest.raises(ValueError, match="no ring"):
        FrameRing(bytearray(ring_bytes(2)), 2)
    with pytest.raises(ValueError, match="bytes"):
        FrameRing(bytearray(10), 2, create=True)
    w, _ = _pair(2)
    with pytest.raises(ValueError, match="axes"):
        w.write(1, 1, np.zeros(3, dtype=NCTOPLC_DTYPE))


def test_stop_and_counters_go_through_the_header() -> None:
    w, r = _pair(2)
    assert not r.stop_requested and not w.counters().ready
    r.set_counters(7, 2, 1, True)
    assert w.counters() == type(w.counters())(7, 2, 1, True)
    w.request_stop()
    assert r.stop_requested


def test_a_promoted_reader_goes_on_after_the_last_slot_published() -> None:
    """A standby publisher promoted after the active one died neither repeats the frame that one put nor
    skips the newest one it did not."""
    w, active = _pair(2)
    standby = FrameRing(w.mv, 2, 4)  # (mapped at its start, long before it is promoted)
    recs = np.zeros(2, dtype=NCTOPLC_DTYPE)
    for c in range(3):
        w.write(c, c, recs)
    got = active.read_newest()
    assert got is not None
    active.set_published(got[0])  # ... and then it dies
    standby.resume_after_published()
    assert standby.read_newest() is None  # nothing new since: no frame twice
    seq = w.write(3, 3, recs)
    got = standby.read_newest()
    assert got is not None and got[0] == seq and got[3] == 0


def test_a_promoted_reader_takes_the_newest_slot_and_sees_the_last_frame_published() -> None:
    """The frames written between the last one put and the promotion are skipped (counted), not put late; the
    promoted publisher reads the last frame put (its frame/<P>ms windows go on from it) while it is in the ring."""
    w, active = _pair(2, slots=4)
    standby = FrameRing(w.mv, 2, 4)
    recs = np.zeros(2, dtype=NCTOPLC_DTYPE)
    assert standby.published_frame() is None  # (nothing published yet)
    w.write(1, 1_000_000, recs)
    got = active.read_newest()
    assert got is not None
    active.set_published(got[0])  # ... and then it dies
    for c in range(2, 5):
        w.write(c, c * 1_000_000, recs)
    assert standby.published_frame() == got[1]
    standby.resume_after_published()
    new = standby.read_newest()
    assert new is not None and decode_frame(new[1])[0]["Cycle"] == 4 and new[3] == 2
    w.write(5, 5_000_000, recs)  # (slot of the published frame, 4 slots later, overwritten)
    assert standby.published_frame() is None


def test_the_fence_marks_frames_older_than_the_max_age_stale() -> None:
    """A hot-standby NC's ring (docs/standby.md): a frame older than the takeover time, e.g. written before the NC
    froze, is stale for the publisher (dropped, counted); the NC's last frame never is; no fence, nothing is."""
    w, r = _pair(2)
    recs = np.zeros(2, dtype=NCTOPLC_DTYPE)
    w.write(1, 1_000_000_000, recs)
    frame = r.read_newest()[1]  # type: ignore[index]
    assert not r.stale(frame, 10**12)  # (no fence: MaxAgeNs 0)
    w.set_max_age(200_000_000)
    assert r.max_age_ns == 200_000_000
    assert not r.stale(frame, 1_000_000_000 + 200_000_000)
    assert r.stale(frame, 1_000_000_000 + 200_000_001)
    w.write(2, 1_000_000_000, recs, flags=int(FrameFlags.ShuttingDown))
    last = r.read_newest()[1]  # type: ignore[index]
    assert not r.stale(last, 10**12)
    assert r.fenced == 0
    r.count_fenced()
    r.count_fenced()
    assert w.fenced == 2


def test_job_records_and_plctonc_at_an_unchanged_version_are_kept_not_copied_byte_identical() -> None:
    """With ``versions`` a slot keeps the job records / PLCTONC it holds at the same count (the cycle copies
    them only after a change): every frame read is still byte for byte encode_frame's, through slot
    wrap-arounds, changes counted between writes, a frame without job records, and other arrays."""
    rng = np.random.default_rng(5)
    n, slots = 8, 4
    w, r = _pair(n, slots)
    recs, jobs, plc = _random(NCTOPLC_DTYPE, n, rng), _random(NCJOBS_DTYPE, n, rng), _random(PLCTONC_DTYPE, n, rng)
    jv = pv = 0
    for k in range(40):
        recs.view(np.uint8)[:] = rng.integers(0, 256, recs.nbytes, dtype=np.uint8)
        if k % 7 == 3:  # a job record changed (counted)
            jobs.view(np.uint8)[k % jobs.nbytes] ^= 0xFF
            jv += 1
        if k % 5 == 1:  # a PLCTONC changed (counted)
            plc.view(np.uint8)[k % plc.nbytes] ^= 0x5A
            pv += 1
        if k == 20:  # other arrays (a core replaced) at the same counts
            jobs, plc = _random(NCJOBS_DTYPE, n, rng), _random(PLCTONC_DTYPE, n, rng)
        if k == 30:
            w.write(k, k, recs, 0)  # a frame without job records and PLCTONC in between
            got = r.read_newest()
            assert got is not None and got[1] == encode_frame(k, k, recs, 0) and got[2] is None
            continue
        w.write(k, k, recs, 0, jobs, plc, (jv, pv))
        got = r.read_newest()
        assert got is not None
        assert got[1] == encode_frame(k, k, recs, 0, jobs), k
        assert got[2] == plc.tobytes(), k
