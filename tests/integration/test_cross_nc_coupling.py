"""Coupling across NCs through real processes (docs/coupling-across-ncs.md): two ``nc-server`` processes on
127.0.0.1 (nc1 the master's, nc2 the slave's, connected router to router), test clients holding the axes and
sending the commands, and every frame of both NCs recorded and checked offline.

* phase: while InGear, at each slave frame, |slave SetPos - start - ratio x (nc1's SetPos at the same NcTimeNs,
  from nc1's frames) - offset| <= |ratio| x J x tau^3 / 6 (tau the slave's MasterAgeUs, J the largest
  |SetJerk| of nc1 over that span), asserted on two thirds of the cycles and the median one (a loaded machine
  misses cycles and delays samples: 78-100 % measured there), and the extrapolation's gain over holding the newest
  sample; the NC's own measurement in the job record and the stats agrees;
* refusals with their codes; the master's NC killed (SIGKILL): the slave stops on its ramp with 0x42A0.

No speed is asserted: the figures of a quiet machine are bench/cross_nc_phase.py's.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any, Iterator

import numpy as np
import pytest

from nc_schema import AxisState, ErrorCodes as E
from znc_testing import wait_until
from znc_testing.cross_nc import RATIO, Pair, gear_in, moves, phase_errors, recorded_around


@pytest.fixture
def pair(tmp_path: Path) -> Iterator[Pair]:
    p = Pair(tmp_path)
    try:
        yield p
    finally:
        p.close()


def test_phase_error_within_the_jerk_bound(pair: Pair) -> None:
    p = pair
    # bad input first: refused with its code, nothing changes
    for args, code in ((dict(MasterNc="nc9"), E.NC_AXIS_ID_NOT_ALLOWED), (dict(MasterNc="nc2"), E.MC_PARAMETER_NOT_CORRECT)):
        rep = p.c2.request("GearIn", 1, Master=1, RatioNumerator=1, RatioDenominator=1, **args)
        assert rep["error"] == code, rep
    rep = p.c2.request("GearIn", 1, Master=5, MasterNc="nc1", RatioNumerator=1, RatioDenominator=1)
    assert rep["error"] == E.NC_AXIS_ID_NOT_ALLOWED, rep
    rep = gear_in(p)
    assert rep["error"] == 0, rep
    wait_until(lambda: (r := p.c2.nctoplc(1)) is not None and int(r["AxisState"]) == int(AxisState.SLAVE_SYNCHRON),
               30, "slave SYNCHRON")
    p.r1.clear()
    p.r2.clear()
    # a loaded machine's publisher skips frames (and a slave sample counts only with every master frame around it):
    # the master moves on (0 -> 40 again, at most 8 times more) until 300 moving samples are usable (232 seen in CI,
    # 108 after three rounds under a load average of 60)
    for targets in ((40.0, 0.0, 40.0), *((0.0, 40.0),) * 8):
        moves(p, targets)
        wait_until(lambda: (r := p.c2.nctoplc(1)) is not None and abs(float(r["SetPos"]) - 20.0) < 1e-6, 60,
                   "slave at ratio x 40")
        m, s = p.r1.array(), p.r2.array()
        s = s[(s[:, 6] == int(AxisState.SLAVE_SYNCHRON)) & (s[:, 1] > m[0, 1] + 20e6) & (s[:, 1] < m[-1, 1])]
        s = s[recorded_around(m, s)]  # (where a master frame did not reach the recorder the reference is not exact)
        err, bound, held = phase_errors(m, s, RATIO)  # (both axes stood at 0 when coupled)
        moving = bound > 0  # (at rest the master's samples are exact: error 0, as checked below)
        if moving.sum() > 300:
            break
    assert moving.sum() > 300, moving.sum()
    # at rest the master's samples are exact; a jerk phase shorter than a cycle can fall between two master frames
    # (no frame shows its jerk: bound 0 while the master moves, error 9.6e-9 seen once in CI): there the bound
    # takes the master's largest jerk
    rest = np.array([not np.any(m[(m[:, 1] >= t - age * 1e3 - 1e6) & (m[:, 1] <= t + 1e6), 3])
                     for t, age in zip(s[:, 1], s[:, 10])], dtype=bool)
    assert np.abs(err[~moving & rest]).max(initial=0.0) <= 1e-9
    unseen = ~moving & ~rest
    jall = float(np.abs(m[:, 5]).max())
    assert (np.abs(err[unseen]) <= abs(RATIO) * jall * (s[unseen, 10] * 1e-6) ** 3 / 6 * 1.01 + 1e-9).all(), (
        err[unseen], s[unseen, 10])
    # where the master's jerk stays on over the span the error IS the bound; MasterAgeUs is whole us: 1 % slack
    within = np.abs(err) <= bound * 1.01 + 1e-9
    share = float(within[moving].mean())
    print(f"cross-NC phase: {int(moving.sum())} moving slave cycles, within the bound {share:.1%}, |err| max "
          f"{np.abs(err).max():.3g} u, tau p50 {np.median(s[moving, 10]):.0f} us")
    # a loaded machine (missed cycles make kinks, samples arrive tens of ms late: docs) keeps the bound on 78-100 %
    # of the cycles measured; asserted: two thirds, the median cycle within it, and the compensation's gain
    assert share >= 0.67, (share, np.abs(err).max())
    assert float(np.median(np.abs(err[moving]) / bound[moving])) <= 1.01
    assert np.median(np.abs(err[moving])) <= 0.1 * np.median(np.abs(held[moving])), "no gain over holding the sample"
    # the NC's own measurement in the job record and the stats
    stats: dict[str, Any] = {}
    wait_until(lambda: bool((st := p.c2.stats()) and st.get("remote_couplings") and stats.update(st) is None), 30,
               "nc2's stats")
    rc = stats["remote_couplings"][1]
    assert rc["master"] == "nc1/1" and rc["measured"] > 300 and rc["within"] >= 0.67 * rc["measured"], rc
    assert rc["phase_err_max"] >= float(np.abs(s[:, 8]).max()) - 1e-12 and rc["phase_err_max"] > 0


def test_master_killed_slave_stops_with_0x42A0(pair: Pair) -> None:
    p = pair
    rep = gear_in(p)
    assert rep["error"] == 0, rep
    assert p.c1.request("MoveVelocity", 1, Velocity=100.0, Acceleration=2000.0, Deceleration=2000.0, Jerk=20000.0,
                        Direction=1)["error"] == 0
    wait_until(lambda: (r := p.c2.nctoplc(1)) is not None and abs(float(r["SetVelo"]) - 50.0) < 1e-6, 30,
               "slave at ratio x master velocity")
    assert p.nc1 is not None and p.nc2 is not None
    p.nc1.kill()
    wait_until(lambda: (r := p.c2.nctoplc(1)) is not None and int(r["ErrorCode"]) == E.NC_CONSEQUENTIAL_ERROR, 60,
               "slave error 0x42A0")
    wait_until(lambda: (r := p.c2.nctoplc(1)) is not None and abs(float(r["SetVelo"])) < 1e-9, 60, "slave stopped")
    s = p.r2.array()
    lost = int(np.argmax(s[:, 7] == E.NC_CONSEQUENTIAL_ERROR))
    run = s[max(0, lost - 400):]
    dv = np.abs(np.diff(run[:, 3]) / np.maximum(np.diff(run[:, 0]), 1))
    assert dv.max() <= 5000.0 * 0.001 * 1.01, dv.max()  # no velocity step: at most AxisDec per cycle
    assert int(s[-1, 11]) == 0  # decoupled (CoupleState SINGLE)
    assert p.nc2.proc.poll() is None  # nc2 goes on
