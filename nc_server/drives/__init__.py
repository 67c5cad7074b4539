"""Drive backends, found through the ``zenoh_nc.drives`` entry point group (like python-can's buses)."""
from __future__ import annotations

from importlib.metadata import entry_points

from .base import DriveABC
from .sim import SimDrive

__all__ = ["DriveABC", "SimDrive", "drive_class"]


def drive_class(name: str) -> type[DriveABC]:
    """The drive class registered under ``name`` (e.g. ``"sim"``).

    Raises:
        ValueError: no such drive backend is installed.
    """
    for ep in entry_points(group="zenoh_nc.drives"):
        if ep.name == name:
            return ep.load()
    if name == "sim":  # works without installed metadata too
        return SimDrive
    raise ValueError(f"unknown drive backend {name!r}")
