"""Fixtures of the ADS tests (helpers in ads_testing.py).

* ``ads_address``: a free loopback address 127.0.0.x whose port 48898 is bindable (AdsLib/pyads always
  connects to 48898, so every test gets its own address instead of a free port).
* ``fake_device``: a fresh ``nc_ads.testing.FakeDevice``.
* ``ads_server``: an ``AdsServer`` serving ``fake_device`` on AMS ports 500 and 501 at ``ads_address``
  (net id ``ads_testing.SERVER_NETID``), 2 ms tick; closed at teardown.
* ``start_ads``: factory ``start_ads(devices=None, **server_kwargs)`` for other servers (same cleanup).
"""
from __future__ import annotations

from typing import Any, Callable, Iterator

import pytest

from ads_testing import SERVER_NETID, free_ads_address, start_server_on_free_address
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
        net_id = kw.pop("net_id", SERVER_NETID)
        port = kw.pop("port", 48898)

        def make(host: str) -> AdsServer:
            s = AdsServer(devs, net_id, (host, port), **kw)
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
