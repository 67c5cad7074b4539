"""A real ``nc-server`` (or ``nc-router``) process and a zenoh client of it, for tests.

Everything here stays on 127.0.0.1 with explicit zenoh configs (client mode, multicast and gossip
scouting off). Typical use (fixtures in ``tests/conftest.py`` wrap these)::

    srv = start_nc_server(tmp_path)                 # waits for the "ready" line
    cl = NcTestClient(srv.port, client_id="t1")     # session + liveliness token
    cl.claim(1)                                     # retries until the NC has seen the token
    cl.feed_plctonc([1])                            # PLCTONC frames every 10 ms (Enable + feeds)
    wait_until(lambda: cl.nctoplc(1)["StateDWord"] & (1 << 20), 10, "axis 1 enabled")
    r = cl.request("MoveAbsolute", axis=1, Position=10.0, Velocity=100.0)
    ...
    cl.close(); srv.stop()

Deadlines are generous on purpose (a loaded 2-core machine); nothing asserts speed.
"""
from __future__ import annotations

import itertools
import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any, Callable, Iterable, Protocol, Sequence, TypeVar

import msgpack
import numpy as np
import zenoh

from nc_schema import Keys
from znc_testing.until import wait_until

#: PLCTONC ControlDWord: Enable | FeedEnablePlus | FeedEnableMinus.
ENABLE_ALL = 0x7
#: NCTOPLC StateDWord bits used by tests.
BIT_OPERATIONAL = 1 << 0
BIT_CONTROL_LOOP_CLOSED = 1 << 20
BIT_ERROR = 1 << 31

#: Default time to wait for the NC process to print its ready line [s].
READY_TIMEOUT = 60.0
#: A small NC for retain-file runs: two persistent axes, a lenient watchdog, the frame publisher as a
#: thread (one process per NC: tests and benches that start many)
RETAIN_CONFIG = """
[nc]
name = "nc1"
watchdog_timeout = 3.0
realtime = "off"
publisher = "thread"

[[axis]]
AxisId = 1
Name = "X"
AxisEnDataPersistence = true

[[axis]]
AxisId = 2
Name = "Y"
AxisEnDataPersistence = true
"""


# ---- basics ---------------------------------------------------------------------------------
def free_port() -> int:
    """A TCP port on 127.0.0.1 that was free a moment ago (the OS picks it)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def zenoh_client_config(port: int, lease_ms: int = 1000) -> zenoh.Config:
    """Client-mode config connecting to ``tcp/127.0.0.1:<port>``; no scouting, no listening."""
    c = zenoh.Config()
    c.insert_json5("mode", '"client"')
    c.insert_json5("connect/endpoints", json.dumps([f"tcp/127.0.0.1:{port}"]))
    c.insert_json5("listen/endpoints", "[]")
    c.insert_json5("scouting/multicast/enabled", "false")
    c.insert_json5("scouting/gossip/enabled", "false")
    c.insert_json5("transport/link/tx/lease", str(int(lease_ms)))
    return c


# ---- the NC process --------------------------------------------------------------------------
def nc_server_command() -> list[str]:
    """How to run ``nc-server``: the venv's console script if present, else ``python -m``."""
    script = Path(sys.executable).with_name("nc-server")
    if script.exists():
        return [str(script)]
    return [sys.executable, "-m", "nc_server.server.cli"]


def kill_process_group(proc: subprocess.Popen[Any], timeout: float = 10.0) -> None:
    """SIGCONT then SIGKILL the process group of ``proc`` (a frozen one too) and reap it; idempotent,
    for finalizers."""
    for sig in (signal.SIGCONT, signal.SIGKILL):
        try:
            os.killpg(proc.pid, sig)
        except (ProcessLookupError, PermissionError):
            pass
    try:
        proc.wait(timeout)
    except subprocess.TimeoutExpired:
        pass


