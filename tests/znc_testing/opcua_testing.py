"""Helpers of the nc-opcua tests: an ``nc-opcua`` process (``python -m nc_opcua``) on a free 127.0.0.1 port in
front of a real nc-server, and asyncua client shortcuts.

    nc = start_nc_server(tmp)                                              # znc_testing
    ua = start_nc_opcua(tmp, nc.endpoint, ["--users", str(users)])         # waits for its ready line
    async with client(ua.url, "alice", "pw") as c: ...
    ua.stop(); nc.kill()

May import: the project's packages, asyncua, the standard library and znc_testing.
"""
from __future__ import annotations

import asyncio
import os
import subprocess
import sys
import time
from pathlib import Path
from typing import Any, Awaitable, Callable, Sequence

from asyncua import Client, ua

from znc_testing.door_process import DoorProcess
from znc_testing.nc_process import free_port, start_with_port_retry

NAMESPACE = "urn:zenoh-nc:nc-opcua"


class NcOpcuaProcess(DoorProcess):
    """A running ``nc-opcua`` listening on ``url``."""

    NAME, READY = "nc-opcua", "nc-opcua ready"

    def __init__(self, proc: subprocess.Popen[str], port: int, url: str, stderr_path: Path) -> None:
        super().__init__(proc, stderr_path)
        self.port, self.url = port, url

    def wait_ready(self, timeout: float = 240.0) -> None:  # importing asyncua took over 90 s on the loaded machine
        super().wait_ready(timeout)

    def stop(self, timeout: float = 15.0) -> int | None:
        return super().stop(timeout)


def opcua_command() -> list[str]:
    return [sys.executable, "-m", "nc_opcua"]


def start_nc_opcua(tmp_path: Path, nc_endpoint: str, args: Sequence[str] = (), wait: bool = True) -> NcOpcuaProcess:
    """Start nc-opcua for ``nc_endpoint`` on a free port (``--listen opc.tcp://127.0.0.1:<port>/zenoh-nc``)."""
    tmp_path.mkdir(parents=True, exist_ok=True)
    def launch() -> NcOpcuaProcess:
        port = free_port()
        url = f"opc.tcp://127.0.0.1:{port}/zenoh-nc"
        err = tmp_path / f"nc-opcua-{port}.stderr"
        with open(err, "w") as f:
            proc = subprocess.Popen([*opcua_command(), "--connect", nc_endpoint, "--listen", url, "--log-level", "INFO",
                                     *args], stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=f, text=True,
                                    start_new_session=True, env=dict(os.environ, PYTHONUNBUFFERED="1"))
        return NcOpcuaProcess(proc, port, url, err)

    if not wait:
        return launch()
    return start_with_port_retry(launch, lambda p: p.wait_ready())


def client(url: str, user: str | None = None, password: str | None = None, timeout: float = 30.0) -> Client:
    """An asyncua client of ``url`` (``async with`` it), logging in as ``user`` if given."""
    c = Client(url, timeout=timeout)
    if user is not None:
        c.set_user(user)
        c.set_password(password or "")
    return c


async def ns(c: Client) -> int:
    return int(await c.get_namespace_index(NAMESPACE))


async def call(c: Client, axis_node: str, method: str, *args: Any) -> tuple[int, list[Any]]:
    """Call ``method`` of axis object ``axis_node`` (e.g. ``"nc1.1"``): (status code value, output values)."""
    idx = await ns(c)
    req = ua.CallMethodRequest()
    req.ObjectId = ua.NodeId(axis_node, idx)
    req.MethodId = ua.NodeId(f"{axis_node}.{method}", idx)
    req.InputArguments = [a if isinstance(a, ua.Variant) else ua.Variant(a) for a in args]
    (res,) = await c.uaclient.call([req])
    return int(res.StatusCode.value), [v.Value for v in res.OutputArguments or []]


async def value(c: Client, node: str) -> Any:
    return await c.get_node(ua.NodeId(node, await ns(c))).read_value()


async def until(pred: Callable[[], Awaitable[Any]], timeout: float, what: str, interval: float = 0.05) -> Any:
    """Await ``pred()`` until it returns a truthy value (returned) or ``timeout`` s pass (AssertionError)."""
    deadline = time.monotonic() + timeout
    last: Any = None
    while time.monotonic() < deadline:
        last = await pred()
        if last:
            return last
        await asyncio.sleep(interval)
    raise AssertionError(f"{what}: not within {timeout} s (last {last!r})")


async def served(c: Client, node: str, timeout: float = 180.0) -> None:
    """Wait until ``node`` exists (nc-opcua adds an NC's axes after its first frame)."""
    async def readable() -> bool:
        try:
            await value(c, node)
            return True
        except Exception:
            return False
    await until(readable, timeout, f"node {node} served")
