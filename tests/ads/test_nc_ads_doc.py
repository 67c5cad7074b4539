"""docs/ads.md's tables are generated from the code and schema/params.json, the README's pyads example runs
exactly as printed against a real nc-server + nc-ads, and the pure payload decoders of nc_device."""
from __future__ import annotations

import errno
import re
import socket
import struct
import subprocess
import sys
import time
from pathlib import Path

import pytest

from nc_ads import doc
from nc_ads.errors import AdsError
from nc_ads.nc_device import FUNCTIONS, _ONLINE, _fn_start, _fn_start_ext, online_struct, parse_frame
from nc_schema import NCTOPLC_DTYPE, PARAMETERS, encode_frame

ROOT = Path(__file__).resolve().parents[2]


def test_docs_tables_are_up_to_date() -> None:
    text = (ROOT / "docs" / "ads.md").read_text()
    assert doc.splice(text) == text, "docs/ads.md is stale: python -m nc_ads.doc --write"


def test_docs_cover_every_function_and_parameter_address() -> None:
    assert set(doc.FUNCTION_DOC) == set(FUNCTIONS)
    block = doc.render()
    for e in PARAMETERS:
        if e.ads is not None:
            assert f"| 0x{e.ads.axis_offset:X} | {e.ads.type} |" in block, e.name
    sizes = {"REAL64": 8, "INT32": 4, "UINT32": 4}
    assert sum(sizes[t] for _, t, _ in doc._ONLINE_FIELDS) == _ONLINE.size  # the doc's layout is the packed one


def test_online_struct_from_a_frame() -> None:
    rec = bytearray(256)
    struct.pack_into("<I", rec, 0, 0x100001)    # StateDWord
    struct.pack_into("<I", rec, 4, 0x4223)      # ErrorCode
    struct.pack_into("<I", rec, 32, 7)          # AxisId
    struct.pack_into("<d", rec, 40, 12.5)       # ActPos
    struct.pack_into("<d", rec, 80, 13.5)       # SetPos
    struct.pack_into("<d", rec, 232, -2.0)      # ActAcc
    recs = __import__("numpy").frombuffer(bytes(rec), dtype=NCTOPLC_DTYPE)
    img = parse_frame(encode_frame(42, 0, recs), 0.0)
    assert img.cycle == 42 and set(img.records) == {7}
    s = online_struct(img.records[7], override=500_000)
    assert len(s) == 256 and s[176:] == bytes(80)
    v = _ONLINE.unpack_from(s)
    assert v[0] == 0x4223 and v[2] == 12.5 and v[4] == 13.5 and v[8] == 500_000 and v[15] == 0x100001
    assert v[19] == -2.0
    with pytest.raises(ValueError):
        parse_frame(b"\0" * 40, 0.0)


def test_start_payload_variants() -> None:
    a = _fn_start(struct.pack("<I4xdd", 1, 5.0, 10.0))
    b = _fn_start(struct.pack("<Idd", 1, 5.0, 10.0))
    assert (a.cmd, a.args) == (b.cmd, b.args) == ("MoveAbsolute", {"Position": 5.0, "Velocity": 10.0,
                                                                     "Acceleration": 0.0, "Deceleration": 0.0,
                                                                     "Jerk": 0.0})
    v = _fn_start(struct.pack("<I4xdd", 4, 0.0, 3.0))
    assert v.cmd == "MoveVelocity" and v.args["Direction"] == 3
    e = _fn_start_ext(struct.pack("<I4xddI4xdI4xdI4xd", 0x105, 90.0, 10.0, 0, 50.0, 1, 7.0, 0, 900.0))
    assert e.cmd == "MoveModulo" and e.args == {"Position": 90.0, "Velocity": 10.0, "Acceleration": 50.0,
                                                 "Deceleration": 0.0, "Jerk": 900.0, "Direction": 2}
    e2 = _fn_start_ext(struct.pack("<IddIdIdId", 0x105, 90.0, 10.0, 0, 50.0, 1, 7.0, 0, 900.0))
    assert e2.args == e.args
    for bad, code in ((struct.pack("<I4xd", 1, 5.0), 0x705), (struct.pack("<I4xdd", 5, 1.0, 1.0), 0x4239),
                      (struct.pack("<I4xdd", 1, float("nan"), 1.0), 0x706)):
        with pytest.raises(AdsError) as ei:
            _fn_start(bad)
        assert ei.value.code == code


# ---- the README example, exactly as printed --------------------------------------------------------------------
def readme_example() -> str:
    text = (ROOT / "README.md").read_text()
    sec = text.split("## Using it from ADS tools", 1)[1]
    m = re.search(r"```python\n(.*?)```", sec, re.S)
    assert m, "README: no python block in 'Using it from ADS tools'"
    return m.group(1)


def test_readme_example_is_five_lines() -> None:
    assert len(readme_example().strip().splitlines()) == 5


def _loopback_48898_free() -> bool:
    s = socket.socket()
    try:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        s.bind(("127.0.0.1", 48898))
        return True
    except OSError as exc:
        if exc.errno != errno.EADDRINUSE:
            raise
        return False
    finally:
        s.close()


def test_readme_example_runs(tmp_path: Path) -> None:
    """The snippet addresses 127.0.0.1:48898 (what a reader has); nc-ads listens there for this test."""
    pytest.importorskip("pyads")
    from znc_testing.nc_ads_testing import NcAdsProcess
    from znc_testing import start_nc_server
    deadline = time.monotonic() + 60
    while not _loopback_48898_free():  # another test of this kind may be using it: wait, never steal it
        assert time.monotonic() < deadline, "127.0.0.1:48898 stayed busy for 60 s"
        time.sleep(0.5)
    nc = start_nc_server(tmp_path / "nc")
    err = tmp_path / "nc-ads.stderr"
    with open(err, "w") as f:
        proc = subprocess.Popen([sys.executable, "-m", "nc_ads.cli", "--nc", f"nc1={nc.endpoint}",
                                 "--netid", "127.0.0.1.1.1"], stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                                stderr=f, text=True, start_new_session=True)
    ads = NcAdsProcess(proc, "127.0.0.1", "127.0.0.1.1.1", err)
    try:
        ads.wait_ready()
        out = ""
        for _ in range(40):  # the first frames may not have arrived yet (0x707): the reader would retry too
            r = subprocess.run([sys.executable, "-c", readme_example()], capture_output=True, text=True, timeout=60)
            out = r.stdout + r.stderr
            if r.returncode == 0:
                break
            time.sleep(0.25)
        assert r.returncode == 0, out
        act_pos, vmax = (float(x) for x in r.stdout.split())
        assert act_pos == 0.0 and vmax == 500.0, out
    finally:
        ads.kill()
        nc.kill()
