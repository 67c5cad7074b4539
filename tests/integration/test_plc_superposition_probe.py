"""MC_MoveSuperImposedExt / MC_AbortSuperposition, MC_ExtSetPointGenEnable / Feed / Disable (and the
watchdog of a feeding PLC that dies), MC_TouchProbe / MC_AbortTrigger (a simulated sensor pattern,
and the PlcEvent source) through the real distributed path: ``nc-server`` and ``plc-run`` processes
on 127.0.0.1, free ports, killed with their process groups at the end, pass or fail.

The PLC program is test_plc_coupling.py's scriptable agent (:class:`ExtPlc`): blocks with
VAR_IN_OUT references, and hooks - code run in every PLC cycle inside the PLC program - for the
set-point generator and the PlcEvent signal. Positions are asserted, never how fast anything
happened; where a PLC stall of the loaded machine could matter the check is made weaker, never wrong
(e.g. the fed ramp is a function of the PLC's clock, so a late cycle feeds where the NC's
extrapolation already is).
"""
from __future__ import annotations

import math
import os
import signal
import threading
from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

from nc_schema import NCTOPLC_DTYPE
from nc_server.server.config import default_config_text
from znc_testing.plc_harness import NC_ARGS, T, Rec, ended, exclusive
from test_plc_coupling import ExtPlc, axis_config, clean, power_both, xp, xplc  # noqa: F401 (fixtures)
from znc_testing import NcServerProcess, NcTestClient, wait_until

#: the NC cycle [s] (default configuration)
DT = 0.001
#: AxisTargetPositionWindow of axis 1
WINDOW = 0.02


def trace_between(p: ExtPlc, axis: int, c0: int, c1: float = math.inf) -> list[Rec]:
    return [s for s in p.trace_of(axis) if c0 <= s.c <= c1]


# ---- superposition --------------------------------------------------------------------------------
def cruise(p: ExtPlc, v0: float) -> Rec:
    """Axis 1 powered, at constant velocity ``v0`` (MC_MoveVelocity), traced; returns a sample at it."""
    power_both(p, 1)
    p.trace(1)
    p.set("mv", "MC_MoveVelocity", Execute=True, Velocity=v0, Acceleration=1000.0, Deceleration=1000.0)
    iv = p.wait("mv", lambda r: r.o["InVelocity"] or ended(r), T)
    assert iv.o["InVelocity"], iv
    return p.wait_trace(1, lambda s: s.c > iv.c and s.a["SetVelo"] == v0 and s.a["SetAcc"] == 0.0, T)


def offset(ref: Rec, s: Rec, v0: float) -> float:
    """How far sample ``s`` is ahead of the uncorrected motion at ``v0`` through ``ref``."""
    return s.a["SetPos"] - (ref.a["SetPos"] + v0 * (s.a["NcCycle"] - ref.a["NcCycle"]) * DT)