class NcServerProcess:
    """A running ``nc-server`` (its own process group).

    Attributes:
        proc: the Popen object.
        port: the TCP port it listens on (127.0.0.1).
        endpoint: ``tcp/127.0.0.1:<port>``.
        name: NC name.
        stdout_lines: stdout lines so far (collected by a reader thread).
        stderr_path: file receiving its stderr.
    """

    def __init__(self, proc: subprocess.Popen[str], port: int, name: str, stderr_path: Path) -> None:
        self.proc = proc
        self.port = port
        self.endpoint = f"tcp/127.0.0.1:{port}"
        self.name = name
        self.stderr_path = stderr_path
        self.stdout_lines: list[str] = []
        self._reader = threading.Thread(target=self._read, name=f"nc-server-{port}-stdout", daemon=True)
        self._reader.start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            self.stdout_lines.append(line.rstrip("\n"))

    @property
    def pid(self) -> int:
        return self.proc.pid

    def stderr(self) -> str:
        """Everything the process wrote to stderr so far."""
        try:
            return self.stderr_path.read_text(errors="replace")
        except OSError:
            return ""

    def ready_line(self) -> str | None:
        return next((ln for ln in self.stdout_lines if " ready: " in ln), None)

    def instance(self) -> str:
        """The NC process's instance id, from its ready line (its token ``nc/<nc>/alive/<instance>``).

        Raises:
            AssertionError: no ready line with an instance (not ready, or not an nc-server).
        """
        line = self.ready_line() or ""
        assert ", instance " in line, line
        return line.rsplit(", instance ", 1)[1].strip()

    def wait_ready(self, timeout: float = READY_TIMEOUT) -> str:
        """Wait for the ready line.

        Raises:
            RuntimeError: the process exited first (message has its stderr).
            AssertionError: timeout.
        """
        deadline = time.monotonic() + timeout
        while True:
            line = self.ready_line()
            if line:
                return line
            if self.proc.poll() is not None:
                self._reader.join(2)
                raise RuntimeError(f"nc-server exited with {self.proc.returncode} before ready:\n{self.stderr()}")
            if time.monotonic() >= deadline:
                raise AssertionError(f"nc-server not ready after {timeout:g} s; stderr:\n{self.stderr()}")
            time.sleep(0.01)

    def send_signal(self, sig: int) -> None:
        """Send ``sig`` to the server process (not its group)."""
        if self.proc.poll() is None:
            os.kill(self.proc.pid, sig)

    def stop(self, sig: int = signal.SIGTERM, timeout: float = 20.0) -> int | None:
        """Ask it to stop with ``sig``, wait, then kill the whole process group if needed.

        Returns:
            The exit code if it exited by itself within ``timeout``, else None (it was killed).
        """
        rc: int | None = None
        if self.proc.poll() is None:
            try:
                self.send_signal(sig)
                rc = self.proc.wait(timeout)
            except subprocess.TimeoutExpired:
                rc = None
        else:
            rc = self.proc.returncode
        self.kill()
        return rc

    def kill(self) -> None:
        """SIGKILL the process group (idempotent; used by finalizers)."""
        kill_process_group(self.proc)
        if self.proc.stdout is not None:
            self.proc.stdout.close()


def nc_router_command() -> list[str]:
    """How to run ``nc-router``: the venv's console script if present, else ``python -m``."""
    script = Path(sys.executable).with_name("nc-router")
    if script.exists():
        return [str(script)]
    return [sys.executable, "-m", "nc_server.router"]


_H = TypeVar("_H", bound="_Startable")


class _Startable(Protocol):
    def kill(self) -> None: ...
    def stderr(self) -> str: ...


def start_with_port_retry(launch: Callable[[], _H], ready: Callable[[_H], object], attempts: int = 3) -> _H:
    """Start a process on an address picked just before (``free_port()``) and wait until it is ready.

    A free port can be taken by another process between the pick and the bind: a start whose ``ready``
    raised RuntimeError with "Address already in use" in the process's stderr is killed and launched
    again (``launch`` picks a fresh address), up to ``attempts`` starts. Any other failure kills the
    process and propagates.
    """
    for attempt in range(attempts):
        h = launch()
        try:
            ready(h)
            return h
        except RuntimeError:
            h.kill()
            if "Address already in use" in h.stderr() and attempt < attempts - 1:
                continue
            raise
        except BaseException:
            h.kill()
            raise
    raise AssertionError("unreachable")


def start_nc_router(tmp_path: Path, extra_args: Sequence[str] = (), port: int | None = None,
                    ready_timeout: float = READY_TIMEOUT) -> NcServerProcess:
    """Start ``nc-router`` listening on ``tcp/127.0.0.1:<port>`` (a free port unless given).

    Returns a handle like :func:`start_nc_server`'s (``name`` "router"); the caller stops or kills it.
    """
    tmp_path.mkdir(parents=True, exist_ok=True)

    def launch() -> NcServerProcess:
        p = port or free_port()
        err_path = tmp_path / f"nc-router-{p}.stderr"
        with open(err_path, "w") as err:
            proc = subprocess.Popen([*nc_router_command(), "--listen", f"tcp/127.0.0.1:{p}", *extra_args],
                                    stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=err, text=True,
                                    start_new_session=True, env=dict(os.environ, PYTHONUNBUFFERED="1"))
        return NcServerProcess(proc, p, "router", err_path)

    return start_with_port_retry(launch, lambda h: h.wait_ready(ready_timeout), attempts=3 if port is None else 1)


