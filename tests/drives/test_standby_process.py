"""A hot-standby NC pair with real processes over real zenoh on 127.0.0.1 (docs/standby.md): an ``nc-router``, two
``nc-server`` processes of NC ``nc1`` in client mode behind it (node ``a`` starts active, ``b`` standby), an
``nc-drive-sim`` hosting the remote drives, a client moving the axes and an observer following the NC as the PLC
runtime does (nc_link: its NC-restart detection).

* kill -9 of the active NC mid-move: the standby takes over (ha status, a higher epoch on the drive host), the
  set-points go on without a step beyond what the dynamics allow, the move reaches its target and ends Done with
  the same CmdNo, a repeated request gets the replicated reply, the observer sees no NC restart and no "NC gone"
  (the standby in step holds the NC's tokens too); the takeover
  time is measured;
* SIGSTOP of the active NC mid-move, then SIGCONT: the standby takes over; the old NC comes back as a standby and
  never drives again (the drive host refuses its epoch; nothing of it reaches the drives);
* kill -9 during a coupling (MC_GearIn 1:2, master and slave on this NC): no jump on either axis, the slave in
  ratio at every cycle seen, the master's move Done, the GearIn block still coupled with its CmdNo;
* kill -9 during a superposition (MC_MoveSuperImposed on a moving axis): no jump, the superposition ends DONE with
  its CmdNo and its full distance, the basic motion goes on.

Reliable on a loaded 2-core machine (checked 3 runs in a row and under bench/cpu_burner.py; the SIGSTOP test is
opt-in, see its reason): every wait is a condition with a generous deadline; the node killed is the one active at
that moment (a false takeover before it, which the loss detection should prevent, is not what these tests check);
the motion (the move, the coupling, the superposition) is asserted still running just before the kill, and it still
has RUN_AFTER_READY s to go when the kill is due: a stall of the test process between the two (0.2-1 s on a loaded
machine) leaves it running (with 0.4-0.6 s a 0.8 s stall ended it first); the kill tests then check that the new
active NC's own samples (its epoch in their stamp) show the same motion going on: the kill was mid-motion. The
observer's sessions announce the rig's lease (a 0.5 s stall of the test process dropped its nc_link session before:
a false "NC gone"). No speed is asserted.
"""
from __future__ import annotations

import os
import signal
import time
from pathlib import Path
from typing import Any, Callable, Iterator

import pytest

from znc_testing import NcServerProcess, NcTestClient, kill_process_group, start_nc_router, start_nc_server, wait_until
from znc_testing.remote_drives import DriveSim, drive_axis, power
from znc_testing.standby_rig import AXIS2, CONFIG, LEASE_MS, Trace, active_node, close_all, ha_status, largest_step

T = 60.0  # generous deadlines: a loaded 2-core machine
CYCLE = 0.002
# the default (15 = 30 ms): the standby's loss detection raises the limit it applies (and publishes) when the logs
# come late on a loaded machine (docs/standby.md, "Loss detection"); a kill is seen at once from the token anyway
TAKEOVER_CYCLES = 15
DRIVE_TIMEOUT = 3.0  # above the loss detection's cap (1 s)
V, A, J = 50.0, 500.0, 5000.0  # the moves' dynamics
DONE, ABORTED, ERROR = 2, 3, 4
#: how long the motion still runs once the test decided to kill (its ``ready``) at the earliest [s]: longer than a
#: stall of the test process on a loaded machine (0.2-1 s)
RUN_AFTER_READY = 1.8

Procs = dict[str, Any]


def wait_logged(pred: Callable[[], Any], what: str, procs: Procs, timeout: float = T) -> Any:
    """wait_until, with the processes' stderr in the failure's message."""
    try:
        return wait_until(pred, timeout, what, interval=0.02)
    except AssertionError as exc:
        logs = "\n".join(f"--- {n}:\n{p.stderr()[-3000:]}" for n, p in procs.items())
        raise AssertionError(f"{exc}\n{logs}") from None


