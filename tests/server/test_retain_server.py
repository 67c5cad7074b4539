"""The retain file with real nc-server processes: home, move, WriteParameter, stop (SIGTERM / SIGKILL),
restart, and what comes back; a corrupt file makes the NC start with its configuration and say so."""
from __future__ import annotations

import os
import random
import signal
import threading
import time
from pathlib import Path
from typing import Any, Callable

import pytest

from nc_schema import MC_AxisPara, StateDWord
from nc_server.server.retain import RetainData, RetainError, parse_retain
from znc_testing import RETAIN_CONFIG, NcServerProcess, NcTestClient, start_nc_server, wait_until

T = 60.0  # generous: a loaded 2-core machine
HOMED = int(StateDWord.Homed)
VELO_MAX = int(MC_AxisPara.AxisVeloMax)

# axis 1 persistent, axis 2 not; a lenient watchdog (the test client's feeder is a Python thread)
CONFIG = """
[nc]
name = "nc1"
watchdog_timeout = 3.0
realtime = "off"

[[axis]]
AxisId = 1
Name = "X"
AxisEnDataPersistence = true
AxisEnMinSoftPosLimit = true
AxisMinSoftPosLimit = -10.0
AxisEnMaxSoftPosLimit = true
AxisMaxSoftPosLimit = 1000.0

[[axis]]
AxisId = 2
Name = "Y"
AxisVeloMax = 500.0
"""


def retained(path: Path) -> RetainData | None:
    """The file's content now (None: missing or not parseable, e.g. while it is replaced)."""
    try:
        return parse_retain(path.read_bytes(), "nc1", [1, 2])
    except (OSError, RetainError):
        return None


def wait_file(path: Path, pred: Callable[[RetainData], bool], what: str) -> RetainData:
    return wait_until(lambda: (d := retained(path)) is not None and pred(d) and d, T, what, interval=0.02)


def wait_stderr(nc: NcServerProcess, text: str) -> str:
    """The server's stderr once it contains ``text`` (its log lines go through a queue thread)."""
    wait_until(lambda: text in nc.stderr(), T, f"{text!r} on stderr")  # a str would mean "not yet"
    return nc.stderr()


def powered_client(nc: NcServerProcess, make: Callable[..., NcTestClient], axes: tuple[int, ...]) -> NcTestClient:
    cl = make(nc.port, "plc-r")
    for a in axes:
        cl.claim(a)
    cl.feed_plctonc(axes)
    for a in axes:
        wait_until(lambda: (s := cl.nctoplc(a)) is not None and int(s["StateDWord"]) & (1 << 20), T,
                   f"axis {a} enabled")
    return cl


def done(cl: NcTestClient, axis: int, reply: dict[str, Any]) -> None:
    assert reply["error"] == 0, reply

    def ended() -> bool:
        s = cl.nctoplc(axis)
        return s is not None and int(s["CmdNo"]) == reply["CmdNo"] and int(s["CmdState"]) == 2

    wait_until(ended, T, f"axis {axis} command {reply['cmd']} done")


def state(cl: NcTestClient, axis: int) -> tuple[float, bool]:
    """(ActPos, Homed) of the newest NCTOPLC."""
    s = wait_until(lambda: cl.nctoplc(axis), T, f"NCTOPLC of axis {axis}")
    return float(s["ActPos"]), bool(int(s["StateDWord"]) & HOMED)


def read_param(cl: NcTestClient, axis: int, number: int) -> Any:
    r = cl.request("ReadParameter", axis=axis, ParameterNumber=number)
    assert r["error"] == 0, r
    return r["Value"]


@pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGTERM])
def test_positions_homed_flags_and_parameters_survive_a_restart(
        start_nc: Callable[..., NcServerProcess], nc_client: Callable[..., NcTestClient], tmp_path: Path,
        sig: int) -> None:
    path = tmp_path / "nc1.retain"
    args = ("--retain", str(path))
    nc = start_nc(CONFIG, args)
    wait_stderr(nc, "does not exist yet")
    cl = powered_client(nc, nc_client, (1, 2))
    for axis, ref, target in ((1, 100.0, 130.0), (2, 50.0, 70.0)):
        done(cl, axis, cl.request("Home", axis=axis, HomingMode=4, Position=ref))  # MC_Direct: homed at ref
        done(cl, axis, cl.request("MoveAbsolute", axis=axis, Position=target, Velocity=200.0))
    assert cl.request("WriteParameter", axis=2, ParameterNumber=VELO_MAX, Value=321.0)["error"] == 0
    assert state(cl, 1) == (pytest.approx(130.0, abs=0.02), True)
    assert state(cl, 2) == (pytest.approx(70.0, abs=0.02), True)
    # the retain thread has written what the NC knows, at standstill (wait on the file, not on a clock)
    wait_file(path, lambda d: 1 in d.axes and abs((d.axes[1].position or 0) - 130.0) < 0.02 and d.axes[1].homed
              and d.axes[1].standstill and 2 in d.axes and d.axes[2].params.get("AxisVeloMax") == (321.0, 500.0),
              "the file to show the state")
    data = retained(path)
    assert data is not None and data.axes[2].position is None and data.axes[2].homed is None  # not persistent
    cl.close()
    rc = nc.stop(sig)
    assert rc == (0 if sig == signal.SIGTERM else -signal.SIGKILL)

    nc2 = start_nc(CONFIG, args)
    assert "refused" not in wait_stderr(nc2, "loaded")
    cl2 = nc_client(nc2.port, "observer")
    act1, homed1 = state(cl2, 1)
    assert act1 == pytest.approx(130.0, abs=0.02) and homed1  # persistent: position and homed flag back
    assert state(cl2, 2) == (0.0, False)  # not persistent: the drive's position, not referenced
    assert read_param(cl2, 2, VELO_MAX) == 321.0  # written at run time: kept
    assert read_param(cl2, 1, VELO_MAX) == 1000.0  # the configuration's (AxisParams default)
    # a second round: a new move, a clean stop; the parameter survives a second restart too
    cl2.close()
    cl3 = powered_client(nc2, nc_client, (1,))
    done(cl3, 1, cl3.request("MoveAbsolute", axis=1, Position=140.0, Velocity=200.0))
    wait_file(path, lambda d: abs((d.axes[1].position or 0) - 140.0) < 0.02 and bool(d.axes[1].standstill),
              "the file to show the new standstill")
    cl3.close()
    assert nc2.stop(signal.SIGTERM) == 0
    nc3 = start_nc(CONFIG, args)
    cl4 = nc_client(nc3.port, "observer")
    assert state(cl4, 1) == (pytest.approx(140.0, abs=0.02), True)
    assert read_param(cl4, 2, VELO_MAX) == 321.0
    nc3.stop()


def test_corrupt_file_starts_with_the_configuration(start_nc: Callable[..., NcServerProcess],
                                                    nc_client: Callable[..., NcTestClient], tmp_path: Path) -> None:
    path = tmp_path / "nc1.retain"
    args = ("--retain", str(path))
    nc = start_nc(CONFIG, args)
    cl = powered_client(nc, nc_client, (1,))
    done(cl, 1, cl.request("Home", axis=1, HomingMode=4, Position=200.0))
    assert cl.request("WriteParameter", axis=1, ParameterNumber=VELO_MAX, Value=123.0)["error"] == 0
    wait_file(path, lambda d: d.axes[1].homed and d.axes[1].params.get("AxisVeloMax") == (123.0, 1000.0), "the file")
    cl.close()
    assert nc.stop(signal.SIGTERM) == 0
    raw = bytearray(path.read_bytes())
    raw[-3] ^= 0xFF  # one flipped byte in the body
    path.write_bytes(bytes(raw))

    nc2 = start_nc(CONFIG, args)
    err = wait_stderr(nc2, "refused")
    lines = [ln for ln in err.splitlines() if "retain" in ln and "ERROR" in ln]
    assert len(lines) == 1 and "0x4002" in lines[0] and "checksum" in lines[0] and \
        "starts with its configuration" in lines[0] and "persistent axes unreferenced" in lines[0], err
    assert (tmp_path / "nc1.retain.rejected").read_bytes() == bytes(raw)  # kept aside, not overwritten
    cl2 = nc_client(nc2.port, "observer")
    assert state(cl2, 1) == (0.0, False)
    assert read_param(cl2, 1, VELO_MAX) == 1000.0
    # and the NC keeps a fresh file from its configured state
    wait_file(path, lambda d: d.axes.get(1) is not None and d.axes[1].position == 0.0 and not d.axes[1].params,
              "a fresh file")
    nc2.stop()

    # a file of another NC is refused the same way
    other = CONFIG.replace('name = "nc1"', 'name = "nc9"')
    nc3 = start_nc(other, args)
    assert "'nc1'" in wait_stderr(nc3, "foreign")
    assert (tmp_path / "nc1.retain.rejected.1").exists()
    nc3.stop()


def test_a_second_nc_on_the_same_retain_file_does_not_start(
        start_nc: Callable[..., NcServerProcess], tmp_path: Path) -> None:
    path = tmp_path / "nc1.retain"
    args = ("--retain", str(path))
    nc = start_nc(CONFIG, args)
    wait_stderr(nc, "does not exist yet")
    second = start_nc_server(tmp_path / "second", CONFIG, args, wait=False)
    try:
        rc = second.proc.wait(T)
        err = second.stderr()
    finally:
        second.kill()
    assert rc == 1, err
    assert f"retain file {path} is in use by another process (pid {nc.proc.pid} holds {path}.lock)" in err, err
    assert "ready" not in err
    # the first one is not disturbed: it still writes its file; once it ends, a new NC starts on it
    wait_file(path, lambda d: 1 in d.axes, "the first NC's file")
    assert nc.stop(signal.SIGTERM) == 0
    nc2 = start_nc(CONFIG, args)
    assert "refused" not in wait_stderr(nc2, "loaded")
    nc2.stop()


