"""Fixtures shared by all test folders, and the one place that sets the import path of the suite.

Helpers live in the package ``tests/znc_testing/`` and are imported one way, ``from znc_testing[.module]
import ...``: this file puts ``tests/`` on ``sys.path`` (before anything imports a helper), and the
repository root for the fuzz program ``tests.fuzz`` (also run as ``python -m tests.fuzz``). So
``make test``, ``pytest tests/<dir>`` and a run from inside ``tests/`` import the same modules.

* ``nc_server``: a real ``nc-server`` process (default config: ``nc1``, axes 1-4) on a free
  127.0.0.1 port; its process group is killed when the test ends, pass or fail.
* ``start_nc``: factory for servers with another config or arguments (same cleanup).
* ``nc_client``: factory for :class:`znc_testing.NcTestClient` sessions (closed at the end).

Every process a test starts from pytest's main thread dies with pytest (``PR_SET_PDEATHSIG``,
:func:`_die_with_pytest`): fixtures kill their process groups when a test ends, but a pytest that is
itself killed (a CI timeout, Ctrl-C twice, ``kill -9``) runs no fixture, and its nc-servers would
keep a core busy for every later test.
"""
from __future__ import annotations

import ctypes
import signal
import subprocess
import sys
import threading
from pathlib import Path
from typing import Any, Callable, Iterator, Sequence

import pytest

TESTS = Path(__file__).resolve().parent
for _path in (TESTS.parent, TESTS):  # idempotent: pytest may have put them there already
    if str(_path) not in sys.path:
        sys.path.insert(0, str(_path))

from znc_testing import NcServerProcess, NcTestClient, start_nc_server  # noqa: E402


def _die_with_pytest() -> None:
    """Install a default ``preexec_fn`` on :class:`subprocess.Popen` (Linux): the child gets SIGKILL when
    pytest ends. Only for Popen calls from the main thread: the kernel signals when the forking *thread*
    ends, and a helper thread of a test may end long before the process it started should."""
    if not sys.platform.startswith("linux"):
        return
    try:
        libc = ctypes.CDLL(None, use_errno=True)
    except OSError:
        return
    main = threading.main_thread()
    original = subprocess.Popen.__init__

    def pdeathsig() -> None:
        libc.prctl(1, int(signal.SIGKILL), 0, 0, 0)  # PR_SET_PDEATHSIG

    def init(self: subprocess.Popen[Any], *args: Any, **kwargs: Any) -> None:
        if threading.current_thread() is main and kwargs.get("preexec_fn") is None:
            kwargs["preexec_fn"] = pdeathsig
        original(self, *args, **kwargs)

    subprocess.Popen.__init__ = init  # type: ignore[method-assign]


_die_with_pytest()


@pytest.fixture
def start_nc(tmp_path: Path) -> Iterator[Callable[..., NcServerProcess]]:
    """``start_nc(config_text=None, extra_args=(), **kw)`` -> a ready NcServerProcess."""
    started: list[NcServerProcess] = []

    def start(config_text: str | None = None, extra_args: Sequence[str] = (), **kw: Any) -> NcServerProcess:
        h = start_nc_server(tmp_path / f"nc{len(started)}", config_text, extra_args, **kw)
        started.append(h)
        return h

    try:
        yield start
    finally:
        for h in started:
            h.kill()


@pytest.fixture
def nc_server(start_nc: Callable[..., NcServerProcess]) -> NcServerProcess:
    """A ready nc-server with the embedded default configuration."""
    return start_nc()


@pytest.fixture
def nc_client() -> Iterator[Callable[..., NcTestClient]]:
    """``nc_client(port, client_id="", **kw)`` -> an NcTestClient closed at teardown."""
    clients: list[NcTestClient] = []

    def make(port: int, client_id: str = "", **kw: Any) -> NcTestClient:
        c = NcTestClient(port, client_id, **kw)
        clients.append(c)
        return c

    try:
        yield make
    finally:
        for c in reversed(clients):
            try:
                c.close()
            except Exception:
                pass
