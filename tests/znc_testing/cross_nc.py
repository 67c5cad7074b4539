"""Two NCs coupled across zenoh (docs/coupling-across-ncs.md): nc1 (the master's, axes 1 and 2) and nc2 (the
slave's) as real ``nc-server`` processes on 127.0.0.1, nc2's router connected to nc1's, test clients holding the
axes, and every frame of both NCs recorded for an offline check of the phase error. Used by
tests/integration/test_cross_nc_coupling.py and bench/cross_nc_phase.py.

May import: the project's packages, numpy, zenoh and :mod:`znc_testing.nc_process` / :mod:`znc_testing.until`.
"""
from __future__ import annotations

import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import zenoh

from nc_schema import (FRAME_HEADER_DTYPE, FRAME_HEADER_SIZE, NCJOBS_DTYPE, NCTOPLC_DTYPE, ErrorCodes as E,
                       frame_header)
from znc_testing.nc_process import NcServerProcess, NcTestClient, start_nc_server
from znc_testing.until import wait_until

#: both NCs announce a 3 s lease (the default 0.5 s: a 0.5 s stall of either NC or of the test's clients on a loaded
#: machine made the other side drop its session: nc2 lost nc1's samples, 0x42A0; the NC lost a client's token, 0x8F01)
NC1 = """
[nc]
name = "nc1"
watchdog_timeout = 10.0
publisher = "thread"

[zenoh]
lease = 3000

[[axis]]
AxisId = 1
Name = "M"
AxisVeloMax = 500.0
AxisAcc = 5000.0
AxisDec = 5000.0
AxisJerk = 50000.0

[[axis]]
AxisId = 2
Name = "L"
AxisVeloMax = 500.0
AxisAcc = 5000.0
AxisDec = 5000.0
AxisJerk = 50000.0
"""
NC2 = """
[nc]
name = "nc2"
watchdog_timeout = 10.0
publisher = "thread"

[zenoh]
connect = ["tcp/127.0.0.1:{port}"]
lease = 3000

[remote]
masters = ["nc1/1"]
max_age = {max_age}

[[axis]]
AxisId = 1
Name = "S"
AxisVeloMax = 500.0
AxisAcc = 5000.0
AxisDec = 5000.0
AxisJerk = 50000.0
"""
RATIO = 0.5
M_DYN = dict(Velocity=200.0, Acceleration=2000.0, Deceleration=2000.0, Jerk=20000.0)
#: a loaded 2-core machine: a master silent this long ends the coupling (the default is 50 ms)
MAX_AGE = 0.3


