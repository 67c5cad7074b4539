"""nc-ads with unmodified pyads against a real nc-server: state structs, parameters at the byte level,
motion through the 0x4200 functions watched by a notification, TwinCAT error codes, roles, the NC going
away and coming back, and a disappearing ADS client's claim.

Processes: one nc-server and one nc-ads (engineer) per module for the tests that do not interfere; the
observer, NC-loss and client-loss tests start their own. Notifications are always deleted before a
Connection is closed (pyads segfaults otherwise, ads-bridge-notes pitfall 8).
"""
from __future__ import annotations

import ctypes
import signal
import struct
import subprocess
import sys
import textwrap
import time
from pathlib import Path
from typing import Any, Iterator

import pytest

pyads = pytest.importorskip("pyads")

from znc_testing.nc_ads_testing import NcAdsProcess, start_nc_ads  # noqa: E402
from nc_schema import PARAMETERS, encode_ads, decode_ads  # noqa: E402
from znc_testing import (  # noqa: E402
    BIT_CONTROL_LOOP_CLOSED, NcServerProcess, NcTestClient, nc_server_command, start_nc_server, wait_until,
)

AXES = [1, 2, 3, 4]
ACCESS_DENIED = 0x723


class NcAxisOnline(ctypes.Structure):
    """NCAXISSTATE_ONLINESTRUCT (TC3, 256 bytes), as a client defines it."""
    _pack_ = 1
    _fields_ = [("ErrState", ctypes.c_int32), ("_r1", ctypes.c_uint32), ("ActPos", ctypes.c_double),
                ("ModuloActPos", ctypes.c_double), ("SetPos", ctypes.c_double), ("ModuloSetPos", ctypes.c_double),
                ("ActVelo", ctypes.c_double), ("SetVelo", ctypes.c_double), ("Override", ctypes.c_int32),
                ("_r2", ctypes.c_uint32), ("Lag", ctypes.c_double), ("PeakNeg", ctypes.c_double),
                ("PeakPos", ctypes.c_double), ("CtrlOut", ctypes.c_double), ("TotalOut", ctypes.c_double),
                ("StateDWord", ctypes.c_uint32), ("ControlDWord", ctypes.c_uint32), ("CoupleState", ctypes.c_uint32),
                ("ControlLoopIndex", ctypes.c_uint32), ("ActAcc", ctypes.c_double), ("SetAcc", ctypes.c_double),
                ("SetJerk", ctypes.c_double), ("SetTorque", ctypes.c_double), ("ActTorque", ctypes.c_double),
                ("SetTorqueChange", ctypes.c_double), ("TorqueOffset", ctypes.c_double),
                ("_fill", ctypes.c_uint8 * 80)]


assert ctypes.sizeof(NcAxisOnline) == 256


def ads_error(fn: Any, *args: Any) -> int:
    """The err_code of the ADSError ``fn(*args)`` raises (fails if it does not)."""
    with pytest.raises(pyads.ADSError) as ei:
        fn(*args)
    return ei.value.err_code


def state(plc: Any, axis: int) -> NcAxisOnline:
    return plc.read(0x4100 + axis, 0, NcAxisOnline)


def connect(ads: NcAdsProcess, port: int = 500) -> Any:
    plc = pyads.Connection(ads.netid, port, ads.host)
    plc.open()
    wait_until(lambda: plc.read_state()[0] == pyads.ADSSTATE_RUN, 30, "nc-ads in RUN (NC frames arriving)",
               interval=0.05)
    return plc


# ---- module fixtures: one nc-ads (engineer); the NC (nc), an operator nc-ads (ads_op) and the observer (watcher)
# ---- come from conftest.py
@pytest.fixture(scope="module")
def ads(nc: NcServerProcess, tmp_path_factory: pytest.TempPathFactory) -> Iterator[NcAdsProcess]:
    h = start_nc_ads(tmp_path_factory.mktemp("ads"), nc.endpoint, role="engineer")
    try:
        yield h
    finally:
        h.kill()


