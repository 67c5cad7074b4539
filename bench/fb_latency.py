"""Function block latency through the real distributed path, next to raw zenoh.

In one run, on 127.0.0.1:
  1. raw zenoh: a client session's ``get`` to a trivial queryable in a router process
     (the same topology as a PLC client and nc-server), one every 10 ms;
  2. an nc-server process and an embedded PLC runtime (``PlcRuntime``, 10 ms cycle): MC_MoveRelative
     Execute edges, 5 mm back and forth with a few PLC cycles at standstill between trials:
       * Execute edge -> the NC's reply in the client process (the reply's arrival, taken by a tap on
         the zenoh ``get`` of the PLC's NC link; the PLC task itself collects replies at its cycle
         start, so its blocks see them up to one PLC cycle later: also printed);
       * Execute edge -> the block sees its command running (``Active``: HasJob with its CmdNo, from
         the first frame with Cycle >= the reply's cycle).

Goals (issue 19; not tests), each printed as the same-run ratio with the absolute figures beside it and
MET / NOT MET:
  * accepted p50 <= 1.5 x raw p50 + 2 NC cycles;
  * accepted p99 <= 3 x raw p99 + 2 NC cycles;
  * (kept from before, with 2 NC cycles) Active seen p50 <= 1.5 x raw p50 + 2 NC cycles + 1 PLC cycle.
Also a same-run noise floor (bench/noise_floor.py: a fixed numpy workload in the NC cycle loop, before and
after the trials) and the machine's busy share during the raw round trips and during the trials
(/proc/stat). bench/many_clients.py runs the same measurement while its 16 clients move
(``--fb-trials``): the goals "also while the 16-client load runs".

    .venv/bin/python bench/fb_latency.py [--trials 60] [--plc-cycle 0.01]
"""
from __future__ import annotations

import argparse
import collections
import sys
import tempfile
import time
from pathlib import Path
from typing import Any, Callable

import msgpack
import zenoh

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from bench.common import Busy, goal_line, pct, use_this_tree, verdict  # noqa: E402

use_this_tree()  # this checkout and its test helpers (znc_testing), also for the processes started
from bench.noise_floor import floor_line  # noqa: E402
from bench.raw_zenoh import RAW_KEY, raw_queryable  # noqa: E402
from znc_testing import free_port, start_nc_server, zenoh_client_config  # noqa: E402

from plc_client import AXIS_REF, MC_MoveRelative, MC_Power  # noqa: E402
from plc_client.runtime import PlcRuntime  # noqa: E402

NC_CYCLE_S = 0.001


def fmt(xs: list[float]) -> str:
    if not xs:
        return "no samples"
    return f"p50 {pct(xs, 50):8.0f}  p99 {pct(xs, 99):8.0f}  max {max(xs):8.0f} us  (n={len(xs)})"


def raw_rtt(n: int, port: int | None = None) -> list[float]:
    """``n`` raw zenoh round trips (after 20 of warm-up), one every 10 ms [us]; a raw queryable router of its
    own unless ``port`` names a running one."""
    out = []
    with raw_queryable(free_port()) if port is None else _nothing(port) as p, zenoh.open(zenoh_client_config(p)) as s:
        for i in range(n + 20):
            t = time.perf_counter()
            replies = list(s.get(RAW_KEY, timeout=5.0))
            dt = (time.perf_counter() - t) * 1e6
            assert replies and replies[0].ok is not None
            if i >= 20:  # warm-up
                out.append(dt)
            time.sleep(0.01)
    return out


class _nothing:
    def __init__(self, v: int) -> None:
        self.v = v

    def __enter__(self) -> int:
        return self.v

    def __exit__(self, *exc: object) -> None:
        return None


# ---- the reply tap -------------------------------------------------------------------------------------------
class _TapRx:
    """What the PLC's command port gets instead of its FifoChannel: the same try_recv, fed by a callback that
    takes the arrival time first."""

    def __init__(self) -> None:
        self.items: collections.deque[Any] = collections.deque()
        self.closed = False

    def try_recv(self) -> Any:
        try:
            return self.items.popleft()
        except IndexError:
            if self.closed:
                raise zenoh.ZError("channel closed") from None  # what an empty, closed FifoChannel raises
            return None

    def recv(self) -> Any:
        while True:
            r = self.try_recv()
            if r is not None:
                return r
            time.sleep(0.0002)

    def __iter__(self) -> Any:
        while True:
            try:
                yield self.recv()
            except zenoh.ZError:
                return


