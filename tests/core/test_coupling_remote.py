"""Coupling across NCs in the pure core (nc_server/core/remote.py, stages/coupling.py): a slave core follows a
master core's samples handed in through NcCore.set_remote_samples, with a transport delay, and compensates it
by extrapolation; the phase error it reports is checked against an offline reconstruction and the
|ratio| x J x tau^3 / 6 bound; lost samples stop the slave with 0x42A0; bad input is refused and changes nothing.
"""
from __future__ import annotations

import collections
from typing import Any

import numpy as np
import pytest

from nc_schema import AxisState, CmdState, CoupleState, ErrorCodes as E, NcJobsSyncFlags
from nc_server.core import MasterSample, NcCore
from znc_testing.nc_core import cmd, powered, snapshot

DT_NS = 1_000_000
T0 = 1_700_000_000_000_000_000
M_DYN = dict(Velocity=200.0, Acceleration=2000.0, Deceleration=2000.0, Jerk=20000.0)


def sample(core: NcCore, row: int = 0, nc: str = "nc1") -> MasterSample:
    r = core.nctoplc[row]
    return MasterSample(nc, int(r["AxisId"]), core.cycle, core.nc_time_ns, float(r["SetPos"]), float(r["SetVelo"]),
                        float(r["SetAcc"]), float(r["SetJerk"]), int(r["CoupleState"]))


class Pair:
    """A master core (nc1, 1 axis) and a slave core (nc2, 2 axes); the slave's cycle starts ``phase_ns`` after the
    master's and receives each master sample ``delay`` slave cycles after it was made."""

    def __init__(self, delay: int = 1, phase_ns: int = 300_000, max_age: float = 0.05) -> None:
        self.m = powered(1)
        self.s = powered(2)
        self.s.configure_remote("nc2", [("nc1", 1)], max_age)
        self.phase_ns = phase_ns
        self.delay = delay
        self.t = T0
        self.queue: collections.deque[tuple[int, MasterSample]] = collections.deque()
        self.master_frames: list[tuple[int, float, float, float, float]] = []
        self.slave_frames: list[tuple[int, float, int, float, float, float]] = []
        self.cut = False

    def step(self, n: int = 1) -> None:
        for _ in range(n):
            self.t += DT_NS
            self.m.step(self.t)
            r = self.m.nctoplc[0]
            self.master_frames.append((self.t, float(r["SetPos"]), float(r["SetVelo"]), float(r["SetAcc"]),
                                       float(r["SetJerk"])))
            if not self.cut:
                self.queue.append((self.s.cycle + self.delay, sample(self.m)))
            due = []
            while self.queue and self.queue[0][0] <= self.s.cycle:
                due.append(self.queue.popleft()[1])
            self.s.set_remote_samples(due)
            self.s.step(self.t + self.phase_ns)
            j = self.s.ncjobs[0]
            self.slave_frames.append((self.t + self.phase_ns, float(self.s.nctoplc[0]["SetPos"]),
                                      int(self.s.nctoplc[0]["AxisState"]), float(j["PhaseError"]),
                                      float(j["PhaseBound"]), float(j["MasterAgeUs"])))

    def gear_in(self, **ratio: Any) -> dict[str, Any]:
        args = ratio or dict(RatioNumerator=1, RatioDenominator=2)
        cmd_name = "GearInFloat" if "GearRatio" in args else "GearIn"
        return cmd(self.s, cmd_name, 1, Master=1, MasterNc="nc1", **args)


def master_at(frames: list[tuple[int, float, float, float, float]], t: int) -> tuple[float, float]:
    """Offline: the master's SetPos at ``t`` from the frame at or before it (Taylor with its jerk)."""
    ts = np.array([f[0] for f in frames])
    k = int(np.searchsorted(ts, t, side="right")) - 1
    t0, p, v, a, j = frames[k]
    tau = (t - t0) * 1e-9
    return p + v * tau + a * tau ** 2 / 2 + j * tau ** 3 / 6, t0