def test_move_superimposed_ext_adds_distance_to_a_constant_velocity(xp: ExtPlc) -> None:
    v0, dist, length = 50.0, 10.0, 50.0
    ref = cruise(xp, v0)
    # VELOREDUCTION_ADDITIVEMOTION: the correction takes the whole window Length / v0 = 1 s
    xp.set("sup", "MC_MoveSuperImposedExt", Execute=True, Mode=1, Distance=dist, VelocityDiff=50.0, Length=length,
           VelocityProcess=v0)
    busy = xp.wait("sup", lambda r: r.o["Busy"] or ended(r), T)
    done = xp.wait("sup", ended, T)
    assert done.o["Done"], (done, xp.history("sup"))
    clean(xp.history("sup"))
    o = done.o
    assert math.isclose(o["ActualDistance"], dist, abs_tol=1e-9), o
    assert math.isclose(o["ActualLength"], length, rel_tol=1e-6), f"ADDITIVE: the reference's travel: {o}"
    assert 0.0 < o["ActualVelocityDiff"] <= 50.0 + 1e-9, o
    # the outputs keep their values after Execute falls
    c = xp.sync()
    xp.set("sup", Execute=False)
    r = xp.wait("sup", lambda r: r.c > c and not r.o["Done"], T)
    assert r.o["ActualDistance"] == o["ActualDistance"] and r.o["ActualLength"] == o["ActualLength"], r
    xp.wait_cycles(10)
    samples = trace_between(xp, 1, ref.c)
    after = [s for s in samples if s.c > done.c]
    assert len(after) >= 5, after
    for s in after:  # ahead of the uncorrected motion by exactly ActualDistance, at v0 again
        assert math.isclose(offset(ref, s, v0), o["ActualDistance"], abs_tol=1e-6), s
        assert s.a["SetVelo"] == v0, s
        assert abs(s.a["ActPos"] - s.a["SetPos"]) < 0.5, f"the drive follows: {s}"
    offsets = [offset(ref, s, v0) for s in samples if s.c <= done.c]
    assert all(-1e-6 <= x <= dist + 1e-6 for x in offsets), offsets
    assert all(b >= a - 1e-6 for a, b in zip(offsets, offsets[1:])), f"a one-way correction: {offsets}"
    # it took (at least) its window: from the last uncorrected sample to the first complete one
    before = [s for s in samples if offset(ref, s, v0) <= 1e-9]
    complete = [s for s in samples if offset(ref, s, v0) >= dist - 1e-9]
    assert before and complete, samples[-3:]
    took = (complete[0].a["NcCycle"] - before[-1].a["NcCycle"]) * DT
    assert took >= o["ActualLength"] / v0 - 2 * DT, (took, o)
    # the axis travelled ActualLength + ActualDistance while it was corrected (ADDITIVE)
    travel = complete[0].a["SetPos"] - before[-1].a["SetPos"]
    assert math.isclose(travel, v0 * took + o["ActualDistance"], abs_tol=1e-6), (travel, took)
    assert travel >= o["ActualLength"] + o["ActualDistance"] - v0 * 2 * DT, (travel, o)
    assert busy.c <= done.c


def test_move_superimposed_and_the_incomplete_compensation(xp: ExtPlc) -> None:
    """MC_MoveSuperImposed (LENGTHREDUCTION_LIMITEDMOTION, MaxDistance): Done with the distance gained;
    then one whose Distance cannot fit (VelocityDiff 5 over 20 u of travel): Error 0x4243 at its end,
    the largest possible distance applied (TcMC 3.9)."""
    v0 = 50.0
    ref = cruise(xp, v0)
    xp.set("sup", "MC_MoveSuperImposed", Execute=True, Distance=5.0, VelocityDiff=20.0, MaxDistance=200.0,
           VelocityProcess=v0)
    done = xp.wait("sup", ended, T)
    assert done.o["Done"], (done, xp.history("sup"))
    clean(xp.history("sup"))
    xp.wait_cycles(5)
    s = xp.wait_trace(1, lambda s: s.c > done.c, T)
    assert math.isclose(offset(ref, s, v0), 5.0, abs_tol=1e-6), s
    xp.set("sup", Execute=False)
    xp.wait("sup", lambda r: not ended(r), T)
    ref2 = xp.wait_trace(1, lambda s: s.c > done.c + 2, T)
    xp.set("sx", "MC_MoveSuperImposedExt", Execute=True, Mode=4, Distance=50.0, VelocityDiff=5.0, Length=20.0,
           VelocityProcess=v0)
    r = xp.wait("sx", ended, T)
    assert r.o["Error"] and r.o["ErrorID"] == 0x4243, (r, xp.history("sx"))
    gained = r.o["ActualDistance"]
    assert 0.0 < gained < 50.0, r.o
    xp.wait_cycles(5)
    s2 = xp.wait_trace(1, lambda s: s.c > r.c, T)
    assert math.isclose(offset(ref2, s2, v0), gained, abs_tol=1e-6), (s2, gained)