class _TapSession:
    """A zenoh session seen through a tap: a ``get`` on a command key (``/cmd/``) with a channel handler gets a
    callback that calls ``on_reply(key, reply map or None, perf_counter())`` as the reply arrives, then queues
    it for the port; everything else is the session's own."""

    def __init__(self, session: Any, on_reply: Callable[[str, dict[str, Any] | None, float], None]) -> None:
        self._s = session
        self._on_reply = on_reply

    def __getattr__(self, name: str) -> Any:
        return getattr(self._s, name)

    def get(self, key: Any, handler: Any = None, **kw: Any) -> Any:
        k = str(key)
        if "/cmd/" not in k or handler is None:
            return self._s.get(key, handler, **kw)
        on_reply = self._on_reply

        def note(reply: Any) -> None:
            t = time.perf_counter()
            try:
                r = msgpack.unpackb(reply.ok.payload.to_bytes(), strict_map_key=False) if reply.ok is not None else None
            except Exception:
                r = None
            on_reply(k, r if isinstance(r, dict) else None, t)

        if isinstance(handler, tuple) and len(handler) == 2 and callable(handler[0]):  # (callback, handler object)
            cb0 = handler[0]
            return self._s.get(key, (lambda reply: (note(reply), cb0(reply))[1], handler[1]), **kw)
        if callable(handler) and not isinstance(handler, zenoh.handlers.Callback):  # a plain Python callback
            return self._s.get(key, lambda reply: (note(reply), handler(reply))[1], **kw)
        if not isinstance(handler, (zenoh.handlers.FifoChannel, zenoh.handlers.RingChannel)):
            return self._s.get(key, handler, **kw)  # not one we can stand in for: untapped
        rx = _TapRx()

        def arrived(reply: Any) -> None:
            note(reply)
            rx.items.append(reply)

        def dropped() -> None:
            rx.closed = True

        try:
            cb = zenoh.handlers.Callback(arrived, dropped, indirect=False)  # on zenoh's thread: the arrival itself
        except TypeError:
            cb = zenoh.handlers.Callback(arrived, dropped)
        self._s.get(key, cb, **kw)
        return rx


def tap_replies(rt: PlcRuntime, on_reply: Callable[[str, dict[str, Any] | None, float], None]) -> int:
    """Put the tap on the zenoh session of every NC link of ``rt`` (after ``rt.open``); the number tapped."""
    n = 0
    for link in getattr(rt, "links", {}).values():
        s = getattr(link, "session", None)
        if s is not None and not isinstance(s, _TapSession):
            link.session = _TapSession(s, on_reply)
            n += 1
    return n


# ---- the measurement -------------------------------------------------------------------------------------------
def measure(endpoint: str, axis_id: int, trials: int, plc_cycle: float, nc: str = "nc1",
            client_id: str = "bench-fb", timeout: float = 60.0) -> dict[str, Any]:
    """MC_MoveRelative trials on axis ``axis_id`` of the NC at ``endpoint`` from a PlcRuntime in this process.

    Returns {"accept": [us], "refused": {code: n}, "seen_reply": [us], "active": [us], "tapped": links tapped,
    "trials": completed, "busy": Busy of the trials}.
    """
    X = AXIS_REF(nc=nc, axis_id=axis_id)
    power, move = MC_Power(), MC_MoveRelative()
    accept: list[float] = []
    seen_reply: list[float] = []
    active: list[float] = []
    refused: dict[int, int] = {}
    st: dict[str, Any] = {"phase": "idle", "t_edge": 0.0, "sign": 1.0, "n": 0, "settle": 0, "got": False,
                          "reply_seen": False}

    def on_reply(key: str, r: dict[str, Any] | None, t: float) -> None:  # a zenoh thread
        if st["phase"] == "wait" and not st["got"] and f"/axis/{axis_id}/cmd/" in key and r is not None \
                and r.get("cmd", "MoveRelative") == "MoveRelative":
            st["got"] = True
            code = int(r.get("error", 0) or 0)
            if code:
                refused[code] = refused.get(code, 0) + 1
            else:
                accept.append((t - st["t_edge"]) * 1e6)

    def program(plc: PlcRuntime) -> None:
        power(Axis=X, Enable=True, Enable_Positive=True, Enable_Negative=True)
        if not power.Status or st["n"] >= trials:
            return
        if st["phase"] == "idle":
            st["settle"] += 1
            if st["settle"] < 3:  # a few cycles at standstill between trials
                return
            # "wait" before the call: the request goes out inside it, and its reply may arrive (zenoh's thread)
            # before the call returns
            st.update(got=False, reply_seen=False, phase="wait", t_edge=time.perf_counter())
            move(Axis=X, Execute=True, Distance=5.0 * st["sign"], Velocity=400.0)
            return
        move(Axis=X)
        now = time.perf_counter()
        if st["phase"] == "wait" and st["got"] and not st["reply_seen"]:
            st["reply_seen"] = True
            seen_reply.append((now - st["t_edge"]) * 1e6)
        if st["phase"] == "wait" and move.Active:
            active.append((now - st["t_edge"]) * 1e6)
            st["phase"] = "moving"
        if move.Done or move.Error or move.CommandAborted:
            move(Execute=False)
            st.update(phase="idle", sign=-st["sign"], n=st["n"] + 1, settle=0)

    rt = PlcRuntime(program, {nc: endpoint}, cycle_time=plc_cycle, client_id=client_id)
    rt.open(wait=10.0)
    tapped = tap_replies(rt, on_reply)
    deadline = time.monotonic() + timeout
    busy = Busy()
    rt.start()
    try:
        while st["n"] < trials and time.monotonic() < deadline:
            time.sleep(0.05)
    finally:
        busy.stop()
        rt.stop()
    return {"accept": accept, "refused": refused, "seen_reply": seen_reply, "active": active, "tapped": tapped,
            "trials": st["n"], "busy": busy}


