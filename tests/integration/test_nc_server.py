"""nc-server as a separate process, driven over real zenoh sessions on 127.0.0.1.

Each test gets its own server on a free port (fixtures in tests/conftest.py kill its process
group at the end, pass or fail). Waits are condition polls with generous deadlines.
"""
from __future__ import annotations

import json
import math
import os
import signal
import struct
import subprocess
import sys
import threading
from pathlib import Path
from typing import Any, Callable, Iterator

import msgpack
import pytest

from nc_schema import COMMAND_CLASS

from znc_testing import (
    BIT_CONTROL_LOOP_CLOSED, BIT_ERROR, NcServerProcess, NcTestClient, wait_until,
)
from znc_testing.plc_harness import NC_ARGS

HERE = Path(__file__).resolve().parent
T = 30.0  # default deadline [s] for conditions on a loaded 2-core machine

# TwinCAT NCTOPLC_AXIS_REF offsets (written down here on purpose, not taken from nc_schema).
OFF_STATE, OFF_ERROR, OFF_AXIS_ID = 0, 4, 32
OFF_ACT_POS, OFF_ACT_VELO, OFF_SET_POS, OFF_SET_VELO = 40, 64, 80, 88
OFF_CMD_NO, OFF_CMD_STATE, OFF_DC_TIME = 124, 126, 240


@pytest.fixture
def nc_server(start_nc: Callable[..., NcServerProcess]) -> NcServerProcess:
    """The default configuration with a 3 s PLCTONC watchdog (NC_ARGS): the tests feed PLCTONC from a
    thread of pytest, which a loaded machine can stall for 0.5 s (the default timeout, a 0x8F02 that no
    test here but the frozen client's is about; that one still sees it, 3 s after the SIGSTOP)."""
    return start_nc(extra_args=NC_ARGS)


def raw(cl: NcTestClient, axis: int) -> tuple[bytes, bytes | None] | None:
    return cl.latest(f"nc/nc1/axis/{axis}/nctoplc")


def field(data: bytes, fmt: str, off: int) -> Any:
    return struct.unpack_from("<" + fmt, data, off)[0]


def enabled(cl: NcTestClient, axis: int) -> bool:
    s = cl.nctoplc(axis)
    return s is not None and bool(int(s["StateDWord"]) & BIT_CONTROL_LOOP_CLOSED)


# ---- (a) raw NCTOPLC at the TwinCAT offsets ---------------------------------------------------
def test_raw_nctoplc_offsets_and_move_absolute(nc_server: NcServerProcess,
                                               nc_client: Callable[..., NcTestClient]) -> None:
    cl = nc_client(nc_server.port, "plc-a")
    first = wait_until(lambda: raw(cl, 1), T, "first nctoplc sample of axis 1")
    payload, att = first
    assert len(payload) == 256
    assert field(payload, "I", OFF_AXIS_ID) == 1
    assert att is not None and len(att) == 24  # STAMP: Cycle, NcTimeNs, Epoch (protocol 5; 0 without redundancy)
    cycle0, nc_time0, epoch0 = struct.unpack("<QQQ", att)
    assert epoch0 == 0
    assert cycle0 > 0 and nc_time0 > 0
    wait_until(lambda: struct.unpack_from("<Q", raw(cl, 1)[1])[0] > cycle0, T, "attachment cycle to advance")
    # The DcTimeStamp is the low 32 bits of the NC time of the same cycle.
    p, a = raw(cl, 1)
    assert field(p, "I", OFF_DC_TIME) == struct.unpack_from("<Q", a, 8)[0] & 0xFFFFFFFF

    # Claim, supply an enabling PLCTONC (PLC frame built by hand: header + AxisId + PLCTONC).
    cl.claim(1)
    pub = cl.session.declare_publisher("nc/nc1/plctonc/plc-a")
    stop = threading.Event()

    def feed() -> None:
        n = 0
        while not stop.wait(0.01):
            n += 1
            plctonc = bytearray(128)
            struct.pack_into("<II", plctonc, 0, 0x7, 1_000_000)  # ControlDWord@0, Override@4
            header = struct.pack("<IHHQHHI", 0x31435050, 1, 24, n, 1, 136, 0)
            pub.put(header + struct.pack("<II", 1, 0) + bytes(plctonc))

    th = threading.Thread(target=feed, daemon=True)
    th.start()
    try:
        wait_until(lambda: field(raw(cl, 1)[0], "I", OFF_STATE) & BIT_CONTROL_LOOP_CLOSED, T, "ControlLoopClosed")
        # The PLCTONC the NC applies is published too (128 B, same stamp attachment).
        applied = wait_until(lambda: (v := cl.latest("nc/nc1/axis/1/plctonc")) and field(v[0], "I", 0) == 0x7 and v,
                             T, "applied PLCTONC sample")
        assert len(applied[0]) == 128 and field(applied[0], "I", 4) == 1_000_000 and len(applied[1]) == 24  # (protocol 5: Cycle, NcTimeNs, Epoch)
        r = cl.request("MoveAbsolute", axis=1, Position=25.0, Velocity=200.0)
        assert r["error"] == 0, r
        cmd_no = r["CmdNo"]

        def arrived() -> bool:
            p = raw(cl, 1)[0]
            return (abs(field(p, "d", OFF_ACT_POS) - 25.0) < 0.02 and field(p, "d", OFF_SET_POS) == 25.0
                    and field(p, "H", OFF_CMD_NO) == cmd_no and field(p, "H", OFF_CMD_STATE) == 2)

        wait_until(arrived, T, "ActPos at 25.0 with the command DONE")
        p = raw(cl, 1)[0]
        assert field(p, "I", OFF_ERROR) == 0
        assert field(p, "I", OFF_STATE) & BIT_ERROR == 0
    finally:
        stop.set()
        th.join(5)


