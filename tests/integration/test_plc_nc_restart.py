"""Killing the NC under a running PLC, and restarting it on the same endpoint."""
from __future__ import annotations

import time
from typing import Callable

from plc_harness import NC_ARGS, T, PlcProcess, power_on
from znc_testing import NcServerProcess, free_port, wait_until


def test_nc_killed_and_restarted(start_nc: Callable[..., NcServerProcess]) -> None:
    port = free_port()
    listen = ("--listen", f"tcp/127.0.0.1:{port}")
    nc = start_nc(extra_args=(*NC_ARGS, *listen))
    with PlcProcess(f"tcp/127.0.0.1:{port}", "plc-a") as a:
        a.wait_started()
        power_on(a)
        a.set("pos", "MC_ReadActualPosition", Enable=True)
        a.set("jog", "MC_MoveVelocity", Execute=True, Velocity=20.0)
        a.set("mv", "MC_MoveAbsolute", Execute=True, Position=800.0, Velocity=10.0)  # aborts jog, runs long
        a.wait("mv", lambda r: r.o["Active"], T)
        assert a.last("mv").a["Epoch"] == 0

        nc.kill()  # SIGKILL: no goodbye
        for name in ("pw", "pos", "mv"):
            r = a.wait(name, lambda r: r.o["Error"], T)
            assert r.o["ErrorID"] == 0x4B0F and not r.a["Valid"], (name, r)
        assert not a.last("pw").o["Status"] and not a.last("pos").o["Valid"]
        a.wait_cycles(20)
        assert a.proc.poll() is None, "the PLC keeps cycling without its NC"

        nc2 = start_nc(extra_args=(*NC_ARGS, *listen))
        # the session reconnects by itself; MC_Power claims the axis again on the new instance
        r = a.wait("pw", lambda r: r.o["Status"] and not r.o["Error"], T)
        assert r.a["Valid"] and r.a["State"] == "STANDSTILL"
        # one restart, one nc_epoch step: its token came back and its cycle counter went back
        wait_until(lambda: any("NC nc1 is back" in line for line in a.err_lines), T, "the NC's token back")
        a.trace(1)
        a.wait_trace(1, lambda r: r.a["Valid"], T)
        a.wait_cycles(10)
        assert {s.a["Epoch"] for s in a.trace_of(1)} == {1}
        a.trace(1, on=False)
        p = a.wait("pos", lambda r: r.o["Valid"], T)
        # nothing moves by itself: mv still shows its error (Execute stays TRUE: no new edge)
        time.sleep(1.0)
        a.wait_cycles(10)
        assert a.last("mv").o["Error"] and not a.last("mv").o["Busy"]
        now = a.last("pos")
        assert now.a["State"] == "STANDSTILL" and abs(now.o["Position"] - p.o["Position"]) < 1e-9
        # and the new NC accepts commands from the same PLC
        a.set("mv", Execute=False)
        a.wait_cycles(2)
        a.set("mv", Execute=True, Position=10.0, Velocity=100.0)
        done = a.wait("mv", lambda r: r.o["Done"], T)
        assert abs(done.a["ActPos"] - 10.0) < 0.02
        assert a.stop() == 0
    nc2.stop()
