"""The frame codec (nc_schema.frames): the struct forms agree with the dtypes byte for byte, and the
fast encoders/decoders with the numpy records."""
import numpy as np
import pytest

import nc_schema as s


def _random(dtype: np.dtype, n: int, seed: int) -> np.ndarray:
    raw = np.random.default_rng(seed).integers(0, 256, n * dtype.itemsize, dtype=np.uint8).tobytes()
    return np.frombuffer(raw, dtype=dtype).copy()


@pytest.mark.parametrize("dtype", [s.NCTOPLC_DTYPE, s.PLCTONC_DTYPE, s.FRAME_HEADER_DTYPE, s.PLC_FRAME_HEADER_DTYPE,
                                   s.STAMP_DTYPE])
def test_struct_of_unpacks_what_numpy_reads(dtype: np.dtype) -> None:
    st = s.struct_of(dtype)
    assert st.size == dtype.itemsize
    rec = _random(dtype, 1, 3)[0]
    values = list(st.unpack(rec.tobytes()))
    for m in s.members(dtype):
        off, one = s.member_struct(dtype, m.name)
        assert off == m.offset
        got = one.unpack_from(rec.tobytes(), off)
        want = np.atleast_1d(rec[m.name]).tolist()
        assert list(got) == pytest.approx(want, nan_ok=True)
        assert values[:len(got)] == pytest.approx(list(got), nan_ok=True)
        del values[:len(got)]
    assert values == []


def test_struct_of_refuses_nested_or_gapped_layouts() -> None:
    with pytest.raises(ValueError):
        s.struct_of(s.NCJOBS_DTYPE)  # Ended[] is a struct
    assert s.PLC_AXIS_HEAD_STRUCT.size + s.PLCTONC_SIZE == s.PLC_AXIS_RECORD_SIZE


@pytest.mark.parametrize("with_jobs", [False, True])
def test_frame_header_records_and_stamp(with_jobs: bool) -> None:
    recs = _random(s.NCTOPLC_DTYPE, 3, 1)
    recs["AxisId"] = [5, 1, 9]
    jobs = _random(s.NCJOBS_DTYPE, 3, 2) if with_jobs else None
    data = s.encode_frame(77, 88, recs, 1, jobs)
    h = s.frame_header(data)
    assert (h.Cycle, h.NcTimeNs, h.AxisCount, h.job_records) == (77, 88, 3, with_jobs)
    assert s.frame_stamp(data) == (77, 88, h.Flags)
    hdr, back, jb = s.decode_frame(data)
    assert s.to_dict(hdr) == h._asdict()
    assert back.tobytes() == recs.tobytes() and (jb is None) == (not with_jobs)
    h2, by_id = s.frame_records(data)
    assert h2 == h and list(by_id) == [5, 1, 9]
    assert by_id[1] == recs[1].tobytes() and data[h.record_offset(2):h.record_offset(2) + s.NCTOPLC_SIZE] == by_id[9]
    buf = bytearray(64)
    assert s.pack_frame_header_into(buf, 8, 77, 88, 3, 1, with_jobs) == s.FRAME_HEADER_SIZE
    assert bytes(buf[8:8 + s.FRAME_HEADER_SIZE]) == data[:s.FRAME_HEADER_SIZE]
    for bad in (data[:-1], b"XXXX" + data[4:], data[:10]):
        with pytest.raises(ValueError):
            s.frame_header(bad)
        with pytest.raises(ValueError):
            s.frame_records(bad)


def test_plc_frame_from_an_array_or_per_axis_buffers() -> None:
    pt = _random(s.PLCTONC_DTYPE, 3, 4)
    ids = [7, 1, 65535]
    ref = s.encode_plc_frame(2**40 + 3, ids, pt)
    assert s.encode_plc_records(2**40 + 3, [(a, bytearray(r.tobytes())) for a, r in zip(ids, pt)]) == ref
    assert s.encode_plc_records(2**40 + 3, [(a, pt[k:k + 1]) for k, a in enumerate(ids)]) == ref
    h, back = s.decode_plc_frame(ref)
    assert int(h["PlcCycle"]) == 2**40 + 3 and back["AxisId"].tolist() == ids
    assert back["PlcToNc"].tobytes() == pt.tobytes()
    with pytest.raises(ValueError):
        s.encode_plc_frame(1, ids, pt[:2])
    with pytest.raises(ValueError):
        s.decode_plc_frame(s.encode_plc_records(1, [(1, b"short")]))
    assert s.decode_stamp(s.encode_stamp(2**63, 5)) == (2**63, 5)
    with pytest.raises(ValueError):
        s.decode_stamp(b"\0" * 15)


