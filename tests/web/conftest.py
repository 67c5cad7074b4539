"""Fixtures of the nc-web tests (helpers in znc_testing.web_testing; the shared ones in
znc_testing.door_fixtures), real processes, module scope:

* ``users_file``: alice (operator), bob (observer), eve (engineer), passwords ``<name>-pw``;
* ``nc``: an nc-server (the default 4 axes X, Y, Z, C of ``nc1``, its PLCTONC watchdog 3 s instead of 0.5 s: on
  a 2-core machine at load 30 nc-web's 20 ms supply thread was starved past 0.5 s and the NC dropped its claim
  with 0x8F02; these tests are about nc-web, the watchdog has its own) on a free 127.0.0.1 port;
* ``web``: nc-web in front of it (``--session-idle 3``), killed at teardown pass or fail;
* ``watch``: a zenoh client ``watch`` of the NC without a token (Info, NCTOPLC, the claims in Info).
"""
from __future__ import annotations

import re
from pathlib import Path
from typing import Iterator

import pytest

from znc_testing import NcServerProcess
from znc_testing.door_fixtures import nc, users_file, watch  # noqa: F401 (fixtures)
from znc_testing.web_testing import NcWebProcess, start_nc_web

#: the embedded default configuration with a 3 s PLCTONC watchdog
LENIENT = re.sub(r"(?m)^watchdog_timeout = .*$", "watchdog_timeout = 3.0",
                 (Path(__file__).resolve().parents[2] / "nc_server" / "server" / "default.toml").read_text())


@pytest.fixture(scope="module")
def nc_config() -> str | None:
    return LENIENT


@pytest.fixture(scope="module")
def web(tmp_path_factory: pytest.TempPathFactory, nc: NcServerProcess, users_file: Path) -> Iterator[NcWebProcess]:
    p = start_nc_web(tmp_path_factory.mktemp("web"), nc.endpoint, ["--users", str(users_file), "--session-idle", "3"])
    try:
        yield p
    finally:
        p.stop()
