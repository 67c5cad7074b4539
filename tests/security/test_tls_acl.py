"""TLS and access control on real processes: nc-server (and nc-router) with ``--tls-dir`` and
``--roles deploy/roles.toml``, clients in this process and a ``plc-run``, all on 127.0.0.1.

What zenoh does with a denied message (verified, ../shared/reference/zenoh-security-notes.md): a
denied put is dropped silently, a denied query is finalized at once without a reply. So "cannot" is
checked as: no reply at all (and the PLC side reports a timeout, never hangs), nothing changed on
the NC, and, for data, nothing arrives while a listed reader gets it.
"""
from __future__ import annotations

import struct
import subprocess
import sys
import time
from pathlib import Path
from typing import Any, Callable

import msgpack
import numpy as np
import pytest
import zenoh

from nc_schema import PLCTONC_DTYPE, ControlDWord, ErrorCodes, Keys, decode, encode_plc_frame, parse_alive_instance
from znc_testing.sec_testing import tls_config
from znc_testing import BIT_CONTROL_LOOP_CLOSED, NcServerProcess, wait_until

T = 30.0  # generous deadline for anything to happen on a loaded machine
K = Keys("nc1")
TIMEOUT_CODES = (int(ErrorCodes.ADSERR_CLIENT_SYNCTIMEOUT), int(ErrorCodes.ADSERR_DEVICE_NOTREADY))


def query(s: zenoh.Session, key: str, msg: dict[str, Any], timeout: float = 10.0) -> list[dict[str, Any]]:
    """All replies (decoded) of every matching queryable (target ALL, no consolidation: every answer
    counts, also an impostor's) to one query; [] when the router denied it (finalized at once)."""
    out = []
    for r in s.get(key, payload=msgpack.packb(msg), timeout=timeout, target=zenoh.QueryTarget.ALL,
                   consolidation=zenoh.ConsolidationMode.NONE):
        assert r.ok is not None, r.err
        out.append(msgpack.unpackb(r.ok.payload.to_bytes(), strict_map_key=False))
    return out


def request(s: zenoh.Session, cmd: str, axis: int | None, client: str, **args: Any) -> list[dict[str, Any]]:
    """``cmd`` on ``client``'s command key of its class (whoever ``s`` authenticated as)."""
    return query(s, K.command_key(cmd, axis, client), {"id": time.time_ns(), "cmd": cmd, **args})


class Watch:
    """Counts samples and keeps the newest payload per key expression of one session."""

    def __init__(self, s: zenoh.Session, *keys: str) -> None:
        self.n: dict[str, int] = {k: 0 for k in keys}
        self.last: dict[str, bytes] = {}
        self._subs = [s.declare_subscriber(k, self._cb(k)) for k in keys]

    def _cb(self, key: str) -> Callable[[zenoh.Sample], None]:
        def on(sample: zenoh.Sample) -> None:
            self.n[key] += 1
            self.last[key] = sample.payload.to_bytes()
        return on

    def msg(self, key: str) -> Any:
        b = self.last.get(key)
        return None if b is None else msgpack.unpackb(b, strict_map_key=False)


def instances(s: zenoh.Session, nc: str = "nc1") -> list[str]:
    """The instance ids of ``nc``'s instance tokens ``nc/<nc>/alive/<id>`` that ``s`` may see."""
    return sorted(p[1] for r in s.liveliness().get(Keys(nc).alive_instance_any, timeout=10.0)
                  if r.ok is not None and (p := parse_alive_instance(r.ok.key_expr)) is not None)


def info(s: zenoh.Session, client: str) -> dict[str, Any]:
    r = request(s, "Info", None, client)
    assert len(r) == 1 and r[0]["error"] == 0, r
    return r[0]["Value"]


def wait_claim(s: zenoh.Session, client: str, axis: int) -> None:
    """Claim ``axis`` as ``client``, retrying while the NC has not seen the client's token yet."""
    wait_until(lambda: (r := request(s, "Claim", axis, client)) and r[0]["error"] == 0, T, f"claim by {client}",
               interval=0.05)