@pytest.fixture
def pair(tmp_path: Path) -> Iterator[Callable[..., Procs]]:
    started: list[Any] = []

    def make(axes: int = 1, max_age: int | None = None) -> Procs:
        router = start_nc_router(tmp_path / "router", ["--lease-ms", str(LEASE_MS)])
        started.append(router)
        text = CONFIG.format(cycle=CYCLE, port=router.port, takeover=TAKEOVER_CYCLES) + (AXIS2 if axes > 1 else "")
        if max_age is not None:  # ([drives.remote] max_age: how old the drive inputs may be, in cycles)
            assert "max_age = 200" in text, "the rig's config changed: [drives.remote] max_age not replaced"
            text = text.replace("max_age = 200", f"max_age = {max_age}")
        cfg = tmp_path / "nc.toml"
        cfg.write_text(text)
        a = start_nc_server(tmp_path / "a", text, name="nc1", connect=router.endpoint,
                            extra_args=["--set", "redundancy.node=a", "--set", "redundancy.start=active"])
        started.append(a)
        b = start_nc_server(tmp_path / "b", text, name="nc1", connect=router.endpoint,
                            extra_args=["--set", "redundancy.node=b"])
        started.append(b)
        sim = DriveSim(tmp_path, ["--config", str(cfg), "--host", "drives1", "--connect", router.endpoint,
                                  "--timeout", str(DRIVE_TIMEOUT), "--lease-ms", str(LEASE_MS)])
        started.append(sim)
        return {"a": a, "b": b, "drives": sim, "port": router.port, "router": router}

    try:
        yield make
    finally:
        for h in reversed(started):
            h.kill()


def servers(p: Procs) -> Procs:
    return {n: p[n] for n in ("a", "b", "drives")}


def setup(p: Procs, axes: list[int]) -> tuple[NcTestClient, Trace]:
    """The client (axes powered) and the observer, once the pair is up: one node active, the other in step."""
    cl = NcTestClient(p["port"], client_id="plc1", lease_ms=LEASE_MS)
    tr: Trace | None = None
    try:
        tr = Trace(p["port"], tuple(axes))
        sim = p["drives"]
        wait_logged(lambda: active_node(cl) is not None, "one node active, the other a standby in step", servers(p))
        wait_logged(lambda: (s := sim.status()) is not None and s["connected"] and s["rx_count"] > 0,
                    "the drive host receiving outputs", servers(p))
        # the pair's takeover limit reaches the drive host with the outputs: at least (15 + 1) cycles of 2 ms, at
        # most the loss detection's cap (1 s) + 1 cycle, below the host's 3 s
        st = wait_logged(lambda: (s := sim.status()) is not None and s["takeover_limit_ms"] > 0 and s,
                         "takeover_limit_ms", servers(p))
        assert (TAKEOVER_CYCLES + 1) * CYCLE * 1e3 - 1e-6 <= st["takeover_limit_ms"] <= 1e3 + 2 * CYCLE * 1e3, st
        assert not st["timeout_short"], st
        power(cl, axes)
    except BaseException:  # (the caller gets neither: their sessions closed here, or pytest waits on their threads)
        close_all(tr, cl, [])
        raise
    return cl, tr


def move(cl: NcTestClient, axis: int, target: float, request_id: int | None = None) -> tuple[dict[str, Any], dict]:
    req = {"Position": target, "Velocity": V, "Acceleration": A, "Deceleration": A, "Jerk": J}
    r = cl.request("MoveAbsolute", axis=axis, request_id=request_id, **req)
    assert r["error"] == 0, r
    return r, req


def kill_active(p: Procs, cl: NcTestClient, sig: int = signal.SIGKILL, ready: Callable[[], Any] | None = None,
                still: Callable[[], Any] | None = None) -> tuple[str, str, int]:
    """Signal the node active now (its process group): (that node, the other, its epoch). The active node is found
    first (ha status queries: slow on a loaded machine), then ``ready()`` waits for the moment to kill, then
    ``still()`` asserts on the NC's state read just before the signal (e.g. the axis still moving: a kill after the
    move ended would prove nothing)."""
    act = wait_logged(lambda: (n := active_node(cl)) is not None and (n,), "one node active, the other a standby in "
                      "step", servers(p))[0]
    other = "b" if act == "a" else "a"
    epoch = int((ha_status(cl, act) or {})["epoch"])
    if ready is not None:
        ready()
    if still is not None:
        still()
    if sig == signal.SIGKILL:
        kill_process_group(p[act].proc)
    else:
        os.killpg(p[act].proc.pid, sig)
    return act, other, epoch


def moving(cl: NcTestClient, axis: int, cmd_no: int, target: float | None) -> None:
    """The axis is moving under block ``cmd_no`` (not ended; short of ``target``), read from the NC now."""
    x = cl.nctoplc(axis)
    assert x is not None and int(x["CmdNo"]) == cmd_no and int(x["CmdState"]) not in (DONE, ABORTED, ERROR), x
    assert abs(float(x["SetVelo"])) > 1.0, float(x["SetVelo"])
    if target is not None:
        assert abs(target - float(x["SetPos"])) > 1.0, (float(x["SetPos"]), target)


