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
    head = s.FRAME_HEADER_STRUCT.pack(s.FRAME_MAGIC, s.WIRE_VERSION, 8, 1, 2, 1, s.NCTOPLC_SIZE, 0)
    data = head + bytes(8 + s.NCTOPLC_SIZE - len(head))
    with pytest.raises(ValueError, match="sizes do not add up"):
        s.frame_header(data)
    ok = s.FRAME_HEADER_STRUCT.pack(s.FRAME_MAGIC, s.WIRE_VERSION, 32, 1, 2, 1, s.NCTOPLC_SIZE, 0)
    assert s.frame_header(ok + bytes(s.NCTOPLC_SIZE)).AxisCount == 1