# ---- authentication ------------------------------------------------------------------------
def test_unlisted_client_and_other_ca_are_refused(start_tls_nc: Callable[..., NcServerProcess],
                                                  session_as: Callable[..., zenoh.Session], certs: Path) -> None:
    nc = start_tls_nc()
    status = session_as(nc.port, "status")
    reader = Watch(status, K.frame)
    # a certificate of another CA (even with a listed CN) cannot open a session at all
    with pytest.raises(zenoh.ZError):
        zenoh.open(tls_config(nc.port, certs / "rogue", "plc1"))
    # plain TCP to the TLS port neither
    c = zenoh.Config()
    c.insert_json5("mode", '"client"')
    c.insert_json5("connect/endpoints", f'["tcp/127.0.0.1:{nc.port}"]')
    c.insert_json5("scouting/multicast/enabled", "false")
    c.insert_json5("scouting/gossip/enabled", "false")
    with pytest.raises(zenoh.ZError):
        zenoh.open(c)
    # a valid certificate whose CN is not in the roles file: connected, but it can do nothing
    stranger = session_as(nc.port, "stranger")
    got = Watch(stranger, K.frame, K.stats, K.claims)
    assert request(stranger, "Info", None, "stranger") == []
    assert request(stranger, "Claim", 1, "stranger") == []
    token = stranger.liveliness().declare_token(K.client_alive("stranger"))  # kept: dropping undeclares
    stranger.put(K.plctonc_in("stranger"), b"x" * 24)
    wait_until(lambda: reader.n[K.frame] > 200, T, "frames at a listed observer")
    assert sum(got.n.values()) == 0, got.n
    v = info(status, "status")
    assert v["claims"] == {} and "stranger" not in v["clients"] and "stranger" not in v["arbitration"]["clients"]


# ---- observer --------------------------------------------------------------------------------
def test_observer_reads_but_cannot_write_or_command(start_tls_nc: Callable[..., NcServerProcess],
                                                    session_as: Callable[..., zenoh.Session], certs: Path) -> None:
    nc = start_tls_nc()
    status = session_as(nc.port, "status")
    w = Watch(status, K.frame, K.claims, K.stats, K.axis_nctoplc(1))
    wait_until(lambda: all(w.n.values()), T, "frames, claims, stats and nctoplc at the observer")
    assert w.msg(K.claims)["claims"] == {}
    # the NC process's instance token (its restart evidence) reaches the observer, no one else's
    assert instances(status) == [nc.instance()]
    v = info(status, "status")
    assert v["arbitration"]["clients"]["status"] == {"alive": False, "role": "observer", "role_source": "roles"}
    r = request(status, "ReadParameter", 1, "status", ParameterNumber=1003)
    assert r[0]["error"] == 0 and r[0]["Value"] == 500.0
    # commands and writes: denied by the router, no reply, nothing done
    t0 = time.monotonic()
    assert request(status, "Reset", 1, "status") == []
    assert request(status, "Claim", 1, "status") == []
    assert request(status, "WriteParameter", 1, "status", ParameterNumber=1003, Value=100.0) == []
    assert time.monotonic() - t0 < 9.0  # finalized by the router, not by the query timeouts
    # on a key of its own class the NC refuses a command of another class (0x723)
    r = query(status, K.axis_cmd(1, "read", "status"), {"id": 1, "cmd": "Reset"})
    assert r[0]["error"] == 0x723
    # a PLCTONC frame and a liveliness token of the observer are dropped
    token = status.liveliness().declare_token(K.client_alive("status"))  # kept: dropping undeclares
    rec = np.zeros(1, dtype=PLCTONC_DTYPE)
    rec["ControlDWord"] = 7
    status.put(K.plctonc_in("status"), encode_plc_frame(1, [1], rec))
    assert request(status, "ReadParameter", 1, "status", ParameterNumber=1003)[0]["Value"] == 500.0
    v = info(status, "status")
    assert v["clients"] == [] and v["claims"] == {}
    stats = wait_until(lambda: w.msg(K.stats), T, "stats")
    assert stats["plctonc_ignored"] == 0 and stats["plctonc_frames"] == 0

    # the PLC side of a denied command: the port and the block report a timeout, they do not hang
    from plc_client import AXIS_REF, MC_Reset
    from plc_client.runtime import PlcRuntime
    rt = PlcRuntime(None, {"nc1": f"tls/127.0.0.1:{nc.port}"}, client_id="status", tls_dir=str(certs),
                    command_timeout=5.0, claim_retry=1000.0)
    try:
        assert rt.open(wait=T)
        p = rt.port.send("nc1", 1, "Reset")
        wait_until(lambda: (rt.port.poll(), p.done)[1], T, "the denied Reset to end")
        assert p.reply is None and p.failed in TIMEOUT_CODES, p
        ax = AXIS_REF(nc="nc1", axis_id=1)
        reset = MC_Reset()
        rt.program = lambda plc: reset(Axis=ax, Execute=True)

        def ended() -> bool:
            rt.step()
            return reset.Error or reset.Done

        wait_until(ended, T, "MC_Reset to end", interval=0.01)
        assert reset.Error and not reset.Done and reset.ErrorID in TIMEOUT_CODES, reset.ErrorID
    finally:
        rt.stop()