def went_on(samples: list[tuple[int, float, float, int, int, float, int]], epoch: int, cmd_no: int,
            velo: float = 1.0) -> None:
    """The new active NC (``epoch``: its samples' stamp) published block ``cmd_no`` still running (not ended,
    |SetVelo| > ``velo``): the kill came mid-motion, whenever the test process ran."""
    run = [s for s in samples if s[6] == epoch and s[3] == cmd_no and s[4] not in (DONE, ABORTED, ERROR)
           and abs(s[2]) > velo]
    assert run, f"no sample of the new active NC (epoch {epoch}) with block {cmd_no} still running: " \
                f"{[s for s in samples if s[6] == epoch][:3]}"


def took_over(p: Procs, cl: NcTestClient, node: str, epoch: int) -> dict[str, Any]:
    st = wait_logged(lambda: (s := ha_status(cl, node)) is not None and s["role"] == "active" and s["epoch"] > epoch
                     and s, f"{node} took over", servers(p))
    wait_logged(lambda: (s := p["drives"].status()) is not None and s["epoch"] == st["epoch"],
                "the drive host follows the new active NC", servers(p))
    return st


def done(p: Procs, cl: NcTestClient, axis: int, cmd_no: int, target: float) -> Any:
    r = wait_logged(lambda: (x := cl.nctoplc(axis)) is not None and int(x["CmdNo"]) == cmd_no
                    and int(x["CmdState"]) in (DONE, ABORTED, ERROR) and x, f"axis {axis}'s move ended", servers(p))
    if not (int(r["CmdState"]) == DONE and int(r["ErrorCode"]) == 0):
        logs = "\n".join(f"--- {n}:\n{x.stderr()[-4000:]}" for n, x in servers(p).items())
        raise AssertionError(f"axis {axis}: CmdState {int(r['CmdState'])}, ErrorCode {hex(int(r['ErrorCode']))}\n{logs}")
    assert abs(float(r["SetPos"]) - target) < 1e-6
    return r


def test_kill_9_of_the_active_nc_mid_move(pair: Callable[..., Procs]) -> None:
    p = pair()
    cl, tr = setup(p, [1])
    try:
        first, req = move(cl, 1, 10.0 + V * RUN_AFTER_READY, request_id=4242)  # (2 s at V)
        _, new, epoch = kill_active(
            p, cl, ready=lambda: wait_logged(lambda: (r := cl.nctoplc(1)) is not None and float(r["SetPos"]) > 10.0,
                                             "axis 1 past 10", servers(p)),
            still=lambda: moving(cl, 1, first["CmdNo"], req["Position"]))
        t_kill = time.monotonic()
        st = took_over(p, cl, new, epoch)
        assert st["takeovers"] >= 1
        done(p, cl, 1, first["CmdNo"], req["Position"])
        went_on(tr.samples, st["epoch"], first["CmdNo"])
        # a repeated request (same client and id) gets the replicated reply: not executed twice
        again = cl.request("MoveAbsolute", axis=1, request_id=4242, **req)
        assert again == first
        assert tr.restarts == [], tr.restarts
        # protocol 5: the frames carry the active NC's epoch; the observer's link follows the new one
        wait_logged(lambda: tr.link.stats()["epoch"] == st["epoch"], "the observer's link on the new epoch", servers(p))
        # the standby in step holds the NC's tokens too: no "NC gone" (nc_link, the PLC runtime) at the kill
        assert tr.gone == [], tr.gone
        step = largest_step(tr.samples, CYCLE, A)
        after = [s for s in tr.samples if s[5] > t_kill]
        assert after and after[0][0] > max(s[0] for s in tr.samples if s[5] <= t_kill) - 1  # the Cycle continued
        assert step < 0.05 * V * CYCLE + 1e-6, step
        print(f"takeover {st['takeover_ms']:.1f} ms ({st['takeover_cycles']} cycles of {CYCLE * 1e3:g} ms, detection "
              f"included; caught up {st['catch_up_cycles']}), largest SetPos step beyond the dynamics {step:.6f}")
        stt = p["drives"].status()
        assert stt is not None and drive_axis(stt, 1)["state"] == "OPERATION_ENABLED"
    finally:
        tr.close()
        cl.close()