def test_slave_follows_a_jerk_limited_master_within_the_bound() -> None:
    pr = Pair(delay=2)
    pr.step(5)
    rep = pr.gear_in()
    assert rep["error"] == 0, rep
    pr.step(2)
    s = pr.s.nctoplc[0]
    assert int(s["CoupleState"]) == int(CoupleState.SLAVE) and int(s["AxisState"]) == int(AxisState.SLAVE_SYNCHRON)
    job = pr.s.ncjobs[0]
    assert int(job["MasterId"]) == 1 and int(job["SyncFlags"]) & int(NcJobsSyncFlags.RemoteMaster)
    start_s, start_m = float(s["SetPos"]), float(pr.m.nctoplc[0]["SetPos"])
    first = len(pr.slave_frames)
    assert cmd(pr.m, "MoveAbsolute", 1, Position=40.0, **M_DYN)["error"] == 0
    pr.step(600)
    assert abs(float(pr.m.nctoplc[0]["SetPos"]) - 40.0) < 1e-9
    errs, bounds = [], []
    for t_s, sp, st, *_ in pr.slave_frames[first:]:
        pm, _ = master_at(pr.master_frames, t_s)
        errs.append(sp - start_s - 0.5 * (pm - start_m))
    errs_a = np.abs(np.array(errs))
    # the extrapolation from samples 2 cycles old (+0.3 ms phase): tau about 2.3 ms; J = 20000
    bound = 0.5 * 20000 * (0.0023 + 1e-6) ** 3 / 6
    assert errs_a.max() <= bound * (1 + 1e-6) + 1e-12, (errs_a.max(), bound)
    assert errs_a.max() > 0  # (the extrapolation does err while the jerk is on)
    # the core's own measurement agrees with the offline one, and is within its bound
    st = pr.s.coupling.remote_stats(pr.s.axis_ids)[1]
    assert st["master"] == "nc1/1" and st["measured"] > 500 and st["within"] == st["measured"]
    assert abs(st["phase_err_max"] - errs_a.max()) <= 1e-9
    assert 2000 <= st["age_us"] <= 2600
    # at the end: the slave stands at start + ratio x travel
    assert abs(float(pr.s.nctoplc[0]["SetPos"]) - (start_s + 0.5 * (40.0 - start_m))) < 1e-9


def test_moving_master_synchronizes_first_then_locks() -> None:
    pr = Pair(delay=1)
    pr.step(3)
    assert cmd(pr.m, "MoveVelocity", 1, Velocity=50.0, Acceleration=2000.0, Deceleration=2000.0, Jerk=20000.0,
               Direction=1)["error"] == 0
    pr.step(200)
    assert pr.gear_in(GearRatio=2.0)["error"] == 0
    pr.step(1)
    assert int(pr.s.nctoplc[0]["AxisState"]) == int(AxisState.SLAVE_SYNCHRONIZING)
    pr.step(300)
    s = pr.s.nctoplc[0]
    assert int(s["AxisState"]) == int(AxisState.SLAVE_SYNCHRON)
    assert abs(float(s["SetVelo"]) - 100.0) < 1e-6


