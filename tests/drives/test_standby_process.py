"""A hot-standby NC pair with real processes over real zenoh on 127.0.0.1 (docs/standby.md): an ``nc-router``, two
``nc-server`` processes of NC ``nc1`` in client mode behind it (node ``a`` starts active, ``b`` standby), an
``nc-drive-sim`` hosting the remote drives, a client moving axis 1 and an observer following the NC as the PLC
runtime does (nc_link: its NC-restart detection).

* kill -9 of the active NC mid-move: the standby takes over (ha status, a higher epoch on the drive host), the
  set-points go on without a step beyond what the dynamics allow, the move reaches its target and ends Done with
  the same CmdNo, a repeated request gets the replicated reply, the observer sees no NC restart; the takeover
  time is measured;
* SIGSTOP of the active NC mid-move, then SIGCONT: the standby takes over; the old NC comes back as a standby and
  never drives again (the drive host refuses its epoch; nothing of it reaches the drives).
"""
from __future__ import annotations

import os
import signal
import time
from pathlib import Path
from typing import Any, Callable, Iterator

import pytest

# Opt-in (ZNC_STANDBY_TESTS=1): green 6 runs in a row at load average 5-7 on 2 cores, but at load average ~24 (a full
# CI run beside) one run saw a 14.8 s log silence then a third epoch (the old node took over again), another a
# command unanswered for 10 s: not reliable enough for make test yet (docs/standby.md).
pytestmark = pytest.mark.skipif(not os.environ.get("ZNC_STANDBY_TESTS"),
                                reason="hot-standby process tests: set ZNC_STANDBY_TESTS=1 (docs/standby.md)")

from znc_testing import NcServerProcess, NcTestClient, kill_process_group, start_nc_router, start_nc_server, wait_until
from znc_testing.remote_drives import DriveSim, drive_axis, power
from znc_testing.standby_rig import CONFIG, Trace, ha_status, largest_step

T = 30.0
CYCLE = 0.002
# 500 ms: above the stalls of a loaded 2-core machine (false takeovers there are a matter of this setting, not of the
# mechanism; bench/takeover.py measures the takeover time), well below the drive host's timeout (DRIVE_TIMEOUT)
TAKEOVER_CYCLES = 250
DRIVE_TIMEOUT = 3.0
V, A, J = 50.0, 500.0, 5000.0  # the move's dynamics


def wait_logged(pred: Callable[[], Any], what: str, *procs: Any, timeout: float = T) -> Any:
    """wait_until, with the processes' stderr in the failure's message."""
    try:
        return wait_until(pred, timeout, what)
    except AssertionError as exc:
        logs = "\n".join(f"--- {getattr(p, 'name', 'drives')} {getattr(p, 'pid', '')}:\n{p.stderr()[-3000:]}"
                         for p in procs)
        raise AssertionError(f"{exc}\n{logs}") from None


@pytest.fixture
def pair(tmp_path: Path) -> Iterator[Callable[[], tuple[NcServerProcess, NcServerProcess, DriveSim, int]]]:
    started: list[Any] = []

    def make() -> tuple[NcServerProcess, NcServerProcess, DriveSim, int]:
        router = start_nc_router(tmp_path / "router")
        started.append(router)
        text = CONFIG.format(cycle=CYCLE, port=router.port, takeover=TAKEOVER_CYCLES)
        cfg = tmp_path / "nc.toml"
        cfg.write_text(text)
        a = start_nc_server(tmp_path / "a", text, name="nc1", connect=router.endpoint,
                            extra_args=["--set", "redundancy.node=a", "--set", "redundancy.start=active"])
        started.append(a)
        b = start_nc_server(tmp_path / "b", text, name="nc1", connect=router.endpoint,
                            extra_args=["--set", "redundancy.node=b"])
        started.append(b)
        sim = DriveSim(tmp_path, ["--config", str(cfg), "--host", "drives1", "--connect", router.endpoint,
                                  "--timeout", str(DRIVE_TIMEOUT)])
        started.append(sim)
        return a, b, sim, router.port

    try:
        yield make
    finally:
        for h in reversed(started):
            h.kill()


def start_move(a: NcServerProcess, b: NcServerProcess, sim: DriveSim, port: int, target: float) -> tuple[
        NcTestClient, Trace, dict[str, Any], dict[str, Any]]:
    cl = NcTestClient(port, client_id="plc1")
    tr = Trace(port)
    wait_logged(lambda: (s := ha_status(cl, "b")) is not None and s["in_step"] and s["role"] == "standby",
                "node b in step as the standby", a, b)
    wait_logged(lambda: (s := ha_status(cl, "a")) is not None and s["role"] == "active", "node a active", a, b)
    wait_until(lambda: (s := sim.status()) is not None and s["connected"] and s["rx_count"] > 0, T,
               f"the drive host receiving outputs; stderr:\n{sim.stderr()}")
    # the pair's takeover bound reaches the drive host with the outputs: (250 + 1) cycles of 2 ms, below its 3 s
    st0 = wait_until(lambda: (s := sim.status()) is not None and s["takeover_limit_ms"] > 0 and s, T, "takeover_limit_ms")
    assert st0["takeover_limit_ms"] == pytest.approx((TAKEOVER_CYCLES + 1) * CYCLE * 1e3) and not st0["timeout_short"]
    power(cl, [1])
    req = {"Position": target, "Velocity": V, "Acceleration": A, "Deceleration": A, "Jerk": J}
    r = cl.request("MoveAbsolute", axis=1, request_id=4242, **req)
    assert r["error"] == 0, r
    return cl, tr, r, req