class Recorder:
    """Every frame of one NC, per axis a row: (Cycle, NcTimeNs - base, SetPos, SetVelo, SetAcc, SetJerk, AxisState,
    ErrorCode, PhaseError, PhaseBound, MasterAgeUs, CoupleState) (a float64 holds 1.7e18 ns only to 256 ns: hence
    the base)."""

    def __init__(self, session: zenoh.Session, nc: str, base: int) -> None:
        self.base = base
        self.frames: list[bytes] = []  # (kept raw: decoding 1000 frames a second per NC in the callback starved the
        #                                 test process on a loaded machine, its clients lost their leases)
        self.rows: dict[int, list[tuple[float, ...]]] = {}
        self._lock = threading.Lock()
        self.sub = session.declare_subscriber(f"nc/{nc}/frame", self._on)

    def _on(self, s: zenoh.Sample) -> None:
        self.frames.append(s.payload.to_bytes())  # (list.append: atomic under the GIL)

    def clear(self) -> None:
        """Forget the frames so far (the recording of interest starts now)."""
        with self._lock:
            self.frames = []
            self.rows = {}

    def _decode(self) -> None:
        """The raw frames into rows, vectorized per frame size (all frames of one NC have one size)."""
        with self._lock:
            frames, self.frames = self.frames, []
            by_size: dict[int, list[bytes]] = {}
            for data in frames:
                by_size.setdefault(len(data), []).append(data)
            for size, group in by_size.items():
                hdr0 = frame_header(group[0])
                n = hdr0.AxisCount
                dt = np.dtype([("hdr", FRAME_HEADER_DTYPE), ("pad", "u1", (hdr0.HeaderSize - FRAME_HEADER_SIZE,)),
                               ("recs", NCTOPLC_DTYPE, (n,)), ("jobs", NCJOBS_DTYPE, (n,))])
                if dt.itemsize != size:
                    continue  # (a frame without job records: not this NC's)
                a = np.frombuffer(b"".join(group), dtype=dt)
                c = a["hdr"]["Cycle"].astype(float)
                t = (a["hdr"]["NcTimeNs"].astype(np.int64) - self.base).astype(float)
                for k in range(n):
                    r, j = a["recs"][:, k], a["jobs"][:, k]
                    cols = np.column_stack((c, t, r["SetPos"], r["SetVelo"], r["SetAcc"], r["SetJerk"], r["AxisState"],
                                            r["ErrorCode"], j["PhaseError"], j["PhaseBound"], j["MasterAgeUs"],
                                            r["CoupleState"]))
                    self.rows.setdefault(int(r["AxisId"][0]), []).extend(map(tuple, cols.tolist()))

    def array(self, axis: int = 1) -> np.ndarray:
        """The frames of ``axis`` so far, by Cycle (columns as the class docstring says)."""
        self._decode()
        with self._lock:
            rows = sorted(set(self.rows.get(axis, [])))
        return np.array(rows, dtype=float).reshape(-1, 12)

    def last(self, axis: int = 1) -> tuple[float, ...] | None:
        self._decode()
        with self._lock:
            rows = self.rows.get(axis)
            return rows[-1] if rows else None


class Pair:
    """nc1 and nc2 running, axis 1 of each (and nc1's axis 2) claimed and enabled by test clients, both NCs'
    frames recorded. ``close()`` kills both process groups, also after a failure."""

    def __init__(self, tmp_path: Path, max_age: float = MAX_AGE) -> None:
        self.nc1: NcServerProcess | None = None
        self.nc2: NcServerProcess | None = None
        self.clients: list[NcTestClient] = []
        try:
            # (generous: on the loaded shared machine a start took 20-60 s, nc2 connecting to nc1 the longer)
            self.nc1 = start_nc_server(tmp_path / "nc1", NC1, name="nc1", ready_timeout=180)
            self.nc2 = start_nc_server(tmp_path / "nc2", NC2.format(port=self.nc1.port, max_age=max_age), name="nc2",
                                       ready_timeout=180)
            self.c1 = NcTestClient(self.nc1.port, client_id="m1", nc="nc1", lease_ms=5000)
            self.clients.append(self.c1)
            self.c2 = NcTestClient(self.nc2.port, client_id="s1", nc="nc2", lease_ms=5000)
            self.clients.append(self.c2)
            base = time.time_ns()
            self.r1 = Recorder(self.c1.session, "nc1", base)
            self.r2 = Recorder(self.c2.session, "nc2", base)
            for cl, axes in ((self.c1, [1, 2]), (self.c2, [1])):
                for a in axes:
                    cl.claim(a)
                cl.feed_plctonc(axes)
                for a in axes:
                    wait_until(lambda cl=cl, a=a: (r := cl.nctoplc(a)) is not None and int(r["StateDWord"]) & (1 << 20),
                               60, f"{cl.nc} axis {a} enabled")
        except BaseException:
            self.close()
            raise

    def close(self) -> None:
        for cl in self.clients:
            try:
                cl.close()
            except Exception:
                pass
        for p in (self.nc2, self.nc1):
            if p is not None:
                p.kill()


