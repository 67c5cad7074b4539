"""``zenoh-nc-demo`` (``make demo``): the NC server plus a PLC program moving all axes.

Starts ``nc-server`` with its embedded default configuration (NC ``nc1``, axes 1-4,
router on tcp/127.0.0.1:7447, ``--port`` for another; a 2 s PLCTONC watchdog), then ``plc-run plc_client/demo_program.py``
in another process, and shows a live table of the axes from ``nc/nc1/frame`` until Ctrl-C,
SIGTERM or the time limit. On a terminal the table is redrawn in place; without one (CI) it
prints plain lines. At the end it checks that every axis moved without an error and the modulo
axis turned several times, and exits 0 only then.

The children die with the launcher: they are started through :mod:`plc_client.lifeline`
(``prctl(PR_SET_PDEATHSIG, SIGTERM)``), so a launcher killed with SIGKILL still leaves no NC
holding the port and no PLC moving axes; ``make demo`` starts the launcher the same way, bound
to make.
"""
from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import IO, Any

import numpy as np
import zenoh

from nc_schema import Keys, decode_frame, error_name, motion_state
from nc_schema.zenoh_config import client_config

from . import demo_program, lifeline

STATE_SHORT = {1: "Disabled", 2: "StandStill", 3: "ErrorStop", 4: "Stopping", 5: "Homing", 6: "Discrete",
               7: "Continuous", 8: "Synchronized"}


def _bin(name: str) -> list[str]:
    exe = Path(sys.executable).with_name(name)
    return [str(exe)] if exe.exists() else [name]


def _client_config(endpoint: str) -> zenoh.Config:
    """The viewer's session: the project's client config (nc_schema.zenoh_config), lease 1 s."""
    return client_config(endpoint, 1000, connect_timeout_ms=0)


class Proc:
    """A child process in its own process group, its output (stdout and stderr) relayed with a prefix.

    It gets SIGTERM when the launcher ends, however it ends (:func:`plc_client.lifeline.wrap`);
    create it from the main thread (the kernel signals when the forking thread ends).
    """

    def __init__(self, name: str, argv: list[str], out: IO[str]) -> None:
        self.name = name
        self.lines: list[str] = []
        self.ready = threading.Event()
        self.proc = subprocess.Popen(lifeline.wrap(argv), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                     start_new_session=True, bufsize=1)
        self._out = out
        self.quiet = False  # True while the live table owns the terminal; lines are still kept
        for stream in (self.proc.stdout, self.proc.stderr):
            threading.Thread(target=self._relay, args=(stream,), daemon=True).start()

    def _relay(self, stream: IO[str] | None) -> None:
        assert stream is not None
        for line in stream:
            line = line.rstrip()
            self.lines.append(line)
            if "ready" in line:
                self.ready.set()
            if not self.quiet:
                print(f"[{self.name}] {line}", file=self._out, flush=True)

    def stop(self, timeout: float = 8.0) -> int | None:
        if self.proc.poll() is None:
            try:
                os.killpg(self.proc.pid, signal.SIGTERM)
                self.proc.wait(timeout)
            except (ProcessLookupError, subprocess.TimeoutExpired):
                try:
                    os.killpg(self.proc.pid, signal.SIGKILL)
                except ProcessLookupError:
                    pass
                self.proc.wait()
        return self.proc.returncode


