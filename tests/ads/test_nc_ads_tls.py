"""nc-ads over mutual TLS with the NC's roles file: its identity has exactly the rights the roles file
gives it, whatever ``--role`` says (real nc-server with --tls-dir/--roles, nc-ads with --tls-dir, pyads)."""
from __future__ import annotations

import shutil
import struct
import subprocess
from pathlib import Path
from typing import Any

import pytest

pyads = pytest.importorskip("pyads")

from znc_testing.nc_ads_testing import start_nc_ads  # noqa: E402
from znc_testing import BIT_CONTROL_LOOP_CLOSED, NcServerProcess, free_port, nc_server_command, wait_until  # noqa: E402

REPO = Path(__file__).resolve().parents[2]
ROLES = """
[nc.nc1]
[client.ads-op]
role = "operator"
[client.ads-obs]
role = "observer"
"""


def _connect(h: Any) -> Any:
    plc = pyads.Connection(h.netid, 500, h.host)
    plc.open()
    wait_until(lambda: plc.read_state()[0] == pyads.ADSSTATE_RUN, 60, "nc-ads RUN over TLS", interval=0.1)
    return plc


def test_tls_identity_and_roles_file(tmp_path: Path) -> None:
    if shutil.which("openssl") is None:
        pytest.skip("openssl is not installed")
    certs = tmp_path / "certs"
    subprocess.run(["sh", str(REPO / "deploy" / "certs" / "make-certs.sh"), str(certs), "--server", "nc1", "ads-op", "ads-obs"],
                   check=True, capture_output=True, timeout=120)
    roles = tmp_path / "roles.toml"
    roles.write_text(ROLES)
    port = free_port()
    err = tmp_path / "nc.stderr"
    with open(err, "w") as f:
        proc = subprocess.Popen([*nc_server_command(), "--listen", f"tls/127.0.0.1:{port}", "--tls-dir", str(certs),
                                 "--roles", str(roles)], stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=f,
                                text=True, start_new_session=True)
    nc = NcServerProcess(proc, port, "nc1", err)
    started = []
    try:
        nc.wait_ready()
        ep = f"tls/127.0.0.1:{port}"
        op = start_nc_ads(tmp_path / "op", ep, role="operator", client_id="ads-op", extra_args=["--tls-dir", str(certs)])
        started.append(op)
        # an observer certificate behind a misconfigured --role operator: the NC and the router still say no
        obs = start_nc_ads(tmp_path / "obs", ep, role="operator", client_id="ads-obs",
                           extra_args=["--tls-dir", str(certs)])
        started.append(obs)
        plc = _connect(op)
        plc2 = _connect(obs)
        try:
            assert plc.read(0x4001, 0x27, pyads.PLCTYPE_LREAL) == plc2.read(0x4001, 0x27, pyads.PLCTYPE_LREAL) > 0
            with pytest.raises(pyads.ADSError) as ei:
                plc2.write(0x4302, 0x01, 7, pyads.PLCTYPE_UDINT)  # Claim on an op key: denied (no reply / 0x723)
            assert ei.value.err_code in (0x707, 0x719, 0x723)
            plc.write(0x4301, 0x01, 7, pyads.PLCTYPE_UDINT)  # the operator certificate may claim and supply
            wait_until(lambda: struct.unpack_from("<I", bytes(plc.read(0x4101, 0, pyads.PLCTYPE_BYTE * 256)), 104)[0]
                       & BIT_CONTROL_LOOP_CLOSED, 30, "axis 1 enabled over TLS")
            start = struct.pack("<I4xdd", 1, 5.0, 50.0)
            plc.write(0x4201, 0x20, start, pyads.PLCTYPE_BYTE * 24)
            wait_until(lambda: plc.read(0x4101, 0x10002, pyads.PLCTYPE_LREAL) == pytest.approx(5.0, abs=1e-6), 30,
                       "axis 1 at 5.0")
            with pytest.raises(pyads.ADSError):
                plc2.write(0x4202, 0x20, start, pyads.PLCTYPE_BYTE * 24)  # motion from the observer: refused
            assert plc2.read(0x4102, 0x10002, pyads.PLCTYPE_LREAL) == 0.0
            assert not struct.unpack_from("<I", bytes(plc.read(0x4102, 0, pyads.PLCTYPE_BYTE * 256)), 104)[0] \
                & BIT_CONTROL_LOOP_CLOSED
        finally:
            plc.close()
            plc2.close()
    finally:
        for h in started:
            h.kill()
        nc.kill()