# Opt-in until 2026-12-06 (under bench/cpu_burner.py 3 of 6 runs had failed: the pair changing roles again after
# the NCs' stalls, a frame of the resumed NC after the new one's); since the loss detector's window of 60 s at 3x and
# the frames' epoch: 8 of 8 runs under the burner and 3 of 3 on the quiet machine passed: in make test.
def test_sigstop_of_the_active_nc_then_sigcont(pair: Callable[..., Procs]) -> None:
    p = pair()
    cl, tr = setup(p, [1])
    try:
        first, req = move(cl, 1, 8.0 + V * RUN_AFTER_READY)
        old, new, epoch = kill_active(
            p, cl, signal.SIGSTOP,
            ready=lambda: wait_logged(lambda: (r := cl.nctoplc(1)) is not None and float(r["SetPos"]) > 8.0,
                                      "axis 1 past 8", servers(p)),
            still=lambda: moving(cl, 1, first["CmdNo"], req["Position"]))
        try:
            st = took_over(p, cl, new, epoch)
        finally:
            os.killpg(p[old].proc.pid, signal.SIGCONT)
        # the old NC comes back as a standby (it stalled with a standby in step, or it sees the higher epoch)
        wait_logged(lambda: (s := ha_status(cl, old)) is not None and s["role"] == "standby" and s["demotions"] >= 1,
                    f"{old} is a standby", servers(p))
        done(p, cl, 1, first["CmdNo"], req["Position"])
        stt = p["drives"].status()
        assert stt is not None and stt["epoch"] == st["epoch"]
        # the old NC never drives again: the host's epoch stays the new one's, and it is back in step as a standby
        wait_logged(lambda: (s := ha_status(cl, old)) is not None and s["in_step"] and time.time() - s["time"] < 1.0,
                    f"{old} in step with {new}", servers(p))
        assert (ha_status(cl, old) or {})["role"] == "standby" and (ha_status(cl, new) or {})["role"] == "active"
        assert (p["drives"].status() or {})["epoch"] == st["epoch"]
        assert tr.restarts == [], tr.restarts
        assert largest_step(tr.samples, CYCLE, A) < 0.05 * V * CYCLE + 1e-6
        assert tr.link.stats()["epoch"] == st["epoch"]
        print(f"frames of a lower epoch dropped by the observer's link: {tr.link.stats()['stale_epoch_frames']}")
    finally:
        tr.close()
        cl.close()


def test_kill_9_during_a_coupling(pair: Callable[..., Procs]) -> None:
    p = pair(axes=2)
    cl, tr = setup(p, [1, 2])
    try:
        m0, s0 = float(cl.nctoplc(1)["SetPos"]), float(cl.nctoplc(2)["SetPos"])  # type: ignore[index]
        gear = cl.request("GearIn", axis=2, Master=1, RatioNumerator=1, RatioDenominator=2)
        assert gear["error"] == 0, gear
        wait_logged(lambda: (j := tr.jobs.get(2)) is not None and int(j["MasterId"]) == 1, "axis 2 coupled", servers(p))
        dist = 10.0 + V * RUN_AFTER_READY
        first, _ = move(cl, 1, m0 + dist)

        def coupled_moving() -> None:  # (the GearIn block may show Done once InGear: not ended, not aborted)
            x = cl.nctoplc(2)
            assert x is not None and int(x["CmdNo"]) == gear["CmdNo"] and int(x["CmdState"]) not in (ABORTED, ERROR)
            assert abs(float(x["SetVelo"])) > 0.5 and int((tr.jobs.get(2) or {"MasterId": 0})["MasterId"]) == 1, x

        _, new, epoch = kill_active(
            p, cl, ready=lambda: wait_logged(lambda: (r := cl.nctoplc(1)) is not None
                                             and float(r["SetPos"]) > m0 + 10.0, "master past 10", servers(p)),
            still=lambda: (moving(cl, 1, first["CmdNo"], m0 + dist), coupled_moving()))
        st = took_over(p, cl, new, epoch)
        done(p, cl, 1, first["CmdNo"], m0 + dist)
        went_on(tr.by_axis[1], st["epoch"], first["CmdNo"])
        r2 = wait_logged(lambda: (x := cl.nctoplc(2)) is not None and abs(float(x["SetPos"]) - s0 - 0.5 * dist) < 1e-6
                         and x, "the slave at its ratio's end position", servers(p))
        # the GearIn block goes on: its CmdNo, no error, still coupled to axis 1 (TwinCAT: InGear until decoupled)
        assert int(r2["CmdNo"]) == gear["CmdNo"] and int(r2["ErrorCode"]) == 0
        assert int(r2["CmdState"]) not in (ABORTED, ERROR)
        assert int(tr.jobs[2]["MasterId"]) == 1
        # in ratio at every cycle both were seen, across the takeover
        master = {c: pos for c, pos, *_ in tr.by_axis[1]}
        pairs = [(master[c], pos) for c, pos, *_ in tr.by_axis[2] if c in master]
        assert len(pairs) > 100
        worst = max(abs((sp - s0) - 0.5 * (mp - m0)) for mp, sp in pairs)
        assert worst < 1e-6, worst
        for a in (1, 2):
            assert largest_step(tr.by_axis[a], CYCLE, A) < 0.05 * V * CYCLE + 1e-6, a
        assert tr.restarts == [], tr.restarts
        # the standby in step holds the NC's tokens too: no "NC gone" (nc_link, the PLC runtime) at the kill
        assert tr.gone == [], tr.gone
    finally:
        tr.close()
        cl.close()


