"""Server configuration: TOML file (or the embedded ``default.toml``) plus command-line overrides.

Layers, each over the one before (:func:`load_config`):

1. the base: ``--config FILE`` (replaces the embedded default as a whole, as before) or the default;
2. ``--config-overlay FILE`` (repeatable, in order): a *partial* TOML merged over the base. ``[nc]`` and
   ``[zenoh]`` keys replace the base's one by one (a list such as ``listen`` is replaced, not extended);
   axes are changed by AxisId, either as ``[axis.2]`` tables (the axis must exist: only the keys given
   change) or as ``[[axis]]`` tables with an ``AxisId`` (an existing axis: its keys given change; a new
   AxisId: a new axis, appended). An overlay cannot remove an axis (use ``--config`` for that);
3. ``--set KEY=VALUE`` (repeatable, in order): one value, ``axis.<AxisId>.<Parameter>`` (the axis must
   exist; e.g. ``axis.1.AxisVeloMax=300``, ``axis.2.Name=Spindle``), ``nc.<key>`` or ``zenoh.<key>``
   (``nc.cycle_time=0.002``, ``zenoh.listen=["tcp/127.0.0.1:7500"]``) or ``drives.<backend>.<key>``
   (``drives.canopen.channel=can0``; an axis's backend: ``axis.1.Drive=cia402-sim``). VALUE is read as a TOML value
   (``300``, ``1e3``, ``true``, ``[..]``), except for string-valued keys (Name, ClientLossReaction,
   nc.name/realtime/drive/retain_file, zenoh.mode/roles/tls_dir), which take the text as given, and
   zenoh.listen/connect, which also take plain endpoints, comma-separated
   (``zenoh.listen=tcp/127.0.0.1:7500,tcp/10.0.0.5:7500``, no shell quoting of a TOML list); it is
   then checked exactly like the same value in a config file: by the parameter's kind and the range of
   its MC_AxisPara entry in ``schema/params.json``;
4. the dedicated options (``--listen``, ``--cycle-time``, ``--name``, ...) last.

A configuration is checked completely before anything starts; every problem is reported as a
:class:`~nc_server.core.params.ConfigError` whose ``key`` names the offending entry, e.g.
``nc.cycle_time`` or ``axis[2].AxisVeloMax``; for a value that came from an overlay or a ``--set``,
the key names that instead (``--set axis.1.AxisVeloMax``, ``over.toml: axis.2.AxisAcc``), so the
message says which argument to fix.

An axis entry that the NC would refuse at run time too carries its TwinCAT code at the end
(:class:`~nc_server.core.params.ConfigError`): ``--set axis.1.AxisVeloMax: must be 1e-06 .. 1e+09
(MC_AxisPara 1003), got 1e+12 [0x070B ADSERR_DEVICE_INVALIDPARM]``, 0x0703 for an unknown parameter
name, 0x4012 for an AxisId that is not configured.
"""
from __future__ import annotations

import logging
import math
import os
import re
import stat
import tomllib
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any, Mapping, Sequence

from nc_schema import ErrorCodes, Keys
from nc_server.core.params import ALIASES, AxisConfig, AxisParams, ConfigError
from nc_server.drives import drive_names
from nc_server.security.roles import Roles, RolesError, load_roles
from nc_schema.tls import TlsError, check_tls_endpoints, tls_files

from .handler import LOSS_REACTIONS

__all__ = ["ConfigError", "ServerConfig", "ZenohSettings", "load_config", "parse_config", "default_config_text",
           "check_endpoint", "REALTIME_MODES", "merge_overlay", "apply_set"]

REALTIME_MODES = ("auto", "fifo", "off")
#: Where the frame publisher runs (nc_server.server.publisher): a child process (own interpreter and GIL)
#: or a thread of the NC process.
PUBLISHER_MODES = ("process", "thread")
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


#: how an NC of a redundant pair starts (docs/standby.md)
REDUNDANCY_ROLES = ("standby", "active")
#: the longest ``[redundancy] node``: a standby watches the active NC's frames as the client ``ha-<node>``
#: (docs/standby.md, "Loss detection"), a client id of at most 64 characters
NODE_MAX = 61