# ---- operator ---------------------------------------------------------------------------------
def test_operator_cannot_write_parameters(start_tls_nc: Callable[..., NcServerProcess],
                                          session_as: Callable[..., zenoh.Session]) -> None:
    nc = start_tls_nc()
    plc1 = session_as(nc.port, "plc1")
    eng1 = session_as(nc.port, "eng1")
    wait_until(lambda: request(plc1, "Info", None, "plc1"), T, "Info for plc1")
    write = {"ParameterNumber": 1003, "Value": 100.0}
    assert request(plc1, "WriteParameter", 1, "plc1", **write) == []  # the eng key: denied by the router
    r = query(plc1, K.axis_cmd(1, "op", "plc1"), {"id": 1, "cmd": "WriteParameter", **write})
    assert r[0]["error"] == 0x723 and "class 'eng'" in r[0]["text"]  # its op key: refused by the NC
    assert request(plc1, "ReadParameter", 1, "plc1", ParameterNumber=1003)[0]["Value"] == 500.0
    # but it operates: claim works
    token = plc1.liveliness().declare_token(K.client_alive("plc1"))  # kept: dropping undeclares
    wait_claim(plc1, "plc1", 2)
    # an engineer writes
    assert request(eng1, "WriteParameter", 1, "eng1", **write)[0]["error"] == 0
    assert request(plc1, "ReadParameter", 1, "plc1", ParameterNumber=1003)[0]["Value"] == 100.0
    arb = info(eng1, "eng1")["arbitration"]
    assert arb["last_command"][1] == {"client": "eng1", "cmd": "WriteParameter", "cycle": arb["last_command"][1]["cycle"]}
    assert arb["claims"] == {2: "plc1"} and arb["clients"]["plc1"]["role"] == "operator"


