"""Server configuration: TOML file (or the embedded ``default.toml``) plus command-line overrides.

A configuration is checked completely before anything starts; every problem is reported as a
:class:`~nc_server.core.params.ConfigError` whose ``key`` names the offending entry, e.g.
``nc.cycle_time`` or ``axis[2].AxisVeloMax``.
"""
from __future__ import annotations

import math
import os
import re
import stat
import tomllib
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any, Mapping, Sequence

from nc_schema import Keys
from nc_server.core.params import AxisConfig, AxisParams, ConfigError
from nc_server.drives import drive_names
from nc_server.security.roles import Roles, RolesError, load_roles
from nc_server.security.tls import TlsError, check_tls_endpoints, tls_files

from .handler import LOSS_REACTIONS

__all__ = ["ConfigError", "ServerConfig", "ZenohSettings", "load_config", "parse_config", "default_config_text",
           "check_endpoint", "REALTIME_MODES"]

REALTIME_MODES = ("auto", "fifo", "off")
ZENOH_MODES = ("router", "peer", "client")

# proto/address[?metadata][#config]; the address part is checked per protocol below.
_ENDPOINT_RE = re.compile(r"^(?P<proto>[a-z][a-z0-9-]*)/(?P<addr>[^?#]+)(?P<rest>[?#].*)?$")
_HOSTPORT_RE = re.compile(r"^(?P<host>\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9.-]+):(?P<port>[0-9]{1,5})$")
_PROTOS = ("tcp", "udp", "tls", "quic", "ws", "unixsock-stream")


@dataclass(frozen=True)
class ZenohSettings:
    """The zenoh session of the NC.

    Attributes:
        mode: ``"router"`` (default: the NC is its clients' router), ``"peer"`` or ``"client"``
            (the NC connects to a router, e.g. ``nc-router``, and needs no listen endpoint).
        listen: explicit listen endpoints (at least one unless ``connect`` is given).
        connect: endpoints to connect to (e.g. a router; usually none).
        lease_ms: transport lease in milliseconds: the lease this NC announces, i.e. how long its
            peers (clients, a router) take to drop it when it freezes (about 0.75 x lease).
        tls_dir: certificate directory (``deploy/certs/make-certs.sh``): mutual TLS with the NC's
            certificate ``<name>.pem``, every endpoint ``tls/``; None: no TLS.
    """

    mode: str = "router"
    listen: tuple[str, ...] = ("tcp/127.0.0.1:7447",)
    connect: tuple[str, ...] = ()
    lease_ms: int = 500
    tls_dir: str | None = None


@dataclass(frozen=True)
class ServerConfig:
    """A checked server configuration.

    Attributes:
        name: NC name (key prefix ``nc/<name>``).
        cycle_time: NC cycle [s].
        watchdog_timeout: maximum age of a claim holder's PLCTONC before 0x8F02 [s].
        realtime: ``"auto"``, ``"fifo"`` or ``"off"``.
        rt_priority: SCHED_FIFO priority (1..99) of the cycle thread.
        drive: name of the drive backend (an entry point of group ``zenoh_nc.drives``; ``"sim"``).
        retain_file: the retain file (positions of persistent axes, homed flags, parameters written at
            run time: :mod:`nc_server.server.retain`), an absolute path (a relative one is resolved
            against the working directory when the configuration is loaded, also in a config file),
            None: nothing is kept across a restart.
        zenoh: the session settings.
        axes: the axes in configuration order.
        roles: the roles file (``zenoh.roles`` / ``--roles``): the NC refuses commands a client's role
            does not allow, and with ``zenoh.tls_dir`` its own router session enforces the access
            control generated from it. None: no roles file.
        loss_reactions: ``ClientLossReaction`` per axis, in the same order: "stop_disable"
            (default), "stop" or "keep_others" (see ``handler.CycleInputs``).
    """

    name: str = "nc1"
    cycle_time: float = 0.001
    watchdog_timeout: float = 0.5
    realtime: str = "auto"
    rt_priority: int = 49
    drive: str = "sim"
    retain_file: str | None = None
    zenoh: ZenohSettings = field(default_factory=ZenohSettings)
    axes: tuple[AxisConfig, ...] = ()
    roles: Roles | None = None
    loss_reactions: tuple[str, ...] = ()


