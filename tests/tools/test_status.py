"""nc-status against a real NC: one snapshot as JSON and as a table, a faulted axis with its error
name, the holder of a claim, the cycle advancing; the decimated ``nc/<nc>/status`` key it reads."""
from __future__ import annotations

import json
from typing import Any

import zenoh

from znc_testing.tools_testing import T, Rig, run_tool
from nc_schema import FrameFlags, decode_frame, error_name
from znc_testing import NcTestClient, start_nc_server, wait_until, zenoh_client_config

NC_LOST = 0x8F01


def snapshot(rig: Rig, *extra: str) -> dict[str, Any]:
    p = run_tool("status", "--connect", rig.endpoint, "--once", "--json", *extra)
    assert p.returncode == 0, p.stderr
    lines = p.stdout.splitlines()
    assert len(lines) == 1, p.stdout
    return json.loads(lines[0])


def nc1(snap: dict[str, Any]) -> dict[str, Any]:
    [v] = [v for v in snap["ncs"] if v["name"] == "nc1"]
    return v


def test_once_json_and_table(rig: Rig) -> None:
    # axis 2: claimed by a client that goes away -> 0x8F01 on the axis, claim released
    t2 = NcTestClient(rig.srv.port, "t2")
    try:
        t2.claim(2)
        t2.feed_plctonc([2])
        wait_until(lambda: (s := rig.cl.nctoplc(2)) is not None and int(s["StateDWord"]) & (1 << 20), T, "axis 2 on")
    finally:
        t2.close()
    wait_until(lambda: int(rig.cl.nctoplc(2)["ErrorCode"]) == NC_LOST, T, "axis 2 faulted with 0x8F01")
    # axis 1: enabled by t1 and moving (a long move: it is still running when nc-status looks)
    rig.enable(1)
    r = rig.request("MoveAbsolute", axis=1, Position=900.0, Velocity=20.0)
    wait_until(lambda: float(rig.cl.nctoplc(1)["SetVelo"]) > 0, T, "axis 1 moving")

    first = nc1(snapshot(rig))
    assert first["state"] == "ALIVE" and first["alive"] is True
    assert first["cycle"] >= r["cycle"] and first["cycle_time"] == 0.001
    assert isinstance(first["missed_cycles"], int) and isinstance(first["overruns"], int)
    assert first["work_us_p99"] > 0 and first["timing"]
    assert "t1" in first["clients"]
    assert first["claims"].get("1") == "t1" and "2" not in first["claims"]
    axes = {a["AxisId"]: a for a in first["axes"]}
    assert sorted(axes) == [1, 2, 3, 4]
    a1, a2 = axes[1], axes[2]
    assert a1["MotionState"] == "MC_AXISSTATE_DISCRETEMOTION" and a1["Holder"] == "t1"
    assert a1["SetVelo"] > 0 and 0 < a1["SetPos"] < 900 and a1["ErrorCode"] == 0 and a1["ErrorName"] is None
    assert a2["MotionState"] == "MC_AXISSTATE_ERRORSTOP" and a2["Holder"] is None
    assert a2["ErrorCode"] == NC_LOST and a2["ErrorName"] == error_name(NC_LOST) != "0x8F01"
    assert axes[3]["MotionState"] == "MC_AXISSTATE_DISABLED"
    if first["claims_source"] == "claims":  # the NC publishes nc/<nc>/claims (protocol version 2)
        lc = a1["LastCommand"]
        assert lc["client"] == "t1" and lc["cmd"] == "MoveAbsolute" and lc["cycle"] >= r["cycle"]
    else:
        assert first["claims_source"] == "stats" and a1["LastCommand"] is None

    # the cycle advances between two snapshots (each its own process)
    second = nc1(snapshot(rig, "--nc", "nc1"))
    assert second["cycle"] > first["cycle"]
    assert {a["AxisId"]: a for a in second["axes"]}[1]["SetPos"] > a1["SetPos"]

    # the table
    p = run_tool("status", "--connect", rig.endpoint, "--once")
    assert p.returncode == 0, p.stderr
    lines = p.stdout.splitlines()
    assert lines[0].startswith("nc1  ALIVE  cycle ") and " 1.000 ms " in lines[0]
    row = {ln.split()[0]: ln for ln in lines if ln.strip()[:1].isdigit()}
    assert set(row) == {"1", "2", "3", "4"}
    assert "DISCRETEMOTION" in row["1"] and "t1" in row["1"]
    assert "ERRORSTOP" in row["2"] and f"0x{NC_LOST:04X} {error_name(NC_LOST)}" in row["2"]
    assert any(ln.strip().startswith("clients:") and "t1" in ln for ln in lines)
    rig.request("Halt", axis=1)


