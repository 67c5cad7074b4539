"""The cycle's shortcuts against the general paths they stand for, record bytes every cycle: the coupling stage's
slices for evenly spaced levels and its per-level memo (set-point StateDWord bits and limit check of the slaves'
velocities and accelerations), the profile stage's runs of rows instead of masks. A core with them off (the general
paths: fancy indexing, masks, no memo) runs the same script first; the core with them must give the same NCTOPLC
and NCJOBS bytes after every step."""
from __future__ import annotations

import hashlib
from typing import Any

import numpy as np
import pytest

import nc_server.core  # noqa: F401  (before nc_server.drives)
from nc_server.core import NcCore
from nc_server.core.stages import coupling as coupling_mod
from nc_server.core.stages import profile as profile_mod
from nc_server.core.stages.profile import _runs, motion_dwords
from znc_testing.nc_core import ALL_ENABLES, cmd, power, powered

N = 14


def _velocity(core: NcCore, axis: int, v: float, acc: float = 2000.0, direction: int = 1) -> None:
    r = cmd(core, "MoveVelocity", axis, Velocity=v, Acceleration=acc, Deceleration=acc, Jerk=0.0,
            Direction=direction, BufferMode=0)
    assert not r["error"], r


def _gear(core: NcCore, slave: int, master: int, num: int, den: int) -> None:
    r = cmd(core, "GearIn", slave, Master=master, RatioNumerator=num, RatioDenominator=den)
    assert not r["error"], r


def _script(core: NcCore, k: int) -> None:
    """Axes 1-8: masters 1, 3, 5, 7 with slaves 2, 4, 6, 8 (one evenly spaced level); 9 a slave of slave 2 (a
    second level); 10-14 single axes. Then stops, a slave leaving, a fault, resets, couplings again, the second
    level gone, a slave beyond its velocity limit."""
    if k == 2:
        for m, (num, den) in zip((1, 3, 5, 7), ((1, 2), (-1, 1), (3, 2), (2, 1))):
            _gear(core, m + 1, m, num, den)
        _gear(core, 9, 2, 1, 1)
    if k == 3:
        for a in (1, 3, 5, 7, 10, 11, 12, 13, 14):
            _velocity(core, a, 50.0 + 10 * a, direction=1 if a % 2 else 3)
    if k == 400:
        _velocity(core, 3, 300.0, acc=500.0)  # (a master accelerating: the slaves' values change every cycle)
    if k == 700:
        assert not cmd(core, "Stop", 4, Deceleration=2000.0, Jerk=0.0)["error"]  # a slave leaves: 2, 6, 8 remain
        assert not cmd(core, "Halt", 12, Deceleration=1000.0, Jerk=0.0)["error"]  # (runs of rows change)
    if k == 1000:
        power(core, 4, ctrl=int(ALL_ENABLES) & ~0x2 & ~0x4)  # master 5 without its feed: an axis error
    if k == 1300:
        assert not cmd(core, "StopRelease", 4)["error"]
        power(core, 4)
        assert not cmd(core, "Reset", 5)["error"]
        assert not cmd(core, "Reset", 6)["error"]
    if k == 1500:
        _gear(core, 4, 3, 1, 3)
        _velocity(core, 5, 80.0)
        _velocity(core, 12, 40.0, direction=3)
    if k == 1600:
        assert not cmd(core, "GearOut", 9)["error"]  # (one level left: the stage's single-level limit check)
    if k == 1700:
        _velocity(core, 7, 600.0, acc=2000.0)  # slave 8 at 2 x: beyond its AxisVeloMax (1000) on the way: 0x4359


def _digests(core: NcCore, cycles: int) -> list[str]:
    out = []
    for k in range(cycles):
        _script(core, k)
        core.step()
        out.append(hashlib.sha256(core.nctoplc.tobytes() + core.ncjobs.tobytes()).hexdigest())
    return out


class _NoMemo:
    """The general path of a level memo: computed every cycle."""

    def dwords_of(self, sv: np.ndarray) -> np.ndarray:
        return motion_dwords(sv[1], sv[2])

    def is_within(self, sv: np.ndarray, lim: np.ndarray) -> bool:
        return not np.count_nonzero(np.abs(sv[1:3]) > lim)


def test_shortcuts_give_the_general_paths_bytes(monkeypatch: pytest.MonkeyPatch) -> None:
    cycles = 2000
    with monkeypatch.context() as m:
        m.setattr(coupling_mod, "_as_index", lambda rows: rows)
        m.setattr(coupling_mod, "_Memo", _NoMemo)
        m.setattr(profile_mod, "_MAX_RUNS", 0)
        general = _digests(powered(N), cycles)
    core = powered(N)
    fast = _digests(core, cycles)
    first = next((k for k, (a, b) in enumerate(zip(general, fast)) if a != b), None)
    assert first is None, f"records differ from cycle {first} on"
    # the shortcuts ran: the evenly spaced level as slices, the rows following a plan as runs
    levels = core.coupling._levels(core)[0]
    assert any(type(lv[8]) is slice for lv in levels)
    assert core.profile._on_runs is not None and not core.all_on
    assert core.nctoplc["ErrorCode"][7] == 0x4359  # (slave 8 beyond AxisVeloMax: the limit check ran)


@pytest.mark.parametrize("rows", [[], [3], [0, 2, 4, 6, 7, 8, 9], [1, 5, 6, 20, 21, 22, 40], list(range(0, 64, 3)),
                                  [0, 1, 3, 6, 10, 15, 21, 28, 36, 45]])
def test_runs_are_the_rows(rows: list[int]) -> None:
    r = np.array(rows, dtype=np.intp)
    runs = _runs(r, 4)
    if runs is None:  # (more runs than 4 needed)
        assert len(rows) > 5
        return
    assert len(runs) <= 4
    got: list[Any] = [x for sl in runs for x in range(sl.start, sl.stop, sl.step)]
    assert got == rows