# ---- identity: plc1 cannot be plc2 ----------------------------------------------------------------
def test_plc1_cannot_act_as_plc2(start_tls_nc: Callable[..., NcServerProcess],
                                 session_as: Callable[..., zenoh.Session]) -> None:
    nc = start_tls_nc()
    status = session_as(nc.port, "status")
    w = Watch(status, K.stats, K.axis_plctonc(1))
    plc2 = session_as(nc.port, "plc2")
    plc2_token = plc2.liveliness().declare_token(K.client_alive("plc2"))
    wait_claim(plc2, "plc2", 1)
    plc1 = session_as(nc.port, "plc1")
    plc1_token = plc1.liveliness().declare_token(K.client_alive("plc1"))  # kept: dropping undeclares
    wait_claim(plc1, "plc1", 2)

    # release plc2's claim: naming plc2 on its own key (NC: 0x723), or on plc2's key (router: no reply)
    r = query(plc1, K.axis_cmd(1, "op", "plc1"), {"id": 1, "cmd": "Release", "client": "plc2"})
    assert r[0]["error"] == 0x723 and "'plc2'" in r[0]["text"]
    assert query(plc1, K.axis_cmd(1, "op", "plc2"), {"id": 2, "cmd": "Release"}) == []
    r = request(plc1, "Release", 1, "plc1")
    assert r[0]["error"] == 0x723 and "held by client 'plc2'" in r[0]["text"]
    assert info(status, "status")["claims"] == {1: "plc2", 2: "plc1"}

    # read plc2's replies: a query on plc2's keys gets nothing (nor does plc2's cache fill)
    assert query(plc1, K.cmd("read", "plc2"), {"id": 3, "cmd": "Info"}) == []
    assert query(plc1, K.axis_cmd(1, "read", "plc2"), {"id": 4, "cmd": "ReadParameter", "ParameterNumber": 1003}) == []

    # send PLCTONC as plc2: dropped by the router. plc1's own frames after them are the barrier
    # (one session, one link: they arrive in order); plc1 holds axis 2, so they count as frames
    rec = np.zeros(1, dtype=PLCTONC_DTYPE)
    rec["ControlDWord"] = int(ControlDWord.Enable | ControlDWord.FeedEnablePlus | ControlDWord.FeedEnableMinus)
    rec["Override"] = 1_000_000
    forged = plc1.declare_publisher(K.plctonc_in("plc2"))
    own = plc1.declare_publisher(K.plctonc_in("plc1"))
    for k in range(20):
        forged.put(encode_plc_frame(k, [1], rec))
    for k in range(5):
        own.put(encode_plc_frame(k, [2], rec))
    stats = wait_until(lambda: (s := w.msg(K.stats)) and s["plctonc_frames"] >= 5 and s, T, "plc1's own frames")
    assert stats["plctonc_frames"] == 5 and stats["plctonc_malformed"] == 0, stats
    applied = wait_until(lambda: w.last.get(K.axis_plctonc(1)), T, "axis 1's applied PLCTONC")
    assert int(decode("PLCTONC_AXIS_REF", applied)["ControlDWord"]) == 0  # nobody enabled axis 1

    # keep plc2 alive with a token of its name: denied; when plc2's token goes, its claim goes
    fake_token = plc1.liveliness().declare_token(K.client_alive("plc2"))
    plc2_token.undeclare()
    wait_until(lambda: info(status, "status")["claims"] == {2: "plc1"}, T, "plc2's claim dropped with its token")
    arb = info(status, "status")["arbitration"]
    assert arb["clients"]["plc2"]["alive"] is False and arb["clients"]["plc1"]["alive"] is True
    del fake_token, plc1_token


# ---- behind nc-router ------------------------------------------------------------------------------
PROGRAM = '''
from plc_client import AXIS_REF, MC_Power
ax = AXIS_REF(nc="nc1", axis_id=1)
pw = MC_Power()
def cycle(plc):
    pw(Axis=ax, Enable=True, Enable_Positive=True, Enable_Negative=True)
'''