@dataclass(frozen=True)
class Redundancy:
    """``[redundancy]``: a hot-standby pair of NCs of one name (docs/standby.md).

    Attributes:
        enabled: this NC is one of a pair (off: a single NC, nothing of this section applies).
        start: ``"standby"`` (default: follow an active NC; take over when it is lost, or after
            ``takeover_cycles`` with none at start) or ``"active"`` (drive from the start with a first epoch, at
            once: where a peer drives already, with a higher epoch, the drive hosts refuse its outputs and it demotes
            itself when it learns that epoch, but its frames went out meanwhile: a node that restarts by itself, a
            container with a restart policy, starts as "standby"; docs/standby.md).
        takeover_cycles: NC cycles without the active NC's log (or at once, its token gone) before a standby takes
            over; the drive hosts' silence timeout must be longer.
        catch_up_ms: at a takeover the core steps at once over the time the active NC was silent, at most this
            long [ms]: the drive hosts extrapolated their targets that far (nc-drive-sim --extrapolate).
        node: this process's name in the pair (the epoch's tie-break and the ha status key); default: the host
            name and the process id.
    """

    enabled: bool = False
    start: str = "standby"
    takeover_cycles: int = 15
    catch_up_ms: float = 10.0
    node: str = ""


@dataclass(frozen=True)
class ServerConfig:
    """A checked server configuration.

    Attributes:
        name: NC name (key prefix ``nc/<name>``).
        cycle_time: NC cycle [s].
        watchdog_timeout: maximum age of a claim holder's PLCTONC before 0x8F02 [s].
        realtime: ``"auto"``, ``"fifo"`` or ``"off"``.
        rt_priority: SCHED_FIFO priority (1..99) of the cycle thread.
        drive: name of the default drive backend (an entry point of group ``zenoh_nc.drives``; ``"cia402-sim"``): the
            backend of every axis without a ``Drive`` of its own.
        axis_drives: per axis (configuration order), its backend and that backend's per-axis options: the
            axis's ``Drive`` (``Drive = "cia402-sim"`` or ``Drive = { backend = "canopen", node_id = 2 }``;
            without one: ``(drive, {})``).
        drive_options: the ``[drives.<backend>]`` tables: options a backend shares among its axes (bus,
            channel, ...), handed over as ``DriveContext.options``.
        retain_file: the retain file (positions of persistent axes, homed flags, parameters written at
            run time: :mod:`nc_server.server.retain`), an absolute path (a relative one is resolved
            against the working directory when the configuration is loaded, also in a config file),
            None: nothing is kept across a restart. In a hot-standby pair each node has its own (on one
            host they may name the same file: its lock decides who writes); only the active NC locks and
            writes it, and only a cold start applies it (docs/standby.md, "Retain files").
        zenoh: the session settings.
        axes: the axes in configuration order.
        roles: the roles file (``zenoh.roles`` / ``--roles``): the NC refuses commands a client's role
            does not allow, and with ``zenoh.tls_dir`` its own router session enforces the access
            control generated from it. None: no roles file.
        loss_reactions: ``ClientLossReaction`` per axis, in the same order: "stop_disable"
            (default), "stop" or "keep_others" (see ``handler.CycleInputs``).
        cpu_affinity: the CPUs the cycle thread may run on (``[nc] cpu_affinity = [1]``); empty: any.
            Worth it only with the CPU kept free of other work (isolcpus, a cpuset, other processes
            pinned elsewhere): see ``cycle.CycleLoop``. The NC's other threads and its publisher stay
            free to use every CPU: the I/O thread shares the cycle thread's GIL and zenoh's threads
            bring its inputs; kept off the cycle's CPU, on a busy other one, they made the cycle wait
            (bench/many_clients.py: missed cycles 0.08 % -> 0.33 %).
        publisher: where the frames are put on zenoh: ``"process"`` (default: a child process with its
            own interpreter, so its puts never hold the cycle thread's GIL) or ``"thread"``
            (:mod:`nc_server.server.publisher`).
        remote_masters: ``[remote] masters``: the axes of other NCs this NC's slaves may couple to, as
            (nc, AxisId) (``["nc1/1", "nc1/2"]``): the NC subscribes to their per-axis samples from the start
            (docs/coupling-across-ncs.md).
        remote_max_age: ``[remote] max_age`` [s]: a slave of a remote master whose newest sample is older
            stops with 0x42A0; a master silent that long is refused at MC_GearIn (0x4012).
    """

    name: str = "nc1"
    cycle_time: float = 0.001
    watchdog_timeout: float = 0.5
    realtime: str = "auto"
    rt_priority: int = 49
    drive: str = "cia402-sim"
    retain_file: str | None = None
    zenoh: ZenohSettings = field(default_factory=ZenohSettings)
    axes: tuple[AxisConfig, ...] = ()
    roles: Roles | None = None
    loss_reactions: tuple[str, ...] = ()
    publisher: str = "process"
    cpu_affinity: tuple[int, ...] = ()
    axis_drives: tuple[tuple[str, dict[str, Any]], ...] = ()
    drive_options: dict[str, dict[str, Any]] = field(default_factory=dict)
    remote_masters: tuple[tuple[str, int], ...] = ()
    remote_max_age: float = 0.05
    redundancy: Redundancy = field(default_factory=Redundancy)