def default_config_text() -> str:
    """The embedded default configuration (TOML text)."""
    return resources.files(__package__).joinpath("default.toml").read_text(encoding="utf-8")


def check_endpoint(ep: Any, key: str) -> str:
    """Return ``ep`` if it is a plausible zenoh endpoint (``tcp/127.0.0.1:7447`` ...).

    Raises:
        ConfigError: not a string, unknown protocol, missing/invalid host:port.
    """
    if not isinstance(ep, str):
        raise ConfigError(key, f"endpoint must be a string like 'tcp/127.0.0.1:7447', got {ep!r}")
    m = _ENDPOINT_RE.match(ep)
    if not m or m["proto"] not in _PROTOS:
        raise ConfigError(key, f"invalid endpoint {ep!r}: expected <proto>/<address> with proto one of "
                               f"{', '.join(_PROTOS)}")
    if m["proto"] == "unixsock-stream":
        return ep
    hp = _HOSTPORT_RE.match(m["addr"])
    if not hp or not 0 <= int(hp["port"]) <= 65535:
        raise ConfigError(key, f"invalid endpoint {ep!r}: expected <proto>/<host>:<port> with port 0..65535")
    return ep


def _table(data: Mapping[str, Any], name: str, allowed: set[str]) -> Mapping[str, Any]:
    t = data.get(name, {})
    if not isinstance(t, Mapping):
        raise ConfigError(name, f"must be a table, got {type(t).__name__}")
    for k in t:
        if k not in allowed:
            raise ConfigError(f"{name}.{k}", f"unknown key (allowed: {', '.join(sorted(allowed))})")
    return t


def _number(v: Any, key: str, lo: float, hi: float) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise ConfigError(key, f"must be a number, got {v!r}")
    if not lo <= v <= hi:
        raise ConfigError(key, f"must be within {lo:g}..{hi:g}, got {v!r}")
    return float(v)


def _integer(v: Any, key: str, lo: int, hi: int) -> int:
    if isinstance(v, bool) or not isinstance(v, int):
        raise ConfigError(key, f"must be an integer, got {v!r}")
    if not lo <= v <= hi:
        raise ConfigError(key, f"must be within {lo}..{hi}, got {v!r}")
    return v


def _choice(v: Any, key: str, choices: Sequence[str]) -> str:
    if v not in choices:
        raise ConfigError(key, f"must be one of {', '.join(repr(c) for c in choices)}, got {v!r}")
    return v


def _endpoints(v: Any, key: str) -> tuple[str, ...]:
    if not isinstance(v, list):
        raise ConfigError(key, f"must be a list of endpoints, got {v!r}")
    return tuple(check_endpoint(ep, f"{key}[{i}]") for i, ep in enumerate(v))


def _retain_path(v: Any, key: str) -> str:
    """A retain file path, made absolute against the working directory (not the config file's).

    It must be a regular file or not exist yet (not a directory, FIFO, device or symlink: the NC
    replaces it by rename), in an existing directory the NC may write (it creates ``<file>.lock`` and
    temporary files there).
    """
    if not isinstance(v, str) or not v.strip():
        raise ConfigError(key, f"must be a file path, got {v!r}")
    p = Path(os.path.abspath(Path(v).expanduser()))
    try:
        st = os.lstat(p)
    except FileNotFoundError:
        st = None
    except OSError as exc:
        raise ConfigError(key, f"{str(p)!r}: {exc.strerror or exc}") from None
    if st is not None and not stat.S_ISREG(st.st_mode):
        what = ("a directory" if stat.S_ISDIR(st.st_mode) else "a FIFO" if stat.S_ISFIFO(st.st_mode)
                else "a symlink (the first write would replace the link: name its target)" if stat.S_ISLNK(st.st_mode)
                else "not a regular file")
        raise ConfigError(key, f"{str(p)!r} is {what}, expected a regular file or a path that does not exist yet")
    if not p.parent.is_dir():
        raise ConfigError(key, f"the directory of {str(p)!r} does not exist")
    if not os.access(p.parent, os.W_OK | os.X_OK):
        raise ConfigError(key, f"the directory {str(p.parent)!r} is not writable (the NC writes the file, "
                               f"its .lock and temporary files there)")
    return str(p)


