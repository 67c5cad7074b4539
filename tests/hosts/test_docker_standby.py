"""A hot-standby NC pair in containers (deploy/compose.standby.yaml over compose.yaml and compose.drives.yaml).

One compose project for the module: router, nc1 (node a) and nc1b (node b) serving NC nc1 with
deploy/standby/nc1.toml (cycle 4 ms, takeover_cycles 125; both start as standby, one takes over), nc-drives
(``nc-drive-sim --host drives1``, silence timeout 1 s, longer than the pair's 504 ms takeover bound) and plc2, which powers nc1 axis 2 (a remote
drive) and shuttles it between 0 and 200 at 100 u/s (ZNC_SHARE_S=0: it leaves axis 1 alone).

Three faults of the active node's container, in sequence on the same project, each during a move of axis 2:

1. ``docker kill`` (SIGKILL), then ``docker start``: the old node comes back as a new process;
2. ``docker pause`` (cgroup freezer: the whole container stops, as under SIGSTOP), then ``docker unpause``;
3. ``docker network disconnect`` from the compose network (link cut), then ``network connect``.

Each time (checked hard): the standby takes over (its ha status: role active, a higher epoch), the drive host
follows the new epoch (it never goes back), the NC's Cycle count continues (no restart seen: the per-axis samples'
cycle stamps never go back, as a client takes them: with the epoch rule every client applies, which drops the samples
the old node still puts after a link cut until it hears of its successor; their number is printed), no SetPos step between consecutive samples beyond what the dynamics and the takeover's
catch-up allow, the block running at the cut ends Done (after a kill -9 also: 0x4B0F, the NC's token gone meanwhile:
docs/standby.md), axis 2 keeps moving (two more moves Done), after the restore the old node is a standby in step
and one node is active. With ZNC_STANDBY_STRICT=1 also: exactly one takeover and one epoch change per fault, no
other block error before or after the old node's return (not met on the loaded VM yet).

The test watches through the router as the observer ``status`` with two sessions: :class:`StatusClient` (frames
at 10 Hz, Info) and :class:`Watch`: every per-axis sample of axis 2 with its cycle stamp, the nodes' ha status
``nc/nc1/ha/status/<node>`` and the drive host's status. Measured and printed (``-s``): the takeover as seen by an observer (arrival of the last sample before the
gap -> the first sample after it), the NC's own figure, the largest SetPos step, what plc2 logged.

Uses the images the other Docker tests build (session fixture ``znc_image``); 1.5-4 minutes on the 2-core VM.
Figures and the defects found: docs/standby.md, "Compose scenario".
"""
from __future__ import annotations

import os
import threading
import time
from collections import deque
from typing import Any, Iterator, Sequence

import msgpack
import numpy as np
import pytest

from znc_testing.hostlib import FIGURES, ROOT, StatusClient, cell_ok, client_config, parse_events
from znc_testing import wait_until

from test_docker import COMPOSE_FILE, RECOVER_TIMEOUT, UP_TIMEOUT, ComposeSystem  # noqa: E402 (tests/hosts on sys.path)

pytestmark = [pytest.mark.timeout(1800),  # the first test may build the images (minutes, cold)
              # opt-in as tests/drives/test_standby_process.py: on the loaded 2-core VM the pair still takes over
              # falsely now and then (docs/standby.md, "Compose scenario")
              pytest.mark.skipif(not os.environ.get("ZNC_STANDBY_TESTS"),
                                 reason="hot-standby compose scenario: set ZNC_STANDBY_TESTS=1 (docs/standby.md)")]
#: ZNC_STANDBY_STRICT=1: also no block error beyond the documented 0x4B0F of a kill, exactly one takeover per fault
STRICT = bool(os.environ.get("ZNC_STANDBY_STRICT"))