def test_through_the_router(start_tls_router: Callable[..., NcServerProcess],
                            start_tls_nc: Callable[..., NcServerProcess],
                            session_as: Callable[..., zenoh.Session], certs: Path, tmp_path: Path) -> None:
    router = start_tls_router()
    nc1 = start_tls_nc("nc1", connect=f"tls/127.0.0.1:{router.port}")
    nc2 = start_tls_nc("nc2", connect=f"tls/127.0.0.1:{router.port}")
    status = session_as(router.port, "status")
    w = Watch(status, K.axis_nctoplc(1), K.claims, K.stats, "nc/nc2/frame")
    wait_until(lambda: w.n["nc/nc2/frame"] and w.n[K.axis_nctoplc(1)], T, "both NCs' data through the router")
    # each NC's instance token through the router (the NC declares it, the observer may watch it)
    wait_until(lambda: instances(status, "nc1") == [nc1.instance()] and
               instances(status, "nc2") == [nc2.instance()], T, "both NCs' instance tokens through the router")

    # a plc-run as plc1 over TLS: claims, supplies PLCTONC, the axis closes its loop
    prog = tmp_path / "power.py"
    prog.write_text(PROGRAM)
    plc = subprocess.Popen([sys.executable, "-m", "plc_client.cli", str(prog), "--client-id", "plc1",
                            "--nc", f"nc1=tls/127.0.0.1:{router.port}", "--tls-dir", str(certs)],
                           stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                           start_new_session=True)
    try:
        def enabled() -> bool:
            b = w.last.get(K.axis_nctoplc(1))
            return b is not None and bool(struct.unpack_from("<I", b, 0)[0] & BIT_CONTROL_LOOP_CLOSED)
        wait_until(enabled, 60, "axis 1 of nc1 enabled by plc-run as plc1")
        wait_until(lambda: (m := w.msg(K.claims)) and m["claims"] == {1: "plc1"}, T, "the claim in nc/nc1/claims")

        # an NC cannot serve another NC's keys: nc2's certificate may not declare nc1's queryable,
        # nor read the PLCTONC sent to nc1
        fake = session_as(router.port, "nc2")
        spy = Watch(fake, K.plctonc_in_any)
        answer = lambda q: q.reply(q.key_expr, msgpack.packb({"fake": True}))  # noqa: E731
        fake_q = fake.declare_queryable("nc/nc1/**", answer)
        # control, declared after them on the same link: its own prefix is allowed, so once the
        # observer's query there gets the fake's answer too, the router has processed the two above
        control = fake.declare_queryable("nc/nc2/axis/99/cmd/read/status", answer)
        wait_until(lambda: len(query(status, "nc/nc2/axis/99/cmd/read/status", {"id": 1, "cmd": "Info"})) == 2, T,
                   "the fake nc2 queryable on its own prefix (and nc2's 0x4012)")
        replies = request(status, "Info", None, "status")
        assert len(replies) == 1 and replies[0]["Value"]["name"] == "nc1", replies
        control.undeclare()
        assert info(status, "status")["claims"] == {1: "plc1"}
        frames0 = wait_until(lambda: (m := w.msg(K.stats)) and m["plctonc_frames"], T, "PLCTONC frames at nc1")
        wait_until(lambda: w.msg(K.stats)["plctonc_frames"] > frames0 + 20, T, "more of plc1's frames at nc1")
        assert spy.n[K.plctonc_in_any] == 0
        fake_q.undeclare()
        # the observer still cannot command through the router
        assert request(status, "Reset", 1, "status") == []
        assert plc.poll() is None, plc.stderr.read() if plc.stderr else ""
    finally:
        plc.terminate()
        try:
            plc.wait(30)
        except subprocess.TimeoutExpired:
            plc.kill()
    wait_until(lambda: (m := w.msg(K.claims)) and m["claims"] == {}, T, "plc-run released its claim at exit")


def test_nc_status_reads_a_secured_nc_as_the_observer(start_tls_nc: Callable[..., NcServerProcess],
                                                      certs: Path) -> None:
    """The observer's own tool over mutual TLS: ``nc-status --tls-dir DIR --client-id status``."""
    import json as _json
    import os
    import subprocess
    import sys

    nc = start_tls_nc()
    cmd = [sys.executable, "-m", "nc_tools.status", "--connect", f"tls/127.0.0.1:{nc.port}", "--tls-dir", str(certs),
           "--client-id", "status", "--once", "--json", "--timeout", "20"]

    def snapshot() -> dict[str, Any] | None:
        p = subprocess.run(cmd, capture_output=True, text=True, timeout=120, env=dict(os.environ, PYTHONUNBUFFERED="1"))
        if p.returncode != 0:
            return None
        return _json.loads(p.stdout)

    doc = wait_until(snapshot, T * 2, "nc-status --once over TLS")
    assert "nc1" in _json.dumps(doc)
