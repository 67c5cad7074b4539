"""Stand-ins for zenoh handler channels in pure tests (no session).

May import: the standard library.
"""
from __future__ import annotations

from types import SimpleNamespace
from typing import Any


class FakeSub:
    """A channel handler whose ``try_recv`` hands out the payloads ``put`` queued, oldest first (None: empty)."""

    def __init__(self) -> None:
        self.queue: list[Any] = []

    def put(self, payload: bytes) -> None:
        self.queue.append(SimpleNamespace(payload=SimpleNamespace(to_bytes=lambda p=payload: p)))

    def try_recv(self) -> Any:
        return self.queue.pop(0) if self.queue else None
