"""Drive backends, found through the ``zenoh_nc.drives`` entry point group (like python-can's buses)."""
from __future__ import annotations

from importlib.metadata import entry_points

# the core first: it imports .base and .sim itself, so a process whose first import is a drive module (the
# nc-drive-sim script: nc_server.drives.remote.host) does not meet them half initialised
from .. import core as _core  # noqa: F401
from .base import DriveABC
from .sim import SimDrive

__all__ = ["DriveABC", "SimDrive", "drive_class", "drive_names"]

#: The entry point group a drive backend registers in (``[project.entry-points."zenoh_nc.drives"]``).
GROUP = "zenoh_nc.drives"


def drive_names() -> list[str]:
    """The names of the installed drive backends, sorted ("sim" and "cia402-sim" always among them)."""
    return sorted({ep.name for ep in entry_points(group=GROUP)} | {"sim", "cia402-sim"})


def drive_class(name: str) -> type[DriveABC]:
    """The drive class registered under ``name`` (e.g. ``"sim"``; the server's ``[nc] drive``).

    Raises:
        ValueError: no such drive backend is installed.
    """
    for ep in entry_points(group=GROUP):
        if ep.name == name:
            return ep.load()
    if name == "sim":  # works without installed metadata too
        return SimDrive
    if name == "cia402-sim":  # (the default: also without installed metadata)
        from .cia402.sim import Cia402SimDrive
        return Cia402SimDrive
    raise ValueError(f"unknown drive backend {name!r} (installed: {', '.join(drive_names())})")