@pytest.fixture
def plc(ads: NcAdsProcess) -> Iterator[Any]:
    c = connect(ads)
    try:
        yield c
    finally:
        c.close()


# ---- the state struct of every axis --------------------------------------------------------------------------
def test_every_axis_state_struct(plc: Any, ads: NcAdsProcess, watcher: NcTestClient) -> None:
    count = plc.read(0x1100, 0x03, pyads.PLCTYPE_UDINT)
    ids = list(plc.read(0x1100, 0x33, pyads.PLCTYPE_UDINT * count))
    assert ids == AXES
    plc501 = pyads.Connection(ads.netid, 501, ads.host)
    plc501.open()
    try:
        for a in ids:
            n = wait_until(lambda: watcher.nctoplc(a), 10, f"NCTOPLC of axis {a}")
            for conn in (plc, plc501):
                s = state(conn, a)
                assert s.ActPos == pytest.approx(float(n["ActPos"]), abs=1e-9)
                assert s.SetPos == pytest.approx(float(n["SetPos"]), abs=1e-9)
                assert s.ErrState == int(n["ErrorCode"])
                assert s.StateDWord & 0x7 == int(n["StateDWord"]) & 0x7  # Operational/Homed/NotMoving at rest
                assert bytes(s._fill) == bytes(80)
            assert plc.read(0x4100 + a, 0x10002, pyads.PLCTYPE_LREAL) == pytest.approx(s.ActPos, abs=1e-9)
            assert plc.read(0x4000 + a, 0x01, pyads.PLCTYPE_UDINT) == a
            nctoplc = bytes(plc.read(0x4300 + a, 0x80, pyads.PLCTYPE_BYTE * 256))
            assert struct.unpack_from("<I", nctoplc, 32)[0] == a  # NCTOPLC.AxisId
    finally:
        plc501.close()


# ---- parameters: the byte-level round trip against the parameter table ----------------------------------------
def _primary_entries() -> list[Any]:
    """One entry per ADS address (the one nc-ads serves there)."""
    return [e for e in PARAMETERS if e.ads is not None and PARAMETERS.ads(e.ads.group, e.ads.offset) is e]


def _new_value(e: Any, old: float | bool) -> float | bool:
    if e.is_bool:
        return not old
    if e.name == "AxisEncoderEncoderMask":  # (2^k - 1 only: one bit less)
        return (old - 1.0) / 2.0
    for v in (old + 1.0, old - 1.0, old * 0.5, old + 0.01):  # (+0.01: the dead time, at most 0.1 s)
        if e.in_range(v) and v != old:
            return v
    raise AssertionError(f"no test value for {e.name}")


def test_parameters_read_bytes_match_the_table(plc: Any, watcher: NcTestClient) -> None:
    for e in _primary_entries():
        raw = bytes(plc.read(0x4001, e.ads.axis_offset, pyads.PLCTYPE_BYTE * e.ads.size))
        ref = watcher.request("ReadParameter", axis=1, ParameterNumber=e.number)
        assert ref["error"] == 0, (e.name, ref)
        assert raw == encode_ads(e, ref["Value"]), e.name


def test_parameters_write_round_trip(plc: Any, watcher: NcTestClient) -> None:
    axis = 4  # nobody enables axis 4 in this module ("disabled" parameters are writable)
    for e in _primary_entries():
        if not e.writable:
            continue
        off, size = e.ads.axis_offset, e.ads.size
        old_raw = bytes(plc.read(0x4000 + axis, off, pyads.PLCTYPE_BYTE * size))
        new = _new_value(e, decode_ads(e, old_raw))
        new_raw = encode_ads(e, new)
        plc.write(0x4000 + axis, off, new_raw, pyads.PLCTYPE_BYTE * size)
        try:
            assert bytes(plc.read(0x4000 + axis, off, pyads.PLCTYPE_BYTE * size)) == new_raw, e.name
            ref = watcher.request("ReadParameter", axis=axis, ParameterNumber=e.number)
            assert ref["Value"] == new, e.name  # the NC's own value, not a cache in nc-ads
        finally:
            plc.write(0x4000 + axis, off, old_raw, pyads.PLCTYPE_BYTE * size)
        assert bytes(plc.read(0x4000 + axis, off, pyads.PLCTYPE_BYTE * size)) == old_raw, e.name