# ---- (b) garbage requests ------------------------------------------------------------------
GARBAGE: list[tuple[str, str, bytes, int]] = [
    ("not msgpack", "axis/1", b"\xc1\xc1\xc1", 0x706),
    ("empty payload", "axis/1", b"", 0x706),
    ("not a map", "axis/1", msgpack.packb([1, 2, 3]), 0x706),
    ("missing id", "axis/1", msgpack.packb({"cmd": "Reset"}), 0x706),
    ("bool id", "axis/1", msgpack.packb({"id": True, "cmd": "Reset"}), 0x706),
    ("unknown cmd", "axis/1", msgpack.packb({"id": 1, "cmd": "SelfDestruct"}), 0x701),
    ("NaN position", "axis/1",
     msgpack.packb({"id": 2, "cmd": "MoveAbsolute", "Position": math.nan, "Velocity": 1.0}), 0x706),
    ("inf velocity", "axis/1", msgpack.packb({"id": 3, "cmd": "MoveVelocity", "Velocity": math.inf}), 0x706),
    ("string position", "axis/1",
     msgpack.packb({"id": 4, "cmd": "MoveAbsolute", "Position": "10", "Velocity": 1.0}), 0x706),
    ("bool velocity", "axis/1", msgpack.packb({"id": 5, "cmd": "MoveVelocity", "Velocity": True}), 0x706),
    ("missing field", "axis/1", msgpack.packb({"id": 6, "cmd": "MoveAbsolute", "Position": 1.0}), 0x706),
    ("unknown field", "axis/1", msgpack.packb({"id": 7, "cmd": "Reset", "Force": 1}), 0x706),
    ("int out of range", "axis/1", msgpack.packb({"id": 8, "cmd": "ReadParameter", "ParameterNumber": 2**40}), 0x706),
    ("huge id", "axis/1", msgpack.packb({"id": "i" * 5000, "cmd": "Reset"}), 0x706),
    ("huge cmd", "axis/1", msgpack.packb({"id": 9, "cmd": "C" * 50_000}), 0x701),
    ("oversized", "axis/1", msgpack.packb({"id": 10, "cmd": "Reset", "x": "y" * 200_000}), 0x706),
    ("bad client id", "axis/1", msgpack.packb({"id": 11, "cmd": "Reset", "client": "a b/c"}), 0x706),
    ("unknown axis", "axis/99", msgpack.packb({"id": 12, "cmd": "Reset"}), 0x4012),
    ("axis id not a number", "axis/x", msgpack.packb({"id": 13, "cmd": "Reset"}), 0x4012),
    ("axis cmd on NC key", "", msgpack.packb({"id": 14, "cmd": "Reset"}), 0x4012),
    ("unknown parameter", "axis/1", msgpack.packb({"id": 15, "cmd": "ReadParameter", "ParameterNumber": 4242}), 0x703),
    # regressions: Info on an axis that does not exist was answered, axis/01 was taken as axis 1
    ("Info on an unknown axis", "axis/99", msgpack.packb({"id": 16, "cmd": "Info"}), 0x4012),
    ("leading zero", "axis/01", msgpack.packb({"id": 17, "cmd": "ReadParameter", "ParameterNumber": 1003}), 0x4012),
    ("leading zero, Info", "axis/01", msgpack.packb({"id": 18, "cmd": "Info"}), 0x4012),
    # key identity and class
    ("class mismatch", "axis/1 eng", msgpack.packb({"id": 19, "cmd": "Reset"}), 0x723),
    ("write on the op key", "axis/1 op",
     msgpack.packb({"id": 20, "cmd": "WriteParameter", "ParameterNumber": 1003, "Value": 1.0}), 0x723),
    ("another client's name", "axis/1", msgpack.packb({"id": 21, "cmd": "Reset", "client": "someone-else"}), 0x723),
    ("unknown class", "axis/1 admin", msgpack.packb({"id": 22, "cmd": "Reset"}), 0x4012),
]