def test_once_reports_a_missing_nc(rig: Rig) -> None:
    p = run_tool("status", "--connect", rig.endpoint, "--once", "--json", "--nc", "nope", "--timeout", "3")
    assert p.returncode == 1 and "nope" in p.stderr
    assert json.loads(p.stdout)["ncs"] == []


def test_no_router_exits_2(rig: Rig) -> None:
    from znc_testing import free_port
    p = run_tool("status", "--connect", f"tcp/127.0.0.1:{free_port()}", "--once")
    assert p.returncode == 2 and "cannot connect" in p.stderr


def test_status_key_is_a_decimated_frame_with_the_final_shutdown(tmp_path) -> None:
    srv = start_nc_server(tmp_path)
    try:
        s = zenoh.open(zenoh_client_config(srv.port))
        got: list[bytes] = []
        sub = s.declare_subscriber("nc/nc1/status", lambda smp: got.append(smp.payload.to_bytes()))
        wait_until(lambda: len(got) >= 3, T, "three status samples")
        hdrs = [decode_frame(b)[0] for b in got[:3]]
        assert all(int(h["AxisCount"]) == 4 for h in hdrs)
        assert int(hdrs[0]["Cycle"]) < int(hdrs[1]["Cycle"]) < int(hdrs[2]["Cycle"])
        srv.stop()  # SIGTERM: the NC's last frame is flagged ShuttingDown, and goes out on the status key too
        wait_until(lambda: int(decode_frame(got[-1])[0]["Flags"]) & int(FrameFlags.ShuttingDown), T,
                   "a ShuttingDown status frame")
        sub.undeclare()
        s.close()
    finally:
        srv.kill()


