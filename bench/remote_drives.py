"""The cost of a remote drive per NC cycle, and the age of its inputs (issue 20; a bench figure, not a test).

One process plays the NC: a zenoh router session (as nc-server's) and the drives of N axes stepped by a 1 kHz loop
(sleep to the deadline, SCHED_OTHER: what nc-server does without realtime); two ``nc-drive-sim`` processes serve
the remote axes. In one run, blocks of ``--block`` s alternate between the backends, so the ratios compare like
with like on a noisy machine:

* ``sim``        SimDrive (first-order lag in the NC process);
* ``cia402-sim`` Cia402SimDrive (the CiA 402 device in the NC process, LocalLink);
* ``remote``     RemoteDrive over zenoh to nc-drive-sim, sender thread (host d1);
* ``remote-cycle`` the same with ``sender = "cycle"`` (puts from the loop; host d2).

Per backend: ``drive.step()`` cost per cycle (p50/p99 us) and, for ``remote``, the inputs' age in NC cycles
(p50/p99/max) and the round trip NC outputs -> drive -> NC (cycles).

    PYTHONPATH=$PWD python bench/remote_drives.py --axes 4 --seconds 20
"""
from __future__ import annotations

import argparse
import json
import os
import signal
import socket
import subprocess
import sys
import time
from typing import Any

import numpy as np
import zenoh


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--axes", type=int, default=4)
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--block", type=float, default=2.0)
    args = ap.parse_args()

    from nc_server.core.params import AxisParams
    from nc_server.drives.base import DriveContext
    from nc_server.drives.cia402.sim import Cia402SimDrive
    from nc_server.drives.remote.drive import RemoteDrive
    from nc_server.drives.sim import SimDrive
    from nc_server.server.config import ZenohSettings

    n, dt = args.axes, 0.001
    port = _free_port()
    c = zenoh.Config()
    c.insert_json5("mode", '"router"')
    c.insert_json5("listen/endpoints", json.dumps([f"tcp/127.0.0.1:{port}"]))
    c.insert_json5("scouting/multicast/enabled", "false")
    c.insert_json5("scouting/gossip/enabled", "false")
    router = zenoh.open(c)
    params = [AxisParams() for _ in range(n)]
    hosts = [subprocess.Popen([sys.executable, "-m", "nc_server.drives.remote.host", "--host", h, "--axes", str(n),
                               "--connect", f"tcp/127.0.0.1:{port}", "--timeout", "1.0"], start_new_session=True,
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL) for h in ("d1", "d2")]
    zs = ZenohSettings(listen=(f"tcp/127.0.0.1:{port}",))
    drives: dict[str, Any] = {
        "sim": SimDrive(params, dt),
        "cia402-sim": Cia402SimDrive(params, dt),
        # the same backend with either sender, each with its own drive host
        "remote": RemoteDrive.from_config(params, dt, [{"host": "d1"}] * n, DriveContext("nc1", {"sender": "thread"}, zs)),
        "remote-cycle": RemoteDrive.from_config(params, dt, [{"host": "d2"}] * n,
                                                DriveContext("nc1", {"sender": "cycle"}, zs)),
    }
    remotes = {k: d for k, d in drives.items() if k.startswith("remote")}
    try:
        deadline = time.monotonic() + 30
        while not all(r.link.stats()["hosts"][h]["seen"] for r, h in zip(remotes.values(), ("d1", "d2"))) \
                and time.monotonic() < deadline:
            for r in remotes.values():
                r.step(np.zeros(n, bool), r.act_pos, np.zeros(n), np.zeros(n))
            time.sleep(dt)
        cost: dict[str, list[float]] = {k: [] for k in drives}
        ages: dict[str, list[int]] = {k: [] for k in remotes}
        rtt: dict[str, list[int]] = {k: [] for k in remotes}
        en = np.ones(n, bool)
        t0 = time.monotonic()
        k = 0
        names = list(drives)
        nxt = time.monotonic()
        while time.monotonic() - t0 < args.seconds:
            name = names[int((time.monotonic() - t0) / args.block) % len(names)]
            d = drives[name]
            k += 1
            pos = np.full(n, 10.0 * np.sin(k * dt))
            vel = np.full(n, 10.0 * np.cos(k * dt))
            a = time.perf_counter_ns()
            d.step(en, pos, vel, np.zeros(n))
            b = time.perf_counter_ns()
            cost[name].append((b - a) / 1e3)
            for rn, r in remotes.items():  # every remote drive is stepped every cycle (its link stays alive)
                if rn != name:
                    r.step(en, pos, vel, np.zeros(n))
                ages[rn].append(int(r.link._tx.age.max()))
                rtt[rn].append(int(r.link.round_trip.max()))
            nxt += dt
            s = nxt - time.monotonic()
            if s > 0:
                time.sleep(s)
        print(f"{n} axes, {args.seconds:g} s, blocks of {args.block:g} s; load {os.getloadavg()[0]:.1f}")
        base = float(np.percentile(cost["sim"], 50))
        for name, v in cost.items():
            x = np.array(v)
            print(f"  {name:11s} step p50 {np.percentile(x, 50):7.1f} us  p99 {np.percentile(x, 99):7.1f} us  "
                  f"({np.percentile(x, 50) / base:4.1f} x sim)")
        for rn, r in remotes.items():
            ag, rt = np.array(ages[rn]), np.array(rtt[rn])
            rt = rt[rt >= 0]
            print(f"  {rn:12s} inputs age [cycles] p50 {np.percentile(ag, 50):.0f} p99 {np.percentile(ag, 99):.0f} "
                  f"max {ag.max()}; round trip [cycles] p50 {np.percentile(rt, 50):.0f} p99 "
                  f"{np.percentile(rt, 99):.0f} max {rt.max()}; sent {r.link.sent}, received {r.link.received}")
    finally:
        for d in drives.values():
            d.close()
        for h in hosts:
            os.killpg(h.pid, signal.SIGTERM)
            h.wait(10)
        router.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