def goals(raw: list[float], m: dict[str, Any], plc_cycle: float, where: str = "") -> list[tuple[str, bool]]:
    """The issue's goal lines for one run (``where``: e.g. " under the 16-client load")."""
    raw50, raw99 = pct(raw, 50), pct(raw, 99)
    acc, act = m["accept"], m["active"]
    acc50, acc99, act50 = pct(acc, 50), pct(acc, 99), pct(act, 50)
    cyc = NC_CYCLE_S * 1e6
    b50 = 1.5 * raw50 + 2 * cyc
    b99 = 3.0 * raw99 + 2 * cyc
    bact = 1.5 * raw50 + 2 * cyc + plc_cycle * 1e6
    return [
        goal_line(f"Execute edge -> NC reply (accepted) p50{where} / (1.5 x raw p50 + 2 NC cycles)", acc50 / b50, 1.0,
                  f"{acc50:.0f} us vs 1.5 x {raw50:.0f} + 2 x {cyc:.0f} = {b50:.0f} us; p50 / raw p50 {acc50 / raw50:.1f}x"),
        goal_line(f"Execute edge -> NC reply (accepted) p99{where} / (3 x raw p99 + 2 NC cycles)", acc99 / b99, 1.0,
                  f"{acc99:.0f} us vs 3 x {raw99:.0f} + 2 x {cyc:.0f} = {b99:.0f} us; p99 / raw p99 {acc99 / raw99:.1f}x"),
        goal_line(f"Execute edge -> block Active p50{where} / (1.5 x raw p50 + 2 NC cycles + 1 PLC cycle)",
                  act50 / bact, 1.0, f"{act50:.0f} us vs {bact:.0f} us"),
    ]


def report(raw: list[float], raw_busy: Busy, m: dict[str, Any], plc_cycle: float, where: str = "") -> list[tuple[str, bool]]:
    print(f"raw zenoh get RTT (client -> router queryable):   {fmt(raw)}   [machine {raw_busy.text()}]")
    print(f"Execute edge -> NC reply in the client (accepted): {fmt(m['accept'])}")
    print(f"Execute edge -> the PLC task has the reply:        {fmt(m['seen_reply'])}  (collected at its cycle start)")
    print(f"Execute edge -> block Active (its command runs):   {fmt(m['active'])}")
    ref = m["refused"]
    unseen = m["trials"] - len(m["accept"]) - sum(ref.values())
    print(f"trials {m['trials']}: replies accepted {len(m['accept'])}, refused {sum(ref.values())}"
          + "".join(f", 0x{c:04X} x{n}" for c, n in sorted(ref.items())) + f", not seen by the tap {unseen}"
          + f"; reply tap on {m['tapped']} link(s){'' if m['tapped'] else ' (NONE: no reply times)'}; "
          f"machine during the trials {m['busy'].text()}")
    print(f"(NC cycle {NC_CYCLE_S * 1e3:g} ms, PLC cycle {plc_cycle * 1e3:g} ms: a block sees frames and replies only "
          f"at its cycle starts)")
    return goals(raw, m, plc_cycle, where)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--trials", type=int, default=60)
    ap.add_argument("--plc-cycle", type=float, default=0.010)
    ap.add_argument("--raw", type=int, default=200, help="raw zenoh round trips")
    args = ap.parse_args()
    floor0, f0 = floor_line()
    raw_busy = Busy()
    raw = raw_rtt(args.raw)
    raw_busy.stop()
    with tempfile.TemporaryDirectory() as tmp:
        nc = start_nc_server(Path(tmp))
        try:
            nc.wait_ready()
            m = measure(nc.endpoint, 1, args.trials, args.plc_cycle)
        finally:
            nc.stop()
    floor1, f1 = floor_line()
    print("== FB latency (MC_MoveRelative Execute edge) vs raw zenoh, loopback ==")
    g = report(raw, raw_busy, m, args.plc_cycle)
    print(f"before: {floor0}")
    print(f"after:  {floor1}")
    fl50 = (f0["p50_us"] + f1["p50_us"]) / 2
    print(f"in noise-floor units (figure p50 / floor p50 {fl50:.0f} us, comparable between runs): raw "
          f"{pct(raw, 50) / fl50:5.1f}, accept {pct(m['accept'], 50) / fl50:5.1f}, Active {pct(m['active'], 50) / fl50:5.1f}")
    verdict("fb_latency", g, m["busy"].text())
    return 0 if m["accept"] and m["active"] else 1


if __name__ == "__main__":
    sys.exit(main())
