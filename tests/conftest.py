"""Fixtures shared by all test folders (helpers live in ``tests/znc_testing.py``).

* ``nc_server``: a real ``nc-server`` process (default config: ``nc1``, axes 1-4) on a free
  127.0.0.1 port; its process group is killed when the test ends, pass or fail.
* ``start_nc``: factory for servers with another config or arguments (same cleanup).
* ``nc_client``: factory for :class:`znc_testing.NcTestClient` sessions (closed at the end).
"""
from __future__ import annotations

from pathlib import Path
from typing import Any, Callable, Iterator, Sequence

import pytest

from znc_testing import NcServerProcess, NcTestClient, start_nc_server


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
