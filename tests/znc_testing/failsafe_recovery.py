"""Recovery after a router restart or a link cut, measured on real processes (127.0.0.1): shared by
tests/integration/test_failsafe_router.py and bench/recovery.py.

Topology: ``nc-router`` <- ``nc-server --mode client`` (axis 1 "stop_disable"); a ``plc-run`` client
(plc_agent.py: MC_Power + MC_MoveVelocity on axis 1, MC_ReadActualPosition) and a measuring client
(NcTestClient ``op-m``) reach the router through a :class:`failsafe_support.TcpProxy` (the link
the "cut" scenarios cut) or directly ("router" scenario: the router is SIGKILLed and started again on
the same port). Nothing else is restarted.

Figures (seconds, monotonic clock of this process):

* ``detect``: outage -> the PLC's blocks report 0x4B0F;
* ``frame``: router back (its port accepts connections again) / link up -> the first fresh NC
  frame at the PLC (its data valid again);
* ``claim``: -> the PLC's MC_Power holds the axis again (its Claim accepted);
* ``command``: -> the first command of ``op-m`` accepted (Reset of axis 2);
* ``baseline_connect``: same run, a fresh client session opened -> its first accepted command
  (what any connection costs here: the ratio ``command / baseline_connect`` says how much the
  recovery adds to it).

Checked on the way: the NC lost its clients meanwhile and reacted as ClientLossReaction says
(axis 1: 0x8F01, stopped, disabled), and after MC_Reset the PLC powers the axis again.
"""
from __future__ import annotations

import socket
import threading
import time
from pathlib import Path
from typing import Any, Callable

from znc_testing.failsafe_support import TcpProxy, failsafe_config
from plc_client.runtime import client_config
from znc_testing.plc_harness import PlcProcess
from znc_testing import (NcServerProcess, NcTestClient, ReplyError, free_port, start_nc_router, start_nc_server,
                         wait_until)

SCENARIOS = ("router", "cut", "blackhole")
T = 60.0


def _first_ok(cl: NcTestClient, cmd: str, axis: int, deadline: float, **args: Any) -> float:
    """Send ``cmd`` until it is accepted (error 0); the monotonic time of the accepting reply."""
    while True:
        try:
            # short: a query sent while the session is still reconnecting gets no reply; ask again
            r = cl.request(cmd, axis=axis, timeout=0.1, **args)
            if r["error"] == 0:
                return time.monotonic()
        except ReplyError:
            pass
        if time.monotonic() > deadline:
            raise AssertionError(f"{cmd} on axis {axis} not accepted in time")
        time.sleep(0.005)


class ListenWatch:
    """Notes the first moment ``127.0.0.1:<port>`` accepts a TCP connection (polled every 2 ms in a
    thread): when a restarted router is back for its clients. (Its ready line comes later: the NC
    and the PLC, retrying every 100-250 ms, may be reconnected before nc-router prints it.)"""

    def __init__(self, port: int, timeout: float = T) -> None:
        self.port = port
        self.at: float | None = None
        self._stop = threading.Event()
        self._deadline = time.monotonic() + timeout
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set() and time.monotonic() < self._deadline:
            try:
                with socket.create_connection(("127.0.0.1", self.port), timeout=0.05):
                    self.at = time.monotonic()
                    return
            except OSError:
                time.sleep(0.002)

    def wait(self) -> float:
        """The first accepting moment [s, monotonic]."""
        self._thread.join(max(0.0, self._deadline - time.monotonic()))
        self._stop.set()
        if self.at is None:
            raise AssertionError(f"nothing listens on 127.0.0.1:{self.port}")
        return self.at


def baseline_connect(port: int) -> float:
    """A fresh client session: zenoh.open -> its first accepted command [s]."""
    t0 = time.monotonic()
    cl = NcTestClient(port, "op-base", config=client_config(f"tcp/127.0.0.1:{port}"))
    try:
        return _first_ok(cl, "Reset", 2, time.monotonic() + T) - t0
    finally:
        cl.close()