def test_parameter_errors_change_nothing(plc: Any) -> None:
    vmax = plc.read(0x4001, 0x27, pyads.PLCTYPE_LREAL)
    assert ads_error(plc.read, 0x4001, 0x999, pyads.PLCTYPE_LREAL) == 0x703  # unknown parameter
    assert ads_error(plc.write, 0x4001, 0x999, 1.0, pyads.PLCTYPE_LREAL) == 0x703
    assert ads_error(plc.write, 0x4001, 0x01, 7, pyads.PLCTYPE_UDINT) == 0x704  # AxisId is read-only
    assert ads_error(plc.read, 0x4001, 0x27, pyads.PLCTYPE_REAL) == 0x705  # 4 bytes for an LREAL
    assert ads_error(plc.write, 0x4001, 0x27, 1.0, pyads.PLCTYPE_REAL) == 0x705
    assert ads_error(plc.write, 0x4001, 0x27, -5.0, pyads.PLCTYPE_LREAL) == 0x70B  # the NC's range check
    assert ads_error(plc.read, 0x4009, 0x27, pyads.PLCTYPE_LREAL) == 0x702  # no axis 9
    assert ads_error(plc.read, 0x4801, 0x27, pyads.PLCTYPE_LREAL) == 0x702
    assert plc.read(0x4001, 0x27, pyads.PLCTYPE_LREAL) == vmax


# ---- motion through 0x4200, watched through a notification on 0x4100 ----------------------------------------
@pytest.fixture
def plc_op(ads_op: NcAdsProcess) -> Iterator[Any]:
    c = connect(ads_op)
    try:
        yield c
    finally:
        c.close()


def test_move_with_functions_watch_notification(plc_op: Any, watcher: NcTestClient) -> None:
    """As an operator: enable through 0x4300, move with 0x4200, watch it through a notification on 0x4100."""
    plc, axis = plc_op, 2
    seen: list[float] = []
    vmax = plc.read(0x4000 + axis, 0x27, pyads.PLCTYPE_LREAL)
    assert ads_error(plc.write, 0x4000 + axis, 0x27, vmax, pyads.PLCTYPE_LREAL) == ACCESS_DENIED  # needs engineer

    @plc.notification(pyads.PLCTYPE_LREAL)
    def on_pos(handle: int, name: str, timestamp: Any, value: float) -> None:
        seen.append(value)

    attr = pyads.NotificationAttrib(8, pyads.ADSTRANS_SERVERONCHA, 0, 10)
    handles = plc.add_device_notification((0x4100 + axis, 0x10002), attr, on_pos)
    try:
        plc.write(0x4200 + axis, 0x01, None, None)  # reset (nothing to clear: accepted)
        plc.write(0x4300 + axis, 0x01, 0x7, pyads.PLCTYPE_UDINT)  # Enable + feed enables: claims the axis
        wait_until(lambda: state(plc, axis).StateDWord & BIT_CONTROL_LOOP_CLOSED, 20, "axis 2 enabled")
        assert watcher.request("Info")["Value"]["claims"].get(axis) == "ads-op"
        start = struct.pack("<I4xdd", 1, 37.5, 150.0)  # absolute start to 37.5 at 150 u/s
        plc.write(0x4200 + axis, 0x20, start, pyads.PLCTYPE_BYTE * len(start))
        wait_until(lambda: seen and seen[-1] == pytest.approx(37.5, abs=1e-6), 30, "the notification shows 37.5")
        assert any(0.0 < v < 37.5 for v in seen), seen[:20]  # it watched the motion, not only the end
        s = state(plc, axis)
        assert s.ErrState == 0 and s.SetPos == pytest.approx(37.5, abs=1e-6)
        # extended start (16-byte variant blocks), relative, default dynamics
        ext = struct.pack("<I4xddI4xdI4xdI4xd", 2, -7.5, 100.0, 1, 0.0, 1, 0.0, 1, 0.0)
        cmd = bytes(plc.read_write(0x4200 + axis, 0x21, pyads.PLCTYPE_BYTE * 4, ext, pyads.PLCTYPE_BYTE * len(ext)))
        assert struct.unpack("<HH", cmd)[0] > 0  # its CmdNo
        wait_until(lambda: seen and seen[-1] == pytest.approx(30.0, abs=1e-6), 30, "the notification shows 30")
        plc.write(0x4200 + axis, 0x50, None, None)  # disable: enables off, claim released
        wait_until(lambda: watcher.request("Info")["Value"]["claims"].get(axis) is None, 20, "axis 2 released")
        assert not state(plc, axis).StateDWord & BIT_CONTROL_LOOP_CLOSED
        assert state(plc, axis).ErrState == 0  # an orderly disable is no client loss
    finally:
        plc.del_device_notification(*handles)


