"""OPC UA through nc-opcua, next to raw zenoh, in one run: a method call until the NC accepted it, and a value's
age when an OPC UA subscription delivers it.

Topology: nc-server (default 4 axes, 1 ms) <- zenoh -> nc-opcua (its own process, ``--sampling-ms S``) <- OPC UA
(opc.tcp, no security) -> the asyncua client in this process, all on loopback. Measured in the same run:

  * raw zenoh RTT:        a client session in this process -> a router process with a trivial queryable
                          (bench/raw_zenoh.py), get + reply, one at a time;
  * zenoh command:        ``Reset`` of axis 2 sent by this process straight to the NC (the NC accepted it: reply);
  * OPC UA method call:   the ``Reset`` method of axis 2 (asyncua call -> nc-opcua -> zenoh -> NC -> back): the
                          command click -> NC acceptance of an HMI.

Value age: axis 1 moves endlessly (MoveVelocity through nc-opcua), so its NCTOPLC changes every cycle. The
asyncua client subscribes (publishing interval S ms) to ``nc1.1.NcToPlc.DcTimeStamp``, the low 32 bits of the NC
time of the frame (CLOCK_REALTIME at the cycle's scheduled start, ns); the notification's CLOCK_REALTIME minus
that is the age of the value when the HMI gets it (NC cycle -> frame/S ms -> zenoh -> nc-opcua's update every S
ms -> its subscription's publish -> TCP -> asyncua). The raw reference: a zenoh subscriber in this process on the
frames nc-opcua takes (``nc/nc1/frame/<S>ms``), receive time minus the frame's NcTimeNs. Same clock.

    .venv/bin/python bench/opcua_latency.py [--n 300] [--seconds 5] [--sampling-ms 100]

Figures only (no goal): the value age is dominated by the sampling interval by design.
"""
from __future__ import annotations

import argparse
import asyncio
import contextlib
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from bench.common import Busy, use_this_tree, verdict  # noqa: E402

use_this_tree()
from bench.raw_zenoh import RAW_KEY, raw_queryable  # noqa: E402
from znc_testing import NcTestClient, free_port, start_nc_server, zenoh_client_config  # noqa: E402


def fmt(name: str, xs: np.ndarray, unit: str = "us") -> str:
    if len(xs) == 0:
        return f"{name:>24}: no samples"
    p50, p99 = np.percentile(xs, (50, 99))
    return f"{name:>24}: p50 {p50:8.0f}  p99 {p99:8.0f}  max {xs.max():8.0f} {unit}  (n={len(xs)})"


def nc_time_of(low32: int, now_ns: int) -> int:
    """The full NC time [ns] whose low 32 bits are ``low32``, at most 2^32 ns (4.3 s) before ``now_ns``."""
    t = (now_ns & ~0xFFFFFFFF) | low32
    return t - (1 << 32) if t > now_ns else t


class _Ages:
    def __init__(self) -> None:
        self.ages: list[float] = []

    def datachange_notification(self, node: Any, val: Any, data: Any) -> None:
        now = time.time_ns()
        self.ages.append((now - nc_time_of(int(val), now)) / 1000.0)


async def opcua_part(url: str, n: int, seconds: float, sampling_ms: int) -> tuple[np.ndarray, np.ndarray]:
    from znc_testing.opcua_testing import call, client, ns, until, value
    from asyncua import ua
    async with client(url, "bench", "bench-pw") as c:
        idx = await ns(c)
        await until(lambda: _has(c, "nc1.2.ActPos"), 60, "axes served")
        calls = []
        for _ in range(n):
            t0 = time.perf_counter()
            st, out = await call(c, "nc1.2", "Reset")
            calls.append((time.perf_counter() - t0) * 1e6)
            assert st == 0, (hex(st), out)
        await call(c, "nc1.1", "Reset")
        assert (await call(c, "nc1.1", "Power", True, 100.0))[0] == 0
        await until(lambda: value(c, "nc1.1.Enabled"), 20, "axis 1 enabled")
        assert (await call(c, "nc1.1", "MoveVelocity", 5.0, 1))[0] == 0
        ages = _Ages()
        sub = await c.create_subscription(sampling_ms, ages)
        await sub.subscribe_data_change(c.get_node(ua.NodeId("nc1.1.NcToPlc.DcTimeStamp", idx)))
        await asyncio.sleep(seconds)
        await sub.delete()
        await call(c, "nc1.1", "Halt")
        await call(c, "nc1.1", "Power", False, 100.0)
        return np.array(calls), np.array(ages.ages[1:])  # (the first is the initial value, not a change)