def test_live_json_refreshes_until_sigint(rig: Rig) -> None:
    import signal
    import subprocess

    from znc_testing.tools_testing import JsonLines, kill_group, tool_command
    p = subprocess.Popen(tool_command("status", "--connect", rig.endpoint, "--json", "--interval", "0.2"),
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        assert p.stdout is not None
        docs = JsonLines(p.stdout)
        cycles: list[int] = []

        def two_docs_with_axes() -> bool:
            v = [n for n in docs.newest()["ncs"] if n["name"] == "nc1"]
            if v and v[0]["axes"]:
                cycles.append(v[0]["cycle"])
            return len(cycles) >= 2 and cycles[-1] > cycles[0]

        wait_until(two_docs_with_axes, T, "two refreshed snapshots with the cycle advancing")
        p.send_signal(signal.SIGINT)
        assert p.wait(T) == 0, p.stderr.read() if p.stderr else ""
    finally:
        kill_group(p)


def test_a_silent_tool_cannot_hold_a_wait_past_its_deadline() -> None:
    """The live-JSON tests wait for lines with a deadline: a blocking readline() inside wait_until (as
    they had) waited here for the writer's 60 s silence, whatever the deadline."""
    import subprocess
    import sys
    import time

    import pytest

    from znc_testing.tools_testing import JsonLines, kill_group
    p = subprocess.Popen([sys.executable, "-c", "import time; print('{\"a\": 1}', flush=True); time.sleep(60)"],
                         stdout=subprocess.PIPE, text=True, start_new_session=True)
    try:
        assert p.stdout is not None
        docs = JsonLines(p.stdout)
        assert docs.newest(T) == {"a": 1}
        t0 = time.monotonic()
        with pytest.raises(AssertionError, match="timed out after 1 s waiting for a second line"):
            wait_until(lambda: docs.newest(0.2), 1.0, "a second line")
        assert time.monotonic() - t0 < 10.0
    finally:
        kill_group(p)


def test_every_nc_on_a_router_and_one_going_away(tmp_path) -> None:
    import signal
    import subprocess

    from znc_testing.tools_testing import JsonLines, kill_group, tool_command
    from znc_testing import start_nc_router
    router = start_nc_router(tmp_path / "router")
    procs = [router]
    live = None
    try:
        procs.append(start_nc_server(tmp_path / "nc1", connect=router.endpoint))
        nc2 = start_nc_server(tmp_path / "nc2", extra_args=("--name", "nc2"), name="nc2", connect=router.endpoint)
        procs.append(nc2)
        # (a snapshot is one moment: on a loaded machine an NC's data may be a moment STALE; asked again until
        # the deadline, the last one's states shown on failure)
        def both_alive() -> bool:
            p = run_tool("status", "--connect", router.endpoint, "--once", "--json", "--nc", "nc1", "--nc", "nc2")
            assert p.returncode == 0, p.stderr
            snap = json.loads(p.stdout)
            assert [v["name"] for v in snap["ncs"]] == ["nc1", "nc2"]
            got = [(v["state"], len(v["axes"]), v.get("problems")) for v in snap["ncs"]]
            assert all(state == "ALIVE" and axes == 4 for state, axes, _ in got), got
            return True
        wait_until(both_alive, T, "both NCs ALIVE with 4 axes in a --once snapshot")
        # live: nc2 stops, the table shows it GONE (its last frame said ShuttingDown, its token went)
        live = subprocess.Popen(tool_command("status", "--connect", router.endpoint, "--json", "--interval", "0.2"),
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)
        assert live.stdout is not None
        docs = JsonLines(live.stdout)

        def states() -> dict[str, str]:
            return {v["name"]: v["state"] for v in docs.newest()["ncs"]}

        wait_until(lambda: states() == {"nc1": "ALIVE", "nc2": "ALIVE"}, T, "both NCs alive in the live view")
        nc2.stop()
        wait_until(lambda: states() == {"nc1": "ALIVE", "nc2": "GONE"}, T, "nc2 gone, nc1 alive")
        live.send_signal(signal.SIGINT)
        assert live.wait(T) == 0
    finally:
        if live is not None:
            kill_group(live)
        for h in reversed(procs):
            h.kill()


def test_restarts_count_new_nc_instances_not_a_token_that_comes_back(tmp_path) -> None:
    """The NC SIGSTOPped 1.5 s (lease 0.5 s): nc-status's link to it is dropped, the NC's tokens go
    (GONE) and come back (ALIVE) with the same instance id: no restart. A new nc-server on the same
    port: one restart, the new instance id shown."""
    import signal
    import subprocess
    import time

    from znc_testing.tools_testing import JsonLines, kill_group, tool_command
    from znc_testing import free_port
    port = free_port()
    listen = ("--listen", f"tcp/127.0.0.1:{port}")
    procs = [start_nc_server(tmp_path / "nc1", extra_args=listen)]
    first = procs[0].instance()
    live = subprocess.Popen(tool_command("status", "--connect", f"tcp/127.0.0.1:{port}", "--json", "--interval", "0.2"),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        assert live.stdout is not None
        docs = JsonLines(live.stdout)
        seen: list[tuple[str, str | None, int]] = []

        def view() -> tuple[str, str | None, int]:
            [v] = [v for v in docs.newest()["ncs"] if v["name"] == "nc1"]
            seen.append((v["state"], v["instance"], v["restarts"]))
            return seen[-1]

        wait_until(lambda: view() == ("ALIVE", first, 0), T, "nc1 alive, its instance shown")
        mark = len(docs.docs)
        procs[0].send_signal(signal.SIGSTOP)
        try:
            time.sleep(1.5)
        finally:
            procs[0].send_signal(signal.SIGCONT)

        def went() -> bool:  # any document since the stop (the newest may already show it back)
            return any(v["name"] == "nc1" and v["state"] == "GONE" for d in list(docs.docs)[mark:] for v in d["ncs"])

        wait_until(went, T, "nc1's token gone for nc-status (its link dropped)")
        wait_until(lambda: view() == ("ALIVE", first, 0), T, "the same nc1 alive again, no restart")
        for _ in range(5):
            assert view()[1:] == (first, 0), seen
        procs[0].kill()
        procs.append(start_nc_server(tmp_path / "nc1b", extra_args=listen))
        second = procs[1].instance()
        assert second != first
        wait_until(lambda: view() == ("ALIVE", second, 1), T, "the new nc1 instance: one restart")
        for _ in range(5):
            assert view()[1:] == (second, 1), seen
    finally:  # (no SIGINT: lines written while the new NC started may still fill the pipe)
        kill_group(live)
        for h in reversed(procs):
            h.kill()


def test_remote_coupling_line_from_the_stats() -> None:
    """A slave of a master on another NC (stats remote_couplings, protocol 4): its line in the table, offline."""
    import time as _time

    import msgpack

    from nc_tools.status import _Raw, nc_view, render

    st = {"cycle": 10, "cycle_time": 0.001, "remote_couplings": {1: {
        "master": "nc1/1", "state": 13, "ratio": 0.5, "age_us": 1830, "phase_err": 1.2e-6, "phase_err_max": 4e-5,
        "phase_bound": 1.3e-6, "measured": 900, "within": 899, "rms": 1e-6}}}
    now = _time.monotonic()
    v = nc_view("nc2", True, None, _Raw(msgpack.packb(st), now), None, now)
    assert v["remote_couplings"][0]["master"] == "nc1/1" and v["remote_couplings"][0]["AxisId"] == "1"
    text = render({"time": "t", "ncs": [v]})
    assert "remote coupling: axis 1 <- nc1/1 x 0.5" in text and "age 1830 us" in text and "899/900" in text
    bad = nc_view("nc2", True, None, _Raw(msgpack.packb({"remote_couplings": [1]}), now), None, now)
    assert "stats: remote_couplings is not a map" in bad["problems"]


def test_ha_line_shows_the_standby_and_its_replication_lag() -> None:
    """A hot-standby pair: the active NC's stats give role and epoch, the standby's own ha status its lag; a stale or
    the active's own ha status is not listed."""
    import time as _time

    import msgpack

    from nc_tools.status import STALE_AFTER, _Raw, nc_view, render

    now = _time.monotonic()
    st = {"cycle": 10, "cycle_time": 0.002, "ha": {"node": "a", "role": "active", "epoch": 65541, "peer_in_step": True,
                                                  "lag_cycles": 0, "takeovers": 0, "takeover_ms": 0.0, "demotions": 0}}
    nodes = [_Raw(msgpack.packb({"node": "a", "role": "active", "in_step": True, "lag_cycles": 0}), now),
             _Raw(msgpack.packb({"node": "b", "role": "standby", "in_step": True, "lag_cycles": 3}), now),
             _Raw(msgpack.packb({"node": "c", "role": "standby", "in_step": False, "lag_cycles": 9}),
                  now - STALE_AFTER - 1)]
    v = nc_view("nc1", True, None, _Raw(msgpack.packb(st), now), None, now, ha_nodes=nodes)
    assert v["ha"]["standbys"] == [{"node": "b", "role": "standby", "in_step": True, "lag_cycles": 3}]
    text = render({"time": "t", "ncs": [v]})
    assert "ha: active node a epoch 65541" in text and "standby b lag 3 cycles" in text and " c " not in text
    # a standby of other NC software says why it will not get in step (docs/standby.md, One software version)
    why = "the active NC runs NC software 111111111111, this standby 222222222222: not in step"
    nodes[1] = _Raw(msgpack.packb({"node": "b", "role": "standby", "in_step": False, "lag_cycles": 0,
                                   "refused": why}), now)
    v = nc_view("nc1", True, None, _Raw(msgpack.packb(st), now), None, now, ha_nodes=nodes)
    assert f"standby b lag 0 cycles (not in step) REFUSED: {why}" in render({"time": "t", "ncs": [v]})


def test_the_status_frames_epoch_is_shown_and_a_lower_epoch_is_dropped() -> None:
    """Protocol 5: nc-status shows the Epoch of the NC's status frames; after a takeover a status frame of the old
    active NC (a lower epoch) is not shown (the newest of the followed epoch stays), and the drops are counted."""
    from types import SimpleNamespace

    import numpy as np

    from nc_schema import NCTOPLC_DTYPE, encode_frame
    from nc_tools.status import NcWatch, render

    w = NcWatch(session=None)  # type: ignore[arg-type]  # (only the callbacks are used)
    on_status = w._on_data("status")

    def put(cycle: int, epoch: int, set_pos: float) -> None:
        recs = np.zeros(1, dtype=NCTOPLC_DTYPE)
        recs["AxisId"], recs["SetPos"] = 1, set_pos
        data = encode_frame(cycle, cycle * 1000, recs, epoch=epoch)
        on_status(SimpleNamespace(key_expr="nc/nc1/status", payload=SimpleNamespace(to_bytes=lambda: data)))

    e1, e2 = (1 << 16) | 7, (2 << 16) | 9
    put(100, e1, 1.0)
    put(160, e2, 2.0)  # the standby took over
    put(90, e1, 99.0)  # the old active NC after a link cut: dropped
    [v] = w.snapshot()["ncs"]
    assert (v["epoch"], v["cycle"], v["stale_epoch_frames"], v["restarts"]) == (e2, 160, 1, 0)
    assert v["axes"][0]["SetPos"] == 2.0
    assert f"epoch {e2} (1 frames of lower epochs dropped)" in render({"time": "t", "ncs": [v]})
    w2 = NcWatch(session=None)  # type: ignore[arg-type]
    w2._on_data("status")(SimpleNamespace(key_expr="nc/nc1/status", payload=SimpleNamespace(
        to_bytes=lambda: encode_frame(5, 5, np.zeros(0, dtype=NCTOPLC_DTYPE)))))
    [v2] = w2.snapshot()["ncs"]
    assert v2["epoch"] == 0 and "epoch 0" in render({"time": "t", "ncs": [v2]})
