"""Helpers of the nc-web tests: an ``nc-web`` process (``python -m nc_web``) on a free 127.0.0.1 port in front of
a real nc-server, and plain HTTP/WebSocket shortcuts (urllib, websockets' sync client; no browser).

    nc = start_nc_server(tmp)                                          # znc_testing
    web = start_nc_web(tmp, nc.endpoint, ["--users", str(users)])      # waits for its ready line
    cookie = login(web.url, "alice", "alice-pw")
    status, reply = post(web.url, cookie, "nc1", 1, "Power", Enable=True)
    web.stop(); nc.kill()

May import: the project's packages, websockets, the standard library and znc_testing.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import urllib.error
import urllib.parse
import urllib.request
from pathlib import Path
from typing import Any, Sequence

from znc_testing.door_process import DoorProcess
from znc_testing.nc_process import free_port, start_with_port_retry


class NcWebProcess(DoorProcess):
    """A running ``nc-web`` at ``url`` (``http://127.0.0.1:<port>``)."""

    NAME, READY = "nc-web", "nc-web ready"

    def __init__(self, proc: subprocess.Popen[str], port: int, stderr_path: Path) -> None:
        super().__init__(proc, stderr_path)
        self.port, self.url = port, f"http://127.0.0.1:{port}"


def start_nc_web(tmp_path: Path, nc_endpoint: str, args: Sequence[str] = (), nc: str = "nc1",
                 wait: bool = True) -> NcWebProcess:
    """Start nc-web for NC ``nc`` at ``nc_endpoint`` on a free port (``--listen 127.0.0.1:<port>``)."""
    tmp_path.mkdir(parents=True, exist_ok=True)

    def launch() -> NcWebProcess:
        port = free_port()
        err = tmp_path / f"nc-web-{port}.stderr"
        with open(err, "w") as f:
            proc = subprocess.Popen([sys.executable, "-m", "nc_web", "--nc", f"{nc}={nc_endpoint}", "--listen",
                                     f"127.0.0.1:{port}", "--log-level", "INFO", *args], stdin=subprocess.DEVNULL,
                                    stdout=subprocess.PIPE, stderr=f, text=True, start_new_session=True,
                                    env=dict(os.environ, PYTHONUNBUFFERED="1"))
        return NcWebProcess(proc, port, err)

    if not wait:
        return launch()
    return start_with_port_retry(launch, lambda p: p.wait_ready())


class _NoRedirect(urllib.request.HTTPRedirectHandler):
    def redirect_request(self, *a: Any, **k: Any) -> None:
        return None


_OPENER = urllib.request.build_opener(_NoRedirect)


def http(url: str, method: str = "GET", body: bytes | None = None, cookie: str | None = None,
         content_type: str = "application/json", timeout: float = 30.0,
         headers: dict[str, str] | None = None) -> tuple[int, dict[str, str], bytes]:
    """(status, headers, body) of one request (``headers``: extra ones); no redirect is followed."""
    req = urllib.request.Request(url, data=body, method=method, headers=headers or {})
    if body is not None:
        req.add_header("Content-Type", content_type)
    if cookie:
        req.add_header("Cookie", cookie)
    try:
        with _OPENER.open(req, timeout=timeout) as r:
            return r.status, dict(r.headers), r.read()
    except urllib.error.HTTPError as e:
        return e.code, dict(e.headers), e.read()


def login(base: str, user: str, password: str) -> str:
    """Log in; the ``Cookie`` header value of the login.

    Raises:
        AssertionError: the login failed (its status and page in the message).
    """
    status, headers, body = http(f"{base}/login", "POST", urllib.parse.urlencode({"user": user, "password": password})
                                 .encode(), content_type="application/x-www-form-urlencoded")
    assert status == 303, (status, body[:300])
    return headers["set-cookie"].split(";", 1)[0]


def post(base: str, cookie: str | None, nc: str, axis: int, cmd: str, **args: Any) -> tuple[int, dict[str, Any]]:
    """POST an axis command: (HTTP status, JSON reply)."""
    status, _, body = http(f"{base}/api/nc/{nc}/axis/{axis}/{cmd}", "POST", json.dumps(args).encode(), cookie)
    return status, json.loads(body)


def websocket(base: str, cookie: str, nc: str = "nc1") -> Any:
    """A connected ``websockets.sync`` client of the page's live channel (close it)."""
    from websockets.sync.client import connect
    return connect(base.replace("http://", "ws://") + f"/ws/nc/{nc}", additional_headers={"Cookie": cookie},
                   open_timeout=30)


def claims(watch: Any) -> dict[int, str]:
    """AxisId -> holder, from the NC's Info (``watch``: a ``znc_testing.NcTestClient``)."""
    arb = watch.request("Info")["Value"]["arbitration"]
    return {int(a): str(c) for a, c in (arb.get("claims") or {}).items()}