DRIVES_FILE = ROOT / "deploy" / "compose.drives.yaml"
STANDBY_FILE = ROOT / "deploy" / "compose.standby.yaml"
SERVICES = ("router", "nc1", "nc1b", "nc-drives", "plc2")
#: node name -> compose service (deploy/compose.standby.yaml)
NODES = {"a": "nc1", "b": "nc1b"}
HOLDERS = {("nc1", 2): "plc2"}
AXIS = 2
#: deploy/standby/nc1.toml
CYCLE = 0.004
TAKEOVER_CYCLES = 125
CATCH_UP = 0.010      # [redundancy] catch_up_ms [s]
ACC = 5000.0          # axis 2's AxisAcc = AxisDec [u/s^2] (plc2's moves use the axis's dynamics)
VELOCITY = 100.0      # plc2's moves (ZNC_PLC2_VELOCITY) [u/s]
DRIVE_TIMEOUT = 1.0   # the drive host's silence timeout [s]
#: a freeze or link cut is seen after TAKEOVER_CYCLES without a log; a loaded 2-core VM adds seconds at worst
TAKEOVER_TIMEOUT = 60.0
#: before a fault: the same active node and drive epoch for this long [s]
STABLE_S = 5.0


class Watch:
    """Axis 2's per-axis samples (every cycle, with the cycle stamp), the ha status of each node and the drive
    host's status, on a session of the observer ``status`` (plain TCP without TLS)."""

    def __init__(self, endpoint: str, tls_dir: str | None) -> None:
        import zenoh

        self._lock = threading.Lock()
        #: (arrival wall time, cycle, SetPos, SetVelo, CmdNo, CmdState) of the samples a client takes: the epoch rule
        #: of every client (nc_schema.NcInstance.take: a sample of a lower epoch than one taken is dropped; docs/
        #: standby.md, "The frames' epoch"); an old node back after a link cut still puts its samples until it hears
        #: of its successor, and those are on the wire, not in a client's data
        self.samples: deque[tuple[float, int, float, float, int, int]] = deque(maxlen=400_000)
        #: (arrival wall time) of each sample of a lower epoch dropped by that rule
        self.dropped: deque[float] = deque(maxlen=400_000)
        from nc_schema import NcInstance
        self._inst = NcInstance()
        self.ha: dict[str, tuple[float, dict[str, Any]]] = {}
        self.drive: deque[tuple[float, dict[str, Any]]] = deque(maxlen=20_000)
        self.session = wait_until(lambda: zenoh.open(client_config(endpoint, tls_dir, "status")), 60,
                                  f"a zenoh session to {endpoint} as status", interval=0.5)
        s = self.session
        self._subs = [s.declare_subscriber(f"nc/nc1/axis/{AXIS}/nctoplc", self._on_sample),
                      s.declare_subscriber("nc/nc1/ha/status/*", self._on_ha),
                      s.declare_subscriber("nc/nc1/drive/drives1/status", self._on_drive)]

    def _on_sample(self, sample: Any) -> None:
        from nc_schema import NCTOPLC_DTYPE, decode_stamp_epoch

        t = time.time()
        try:
            r = np.frombuffer(sample.payload.to_bytes(), dtype=NCTOPLC_DTYPE, count=1)[0]
            cycle, _, epoch = decode_stamp_epoch(sample.attachment.to_bytes()) if sample.attachment is not None \
                else (-1, 0, 0)
        except (ValueError, TypeError):
            return
        with self._lock:
            if not self._inst.take(int(cycle), int(epoch), time.monotonic())[0]:
                self.dropped.append(t)
                return
            self.samples.append((t, int(cycle), float(r["SetPos"]), float(r["SetVelo"]), int(r["CmdNo"]),
                                 int(r["CmdState"])))

    @staticmethod
    def _unpack(sample: Any) -> dict[str, Any] | None:
        try:
            d = msgpack.unpackb(sample.payload.to_bytes(), raw=False, strict_map_key=False)
        except Exception:
            return None
        return d if isinstance(d, dict) else None

    def _on_ha(self, sample: Any) -> None:
        d = self._unpack(sample)
        if d is not None:
            with self._lock:
                self.ha[str(sample.key_expr).rsplit("/", 1)[-1]] = (time.time(), d)

    def _on_drive(self, sample: Any) -> None:
        d = self._unpack(sample)
        if d is not None:
            with self._lock:
                self.drive.append((time.time(), d))

    # -- reading ------------------------------------------------------------------------------------------------
    def node(self, name: str, fresh: float = 2.0) -> dict[str, Any] | None:
        """The node's newest ha status, None when older than ``fresh`` seconds (a killed, frozen or cut node)."""
        with self._lock:
            v = self.ha.get(name)
        return None if v is None or time.time() - v[0] > fresh else v[1]

    def since(self, t: float) -> list[tuple[float, int, float, float, int, int]]:
        with self._lock:
            return [s for s in self.samples if s[0] >= t]

    def dropped_since(self, t: float) -> int:
        """Samples of a lower epoch dropped since ``t`` (the old node's, on the wire until it demoted itself)."""
        with self._lock:
            return sum(1 for x in self.dropped if x >= t)

    def latest(self) -> tuple[float, int, float, float, int, int] | None:
        with self._lock:
            return self.samples[-1] if self.samples else None

    def drive_since(self, t: float) -> list[dict[str, Any]]:
        with self._lock:
            return [d for ts, d in self.drive if ts >= t]

    def drive_latest(self) -> dict[str, Any] | None:
        with self._lock:
            return self.drive[-1][1] if self.drive else None

    def close(self) -> None:
        for sub in self._subs:
            try:
                sub.undeclare()
            except Exception:
                pass
        try:
            self.session.close()
        except Exception:
            pass


