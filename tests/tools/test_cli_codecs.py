"""zenoh-cli codec plugins: requests and replies round trip, frames decode, bad input is refused clearly."""
from __future__ import annotations

import inspect
import json
import shlex
import subprocess
import threading
import tomllib
from pathlib import Path

import numpy as np
import pytest

from nc_schema import (
    NCTOPLC_DTYPE, PLCTONC_DTYPE, ErrorCodes, cli_codecs, encode_frame, encode_plc_frame, make_reply, pack,
    Keys, parse_request, unpack,
)
from znc_testing.tools_testing import T, Rig, kill_group, zenoh_cli_command

ROOT = Path(__file__).resolve().parents[2]


def test_entry_points_name_functions_that_exist() -> None:
    eps = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["entry-points"]
    for group in ("zenoh_cli.codecs.decoders", "zenoh_cli.codecs.encoders"):
        for name, target in eps[group].items():
            mod, func = target.split(":")
            assert mod == "nc_schema.cli_codecs" and callable(getattr(cli_codecs, func)), (name, target)
    assert {"ncrequest", "ncreply", "plcframe", "ncframe", "msgpack"} <= set(eps["zenoh_cli.codecs.decoders"])
    assert {"ncrequest", "msgpack"} <= set(eps["zenoh_cli.codecs.encoders"])


@pytest.mark.parametrize("req", [
    {"id": 7, "cmd": "Info"},
    {"id": "a-1", "client": "plc1", "cmd": "MoveAbsolute", "Position": 10.5, "Velocity": 100.0},
    {"id": 3, "cmd": "ReadParameter", "ParameterNumber": 1003},
    {"id": 4, "cmd": "WriteParameter", "ParameterNumber": 1003, "Value": True},
])
def test_request_round_trip(req: dict) -> None:
    data = cli_codecs.encode_request("", json.dumps(req))
    assert unpack(data) == req
    line = cli_codecs.decode_request("", data)
    assert "\n" not in line and json.loads(line) == req


def test_request_encoder_makes_fresh_ids() -> None:
    a = unpack(cli_codecs.encode_request("nc/nc1/cmd", '{"cmd": "Info"}'))
    b = unpack(cli_codecs.encode_request("nc/nc1/cmd", '{"cmd": "Info"}'))
    assert isinstance(a["id"], int) and a["id"] != b["id"]
    assert parse_request(pack(a))["cmd"] == "Info"


@pytest.mark.parametrize("text, what", [
    ("not json", "not JSON"),
    ("[1, 2]", "JSON object"),
    ('{"cmd": "Nope"}', "0x0701"),
    ('{"cmd": "MoveAbsolute", "Position": 1.0}', "0x0706"),  # Velocity missing
    ('{"cmd": "MoveAbsolute", "Position": 1.0, "Velocity": 1.0, "Typo": 1}', "unknown field"),
    ('{"cmd": "MoveAbsolute", "Position": NaN, "Velocity": 1.0}', "finite"),
])
def test_request_encoder_refuses_what_the_nc_refuses(text: str, what: str) -> None:
    with pytest.raises(ValueError, match=what):
        cli_codecs.encode_request("", text)


def test_request_encoder_checks_the_command_key() -> None:
    enc = cli_codecs.encode_request
    move = '{"cmd": "MoveAbsolute", "Position": 1.0, "Velocity": 1.0}'
    assert unpack(enc("nc/nc1/axis/1/cmd/op/plc1", move))["cmd"] == "MoveAbsolute"
    assert unpack(enc("nc/nc1/axis/1/cmd", move))["cmd"] == "MoveAbsolute"  # the old layout: no class to check
    with pytest.raises(ValueError, match="axis command"):
        enc("nc/nc1/cmd/op/plc1", move)
    with pytest.raises(ValueError, match="NC command"):
        enc("nc/nc1/axis/1/cmd/read/plc1", '{"cmd": "Info"}')
    with pytest.raises(ValueError, match="key's client"):
        enc("nc/nc1/axis/1/cmd/op/plc1", '{"cmd": "Claim", "client": "plc2"}')
    cls = cli_codecs.COMMANDS["MoveAbsolute"].get("class")
    if cls is not None:  # protocol.json with command classes (protocol version 2)
        other = "read" if cls != "read" else "op"
        with pytest.raises(ValueError, match="class"):
            enc(f"nc/nc1/axis/1/cmd/{other}/plc1", move)


def test_request_decoder_marks_invalid_requests() -> None:
    out = json.loads(cli_codecs.decode_request("", pack({"id": 1, "cmd": "Halt", "Bogus": 2})))
    assert out["cmd"] == "Halt" and out["Bogus"] == 2 and out["invalid"].startswith("0x0706")
    out = json.loads(cli_codecs.decode_request("", pack([1, 2])))
    assert out["value"] == [1, 2] and "invalid" in out
    with pytest.raises(Exception):
        cli_codecs.decode_request("", b"\xc1")  # never used by msgpack


@pytest.mark.parametrize("reply", [
    make_reply(1, "Info", cycle=12, value={"name": "nc1", "axes": [{"AxisId": 1}], "claims": {1: "plc1"}}),
    make_reply("x", "MoveAbsolute", cycle=99, cmd_no=5),
    make_reply(2, "ReadParameter", cycle=3, value=500.0),
    make_reply(3, "MoveAbsolute", error=ErrorCodes.NC_NO_ENABLE, cycle=4),
    make_reply(None, None, error=ErrorCodes.ADSERR_DEVICE_INVALIDDATA, text="payload is not msgpack"),
])
def test_reply_round_trip(reply: dict) -> None:
    line = cli_codecs.decode_reply("nc/nc1/cmd", pack(reply))
    out = json.loads(line)
    name = out.pop("error_name", None)
    assert (name is not None) == (reply["error"] != 0)
    if name is not None:
        assert name == cli_codecs.error_name(reply["error"]) and not name.startswith("0x")
    assert out == json.loads(json.dumps(reply))  # int map keys become strings in JSON, nothing else changes