def _redundancy(data: Mapping[str, Any]) -> Redundancy:
    """The ``[redundancy]`` section (docs/standby.md)."""
    r = _table(data, "redundancy", {"enabled", "start", "takeover_cycles", "catch_up_ms", "node"})
    enabled = r.get("enabled", False)
    if not isinstance(enabled, bool):
        raise ConfigError("redundancy.enabled", f"must be true or false, got {enabled!r}")
    start = _choice(r.get("start", "standby"), "redundancy.start", REDUNDANCY_ROLES)
    cycles = _integer(r.get("takeover_cycles", 15), "redundancy.takeover_cycles", 2, 100_000)
    catch_up = _number(r.get("catch_up_ms", 10.0), "redundancy.catch_up_ms", 0.0, 1000.0)
    node = r.get("node", "")
    if not isinstance(node, str) or len(node) > NODE_MAX \
            or not all(c.isascii() and (c.isalnum() or c in "-_") for c in node):
        raise ConfigError("redundancy.node", f"0..{NODE_MAX} characters of letters, digits, '-' and '_' (the standby "
                                             f"watches the frames as the client 'ha-<node>', at most 64), got {node!r}")
    return Redundancy(enabled, start, cycles, catch_up, node)


def _cpus(v: Any, key: str) -> tuple[int, ...]:
    """A list of online CPU numbers (not only those this process runs on: an isolated CPU, isolcpus or
    a systemd CPUAffinity, is outside the inherited mask; the cycle thread moves there when it starts)."""
    if isinstance(v, int) and not isinstance(v, bool):
        v = [v]
    if not isinstance(v, list) or not all(isinstance(c, int) and not isinstance(c, bool) for c in v):
        raise ConfigError(key, f"must be a list of CPU numbers, got {v!r}")
    if v and not hasattr(os, "sched_setaffinity"):
        raise ConfigError(key, "CPU affinity is not available on this platform")
    online = _online_cpus()
    bad = [c for c in v if c not in online]
    if bad:
        raise ConfigError(key, f"CPU {bad[0]} is not an online CPU ({_ranges(online)})")
    return tuple(sorted(set(v)))


def _online_cpus() -> set[int]:
    """The online CPUs (/sys/devices/system/cpu/online; else 0 .. cpu_count - 1)."""
    try:
        text = open("/sys/devices/system/cpu/online", encoding="ascii").read().strip()
        out: set[int] = set()
        for part in text.split(","):
            lo, _, hi = part.partition("-")
            out.update(range(int(lo), int(hi or lo) + 1))
        return out
    except (OSError, ValueError):
        return set(range(os.cpu_count() or 1))


def _ranges(cpus: set[int]) -> str:
    s = sorted(cpus)
    return f"{s[0]}-{s[-1]}" if s == list(range(s[0], s[-1] + 1)) and len(s) > 1 else ", ".join(map(str, s))


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