def test_function_errors(plc: Any) -> None:
    axis = 3  # disabled
    start = struct.pack("<I4xdd", 1, 10.0, 100.0)
    assert ads_error(plc.write, 0x4200 + axis, 0x20, start, pyads.PLCTYPE_BYTE * 24) == 0x4223  # NC: no enable
    odd = struct.pack("<I4xdd", 99, 10.0, 100.0)
    assert ads_error(plc.write, 0x4200 + axis, 0x20, odd, pyads.PLCTYPE_BYTE * 24) == 0x4239  # start type
    assert ads_error(plc.write, 0x4200 + axis, 0x20, start[:10], pyads.PLCTYPE_BYTE * 10) == 0x705
    assert ads_error(plc.write, 0x4200 + axis, 0x77, None, None) == 0x703
    assert ads_error(plc.read, 0x4200 + axis, 0x20, pyads.PLCTYPE_UDINT) == 0x704
    assert ads_error(plc.write, 0x4100 + axis, 0, bytes(256), pyads.PLCTYPE_BYTE * 256) == 0x704  # state: read-only
    assert ads_error(plc.write, 0x4300 + axis, 0x21, 2_000_000, pyads.PLCTYPE_UDINT) == 0x706  # override > 100 %
    assert state(plc, axis).SetPos == 0.0 and state(plc, axis).ErrState == 0


# ---- roles: an observer nc-ads refuses every write before sending anything ------------------------------------
def test_observer_role_refuses_writes(nc: NcServerProcess, watcher: NcTestClient, tmp_path: Path) -> None:
    obs = start_nc_ads(tmp_path, nc.endpoint, role="observer", client_id="ads-obs")
    try:
        plc = connect(obs)
        try:
            before = watcher.request("Info")["Value"]
            vmax = plc.read(0x4001, 0x27, pyads.PLCTYPE_LREAL)  # reads work
            assert ads_error(plc.write, 0x4001, 0x27, vmax + 1, pyads.PLCTYPE_LREAL) == ACCESS_DENIED
            assert ads_error(plc.write, 0x4303, 0x01, 7, pyads.PLCTYPE_UDINT) == ACCESS_DENIED
            assert ads_error(plc.write, 0x4203, 0x01, None, None) == ACCESS_DENIED
            start = struct.pack("<I4xdd", 1, 10.0, 100.0)
            assert ads_error(plc.write, 0x4203, 0x20, start, pyads.PLCTYPE_BYTE * 24) == ACCESS_DENIED
            after = watcher.request("Info")["Value"]
            assert plc.read(0x4001, 0x27, pyads.PLCTYPE_LREAL) == vmax
            assert 3 not in after["claims"]
            # nothing was sent: the NC saw ads-obs use class read only (a write would make it an operator or
            # engineer in the NC's "seen" roles), without a liveliness token
            seen = after["arbitration"]["clients"]["ads-obs"]
            assert seen["role"] == "observer" and not seen["alive"], seen
            assert after["arbitration"].get("last_command", {}) == before["arbitration"].get("last_command", {})
        finally:
            plc.close()
    finally:
        obs.kill()


