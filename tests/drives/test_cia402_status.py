"""The drive's own error code (CiA 402 0x603F) where a user reads it: nc-status shows the stats' ``drive_errors``
next to the axis error (nc_tools.status.nc_view / render, pure)."""
from __future__ import annotations

import msgpack
import numpy as np

from nc_schema import NCTOPLC_DTYPE, encode_frame
from nc_tools.status import _Raw, link_text, nc_view, render


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


CANOPEN = {"link": "canopen", "node_id": 3, "monitoring": "heartbeat", "nmt": "OPERATIONAL", "alive": True,
           "heartbeat_age_ms": 42.0, "tpdo_late": 7, "tpdo_missed": 2, "setups": 1, "tx_errors": 0}
REMOTE = {"link": "remote", "host": "drives1", "alive": False, "age": 12, "round_trip": 3}


def test_the_drive_link_per_axis_and_in_the_table() -> None:
    v = _view({"cycle": 10, "drive_link": {1: CANOPEN, "2": REMOTE}})
    a1, a2 = v["axes"]
    assert a1["DriveLink"] == CANOPEN and a2["DriveLink"] == REMOTE and not v["problems"]
    text = render({"time": "t", "ncs": [v]})
    assert ("drive link: canopen node 3 OPERATIONAL (heartbeat 42 ms ago), TPDOs late 7 missed 2, set-ups 1, "
            "bus tx errors 0") in text
    assert "drive link: remote host drives1 LOST, round trip 3 cycles, input age 12 cycles" in text
    assert "LOST" in link_text(dict(CANOPEN, alive=False, nmt=None, heartbeat_age_ms=None))


def test_no_drive_link_or_a_malformed_one() -> None:
    v = _view({"cycle": 10})
    assert [a["DriveLink"] for a in v["axes"]] == [None, None] and "drive link" not in render({"time": "t", "ncs": [v]})
    v = _view({"drive_link": [1]})
    assert "stats: drive_link is not a map" in v["problems"] and v["axes"][0]["DriveLink"] is None
    assert _view({"drive_link": {1: "x"}})["axes"][0]["DriveLink"] is None