def _table(h: Any, recs: np.ndarray, names: dict[int, str]) -> list[str]:
    rows = [f"NC cycle {int(h['Cycle']):>9}   {'axis':<6} {'position':>12} {'modulo':>9} {'velocity':>10}  "
            f"{'PLCopen state':<13} error"]
    for r in recs:
        ax = int(r["AxisId"])
        st = STATE_SHORT.get(int(motion_state(int(r["StateDWord"]), int(r["CoupleState"]))), "?")
        err = int(r["ErrorCode"])
        rows.append(f"{'':>19} {ax:>2} {names.get(ax, ''):<3} {r['ActPos']:>12.3f} {r['ModuloActPos']:>9.3f} "
                    f"{r['ActVelo']:>10.2f}  {st:<13} {('0x%04X %s' % (err, error_name(err))) if err else '-'}")
    return rows


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="zenoh-nc-demo", description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=None,
                    help="stop after S seconds (default: until Ctrl-C on a terminal, 20 s otherwise)")
    ap.add_argument("--port", type=int, default=None, help="listen on tcp/127.0.0.1:PORT instead of the default 7447")
    ap.add_argument("--web", type=int, default=None, metavar="PORT",
                    help="also start nc-web on http://127.0.0.1:PORT/ (a user 'demo', engineer, with a password made "
                         "now and printed, unless --web-users)")
    ap.add_argument("--web-users", metavar="FILE", help="nc-web's users file (nc-web user FILE NAME --role R)")
    args = ap.parse_args(argv)
    tty = sys.stdout.isatty()
    duration = args.duration if args.duration is not None else (None if tty else 20.0)
    endpoint = f"tcp/127.0.0.1:{args.port or 7447}"
    out = sys.stdout
    # a lenient PLCTONC watchdog (2 s, nc-server's default 0.5 s), as examples/09_coupled_conveyor.toml: the demo
    # also runs on a loaded machine (CI), where a plc-run stall of 0.5 s would fault an axis and fail its check
    server_argv = _bin("nc-server") + ["--watchdog-timeout", "2"] + (["--listen", endpoint] if args.port else [])
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    nc = Proc("nc-server", server_argv, out)
    plc: Proc | None = None
    web: Proc | None = None
    first: dict[int, tuple[float, int]] = {}
    last: tuple[Any, np.ndarray] | None = None
    moved_turns: dict[int, float] = {}
    try:
        deadline = time.monotonic() + 20.0
        while not nc.ready.wait(0.05):
            if stop.is_set():
                return 1
            if nc.proc.poll() is not None or time.monotonic() >= deadline:
                print(f"zenoh-nc-demo: nc-server did not become ready (is port {args.port or 7447} in use? "
                      "try --port)", file=sys.stderr)
                return 1
        plc = Proc("plc", _bin("plc-run") + [demo_program.__file__, "--nc", f"nc1={endpoint}", "--client-id", "demo-plc"],
                   out)
        if args.web is not None:
            web = Proc("nc-web", _web_argv(args.web, args.web_users, endpoint, out), out)
        keys = Keys("nc1")
        with zenoh.open(_client_config(endpoint)) as session:
            sub = session.declare_subscriber(keys.frame, zenoh.handlers.RingChannel(1))
            nc.quiet = plc.quiet = tty  # the table redraws in place: no interleaved log lines
            if web is not None:
                web.quiet = tty
            names = {1: "X", 2: "Y", 3: "Z", 4: "C"}
            t0 = time.monotonic()
            next_draw = 0.0
            drawn = 0
            while not stop.is_set():
                now = time.monotonic() - t0
                if duration is not None and now >= duration:
                    break
                if nc.proc.poll() is not None or plc.proc.poll() is not None:
                    for p in (nc, plc):
                        if p.quiet:
                            print("\n".join(f"[{p.name}] {line}" for line in p.lines[-20:]), file=sys.stderr)
                    print("zenoh-nc-demo: a process ended unexpectedly", file=sys.stderr)
                    return 1
                sample = sub.try_recv()
                if sample is not None:
                    h, recs, _ = decode_frame(sample.payload.to_bytes())
                    last = (h, recs.copy())
                    for r in recs:
                        ax = int(r["AxisId"])
                        first.setdefault(ax, (float(r["ActPos"]), int(r["ModuloActTurns"])))
                        moved_turns[ax] = max(moved_turns.get(ax, 0.0), abs(float(r["ActPos"]) - first[ax][0]))
                if last is not None and now >= next_draw:
                    rows = _table(last[0], last[1], names)
                    if tty:
                        sys.stdout.write((f"\x1b[{drawn}F" if drawn else "") + "\n".join(r + "\x1b[K" for r in rows) + "\n")
                        sys.stdout.flush()
                        drawn = len(rows)
                        next_draw = now + 0.1
                    else:
                        print(f"t={now:5.1f}s " + " | ".join(
                            f"{int(r['AxisId'])}:{r['ActPos']:.2f}@{r['ActVelo']:.0f} "
                            f"{STATE_SHORT.get(int(motion_state(int(r['StateDWord']))), '?')}"
                            f"{' E%04X' % int(r['ErrorCode']) if int(r['ErrorCode']) else ''}" for r in last[1]),
                            flush=True)
                        next_draw = now + 1.0
                time.sleep(0.01)
            sub.undeclare()
    except KeyboardInterrupt:
        pass
    finally:
        for proc in (web, plc, nc):
            if proc is not None:
                proc.quiet = False
                proc.stop()
    if last is None:
        print("zenoh-nc-demo: no status frame received", file=sys.stderr)
        return 1
    recs = last[1]
    errors = {int(r["AxisId"]): int(r["ErrorCode"]) for r in recs if int(r["ErrorCode"])}
    c_turns = moved_turns.get(4, 0.0) / 360.0
    print(f"demo summary: travel per axis {', '.join(f'{a}: {d:.1f}' for a, d in sorted(moved_turns.items()))}; "
          f"modulo axis 4 turned {c_turns:.1f} turns; errors {errors or 'none'}")
    ok = not errors and all(moved_turns.get(a, 0.0) > 1.0 for a in (1, 2, 3, 4)) and c_turns >= 2.0
    print("demo OK" if ok else "demo FAILED: not every axis moved, or an axis reported an error")
    return 0 if ok else 1


def _web_argv(port: int, users: str | None, endpoint: str, out: IO[str]) -> list[str]:
    """nc-web's command line for the demo; without ``users`` a users file with user ``demo`` (engineer) and a
    random password (printed: nothing is stored in the source) in a temporary directory."""
    if users is None:
        import secrets
        import tempfile

        from nc_link.users import add_user
        users = str(Path(tempfile.mkdtemp(prefix="zenoh-nc-demo-")) / "users.toml")
        password = secrets.token_urlsafe(9)
        add_user(users, "demo", "engineer", password)
        print(f"nc-web: http://127.0.0.1:{port}/  user demo, password {password} (the demo PLC holds the axes: "
              "watch them; commands get 0x723 until it lets go)", file=out, flush=True)
    return _bin("nc-web") + ["--nc", f"nc1={endpoint}", "--listen", f"127.0.0.1:{port}", "--users", users]


if __name__ == "__main__":
    sys.exit(main())