# ---- the NC killed: a clear ADS error quickly, recovery when it is back ---------------------------------------
def _restart_nc(port: int, tmp_path: Path) -> NcServerProcess:
    err = tmp_path / f"nc-restart-{port}.stderr"
    args = [*nc_server_command(), "--listen", f"tcp/127.0.0.1:{port}"]
    with open(err, "w") as f:
        proc = subprocess.Popen(args, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=f, text=True,
                                start_new_session=True)
    h = NcServerProcess(proc, port, "nc1", err)
    h.wait_ready()
    return h


def test_nc_killed_fails_fast_and_recovers(tmp_path: Path) -> None:
    nc1 = start_nc_server(tmp_path / "nc")
    nc2: NcServerProcess | None = None
    ads1 = start_nc_ads(tmp_path / "ads", nc1.endpoint, role="operator")
    try:
        plc = connect(ads1)
        try:
            assert plc.read(0x4001, 0x27, pyads.PLCTYPE_LREAL) > 0
            nc1.kill()
            killed = time.monotonic()
            for req in (lambda: plc.read(0x4001, 0x27, pyads.PLCTYPE_LREAL),
                        lambda: plc.read(0x4101, 0, NcAxisOnline),  # from the frames: fails once they are stale
                        lambda: plc.write(0x4301, 0x01, 7, pyads.PLCTYPE_UDINT)):
                while True:
                    t0 = time.monotonic()
                    try:
                        req()
                    except pyads.ADSError as exc:
                        code = exc.err_code
                        break
                    finally:
                        took = time.monotonic() - t0
                        # one request never takes as long as pyads's own 5 s timeout (a hang)
                        assert took < 4.0, f"a request took {took:.1f} s"
                    assert time.monotonic() - killed < 4.0, "requests still succeed after the NC was killed"
                    time.sleep(0.05)
                assert code in (0x707, 0x719), hex(code)
            assert time.monotonic() - killed < 4.0
            wait_until(lambda: plc.read_state()[0] != pyads.ADSSTATE_RUN, 10, "ReadState not RUN")
            nc2 = _restart_nc(nc1.port, tmp_path)
            wait_until(lambda: plc.read_state()[0] == pyads.ADSSTATE_RUN, 30, "RUN again", interval=0.1)
            wait_until(lambda: plc.read(0x4001, 0x27, pyads.PLCTYPE_LREAL) > 0, 30, "parameter reads again")
            plc.write(0x4301, 0x01, 7, pyads.PLCTYPE_UDINT)  # claims on the new NC instance
            wait_until(lambda: state(plc, 1).StateDWord & BIT_CONTROL_LOOP_CLOSED, 20, "axis 1 enabled")
        finally:
            plc.close()
    finally:
        ads1.kill()
        nc1.kill()
        if nc2 is not None:
            nc2.kill()