def gear_in(p: Pair, **args: Any) -> dict[str, Any]:
    """GearIn of nc2's axis 1 to nc1's axis 1 at RATIO; retried while nc2 has no sample of nc1's yet (0x4012
    "no sample": nc2's subscription reaches nc1 some time after both started)."""
    out: dict[str, Any] = {}

    def attempt() -> bool:
        out.clear()
        out.update(p.c2.request("GearIn", 1, timeout=30.0, Master=1, MasterNc="nc1", RatioNumerator=1,
                                RatioDenominator=2, **args))
        return not (out["error"] == E.NC_AXIS_ID_NOT_ALLOWED and "no sample" in out.get("text", ""))

    wait_until(attempt, 60, "nc2 receives nc1's samples")
    return out


def moves(p: Pair, targets: tuple[float, ...] = (40.0, 0.0, 40.0)) -> None:
    """nc1's axis 1 moves to each target in turn (M_DYN: jerk-limited), each awaited at rest."""
    for target in targets:
        rep = p.c1.request("MoveAbsolute", 1, timeout=30.0, Position=target, **M_DYN)
        assert rep["error"] == 0, rep
        wait_until(lambda t=target: (r := p.c1.nctoplc(1)) is not None and abs(float(r["SetPos"]) - t) < 1e-9
                   and abs(float(r["SetVelo"])) < 1e-12, 60, f"master at {target}")


def master_at(m: np.ndarray, t: float) -> float:
    """nc1's SetPos at NcTimeNs ``t`` (less the base) from its frame at or before ``t`` (Taylor with SetJerk: exact
    within a constant-jerk segment)."""
    k = int(np.searchsorted(m[:, 1], t, side="right")) - 1
    tau = (t - m[k, 1]) * 1e-9
    return float(m[k, 2] + tau * (m[k, 3] + tau * (m[k, 4] / 2 + tau * m[k, 5] / 6)))


def recorded_around(m: np.ndarray, s: np.ndarray) -> np.ndarray:
    """Per slave row of ``s``: whether the recording ``m`` holds every master frame (consecutive Cycles) from the
    one at or before t - MasterAgeUs - 1 ms to the first at or after t + 1 ms. Only there is :func:`master_at`
    exact and the span's largest jerk known: a frame the recorder did not get (a subscriber that was late, an NC
    that skipped publishing) may be the one where the master's jerk came on, and the reference taken from the
    frame before it was off by J x tau^3 / 6 (8e-9 u seen at "rest" in a CI run)."""
    times, cycles = m[:, 1], m[:, 0]
    t, age = s[:, 1], s[:, 10] * 1000.0
    k0 = np.searchsorted(times, t - age - 1e6, side="right") - 1
    k1 = np.searchsorted(times, t + 1e6, side="left")
    ok = (k0 >= 0) & (k1 < len(m))
    k0c, k1c = np.clip(k0, 0, len(m) - 1), np.clip(k1, 0, len(m) - 1)
    return ok & (cycles[k1c] - cycles[k0c] == k1c - k0c)


def phase_errors(m: np.ndarray, s: np.ndarray, ratio: float, s0: float = 0.0, m0: float = 0.0
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per slave row of ``s`` (SYNCHRON, within ``m``'s time span, :func:`recorded_around`): the phase error slave SetPos - s0 - ratio x
    (master SetPos at its NcTimeNs - m0), the bound |ratio| x J x tau^3 / 6 (tau its MasterAgeUs, J the largest
    |SetJerk| of ``m`` from tau (+1 ms) before to 1 ms after), and the error holding the newest sample instead of
    extrapolating (ratio x (master at t - tau - master at t): what the compensation removes)."""
    err, bound, held = [], [], []
    for row in s:
        t, sp, age = row[1], row[2], row[10] * 1000.0
        pm = master_at(m, t)
        span = m[(m[:, 1] >= t - age - 1e6) & (m[:, 1] <= t + 1e6)]
        jmax = float(np.abs(span[:, 5]).max()) if len(span) else 0.0
        err.append(sp - s0 - ratio * (pm - m0))
        bound.append(abs(ratio) * jmax * (age * 1e-9) ** 3 / 6)
        held.append(ratio * (master_at(m, t - age) - pm))
    return np.array(err), np.array(bound), np.array(held)