KILL_ROUNDS = int(os.environ.get("ZNC_KILL_ROUNDS", "50"))
#: SetActualPosition's target in KILL_TARGETS (else a parameter number)
POSITION = "position"
#: (axis, parameter or POSITION) each written by a writer thread of its own: concurrent writes share fsyncs.
#: Axis 1 is persistent (RETAIN_CONFIG): its SetActualPosition replies wait for the file too.
KILL_TARGETS: tuple[tuple[int, int | str], ...] = (
    (1, int(MC_AxisPara.AxisVeloMax)), (2, int(MC_AxisPara.AxisVeloMax)),
    (1, int(MC_AxisPara.AxisAcc)), (2, int(MC_AxisPara.AxisAcc)), (1, POSITION))


class _Writer(threading.Thread):
    """Writes 1, 2, 3, ... (+ base) to one parameter (or the actual position: SetActualPosition), one request
    at a time, until a request fails (the NC was killed); ``acked``: the last value answered with no error,
    ``in_flight``: the one sent after it; ``maybe``: values since ``acked`` answered 0x4002 late (applied, their
    file write slower than the NC's hold limit on a loaded machine: kept or not, like one in flight)."""

    def __init__(self, cl: NcTestClient, axis: int, target: int | str, base: float) -> None:
        super().__init__(daemon=True)
        self.cl, self.axis, self.target, self.base = cl, axis, target, base
        self.acked: float | None = None
        self.in_flight: float | None = None
        self.errors: list[dict[str, Any]] = []
        self.maybe: set[float] = set()

    def run(self) -> None:
        k = 0
        while True:
            k += 1
            self.in_flight = self.base + k
            try:
                if self.target == POSITION:
                    r = self.cl.request("SetActualPosition", axis=self.axis, Position=self.in_flight, timeout=5.0)
                else:
                    r = self.cl.request("WriteParameter", axis=self.axis, ParameterNumber=self.target,
                                        Value=self.in_flight, timeout=5.0)
            except Exception:  # no reply: the NC is gone (the value may or may not be kept)
                return
            if r["error"] == 0x4002 and "not confirmed kept within the time" in r.get("text", ""):
                self.maybe.add(self.in_flight)
                continue
            if r["error"]:
                self.errors.append(r)
                return
            self.acked, self.in_flight = self.in_flight, None
            self.maybe.clear()


def _kept(cl: NcTestClient, axis: int, target: int | str, values: set[float],
          make: Callable[[], NcTestClient]) -> tuple[bool, float]:
    """Whether the restarted NC holds one of ``values`` (acknowledged / in flight) for ``target``; the value.
    A position is read from the NCTOPLC by a client of its own (``make``), closed at once: receiving the
    frames of every cycle for the rest of the round doubled the test's time on 2 cores."""
    if target == POSITION:
        reader = make()
        try:
            got = state(reader, axis)[0]
        finally:
            reader.close()
        return any(abs(got - v) < 1e-3 for v in values), got
    got = read_param(cl, axis, int(target))
    return got in values, got


def test_every_acknowledged_write_survives_kill_9_at_random_moments(
        start_nc: Callable[..., NcServerProcess], nc_client: Callable[..., NcTestClient], tmp_path: Path) -> None:
    """A stream of acknowledged WriteParameters and SetActualPositions (persistent axis), the NC killed with
    SIGKILL at a random moment, 50 rounds: after each restart every parameter and the position hold their last
    acknowledged value (or the one in flight)."""
    path = tmp_path / "nc1.retain"
    args = ("--retain", str(path))
    seed = random.randrange(1 << 30)
    rnd = random.Random(seed)
    nc = start_nc(RETAIN_CONFIG, args)
    expected: dict[tuple[int, int | str], set[float]] = {}
    for rnd_no in range(KILL_ROUNDS):
        cl = nc_client(nc.port, f"writer{rnd_no}")
        for (axis, target), values in expected.items():  # the previous round's values came back
            ok, got = _kept(cl, axis, target, values, lambda: nc_client(nc.port, f"frames{rnd_no}"))
            assert ok, (f"round {rnd_no} (seed {seed}): axis {axis} {target} is {got}, "
                        f"acknowledged / in flight: {sorted(values)}")
        base = 1000.0 * (rnd_no + 1)  # every round writes values of its own (above the configured ones)
        writers = [_Writer(cl, axis, target, base) for axis, target in KILL_TARGETS]
        for w in writers:
            w.start()
        wait_until(lambda: all(w.acked is not None for w in writers), T, "a first acknowledged write of each writer")
        deadline = time.monotonic() + rnd.uniform(0.0, 0.3)
        wait_until(lambda: time.monotonic() >= deadline, T, "the random moment", interval=0.001)
        nc.kill()  # SIGKILL (the process group): no final write
        for w in writers:
            w.join(T)
            assert not w.is_alive() and not w.errors, w.errors
        expected = {(w.axis, w.target): {w.acked} | w.maybe | ({w.in_flight} if w.in_flight is not None else set())
                    for w in writers}
        cl.close()
        nc = start_nc(RETAIN_CONFIG, args)
    cl = nc_client(nc.port, "reader")
    for axis, target in KILL_TARGETS:
        assert _kept(cl, axis, target, expected[axis, target], lambda: nc_client(nc.port, "frames"))[0], seed
    nc.stop()