def _axes(data: Mapping[str, Any], default_drive: str = "cia402-sim", known: Sequence[str] = ("sim", "cia402-sim")
          ) -> tuple[tuple[AxisConfig, ...], tuple[str, ...], tuple[tuple[str, dict[str, Any]], ...]]:
    """The [[axis]] tables: the axes, their ClientLossReaction and their Drive (server keys, not AxisParams ones)."""
    tables = data.get("axis")
    if not isinstance(tables, list) or not tables:
        raise ConfigError("axis", "at least one [[axis]] table is required")
    axes: list[AxisConfig] = []
    reactions: list[str] = []
    drives: list[tuple[str, dict[str, Any]]] = []
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
        drives.append(_axis_drive(t.pop("Drive", None), f"{where}.Drive", default_drive, known))
        params = AxisParams.from_mapping(t, where=where)
        try:
            ax = AxisConfig(AxisId=axis_id, Name=name, params=params)
        except ConfigError as exc:
            raise exc.renamed(f"{where}.{exc.key}") from None
        if ax.AxisId in ids:
            raise ConfigError(f"{where}.AxisId", f"duplicate AxisId {ax.AxisId} (also axis[{ids[ax.AxisId]}])")
        if ax.Name in names:
            raise ConfigError(f"{where}.Name", f"duplicate Name {ax.Name!r} (also axis[{names[ax.Name]}])")
        ids[ax.AxisId] = i
        names[ax.Name] = i
        axes.append(ax)
    return tuple(axes), tuple(reactions), tuple(drives)


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
        if k not in ("nc", "zenoh", "axis", "drives", "remote", "redundancy"):
            raise ConfigError(k, "unknown top-level key (allowed: nc, zenoh, axis, drives, remote, redundancy)")
    nc = _table(data, "nc", {"name", "cycle_time", "watchdog_timeout", "realtime", "rt_priority", "drive",
                            "retain_file", "publisher", "cpu_affinity"})
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
    publisher = _choice(nc.get("publisher", "process"), "nc.publisher", PUBLISHER_MODES)
    cpu_affinity = _cpus(nc.get("cpu_affinity", []), "nc.cpu_affinity")
    drive = nc.get("drive", "cia402-sim")
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
    axes, reactions, axis_drives = _axes(data, drive, known)
    drive_options = _drive_sections(data, known)
    remote_masters, remote_max_age = _remote(data, name)
    redundancy = _redundancy(data)
    _check_drive_timeout(redundancy, cycle_time, axis_drives, drive_options, lease)
    return ServerConfig(name=name, cycle_time=cycle_time, watchdog_timeout=watchdog, realtime=realtime,
                        rt_priority=rt_priority, drive=drive, retain_file=retain_file,
                        zenoh=ZenohSettings(mode, listen, connect, lease, tls_dir), axes=axes, roles=roles,
                        loss_reactions=reactions, publisher=publisher, cpu_affinity=cpu_affinity,
                        axis_drives=axis_drives, drive_options=drive_options, remote_masters=remote_masters,
                        remote_max_age=remote_max_age,
                        redundancy=redundancy)


def _check_drive_timeout(redundancy: Redundancy, cycle_time: float,
                         axis_drives: Sequence[tuple[str, Mapping[str, Any]]],
                         drive_options: Mapping[str, Mapping[str, Any]], lease_ms: int) -> None:
    """A hot-standby pair on remote drives: the drive hosts' silence timeout must be longer than the longest
    takeover the pair may publish (nc_server.drives.remote.config: ``worst_takeover``, from ``takeover_cycles``, the
    loss detector's cap and ``[zenoh] lease``). Refused when ``[drives.remote] timeout_ms`` says it; without it the
    NC cannot know a drive host's ``--timeout`` (nc-drive-sim --config checks it, and takes a long enough default).

    Raises:
        ConfigError: ``drives.remote.timeout_ms`` not longer than that bound.
    """
    if not redundancy.enabled or not any(b == "remote" for b, _ in axis_drives):
        return
    from nc_server.drives.remote.config import (DEFAULT_TIMEOUT, check_timeout, pair_default_timeout, parse_options,
                                                worst_takeover)

    opts = parse_options(drive_options.get("remote", {}))
    if opts.timeout_ms is not None:
        check_timeout(opts.timeout_ms / 1000.0, redundancy.takeover_cycles, cycle_time, "drives.remote.timeout_ms",
                      lease_ms / 1000.0)
        return
    bound = worst_takeover(redundancy.takeover_cycles, cycle_time, lease_ms / 1000.0)
    logging.getLogger("nc_server.config").info(
        "[redundancy]: a takeover may take up to %g ms (a loaded machine; the lease %d ms): the drive hosts' silence "
        "timeout must be longer: nc-drive-sim --config with this file takes %g ms by default, with --axes %g ms "
        "(too short: give --timeout); or give [drives.remote] timeout_ms (then checked here)", bound * 1e3, lease_ms,
        pair_default_timeout(redundancy.takeover_cycles, cycle_time, lease_ms / 1000.0) * 1e3, DEFAULT_TIMEOUT * 1e3)