async def _has(c: Any, node: str) -> bool:
    from znc_testing.opcua_testing import value
    try:
        await value(c, node)
        return True
    except Exception:
        return False


def zenoh_baselines(stack: contextlib.ExitStack, nc_port: int, n: int) -> tuple[list[float], list[float], NcTestClient]:
    """The same-run references of the doors' benches, ``n`` each, in us: a raw zenoh get + reply against a trivial
    queryable router (bench/raw_zenoh.py), and a Reset sent straight to the NC on ``nc_port`` until its reply; with the NC client used (closed by ``stack``)."""
    import zenoh

    raw_port = stack.enter_context(raw_queryable(free_port()))
    raw = zenoh.open(zenoh_client_config(raw_port))
    stack.callback(raw.close)
    rtt = []
    for _ in range(n):
        t0 = time.perf_counter()
        for r in raw.get(RAW_KEY, timeout=5.0):
            assert r.ok is not None
        rtt.append((time.perf_counter() - t0) * 1e6)
    cl = NcTestClient(nc_port, client_id="bench-z", token=False)
    stack.callback(cl.close)
    cmd = []
    for _ in range(n):
        t0 = time.perf_counter()
        assert cl.request("Reset", axis=2)["error"] == 0
        cmd.append((time.perf_counter() - t0) * 1e6)
    return rtt, cmd, cl


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=300, help="round trips per kind")
    ap.add_argument("--seconds", type=float, default=5.0, help="how long the value ages are collected")
    ap.add_argument("--sampling-ms", type=int, default=100, choices=(2, 5, 10, 20, 50, 100))
    a = ap.parse_args(argv)

    from nc_link.users import add_user
    from nc_schema import frame_header
    from znc_testing.opcua_testing import start_nc_opcua

    busy = Busy()
    with tempfile.TemporaryDirectory() as tmp_s, contextlib.ExitStack() as stack:
        tmp = Path(tmp_s)
        add_user(tmp / "users.toml", "bench", "operator", "bench-pw")
        nc = start_nc_server(tmp / "nc")
        stack.callback(nc.kill)
        ua_proc = start_nc_opcua(tmp, nc.endpoint, ["--users", str(tmp / "users.toml"), "--log-level", "WARNING",
                                                     "--sampling-ms", str(a.sampling_ms)])
        stack.callback(ua_proc.stop)
        rtt, cmd, cl = zenoh_baselines(stack, nc.port, a.n)
        frame_ages: list[float] = []
        lock = threading.Lock()

        def on_frame(s: Any) -> None:
            now = time.time_ns()
            h = frame_header(s.payload.to_bytes())
            with lock:
                frame_ages.append((now - h.NcTimeNs) / 1000.0)

        sub = cl.session.declare_subscriber(f"nc/nc1/frame/{a.sampling_ms}ms", on_frame)
        calls, ages = asyncio.run(asyncio.wait_for(opcua_part(ua_proc.url, a.n, a.seconds, a.sampling_ms), 600))
        sub.undeclare()
        print(f"opcua_latency: nc-opcua --sampling-ms {a.sampling_ms}, {a.n} round trips each, values for "
              f"{a.seconds:g} s")
        print(fmt("raw zenoh RTT", np.array(rtt)))
        print(fmt("zenoh command (Reset)", np.array(cmd)))
        print(fmt("OPC UA method (Reset)", calls))
        print(fmt("frame age at zenoh sub", np.array(frame_ages)))
        print(fmt("value age at OPC UA sub", ages))
    verdict("opcua_latency", [], busy.text())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
