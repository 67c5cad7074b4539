"""nc_schema.layout.flat_struct: a span of a record's members as one struct, nested structs flattened."""
from __future__ import annotations

import numpy as np
import pytest

from nc_schema import NCJOBS_DTYPE
from nc_schema.layout import flat_struct


def test_ncjobs_queue_and_slots_parts_cover_the_record_with_the_ended_array_flattened() -> None:
    n = NCJOBS_DTYPE["Ended"].shape[0]
    queue = flat_struct(NCJOBS_DTYPE, stop="MasterId")
    slots = flat_struct(NCJOBS_DTYPE, start="MasterId")
    assert queue.format == "<IHHHHHH" + "HHI" * n
    assert queue.size + slots.size == NCJOBS_DTYPE.itemsize
    rec = np.zeros(1, NCJOBS_DTYPE)
    rec["Ended"][0][1] = (7, 3, 0x4B0F)
    rec["MasterId"] = 5
    raw = rec.tobytes()
    q = queue.unpack_from(raw, 0)
    assert q[7 + 3:7 + 6] == (7, 3, 0x4B0F)
    assert slots.unpack_from(raw, queue.size)[0] == 5


def test_a_gap_or_an_unknown_member_is_refused() -> None:
    gappy = np.dtype({"names": ["a", "b"], "formats": ["<u4", "<f8"], "offsets": [0, 8], "itemsize": 16})
    with pytest.raises(ValueError, match="gap"):
        flat_struct(gappy)
    with pytest.raises(KeyError):
        flat_struct(NCJOBS_DTYPE, start="NoSuchMember")
