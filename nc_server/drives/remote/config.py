"""The configuration of remote drives, shared by the NC (``RemoteDrive.from_config``) and ``nc-drive-sim``.

In the NC's TOML::

    [drives.remote]                      # the backend's options (all optional)
    connect = ["tcp/127.0.0.1:7447"]     # where the NC's drive link connects (default: see link_endpoints)
    max_age = 50                         # NC cycles an axis's inputs may be old before 0x4655
    # max_age_ms = 50.0                  # or the same as a time [ms] (whole NC cycles, rounded up; not both)
    sender = "cycle"                     # "cycle" | "thread": who puts the outputs (.link)
    lease_ms = 500                       # the link session's transport lease (default: the NC's)
    timeout_ms = 100                     # the drive hosts' silence timeout (nc-drive-sim --timeout; default 100)
    reaction_margin = 0                  # NC cycles a drive's state machine may lag its host's echo (gateways to
                                         # real drives: 2; Cia402Drive's docstring); default 0 (nc-drive-sim)

    [[axis]]
    AxisId = 1
    Drive = { backend = "remote", host = "drives1" }            # slot: its order among drives1's axes
    [[axis]]
    AxisId = 2
    Drive = { backend = "remote", host = "drives1", slot = 1 }  # or an explicit slot
    # mode = "csv", kv = 50.0: cyclic synchronous velocity, as for cia402-sim (cia402.drive.axis_options)

Decisions:

* ``max_age`` default 50 NC cycles (50 ms at 1 ms): a drive host publishes every drive cycle, so inputs are
  normally 0-2 cycles old (bench/remote_drives.py: p50 1, round trip p50 2 cycles), but on the 2-core VM under
  load (load average 9) the age reached p99 ~20 and max ~40 cycles (both processes taken off the CPU for tens of
  ms); 20 would have raised false 0x4655 there. 50 rides through that and still reports a drive whose data
  stopped within 50 ms, half the drive's own silence timeout (100 ms by default): the NC knows before the drive
  stops itself. A lost host (its token gone, 2-3 ms after a crash) is reported at once as 0x4651 anyway.
* ``timeout_ms``: the drive hosts' silence timeout, read by ``nc-drive-sim --config`` (its ``--timeout`` overrides
  it) and by the NC, so that both check it against a hot-standby pair's takeover where the TOML has
  ``[redundancy] enabled``: it must be longer than :func:`worst_takeover` (the longest takeover the pair may
  publish: ``max(takeover_cycles, min(LIMIT_CAP_S, [zenoh] lease)) + 1`` NC cycles: the log silence a standby waits
  under load and the cycle that notices it; docs/standby.md), else a takeover would find the drives quick-stopped
  (0x8130). A refusal (``ConfigError`` on ``drives.remote.timeout_ms``, nc-drive-sim's exit code 2) where both are
  known: the NC with ``timeout_ms`` in its TOML, nc-drive-sim with ``--config`` (the timeout it will use:
  ``--timeout``, else ``timeout_ms``, else for a pair :func:`pair_default_timeout`, that bound + 100 ms). The NC
  without ``timeout_ms`` cannot know a drive host's ``--timeout``: it logs the bound. nc-drive-sim without
  ``--config`` (default 100 ms: too short for any pair) learns the limit in force from the NC's outputs (``rx``
  ``takeover_limit_ms``, 0 without redundancy) and warns once (its status
  ``timeout_short``): it is running already and stopping it would stop the drives.
* ``max_age`` counts NC cycles, as the link counts the inputs' age (+1 per exchange without new inputs) and as
  TwinCAT counts its "n continuous NC cycles" of invalid I/O data; ``max_age_ms`` gives it as a time, as the
  section's other times (``lease_ms``, ``timeout_ms``), turned into whole NC cycles (rounded up, at least 1) by
  the NC, which knows its cycle: the same drive host then gets the same time whatever the NC's cycle.
* Slots: per host either every axis names its ``slot`` or none does (then the order of the axes in the file);
  a host's slots are 0..k-1, each once.
* The link's endpoints (:func:`link_endpoints`): ``connect`` if given; else the NC's own ``[zenoh] connect``
  (an NC behind a router: the link and the drive hosts meet at that router); else the NC's listen endpoints
  with a wildcard address replaced by loopback (the link is a client of the NC's own router session, on the same
  machine). With TLS the link uses the NC's certificate; give ``connect`` with a name the router's certificate has.

It may import: nc_server.core.params, nc_server.drives.remote.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass
from typing import Any, Mapping, Sequence

from ...core.params import ConfigError
from ..cia402.drive import reaction_margin_option
from .link import HostSlots
from .wire import check_host

SENDERS = ("cycle", "thread")
#: [drives.remote] keys and per-axis Drive keys (without ``backend``).
BACKEND_KEYS = ("connect", "max_age", "max_age_ms", "sender", "lease_ms", "timeout_ms", "reaction_margin")
AXIS_KEYS = ("host", "slot")
DEFAULT_MAX_AGE = 50
#: the largest max_age [NC cycles] (also max_age_ms in cycles)
MAX_AGE_CYCLES = 100_000
#: the drive hosts' silence timeout unless ``timeout_ms`` or nc-drive-sim's ``--timeout`` say otherwise [s]
DEFAULT_TIMEOUT = 0.1
#: ``[redundancy] takeover_cycles`` unless set (nc_server.server.config)
DEFAULT_TAKEOVER_CYCLES = 15


@dataclass(frozen=True)
class RemoteOptions:
    """Checked ``[drives.remote]`` options (see the module docstring)."""

    connect: tuple[str, ...] = ()
    max_age: int = DEFAULT_MAX_AGE
    sender: str = "cycle"
    lease_ms: int | None = None
    timeout_ms: float | None = None
    max_age_ms: float | None = None
    reaction_margin: int = 0

    def max_age_cycles(self, cycle_time: float) -> int:
        """``max_age`` in NC cycles: ``max_age_ms`` in whole cycles (rounded up, at least 1) if given."""
        return self.max_age if self.max_age_ms is None else cycles(self.max_age_ms / 1000.0, cycle_time)


_ENDPOINT = re.compile(r"^(tcp|udp|tls|quic|ws)/(\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9.-]+):[0-9]{1,5}([?#].*)?$|^unixsock-stream/.+$")


def _endpoint(ep: Any, key: str) -> str:
    if not isinstance(ep, str) or not _ENDPOINT.match(ep):
        raise ConfigError(key, f"invalid endpoint {ep!r}: expected e.g. 'tcp/127.0.0.1:7447' or "
                               f"'unixsock-stream//run/nc.sock'")
    return ep


def parse_options(options: Mapping[str, Any], where: str = "drives.remote") -> RemoteOptions:
    """Check the backend's ``[drives.remote]`` table.

    Raises:
        ConfigError: an unknown key or a bad value (the key names it, e.g. ``drives.remote.max_age``).
    """
    if not isinstance(options, Mapping):
        raise ConfigError(where, f"must be a table, got {type(options).__name__}")
    for k in options:
        if k not in BACKEND_KEYS:
            raise ConfigError(f"{where}.{k}", f"unknown key (allowed: {', '.join(BACKEND_KEYS)})")
    connect = options.get("connect", [])
    if isinstance(connect, str):
        connect = [connect]
    if not isinstance(connect, list):
        raise ConfigError(f"{where}.connect", f"must be a list of endpoints, got {connect!r}")
    eps = tuple(_endpoint(ep, f"{where}.connect[{i}]") for i, ep in enumerate(connect))
    max_age = options.get("max_age", DEFAULT_MAX_AGE)
    if isinstance(max_age, bool) or not isinstance(max_age, int) or not 1 <= max_age <= MAX_AGE_CYCLES:
        raise ConfigError(f"{where}.max_age", f"must be an integer number of NC cycles 1..{MAX_AGE_CYCLES}, "
                                              f"got {max_age!r}")
    max_age_ms = options.get("max_age_ms")
    if max_age_ms is not None:
        if "max_age" in options:
            raise ConfigError(f"{where}.max_age_ms", "give max_age (NC cycles) or max_age_ms, not both")
        if isinstance(max_age_ms, bool) or not isinstance(max_age_ms, (int, float)) or \
                not 0.0 < max_age_ms <= 3_600_000.0:
            raise ConfigError(f"{where}.max_age_ms", f"must be a number of ms > 0 (at most 3600000), got {max_age_ms!r}")
    sender = options.get("sender", "cycle")
    if sender not in SENDERS:
        raise ConfigError(f"{where}.sender", f"must be one of {', '.join(map(repr, SENDERS))}, got {sender!r}")
    lease = options.get("lease_ms")
    if lease is not None and (isinstance(lease, bool) or not isinstance(lease, int) or not 100 <= lease <= 3_600_000):
        raise ConfigError(f"{where}.lease_ms", f"must be an integer number of ms 100..3600000, got {lease!r}")
    timeout = options.get("timeout_ms")
    if timeout is not None and (isinstance(timeout, bool) or not isinstance(timeout, (int, float))
                                or not 1.0 <= timeout <= 3_600_000.0):
        raise ConfigError(f"{where}.timeout_ms", f"must be a number of ms 1..3600000, got {timeout!r}")
    margin, _ = reaction_margin_option({k: v for k, v in options.items() if k == "reaction_margin"}, where, 0)
    return RemoteOptions(eps, max_age, sender, lease, None if timeout is None else float(timeout),
                         None if max_age_ms is None else float(max_age_ms), margin)


def host_slots(axis_options: Sequence[Mapping[str, Any]], axis_ids: Sequence[int] | None = None,
               where: Sequence[str] | None = None) -> list[HostSlots]:
    """The hosts and their slots from the axes' ``Drive`` tables (without ``backend``), in first-seen order.

    Args:
        axis_options: per axis (the backend's axes, in order) its ``Drive`` options.
        axis_ids: their AxisIds (None: unknown, sent as 0: the host checks nothing).
        where: per axis the config key of its Drive table (default ``axis[i].Drive``).

    Raises:
        ConfigError: a missing or bad ``host``, a bad or duplicate ``slot``, slots not 0..k-1, slots on some axes
            of a host only, an unknown key.
    """
    keys = list(where) if where is not None else [f"axis[{i}].Drive" for i in range(len(axis_options))]
    ids = list(axis_ids) if axis_ids is not None else [0] * len(axis_options)
    per_host: dict[str, list[tuple[int | None, int]]] = {}
    for i, opts in enumerate(axis_options):
        key = keys[i]
        for k in opts:
            if k not in AXIS_KEYS:
                raise ConfigError(f"{key}.{k}", f"unknown key for the remote backend (allowed: backend, "
                                                f"{', '.join(AXIS_KEYS)}, mode, kv)")
        if "host" not in opts:
            raise ConfigError(f"{key}.host", "missing: which drive host (nc-drive-sim --host) serves the axis")
        try:
            host = check_host(opts["host"], f"{key}.host")
        except ValueError as exc:
            raise ConfigError(f"{key}.host", str(exc).split(": ", 1)[1]) from None
        slot = opts.get("slot")
        if slot is not None and (isinstance(slot, bool) or not isinstance(slot, int) or not 0 <= slot <= 4095):
            raise ConfigError(f"{key}.slot", f"must be an integer 0..4095, got {slot!r}")
        per_host.setdefault(host, []).append((slot, i))
    out = []
    for host, entries in per_host.items():
        given = [s for s, _ in entries if s is not None]
        if given and len(given) != len(entries):
            i = next(i for s, i in entries if s is None)
            raise ConfigError(f"{keys[i]}.slot", f"missing: the other axes of host {host!r} give their slot "
                                                 f"(all or none)")
        if given:
            if sorted(given) != list(range(len(entries))):
                i = entries[-1][1]
                raise ConfigError(f"{keys[i]}.slot", f"the slots of host {host!r} must be 0..{len(entries) - 1}, "
                                                     f"each once, got {sorted(given)}")
            entries = sorted(entries, key=lambda e: e[0] if e[0] is not None else 0)
        rows = tuple(i for _, i in entries)
        out.append(HostSlots(host, rows, tuple(int(ids[i]) for i in rows)))
    return out


def link_endpoints(options: RemoteOptions, zenoh_settings: Any) -> tuple[str, ...]:
    """Where the NC's drive link connects (see the module docstring).

    Raises:
        ConfigError: nothing to connect to (no ``connect``, the NC neither connects nor listens on a usable endpoint).
    """
    if options.connect:
        return options.connect
    if zenoh_settings is None:
        raise ConfigError("drives.remote.connect", "missing: the NC has no zenoh settings to derive it from")
    if zenoh_settings.connect:
        return tuple(zenoh_settings.connect)
    out = []
    for ep in zenoh_settings.listen:
        proto, _, addr = ep.partition("/")
        if proto == "unixsock-stream":
            out.append(ep)
            continue
        host, _, port = addr.partition("#")[0].partition("?")[0].rpartition(":")
        if port in ("", "0"):
            continue  # a random port: nothing to connect to
        host = {"0.0.0.0": "127.0.0.1", "[::]": "[::1]"}.get(host, host)
        out.append(f"{proto}/{host}:{port}")
    if not out:
        raise ConfigError("drives.remote.connect", "missing: the NC listens on no endpoint the drive link can "
                                                   "connect to (give [drives.remote] connect)")
    return tuple(out)


def cycles(seconds: float, cycle_time: float) -> int:
    """``seconds`` in whole NC cycles (at least 1)."""
    return max(1, math.ceil(seconds / cycle_time - 1e-9))


#: the most a hot-standby pair's standby waits for the active NC's logs before it takes over [s] (its loss
#: detector's cap under load; nc_server.server.standby.LIMIT_CAP_S)
LIMIT_CAP_S = 1.0
#: the zenoh lease an NC announces by default [ms] ([zenoh] lease)
DEFAULT_LEASE_MS = 500


def takeover_bound(takeover_cycles: int, cycle_time: float) -> float:
    """The longest a hot-standby pair leaves its drives without outputs at a takeover [s] when its standby's limit
    is ``takeover_cycles`` NC cycles without the active NC's log (a freeze, a cut link; a crash is seen at once): it
    notices at the start of the next cycle, whose outputs go out (docs/standby.md, the ha status's
    ``takeover_limit_cycles``)."""
    return (int(takeover_cycles) + 1) * float(cycle_time)


def worst_takeover(takeover_cycles: int, cycle_time: float, lease_s: float) -> float:
    """The longest takeover the pair may publish [s]: its standby's limit grows with the gaps between the active
    NC's logs under load up to LIMIT_CAP_S, and the active NC's lease (its tokens go after a freeze that long: a
    takeover then at the latest) bounds it too; at least ``takeover_cycles``; plus the cycle whose outputs go out."""
    cycles = max(int(takeover_cycles), math.ceil(min(LIMIT_CAP_S, float(lease_s)) / float(cycle_time) - 1e-9))
    return takeover_bound(cycles, cycle_time)


def pair_default_timeout(takeover_cycles: int, cycle_time: float, lease_s: float) -> float:
    """nc-drive-sim's silence timeout for a hot-standby pair when neither ``--timeout`` nor ``[drives.remote]
    timeout_ms`` gives one [s]: the pair's :func:`worst_takeover` plus the usual default timeout (DEFAULT_TIMEOUT,
    100 ms, is below any pair's worst case)."""
    return worst_takeover(takeover_cycles, cycle_time, lease_s) + DEFAULT_TIMEOUT


def check_timeout(timeout: float, takeover_cycles: int, cycle_time: float, key: str,
                  lease_s: float = DEFAULT_LEASE_MS / 1000.0) -> None:
    """A drive host's silence timeout [s] must be longer than the longest takeover the pair may publish
    (:func:`worst_takeover`: ``min(LIMIT_CAP_S, lease)`` + 1 cycle, at least ``takeover_cycles`` + 1).

    Raises:
        ConfigError: on ``key``, naming the figures.
    """
    bound = worst_takeover(takeover_cycles, cycle_time, lease_s)
    if not timeout > bound:
        raise ConfigError(key, f"the drive hosts' silence timeout ({timeout * 1e3:g} ms) must be longer than the "
                               f"standby NC's longest takeover ({bound * 1e3:g} ms: its limit grows under load up to "
                               f"{LIMIT_CAP_S * 1e3:g} ms or the NC's lease of {lease_s * 1e3:g} ms, whichever is "
                               f"shorter, at least [redundancy] takeover_cycles {takeover_cycles}, plus one cycle of "
                               f"{cycle_time * 1e3:g} ms): the drives would stop with 0x8130 at a takeover")