def test_kill_9_of_the_active_nc_mid_move(pair: Callable[..., Any]) -> None:
    a, b, sim, port = pair()
    cl, tr, first, req = start_move(a, b, sim, port, 40.0)
    try:
        wait_logged(lambda: (r := cl.nctoplc(1)) is not None and float(r["SetPos"]) > 10.0, "axis 1 past 10", a, b, sim)
        epoch_a = ha_status(cl, "a")["epoch"]  # type: ignore[index]
        kill_process_group(a.proc)  # kill -9 of the active NC (its process group)
        t_kill = time.monotonic()
        st = wait_until(lambda: (s := ha_status(cl, "b")) is not None and s["role"] == "active" and s, T,
                        f"b took over; stderr:\n{b.stderr()}")
        assert st["epoch"] > epoch_a and st["takeovers"] >= 1
        wait_until(lambda: (s := sim.status()) is not None and s["epoch"] == st["epoch"], T, "drive host follows b")
        r = wait_until(lambda: (x := cl.nctoplc(1)) is not None and int(x["CmdState"]) == 2 and x, T * 2,
                       "the move ended Done")  # (CmdState 2: DONE)
        assert abs(float(r["SetPos"]) - 40.0) < 1e-6 and int(r["CmdNo"]) == first["CmdNo"]
        assert int(r["ErrorCode"]) == 0
        # a repeated request (same client and id) gets the replicated reply: not executed twice
        again = cl.request("MoveAbsolute", axis=1, request_id=4242, **req)
        assert again == first
        assert tr.restarts == [], tr.restarts
        step = largest_step(tr.samples, CYCLE, A)
        after = [s for s in tr.samples if s[5] > t_kill]
        assert after and after[0][0] > max(s[0] for s in tr.samples if s[5] <= t_kill) - 1  # the Cycle continued
        assert step < 0.05 * V * TAKEOVER_CYCLES * CYCLE + 1e-3, step
        print(f"takeover {st['takeover_ms']:.1f} ms ({st['takeover_cycles']} cycles of {CYCLE * 1e3:g} ms, detection "
              f"included; caught up {st['catch_up_cycles']}), largest SetPos step beyond the dynamics {step:.6f}")
        stt = sim.status()
        assert stt is not None and drive_axis(stt, 1)["state"] == "OPERATION_ENABLED"
    finally:
        tr.close()
        cl.close()


def test_sigstop_of_the_active_nc_then_sigcont(pair: Callable[..., Any]) -> None:
    a, b, sim, port = pair()
    cl, tr, first, _ = start_move(a, b, sim, port, 30.0)
    try:
        wait_until(lambda: (r := cl.nctoplc(1)) is not None and float(r["SetPos"]) > 8.0, T, "axis 1 past 8")
        os.killpg(a.proc.pid, signal.SIGSTOP)
        try:
            st = wait_until(lambda: (s := ha_status(cl, "b")) is not None and s["role"] == "active" and s, T,
                            f"b took over; stderr:\n{b.stderr()}")
        finally:
            os.killpg(a.proc.pid, signal.SIGCONT)
        # the old NC comes back as a standby (it stalled with a standby in step, or it sees the higher epoch)
        wait_until(lambda: (s := ha_status(cl, "a")) is not None and s["role"] == "standby" and s["demotions"] >= 1,
                   T, f"a is a standby; stderr:\n{a.stderr()}")
        r = wait_until(lambda: (x := cl.nctoplc(1)) is not None and int(x["CmdState"]) == 2 and x, T * 2,
                       "the move ended Done")
        assert abs(float(r["SetPos"]) - 30.0) < 1e-6 and int(r["CmdNo"]) == first["CmdNo"]
        stt = sim.status()
        assert stt is not None and stt["epoch"] == st["epoch"]
        # a never drives again: the host's epoch stays b's, and a is back in step as a standby of b
        wait_logged(lambda: (s := ha_status(cl, "a")) is not None and s["in_step"], "a in step with b", a, b)
        assert (ha_status(cl, "a") or {})["role"] == "standby" and (ha_status(cl, "b") or {})["role"] == "active"
        assert tr.restarts == [], tr.restarts
    finally:
        tr.close()
        cl.close()