def largest_step(samples: Sequence[tuple[float, int, float, float, int, int]]) -> tuple[float, float]:
    """(largest |SetPos change| between consecutive samples, largest change beyond what the dynamics allow: the
    larger SetVelo of the two and ACC over the cycles between them). Samples in arrival order; a sample whose
    cycle is not above the previous one is skipped (counted by :func:`cycles_back`)."""
    raw = beyond = 0.0
    prev = None
    for s in samples:
        if prev is not None and s[1] <= prev[1]:
            continue
        if prev is not None:
            dt = (s[1] - prev[1]) * CYCLE
            d = abs(s[2] - prev[2])
            raw = max(raw, d)
            beyond = max(beyond, d - max(abs(s[3]), abs(prev[3])) * dt - 0.5 * ACC * dt * dt)
        prev = s
    return raw, beyond


def cycles_back(samples: Sequence[tuple[float, int, float, float, int, int]]) -> int:
    """Samples whose cycle stamp is not above the newest before it: an NC restart or a second NC's frames."""
    n, top = 0, -1
    for s in samples:
        if s[1] <= top:
            n += 1
        top = max(top, s[1])
    return n


class StandbySystem(ComposeSystem):
    watch: Watch | None = None


@pytest.fixture(scope="module")
def standby_system(znc_image: str, tmp_path_factory: pytest.TempPathFactory) -> Iterator[StandbySystem]:
    s = StandbySystem(znc_image, tmp_path_factory.mktemp("compose-standby"),
                      files=(COMPOSE_FILE, DRIVES_FILE, STANDBY_FILE), services=SERVICES, plcs=("plc2",),
                      identities=("nc1", "plc2", "status", "drives1"),
                      env={"ZNC_SHARE_S": "0", "ZNC_DRIVE_TIMEOUT_S": str(DRIVE_TIMEOUT),
                           "ZNC_PLC2_VELOCITY": str(VELOCITY),
                           # the router keeps a stalled session's tokens: stalls of seconds were seen at load 25-40
                           "ZNC_ROUTER_LEASE_MS": "5000"})
    try:
        t0 = time.monotonic()
        s.up()
        endpoint = f"{s.transport}/127.0.0.1:{s.port}"
        s.status = StatusClient(endpoint, ncs=("nc1",), tls_dir=s.status_tls())
        s.watch = Watch(endpoint, s.status_tls())
        t_up = time.time()
        try:
            wait_until(lambda: cell_ok(s.status, HOLDERS, moved_since=t_up), UP_TIMEOUT,  # type: ignore[arg-type]
                       "plc2 holding nc1 axis 2 (a remote drive) and moving it", interval=0.25)
            wait_until(lambda: pair_ready(s.watch) is not None, UP_TIMEOUT, "an active node and a standby in step",
                       interval=0.25)  # type: ignore[arg-type]
        except AssertionError as exc:
            raise AssertionError(f"{exc}; ha {s.watch.ha if s.watch else None}; {s.diagnosis()}") from None
        FIGURES["scenarios"].append({"where": "docker", "scenario": "standby: up -> axis 2 moving, b in step",
                                     "react_s": None, "recover_s": round(time.monotonic() - t0, 2),
                                     "notes": f"project {s.project}, {s.transport}"})
        yield s
    finally:
        if s.watch is not None:
            s.watch.close()
        s.down()