def test_plc_frame_axis_heads_are_cached_and_bounded() -> None:
    from nc_schema import frames
    pt = _random(s.PLCTONC_DTYPE, 1, 5)
    for a in range(5000):  # more ids than the cache keeps: it starts over, the frames stay right
        data = s.encode_plc_records(1, [(a, pt)])
        assert s.decode_plc_frame(data)[1]["AxisId"].tolist() == [a]
    assert len(frames._AXIS_HEADS) <= 4096


def test_frame_header_refuses_a_header_size_below_the_header() -> None:
    # HeaderSize 8 and one 256-byte record: the length adds up (8 + 256), but the records would overlap the header
    head = s.FRAME_HEADER_STRUCT.pack(s.FRAME_MAGIC, s.WIRE_VERSION, 8, 1, 2, 1, s.NCTOPLC_SIZE, 0, 0)
    data = head + bytes(8 + s.NCTOPLC_SIZE - len(head))
    with pytest.raises(ValueError, match="sizes do not add up"):
        s.frame_header(data)
    ok = s.FRAME_HEADER_STRUCT.pack(s.FRAME_MAGIC, s.WIRE_VERSION, 40, 1, 2, 1, s.NCTOPLC_SIZE, 0, 7)
    h = s.frame_header(ok + bytes(s.NCTOPLC_SIZE))
    assert (h.AxisCount, h.Epoch) == (1, 7)


def test_the_epoch_in_the_frame_header_and_the_stamp() -> None:
    """Protocol 5: FRAME_HEADER is 40 bytes, Epoch a ULINT at 32; STAMP 24 bytes, Epoch a ULINT at 16. Every
    decoder and the NC's own helpers carry it through (a view frame keeps it)."""
    epoch_off, epoch = s.member_struct(s.FRAME_HEADER_DTYPE, "Epoch")
    assert (s.FRAME_HEADER_SIZE, epoch_off, epoch.format) == (40, 32, "<Q")
    assert s.member_struct(s.STAMP_DTYPE, "Epoch")[0] == 16 and s.STAMP_SIZE == 24
    recs = _random(s.NCTOPLC_DTYPE, 3, 1)
    recs["AxisId"] = [5, 1, 9]
    jobs = _random(s.NCJOBS_DTYPE, 3, 2)
    e = (7 << 16) | 0xBEEF
    data = s.encode_frame(77, 88, recs, 0, jobs, epoch=e)
    assert s.frame_header(data).Epoch == e and s.frame_header(data).HeaderSize == 40
    assert int(s.decode_frame(data)[0]["Epoch"]) == e and s.frame_records(data)[0].Epoch == e
    assert s.frame_epoch(data) == e and s.frame_epoch(s.view_frame(data, 3, [2])) == e
    assert s.encode_frame(1, 2, recs).startswith(s.encode_frame(1, 2, recs, epoch=0)[:40])
    assert s.frame_header(s.encode_frame(1, 2, recs)).Epoch == 0  # without redundancy: 0
    buf = bytearray(64)
    s.pack_frame_header_into(buf, 0, 77, 88, 3, 0, True, e)
    assert bytes(buf[:40]) == data[:40]
    assert s.decode_stamp_epoch(s.encode_stamp(3, 4, e)) == (3, 4, e)
    assert s.decode_stamp(s.encode_stamp(3, 4, e)) == (3, 4)
    assert len(s.encode_stamp(3, 4)) == 24


@pytest.mark.parametrize("with_jobs", [False, True])
def test_a_frame_and_a_stamp_of_protocol_4_read_with_epoch_0(with_jobs: bool) -> None:
    """An NC before protocol 5 sends a 32-byte header (HeaderSize 32) and a 16-byte STAMP: read, Epoch 0. A
    receiver before protocol 5 reads the new frames by their HeaderSize (records where HeaderSize says)."""
    import struct
    recs = _random(s.NCTOPLC_DTYPE, 2, 1)
    recs["AxisId"] = [3, 4]
    jobs = _random(s.NCJOBS_DTYPE, 2, 2) if with_jobs else None
    new = s.encode_frame(9, 10, recs, 0, jobs, epoch=5)
    old = new[:6] + struct.pack("<H", 32) + new[8:32] + new[40:]
    h = s.frame_header(old)
    assert (h.HeaderSize, h.Epoch, h.Cycle, h.AxisCount, h.job_records) == (32, 0, 9, 2, with_jobs)
    hdr, back, jb = s.decode_frame(old)
    assert int(hdr["Epoch"]) == 0 and int(hdr["Cycle"]) == 9 and back.tobytes() == recs.tobytes()
    assert (jb is None) == (not with_jobs)
    assert list(s.frame_records(old)[1]) == [3, 4]
    empty = s.encode_frame(9, 10, recs[:0])
    empty_old = empty[:6] + struct.pack("<H", 32) + empty[8:32]
    assert s.frame_header(empty_old).AxisCount == 0
    # the plain tuple a client's hot path reads (plc_client): the same values, in FrameHeader's order
    for d in (new, old, empty, empty_old):
        assert s.frame_header_values(d) == tuple(s.frame_header(d))
    with pytest.raises(ValueError):
        s.frame_header_values(old[:-1])
    assert s.decode_stamp_epoch(struct.pack("<QQ", 3, 4)) == (3, 4, 0)
    # the protocol-4 reader: the 32 bytes before Epoch, the records at HeaderSize
    v4 = s.struct_of(s.FRAME_HEADER_DTYPE, stop="Epoch").unpack_from(new)
    assert v4[2] == 40 and new[v4[2]:v4[2] + s.NCTOPLC_SIZE] == recs[0].tobytes()
    for bad in (b"\0" * 15, b"\0" * 20):
        with pytest.raises(ValueError):
            s.decode_stamp(bad)


