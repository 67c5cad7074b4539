"""The drive's own error code (0x603F) and CANopen's EMCY code where a user reads them: the drive's link figures (stats
``drive_link``, built by the server's ``NcServer._drive_link``) and nc-status's drive line, next to ``drive_errors``
and the axis error. A simulated drive fault with a given 0x603F shows that value in both."""
from __future__ import annotations

import types
import uuid
from typing import Any

import msgpack
import numpy as np

import nc_server.core  # noqa: F401  (first: nc_server.drives imports the core, which imports drives.base)
from nc_schema import NCTOPLC_DTYPE, encode_frame
from nc_server.core import AxisConfig, AxisParams, NcCore
from nc_server.drives.base import DriveContext
from nc_server.drives.canopen.drive import CanopenDrive
from nc_server.drives.cia402.sim import Cia402SimDrive
from nc_server.server.app import NcServer
from nc_tools.status import _Raw, nc_view, render
from znc_testing.nc_core import power
from znc_testing.until import step_until

DT = 0.001


def _stats(core: NcCore) -> dict[str, Any]:
    """The stats' drive fields as the server builds them (its methods on a stand-in holding just the core)."""
    fake = types.SimpleNamespace(core=core)
    return {"cycle": 10, "drive_errors": NcServer._drive_errors(fake),  # type: ignore[arg-type]
            "drive_link": NcServer._drive_link(fake)}  # type: ignore[arg-type]


def _text(core: NcCore, stats: dict[str, Any]) -> tuple[dict[str, Any], str]:
    st = msgpack.unpackb(msgpack.packb(stats), strict_map_key=False)  # (over the wire: msgpack)
    rec = np.array(core.nctoplc, dtype=NCTOPLC_DTYPE)
    v = nc_view("nc1", True, _Raw(encode_frame(10, 0, rec), 100.0), _Raw(msgpack.packb(st), 100.0), None, 100.0)
    return v, render({"time": "t", "ncs": [v]})


def test_a_cia402_sim_drive_fault_shows_its_0x603f_in_the_stats_and_nc_status() -> None:
    p = [AxisParams(), AxisParams()]
    core = NcCore([AxisConfig(7, "A7", p[0]), AxisConfig(8, "A8", p[1])], DT, drive=Cia402SimDrive(p, DT))
    power(core, 0)
    power(core, 1)
    core.step()
    stats = _stats(core)
    assert stats["drive_link"] == {} and stats["drive_errors"] == {}  # no error: no drive line for an in-process drive
    core.drive.inject_fault(0, 0x2311)  # type: ignore[attr-defined]
    step_until(core.step, lambda: int(core.nctoplc[0]["ErrorCode"]) == 0x4650, 50)
    stats = _stats(core)
    assert stats["drive_errors"] == {7: 0x2311}
    assert stats["drive_link"] == {7: {"link": "local", "error_code": 0x2311}}
    v, text = _text(core, stats)
    a7, a8 = v["axes"]
    assert a7["DriveErrorCode"] == 0x2311 and a7["DriveLink"]["error_code"] == 0x2311 and a8["DriveLink"] is None
    assert "0x4650 NC_DRIVE_NOT_READY (drive 0x2311)" in text
    assert "drive link: in-process drive, drive error 0x2311" in text


def test_a_canopen_drive_fault_shows_its_0x603f_and_emcy_on_the_drive_line() -> None:
    p = [AxisParams(AxisEncoderScalingFactor=0.0001) for _ in range(2)]
    opts = {"simulate_slaves": True, "channel": f"test-{uuid.uuid4().hex[:10]}", "heartbeat_timeout": 1.0}
    drive = CanopenDrive.from_config(p, DT, [{"node_id": 2}, {"node_id": 3}], DriveContext(options=opts))
    assert isinstance(drive, CanopenDrive) and drive.slaves is not None
    core = NcCore([AxisConfig(i + 1, f"A{i + 1}", q) for i, q in enumerate(p)], DT, drive=drive)

    def step() -> None:
        core.step()
        assert drive.link.wait_answered(5.0), "the slaves did not answer a SYNC"

    try:
        power(core, 0)
        power(core, 1)
        step_until(step, lambda: bool(drive.following.all()), 100)
        f = _stats(core)["drive_link"]
        assert f[1]["error_code"] == 0 and f[1]["emcy"] == 0
        assert "drive error" not in _text(core, _stats(core))[1]
        drive.slaves.inject_fault(1, 0x7305)
        step_until(step, lambda: int(core.nctoplc[1]["ErrorCode"]) == 0x4650 and int(drive.link.emcy_code[1]), 5000)
        stats = _stats(core)
        assert stats["drive_errors"] == {2: 0x7305}
        f1, f2 = stats["drive_link"][1], stats["drive_link"][2]
        assert (f2["link"], f2["node_id"], f2["error_code"], f2["emcy"]) == ("canopen", 3, 0x7305, 0x7305)
        assert (f1["error_code"], f1["emcy"]) == (0, 0)
        _, text = _text(core, stats)
        assert "bus tx errors 0, drive error 0x7305, EMCY 0x7305" in text
        assert "(drive 0x7305)" in text
    finally:
        drive.close()