def key_of(where: str, payload: bytes) -> str:
    """The command key for GARBAGE's ``where`` ("axis/1", "axis/1 <class>", "" = NC level) from
    client "fuzzer": the class of the payload's command unless given."""
    where, _, cls = where.partition(" ")
    if not cls:
        try:
            cmd = msgpack.unpackb(payload).get("cmd")
        except Exception:
            cmd = None
        cls = COMMAND_CLASS.get(cmd, "op") if isinstance(cmd, str) else "op"
    return f"nc/nc1/{where}/cmd/{cls}/fuzzer" if where else f"nc/nc1/cmd/{cls}/fuzzer"


def test_garbage_requests_get_error_codes(nc_server: NcServerProcess,
                                          nc_client: Callable[..., NcTestClient]) -> None:
    cl = nc_client(nc_server.port, "fuzzer")
    wait_until(lambda: raw(cl, 1), T, "status samples")
    c0 = struct.unpack_from("<Q", raw(cl, 1)[1])[0]
    got = {}
    for name, where, payload, _ in GARBAGE:
        r = cl.raw_request(key_of(where, payload), payload)
        got[name] = r["error"]
        assert r["text"], (name, r)
    assert got == {name: code for name, _, _, code in GARBAGE}

    # Negative velocity on an enabled axis: the NC's own check (0x4221).
    cl.claim(1)
    cl.feed_plctonc([1])
    wait_until(lambda: enabled(cl, 1), T, "axis 1 enabled")
    r = cl.request("MoveAbsolute", axis=1, Position=5.0, Velocity=-10.0)
    assert r["error"] == 0x4221, r

    # Malformed PLC frames on the PLCTONC key are dropped and counted: from a client that holds
    # nothing before any decoding (ignored), from the holder after decoding (malformed).
    junk = cl.session.declare_publisher("nc/nc1/plctonc/junk")
    own = cl.session.declare_publisher("nc/nc1/plctonc/fuzzer")
    for payload in (b"", b"garbage", b"\x50\x50\x43\x31" + bytes(40)):
        junk.put(payload)
        own.put(payload)
    wait_until(lambda: (s := cl.stats()) is not None and s["plctonc_ignored"] >= 3, T, "foreign frames ignored")
    wait_until(lambda: (s := cl.stats()) is not None and s["plctonc_malformed"] >= 3, T, "malformed frames counted")

    # Still cycling, and a valid command still works.
    wait_until(lambda: struct.unpack_from("<Q", raw(cl, 1)[1])[0] > c0 + 100, T, "cycles to advance")
    r = cl.request("ReadParameter", axis=1, ParameterNumber=1003)  # AxisVeloMax
    assert r["error"] == 0 and r["Value"] == 500.0
    r = cl.request("MoveAbsolute", axis=1, Position=5.0, Velocity=100.0)
    assert r["error"] == 0, r
    wait_until(lambda: abs(float(cl.nctoplc(1)["ActPos"]) - 5.0) < 0.02, T, "axis 1 at 5.0")
    assert nc_server.proc.poll() is None


