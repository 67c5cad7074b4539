"""MC_Jog and MC_Home through the real distributed path (``nc-server`` and ``plc-run`` processes
on 127.0.0.1), and examples 06-08 run as their README says: each against a fresh nc-server,
ending by itself with exit code 0.

Deadlines are generous (loaded 2-core VM); every process is killed with its process group.
"""
from __future__ import annotations

import math
import re

from znc_testing import plc_harness
from znc_testing.plc_harness import T, PlcProcess, exclusive, power_on
from znc_testing import NcServerProcess


def test_jog_continuous_and_inching(plc: PlcProcess) -> None:
    power_on(plc)
    plc.set("jog", "MC_Jog", Mode=0, JogForward=True)  # STANDARD_SLOW: AxisVeloManSlow (20 mm/s on X)
    plc.wait("jog", lambda r: r.o["Active"], T)
    moving = plc.wait("jog", lambda r: r.a["State"] == "CONTINOUSMOTION", T)
    plc.wait_cycles(30)
    plc.set("jog", JogForward=False)
    done = plc.wait("jog", lambda r: r.o["Done"], T)
    assert done.a["State"] == "STANDSTILL" and done.a["ActPos"] > moving.a["ActPos"] + 1.0
    plc.wait("jog", lambda r: not r.o["Done"], T)  # a one-cycle pulse: the key was released
    start = done.a["ActPos"]
    plc.set("jog", Mode=3, Position=2.0, Velocity=20.0, JogBackwards=True)  # INCHING backwards
    step = plc.wait("jog", lambda r: r.o["Done"], T)
    assert math.isclose(step.a["ActPos"], start - 2.0, abs_tol=0.02)
    plc.wait_cycles(10)
    assert plc.last("jog").o["Done"], "Done held while the key stays pressed"
    exclusive(plc.history("jog"))


def test_home_direct_and_reference_flag(plc: PlcProcess) -> None:
    power_on(plc)
    plc.set("home", "MC_Home", Execute=True, Position=5.0, HomingMode=4)  # MC_Direct
    r = plc.wait("home", lambda r: not r.o["Busy"] and (r.o["Done"] or r.o["Error"]), T)
    assert r.o["Done"], r
    assert math.isclose(r.a["ActPos"], 5.0, abs_tol=1e-6)
    plc.set("ref", "MC_SetReferenceFlag", Execute=True, ReferenceFlag=False)
    assert plc.wait("ref", lambda r: r.o["Done"] or r.o["Error"], T).o["Done"]
    exclusive(plc.history("home"))


def run_example(name: str, endpoint: str) -> str:
    rc, out = plc_harness.run_example(name, endpoint)
    assert rc == 0, f"{name} exited {rc}:\n{out[-3000:]}"
    return out


def test_example_06_home_and_jog(nc: NcServerProcess) -> None:
    out = run_example("06_home_and_jog.py", nc.endpoint)
    assert "X: homed=True, HomingState 0" in out and "Y: homed=True, HomingState 0" in out, out
    assert "inching step 3" in out and "released: Done" in out, out


def test_example_07_modulo_application(nc: NcServerProcess) -> None:
    out = run_example("07_modulo_application.py", nc.endpoint)
    lines = [line for line in out.splitlines() if line.startswith("cycle ")]
    assert len(lines) == 4, out
    for k, line in enumerate(lines, 1):  # every working cycle: one full turn back to modulo 90
        nums = dict(re.findall(r"(ActPos|modulo|turns)\s+(-?[\d.]+)", line))
        assert math.isclose(float(nums["modulo"]), 90.0, abs_tol=0.06), line
        assert int(nums["turns"]) == k and math.isclose(float(nums["ActPos"]), 90.0 + 360.0 * k, abs_tol=0.06), line
    assert "MC_Reset" in out, out


def test_example_08_buffered_blending(nc: NcServerProcess) -> None:
    out = run_example("08_buffered_blending.py", nc.endpoint)
    assert "move 3 Done: X at 300.0" in out and "CmdBuffered True" in out, out
    passed = {float(p): float(v) for p, v in re.findall(r"passed (\d+) mm at (-?[\d.]+) mm/s", out)}
    assert set(passed) == {100.0, 250.0}, out
    assert passed[100.0] > 90.0 and passed[250.0] > 90.0, "blended: the transitions are passed at ~100 mm/s"
