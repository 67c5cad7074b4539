"""The ``canopen`` drive backend: CiA 402 drives on a CAN bus (python-canopen over python-can).

Configured in the NC's TOML (the ``Drive`` table of each axis and the backend's ``[drives.canopen]`` section)::

    [drives.canopen]
    interface = "virtual"        # python-can interface ("socketcan", "pcan", "kvaser", ...); default "virtual"
    channel = "can0"             # python-can channel; default "can0"
    bitrate = 1000000            # [bit/s]; default 1000000 (the virtual bus ignores it)
    simulate_slaves = true       # simulated CiA 402 slaves in the NC's process (virtual bus only); default false
    sdo_timeout = 0.3            # [s] per SDO response at start; default 0.3, at most 60
    heartbeat_period = 0.1       # [s] the nodes' producer heartbeat time (0x1017); default 0.1, 0.001..65.535
    heartbeat_timeout = 0.35     # [s] no heartbeat for this long: the node is lost (0x4651); default 3.5 periods
    monitoring = "heartbeat"     # or "node_guarding": the master polls every heartbeat_period (0x100C/0x100D)
    start_timeout = 2.0          # [s] for the operational heartbeat and the first TPDOs at start; default 2.0, at most 60
    max_age = 3                  # [NC cycles] older inputs are invalid I/O data (0x4655); default 3
    reaction_margin = 2          # [NC cycles] a drive's state machine may lag its TPDO's SYNC; default 2

    [[axis]]
    AxisId = 1
    AxisEncoderScalingFactor = 0.0001   # [mm/inc]: positions travel as INT32 increments
    Drive = { backend = "canopen", node_id = 2, mode = "csp", eds = "drives/servo.eds" }

Per axis: ``node_id`` (required, 1..127, unique), ``mode`` ("csp", default, or "csv"), ``kv`` (CSV: the NC's
position loop gain [1/s]), ``eds`` (the drive's EDS file; default the simulated drive's ``cia402_sim.eds``; a
relative path is taken from the working directory). A bad or unknown key is a
:class:`~nc_server.core.params.ConfigError`; a missing bus or node a :class:`.link.CanopenStartError` (bounded by
the SDO timeouts and ``start_timeout``). python-canopen's own logger ("canopen") is set to WARNING unless
something configured it (it logs every SDO transfer at INFO).

It may import: numpy, can, canopen, nc_server.core.params, nc_server.drives, .link, .slave, .pdo.
"""
from __future__ import annotations

import logging
import math
import os
from typing import Any, Mapping, Sequence

import canopen

from ...core.params import AxisParams, ConfigError
from ..base import DriveABC, DriveContext
from ..cia402.drive import DEFAULT_KV, Cia402Drive, axis_options, link_options, reaction_margin_option
from ..cia402.objects import INTERPOLATION_TIME_PERIOD, Mode
from . import pdo
from .link import MONITORING, BusConfig, CanopenLink, NodeConfig, interpolation_period
from .slave import SimulatedSlaves

log = logging.getLogger(__name__)

_AXIS_KEYS = {"node_id", "eds"}
#: upper bound of sdo_timeout and start_timeout: beyond it a missing node looks like a hung server
_MAX_WAIT = 60.0
#: heartbeat_period's upper bound: 0x1017 / 0x100C hold it in ms as UNSIGNED16
_MAX_PERIOD = 65.535
_BUS_KEYS = {"interface", "channel", "bitrate", "simulate_slaves", "sdo_timeout", "heartbeat_period",
             "heartbeat_timeout", "start_timeout", "monitoring"}
_SECTION = "drives.canopen"
#: ``reaction_margin`` unless set: a real drive's state machine often runs in a slower task than its PDOs and shows
#: Operation enabled for a cycle or two after the SYNC that brought a Shutdown (Cia402Drive's docstring)
DEFAULT_REACTION_MARGIN = 2