def test_abort_superposition(xp: ExtPlc) -> None:
    v0, dist = 50.0, 10.0
    ref = cruise(xp, v0)
    # a slow correction: a window of 400 / 50 = 8 s
    xp.set("sup", "MC_MoveSuperImposedExt", Execute=True, Mode=1, Distance=dist, VelocityDiff=50.0, Length=400.0,
           VelocityProcess=v0)
    xp.wait("sup", lambda r: r.o["Busy"] or ended(r), T)
    s = xp.wait_trace(1, lambda s: offset(ref, s, v0) > 0.05, T)
    assert not ended(xp.last("sup")), xp.last("sup")
    xp.set("ab", "MC_AbortSuperposition", Execute=True)
    ab = xp.wait("ab", ended, T)
    assert ab.o["Done"], ab
    r = xp.wait("sup", ended, T)
    assert r.o["CommandAborted"], (r, xp.history("sup"))
    exclusive(xp.history("sup"))
    exclusive(xp.history("ab"))
    # the basic motion goes on at v0 with what was superimposed so far (the offset brakes to rest)
    late = xp.wait_trace(1, lambda x: x.c > ab.c + 20 and x.a["SetVelo"] == v0 and x.a["SetAcc"] == 0.0, T)
    xp.wait_cycles(10)
    tail = trace_between(xp, 1, late.c)
    kept = offset(ref, late, v0)
    assert offset(ref, s, v0) <= kept < dist - 1.0, f"part of the distance, not all of it: {kept}"
    for x in tail:
        assert math.isclose(offset(ref, x, v0), kept, abs_tol=1e-6) and x.a["SetVelo"] == v0, x
    assert not any(x.a["ErrorId"] for x in tail), tail[-1]


# ---- external set-point generator ------------------------------------------------------------------
#: A trapezoid ramp of D [u] at V [u/s], A [u/s^2] from where axis ``AX`` stands once MC_ExtSetPointGenEnable
#: ``EN`` is Done and ``go`` is set, computed every PLC cycle from the PLC's clock (a late cycle feeds
#: where the NC's extrapolation of the previous feed already is) and fed with MC_ExtSetPointGenFeed;
#: after the ramp its end is fed on. ``stop`` (var): feed nothing from then on.
RAMP = """
if state == "wait" and go and fb(EN).Done and fb(EN).Enabled:
    state, t0, p0 = "run", now(), float(ax(AX).NcToPlc["SetPos"])
if state in ("run", "end") and not stop:
    t = now() - t0
    ta = V / A
    da = 0.5 * V * ta
    tc = (D - 2.0 * da) / V
    if t < ta:
        p, v, a = 0.5 * A * t * t, A * t, A
    elif t < ta + tc:
        p, v, a = da + V * (t - ta), V, 0.0
    elif t < 2.0 * ta + tc:
        td = t - ta - tc
        p, v, a = D - da + V * td - 0.5 * A * td * td, V - A * td, -A
    else:
        p, v, a, state = D, 0.0, 0.0, "end"
    Feed(p0 + p, v, a, 1 if v > 0 else 0, ax(AX))
    r = ax(AX).NcToPlc
    emit(st=state, p0=p0, p=p0 + p, v=v, sp=float(r["SetPos"]), sv=float(r["SetVelo"]),
         nc=int(ax(AX).Status.NcCycleCounter), en=fb(EN).Enabled, t=now())
"""
NOT_MOVING, EXT_ENABLED = 1 << 2, 1 << 14  # StateDWord
#: axis 1 with a large AxisVeloMax: the NC's "no jump" reach per NC cycle (AxisVeloMax x 1.5 cycles)
#: tolerates the delivery jitter of the fed set-points on a loaded machine (V x jitter)
EXT_CONFIG = axis_config(default_config_text(), 1, AxisVeloMax=5000.0)


#: a stall of the loaded machine [s] (the PLC's cycle, or the NC's clock against the PLC's) long enough to
#: turn the ramp's feeds into a jump the NC refuses: the fed acceleration carries the NC's set-point on
#: while no feed comes (at the end of the acceleration phase a pause of 0.25 s is 0x4359)
STALL = 0.1
#: the ramps' acceleration [u/s^2]: the NC carries the last fed acceleration while no feed arrives, and refuses
#: the next feed as a jump beyond amax T^2 / 2 (amax 5000, T <= 50 ms: 6.5 u); at the end of an acceleration
#: of A a gap g in the feeds' delivery is 0.5 A g^2 off: at 200 a 0.25 s gap of the PLCTONC path alone (no
#: clock of the records showed it: CI saw 0x4359 with the records' longest stall 0.044 s), at 20 one of 0.8 s
RAMP_ACC = 20.0