def test_wildcard_query_is_answered(nc_server: NcServerProcess, nc_client: Callable[..., NcTestClient]) -> None:
    cl = nc_client(nc_server.port)
    payload = msgpack.packb({"id": 1, "cmd": "Info"})
    replies = list(cl.session.get("nc/nc1/**", payload=payload, timeout=T))
    assert replies and all(r.ok is not None for r in replies)
    assert msgpack.unpackb(replies[0].ok.payload.to_bytes(), strict_map_key=False)["error"] == 0x4012


# ---- (c) frozen controlling client ----------------------------------------------------------
@pytest.fixture
def frozen_client(nc_server: NcServerProcess) -> Iterator[subprocess.Popen[str]]:
    proc = subprocess.Popen([sys.executable, str(HERE / "frozen_client.py"), str(nc_server.port), "frozen", "1", "50"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        yield proc
    finally:
        for sig in (signal.SIGCONT, signal.SIGKILL):
            try:
                os.killpg(proc.pid, sig)
            except ProcessLookupError:
                pass
        proc.wait(10)


def test_frozen_client_axis_is_stopped_and_released(nc_server: NcServerProcess, frozen_client: subprocess.Popen[str],
                                                    nc_client: Callable[..., NcTestClient]) -> None:
    lines: list[str] = []
    threading.Thread(target=lambda: lines.extend(frozen_client.stdout), daemon=True).start()  # type: ignore[arg-type]
    wait_until(lambda: any('"moving"' in ln for ln in lines) or frozen_client.poll() is not None, 60,
               "the client to start its move")
    assert frozen_client.poll() is None, frozen_client.stderr.read() if frozen_client.stderr else ""
    cmd_no = json.loads(next(ln for ln in lines if '"moving"' in ln))["CmdNo"]

    cl = nc_client(nc_server.port, "rescuer")
    wait_until(lambda: (s := cl.nctoplc(1)) is not None and float(s["ActVelo"]) > 10.0, T, "axis 1 moving")
    r = cl.request("Claim", axis=1)
    assert r["error"] == 0x723 and "frozen" in r["text"]

    os.kill(frozen_client.pid, signal.SIGSTOP)

    def faulted() -> bool:
        s = cl.nctoplc(1)
        return int(s["ErrorCode"]) in (0x8F02, 0x8F01) and bool(int(s["StateDWord"]) & BIT_ERROR)

    wait_until(faulted, T, "ZNC_PLCTONC_TIMEOUT/ZNC_CLIENT_LOST on axis 1")
    s = cl.nctoplc(1)
    assert int(s["CmdNo"]) == cmd_no and int(s["CmdState"]) in (3, 4)  # the move was aborted / ended in error
    wait_until(lambda: float(cl.nctoplc(1)["SetVelo"]) == 0.0 and abs(float(cl.nctoplc(1)["ActVelo"])) < 1e-3,
               T, "axis 1 stopped")
    # The claim was released: another client can take over.
    assert cl.claim(1)["error"] == 0
    info = cl.request("Info")["Value"]
    assert info["claims"] == {1: "rescuer"}


# ---- (d) clean shutdown ---------------------------------------------------------------------
@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_signal_gives_clean_exit(nc_server: NcServerProcess, nc_client: Callable[..., NcTestClient],
                                 sig: int) -> None:
    # Connected clients, a PLCTONC publisher and a watched frame: none may keep the NC alive.
    cl = nc_client(nc_server.port, "watcher")
    cl.watch("nc/nc1/frame")
    cl.claim(2)
    cl.feed_plctonc([2])
    wait_until(lambda: enabled(cl, 2), T, "axis 2 enabled")
    rc = nc_server.stop(sig, timeout=T)
    assert rc == 0, nc_server.stderr()
    err = nc_server.stderr()
    assert "Traceback" not in err and "leaked" not in err
    # The last frame says ShuttingDown (FRAME_FLAGS bit 0 at header offset 28).
    wait_until(lambda: struct.unpack_from("<I", cl.latest("nc/nc1/frame")[0], 28)[0] & 1, T, "ShuttingDown frame")


def test_listen_endpoint_in_use_fails(nc_server: NcServerProcess) -> None:
    from znc_testing import nc_server_command
    proc = subprocess.run([*nc_server_command(), "--listen", nc_server.endpoint], capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 1
    assert nc_server.endpoint in proc.stderr


# ---- (e) claims and dedup -------------------------------------------------------------------
def test_second_claimant_refused_and_duplicate_request_runs_once(
        nc_server: NcServerProcess, nc_client: Callable[..., NcTestClient]) -> None:
    a = nc_client(nc_server.port, "plc-a")
    b = nc_client(nc_server.port, "plc-b")
    anonymous = nc_client(nc_server.port)
    a.claim(3)
    r = b.request("Claim", axis=3)  # one attempt, no retry
    assert r["error"] == 0x723 and "plc-a" in r["text"], r
    assert b.request("SetOverride", axis=3, Override=10.0)["error"] == 0x723
    assert anonymous.request("SetOverride", axis=3, Override=10.0)["error"] == 0x723
    assert b.request("Release", axis=3)["error"] == 0x723
    # A claim without a liveliness token is refused, saying why.
    r = anonymous.request("Claim", axis=4)
    assert r["error"] == 0x723 and "liveliness" in r["text"]
    # b cannot act as a: a request naming plc-a on b's key is refused (nothing released)
    r = b.request("Release", axis=3, client="plc-a")
    assert r["error"] == 0x723 and "'plc-a'" in r["text"]

    a.feed_plctonc([3])
    wait_until(lambda: enabled(a, 3), T, "axis 3 enabled")
    start = float(a.nctoplc(3)["SetPos"])
    req = msgpack.packb({"id": "move-1", "client": "plc-a", "cmd": "MoveRelative", "Distance": -10.0,
                         "Velocity": 100.0})
    r1 = a.raw_request("nc/nc1/axis/3/cmd/op/plc-a", req)
    r2 = a.raw_request("nc/nc1/axis/3/cmd/op/plc-a", req)
    assert r1["error"] == 0 and r1 == r2  # the second answer came from the cache

    def done() -> bool:
        s = a.nctoplc(3)
        return int(s["CmdNo"]) == r1["CmdNo"] and int(s["CmdState"]) == 2

    wait_until(done, T, "MoveRelative done")
    s = a.nctoplc(3)
    assert abs(float(s["SetPos"]) - (start - 10.0)) < 1e-6, (start, float(s["SetPos"]))
    # The same id from another client is a different request.
    r3 = b.raw_request("nc/nc1/axis/3/cmd/read/plc-b", msgpack.packb({"id": "move-1", "client": "plc-b", "cmd": "ReadParameter",
                                                           "ParameterNumber": 1003}))
    assert r3["error"] == 0 and r3["Value"] == 250.0

    assert a.request("Release", axis=3)["error"] == 0
    assert b.claim(3)["error"] == 0
    stats = wait_until(lambda: (s := a.stats()) is not None and s["claims"] == {3: "plc-b"} and s, T, "stats claims")
    for k in ("cycle", "cycle_time", "missed_cycles", "overruns", "timing", "work_us_p50", "work_us_p99",
              "work_us_max", "lateness_us_p99", "clients"):
        assert k in stats
    assert stats["timing"] in ("SCHED_FIFO", "SCHED_OTHER") and stats["dedup_hits"] >= 1


def test_request_burst_is_answered_completely(nc_server: NcServerProcess,
                                              nc_client: Callable[..., NcTestClient]) -> None:
    # 300 requests in flight at once: drained a bounded number per cycle, every one answered.
    cl = nc_client(nc_server.port, "burst")
    handlers = [cl.session.get("nc/nc1/axis/2/cmd/read/burst", timeout=T,
                               payload=msgpack.packb({"id": k, "client": "burst", "cmd": "ReadParameter",
                                                      "ParameterNumber": 1003}))
                for k in range(300)]
    answers = {}
    for h in handlers:
        for r in h:
            assert r.ok is not None
            m = msgpack.unpackb(r.ok.payload.to_bytes(), strict_map_key=False)
            answers[m["id"]] = m
    assert sorted(answers) == list(range(300))
    assert all(m["error"] == 0 and m["Value"] == 500.0 for m in answers.values())
    # (no bound on replies per cycle value: the NC also answers between cycles, under the same value)


def test_config_file_and_overrides(start_nc: Callable[..., NcServerProcess],
                                   nc_client: Callable[..., NcTestClient]) -> None:
    cfg = """
[nc]
name = "mill"
cycle_time = 0.002
watchdog_timeout = 0.3
[zenoh]
listen = ["tcp/127.0.0.1:1"]   # replaced by --listen (start_nc passes a free port)
[[axis]]
AxisId = 10
Name = "A"
AxisVeloMax = 123.0
[[axis]]
AxisId = 20
Name = "B"
Modulo = true
AxisEncoderModuloValue = 360.0
"""
    srv = start_nc(cfg, name="mill")
    assert "nc-server mill ready: 2 axes, cycle 2.000 ms" in srv.ready_line()
    cl = nc_client(srv.port, "cfg-test", nc="mill")
    info = cl.request("Info")["Value"]
    assert info["name"] == "mill" and info["cycle_time"] == 0.002 and info["watchdog_timeout"] == 0.3
    assert [(a["AxisId"], a["Name"], a["Modulo"]) for a in info["axes"]] == [(10, "A", False), (20, "B", True)]
    assert cl.request("ReadParameter", axis=10, ParameterNumber=1003)["Value"] == 123.0
    assert cl.request("ReadParameter", axis=1, ParameterNumber=1003)["error"] == 0x4012
    s = wait_until(lambda: cl.nctoplc(20), T, "nctoplc of axis 20")
    assert int(s["AxisId"]) == 20


def test_invalid_config_exits_2(start_nc: Callable[..., NcServerProcess]) -> None:
    srv = start_nc("[[axis]]\nAxisId = 1\n[[axis]]\nAxisId = 1\n", wait=False)
    assert srv.proc.wait(60) == 2
    err = srv.stderr()
    assert "axis[1].AxisId" in err and "Traceback" not in err


# ---- (f) who holds what: nc/<nc>/claims -----------------------------------------------------
def test_claims_are_published(nc_server: NcServerProcess, nc_client: Callable[..., NcTestClient]) -> None:
    a = nc_client(nc_server.port, "plc-a")
    status = nc_client(nc_server.port, "status", token=False)
    status.watch("nc/nc1/claims")

    def claims() -> dict[str, Any] | None:
        got = status.latest("nc/nc1/claims")
        return msgpack.unpackb(got[0], strict_map_key=False) if got else None

    first = wait_until(claims, T, "a first claims map (published at start and every 1 s)")
    assert set(first) == {"cycle", "claims", "clients", "last_command"}
    a.claim(2)
    a.feed_plctonc([2])
    wait_until(lambda: enabled(a, 2), T, "axis 2 enabled")
    r = a.request("MoveVelocity", axis=2, Velocity=10.0)
    assert r["error"] == 0
    assert status.request("ReadParameter", axis=2, ParameterNumber=1003)["error"] == 0

    def shows_all() -> dict[str, Any] | None:
        m = claims()
        ok = (m and m["claims"] == {2: "plc-a"} and m["last_command"].get(2, {}).get("cmd") == "MoveVelocity"
              and m["clients"].get("status", {}).get("role") == "observer")
        return m if ok else None

    m = wait_until(shows_all, T, "the claim, the move and the observer in the claims map")
    assert m["last_command"][2] == {"client": "plc-a", "cmd": "MoveVelocity", "cycle": r["cycle"]}
    assert m["clients"]["plc-a"] == {"alive": True, "role": "operator", "role_source": "seen"}
    assert m["clients"]["status"] == {"alive": False, "role": "observer", "role_source": "seen"}
    info = status.request("Info")["Value"]
    assert info["arbitration"]["claims"] == {2: "plc-a"} and info["arbitration"]["last_command"][2]["client"] == "plc-a"
    # unchanged: republished (about every second) with a newer cycle
    c0 = m["cycle"]
    wait_until(lambda: (x := claims()) and x["cycle"] > c0 + 200, T, "the claims map republished")
    assert a.request("Stop", axis=2)["error"] == 0