def pair_ready(w: Watch | None) -> tuple[str, str] | None:
    """(active node, standby node) when one node is active and the other a standby in step; else None."""
    if w is None:
        return None
    st = {n: w.node(n) for n in NODES}
    act = [n for n, d in st.items() if d is not None and d.get("role") == "active"]
    sby = [n for n, d in st.items() if d is not None and d.get("role") == "standby" and d.get("in_step")]
    return (act[0], sby[0]) if len(act) == 1 and len(sby) == 1 else None


def plc_events(system: ComposeSystem, since: float) -> list[Any]:
    return [e for e in parse_events(system.logs("plc2")) if e.t >= since and e.nc == "nc1" and e.axis == AXIS]


def takeover_gap(samples: Sequence[tuple[float, int, float, float, int, int]], t_cut: float,
                 t_took: float) -> tuple[float, int, int, float]:
    """The observer's takeover: the largest arrival gap between consecutive samples from ``t_cut`` (- 0.5 s: the
    docker command's own latency) to 1 s after the takeover was seen -> (gap [s], cycle of the last sample before
    it, of the first after it, SetVelo of the first after it)."""
    best = (0.0, -1, -1, 0.0)
    for a, b in zip(samples, samples[1:]):
        if t_cut - 0.5 <= b[0] <= t_took + 1.0 and b[0] - a[0] > best[0]:
            best = (b[0] - a[0], a[1], b[1], b[3])
    return best


