"""The fixtures the user-facing doors' tests share (tests/opcua, tests/web): real processes, module scope.

* ``users_file``: alice (operator), bob (observer), eve (engineer), passwords ``<name>-pw``;
* ``nc``: an nc-server (the default 4 axes X, Y, Z, C of ``nc1``) on a free 127.0.0.1 port, configured by the
  module-scoped ``nc_config`` fixture (None: the embedded default), killed at teardown pass or fail;
* ``watch``: a zenoh client ``watch`` of the NC without a token (Info, NCTOPLC).

A conftest imports them (``from znc_testing.door_fixtures import nc, users_file, watch``) and may override
``nc_config``.
"""
from __future__ import annotations

from pathlib import Path
from typing import Iterator

import pytest

from nc_link.users import add_user
from znc_testing import NcServerProcess, NcTestClient, start_nc_server

USERS = {"alice": "operator", "bob": "observer", "eve": "engineer"}


@pytest.fixture(scope="module")
def users_file(tmp_path_factory: pytest.TempPathFactory) -> Path:
    p = tmp_path_factory.mktemp("users") / "users.toml"
    for name, role in USERS.items():
        add_user(p, name, role, f"{name}-pw")
    return p


@pytest.fixture(scope="module")
def nc_config() -> str | None:
    return None


@pytest.fixture(scope="module")
def nc(tmp_path_factory: pytest.TempPathFactory, nc_config: str | None) -> Iterator[NcServerProcess]:
    srv = start_nc_server(tmp_path_factory.mktemp("nc"), nc_config)
    try:
        yield srv
    finally:
        srv.kill()


@pytest.fixture(scope="module")
def watch(nc: NcServerProcess) -> Iterator[NcTestClient]:
    c = NcTestClient(nc.port, client_id="watch", token=False)
    try:
        yield c
    finally:
        c.close()
