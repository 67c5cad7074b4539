"""The drive's own error code (CiA 402 0x603F) where a user reads it: nc-status shows the stats' ``drive_errors``
next to the axis error (nc_tools.status.nc_view / render, pure)."""
from __future__ import annotations

import msgpack
import numpy as np

from nc_schema import NCTOPLC_DTYPE, encode_frame
from nc_tools.status import _Raw, nc_view, render


def _view(stats: dict) -> dict:
    rec = np.zeros(2, dtype=NCTOPLC_DTYPE)
    rec["AxisId"] = [1, 2]
    rec["ErrorCode"] = [0x4650, 0]
    status = _Raw(encode_frame(10, 0, rec), 100.0)
    return nc_view("nc1", True, status, _Raw(msgpack.packb(stats), 100.0), None, 100.0)


def test_drive_errors_per_axis_and_in_the_table() -> None:
    v = _view({"cycle": 10, "drive_errors": {1: 0x2310}})
    a1, a2 = v["axes"]
    assert (a1["ErrorCode"], a1["DriveErrorCode"]) == (0x4650, 0x2310)
    assert a2["DriveErrorCode"] == 0 and not v["problems"]
    text = render({"time": "t", "ncs": [v]})
    assert "0x4650 NC_DRIVE_NOT_READY (drive 0x2310)" in text


def test_string_keys_and_older_ncs_without_the_field() -> None:
    assert _view({"drive_errors": {"2": 0x8130}})["axes"][1]["DriveErrorCode"] == 0x8130
    v = _view({"cycle": 10})
    assert [a["DriveErrorCode"] for a in v["axes"]] == [0, 0] and not v["problems"]


def test_a_malformed_field_is_a_problem_not_a_crash() -> None:
    v = _view({"drive_errors": [1, 2]})
    assert "stats: drive_errors is not a map" in v["problems"]
    assert [a["DriveErrorCode"] for a in v["axes"]] == [0, 0]
    v = _view({"drive_errors": {1: "x", 2: True}})
    assert [a["DriveErrorCode"] for a in v["axes"]] == [0, 0]