@dataclass
class Fed:
    """A ramp run by :func:`feed_ramp`: the MC_ExtSetPointGenEnable block ``en`` and its Done record
    ``enabled``, the hook ``gen`` and its record that met the condition, ``reached``."""
    en: str
    enabled: Rec
    gen: str
    reached: Rec


def enable_ext(p: ExtPlc, name: str = "en") -> Rec:
    """MC_ExtSetPointGenEnable ``name`` on axis 1 (Done, Enabled); returns the Done record."""
    p.set(name, "MC_ExtSetPointGenEnable", Execute=True, Position=0.0, PositionType=1)
    en = p.wait(name, ended, T)
    assert en.o["Done"] and en.o["Enabled"], en
    assert en.a["StateDWord"] & EXT_ENABLED, f"ExtSetPointGenEnabled in the StateDWord: {en}"
    return en


def stall_of(recs: list[Rec]) -> float:
    """The longest stall the ramp's records show [s]: a PLC cycle late (the PLC's clock between two
    records), or the NC's clock falling behind the PLC's (their difference's spread)."""
    if len(recs) < 2:
        return 0.0
    ts = [r.o["t"] for r in recs]
    lag = [r.o["t"] - r.o["nc"] * DT for r in recs]
    return max(max(b - a for a, b in zip(ts, ts[1:])), max(lag) - min(lag))


def feed_ramp(p: ExtPlc, d: float, until: Callable[[Rec], bool], name: str = "gen", en: str | None = None,
              tries: int = 3) -> Fed:
    """Enable the generator (unless block ``en`` has), run the ramp of ``d`` [u] as hook ``name`` and wait
    for a record that meets ``until``. The ramp is a function of the PLC's clock: a loaded machine that
    stalls the PLC (or the NC) long enough makes it a jump, which the NC rightly refuses (0x4359, the
    generator disabled); such a loss, proven by the records' clocks, is reset and run again (at most
    ``tries`` times). Any other loss fails. Traces axis 1."""
    p.trace(1)
    for k in range(tries):
        gen = f"{name}{k}" if k else name
        if en is None:
            en = f"en_{gen}"
            enabled = enable_ext(p, en)
        else:
            last = p.last(en)
            assert last is not None and last.o["Enabled"], last
            enabled = last
        p.hook(gen, RAMP, AX=1, EN=en, D=d, V=20.0, A=RAMP_ACC, state="wait", go=True, stop=False, t0=0.0, p0=0.0)
        r = p.wait(gen, lambda r: not r.o["en"] or until(r), T)
        if r.o["en"]:
            return Fed(en, enabled, gen, r)
        p.unhook(gen)
        recs = p.hook_records(gen)
        stall = stall_of(recs)
        errs = [s.a["ErrorId"] for s in trace_between(p, 1, recs[0].c) if s.a["ErrorId"]]
        assert errs and errs[0] == 0x4359 and stall > STALL, \
            f"generator {gen} lost (axis errors {errs}, longest stall {stall:.3f} s): {r}"
        p.set(f"rst{k}", "MC_Reset", Execute=True)
        rst = p.wait(f"rst{k}", ended, T)
        assert rst.o["Done"], rst
        p.wait_trace(1, lambda s: s.c > rst.c and s.a["State"] == "STANDSTILL", T)  # (it brakes on)
        en = None
    raise AssertionError(f"the ramp lost to a stall {tries} times in a row")