def _axes(data: Mapping[str, Any]) -> tuple[tuple[AxisConfig, ...], tuple[str, ...]]:
    """The [[axis]] tables: the axes and their ClientLossReaction (a server key, not an AxisParams one)."""
    tables = data.get("axis")
    if not isinstance(tables, list) or not tables:
        raise ConfigError("axis", "at least one [[axis]] table is required")
    axes: list[AxisConfig] = []
    reactions: list[str] = []
    ids: dict[int, int] = {}
    names: dict[str, int] = {}
    for i, t in enumerate(tables):
        where = f"axis[{i}]"
        if not isinstance(t, Mapping):
            raise ConfigError(where, "must be a table")
        t = dict(t)
        if "AxisId" not in t:
            raise ConfigError(f"{where}.AxisId", "missing")
        axis_id = t.pop("AxisId")
        name = t.pop("Name", "")
        if not isinstance(name, str) or len(name) > 64:
            raise ConfigError(f"{where}.Name", f"must be a string of at most 64 characters, got {name!r}")
        reactions.append(_choice(t.pop("ClientLossReaction", LOSS_REACTIONS[0]), f"{where}.ClientLossReaction",
                                 LOSS_REACTIONS))
        params = AxisParams.from_mapping(t, where=where)
        try:
            ax = AxisConfig(AxisId=axis_id, Name=name, params=params)
        except ConfigError as exc:
            raise ConfigError(f"{where}.{exc.key}", str(exc).split(": ", 1)[-1]) from None
        if ax.AxisId in ids:
            raise ConfigError(f"{where}.AxisId", f"duplicate AxisId {ax.AxisId} (also axis[{ids[ax.AxisId]}])")
        if ax.Name in names:
            raise ConfigError(f"{where}.Name", f"duplicate Name {ax.Name!r} (also axis[{names[ax.Name]}])")
        ids[ax.AxisId] = i
        names[ax.Name] = i
        axes.append(ax)
    return tuple(axes), tuple(reactions)


def _path(v: Any, key: str) -> str:
    """A path value: absolute, a relative one resolved against the working directory (as retain_file)."""
    if not isinstance(v, str) or not v.strip():
        raise ConfigError(key, f"must be a path, got {v!r}")
    return str(Path(v).expanduser().resolve())


def parse_config(data: Mapping[str, Any]) -> ServerConfig:
    """Check a parsed TOML document and build the configuration.

    Raises:
        ConfigError: the first problem found, with its key.
    """
    for k in data:
        if k not in ("nc", "zenoh", "axis"):
            raise ConfigError(k, "unknown top-level key (allowed: nc, zenoh, axis)")
    nc = _table(data, "nc", {"name", "cycle_time", "watchdog_timeout", "realtime", "rt_priority", "drive",
                            "retain_file"})
    zn = _table(data, "zenoh", {"mode", "listen", "connect", "lease", "roles", "tls_dir"})
    name = nc.get("name", "nc1")
    try:
        Keys(name if isinstance(name, str) else "")
    except ValueError as exc:
        raise ConfigError("nc.name", str(exc)) from None
    cycle_time = _number(nc.get("cycle_time", 0.001), "nc.cycle_time", 0.0001, 1.0)
    watchdog = _number(nc.get("watchdog_timeout", 0.5), "nc.watchdog_timeout", 0.0, 3600.0)
    if watchdog < 2 * cycle_time:
        raise ConfigError("nc.watchdog_timeout",
                          f"must be at least two cycles ({2 * cycle_time:g} s), got {watchdog:g}")
    realtime = _choice(nc.get("realtime", "auto"), "nc.realtime", REALTIME_MODES)
    rt_priority = _integer(nc.get("rt_priority", 49), "nc.rt_priority", 1, 99)
    drive = nc.get("drive", "sim")
    if drive not in (known := drive_names()):
        raise ConfigError("nc.drive", f"unknown drive {drive!r} (installed drives: {', '.join(known)}; "
                                      f"entry point group zenoh_nc.drives)")
    retain_file = nc.get("retain_file")
    if retain_file is not None:
        retain_file = _retain_path(retain_file, "nc.retain_file")
    mode = _choice(zn.get("mode", "router"), "zenoh.mode", ZENOH_MODES)
    connect = _endpoints(zn.get("connect", []), "zenoh.connect")
    listen = _endpoints(zn.get("listen", [] if mode == "client" else ["tcp/127.0.0.1:7447"]), "zenoh.listen")
    if mode == "client" and listen:
        raise ConfigError("zenoh.listen", "a client-mode NC listens nowhere: remove zenoh.listen or use mode router")
    if not listen and not connect:
        raise ConfigError("zenoh.listen", "at least one listen or connect endpoint is required")
    lease = _integer(zn.get("lease", ZenohSettings.lease_ms), "zenoh.lease", 100, 600_000)
    tls_dir = None
    if zn.get("tls_dir") is not None:
        tls_dir = _path(zn["tls_dir"], "zenoh.tls_dir")
        try:
            tls_files(tls_dir, name)
            check_tls_endpoints(listen, "zenoh.listen")
            check_tls_endpoints(connect, "zenoh.connect")
        except TlsError as exc:
            raise ConfigError("zenoh.tls_dir", str(exc)) from None
    roles = None
    if zn.get("roles") is not None:
        try:
            roles = load_roles(_path(zn["roles"], "zenoh.roles"))
        except RolesError as exc:
            raise ConfigError("zenoh.roles", str(exc)) from None
        if name not in roles.ncs:
            raise ConfigError("zenoh.roles", f"{roles.source}: NC {name!r} is not listed (add [nc.{name}])")
    axes, reactions = _axes(data)
    return ServerConfig(name=name, cycle_time=cycle_time, watchdog_timeout=watchdog, realtime=realtime,
                        rt_priority=rt_priority, drive=drive, retain_file=retain_file,
                        zenoh=ZenohSettings(mode, listen, connect, lease, tls_dir), axes=axes, roles=roles,
                        loss_reactions=reactions)