def _remote(data: Mapping[str, Any], own: str) -> tuple[tuple[tuple[str, int], ...], float]:
    """``[remote]``: masters (``"<nc>/<AxisId>"`` of other NCs) and max_age [s]."""
    rm = _table(data, "remote", {"masters", "max_age"})
    max_age = _number(rm.get("max_age", 0.05), "remote.max_age", 0.001, 10.0)
    masters = rm.get("masters", [])
    if not isinstance(masters, list):
        raise ConfigError("remote.masters", f'must be a list of "<nc>/<AxisId>", got {masters!r}')
    out: list[tuple[str, int]] = []
    for m in masters:
        nc, _, ax = m.rpartition("/") if isinstance(m, str) else ("", "", "")
        try:
            Keys(nc)
            axis = int(ax)
            if not (ax.isdigit() and 0 < axis < 2**32):
                raise ValueError(ax)
        except ValueError:
            raise ConfigError("remote.masters", f'{m!r} is not "<nc>/<AxisId>" (e.g. "nc1/1")') from None
        if nc == own:
            raise ConfigError("remote.masters", f"{m!r} is an axis of this NC ({own!r}): couple to it without MasterNc")
        if (nc, axis) in out:
            raise ConfigError("remote.masters", f"{m!r} is listed twice")
        out.append((nc, axis))
    return tuple(out), max_age


def _drive_sections(data: Mapping[str, Any], known: Sequence[str]) -> dict[str, dict[str, Any]]:
    """The ``[drives.<backend>]`` tables: each backend's own options (the backend checks their keys)."""
    sections = data.get("drives", {})
    if not isinstance(sections, Mapping):
        raise ConfigError("drives", "must be a table of [drives.<backend>] tables")
    out: dict[str, dict[str, Any]] = {}
    for backend, options in sections.items():
        if backend not in known:
            raise ConfigError(f"drives.{backend}", f"unknown drive backend (installed: {', '.join(known)})")
        if not isinstance(options, Mapping):
            raise ConfigError(f"drives.{backend}", "must be a table")
        out[backend] = dict(options)
    return out


def _axis_drive(value: Any, where: str, default: str, known: Sequence[str]) -> tuple[str, dict[str, Any]]:
    """An axis's ``Drive``: a backend name, or a table with ``backend`` (default ``[nc] drive``) and the
    backend's per-axis options (e.g. ``{ backend = "canopen", node_id = 2 }``)."""
    if value is None:
        return default, {}
    if isinstance(value, str):
        value = {"backend": value}
    if not isinstance(value, Mapping):
        raise ConfigError(where, f"must be a backend name or a table with backend = ..., got {value!r}")
    options = dict(value)
    backend = options.pop("backend", default)
    if backend not in known:
        raise ConfigError(f"{where}.backend", f"unknown drive backend {backend!r} (installed: {', '.join(known)}; "
                                              f"entry point group zenoh_nc.drives)")
    return backend, options


#: zenoh keys whose --set VALUE may also be plain endpoints, comma-separated (not only a TOML list)
_LIST_KEYS = {"listen", "connect"}
#: keys whose --set VALUE is the text as given (not a TOML value)
_STRING_KEYS = {"nc": {"name", "realtime", "drive", "retain_file", "publisher"}, "zenoh": {"mode", "roles", "tls_dir"},
                "redundancy": {"start", "node"},
                "axis": {"Name", "ClientLossReaction"}}


class _Provenance:
    """Where overridden entries came from: a config key prefix (``axis[1].AxisVeloMax``, ``nc.cycle_time``,
    ``axis[4]``) -> the label an error names instead (``--set axis.2.AxisVeloMax``)."""

    def __init__(self) -> None:
        self.labels: dict[str, str] = {}

    def note(self, key: str, label: str) -> None:
        self.labels[key] = label

    def translate(self, exc: ConfigError) -> ConfigError:
        key = exc.key
        best = ""
        for k in self.labels:
            if (key == k or key.startswith(k + ".") or key.startswith(k + "[")) and len(k) > len(best):
                best = k
        if not best:
            return exc
        return exc.renamed(self.labels[best] + key[len(best):])


_NO_AXIS = int(ErrorCodes.NC_AXIS_ID_NOT_ALLOWED)  # 0x4012: what the NC answers for an axis it does not have