class CanopenDrive(Cia402Drive):
    """CiA 402 drives on one CAN bus: a :class:`~..cia402.drive.Cia402Drive` over a :class:`.link.CanopenLink`.

    Args:
        params: the axes, in order.
        cycle_time: the NC cycle [s].
        link: the started CANopen link (one node per axis, same order).
        slaves: the in-process simulated slaves (closed with the drive), or None.
        max_age: inputs older than this [NC cycles] are invalid I/O data.
        modes: per axis CSP or CSV.
    """

    def __init__(self, params: Sequence[AxisParams], cycle_time: float, link: CanopenLink, *,
                 slaves: SimulatedSlaves | None = None, max_age: int = 3,
                 mode: Mode | Sequence[Mode] = Mode.CSP, kv: float | Sequence[float] = DEFAULT_KV,
                 reaction_margin: int = DEFAULT_REACTION_MARGIN) -> None:
        self.slaves = slaves
        super().__init__(params, cycle_time, link, simulated=slaves is not None, max_age=max_age, mode=mode, kv=kv,
                         reaction_margin=reaction_margin)

    @classmethod
    def from_config(cls, params: Sequence[AxisParams], cycle_time: float,
                    axis_options: Sequence[Mapping[str, Any]], context: DriveContext) -> DriveABC:
        """The drives as ``[drives.canopen]`` and the axes' ``Drive`` tables configure them (module docstring).

        Raises:
            ConfigError: an unknown key or a bad value.
            CanopenStartError: the bus cannot be opened or a node does not answer at start.
        """
        opts = dict(context.options)
        bus, simulate, max_age, margin = _bus_options(opts)
        quiet = logging.getLogger("canopen")
        if quiet.level == logging.NOTSET:  # canopen logs every SDO, mapping entry and NMT change at INFO
            quiet.setLevel(logging.WARNING)
        try:
            interpolation_period(cycle_time)
        except ValueError as e:
            raise ConfigError("nc.cycle_time", f"the canopen backend: {e}") from None
        axes = [_node_options(i, o) for i, o in enumerate(axis_options)]
        nodes = [n for n, _, _ in axes]
        if len(nodes) != len(params):
            raise ConfigError(_SECTION, f"{len(params)} axes, {len(nodes)} Drive tables")
        ids = [n.node_id for n in nodes]
        for i, nid in enumerate(ids):
            if ids.index(nid) != i:
                raise ConfigError(f"axis[{i}].Drive.node_id", f"node id {nid} is already axis[{ids.index(nid)}]'s")
        if bus.interface != "virtual":
            load = pdo.bus_load(len(nodes), cycle_time, bus.bitrate)
            if load > 1.0:
                log.warning("the cyclic PDOs of %d axes need %.0f %% of a %d bit/s bus at a %.4f s cycle",
                            len(nodes), 100 * load, bus.bitrate, cycle_time)
        slaves = None
        if simulate:
            slaves = SimulatedSlaves(ids, params, cycle_time, channel=bus.channel, eds=[n.eds for n in nodes])
        try:
            link = CanopenLink(nodes, cycle_time, bus)
            return cls(params, cycle_time, link, slaves=slaves, max_age=max_age, mode=[m for _, m, _ in axes],
                       kv=[k for _, _, k in axes], reaction_margin=margin)
        except BaseException:
            if slaves is not None:
                slaves.close()
            raise

    def set_probe_signal(self, index: int, level: bool, offset: float) -> None:
        """Touch probe input 2 of a simulated slave (MC_TouchProbe's input 1; :meth:`..cia402.device.Cia402Device.
        set_probe_signal`, applied at the slave's next SYNC).

        Raises:
            NotImplementedError: real slaves (no simulated input), or an axis with a sensor pattern.
            IndexError, ValueError: no axis ``index``; an offset outside the cycle.
        """
        if self.slaves is None:
            raise NotImplementedError("a real CANopen drive's touch probe input cannot be simulated")
        self.slaves.device.set_probe_signal(index, level, offset)

    def close(self) -> None:
        """Stop the network and the bus, then the simulated slaves (idempotent)."""
        self.link.close()
        if self.slaves is not None:
            self.slaves.close()