def test_ext_set_point_generator_follows_a_fed_ramp_and_disable_stops(start_nc: Callable[..., NcServerProcess],
                                                                     xplc: Callable[..., ExtPlc]) -> None:
    p = xplc(start_nc(config_text=EXT_CONFIG, extra_args=NC_ARGS))
    power_both(p, 1)
    p.trace(1)
    # the axis follows the ramp and ends exactly at its end
    ramp = feed_ramp(p, 30.0, lambda r: r.o["st"] == "end" and r.o["sv"] == 0.0 and abs(r.o["sp"] - r.o["p"]) < 1e-9)
    end, en = ramp.reached, ramp.enabled
    recs = p.hook_records(ramp.gen)
    p0 = recs[0].o["p0"]
    assert math.isclose(p0, en.a["SetPos"], abs_tol=1e-9), "started where the axis stood"
    assert math.isclose(end.o["sp"], p0 + 30.0, abs_tol=1e-9), end
    assert all(r.o["en"] for r in recs), "Enabled while fed"
    cruising = [r for r in recs if r.o["sv"] == 20.0]
    assert len(cruising) >= 10, "the NC took the fed velocity"
    for r in recs:  # never outside what the generator produced (plus a PLC stall's extrapolation)
        assert p0 - 1e-9 <= r.o["sp"] <= p0 + 30.0 + 0.5, r
    assert not any(s.a["ErrorId"] for s in trace_between(p, 1, en.c)), p.trace_of(1)[-1]
    # a second ramp, long: MC_ExtSetPointGenDisable while it cruises
    p.unhook(ramp.gen)
    ramp2 = feed_ramp(p, 1000.0, lambda r: r.o["sv"] == 20.0, name="gen2", en=ramp.en)
    cr = ramp2.reached
    p.set("dis", "MC_ExtSetPointGenDisable", Execute=True)
    dis = p.wait("dis", ended, T)
    assert dis.o["Done"] and not dis.o["Enabled"], dis
    p.var(ramp2.gen, stop=True)
    s = p.wait_trace(1, lambda s: s.c > dis.c and s.a["SetVelo"] == 0.0 and s.a["StateDWord"] & NOT_MOVING, T)
    assert s.a["State"] == "STANDSTILL" and not s.a["ErrorId"] and not s.a["StateDWord"] & EXT_ENABLED, s
    clean(p.history("dis"))
    assert not p.last(ramp2.en).o["Enabled"], p.last(ramp2.en)
    # no jump: between two PLC samples no more than the fed velocity allows (while fed, plus the
    # difference of the PLC's and the NC's clocks a new feed makes up for), never backwards; the
    # braking after the disable strictly, its velocity falling
    tr = trace_between(p, 1, cr.c, s.c + 10)
    for a, b in zip(tr, tr[1:]):
        dt = (b.a["NcCycle"] - a.a["NcCycle"]) * DT
        slack = 1e-9 if a.c >= dis.c else 0.5  # (0.5: as the bound above; CI under load saw 0.3 once)
        assert 0.0 <= b.a["SetPos"] - a.a["SetPos"] <= 20.0 * dt + slack, (a, b)
        assert 0.0 <= b.a["SetVelo"] <= 20.0 + 1e-9, b
        assert a.c < dis.c or b.a["SetVelo"] <= a.a["SetVelo"], (a, b)
    rest = trace_between(p, 1, s.c)
    assert all(x.a["SetPos"] == s.a["SetPos"] for x in rest), "it stays"


def test_ext_set_point_disable_brake_is_not_standstill(start_nc: Callable[..., NcServerProcess],
                                                       xplc: Callable[..., ExtPlc]) -> None:
    # a soft AxisDec (100 u/s^2: ~0.2 s of braking from 20 u/s) so that many PLC cycles see the ramp
    p = xplc(start_nc(config_text=axis_config(EXT_CONFIG, 1, AxisDec=100.0), extra_args=NC_ARGS))
    power_both(p, 1)
    p.trace(1)
    ramp = feed_ramp(p, 1000.0, lambda r: r.o["sv"] == 20.0)
    p.set("dis", "MC_ExtSetPointGenDisable", Execute=True)
    dis = p.wait("dis", ended, T)
    assert dis.o["Done"], dis
    p.var(ramp.gen, stop=True)
    s = p.wait_trace(1, lambda s: s.c > dis.c and s.a["SetVelo"] == 0.0 and s.a["StateDWord"] & NOT_MOVING, T)
    braking = [x for x in trace_between(p, 1, dis.c, s.c) if x.a["SetVelo"] > 0.0]
    assert len(braking) >= 3, braking
    wrong = [x for x in braking if x.a["State"] == "STANDSTILL"]
    assert not wrong, f"{len(wrong)} of {len(braking)} braking samples in STANDSTILL, e.g. {wrong[0]}"