def test_kill_9_during_a_superposition(pair: Callable[..., Procs]) -> None:
    p = pair()
    cl, tr = setup(p, [1])
    try:
        r = cl.request("MoveVelocity", axis=1, Velocity=20.0, Acceleration=A, Deceleration=A, Jerk=J, Direction=1)
        assert r["error"] == 0, r
        wait_logged(lambda: (x := cl.nctoplc(1)) is not None and abs(float(x["SetVelo"]) - 20.0) < 1e-9,
                    "axis 1 at 20 u/s", servers(p))
        # mode 1 (VELOREDUCTION_ADDITIVE): 5 u more over 60 u of process travel, i.e. over 3 s (1 to 4.5 u of it:
        # about RUN_AFTER_READY s or more)
        sup = cl.request("MoveSuperImposed", axis=1, Mode=1, Distance=5.0, VelocityDiff=20.0, Length=60.0,
                         VelocityProcess=20.0)
        assert sup["error"] == 0 and sup["Value"]["ActualDistance"] == 5.0, sup
        wait_logged(lambda: (j := tr.jobs.get(1)) is not None and int(j["SuperCmdNo"]) == sup["CmdNo"]
                    and float(j["SuperDistance"]) == 5.0, "the superposition running", servers(p))
        base = tr.samples[-1]  # (cycle, SetPos, ...): the superposed distance is what SetPos gained beyond 20 u/s

        def superposed() -> float:
            c, pos = tr.samples[-1][:2]
            return (pos - base[1]) - 20.0 * CYCLE * (c - base[0])

        def super_running() -> None:
            j, x = tr.jobs.get(1), cl.nctoplc(1)  # (the newest NCJOBS and NCTOPLC of axis 1)
            assert j is not None and x is not None
            assert int(j["SuperCmdNo"]) == sup["CmdNo"] and int(j["SuperState"]) not in (DONE, ABORTED, ERROR), j
            assert float(x["SetVelo"]) > 20.0 + 1e-6 and superposed() < 4.5, (float(x["SetVelo"]), superposed())

        _, new, epoch = kill_active(
            p, cl, ready=lambda: wait_logged(lambda: superposed() > 1.0, "the superposition well under way (1 of 5 u)",
                                             servers(p)),
            still=super_running)
        st = took_over(p, cl, new, epoch)
        # the new active NC's samples show the superposition still adding velocity: the kill came during it
        assert any(s[6] == st["epoch"] and s[2] > 20.0 + 1e-6 for s in tr.samples), "no superposition after the kill"
        j = wait_logged(lambda: (j := tr.jobs.get(1)) is not None and int(j["SuperCmdNo"]) == sup["CmdNo"]
                        and int(j["SuperState"]) in (DONE, ABORTED, ERROR) and j, "the superposition ended", servers(p))
        assert int(j["SuperState"]) == DONE and int(j["SuperErrorId"]) == 0
        x = cl.nctoplc(1)
        assert x is not None and int(x["ErrorCode"]) == 0 and abs(float(x["SetVelo"]) - 20.0) < 1e-9  # goes on
        assert tr.restarts == [], tr.restarts
        # the standby in step holds the NC's tokens too: no "NC gone" (nc_link, the PLC runtime) at the kill
        assert tr.gone == [], tr.gone
        assert largest_step(tr.samples, CYCLE, A) < 0.05 * V * CYCLE + 1e-6
        cl.request("Halt", axis=1, Deceleration=A, Jerk=J)
    finally:
        tr.close()
        cl.close()