def start_nc_server(tmp_path: Path, config_text: str | None = None, extra_args: Sequence[str] = (),
                    name: str = "nc1", ready_timeout: float = READY_TIMEOUT, wait: bool = True,
                    connect: str | None = None) -> NcServerProcess:
    """Start ``nc-server`` on a free 127.0.0.1 port (``--listen`` overrides the config's endpoints).

    With ``connect`` (a router's endpoint, e.g. :func:`start_nc_router`'s) the NC runs in client mode
    behind that router instead (``--mode client --connect``); the handle's ``port`` is then the
    router's, which is where clients connect.

    Args:
        tmp_path: where the config file and the stderr log go.
        config_text: TOML replacing the embedded default (None: the default, 4 axes ``nc1``).
        extra_args: more command-line arguments.
        name: the NC name the config defines (only recorded on the handle).
        ready_timeout: seconds to wait for the ready line.
        wait: False to return at once (e.g. to test a failing start).

    The caller must ``stop()`` or ``kill()`` the handle (the ``nc_server`` fixtures do it).

    Raises:
        RuntimeError / AssertionError: see :meth:`NcServerProcess.wait_ready`.
    """
    tmp_path.mkdir(parents=True, exist_ok=True)
    def launch() -> NcServerProcess:
        if connect is not None:
            port = int(connect.rsplit(":", 1)[1])
            args = [*nc_server_command(), "--mode", "client", "--connect", connect]
        else:
            port = free_port()
            args = [*nc_server_command(), "--listen", f"tcp/127.0.0.1:{port}"]
        if config_text is not None:
            cfg = tmp_path / f"nc-{name}-{port}.toml"
            cfg.write_text(config_text)
            args += ["--config", str(cfg)]
        args += list(extra_args)
        err_path = tmp_path / f"nc-server-{name}-{port}.stderr"
        with open(err_path, "w") as err:
            proc = subprocess.Popen(args, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=err, text=True,
                                    start_new_session=True, env=dict(os.environ, PYTHONUNBUFFERED="1"))
        return NcServerProcess(proc, port, name, err_path)

    if not wait:
        return launch()
    return start_with_port_retry(launch, lambda h: h.wait_ready(ready_timeout))


# ---- a client in the test process ------------------------------------------------------------
class ReplyError(AssertionError):
    """The NC answered a query with an error reply (not an error code) or not at all."""


def unpack(data: bytes) -> Any:
    return msgpack.unpackb(data, raw=False, strict_map_key=False)