def test_killed_feeding_plc_the_axis_stops(start_nc: Callable[..., NcServerProcess], xplc: Callable[..., ExtPlc],
                                           nc_client: Callable[..., NcTestClient]) -> None:
    nc = start_nc(config_text=EXT_CONFIG, extra_args=("--watchdog-timeout", "1.0"))
    p = xplc(nc)
    # an observer without a claim: every NCTOPLC sample of axis 1
    obs = nc_client(nc.port)
    seen: list[tuple[float, float, int, int]] = []
    lock = threading.Lock()

    def on_sample(sample: Any) -> None:
        r = np.frombuffer(sample.payload.to_bytes(), dtype=NCTOPLC_DTYPE, count=1)[0]
        with lock:
            seen.append((float(r["SetPos"]), float(r["SetVelo"]), int(r["ErrorCode"]), int(r["StateDWord"])))

    sub = obs.session.declare_subscriber("nc/nc1/axis/1/nctoplc", on_sample)  # (closed with the session)
    power_both(p, 1)
    feed_ramp(p, 1000.0, lambda r: r.o["sv"] == 20.0)
    wait_until(lambda: seen and seen[-1][1] == 20.0, T, "the observer sees the axis move")
    with lock:
        k = len(seen)
    os.killpg(p.proc.pid, signal.SIGKILL)  # the feeding PLC dies mid-motion (its last feed: cruising)
    p.proc.wait(10)

    def stopped() -> Any:
        with lock:
            last = seen[-1]
        return last if last[1] == 0.0 and last[2] in (0x8F01, 0x8F02) else None

    last = wait_until(stopped, T, "the axis stopped by the watchdog")
    assert last[3] & (1 << 31), f"an axis error: {last}"
    n = len(seen)
    wait_until(lambda: len(seen) > n + 50, T, "more NC cycles")
    with lock:
        tail = seen[n:]
    # it stays (a faulted, disabled axis: the set position is the held actual position)
    assert all(x[0] == tail[0][0] and x[1] == 0.0 and x[3] & (1 << 2) for x in tail), (last, tail[:3], tail[-3:])
    assert abs(tail[0][0] - last[0]) < 0.5, (last, tail[0])
    with lock:
        after = seen[k:]
    assert all(0.0 <= x[1] <= 20.0 + 1e-9 for x in after), "never faster than fed, never backwards"
    assert all(b[0] >= a[0] - 0.5 for a, b in zip(after, after[1:])), "no jump back"
    del sub


# ---- touch probe -----------------------------------------------------------------------------------
#: the sensor of axis 1: TRUE on [12.5 + 50 k, 17.5 + 50 k): rising edges at 12.5, 62.5, 112.5, ...
PROBE_CONFIG = axis_config(default_config_text(), 1, SimProbePeriod=50.0, SimProbeOffset=12.5, SimProbeWidth=5.0)
ARMED = 1  # TouchProbeState bit 0


def probe_edge(p: ExtPlc, **inputs: Any) -> int:
    """A rising edge of MC_TouchProbe ``tp`` (TriggerInput ``r``) with ``inputs``; returns the cycle before it."""
    c = p.edge("tp", **inputs)
    p.wait("tp", lambda r: r.c > c and (r.o["Busy"] or ended(r)), T)
    return c