def test_lost_master_stops_the_slave_with_0x42A0() -> None:
    pr = Pair(delay=1, max_age=0.02)
    pr.step(3)
    assert pr.gear_in(RatioNumerator=1, RatioDenominator=1)["error"] == 0
    assert cmd(pr.m, "MoveVelocity", 1, Velocity=100.0, Acceleration=2000.0, Deceleration=2000.0, Jerk=20000.0,
               Direction=1)["error"] == 0
    pr.step(300)
    assert abs(float(pr.s.nctoplc[0]["SetVelo"]) - 100.0) < 1e-6
    pr.cut = True
    pr.queue.clear()
    pr.step(17)
    assert int(pr.s.nctoplc[0]["ErrorCode"]) == 0  # (within max_age: extrapolated)
    pr.step(4)
    s, job = pr.s.nctoplc[0], pr.s.ncjobs[0]
    assert int(s["ErrorCode"]) == int(E.NC_CONSEQUENTIAL_ERROR)
    assert int(job["ActiveState"]) == int(CmdState.ERROR) or any(
        int(e["ErrorId"]) == int(E.NC_CONSEQUENTIAL_ERROR) for e in job["Ended"])
    assert int(s["CoupleState"]) == int(CoupleState.SINGLE)
    prev_v = float(s["SetVelo"])
    assert prev_v > 90.0  # (no velocity jump: the ramp starts where the slave was)
    for _ in range(400):
        pr.step(1)
        v = float(pr.s.nctoplc[0]["SetVelo"])
        assert v <= prev_v + 1e-9 and abs(v - prev_v) <= 5000 * 0.001 + 1e-9
        prev_v = v
    assert abs(prev_v) < 1e-9


@pytest.mark.parametrize("args, code", [
    (dict(Master=7, MasterNc="nc1", RatioNumerator=1, RatioDenominator=1), E.NC_AXIS_ID_NOT_ALLOWED),
    (dict(Master=1, MasterNc="nc9", RatioNumerator=1, RatioDenominator=1), E.NC_AXIS_ID_NOT_ALLOWED),
    (dict(Master=1, MasterNc="nc2", RatioNumerator=1, RatioDenominator=1), E.MC_PARAMETER_NOT_CORRECT),
])
def test_bad_remote_masters_are_refused(args: dict[str, Any], code: int) -> None:
    pr = Pair()
    pr.step(3)
    before = snapshot(pr.s)
    rep = cmd(pr.s, "GearIn", 1, **args)
    assert rep["error"] == code, rep
    assert snapshot(pr.s) == before


def test_silent_master_slave_master_and_dyn_are_refused() -> None:
    pr = Pair()
    pr.cut = True
    pr.step(3)
    rep = pr.gear_in()
    assert rep["error"] == E.NC_AXIS_ID_NOT_ALLOWED and "no sample" in rep["text"]
    pr.cut = False
    # the master on nc1 is itself a slave (of its own axis 2): a chain across NCs is refused
    pr.m = powered(2)
    pr.step(1)
    assert cmd(pr.m, "GearIn", 1, Master=2, RatioNumerator=1, RatioDenominator=1)["error"] == 0
    pr.step(3)
    rep = pr.gear_in()
    assert rep["error"] == E.MC_PARAMETER_NOT_CORRECT and "itself a coupled slave" in rep["text"]
    rep = cmd(pr.s, "GearInDyn", 1, Master=1, MasterNc="nc1", GearRatio=1.0)
    assert rep["error"] == E.MC_PARAMETER_NOT_CORRECT


def test_gear_out_and_local_slave_of_a_remote_slave() -> None:
    pr = Pair()
    pr.step(3)
    assert pr.gear_in(RatioNumerator=1, RatioDenominator=1)["error"] == 0
    # axis 2 of nc2 follows axis 1 of nc2 (a local chain below the remote link)
    assert cmd(pr.s, "GearIn", 2, Master=1, RatioNumerator=2, RatioDenominator=1)["error"] == 0
    assert cmd(pr.m, "MoveAbsolute", 1, Position=10.0, **M_DYN)["error"] == 0
    pr.step(300)
    s1, s2 = float(pr.s.nctoplc[0]["SetPos"]), float(pr.s.nctoplc[1]["SetPos"])
    assert abs(s1 - 10.0) < 1e-9 and abs(s2 - 20.0) < 1e-9
    assert int(pr.s.nctoplc[0]["CoupleState"]) == int(CoupleState.MASTERSLAVE)
    assert cmd(pr.s, "GearOut", 1)["error"] == 0
    pr.step(2)
    assert int(pr.s.nctoplc[0]["CoupleState"]) == int(CoupleState.MASTER)
    assert int(pr.s.ncjobs[0]["MasterId"]) == 0