def load_config(path: str | Path | None = None, *, listen: Sequence[str] | None = None,
                connect: Sequence[str] | None = None, mode: str | None = None, name: str | None = None,
                cycle_time: float | None = None, realtime: str | None = None,
                watchdog_timeout: float | None = None, retain_file: str | None = None, roles: str | None = None,
                tls_dir: str | None = None, lease_ms: int | None = None) -> ServerConfig:
    """Load ``path`` (TOML) or the embedded default, then apply the command-line overrides.

    Args:
        path: a TOML file replacing the default as a whole; None for the embedded default.
        listen: replaces ``zenoh.listen`` when given (non-empty).
        connect: replaces ``zenoh.connect`` when given (non-empty).
        mode: replaces ``zenoh.mode``; ``"client"`` without ``listen`` also drops the default listen endpoint.
        name, cycle_time, realtime, watchdog_timeout, retain_file: replace ``nc.*`` when given.
        roles, tls_dir: replace ``zenoh.roles`` / ``zenoh.tls_dir`` when given (a relative path, here
            or in the file, is resolved against the working directory, as ``nc.retain_file``).
        lease_ms: replaces ``zenoh.lease`` when given.

    Raises:
        ConfigError: unreadable file (key ``--config``), TOML syntax error, or any invalid value.
    """
    if path is None:
        text, origin = default_config_text(), "default.toml"
    else:
        try:
            text, origin = Path(path).read_text(encoding="utf-8"), str(path)
        except OSError as exc:
            raise ConfigError("--config", f"cannot read {path}: {exc.strerror or exc}") from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError("--config", f"{origin}: TOML syntax error: {exc}") from None
    nc = data.setdefault("nc", {})
    zn = data.setdefault("zenoh", {})
    if not isinstance(nc, dict) or not isinstance(zn, dict):
        return parse_config(data)  # reports the non-table
    if mode is not None:
        zn["mode"] = mode
        if mode == "client" and not listen:
            zn.pop("listen", None)
    if listen:
        zn["listen"] = list(listen)
    if connect:
        zn["connect"] = list(connect)
    if lease_ms is not None:
        zn["lease"] = lease_ms
    for key, value in (("name", name), ("cycle_time", cycle_time), ("realtime", realtime),
                       ("watchdog_timeout", watchdog_timeout), ("retain_file", retain_file)):
        if value is not None:
            nc[key] = value
    for key, value in (("roles", roles), ("tls_dir", tls_dir)):
        if value is not None:
            zn[key] = value
    return parse_config(data)
