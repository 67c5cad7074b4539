"""A hot-standby NC pair's test rig (docs/standby.md): its config, the observer of its set-points and frames, the
ha status and the SetPos-jump measure; shared by tests/drives/test_standby_process.py and bench/takeover.py."""
from __future__ import annotations

import threading
import time
from typing import Any

import msgpack
import numpy as np

from nc_link import NcLink
from nc_schema import NCTOPLC_DTYPE, decode_frame, decode_stamp_epoch, frame_header
from znc_testing.nc_process import NcTestClient

__all__ = ["AXIS2", "CONFIG", "LEASE_MS", "Trace", "active_node", "ha_status", "largest_step"]

#: the zenoh lease of every process of the rig (the router's --lease-ms, the drive host's --lease-ms, CONFIG's)
LEASE_MS = 3000

CONFIG = """
[nc]
name = "nc1"
cycle_time = {cycle}
watchdog_timeout = 5.0
realtime = "off"
publisher = "thread"

[zenoh]
mode = "client"
connect = ["tcp/127.0.0.1:{port}"]
# (LEASE_MS: a starved process's session is not dropped on a loaded machine, and a freeze is detected by the
# standby's loss detection, not by the session's lease; a kill drops the token at once whatever the lease)
lease = 3000

[redundancy]
enabled = true
takeover_cycles = {takeover}

[drives.remote]
max_age = 200

[[axis]]
AxisId = 1
Name = "X"
AxisVeloMax = 200.0
Drive = {{ backend = "remote", host = "drives1" }}
"""

#: a second axis on the same drive host (append to CONFIG: a coupling of two axes of the NC)
AXIS2 = """
[[axis]]
AxisId = 2
Name = "Y"
AxisVeloMax = 200.0
Drive = { backend = "remote", host = "drives1" }
"""


class Trace:
    """Every NCTOPLC sample of ``axes`` (cycle, SetPos, SetVelo, CmdNo, CmdState, monotonic time, the NC's epoch from
    the sample's stamp; :attr:`samples` is axis 1's, :attr:`by_axis` every axis's), and the NC's frames through
    nc_link (its NC-restart detection; "NC gone" events in :attr:`gone`; the newest NCJOBS record of each axis in
    :attr:`jobs`), gathered on the test's sessions.

    Both sessions announce the rig's lease (LEASE_MS): with nc_link's default (0.5 s) a stall of the test process
    itself (0.5 s seen on a loaded machine) let the router drop the observer's session, and the NC's tokens it had
    seen went with it: an "NC gone" that no NC caused."""

    def __init__(self, port: int, axes: tuple[int, ...] = (1,)) -> None:
        self.by_axis: dict[int, list[tuple[int, float, float, int, int, float, int]]] = {a: [] for a in axes}
        self.samples = self.by_axis.setdefault(1, [])
        self.jobs: dict[int, Any] = {}
        self.cl = NcTestClient(port, client_id="observer", token=False, lease_ms=LEASE_MS)
        self.subs = [self.cl.session.declare_subscriber(f"nc/nc1/axis/{a}/nctoplc",
                                                        lambda s, a=a: self._on(s, a)) for a in axes]
        self.link = NcLink("nc1", f"tcp/127.0.0.1:{port}", "observer-link", lease_ms=LEASE_MS, holder=False)
        self.link.open()
        self.restarts: list[str] = []
        #: when nc_link saw the NC's token go ("NC gone": the PLC runtime ends every block with 0x4B0F then)
        self.gone: list[float] = []
        self.frames = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _on(self, s: Any, axis: int) -> None:
        r = np.frombuffer(s.payload.to_bytes(), dtype=NCTOPLC_DTYPE, count=1)[0]
        cycle, _, epoch = decode_stamp_epoch(s.attachment.to_bytes()) if s.attachment is not None else (-1, 0, -1)
        self.by_axis[axis].append((cycle, float(r["SetPos"]), float(r["SetVelo"]), int(r["CmdNo"]), int(r["CmdState"]),
                                   time.monotonic(), epoch))

    def _run(self) -> None:
        while not self._stop.wait(0.002):
            f = self.link.take_frame()
            if f is not None:
                self.frames += 1
                try:
                    h = frame_header(f)
                except ValueError:
                    continue
                taken, why = self.link.follow_frame(h.Cycle, h.Epoch)  # (the clients' rule: protocol 5's epoch)
                if why:
                    self.restarts.append(why)
                if not taken:  # a frame of a lower epoch (the old active node's): counted by the link
                    continue
                try:
                    _, recs, jobs = decode_frame(bytes(f))
                    if jobs is not None:
                        for rec, job in zip(recs, jobs):
                            self.jobs[int(rec["AxisId"])] = job.copy()
                except ValueError:
                    pass
            for ev in self.link.take_events():
                if ev.kind == "restart":
                    self.restarts.append(ev.why)
                elif ev.kind == "gone":
                    self.gone.append(time.monotonic())

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2)
        self.link.close()
        self.cl.close()


def ha_status(cl: NcTestClient, node: str) -> dict[str, Any] | None:
    v = cl.latest(f"nc/nc1/ha/status/{node}")
    return None if v is None else msgpack.unpackb(v[0], raw=False)


def active_node(cl: NcTestClient, nodes: tuple[str, ...] = ("a", "b")) -> str | None:
    """The node whose fresh ha status says active while the others' say standby in step (None: not so now)."""
    st = {n: ha_status(cl, n) for n in nodes}
    if any(s is None or time.time() - s["time"] > 1.0 for s in st.values()):
        return None
    act = [n for n, s in st.items() if s is not None and s["role"] == "active"]
    if len(act) != 1 or not all(s is not None and s["in_step"] for s in st.values()):
        return None
    return act[0]


def largest_step(samples: list[tuple[int, float, float, int, int, float, int]], cycle: float, accel: float) -> float:
    """The largest |SetPos change| beyond what ``v`` (the larger of the two samples' SetVelo) and ``accel`` allow over
    the cycles between two samples (``cycle`` [s] each): a jump, not motion."""
    worst = 0.0
    for (c0, p0, v0, *_), (c1, p1, v1, *_) in zip(samples, samples[1:]):
        if c1 <= c0:
            continue
        t = (c1 - c0) * cycle
        worst = max(worst, abs(p1 - p0) - max(abs(v0), abs(v1)) * t - 0.5 * accel * t * t)
    return worst


def close_all(tr: Any, cl: Any, started: list[Any]) -> None:
    """A rig's teardown: the trace and the client closed (None: not made), the processes killed newest first."""
    if tr is not None:
        tr.close()
    if cl is not None:
        cl.close()
    for h in reversed(started):
        h.kill()