def test_frame_and_plc_frame_decoders() -> None:
    recs = np.zeros(2, dtype=NCTOPLC_DTYPE)
    recs["AxisId"] = [1, 2]
    recs["SetPos"] = [1.5, -2.0]
    out = json.loads(cli_codecs.decode_frame("nc/nc1/status", encode_frame(42, 7, recs, epoch=(3 << 16) | 5)))
    assert out["header"]["Cycle"] == 42 and [a["SetPos"] for a in out["axes"]] == [1.5, -2.0]
    assert out["header"]["Epoch"] == (3 << 16) | 5 and out["header"]["HeaderSize"] == 40  # (protocol 5)
    assert out["axes"][0]["MotionState"] == "MC_AXISSTATE_DISABLED"
    pc = np.zeros(1, dtype=PLCTONC_DTYPE)
    pc["ControlDWord"] = 0x7
    out = json.loads(cli_codecs.decode_plcframe("nc/nc1/plctonc/plc1", encode_plc_frame(9, [3], pc)))
    assert out["header"]["PlcCycle"] == 9 and out["axes"][0]["AxisId"] == 3
    assert out["axes"][0]["ControlDWordBits"][:1] == ["Enable"]
    with pytest.raises(ValueError):
        cli_codecs.decode_plcframe("", b"\0" * 10)


# ---- the README's zenoh-cli lines, run against a real NC ---------------------------------------
def _readme_lines() -> tuple[list[str], list[list[str]]]:
    """(the ``Z=...`` prefix as arguments, the ``$ $Z ...`` lines as arguments) of the README's first
    zenoh-cli block."""
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    sec = text[text.index("### Watching the wire with zenoh-cli"):]
    block = sec.split("```")[1]
    z: list[str] | None = None
    lines = []
    for ln in block.splitlines():
        if ln.startswith("$ Z="):
            z = shlex.split(ln[len("$ Z="):])[0].split()
        elif ln.startswith("$ $Z "):
            lines.append(shlex.split(ln[len("$ $Z "):], comments=True))
    assert z is not None and z[0] == "zenoh" and lines
    return z[1:], lines


def _protocol_v2() -> bool:
    """The checkout's NC has the command keys with class and client (protocol version 2)."""
    return "cls" in inspect.signature(Keys.axis_cmd).parameters


def _first_line(cmd: list[str], timeout: float) -> str:
    """Start ``cmd`` (own process group), return its first stdout line, then kill it."""
    p = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)
    got: list[str] = []
    th = threading.Thread(target=lambda: got.append(p.stdout.readline()), daemon=True)  # type: ignore[union-attr]
    th.start()
    try:
        th.join(timeout)
    finally:
        kill_group(p)
    err = p.stderr.read() if p.stderr else ""
    assert got and got[0], f"no output from {cmd[4:]} within {timeout} s; stderr: {err[-2000:]}"
    return got[0]


def test_readme_zenoh_cli_lines(rig: Rig) -> None:
    rig.enable(1)  # t1 feeds PLCTONC for axis 1 and holds a client token
    # t1's view of axis 1 (a PLC client's liveliness token): the NC then puts nc/nc1/view/t1
    view = rig.cl.session.liveliness().declare_token(Keys("nc1").view_select("t1", 0, [1]))
    z, lines = _readme_lines()
    i = z.index("--connect")
    z[i + 1] = rig.endpoint
    z += ["--cfg", "scouting/multicast/enabled:false", "--cfg", "scouting/gossip/enabled:false"]
    keys_seen = set()
    v2 = _protocol_v2()
    for args in lines:
        sub = args[0] if args[0] != "liveliness" else " ".join(args[:2])
        key = args[args.index("-k" if "-k" in args else "-s") + 1]
        keys_seen.add(key)
        if not v2 and ("/cmd/" in key or key.endswith("/claims")):
            continue  # the command key layout / claims key of protocol version 2 (helper "roles")
        cmd = zenoh_cli_command(*z, *args)
        if sub in ("subscribe", "liveliness sub"):
            out = [_first_line(cmd, T)]
        else:
            p = subprocess.run(cmd, capture_output=True, text=True, timeout=T * 2, start_new_session=True)
            assert p.returncode == 0, (args, p.stderr)
            out = p.stdout.splitlines()
            assert out, (args, p.stderr)
        for line in out:
            if "--line" in args:  # '{key} {value}'
                k, _, line = line.partition(" ")
                assert k.startswith("nc/nc1/plctonc/")
            v = json.loads(line)
            if sub == "get":
                assert v["error"] == 0 and v["cmd"] == json.loads(args[args.index("-v") + 1])["cmd"], v
            elif args[-1] in ("ncframe", "nctoplc", "plctonc", "plcframe"):
                assert v, line
    for key in ("nc/nc1/frame", "nc/nc1/status", "nc/nc1/stats", "nc/nc1/claims", "nc/nc1/axis/1/nctoplc",
                "nc/nc1/axis/1/plctonc", "nc/nc1/plctonc/*", "nc/*/alive", "nc/nc1/client/*"):
        assert key in keys_seen, f"README has no zenoh-cli line for {key}"
    assert any("/cmd/" in k for k in keys_seen)
    view.undeclare()
