"""Fixtures of the nc-opcua tests (helpers in znc_testing.opcua_testing; the shared ones in
znc_testing.door_fixtures), real processes, module scope:

* ``users_file``: alice (operator), bob (observer), eve (engineer), passwords ``<name>-pw``;
* ``nc``: an nc-server (the default 4 axes X, Y, Z, C of ``nc1``) on a free 127.0.0.1 port;
* ``opcua``: nc-opcua in front of it (``--anonymous``, session timeout 3 s), its 4 axes served; killed at teardown
  pass or fail;
* ``watch``: a zenoh client ``watch`` of the NC without a token (Info, NCTOPLC).
"""
from __future__ import annotations

import asyncio
from pathlib import Path
from typing import Iterator

import pytest

from znc_testing import NcServerProcess
from znc_testing.door_fixtures import nc, nc_config, users_file, watch  # noqa: F401 (fixtures)
from znc_testing.opcua_testing import NcOpcuaProcess, client, served, start_nc_opcua


@pytest.fixture(scope="module")
def opcua(tmp_path_factory: pytest.TempPathFactory, nc: NcServerProcess, users_file: Path) -> Iterator[NcOpcuaProcess]:
    p = start_nc_opcua(tmp_path_factory.mktemp("opcua"), nc.endpoint,
                       ["--users", str(users_file), "--anonymous", "--session-timeout", "3"])
    try:
        asyncio.run(_axes_served(p.url))
        yield p
    finally:
        p.stop()


async def _axes_served(url: str) -> None:
    async with client(url) as c:
        for a in (1, 2, 3, 4):
            await served(c, f"nc1.{a}.ActPos")
