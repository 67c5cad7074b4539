"""Example 09 (coupled conveyor) run as its docstring says: ``nc-server --config
examples/09_coupled_conveyor.toml --listen tcp/127.0.0.1:PORT`` (a fresh server on a free port) and
``plc-run examples/09_coupled_conveyor.py --nc nc1=tcp/127.0.0.1:PORT``, ending by itself with exit
code 0; the facts it prints are checked (ratios, recorded edge, superimposed distance, where the
decoupled slave stopped).

Deadlines are generous (loaded 2-core VM); every process is killed with its process group.
"""
from __future__ import annotations

import math
import re
from typing import Callable

from znc_testing.plc_harness import EXAMPLES, run_example
from znc_testing import NcServerProcess


def number(pattern: str, out: str) -> float:
    m = re.search(pattern, out)
    assert m, f"{pattern!r} not in:\n{out}"
    return float(m.group(1))


def test_example_09_coupled_conveyor(start_nc: Callable[..., NcServerProcess]) -> None:
    nc = start_nc(extra_args=("--config", str(EXAMPLES / "09_coupled_conveyor.toml")))
    assert "3 axes" in (nc.ready_line() or ""), nc.ready_line()
    rc, out = run_example("09_coupled_conveyor.py", nc.endpoint)
    assert rc == 0, f"example 09 exited {rc}:\n{out[-3000:]}\nnc-server stderr:\n{nc.stderr()[-2000:]}"
    assert "all checks passed" in out and "CHECK FAILED" not in out, out
    # couplings: fixed 1:2 and the dynamic ratio 1.0 -> 1.5, seen in the set velocities
    assert "PrintRoller MC_GearIn 1:2 (NC ratio 0.500, CoupleState 3)" in out, out
    assert "velocity ratios PrintRoller 0.500, FeedBelt 1.000" in out, out
    assert "FeedBelt: GearRatio 1.0 -> 1.5" in out, out
    assert "velocity ratios now: PrintRoller 0.500, FeedBelt 1.500 (NC ratio 1.500)" in out, out
    # the latch: the second product's leading edge (the first one is outside the window)
    assert math.isclose(number(r"product edge recorded at (-?[\d.]+) mm", out), 250.0, abs_tol=1e-3), out
    assert "TouchProbeCounter 1)" in out, out
    # the registration correction: (250 - 230) / 2 = 10 mm on top of the coupling
    assert math.isclose(number(r"added (-?[\d.]+) mm", out), 10.0, abs_tol=1e-3), out
    assert math.isclose(number(r"ActualDistance (-?[\d.]+)", out), 10.0, abs_tol=1e-3), out
    # MC_GearOutExt NEWPOS: the FeedBelt at its target, decoupled
    target = number(r"MC_GearOutExt NEWPOS (\d+)", out)
    assert target % 100 == 0, out
    stopped = number(r"FeedBelt decoupled, stopped at (-?[\d.]+)", out)
    assert math.isclose(stopped, target, abs_tol=0.02) and "CoupleState 0)" in out, out
    # everything stopped, the roller decoupled at 1/2 of the conveyor + the correction
    conveyor = number(r"stopped: Conveyor at (-?[\d.]+)", out)
    roller = number(r"PrintRoller at (-?[\d.]+) \(decoupled: CoupleState 0", out)
    assert conveyor > 300.0 and math.isclose(roller, conveyor / 2 + 10.0, abs_tol=0.02), out