def measure(tmp: Path, scenario: str, log: Callable[[str], None] = print) -> dict[str, float]:
    """Run one scenario (see the module docstring); returns its figures [s].

    Raises:
        AssertionError: something did not recover within the (generous) deadlines.
    """
    assert scenario in SCENARIOS
    rport = free_port()
    router = start_nc_router(tmp / "router", port=rport, extra_args=["--lease-ms", "500"])
    nc: NcServerProcess | None = None
    proxy = TcpProxy(rport) if scenario != "router" else None
    ep = proxy.endpoint if proxy else router.endpoint
    port = proxy.port if proxy else rport
    plc = m = None
    try:
        nc = start_nc_server(tmp / "nc", failsafe_config(["stop_disable", "stop_disable"], watchdog=3.0),
                             extra_args=["--name", "nc1"], connect=router.endpoint)
        plc = PlcProcess(ep, "plc-a")
        plc.wait_started(T)
        m = NcTestClient(port, "op-m", config=client_config(ep))  # a PLC's zenoh settings
        plc.set("pw", "MC_Power", Enable=True, Enable_Positive=True, Enable_Negative=True)
        plc.set("pos", "MC_ReadActualPosition", Enable=True)
        plc.wait("pw", lambda r: r.o["Status"], T)
        plc.set("mv", "MC_MoveVelocity", Execute=True, Velocity=20.0)
        plc.wait("mv", lambda r: r.o["InVelocity"], T)
        base = baseline_connect(port)
        pids = (plc.proc.pid, nc.pid)

        # the outage
        if scenario == "router":
            t_out = time.monotonic()
            router.kill()
        elif scenario == "cut":
            t_out = proxy.cut()  # type: ignore[union-attr]
        else:
            t_out = proxy.blackhole()  # type: ignore[union-attr]
        lost = plc.wait("pos", lambda r: r.t >= t_out and r.o["Error"] and r.o["ErrorID"] == 0x4B0F, T)
        # the NC drops the PLC (its lease) and reacts (0x8F01, checked below) before the way back opens
        wait_until(lambda: "client plc-a lost" in nc.stderr(), T, "the NC to drop plc-a (its log)", interval=0.05)

        # back; op-m asks from now on (in a thread), so its figure does not wait for nc-router's ready line
        accepted: list[float] = []
        asker = threading.Thread(target=lambda: accepted.append(_first_ok(m, "Reset", 2, time.monotonic() + 2 * T)),
                                 daemon=True)
        asker.start()
        if scenario == "router":
            listening = ListenWatch(rport)
            router = start_nc_router(tmp / "router2", port=rport, extra_args=["--lease-ms", "500"])
            t_back = listening.wait()  # the router listens again (before its ready line)
        else:
            t_back = proxy.restore()  # type: ignore[union-attr]
        frame = plc.wait("pos", lambda r: r.t >= t_back and r.o["Valid"], T)
        asker.join(2 * T)
        assert accepted, "op-m's Reset was not accepted in time"
        t_cmd = accepted[0]
        claim = plc.wait("pw", lambda r: r.t >= t_back and r.o["Active"], T)
        # the NC's reaction to losing its client meanwhile (ClientLossReaction "stop_disable")
        err = plc.wait("pw", lambda r: r.t >= t_back and r.a["Valid"] and r.a["ErrorId"] != 0, T)
        assert err.a["ErrorId"] == 0x8F01, err
        assert (plc.proc.pid, nc.pid) == pids and plc.proc.poll() is None and nc.proc.poll() is None
        # and everything works again without a restart
        _first_ok(m, "Reset", 1, time.monotonic() + T)
        plc.wait("pw", lambda r: r.t >= t_back and r.o["Status"], T)
        out = {"detect": lost.t - t_out, "frame": frame.t - t_back, "claim": claim.t - t_back,
               "command": t_cmd - t_back, "baseline_connect": base}
        log(f"[recovery] {scenario:>9}: 0x4B0F after {out['detect'] * 1e3:.0f} ms; back -> first frame "
            f"{out['frame'] * 1e3:.0f} ms, command accepted {out['command'] * 1e3:.0f} ms, claim {out['claim'] * 1e3:.0f} ms "
            f"(fresh connection: {base * 1e3:.0f} ms, ratio {out['command'] / base:.1f})")
        return out
    finally:
        if m is not None:
            m.close()
        if plc is not None:
            plc.stop()
        if nc is not None:
            nc.kill()
        router.kill()
        if proxy is not None:
            proxy.close()