def _axis_index(data: Mapping[str, Any], axis_id: Any) -> int | None:
    axes = data.get("axis")
    if not isinstance(axes, list):
        return None
    for i, t in enumerate(axes):
        if isinstance(t, Mapping) and t.get("AxisId") == axis_id and not isinstance(axis_id, bool):
            return i
    return None


def _axis_ids(data: Mapping[str, Any]) -> str:
    axes = data.get("axis")
    ids = [str(t.get("AxisId")) for t in axes if isinstance(t, Mapping)] if isinstance(axes, list) else []
    return ", ".join(ids) or "none"


def merge_overlay(data: dict[str, Any], overlay: Mapping[str, Any], origin: str,
                  prov: _Provenance | None = None) -> None:
    """Merge a parsed partial TOML ``overlay`` into ``data`` (in place; see the module docstring).

    Raises:
        ConfigError: an axis table without AxisId, ``[axis.N]`` for an axis that does not exist, a
            section that is not a table; the key names ``origin``.
    """
    prov = prov or _Provenance()
    for section, value in overlay.items():
        if section == "axis":
            _merge_axes(data, value, origin, prov)
        elif isinstance(value, Mapping) and section == "drives":
            base = data.setdefault("drives", {})
            if not isinstance(base, dict):
                raise ConfigError("drives", "must be a table")
            for backend, opts in value.items():
                if isinstance(opts, Mapping) and isinstance(base.get(backend), dict):
                    for k, v in opts.items():
                        base[backend][k] = v
                        prov.note(f"drives.{backend}.{k}", f"{origin}: drives.{backend}.{k}")
                else:
                    base[backend] = opts
                    prov.note(f"drives.{backend}", f"{origin}: drives.{backend}")
        elif isinstance(value, Mapping) and section in ("nc", "zenoh"):
            base = data.setdefault(section, {})
            if not isinstance(base, dict):
                raise ConfigError(section, "must be a table")
            for k, v in value.items():
                base[k] = v
                prov.note(f"{section}.{k}", f"{origin}: {section}.{k}")
        else:  # not a known table: parse_config reports it, naming the overlay
            data[section] = value
            prov.note(section, f"{origin}: {section}")


def _merge_axes(data: dict[str, Any], value: Any, origin: str, prov: _Provenance) -> None:
    axes = data.setdefault("axis", [])
    if not isinstance(axes, list):
        raise ConfigError("axis", "must be an array of [[axis]] tables")
    if isinstance(value, Mapping):  # [axis.2] tables: change existing axes
        items = []
        for k, t in value.items():
            try:
                axis_id = int(k)
            except ValueError:
                raise ConfigError(f"{origin}: axis.{k}", "expected [axis.<AxisId>] with an integer AxisId, "
                                                         "e.g. [axis.1]", _NO_AXIS) from None
            i = _axis_index(data, axis_id)
            if i is None:
                raise ConfigError(f"{origin}: axis.{k}", f"no axis with AxisId {axis_id} (configured: "
                                                         f"{_axis_ids(data)}; add one with an [[axis]] table)",
                                  _NO_AXIS)
            if not isinstance(t, Mapping):
                raise ConfigError(f"{origin}: axis.{k}", "must be a table")
            if "AxisId" in t and (isinstance(t["AxisId"], bool) or t["AxisId"] != axis_id):
                # (as --set axis.N.AxisId: [axis.N] names the axis it changes, it cannot renumber it)
                raise ConfigError(f"{origin}: axis.{k}.AxisId", f"an axis's AxisId cannot be changed, got "
                                                                f"{t['AxisId']!r} in [axis.{k}] (use a config file)")
            items.append((i, f"{origin}: axis.{k}", t))
    elif isinstance(value, list):  # [[axis]] tables: by AxisId, a new one is appended
        items = []
        for n, t in enumerate(value):
            where = f"{origin}: axis[{n}]"
            if not isinstance(t, Mapping):
                raise ConfigError(where, "must be a table")
            if "AxisId" not in t:
                raise ConfigError(f"{where}.AxisId", "missing (an overlay's [[axis]] table names the axis it "
                                                    "changes or adds by AxisId)")
            i = _axis_index(data, t["AxisId"])
            if i is None:
                axes.append({})
                i = len(axes) - 1
                prov.note(f"axis[{i}]", where)
            items.append((i, where, t))
    else:
        raise ConfigError(f"{origin}: axis", "must be [axis.<AxisId>] or [[axis]] tables")
    for i, where, t in items:
        for k, v in t.items():
            _put_axis_key(axes[i], k, v)
            prov.note(f"axis[{i}].{k}", f"{where}.{k}")


