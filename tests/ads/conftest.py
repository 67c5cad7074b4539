"""Fixtures of the ADS tests (helpers in znc_testing.ads_testing).

* ``ads_address``: a free loopback address 127.0.0.x whose port 48898 is bindable (AdsLib/pyads always
  connects to 48898, so every test gets its own address instead of a free port).
* ``fake_device``: a fresh ``nc_ads.testing.FakeDevice``.
* ``ads_server``: an ``AdsServer`` serving ``fake_device`` on AMS ports 500 and 501 at ``ads_address``
  (net id ``netid_for(host)``, see ``server.net_id``), 2 ms tick; closed at teardown.
* ``pyads_session``: factory ``pyads_session(server)`` -> ``PyadsSession`` (``.open(ams_port)`` gives
  pyads Connections; notifications are deleted before close at teardown, pass or fail).
* ``nc``, ``ads_op``, ``watcher`` (module scope, real processes): an nc-server, an nc-ads (operator, client id
  "ads-op") in front of it and a zenoh client "watch" of the NC (stats, claims, NCTOPLC).
* ``start_ads``: factory ``start_ads(devices=None, **server_kwargs)`` for other servers (same cleanup).
"""
from __future__ import annotations

from typing import Any, Callable, Iterator

import pytest

from znc_testing.ads_testing import PyadsSession, free_ads_address, netid_for, start_server_on_free_address
from znc_testing.nc_ads_testing import NcAdsProcess, start_nc_ads
from znc_testing import NcServerProcess, NcTestClient, start_nc_server
from nc_ads.server import AdsServer
from nc_ads.testing import FakeDevice


@pytest.fixture
def ads_address() -> str:
    return free_ads_address()


@pytest.fixture
def fake_device() -> FakeDevice:
    return FakeDevice()


@pytest.fixture
def start_ads(fake_device: FakeDevice) -> Iterator[Callable[..., AdsServer]]:
    servers: list[AdsServer] = []

    def start(devices: Any = None, **kw: Any) -> AdsServer:
        kw.setdefault("tick_ms", 2.0)
        devs = devices if devices is not None else {500: fake_device, 501: fake_device}
        net_id = kw.pop("net_id", None)
        port = kw.pop("port", 48898)

        def make(host: str) -> AdsServer:
            s = AdsServer(devs, net_id or netid_for(host), (host, port), **kw)
            s.start()
            return s

        _, server = start_server_on_free_address(make)
        servers.append(server)
        return server

    try:
        yield start
    finally:
        for s in servers:
            s.close()


@pytest.fixture
def ads_server(start_ads: Callable[..., AdsServer]) -> AdsServer:
    return start_ads()


@pytest.fixture
def pyads_session(start_ads: Callable[..., AdsServer]) -> Iterator[Callable[[AdsServer], PyadsSession]]:
    # depends on start_ads so that it is torn down first: notifications deleted while the server still runs
    sessions: list[PyadsSession] = []

    def make(server: AdsServer) -> PyadsSession:
        s = PyadsSession(server)
        sessions.append(s)
        return s

    try:
        yield make
    finally:
        for s in sessions:
            s.close()


@pytest.fixture(scope="module")
def nc(tmp_path_factory: pytest.TempPathFactory) -> Iterator[NcServerProcess]:
    h = start_nc_server(tmp_path_factory.mktemp("nc"))
    try:
        yield h
    finally:
        h.kill()


@pytest.fixture(scope="module")
def ads_op(nc: NcServerProcess, tmp_path_factory: pytest.TempPathFactory) -> Iterator[NcAdsProcess]:
    h = start_nc_ads(tmp_path_factory.mktemp("ads-op"), nc.endpoint, role="operator", client_id="ads-op")
    try:
        yield h
    finally:
        h.kill()


@pytest.fixture(scope="module")
def watcher(nc: NcServerProcess) -> Iterator[NcTestClient]:
    c = NcTestClient(nc.port, "watch", token=False)
    try:
        yield c
    finally:
        c.close()