class NcTestClient:
    """A client-mode zenoh session to one NC, with request helpers.

    Args:
        port: the NC's port on 127.0.0.1.
        client_id: the identity in the command keys and sent with every request ("": the keys carry
            a unique ``anon-...`` id and requests no client field); with ``token=True`` a liveliness token
            ``nc/<nc>/client/<client_id>`` is declared (needed for Claim).
        nc: NC name.
        token: declare the liveliness token.
        lease_ms: transport lease of this session.
        config: a zenoh config to open instead (e.g. ``plc_client.runtime.client_config``'s).
    """

    _ids = itertools.count(1)
    _anon = itertools.count(1)

    def __init__(self, port: int, client_id: str = "", nc: str = "nc1", token: bool = True,
                 lease_ms: int = 1000, config: zenoh.Config | None = None) -> None:
        self.port = port
        self.client_id = client_id
        #: the identity in this client's command keys: client_id, or a unique one per instance
        #: for an "anonymous" client (the NC takes the identity from the key)
        self.key_client = client_id or f"anon-{os.getpid()}-{next(self._anon)}"
        self.nc = nc
        self.session = zenoh.open(config if config is not None else zenoh_client_config(port, lease_ms))
        self.token = self.session.liveliness().declare_token(f"nc/{nc}/client/{client_id}") \
            if token and client_id else None
        self._latest: dict[str, tuple[bytes, bytes | None]] = {}
        self._subs: dict[str, Any] = {}
        self._feeder: threading.Thread | None = None
        self._feed_stop = threading.Event()
        self._feed: dict[int, tuple[int, int]] = {}
        self._feed_lock = threading.Lock()
        self.plc_cycle = 0

    # -- requests -------------------------------------------------------------------------------
    def key(self, axis: int | None, cmd: str = "Info") -> str:
        """The command key of ``cmd`` (its class from protocol.json) for this client's identity."""
        return Keys(self.nc).command_key(cmd, axis, self.key_client)

    def next_id(self) -> int:
        return next(self._ids)

    def raw_request(self, key: str, payload: bytes, timeout: float = 10.0) -> dict[str, Any]:
        """Send raw bytes as a query to ``key``; return the unpacked reply map.

        Raises:
            ReplyError: no reply within ``timeout`` or an error reply.
        """
        for r in self.session.get(key, payload=payload, timeout=timeout):
            if r.ok is not None:
                return unpack(r.ok.payload.to_bytes())
            raise ReplyError(f"error reply from {key}: {r.err.payload.to_bytes()!r}")
        raise ReplyError(f"no reply from {key} within {timeout} s")

    def request(self, cmd: str, axis: int | None = None, timeout: float = 10.0, request_id: Any = None,
                client: str | None = None, **args: Any) -> dict[str, Any]:
        """Send ``{"id", "client", "cmd", **args}`` to the command key of ``cmd`` (axis or NC) of this
        client (:attr:`key_client`); ``client`` replaces the request's ``client`` field (the key stays
        this client's); return the reply map."""
        msg: dict[str, Any] = {"id": self.next_id() if request_id is None else request_id, "cmd": cmd}
        cid = self.client_id if client is None else client
        if cid:
            msg["client"] = cid
        msg.update(args)
        return self.raw_request(self.key(axis, cmd), msgpack.packb(msg, use_bin_type=True), timeout)

    def claim(self, axis: int, timeout: float = 20.0) -> dict[str, Any]:
        """Claim ``axis``, retrying while the NC has not seen this client's token yet (0x723)."""
        def attempt() -> dict[str, Any] | None:
            r = self.request("Claim", axis=axis)
            return r if r["error"] == 0 else None
        return wait_until(attempt, timeout, f"claim of axis {axis} by {self.client_id!r}", interval=0.05)

    # -- cyclic data ----------------------------------------------------------------------------
    def watch(self, key: str) -> None:
        """Subscribe to ``key`` keeping the newest (payload, attachment) (idempotent)."""
        if key in self._subs:
            return

        def on_sample(s: zenoh.Sample) -> None:
            att = s.attachment.to_bytes() if s.attachment is not None else None
            self._latest[key] = (s.payload.to_bytes(), att)

        self._subs[key] = self.session.declare_subscriber(key, on_sample)

    def latest(self, key: str) -> tuple[bytes, bytes | None] | None:
        """Newest (payload, attachment) on a watched key, or None yet."""
        self.watch(key)
        return self._latest.get(key)

    def nctoplc(self, axis: int) -> np.void | None:
        """Newest NCTOPLC of ``axis`` decoded with the project codec (None before the first sample)."""
        from nc_schema import NCTOPLC_DTYPE
        v = self.latest(f"nc/{self.nc}/axis/{axis}/nctoplc")
        return None if v is None else np.frombuffer(v[0], dtype=NCTOPLC_DTYPE, count=1)[0]

    def stats(self) -> dict[str, Any] | None:
        v = self.latest(f"nc/{self.nc}/stats")
        return None if v is None else unpack(v[0])

    # -- PLCTONC ----------------------------------------------------------------------------------
    def feed_plctonc(self, axes: Iterable[int], control: int = ENABLE_ALL, override: int = 1_000_000,
                     period: float = 0.01) -> None:
        """Publish a PLC frame for ``axes`` every ``period`` s from a thread (until :meth:`close`).

        Calling it again changes the records (e.g. ``control=0`` to disable).
        """
        from nc_schema import PLCTONC_DTYPE, encode_plc_frame
        with self._feed_lock:
            for a in axes:
                self._feed[int(a)] = (int(control), int(override))
        if self._feeder is not None:
            return
        pub = self.session.declare_publisher(f"nc/{self.nc}/plctonc/{self.client_id}")

        def run() -> None:
            while not self._feed_stop.wait(period):
                with self._feed_lock:
                    items = sorted(self._feed.items())
                recs = np.zeros(len(items), dtype=PLCTONC_DTYPE)
                recs["ControlDWord"] = [c for _, (c, _) in items]
                recs["Override"] = [o for _, (_, o) in items]
                self.plc_cycle += 1
                try:
                    pub.put(encode_plc_frame(self.plc_cycle, [a for a, _ in items], recs))
                except Exception:  # session closing
                    return

        self._feeder = threading.Thread(target=run, name=f"plctonc-{self.client_id}", daemon=True)
        self._feeder.start()

    def close(self) -> None:
        """Stop the feeder, close the session (idempotent)."""
        self._feed_stop.set()
        if self._feeder is not None:
            self._feeder.join(5)
        if self.session is not None and not self.session.is_closed():
            self.session.close()