@pytest.mark.parametrize("jobs", [False, True])
def test_view_frame_is_the_frame_of_the_rows(jobs: bool) -> None:
    """Issue 19: a client's view is the NC's frame cut to its axes: same header but AxisCount, the rows'
    records (and job records) in the order given."""
    rng = np.random.default_rng(7)
    n = 9
    recs = np.frombuffer(rng.integers(0, 256, n * s.NCTOPLC_SIZE, dtype=np.uint8).tobytes(), dtype=s.NCTOPLC_DTYPE)
    recs = recs.copy()
    recs["AxisId"] = np.arange(10, 10 + n)
    jr = np.frombuffer(rng.integers(0, 256, n * s.NCJOBS_SIZE, dtype=np.uint8).tobytes(), dtype=s.NCJOBS_DTYPE)
    frame = s.encode_frame(123, 456789, recs, int(s.FrameFlags.ShuttingDown), jr if jobs else None)
    for rows in ([], [0], [2, 5, 8], list(range(n))):
        v = s.view_frame(frame, n, rows)
        h, got, gj = s.decode_frame(v)
        assert (int(h["Cycle"]), int(h["NcTimeNs"]), int(h["AxisCount"])) == (123, 456789, len(rows))
        assert int(h["Flags"]) & int(s.FrameFlags.ShuttingDown)
        assert got.tobytes() == recs[rows].tobytes()
        assert (gj is not None) == jobs
        if jobs:
            assert gj is not None and gj.tobytes() == jr[rows].tobytes()
    assert s.view_frame(frame, n, list(range(n))) == frame


def test_view_keys() -> None:
    k = s.Keys("nc1")
    assert k.view("plc1") == "nc/nc1/view/plc1"
    assert k.view_select("plc1", 5, [3, 1, 2, 3]) == "nc/nc1/select/plc1/5ms/1,2,3"
    assert k.view_select("plc1", 0, []) == "nc/nc1/select/plc1/0ms/none"
    assert s.parse_view_select(k.view_select("plc1", 5, [3, 1])) == ("nc1", "plc1", 5, (1, 3))
    assert s.parse_view_select("nc/nc1/select/plc1/0ms/none") == ("nc1", "plc1", 0, ())
    for bad in ("nc/nc1/select/plc1/3ms/1", "nc/nc1/select/plc1/05ms/1", "nc/nc1/select/plc1/5ms/01",
                "nc/nc1/select/plc1/5ms/2,1", "nc/nc1/select/plc1/5ms/1,1", "nc/nc1/select/plc1/5ms/",
                "nc/nc1/select/plc1/5ms/a", "nc/nc1/select/p l/5ms/1", "nc/nc1/select/plc1/5/1",
                "nc/nc1/select/plc1/5ms/1/2", "nc/nc1/view/plc1", "x/nc1/select/plc1/5ms/1",
                "nc/nc1/select/plc1/5ms/" + ",".join(map(str, range(s.MAX_VIEW_AXES + 1)))):
        assert s.parse_view_select(bad) is None, bad
    assert s.parse_view_select("nc/nc1/select/plc1/5ms/" + ",".join(map(str, range(s.MAX_VIEW_AXES)))) is not None
    for args in (("plc1", 3, [1]), ("plc1", 5, [-1]), ("p l", 5, [1]), ("plc1", 5, range(s.MAX_VIEW_AXES + 1))):
        with pytest.raises(ValueError):
            k.view_select(*args)  # type: ignore[arg-type]