def test_prepare_and_activate_as_the_server_does() -> None:
    """The server's two steps (core.prepare between cycles, core.activate at the cycle start) for a remote master."""
    from nc_schema import make_request, parse_request

    pr = Pair()
    pr.step(3)
    req = parse_request(make_request("GearIn", 99, "test", Master=1, MasterNc="nc1", RatioNumerator=1,
                                     RatioDenominator=1))
    prep = pr.s.prepare(req, 1)
    assert not isinstance(prep, dict), prep
    rep = pr.s.activate(prep)
    assert rep is not None and rep["error"] == 0, rep
    pr.step(2)
    assert int(pr.s.nctoplc[0]["CoupleState"]) == int(CoupleState.SLAVE)


def test_a_master_sample_from_the_future_is_no_master() -> None:
    """Clocks seconds apart (the master's host ahead): its samples are refused as a master (0x4012) and, once
    coupled, the slave stops with 0x42A0 instead of extrapolating the master far away."""
    pr = Pair()
    pr.m.execute  # (the master stands)
    future = 5_000_000_000
    pr.t += DT_NS
    pr.m.step(pr.t + future)
    pr.s.set_remote_samples([sample(pr.m)])
    pr.s.step(pr.t)
    before = snapshot(pr.s)
    r = pr.gear_in()
    assert r["error"] == E.NC_AXIS_ID_NOT_ALLOWED and "future" in r["text"], r
    assert snapshot(pr.s) == before  # refused: nothing changed
    # coupled with a sane clock, then the master's clock jumps ahead
    pr2 = Pair()
    pr2.step(5)
    assert pr2.gear_in()["error"] == 0
    pr2.step(20)
    pr2.phase_ns -= future  # the slave's clock is now 5 s behind the master's
    pr2.step(5)
    s = pr2.s.nctoplc[0]
    assert int(s["ErrorCode"]) == E.NC_CONSEQUENTIAL_ERROR, hex(int(s["ErrorCode"]))
    assert abs(float(s["SetPos"])) < 1.0  # it did not jump


def test_a_remote_masters_samples_of_a_lower_epoch_are_dropped() -> None:
    """Protocol 5: the master's NC is a hot-standby pair; after a takeover (a higher epoch in the STAMP) the old
    active node's samples (its own plan, back after a link cut) are dropped and counted, not taken as the master's;
    a lower epoch is taken again once its NcTimeNs is EPOCH_HOLD_NS past the newest sample taken."""
    from nc_server.core.remote import EPOCH_HOLD_NS, RemoteMasters

    e1, e2 = (1 << 16) | 3, (2 << 16) | 4
    rm = RemoteMasters("nc2", [("nc1", 1)])

    def s(t: int, pos: float, epoch: int) -> MasterSample:
        return MasterSample("nc1", 1, t // DT_NS, t, pos, 0.0, 0.0, 0.0, 0, epoch)

    rm.feed([s(T0, 1.0, e1), s(T0 + DT_NS, 1.1, e1)])
    rm.feed([s(T0 + 2 * DT_NS, 1.2, e2)])  # the takeover: taken at once
    rm.feed([s(T0 + 3 * DT_NS, 50.0, e1), s(T0 + 3 * DT_NS + 1, 1.3, e2)])  # the old node's sample: dropped
    assert [p for _, p, *_ in rm.hist[0]] == [1.0, 1.1, 1.2, 1.3]
    assert rm.stale_epoch == 1 and rm.epoch[0] == e2 and rm.ignored == 0
    rm.feed([s(T0 + 3 * DT_NS + 1 + EPOCH_HOLD_NS, 2.0, 0)])  # the pair gone, an NC at epoch 0 in its place
    assert rm.hist[0][-1][1] == 2.0 and rm.epoch[0] == 0 and rm.stale_epoch == 1
