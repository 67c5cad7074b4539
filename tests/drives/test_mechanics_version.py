"""Mechanics.set_version (what the output packer relies on to copy the torque rows ActTorque and its derivative
alone): while it stays, rows 0, 3, 4 and 5 of ``fields`` (SetTorque, SetTorqueDerivative, AbsPhasingPos,
TorqueOffset) hold the same bytes. Random sequences of the calls the drives make (step, step_set, step_actual,
set_offset, configure) on a few axes, with steady stretches (the same inputs again) and rests (nothing delivering)."""
from __future__ import annotations

import random

import numpy as np
import pytest

import nc_server.core  # noqa: F401  (before nc_server.drives)
from nc_server.core import AxisParams
from nc_server.drives.mechanics import Mechanics

N = 5
ROWS = [0, 3, 4, 5]


@pytest.mark.parametrize("seed", range(4))
def test_rows_stay_while_the_version_stays(seed: int) -> None:
    rnd = random.Random(seed)
    m = Mechanics(N, 0.001)
    for i in range(N):
        m.configure(i, AxisParams(SimLoadInertia=1e-4 * (1 + i), SimViscousFriction=2e-4))
    velo, acc = np.zeros(N), np.zeros(N)
    deliver = np.ones(N, dtype=bool)
    seen = (m.set_version, m.fields[ROWS].copy())
    changes = kept = 0
    for k in range(3000):
        r = rnd.random()
        if r < 0.05:  # new set-points (else the same again: the steady cycle)
            velo = np.array([rnd.choice([0.0, 100.0, -250.5, 1e3]) for _ in range(N)])
            acc = np.array([rnd.choice([0.0, 0.0, 500.0, -2e3]) for _ in range(N)])
        elif r < 0.07:
            deliver = np.array([rnd.random() < 0.7 for _ in range(N)]) if rnd.random() < 0.7 else np.zeros(N, bool)
        elif r < 0.08:
            m.set_offset(np.array([rnd.choice([0.0, 12.5, np.nan, -2e3]) for _ in range(N)]))
        elif r < 0.085:
            m.configure(rnd.randrange(N), AxisParams(SimCoulombFriction=rnd.choice([0.02, 0.05])))
        act_v = velo * 0.99
        how = rnd.random()
        if how < 0.45:
            m.step_set(deliver, velo, acc)  # (the CiA 402 drive: then its own ActTorque rows)
            m.step_actual(deliver, act_v, acc)
        elif how < 0.55:
            m.step(deliver, velo, acc, act_v, acc)  # (SimDrive)
        else:
            m.step_set(deliver, velo, acc)
        rows = m.fields[ROWS]
        if m.set_version == seen[0]:
            assert rows.tobytes() == seen[1].tobytes(), f"step {k}: rows changed, version {m.set_version} stayed"
            kept += 1
        else:
            changes += 1
            seen = (m.set_version, rows.copy())
    assert kept > 500 and changes > 50  # (both kinds of step happened)