def _bus_options(opts: dict[str, Any]) -> tuple[BusConfig, bool, int, int]:
    max_age, opts = link_options(opts, _SECTION)
    margin, opts = reaction_margin_option(opts, _SECTION, DEFAULT_REACTION_MARGIN)
    unknown = sorted(set(opts) - _BUS_KEYS)
    if unknown:
        raise ConfigError(f"{_SECTION}.{unknown[0]}", f"unknown option (known: "
                                                      f"{', '.join(sorted(_BUS_KEYS | {'max_age', 'reaction_margin'}))})")
    d = BusConfig()
    interface = _str(opts, "interface", d.interface)
    channel = _str(opts, "channel", d.channel)
    bitrate = _int(opts, "bitrate", d.bitrate, 1)
    simulate = opts.get("simulate_slaves", False)
    if not isinstance(simulate, bool):
        raise ConfigError(f"{_SECTION}.simulate_slaves", f"must be true or false, got {simulate!r}")
    if simulate and interface != "virtual":
        raise ConfigError(f"{_SECTION}.simulate_slaves",
                          f"simulated slaves need interface = \"virtual\", got {interface!r}")
    sdo_timeout = _float(opts, "sdo_timeout", d.sdo_timeout, _MAX_WAIT)
    period = _float(opts, "heartbeat_period", d.heartbeat_period)
    if not 0.001 <= period <= _MAX_PERIOD:
        raise ConfigError(f"{_SECTION}.heartbeat_period", f"must be 0.001 .. {_MAX_PERIOD} s (0x1017 and 0x100C "
                                                          f"are UNSIGNED16 ms), got {period}")
    timeout = _float(opts, "heartbeat_timeout", 3.5 * period)
    if timeout <= period:
        raise ConfigError(f"{_SECTION}.heartbeat_timeout",
                          f"must be longer than heartbeat_period ({period} s), got {timeout}")
    start_timeout = _float(opts, "start_timeout", d.start_timeout, _MAX_WAIT)
    monitoring = opts.get("monitoring", d.monitoring)
    if monitoring not in MONITORING:
        raise ConfigError(f"{_SECTION}.monitoring", f"must be one of {', '.join(map(repr, MONITORING))}, "
                                                    f"got {monitoring!r}")
    return (BusConfig(interface, channel, bitrate, sdo_timeout, period, timeout, start_timeout, monitoring),
            simulate, max_age, margin)


def _node_options(i: int, o: Mapping[str, Any]) -> tuple[NodeConfig, Mode, float]:
    key = f"axis[{i}].Drive"
    mode, kv, rest = axis_options(o, key)
    unknown = sorted(set(rest) - _AXIS_KEYS)
    if unknown:
        raise ConfigError(f"{key}.{unknown[0]}", f"unknown option of the canopen backend (known: "
                                                 f"{', '.join(sorted(_AXIS_KEYS | {'mode', 'kv'}))})")
    if "node_id" not in rest:
        raise ConfigError(f"{key}.node_id", "required by the canopen backend (1..127)")
    nid = rest["node_id"]
    if isinstance(nid, bool) or not isinstance(nid, int) or not 1 <= nid <= 127:
        raise ConfigError(f"{key}.node_id", f"must be an integer 1..127, got {nid!r}")
    eds = rest.get("eds")
    if eds is not None:
        if not isinstance(eds, str) or not os.path.isfile(eds):
            raise ConfigError(f"{key}.eds", f"no such EDS file: {eds!r}")
        _check_eds(f"{key}.eds", eds, nid)
    return NodeConfig(nid, mode == Mode.CSV, eds), mode, kv


#: what the link maps or writes by SDO: an EDS without them fails later with a raw KeyError or ValueError
_EDS_OBJECTS = sorted({i for e in (pdo.RPDO1, pdo.RPDO2_CSV, *pdo.TPDO_LAYOUT.values()) for i, _ in e}
                      | {INTERPOLATION_TIME_PERIOD})


def _check_eds(key: str, eds: str, nid: int) -> None:
    try:
        od = canopen.import_od(eds, nid)
    except Exception as e:  # configparser, ValueError, KeyError ...: whatever the file's defect, it is not an EDS
        raise ConfigError(key, f"{eds!r} is not a readable EDS file: {type(e).__name__}: {e}") from None
    missing = [f"0x{i:04X}" for i in _EDS_OBJECTS if i not in od]
    if missing:
        raise ConfigError(key, f"the EDS {eds!r} lacks the objects {', '.join(missing)} a CiA 402 drive of the "
                               f"canopen backend needs")


def _str(opts: Mapping[str, Any], k: str, default: str) -> str:
    v = opts.get(k, default)
    if not isinstance(v, str) or not v:
        raise ConfigError(f"{_SECTION}.{k}", f"must be a non-empty string, got {v!r}")
    return v


def _int(opts: Mapping[str, Any], k: str, default: int, lo: int) -> int:
    v = opts.get(k, default)
    if isinstance(v, bool) or not isinstance(v, int) or v < lo:
        raise ConfigError(f"{_SECTION}.{k}", f"must be an integer >= {lo}, got {v!r}")
    return v


def _float(opts: Mapping[str, Any], k: str, default: float, hi: float = math.inf) -> float:
    v = opts.get(k, default)
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v <= 0:
        raise ConfigError(f"{_SECTION}.{k}", f"must be a positive number of seconds, got {v!r}")
    if v > hi:
        raise ConfigError(f"{_SECTION}.{k}", f"must be at most {hi:g} s (a longer wait is a hang), got {v!r}")
    return float(v)