# ---- an ADS client that disappears: its claim ends, the axis stops by the fail-safe rules ---------------------
CLIENT = textwrap.dedent("""
    import struct, sys, time
    import pyads
    netid, host = sys.argv[1], sys.argv[2]
    plc = pyads.Connection(netid, 500, host)
    plc.open()
    for _ in range(600):  # nc-ads answers 0x707 until the NC's first frame
        if plc.read_state()[0] == pyads.ADSSTATE_RUN:
            break
        time.sleep(0.05)
    plc.write(0x4301, 0x01, 7, pyads.PLCTYPE_UDINT)
    for _ in range(400):
        if struct.unpack_from("<I", bytes(plc.read(0x4101, 0, pyads.PLCTYPE_BYTE * 256)), 104)[0] & (1 << 20):
            break
        time.sleep(0.05)
    plc.write(0x4201, 0x20, struct.pack("<I4xdd", 3, 0.0, 20.0), pyads.PLCTYPE_BYTE * 24)  # endless plus
    print("moving", flush=True)
    time.sleep(120)
""")


def test_client_gone_releases_claim_and_stops(tmp_path: Path) -> None:
    nc1 = start_nc_server(tmp_path / "nc")
    ads1 = start_nc_ads(tmp_path / "ads", nc1.endpoint, role="operator")
    watch = NcTestClient(nc1.port, "watch2", token=False)
    err = open(tmp_path / "client.stderr", "w+")
    client = subprocess.Popen([sys.executable, "-c", CLIENT, ads1.netid, ads1.host], stdout=subprocess.PIPE,
                              stderr=err, text=True, start_new_session=True)
    try:
        assert client.stdout is not None
        line = client.stdout.readline().strip()
        assert line == "moving", f"client: {line!r}\n{(tmp_path / 'client.stderr').read_text()}\n{ads1.stderr()}"
        wait_until(lambda: float(watch.nctoplc(1)["ActVelo"]) > 1.0, 20, "axis 1 moving")
        assert watch.request("Info")["Value"]["claims"].get(1) == "ads1"
        client.kill()  # the TCP connection ends without a goodbye
        client.wait(10)
        wait_until(lambda: int(watch.nctoplc(1)["ErrorCode"]) == 0x8F01, 20, "axis 1 error 0x8F01 (client lost)")
        wait_until(lambda: watch.request("Info")["Value"]["claims"].get(1) is None, 20, "the claim released")
        wait_until(lambda: float(watch.nctoplc(1)["ActVelo"]) == 0.0, 20, "axis 1 stopped")
        wait_until(lambda: not int(watch.nctoplc(1)["StateDWord"]) & BIT_CONTROL_LOOP_CLOSED, 20, "axis 1 disabled")
    finally:
        client.kill()
        client.wait(10)
        err.close()
        watch.close()
        ads1.kill()
        nc1.kill()


# ---- the NC frozen past its lease: its token goes and comes back, no restart ------------------------------------
def test_nc_frozen_past_its_lease_keeps_the_supply(tmp_path: Path) -> None:
    """The NC SIGSTOPped 1.2 s (lease 0.5 s): nc-ads's zenoh drops the link, the NC's liveliness token goes
    and comes back while the same instance runs on (what a starved process on a loaded machine does). The NC
    excuses its own stall, so nc-ads still holds the axis: it must go on supplying PLCTONC. Before, it took
    the token's loss for a restart, ended the supply, and the NC's watchdog stopped the axis (0x8F02)."""
    nc1 = start_nc_server(tmp_path / "nc")
    ads1 = start_nc_ads(tmp_path / "ads", nc1.endpoint, role="operator")
    watch = NcTestClient(nc1.port, "watch3", token=False)
    lost = "its liveliness token disappeared"
    try:
        plc = connect(ads1)
        try:
            plc.write(0x4301, 0x01, 7, pyads.PLCTYPE_UDINT)  # claims axis 1 and enables it: nc-ads supplies it
            wait_until(lambda: state(plc, 1).StateDWord & BIT_CONTROL_LOOP_CLOSED, 20, "axis 1 enabled")
            wait_until(lambda: watch.nctoplc(1) is not None, 20, "the observer's first NCTOPLC sample")
            for _ in range(2):
                n = ads1.stderr().count(lost)
                nc1.send_signal(signal.SIGSTOP)
                try:
                    time.sleep(1.2)
                finally:
                    nc1.send_signal(signal.SIGCONT)
                wait_until(lambda: ads1.stderr().count(lost) > n, 20, "nc-ads saw the NC's token go (its link dropped)")
                wait_until(lambda: plc.read_state()[0] == pyads.ADSSTATE_RUN, 30, "RUN again", interval=0.05)
            # several watchdog timeouts (0.5 s) after the stall: the axis still supplied, enabled, no error
            until = time.monotonic() + 2.0
            while time.monotonic() < until:
                rec = watch.nctoplc(1)
                code = int(rec["ErrorCode"]) if rec is not None else -1
                assert code == 0, f"axis 1 error 0x{code:X}\n{ads1.stderr()}"
                time.sleep(0.05)
            assert state(plc, 1).StateDWord & BIT_CONTROL_LOOP_CLOSED
            assert watch.request("Info")["Value"]["claims"].get(1) == "ads1"
            assert "restarted" not in ads1.stderr() and "supply" not in ads1.stderr(), ads1.stderr()
        finally:
            plc.close()
    finally:
        watch.close()
        ads1.kill()
        nc1.kill()


