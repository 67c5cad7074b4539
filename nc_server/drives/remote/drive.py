"""``remote``: CiA 402 drives in another process (``nc-drive-sim`` or a gateway), reached over zenoh.

:class:`RemoteDrive` is the NC side of :class:`..cia402.drive.Cia402Drive` (state machine, encoder chain, drive
errors -> NC axis errors) over a :class:`.link.RemoteLink`. Options and per-axis ``Drive`` tables:
:mod:`.config`.

What the NC shows (through ``Cia402Drive``):

* a host whose liveliness token is gone, or that has not sent inputs yet: ``alive`` False -> lost communication
  (axis error 0x4651), the axis not ready (a start is refused with 0x4225);
* inputs older than ``max_age`` NC cycles: invalid I/O data (IoDataInvalid, then 0x4655 after 3 cycles), the last
  valid actual values stay;
* the drive's own faults (0x603F), e.g. 0x8130 after the drive saw the NC go silent.

Decisions:

* A drive host that is not there at start: the NC starts anyway, with that host's axes not ready and in
  communication error (0x4651) until the host's token and first inputs arrive; then MC_Reset and MC_Power bring
  them up. Reasons: the drive link can only connect once the NC's own session listens (after the drives are
  built), containers start in any order, and one missing host must not keep the NC from serving its other axes.
  A host still missing :data:`MISSING_WARN_S` after the link connected is logged as a warning.
* ``simulated`` is False: the NC cannot tell a simulated remote drive from a real one.

It may import: numpy, zenoh, nc_server.core.params, nc_server.drives.
"""
from __future__ import annotations

import logging
from typing import Any, Mapping, Sequence

from ...core.params import AxisParams, ConfigError
from ..base import DriveContext
from ..cia402.drive import DEFAULT_KV, Cia402Drive
from ..cia402.drive import axis_options as cia402_axis_options
from ..cia402.objects import Mode
from .config import MAX_AGE_CYCLES, RemoteOptions, host_slots, link_endpoints, parse_options
from .link import HostSlots, RemoteLink, link_config

log = logging.getLogger("nc_server.drives.remote")

#: A host not seen this long after the link connected is logged (once) [s].
MISSING_WARN_S = 5.0


class RemoteDrive(Cia402Drive):
    """CiA 402 drives on drive hosts reached over zenoh.

    Args:
        params: the axes' parameters.
        cycle_time: the NC cycle [s].
        link: the process data link (:meth:`from_config` builds a :class:`RemoteLink`).
        max_age: NC cycles an axis's inputs may be old before they are invalid I/O data.
    """

    link: RemoteLink

    def __init__(self, params: Sequence[AxisParams], cycle_time: float, link: RemoteLink, *,
                 max_age: int = 50, mode: Mode | Sequence[Mode] = Mode.CSP,
                 kv: float | Sequence[float] = DEFAULT_KV, reaction_margin: int = 0) -> None:
        super().__init__(params, cycle_time, link, simulated=False, max_age=max_age, mode=mode, kv=kv,
                         reaction_margin=reaction_margin)

    @classmethod
    def from_config(cls, params: Sequence[AxisParams], cycle_time: float,
                    axis_options: Sequence[Mapping[str, Any]], context: DriveContext) -> RemoteDrive:
        """The remote drives of ``params`` (see :mod:`.config` for the options).

        Raises:
            ConfigError: an unknown option, a bad value, a missing ``host``, bad slots, nowhere to connect.
        """
        if len(axis_options) != len(params):
            raise ConfigError("axis", f"{len(params)} axes but {len(axis_options)} Drive tables")
        opts: RemoteOptions = parse_options(context.options)
        ids = context.axis_ids  # (None: not known, sent as 0; else the hosts check them)
        modes, kvs, rest = [], [], []
        for i, o in enumerate(axis_options):  # the CiA 402 options (mode, kv) as cia402-sim takes them
            mode, kv, others = cia402_axis_options(o, f"axis[{i}].Drive")
            modes.append(mode)
            kvs.append(kv)
            rest.append(others)
        max_age = opts.max_age_cycles(cycle_time)
        if max_age > MAX_AGE_CYCLES:  # (refused as max_age is, not capped silently)
            raise ConfigError("drives.remote.max_age_ms", f"{opts.max_age_ms:g} ms is {max_age} NC cycles of "
                                                          f"{cycle_time * 1e3:g} ms: at most {MAX_AGE_CYCLES} "
                                                          f"(as max_age)")
        hosts = host_slots(rest, ids)
        endpoints = link_endpoints(opts, context.zenoh)
        z = context.zenoh
        lease = opts.lease_ms if opts.lease_ms is not None else int(getattr(z, "lease_ms", 500) or 500)
        tls_dir = getattr(z, "tls_dir", None)
        name = context.nc_name
        try:
            link_config(endpoints, lease, tls_dir, name)  # zenoh's own checks, now: a start error, not a log line
        except Exception as exc:
            raise ConfigError("drives.remote.connect", f"{exc}") from None
        link = RemoteLink(name, len(params), hosts, lambda: link_config(endpoints, lease, tls_dir, name),
                          sender=opts.sender, missing_warn_cycles=max(1, round(MISSING_WARN_S / cycle_time)))
        try:
            return cls(params, cycle_time, link, max_age=max_age, mode=modes, kv=kvs,
                       reaction_margin=opts.reaction_margin)
        except BaseException:
            link.close()
            raise

    @property
    def hosts(self) -> list[HostSlots]:
        """The drive hosts and their slots."""
        return self.link.host_slots
