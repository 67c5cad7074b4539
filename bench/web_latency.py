"""nc-web next to raw zenoh, in one run: a command until the NC accepted it, a value's age when the page's
WebSocket delivers it, and hold-to-run: how long after the page's last heartbeat the NC halts the jog.

Topology: nc-server (default 4 axes, 1 ms) <- zenoh -> nc-web (its own process, ``--frame-ms F``) <- HTTP /
WebSocket -> this process, all on loopback (no browser: its rendering is not measured). Measured in one run:

  * raw zenoh RTT:       a client session in this process -> a router process with a trivial queryable
                         (bench/raw_zenoh.py), get + reply, one at a time;
  * zenoh command:       ``Reset`` of axis 2 sent by this process straight to the NC (reply: accepted);
  * nc-web command:      ``POST /api/nc/nc1/axis/2/Reset`` (what the page's Reset button sends; HTTP keep-alive
                         off, as a click's fetch on a fresh connection) -> nc-web -> zenoh -> NC -> HTTP reply:
                         command click -> NC acceptance;
  * value age:           axis 1 moves endlessly; per WebSocket ``frame`` message, its receive time
                         (CLOCK_REALTIME) minus the NC time of the frame (the low 32 bits in DcTimeStamp): NC
                         cycle -> frame/F ms -> zenoh -> nc-web's push every F ms -> WebSocket. Beside it the
                         raw reference: a zenoh subscriber here on the same ``nc/nc1/frame/<F>ms``;
  * hold-to-run:         axis 3 jogged with heartbeats every 30 ms (the page's) over the WebSocket, then none: the time from
                         the last heartbeat until the NC's SetVelo of the axis drops (Halt accepted, braking),
                         seen by a zenoh subscriber here on its NCTOPLC. Goal: p99 <= 200 ms (issue 22).

    .venv/bin/python bench/web_latency.py [--n 200] [--seconds 5] [--frame-ms 50] [--jogs 10]
"""
from __future__ import annotations

import argparse
import contextlib
import http.client
import json
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from bench.common import Busy, mark, use_this_tree, verdict  # noqa: E402

use_this_tree()
from bench.opcua_latency import fmt, nc_time_of, zenoh_baselines  # noqa: E402
from znc_testing import start_nc_server, wait_until  # noqa: E402