# ---- axes above 255 have no index group -------------------------------------------------------------------------
BIG_IDS = """
[nc]
name = "nc1"
cycle_time = 0.001
[zenoh]
listen = ["tcp/127.0.0.1:7447"]
[[axis]]
AxisId = 7
Name = "Small"
[[axis]]
AxisId = 300
Name = "Big"
"""


def test_axes_above_255_are_left_out(tmp_path: Path) -> None:
    nc1 = start_nc_server(tmp_path / "nc", config_text=BIG_IDS)
    ads1 = start_nc_ads(tmp_path / "ads", nc1.endpoint, role="observer")
    try:
        plc = connect(ads1)
        try:
            assert plc.read(0x1100, 0x03, pyads.PLCTYPE_UDINT) == 1
            assert list(plc.read(0x1100, 0x33, pyads.PLCTYPE_UDINT * 1)) == [7]
            assert plc.read(0x4007, 0x02, pyads.PLCTYPE_STRING) == "Small"
            assert ads_error(plc.read, 0x4000 + (300 & 0xFF), 0x27, pyads.PLCTYPE_LREAL) == 0x702  # 0x402C: no axis 44
        finally:
            plc.close()
        wait_until(lambda: "axis 300 has no ADS index group" in ads1.stderr(), 10, "the log line about axis 300")
    finally:
        ads1.kill()
        nc1.kill()


# ---- nc-ads stopping: an orderly end (enables off, release), no client-loss error -----------------------------
def test_nc_ads_stop_releases_without_error(nc: NcServerProcess, watcher: NcTestClient, tmp_path: Path) -> None:
    h = start_nc_ads(tmp_path, nc.endpoint, role="operator", client_id="ads-stop")
    try:
        plc = connect(h)
        try:
            plc.write(0x4303, 0x02, 1, pyads.PLCTYPE_UINT)  # controller enable alone (IO 0x02)
            wait_until(lambda: state(plc, 3).StateDWord & BIT_CONTROL_LOOP_CLOSED, 20, "axis 3 enabled")
            assert plc.read(0x4303, 0x01, pyads.PLCTYPE_UDINT) == 0x1
            assert watcher.request("Info")["Value"]["claims"].get(3) == "ads-stop"
            assert h.stop() == 0  # SIGTERM while the ADS connection is still open
        finally:
            plc.close()
        wait_until(lambda: watcher.request("Info")["Value"]["claims"].get(3) is None, 20, "axis 3 released")
        n = wait_until(lambda: (x := watcher.nctoplc(3)) is not None and
                       not int(x["StateDWord"]) & BIT_CONTROL_LOOP_CLOSED and x, 20, "axis 3 disabled")
        assert int(n["ErrorCode"]) == 0
    finally:
        h.kill()