def _put_axis_key(table: dict[str, Any], key: str, value: Any) -> None:
    """Set an [[axis]] key, dropping another spelling of the same parameter (AxisMaxVelocity = AxisVeloMax)."""
    canon = ALIASES.get(key, key)
    for k in [k for k in table if k != key and ALIASES.get(k, k) == canon]:
        del table[k]
    table[key] = value


def apply_set(data: dict[str, Any], item: str, prov: _Provenance | None = None) -> None:
    """Apply one ``--set KEY=VALUE`` to ``data`` (in place; see the module docstring).

    Raises:
        ConfigError: a malformed item or an axis that does not exist (key ``--set ...``); a bad
            value is found by :func:`parse_config`, named the same way through ``prov``.
    """
    prov = prov or _Provenance()
    key, sep, text = item.partition("=")
    key = key.strip()
    parts = key.split(".")
    label = f"--set {key}"
    if not sep or len(parts) < 2 or not all(parts):
        raise ConfigError(f"--set {item}", "expected KEY=VALUE, e.g. axis.1.AxisVeloMax=300 or nc.cycle_time=0.002")
    if parts[0] == "axis":
        if len(parts) != 3:
            raise ConfigError(label, "expected axis.<AxisId>.<Parameter>=VALUE, e.g. axis.1.AxisVeloMax=300")
        try:
            axis_id = int(parts[1])
        except ValueError:
            raise ConfigError(label, f"the AxisId must be an integer, got {parts[1]!r}", _NO_AXIS) from None
        name = parts[2]
        if name == "AxisId":
            raise ConfigError(label, "an axis's AxisId cannot be changed (use a config file)")
        i = _axis_index(data, axis_id)
        if i is None:
            raise ConfigError(label, f"no axis with AxisId {axis_id} (configured: {_axis_ids(data)})", _NO_AXIS)
        _put_axis_key(data["axis"][i], name, _set_value(text, name in _STRING_KEYS["axis"]))
        prov.note(f"axis[{i}].{name}", label)
    elif parts[0] in ("nc", "zenoh", "redundancy"):
        if len(parts) != 2:
            raise ConfigError(label, f"expected {parts[0]}.<key>=VALUE, e.g. nc.cycle_time=0.002")
        table = data.setdefault(parts[0], {})
        if not isinstance(table, dict):
            raise ConfigError(parts[0], "must be a table")
        value = _set_value(text, parts[1] in _STRING_KEYS[parts[0]])
        if parts[0] == "zenoh" and parts[1] in _LIST_KEYS and isinstance(value, str):
            value = [e.strip() for e in value.split(",")]  # --set zenoh.listen=tcp/a:1,tcp/b:2 (no TOML quoting)
        table[parts[1]] = value
        prov.note(f"{parts[0]}.{parts[1]}", label)
    elif parts[0] == "drives":
        if len(parts) != 3:
            raise ConfigError(label, "expected drives.<backend>.<key>=VALUE, e.g. drives.canopen.channel=can0")
        sections = data.setdefault("drives", {})
        if not isinstance(sections, dict):
            raise ConfigError("drives", "must be a table")
        table = sections.setdefault(parts[1], {})
        if not isinstance(table, dict):
            raise ConfigError(f"drives.{parts[1]}", "must be a table")
        table[parts[2]] = _set_value(text, False)
        prov.note(f"drives.{parts[1]}.{parts[2]}", label)
    else:
        raise ConfigError(label, "unknown section (allowed: axis.<AxisId>.<Parameter>, nc.<key>, zenoh.<key>, "
                                 "redundancy.<key>, drives.<backend>.<key>)")


def _set_value(text: str, string: bool) -> Any:
    """A --set VALUE: the text for a string-valued key, else a TOML value (true/false in any case), else the text."""
    if string:
        return text
    t = text.strip()
    if t.lower() in ("true", "false"):
        return t.lower() == "true"
    try:
        return tomllib.loads(f"v = {t}")["v"]
    except tomllib.TOMLDecodeError:
        return text  # not a TOML value: parse_config names the type it needs


