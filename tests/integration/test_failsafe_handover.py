"""HandOver between two ``plc-run`` clients (real processes, 127.0.0.1): axis 1 enabled and moving
under client A is handed to client B (``PlcTask.hand_over`` / ``expect_hand_over``); every NCTOPLC
sample of the axis shows it enabled and without error throughout (StateDWord bit 20,
ControlLoopClosed, and Operational); B then commands and supplies the axis, A can no longer
(its PLCTONC is ignored, its holder-only commands are refused with 0x723)."""
from __future__ import annotations

import time
from pathlib import Path
from typing import Callable

from znc_testing.failsafe_support import T, AxisWatch, failsafe_config, resume_and_kill
from test_plc_coupling import ExtPlc
from znc_testing import BIT_OPERATIONAL, NcServerProcess

#: plc-run's lease: losing a PLC is not the point here (a loaded machine must not drop it)
LONG_LEASE = ["--lease-ms", "2000"]

HAND_OVER = """
if req is None:
    req = plc.hand_over("nc1", 1, to)
elif req.done and not said:
    said = True
    emit(done=True, error=req.error)
"""

EXPECT = """
if not asked:
    asked = True
    plc.expect_hand_over("nc1", 1)
"""

#: send one command from this client (the holder-only ones are refused once the axis is B's)
SEND = """
if p is None:
    p = plc.send(ax(1), cmd, **args)
elif p.done and not said:
    said = True
    emit(cmd=cmd, error=p.error or 0)
"""


def test_hand_over_keeps_the_axis_enabled_and_moves_the_rights(start_nc: Callable[..., NcServerProcess],
                                                               tmp_path: Path) -> None:
    nc = start_nc(failsafe_config(["stop_disable"], watchdog=3.0))
    a = ExtPlc(nc.endpoint, "plc-a", tmp_path / "a.py", extra=LONG_LEASE)
    b = ExtPlc(nc.endpoint, "plc-b", tmp_path / "b.py", extra=LONG_LEASE)
    watch = AxisWatch(nc.port, [1])
    try:
        a.wait_started(60)
        b.wait_started(60)
        a.set("pw", "MC_Power", axis=1, Enable=True, Enable_Positive=True, Enable_Negative=True)
        a.wait("pw", lambda r: r.o["Status"], T)
        a.set("mv", "MC_MoveVelocity", axis=1, Execute=True, Velocity=40.0)
        a.wait("mv", lambda r: r.o["InVelocity"], T)
        t_start = time.monotonic()

        # B accepts the hand-over: its MC_Power publishes PLCTONC for the axis, waiting without an error
        b.hook("expect", EXPECT, asked=False)
        b.sync()
        b.set("pw", "MC_Power", axis=1, Enable=True, Enable_Positive=True, Enable_Negative=True)
        b.wait_cycles(20)
        rb = b.last("pw")
        assert rb.o["Busy"] and not rb.o["Error"] and not rb.o["Active"] and not rb.o["Status"], rb

        a.hook("ho", HAND_OVER, req=None, said=False, to="plc-b")
        r = a.wait("ho", lambda r: r.o.get("done"), T)
        assert r.o["error"] == 0, r
        t_hand = r.t
        rb = b.wait("pw", lambda r: r.o["Status"] and r.o["Active"], T)
        print(f"\n[failsafe] hand-over: B's MC_Power Active {(rb.t - t_hand) * 1e3:.0f} ms after A saw the reply")

        # A lets go: its MC_Power disabled, its frames (Enable off) no longer count
        a.set("pw", Enable=False)
        a.wait_cycles(30)
        # B commands the axis
        b.set("mv", "MC_MoveVelocity", axis=1, Execute=True, Velocity=10.0)
        b.wait("mv", lambda r: r.o["InVelocity"], T)
        watch.wait(1, lambda s: abs(s.velo - 10.0) < 1e-6, what="B's velocity")
        # A's holder-only commands are refused
        for cmd, args in (("SetOverride", {"Override": 50.0}), ("Release", {}), ("HandOver", {"To": "plc-a"})):
            a.hook(f"send-{cmd}", SEND, p=None, said=False, cmd=cmd, args=args)
            r = a.wait(f"send-{cmd}", lambda r: "error" in r.o, T)
            assert r.o["error"] == 0x723, r

        samples = watch.since(1, t_start)
        assert len(samples) > 100
        off = [s for s in samples if not s.enabled or not s.sd & BIT_OPERATIONAL or s.err]
        assert not off, f"the axis was disabled or faulted during the hand-over: {off[:3]}"
        # and B's disable does disable it: B supplies the PLCTONC now
        b.set("pw", Enable=False)
        watch.wait(1, lambda s: not s.enabled, after=time.monotonic(), what="disabled by B")
    finally:
        watch.close()
        resume_and_kill(a.proc)
        resume_and_kill(b.proc)