def run_fault(system: StandbySystem, name: str, cut: Sequence[Sequence[str]], restore: Sequence[Sequence[str]],
              restarted: bool) -> None:
    """One fault of the active node's container during a move of axis 2, then its restore; checks and figures."""
    w, st = system.watch, system.status
    assert w is not None and st is not None
    # the pair settled: the same active node and drive epoch for STABLE_S (a loaded machine's false takeovers before
    # the fault would be counted as its effects)
    calm: dict[str, Any] = {}

    def settled() -> Any:
        p, d = pair_ready(w), w.drive_latest()
        now = time.time()
        key = (p, d and d.get("epoch"))
        if p is None or d is None or calm.get("key") != key:
            calm.update(key=key, since=now)
            return False
        return now - calm["since"] >= STABLE_S and p
    pair = wait_until(settled, RECOVER_TIMEOUT * 2, f"the pair settled before {name}", interval=0.2)
    t_stable = calm["since"]
    active, standby = pair
    target = NODES[active]
    fmt = {"id": system.cid(target), "net": system.network, "alias": target}
    before_ha = {n: dict(w.node(n) or {}) for n in NODES}
    drive0 = wait_until(lambda: w.drive_latest(), 30.0, "the drive host's status")
    others = {s: system.started(s) for s in SERVICES if s != target}
    mine = system.started(target)

    # a move of axis 2 in its first half (2 s per move at 100 u/s: the docker command lands in it)
    def early_in_a_move() -> bool | str:
        x = w.latest()
        if x is None:
            return "no samples"
        _, _, pos, velo, _, _ = x
        going_up, going_down = velo > 0.8 * VELOCITY, velo < -0.8 * VELOCITY
        return (going_up and 20.0 < pos < 70.0) or (going_down and 130.0 < pos < 180.0) or f"SetPos {pos} {velo}"
    wait_until(early_in_a_move, RECOVER_TIMEOUT, f"axis 2 early in a move before {name}", interval=0.005)
    t_cut = time.time()
    moving_at_cut = w.latest()
    restored = False
    try:
        for c in cut:
            system.docker(*(a.format(**fmt) for a in c))
        t_cut_done = time.time()

        # the standby takes over with a higher epoch; the drive host follows it
        def took_over() -> dict[str, Any] | bool | str:
            d = w.node(standby)
            return (d is not None and d.get("role") == "active" and d.get("epoch", 0) > before_ha[active]["epoch"]
                    and d) or f"{standby}: {d}"
        new = wait_until(took_over, TAKEOVER_TIMEOUT, f"{standby} took over after {name}", interval=0.01)
        t_took = time.time()
        epoch = int(new["epoch"])
        wait_until(lambda: (d := w.drive_latest()) is not None and d["epoch"] == epoch or f"drive {d and d['epoch']}",
                   30.0, "the drive host follows the new epoch", interval=0.05)
        # the move in progress at the cut ends Done, and the next one too (axis 2 keeps moving)
        def moves_done() -> bool | str:
            ev = plc_events(system, t_cut - 3.0)
            done = [e for e in ev if e.text.startswith("done at") and e.t > t_cut]
            moves_after = [e for e in ev if e.text.startswith("move ->") and e.t > t_cut]
            return (len(done) >= 2 and len(moves_after) >= 1) or f"plc2: {[e.text for e in ev][-6:]}"
        wait_until(moves_done, RECOVER_TIMEOUT, f"plc2's moves Done after {name}", interval=0.25)
        t_moves = time.time()

        # the old node back
        for c in restore:
            system.docker(*(a.format(**fmt) for a in c))
        restored = True
        t_restore = time.time()

        seen: list[bool] = []

        def old_is_standby() -> bool | str:  # (seen once as a standby in step; then the pair settled)
            d = w.node(active)
            if d is not None and d.get("role") == "standby" and d.get("in_step") and (
                    restarted or d.get("demotions", 0) > before_ha[active].get("demotions", 0)):
                seen.append(True)
            return (bool(seen) and pair_ready(w) is not None) or f"{active}: {d}"
        wait_until(old_is_standby, RECOVER_TIMEOUT, f"{active} a standby in step after the restore of {name}",
                   interval=0.1)
        # the pair settled: moves go on under the new active node; then the checks over the whole window
        t_settled = time.time()
        wait_until(lambda: len([e for e in plc_events(system, t_settled) if e.text.startswith("done at")]) >= 1,
                   RECOVER_TIMEOUT, f"a move Done after the old node's return ({name})", interval=0.25)
        t_end = time.time()
    finally:
        if not restored:
            for c in restore:
                system.docker(*(a.format(**fmt) for a in c), check=False)

    t_from = max(t_stable, t_cut - 3.0)
    samples = w.since(t_from)
    gap, c_last, c_first, v_first = takeover_gap(samples, t_cut, t_took)
    raw, beyond = largest_step(samples)
    back = cycles_back(samples)
    dropped = w.dropped_since(t_from)
    ev = plc_events(system, t_from)

    def bad(e: Any) -> bool:
        return e.text.startswith(("error", "aborted", "axis error", "reset error"))
    # a kill -9 deletes the NC's liveliness token nc/nc1/alive until the standby declares it at its takeover: the
    # PLC's blocks end with 0x4B0F at once (plc_client: "NC nc1 is gone"); a known gap (docs/standby.md)
    known = "0x4B0F" if restarted else None
    during = [e.text for e in ev if t_cut < e.t <= t_restore and bad(e) and not (known and known in e.text)]
    after = [e.text for e in ev if e.t > t_restore and bad(e)]
    gone_errors = len([e for e in ev if t_cut < e.t <= t_restore and bad(e) and known and known in e.text])
    # how the block running at the cut ended: its first Done or error after the cut
    first_end = next((e.text for e in ev if e.t > t_cut and (e.text.startswith("done at") or bad(e))), None)
    epochs = [int(d["epoch"]) for d in w.drive_since(t_from)]
    rises = sum(1 for x, y in zip(epochs, epochs[1:]) if y != x)
    final = {n: w.node(n) or {} for n in NODES}
    final_pair = pair_ready(w)
    extra = [f"{n}: takeovers +{int(final[n].get('takeovers', 0)) - int(before_ha[n].get('takeovers', 0))}"
             for n in NODES]
    drive1 = w.drive_latest() or {}
    new_takeovers = int(final[standby].get("takeovers", 0)) - int(before_ha[standby].get("takeovers", 0))
    line = (f"{name}: takeover seen by an observer {gap * 1e3:.0f} ms (last sample cycle {c_last} -> first "
            f"{c_first} at {v_first:.1f} u/s; cut command {(t_cut_done - t_cut) * 1e3:.0f} ms, role change seen {(t_took - t_cut) * 1e3:.0f} "
            f"ms after it was issued), the NC's own {new.get('takeover_ms')} ms / {new.get('takeover_cycles')} "
            f"cycles (limit {new.get('takeover_limit_cycles')}), caught up {new.get('catch_up_cycles')}; "
            f"largest SetPos step {raw:.4f} u (beyond the dynamics {beyond:.6f}), cycle went back {back}x (samples of a lower epoch "
            f"dropped by the clients' epoch rule: {dropped}); "
            f"drive epoch {drive0['epoch']} -> {epoch} ({rises} change(s), refused {drive1.get('stale_epoch')}); "
            f"moving at the cut {moving_at_cut and round(moving_at_cut[3], 1)} u/s; 0x4B0F at the NC's token loss: "
            f"{gone_errors}; the block at the cut: {first_end!r}; plc2 errors during the takeover {during}, after "
            f"the return {after}; {', '.join(extra)}; plc2 after the cut: "
            f"{[e.text for e in ev if e.t > t_cut]}; old node {active}: {final[active].get('role')} "
            f"(demotions {final[active].get('demotions')}), {standby} takeovers +{new_takeovers}")
    print("\n" + line)
    FIGURES["scenarios"].append({"where": "docker", "scenario": f"standby: {name}",
                                 "react_s": round(gap, 3), "recover_s": round(t_end - t_restore, 2),
                                 "notes": f"step {raw:.4f} (beyond {beyond:.6f}), NC {new.get('takeover_ms')} ms"})
    try:
        # the safety: no NC restart seen, no jump, the drive host's epoch never goes back, one active node in the end
        assert c_first > c_last, f"the Cycle count went back at the takeover: {c_last} -> {c_first}"
        assert back == 0, f"{back} samples with a cycle not above the previous (a restart or a second NC)"
        # (the takeover may step over catch_up_ms at once: the drives extrapolated their targets that long)
        assert beyond < VELOCITY * CATCH_UP + 1e-3, f"a SetPos step beyond the dynamics: {beyond} (largest {raw})"
        assert raw < VELOCITY * 0.2, raw  # (a catch-up of at most 10 ms + a loaded observer's lost samples)
        assert all(y >= x for x, y in zip(epochs, epochs[1:])) and epochs[-1] >= epoch, epochs
        assert final_pair is not None, f"not one active node and one standby in step in the end: {final}"
        # the block running at the cut ends Done (after a kill -9: or with the documented 0x4B0F)
        assert first_end is not None and (first_end.startswith("done at") or (known and known in first_end)), \
            first_end
        if STRICT:  # also: no other block error, one takeover only (not met on a loaded machine yet: docs/standby.md)
            assert during == [], f"plc2's errors during the takeover: {during}"
            assert after == [], f"plc2's errors after the old node's return: {after}"
            assert new_takeovers == 1, (before_ha[standby], final[standby])
            assert rises == 1 and epochs[-1] == epoch, f"drive host epochs since the cut: {sorted(set(epochs))}"
            assert final[standby].get("role") == "active" and final[active].get("role") == "standby", final
        assert {s: system.started(s) for s in others} == others, "another container was restarted"
        assert (system.started(target) != mine) == restarted
        assert st.latest("nc1", AXIS) is not None and st.frame_age("nc1") < 5.0
        claims = st.claims("nc1")
        assert claims is not None and claims.get(AXIS) == "plc2", f"Info claims after {name}: {claims}"
    except AssertionError as exc:
        raise AssertionError(f"{exc}\n{line}\n{system.diagnosis()}") from None


DISCONNECT = [["network", "disconnect", "{net}", "{id}"]]
CONNECT = [["network", "connect", "--alias", "{alias}", "{net}", "{id}"]]


def test_kill_of_the_active_nc_then_start(standby_system: StandbySystem) -> None:
    run_fault(standby_system, "kill -9 / start", [["kill", "{id}"]], [["start", "{id}"]], restarted=True)


def test_pause_of_the_active_nc_then_unpause(standby_system: StandbySystem) -> None:
    run_fault(standby_system, "pause / unpause", [["pause", "{id}"]], [["unpause", "{id}"]], restarted=False)


def test_link_cut_of_the_active_nc_then_reconnect(standby_system: StandbySystem) -> None:
    run_fault(standby_system, "link cut / reconnect", DISCONNECT, CONNECT, restarted=False)