def _read_toml(path: str | Path, option: str) -> dict[str, Any]:
    try:
        text = Path(path).read_text(encoding="utf-8")
    except OSError as exc:
        raise ConfigError(option, f"cannot read {path}: {exc.strerror or exc}") from None
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(option, f"{path}: TOML syntax error: {exc}") from None


def load_config(path: str | Path | None = None, *, listen: Sequence[str] | None = None,
                connect: Sequence[str] | None = None, mode: str | None = None, name: str | None = None,
                cycle_time: float | None = None, realtime: str | None = None,
                watchdog_timeout: float | None = None, retain_file: str | None = None, roles: str | None = None,
                tls_dir: str | None = None, lease_ms: int | None = None, overlays: Sequence[str | Path] = (),
                sets: Sequence[str] = ()) -> ServerConfig:
    """Load ``path`` (TOML) or the embedded default, then apply the overlays, ``sets`` and the
    command-line overrides (the layers of the module docstring).

    Args:
        path: a TOML file replacing the default as a whole; None for the embedded default.
        overlays: partial TOML files merged over it, in order (``--config-overlay``).
        sets: ``KEY=VALUE`` items applied after the overlays, in order (``--set``).
        listen: replaces ``zenoh.listen`` when given (non-empty).
        connect: replaces ``zenoh.connect`` when given (non-empty).
        mode: replaces ``zenoh.mode``; ``"client"`` without ``listen`` also drops the default listen endpoint.
        name, cycle_time, realtime, watchdog_timeout, retain_file: replace ``nc.*`` when given.
        roles, tls_dir: replace ``zenoh.roles`` / ``zenoh.tls_dir`` when given (a relative path, here
            or in the file, is resolved against the working directory, as ``nc.retain_file``).
        lease_ms: replaces ``zenoh.lease`` when given.

    Raises:
        ConfigError: unreadable file (key ``--config`` / ``--config-overlay``), TOML syntax error, or
            any invalid value (an overlay's or a --set's named as such).
    """
    if path is None:
        try:
            data = tomllib.loads(default_config_text())
        except tomllib.TOMLDecodeError as exc:  # pragma: no cover - the shipped file is tested
            raise ConfigError("--config", f"default.toml: TOML syntax error: {exc}") from None
    else:
        data = _read_toml(path, "--config")
    prov = _Provenance()
    for ov in overlays:
        merge_overlay(data, _read_toml(ov, "--config-overlay"), str(ov), prov)
    for item in sets:
        apply_set(data, item, prov)
    try:
        return _apply_options(data, prov, listen=listen, connect=connect, mode=mode, name=name, cycle_time=cycle_time,
                              realtime=realtime, watchdog_timeout=watchdog_timeout, retain_file=retain_file,
                              roles=roles, tls_dir=tls_dir, lease_ms=lease_ms)
    except ConfigError as exc:
        raise prov.translate(exc) from None


def _apply_options(data: dict[str, Any], prov: _Provenance, *, listen: Sequence[str] | None,
                   connect: Sequence[str] | None,
                   mode: str | None, name: str | None, cycle_time: float | None, realtime: str | None,
                   watchdog_timeout: float | None, retain_file: str | None, roles: str | None,
                   tls_dir: str | None, lease_ms: int | None) -> ServerConfig:
    nc = data.setdefault("nc", {})
    zn = data.setdefault("zenoh", {})
    if not isinstance(nc, dict) or not isinstance(zn, dict):
        return parse_config(data)  # reports the non-table
    def put(table: dict[str, Any], section: str, key: str, value: Any) -> None:
        table[key] = value
        prov.labels.pop(f"{section}.{key}", None)  # an error in it is the option's, not an overlay's

    if mode is not None:
        put(zn, "zenoh", "mode", mode)
        if mode == "client" and not listen:
            zn.pop("listen", None)
    if listen:
        put(zn, "zenoh", "listen", list(listen))
    if connect:
        put(zn, "zenoh", "connect", list(connect))
    if lease_ms is not None:
        put(zn, "zenoh", "lease", lease_ms)
    for key, value in (("name", name), ("cycle_time", cycle_time), ("realtime", realtime),
                       ("watchdog_timeout", watchdog_timeout), ("retain_file", retain_file)):
        if value is not None:
            put(nc, "nc", key, value)
    for key, value in (("roles", roles), ("tls_dir", tls_dir)):
        if value is not None:
            put(zn, "zenoh", key, value)
    return parse_config(data)