def post_ms(port: int, cookie: str, path: str, body: dict[str, Any]) -> tuple[float, int]:
    """(round trip [us], status) of one POST on a fresh connection."""
    data = json.dumps(body).encode()
    t0 = time.perf_counter()
    c = http.client.HTTPConnection("127.0.0.1", port, timeout=30)
    c.request("POST", path, data, {"Content-Type": "application/json", "Cookie": cookie})
    r = c.getresponse()
    r.read()
    c.close()
    return (time.perf_counter() - t0) * 1e6, r.status


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=200, help="round trips per kind")
    ap.add_argument("--seconds", type=float, default=5.0, help="how long the value ages are collected")
    ap.add_argument("--frame-ms", type=int, default=50, choices=(2, 5, 10, 20, 50, 100))
    ap.add_argument("--jogs", type=int, default=10, help="hold-to-run trials")
    a = ap.parse_args(argv)
    from nc_link.users import add_user
    from nc_schema import NCTOPLC_DTYPE, frame_header
    from znc_testing.web_testing import login, post, start_nc_web, websocket

    busy = Busy()
    with tempfile.TemporaryDirectory() as tmp_s, contextlib.ExitStack() as stack:
        tmp = Path(tmp_s)
        add_user(tmp / "users.toml", "bench", "operator", "bench-pw")
        nc = start_nc_server(tmp / "nc")
        stack.callback(nc.kill)
        web = start_nc_web(tmp, nc.endpoint, ["--users", str(tmp / "users.toml"), "--log-level", "WARNING",
                                              "--frame-ms", str(a.frame_ms)])
        stack.callback(web.stop)
        rtt, cmd, cl = zenoh_baselines(stack, nc.port, a.n)

        cookie = login(web.url, "bench", "bench-pw")
        wait_until(lambda: post(web.url, cookie, "nc1", 2, "Reset")[0] == 200, 60, "nc-web serving nc1")
        clicks = []
        for _ in range(a.n):
            us, status = post_ms(web.port, cookie, "/api/nc/nc1/axis/2/Reset", {})
            assert status == 200, status
            clicks.append(us)

        # value ages: axis 1 moving endlessly
        frame_ages: list[float] = []
        lock = threading.Lock()

        def on_frame(s: Any) -> None:
            now = time.time_ns()
            h = frame_header(s.payload.to_bytes())
            with lock:
                frame_ages.append((now - h.NcTimeNs) / 1000.0)
        sub = cl.session.declare_subscriber(f"nc/nc1/frame/{a.frame_ms}ms", on_frame)
        ages: list[float] = []
        halts: list[float] = []
        with websocket(web.url, cookie) as ws:
            for axis in (1, 3):
                assert post(web.url, cookie, "nc1", axis, "Power", Enable=True, Override=100)[0] == 200
            wait_until(lambda: post(web.url, cookie, "nc1", 1, "MoveRelative", Distance=900.0, Velocity=5.0)[0]
                       == 200, 30, "axis 1 moving")
            end = time.monotonic() + a.seconds
            while time.monotonic() < end:
                m = json.loads(ws.recv(30))
                now = time.time_ns()
                if m["type"] == "frame" and m["axes"]:
                    ax1 = next(x for x in m["axes"] if x["AxisId"] == 1)
                    ages.append((now - nc_time_of(ax1["DcTimeStamp"], now)) / 1000.0)
            sub.undeclare()
            assert post(web.url, cookie, "nc1", 1, "Halt")[0] == 200

            # hold-to-run: heartbeats for 0.5 s, then none
            velo: list[tuple[float, float]] = []

            def on_rec(s: Any) -> None:
                rec = np.frombuffer(s.payload.to_bytes(), dtype=NCTOPLC_DTYPE, count=1)[0]
                velo.append((time.monotonic(), float(rec["SetVelo"])))
            vsub = cl.session.declare_subscriber("nc/nc1/axis/3/nctoplc", on_rec)
            jog = json.dumps({"type": "jog", "axis": 3, "direction": 1, "velocity": 20.0})
            for i in range(a.jogs):
                wait_until(lambda: velo and abs(velo[-1][1]) < 1e-9, 30, "axis 3 at rest")
                if i % 2:  # back and forth, inside the soft limits
                    jog = jog.replace('"direction": 1', '"direction": 3')
                else:
                    jog = jog.replace('"direction": 3', '"direction": 1')
                deadline = time.monotonic() + 10
                while not (velo and abs(velo[-1][1]) >= 19.99):  # heartbeats until at speed
                    assert time.monotonic() < deadline, "the jog never reached its speed"
                    ws.send(jog)
                    time.sleep(0.03)
                ws.send(jog)
                last = time.monotonic()
                wait_until(lambda: velo[-1][0] > last and abs(velo[-1][1]) < 19.99, 10, "the halt", interval=0.001)
                halts.append((next(t for t, v in velo if t > last and abs(v) < 19.99) - last) * 1e6)
            vsub.undeclare()
            for axis in (1, 3):
                post(web.url, cookie, "nc1", axis, "Power", Enable=False)
        print(f"web_latency: nc-web --frame-ms {a.frame_ms}, {a.n} round trips each, values for {a.seconds:g} s, "
              f"{a.jogs} hold-to-run stops (hold timeout 100 ms)")
        print(fmt("raw zenoh RTT", np.array(rtt)))
        print(fmt("zenoh command (Reset)", np.array(cmd)))
        print(fmt("nc-web POST (Reset)", np.array(clicks)))
        print(fmt("frame age at zenoh sub", np.array(frame_ages)))
        print(fmt("value age at WebSocket", np.array(ages)))
        print(fmt("halt after last beat", np.array(halts)))
        p99 = float(np.percentile(halts, 99)) / 1000 if halts else float("nan")
        ok = p99 == p99 and p99 <= 200.0
        goals = [(f"goal: hold-to-run: the NC halts the jog p99 {p99:.0f} ms after the page's last heartbeat "
                  f"(goal <= 200 ms) -> {mark(ok)}", ok)]
    verdict("web_latency", goals, busy.text())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