def test_touch_probe_on_a_simulated_sensor_pattern(start_nc: Callable[..., NcServerProcess],
                                                   xplc: Callable[..., ExtPlc]) -> None:
    p = xplc(start_nc(config_text=PROBE_CONFIG, extra_args=NC_ARGS))
    power_both(p, 1)
    p.trace(1)
    p.iref("r")  # TouchProbe1, RisingEdge
    p.set("tp", "MC_TouchProbe", refs={"TriggerInput": "r"}, Execute=True)
    p.wait_trace(1, lambda s: s.a["TouchProbeState"] & ARMED, T)
    # slow enough (25 u/s) that re-arming after the edge at 12.5 lands well before the one at 62.5: 2 s
    # of travel, however late a loaded machine runs the PLC's cycles
    p.set("mv", "MC_MoveVelocity", Execute=True, Velocity=25.0, Acceleration=1000.0, Deceleration=1000.0)
    r = p.wait("tp", ended, T)
    assert r.o["Done"] and abs(r.o["RecordedPosition"] - 12.5) <= 1e-9, r
    assert r.a["ActPos"] >= 12.5 and r.a["TouchProbeState"] & 2, f"a valid recorded position: {r}"
    # WindowOnly 70..130: the edge at 62.5 is rejected, the one at 112.5 recorded
    c = probe_edge(p, WindowOnly=True, FirstPosition=70.0, LastPosition=130.0)
    armed = p.wait_trace(1, lambda s: s.c > c and s.a["TouchProbeState"] & ARMED, T)
    assert armed.a["ActPos"] < 62.5, f"armed too late for the test: {armed}"
    r = p.wait("tp", lambda r: r.c > c and ended(r), T)
    assert r.o["Done"] and abs(r.o["RecordedPosition"] - 112.5) <= 1e-9, r
    assert 112.5 <= r.a["ActPos"], r
    # MC_AbortTrigger: the armed touch probe (a window the test never reaches) ends CommandAborted
    c = probe_edge(p, WindowOnly=True, FirstPosition=900.0, LastPosition=950.0)
    p.wait_trace(1, lambda s: s.c > c and s.a["TouchProbeState"] & ARMED, T)
    p.set("ab", "MC_AbortTrigger", refs={"TriggerInput": "r"}, Execute=True)
    ab = p.wait("ab", ended, T)
    assert ab.o["Done"], ab
    r = p.wait("tp", lambda r: r.c > c and ended(r), T)
    assert r.o["CommandAborted"] and not r.a["TouchProbeState"] & ARMED, r
    exclusive(p.history("tp"))
    exclusive(p.history("ab"))
    assert not any(r.o["Error"] for r in p.history("tp")), p.history("tp")
    p.set("halt", "MC_Halt", Execute=True)
    h = p.wait("halt", ended, T)
    assert h.o["Done"] and h.a["ActPos"] < 900.0, h


#: PlcEvent of MC_InputRef ``REF``: TRUE for HALF PLC cycles, FALSE for HALF, while ``on``; each rising
#: edge emits the ActPos of that cycle's snapshot (the hook runs before the blocks of the cycle)
PULSE = """
r = iref(REF)
if on:
    n += 1
    level = (n // HALF) % 2 == 1
    if level and not r.PlcEvent:
        emit(rise=float(ax(AX).NcToPlc["ActPos"]))
    r.PlcEvent = level
"""


def test_touch_probe_plc_event_records_act_pos(xp: ExtPlc) -> None:
    power_both(xp, 1)
    xp.set("mv", "MC_MoveVelocity", Execute=True, Velocity=50.0, Acceleration=1000.0, Deceleration=1000.0)
    xp.wait("mv", lambda r: r.o["InVelocity"], T)
    xp.iref("pe", TouchProbe=10)  # PlcEvent
    xp.hook("pulse", PULSE, REF="pe", AX=1, HALF=5, n=0, on=False)
    xp.set("tp", "MC_TouchProbe", refs={"TriggerInput": "pe"}, Execute=True)
    xp.wait("tp", lambda r: r.o["Busy"] or ended(r), T)
    xp.var("pulse", on=True)
    r = xp.wait("tp", ended, T)
    assert r.o["Done"], r
    rises = xp.hook_records("pulse")
    first = rises[0]
    assert r.c == first.c and r.o["RecordedPosition"] == first.o["rise"], (r, first)
    assert r.a["ActPos"] == r.o["RecordedPosition"], "the ActPos of the cycle's snapshot"
    # WindowOnly: edges before FirstPosition are rejected, the first one inside is recorded
    # (FirstPosition 100 u = 2 s ahead: re-arming and the first rejected rise, every 0.1 s, fit in it
    # however late a loaded machine runs the PLC's cycles)
    lo = r.a["ActPos"] + 100.0
    c = xp.edge("tp", WindowOnly=True, FirstPosition=lo, LastPosition=lo + 1000.0)
    r = xp.wait("tp", lambda r: r.c > c and ended(r), T)
    assert r.o["Done"], r
    rises = [x for x in xp.hook_records("pulse") if x.c > c]
    inside = next(x for x in rises if x.o["rise"] >= lo)
    assert r.c == inside.c and r.o["RecordedPosition"] == inside.o["rise"], (r, inside)
    assert any(x.o["rise"] < lo for x in rises if x.c < inside.c), f"an edge outside was rejected: {rises[:4]}"
    exclusive(xp.history("tp"))
    assert not any(x.o["Error"] or x.o["CommandAborted"] for x in xp.history("tp")), xp.history("tp")
