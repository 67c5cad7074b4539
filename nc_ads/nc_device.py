"""NcDevice: the zenoh NC as an ADS device (TwinCAT's NC index groups on AMS ports 500/501).

nc-ads is an ordinary zenoh client of one NC through the client link (:class:`nc_link.NcLink`: the one
explicit client config, scouting off, TLS, the NC's liveliness and instance, commands): it subscribes to the
NC's status frames, sends the NC's commands as zenoh queries on its own command keys
(``nc/<nc>/[axis/<id>/]cmd/<class>/<client_id>``, the same RequestHandler path every door uses) and, for
PLCTONC writes, claims the axis and publishes PLCTONC frames on ``nc/<nc>/plctonc/<client_id>`` like a PLC.
docs/ads.md has the user-facing tables; in short:

=================  ===========================================================================
index group        what
=================  ===========================================================================
0x1100             Ring-0 manager state: IO 0x03 axis count, 0x33 axis ids (UDINT[n]);
                   0x04/0x05/0x06 encoder/controller/drive counts and 0x34/0x35/0x36 their ids
                   (one each per axis, with the axis's id)
0x4000+ID          parameters by ``nc_schema.PARAMETERS`` (schema/params.json ``ads``), through
                   ReadParameter/WriteParameter; IO 0x02 the axis name (STRING(30), read-only)
0x4100+ID          axis state: IO 0 the 256-byte NCAXISSTATE_ONLINESTRUCT (TC3 layout) built
                   from the newest NCTOPLC; single fields (:data:`STATE_FIELDS`)
0x4200+ID          axis functions (ADS Write; ReadWrite returns CmdNo/CmdState), :data:`FUNCTIONS`
0x4300+ID          cyclic process data: IO 0 PLCTONC (128 B), single fields; IO 0x80 NCTOPLC
                   (256 B, read-only: zenoh-nc's choice, the NC->PLC block has no Beckhoff
                   offset in this group)
=================  ===========================================================================

Axes with an id above 255 have no ADS index group (ID is one byte of the group): they are logged
once and left out of 0x1100.

Roles (``role``, default observer): the command classes of ``nc_schema.ROLE_CLASSES``. A write the
role does not allow (parameters need engineer; functions and PLCTONC operator, SetActualPosition
engineer) is refused with 0x723 before anything is sent, as is a write from a source the server's
write policy does not allow (``AdsSource.may_write``).

Claims: a PLCTONC write (0x4300+ID IO 0, 0x01..0x04, 0x07, 0x21, 0x22, 0x25..0x27, or the
enable/disable functions 0x4200 0x51/0x50) claims the axis for nc-ads's client id (the NC answers
0x723 naming the holder while another client holds it) and makes the writing TCP connection the
axis's *supplier*: nc-ads then publishes that PLCTONC every ``supply_period`` (the NC's watchdog sees
a live holder) until

* the supplying connection closes: an axis whose supplied Enable was on gets the error 0x8F01
  (ZNC_CLIENT_LOST, through SetExternalError: the NC stops it with its deceleration and keeps the
  drive enabled until the ramp ends), then the claim is released (default PLCTONC: disabled) - the
  NC's "stop_disable" reaction to a lost client, per connection; an axis supplied with Enable off
  is just released;
* another connection writes PLCTONC to the axis: it becomes the supplier (same zenoh identity);
* 0x4200+ID 0x50 (disable): enables off for a few supply periods, then Release;
* the NC restarts (a new NC instance, ``nc_schema.NcInstance``: its instance token ``nc/<nc>/alive/<id>``
  carries another id, or its frames' cycle counter goes back) or the NC reports that it no longer holds the
  axis (``nc/<nc>/claims``): the supply ends; nothing is re-enabled by itself. The NC's liveliness token
  going away (and its instance token coming back with the same id) is no restart: zenoh drops the
  link (and the token) whenever nc-ads, the NC or a router is starved for a lease, and the same NC is
  back 0.1-0.3 s later, still holding the axis for nc-ads (its stall) or not (nc-ads's stall: the
  claims map says so).

nc-ads stopping (SIGTERM/SIGINT, ``close()``) ends like plc-run: enables off for a few supply periods, then
Release, no error. If nc-ads itself dies or freezes, the NC's own client-loss rules apply to all its axes (token gone /
PLCTONC watchdog, ClientLossReaction).

The NC unreachable: no status frame for ``stale_after`` seconds (1 s; or none yet) -> every request fails
at once with 0x707 (not ready), ReadState answers ADS state ERROR (11); a query without a reply fails
with 0x719 after ``query_timeout`` (1.5 s, well inside pyads's 5 s) or 0x707 if zenoh ended it early.
Commands are refused on stale frames too, not sent: a frozen NC would otherwise hold a worker thread for
each query's whole timeout and starve the other connections' requests.
"""
from __future__ import annotations

import logging
import math
import struct
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import zenoh
from zenoh.handlers import RingChannel

from nc_link import CommandError, NcLink, Supplies
from nc_link.link import GONE, RESTART
from nc_link.supply import CONTROL_ENABLE_ALL
from nc_link.supply import Supply as _Supply  # noqa: F401  (the supply of one axis: nc_link's)
from nc_schema import COMMAND_CLASS, PARAMETERS, ROLE_CLASSES, ErrorCodes, Keys, check_client_id
from nc_schema import (
    NCTOPLC_DTYPE, NCTOPLC_SIZE, PLCTONC_DTYPE, PLCTONC_SIZE, decode_ads, encode_ads, encode_plc_records,
    frame_records, member_struct, members,
)

from .device import AdsDevice, AdsSource, Symbol
from .errors import (
    ADSERR_DEVICE_ACCESSDENIED, ADSERR_DEVICE_INVALIDACCESS, ADSERR_DEVICE_INVALIDDATA, ADSERR_DEVICE_INVALIDGRP,
    ADSERR_DEVICE_INVALIDOFFSET, ADSERR_DEVICE_INVALIDSIZE, ADSERR_DEVICE_NOTREADY, ADSERR_DEVICE_SRVNOTSUPP,
    AdsError,
)

log = logging.getLogger(__name__)

#: ADS states (pyads constants): RUN while the NC is reachable, ERROR while not.
ADSSTATE_RUN = 5
ADSSTATE_ERROR = 11

#: Index groups (reference 5.4).
IG_R0_STATE = 0x1100
IG_AXIS_PARAM = 0x4000
IG_AXIS_STATE = 0x4100
IG_AXIS_FUNC = 0x4200
IG_AXIS_CYCLIC = 0x4300
#: Largest axis id with an ADS index group (the ID is the low byte of the group).
MAX_ADS_AXIS_ID = 255

#: 0x4300 IO of the NCTOPLC block (zenoh-nc's choice; by analogy with 0x2300, unconfirmed).
IO_NCTOPLC = 0x80
#: 0x4000 IO of the axis name (STRING(30) + NUL).
IO_AXIS_NAME = 0x02
AXIS_NAME_SIZE = 31

ONLINE_SIZE = 256

#: NCTOPLC_AXIS_REF field -> (offset, struct.Struct), from schema/structs.json (nc_schema.member_struct)
_N = {n: member_struct(NCTOPLC_DTYPE, n) for n in (
    "StateDWord", "ErrorCode", "CoupleState", "AxisId", "OpModeDWord", "ActPos", "ModuloActPos",
    "ActiveControlLoopIndex", "ModuloActTurns", "ActVelo", "PosDiff", "SetPos", "SetVelo", "SetAcc", "TargetPos",
    "ModuloSetPos", "ModuloSetTurns", "CmdNo", "CmdState", "SetJerk", "SetTorque", "ActTorque", "SetTorqueDerivative",
    "TorqueOffset", "ActAcc")}

#: NCAXISSTATE_ONLINESTRUCT, TC3 layout (reference 5.4.2, TwinSharp): ErrState, reserved, ActPos,
#: ModuloActPos, SetPos, ModuloSetPos, ActVelo, SetVelo, Override, reserved, lag, peak-hold neg/pos,
#: controller output %, total output %, StateDWord, control DWord, CoupleState, ControlLoopIndex,
#: ActAcc, SetAcc, SetJerk, SetTorque, ActTorque, SetTorqueChange, TorqueOffset; then zero fill to 256.
_ONLINE = struct.Struct("<iI6diI5d4I7d")
assert _ONLINE.size == 176

#: 0x4100+ID single fields: IO -> (NCTOPLC field or a derived name, ADS format).
STATE_FIELDS: dict[int, tuple[str, str]] = {
    0x01: ("ErrorCode", "<I"), 0x09: ("@Cycle", "<I"), 0x0A: ("SetPos", "<d"), 0x0B: ("ModuloSetPos", "<d"),
    0x0C: ("ModuloSetTurns", "<i"), 0x0D: ("@SetDirection", "<d"), 0x0E: ("SetVelo", "<d"), 0x0F: ("SetAcc", "<d"),
    0x10: ("SetJerk", "<d"), 0x11: ("SetTorque", "<d"), 0x13: ("TargetPos", "<d"), 0x15: ("CmdNo", "<i"),
    0x20: ("CoupleState", "<I"), 0x10002: ("ActPos", "<d"), 0x10003: ("ModuloActPos", "<d"),
    0x10004: ("ModuloActTurns", "<i"), 0x10005: ("ActVelo", "<d"), 0x10006: ("ActAcc", "<d"),
    0x2000D: ("PosDiff", "<d"), 0x2000F: ("PosDiff", "<d"),
}

def _plc(name: str) -> tuple[int, str]:
    """(offset, struct format) of PLCTONC member ``name``, from the contract's layout."""
    off, st = member_struct(PLCTONC_DTYPE, name)
    return off, st.format


#: 0x4300+ID single fields writing into PLCTONC: IO -> (PLCTONC offset, format).
CYCLIC_FIELDS: dict[int, tuple[int, str]] = {
    0x01: _plc("ControlDWord"), 0x21: _plc("Override"), 0x22: _plc("AxisModeRequest"),
    0x25: _plc("PositionCorrection"), 0x26: _plc("ExtControllerOutput")}
#: 0x4300+ID UINT16 0/1 flags: IO -> ControlDWord bit (Enable, FeedEnablePlus, FeedEnableMinus, HomingSensor).
CYCLIC_BITS: dict[int, int] = {0x02: 0, 0x03: 1, 0x04: 2, 0x07: 5}
#: 0x4300+ID IO 0x27: external set-point {REAL64 pos, velo, acc, INT32 dir}, 28 bytes (32 with padding).
IO_EXT_SETPOINT = 0x27
_CONTROL_DWORD = _plc("ControlDWord")[0]
_OVERRIDE = _plc("Override")[0]
#: PLCTONC's ExtSetPos .. ExtSetDirection: the 28 bytes IO 0x27 reads and writes
_EXT_SETPOINT = slice(_plc("ExtSetPos")[0], _plc("ExtSetDirection")[0] + 4)
assert _EXT_SETPOINT.stop - _EXT_SETPOINT.start == 28
#: the offsets of PLCTONC's REAL64 members (all must be finite)
_REAL64_OFFSETS = tuple(m.offset for m in members(PLCTONC_DTYPE) if m.fmt == "d")

OVERRIDE_100 = 1_000_000


def _default_plctonc() -> bytearray:
    """The PLCTONC the NC applies to an axis nobody holds: all enables off, override 100 %."""
    rec = bytearray(PLCTONC_SIZE)
    struct.pack_into("<I", rec, _OVERRIDE, OVERRIDE_100)
    return rec


def _field(rec: bytes, name: str) -> Any:
    off, st = _N[name]
    return st.unpack_from(rec, off)[0]


def online_struct(nctoplc: bytes, override: int = 0) -> bytes:
    """The 256-byte NCAXISSTATE_ONLINESTRUCT of one NCTOPLC_AXIS_REF record (``override`` in
    1/1000000: the PLCTONC's, which the NCTOPLC does not carry; 0 when not known)."""
    f = lambda n: _field(nctoplc, n)  # noqa: E731
    err = f("ErrorCode")
    body = _ONLINE.pack(err if err < 2**31 else err - 2**32, 0, f("ActPos"), f("ModuloActPos"), f("SetPos"),
                        f("ModuloSetPos"), f("ActVelo"), f("SetVelo"), min(int(override), 2**31 - 1), 0,
                        f("PosDiff"), 0.0, 0.0, 0.0, 0.0, f("StateDWord"), f("OpModeDWord"), f("CoupleState"),
                        f("ActiveControlLoopIndex"), f("ActAcc"), f("SetAcc"), f("SetJerk"), f("SetTorque"),
                        f("ActTorque"), f("SetTorqueDerivative"), f("TorqueOffset"))
    return body + bytes(ONLINE_SIZE - len(body))


@dataclass(frozen=True)
class Image:
    """The newest status frame: NC cycle and time, when it arrived (monotonic), the NCTOPLC record per AxisId, the
    NC's epoch (protocol 5; 0 without redundancy)."""

    cycle: int
    nc_time_ns: int
    received: float
    records: Mapping[int, bytes]
    epoch: int = 0


def parse_frame(data: bytes, received: float) -> Image:
    """An :class:`Image` of a status frame's bytes (FRAME_HEADER + NCTOPLC records [+ job records]), by
    ``nc_schema.frame_records`` (struct, no numpy: 500 frames a second).

    Raises:
        ValueError: not a zenoh-nc status frame.
    """
    h, recs = frame_records(data)
    return Image(h.Cycle, h.NcTimeNs, received, recs, h.Epoch)


class _Call:
    """One ADS function mapped onto an NC command: cmd name and its arguments."""

    __slots__ = ("cmd", "args")

    def __init__(self, cmd: str, **args: Any) -> None:
        self.cmd = cmd
        self.args = args


# ---- 0x4200 payloads ---------------------------------------------------------------------------------------------
def _unpack_variants(data: bytes, variants: Mapping[int, str]) -> tuple[Any, ...]:
    """Unpack ``data`` by the format registered for its length (the 12/16-byte disagreement of the reference).

    Raises:
        AdsError: 0x705 a length no variant has.
    """
    fmt = variants.get(len(data))
    if fmt is None:
        sizes = "/".join(str(n) for n in sorted(variants))
        raise AdsError(ADSERR_DEVICE_INVALIDSIZE, f"payload of {len(data)} bytes, expected {sizes}")
    return struct.unpack(fmt, data)


def _void(data: bytes) -> None:
    # TwinSharp writes a BOOL to the VOID functions; accept up to 4 bytes of anything
    if len(data) > 4:
        raise AdsError(ADSERR_DEVICE_INVALIDSIZE, f"this function takes no data (or a BOOL), got {len(data)} bytes")


def _finite(*values: float) -> None:
    if not all(math.isfinite(v) for v in values):
        raise AdsError(ADSERR_DEVICE_INVALIDDATA, "non-finite REAL64 in the payload")


#: ADS start types (_E_TcNC_StartPosType) -> (command, MC_Direction or None).
START_TYPES: dict[int, tuple[str, int | None]] = {
    1: ("MoveAbsolute", None), 2: ("MoveRelative", None), 3: ("MoveVelocity", 1), 4: ("MoveVelocity", 3),
    6: ("MoveAdditive", None), 0x105: ("MoveModulo", 2), 0x205: ("MoveModulo", 1), 0x305: ("MoveModulo", 3),
    0x405: ("MoveModulo", 4),
}


def _start(start_type: int, pos: float, velo: float, acc: float = 0.0, dec: float = 0.0, jerk: float = 0.0) -> _Call:
    _finite(pos, velo, acc, dec, jerk)
    m = START_TYPES.get(start_type)
    if m is None:
        raise AdsError(ErrorCodes.NC_START_TYPE_NOT_ALLOWED, f"start type {start_type} is not supported "
                       f"(supported: {', '.join(str(k) for k in START_TYPES)})")
    cmd, direction = m
    dyn = {"Acceleration": acc, "Deceleration": dec, "Jerk": jerk}
    if cmd in ("MoveAbsolute", "MoveModulo"):
        c = _Call(cmd, Position=pos, Velocity=velo, **dyn)
    elif cmd in ("MoveRelative", "MoveAdditive"):
        c = _Call(cmd, Distance=pos, Velocity=velo, **dyn)
    else:
        c = _Call(cmd, Velocity=velo, **dyn)
    if direction is not None:
        c.args["Direction"] = direction
    return c


def _fn_start(data: bytes) -> _Call:
    # UINT32 start type, [UINT32 reserved], REAL64 end position, REAL64 velocity
    v = _unpack_variants(data, {20: "<Idd", 24: "<I4xdd"})
    return _start(v[0], v[1], v[2])


def _fn_start_ext(data: bytes) -> _Call:
    # start type, 0, target, velocity, then {UINT32 useDefault, 0, REAL64 value} for acc, dec, jerk
    v = _unpack_variants(data, {56: "<IddIdIdId", 72: "<I4xddI4xdI4xdI4xd"})
    st, pos, velo, ua, a, ud, d, uj, j = v
    return _start(st, pos, velo, 0.0 if ua == 1 else a, 0.0 if ud == 1 else d, 0.0 if uj == 1 else j)


def _fn_new_end_pos(data: bytes) -> _Call:
    typ, pos = _unpack_variants(data, {12: "<Id", 16: "<I4xd"})
    _finite(pos)
    if typ != 1:
        raise AdsError(ErrorCodes.NC_START_TYPE_NOT_ALLOWED, f"end position type {typ}: only 1 (absolute) is supported")
    return _Call("NewPos", NewPos=pos)


def _fn_new_pos_velo(data: bytes) -> _Call:
    mode, typ, pos, velo, switch = _unpack_variants(data, {32: "<IIddd"})
    _finite(pos, velo, switch)
    if typ != 1:
        raise AdsError(ErrorCodes.NC_START_TYPE_NOT_ALLOWED, f"end position type {typ}: only 1 (absolute) is supported")
    return _Call("NewPosAndVelo", Mode=int(mode), NewPos=pos, NewVelo=velo, ActivationPos=switch)


def _fn_stop_ramp(data: bytes) -> _Call:
    dec, jerk = _unpack_variants(data, {16: "<dd"})
    _finite(dec, jerk)
    return _Call("Halt", Deceleration=dec, Jerk=jerk)


def _fn_oriented_stop(data: bytes) -> _Call:
    pos, dec, jerk = _unpack_variants(data, {24: "<ddd"})
    _finite(pos, dec, jerk)
    return _Call("OrientedStop", Position=pos, Deceleration=dec, Jerk=jerk)


def _fn_external_error(data: bytes) -> _Call:
    (code,) = _unpack_variants(data, {4: "<I"})
    if not 0 < code < 2**31:
        raise AdsError(ErrorCodes.MC_PARAMETER_NOT_CORRECT, f"error code {code:#x} out of range")
    return _Call("SetExternalError", ErrorCode=int(code))


def _fn_simple(cmd: str) -> Callable[[bytes], _Call]:
    def fn(data: bytes) -> _Call:
        _void(data)
        return _Call(cmd)
    return fn


#: 0x4200+ID IO -> (name, payload decoder). 0x1A (set actual position), 0x50/0x51 (disable/enable) are handled
#: by NcDevice itself (they need the frame or the claim machinery).
FUNCTIONS: dict[int, tuple[str, Callable[[bytes], _Call] | None]] = {
    0x01: ("reset", _fn_simple("Reset")),
    0x02: ("stop", _fn_simple("Halt")),
    0x04: ("emergency stop (dec, jerk)", _fn_stop_ramp),
    0x05: ("parametrized stop (dec, jerk)", _fn_stop_ramp),
    0x09: ("oriented stop (modulo pos, dec, jerk)", _fn_oriented_stop),
    0x10: ("home (calibrate)", _fn_simple("Home")),
    0x11: ("new end position", _fn_new_end_pos),
    0x12: ("new end position and velocity", _fn_new_pos_velo),
    0x19: ("set external error", _fn_external_error),
    0x1A: ("set actual position", None),
    0x20: ("start", _fn_start),
    0x21: ("extended start", _fn_start_ext),
    0x50: ("disable (enables off, release)", None),
    0x51: ("enable (Enable and feed enables on)", None),
}

#: The command class each function needs (for the local role check).
FUNCTION_CLASS: dict[int, str] = {io: "op" for io in FUNCTIONS} | {0x1A: "eng"}


class NcDevice(AdsDevice):
    """The NC ``nc`` at zenoh ``endpoint`` as an ADS device (see the module docstring).

    Args:
        nc: the NC name (its keys ``nc/<nc>/...``).
        endpoint: the zenoh endpoint of the NC (or its router), e.g. ``tcp/127.0.0.1:7447``.
        client_id: nc-ads's zenoh identity (with ``tls_dir`` its certificate ``<tls_dir>/<client_id>.pem``).
        role: observer (default), operator or engineer: which writes nc-ads lets through.
        tls_dir: certificate directory for mutual TLS (a ``tls/`` endpoint), or None.
        query_timeout: how long a command waits for the NC's reply [s] (then 0x719).
        stale_after: no status frame for this long [s]: the NC counts as unreachable (0x707).
        supply_period: period of the PLCTONC frames for held axes [s] (well inside the NC's watchdog).
        frame_period_ms: the status frames taken (``nc/<nc>/frame/<P>ms``); 0: every NC cycle's frame.
        lease_ms: the zenoh lease this session announces [ms].
        config: a zenoh config to use instead of the built one (tests).

    Raises:
        ValueError: invalid NC name, client id or role.
    """

    name = "zenoh-nc NC"
    version = (3, 1, 0)

    def __init__(self, nc: str, endpoint: str, client_id: str = "ads1", role: str = "observer",
                 tls_dir: str | None = None, query_timeout: float = 1.5, stale_after: float = 1.0,
                 supply_period: float = 0.01, frame_period_ms: int = 2, lease_ms: int = 500,
                 config: zenoh.Config | None = None) -> None:
        if role not in ROLE_CLASSES:
            raise ValueError(f"role must be one of {', '.join(ROLE_CLASSES)}, got {role!r}")
        self.keys = Keys(nc)
        self.nc = nc
        self.endpoint = endpoint
        self.client_id = check_client_id(client_id)
        self.role = role
        self.classes = ROLE_CLASSES[role]
        self.tls_dir = tls_dir
        self.query_timeout = float(query_timeout)
        self.stale_after = float(stale_after)
        self.supply_period = float(supply_period)
        self.frame_key = self.keys.frame_every(frame_period_ms) if frame_period_ms else self.keys.frame
        self.lease_ms = int(lease_ms)
        # an observer has no token and sends no PLCTONC (the ACL would deny both)
        self.link = NcLink(nc, endpoint, self.client_id, self.lease_ms, tls_dir, self.frame_key,
                           holder="op" in self.classes, claims=True, query_timeout=self.query_timeout, config=config)
        self._lock = threading.Lock()  # image, supplies, listeners
        self._claim_lock = threading.Lock()  # one claim/release sequence at a time
        self._publish_lock = threading.Lock()  # the PLC cycle counter of the supply frames
        self._image: Image | None = None
        #: the claim/supply machine (nc_link), under the same lock as the image
        self.supplies = Supplies(self._lock)
        self._listeners: list[Callable[[], None]] = []
        self._names: dict[int, str] = {}
        self._applied: dict[int, Any] = {}  # AxisId -> RingChannel subscriber of nc/<nc>/axis/<id>/plctonc
        self._applied_latest: dict[int, bytes] = {}  # AxisId -> the newest applied PLCTONC seen there
        self._warned_ids: set[int] = set()
        self._claims_map: tuple[int, dict[int, str]] | None = None
        self._plc_cycle = 0
        self._closed = threading.Event()
        self._closing = False
        self._threads: list[threading.Thread] = []
        self.frames_seen = 0
        self.bad_frames = 0

    @property
    def restarts(self) -> int:
        """NC restarts seen (new NC instances: instance tokens and frames; the link's rule)."""
        return self.link.restarts

    @property
    def stale_epoch_frames(self) -> int:
        """Frames dropped for a lower epoch than the one followed (the link's rule, ``NcLink.follow_frame``)."""
        return int(self.link.stats()["stale_epoch_frames"] or 0)

    # the link's declarations and the supplies, by their former names (tests feed channels through them)
    @property
    def _session(self) -> zenoh.Session | None:
        return self.link.session

    @property
    def _alive(self) -> Any:
        return self.link.alive_sub

    @_alive.setter
    def _alive(self, sub: Any) -> None:
        self.link.alive_sub = sub

    @property
    def _instance_sub(self) -> Any:
        return self.link.instance_sub

    @_instance_sub.setter
    def _instance_sub(self, sub: Any) -> None:
        self.link.instance_sub = sub

    @property
    def _claims_sub(self) -> Any:
        return self.link.claims_sub

    @_claims_sub.setter
    def _claims_sub(self, sub: Any) -> None:
        self.link.claims_sub = sub

    @property
    def _supplies(self) -> dict[int, _Supply]:
        return self.supplies.axes

    # ---- lifecycle --------------------------------------------------------------------------------------------
    def start(self) -> None:
        """Connect (in the background: an unreachable NC is retried every 0.5 s) and start the threads."""
        t = threading.Thread(target=self._connect_loop, name=f"nc-ads-{self.nc}-connect", daemon=True)
        t.start()
        self._threads.append(t)

    def _connect_loop(self) -> None:
        while not self._closed.is_set():
            if not self.link.open():  # nobody listens there (yet), or a declaration failed
                log.warning("NC %s at %s not reachable (%s); retrying", self.nc, self.endpoint, self.link.last_error)
                self._closed.wait(0.5)
                continue
            log.info("connected to NC %s at %s as %s (%s)", self.nc, self.endpoint, self.client_id, self.role)
            break
        if self._closed.is_set():
            return
        for target, name in ((self._frame_loop, "frames"), (self._supply_loop, "supply")):
            t = threading.Thread(target=target, name=f"nc-ads-{self.nc}-{name}", daemon=True)
            t.start()
            self._threads.append(t)

    def close(self) -> None:
        """Stop supplying, close the session (ends the threads). Idempotent."""
        if self._closed.is_set() or self._closing:
            return
        self._closing = True  # no new claims; a connection closing now is part of the shutdown, not a loss
        self._shutdown_supplies()
        self._closed.set()
        self.link.close(undeclare=False)  # ends the frame thread's recv (never undeclare under a blocked recv)
        for t in self._threads:
            if t is not threading.current_thread():
                t.join(3)

    def _shutdown_supplies(self) -> None:
        """As plc-run's shutdown: PLCTONC with all enables off for a few supply periods, then Release
        (skipped while the NC is unreachable: its own client-loss rules take over when the session ends)."""
        axes = self.supplies.disable_all()
        if not axes:
            return
        try:
            self.fresh_image()
        except AdsError:
            return
        for _ in range(3):
            try:
                self._publish_supply()
            except Exception:
                break
            time.sleep(self.supply_period)
        for a in axes:
            self._release(a, None)

    # ---- the cyclic image -------------------------------------------------------------------------------------
    def _frame_loop(self) -> None:
        frames = self.link.frames
        while not self._closed.is_set():
            try:
                sample = frames.recv()  # releases the GIL; ends when the session closes
            except Exception:
                return
            now = time.monotonic()
            try:
                img = parse_frame(sample.payload.to_bytes(), now)
            except ValueError as exc:
                self.bad_frames += 1
                if self.bad_frames == 1:
                    log.error("undecodable status frame ignored (%s)", exc)
                continue
            taken, why = self.link.follow_frame(img.cycle, img.epoch)
            if not taken:  # a frame of a lower epoch (a hot-standby pair's old active NC): counted by the link
                continue
            with self._lock:
                old = self._image
                self._image = img
                listeners = list(self._listeners)
            self.frames_seen += 1
            if why is not None:
                self._nc_restarted(why)
            if old is None or old.records.keys() != img.records.keys():
                self._check_ids(img)
            for cb in listeners:
                try:
                    cb()
                except Exception:
                    log.exception("change listener failed")

    def _check_ids(self, img: Image) -> None:
        for a in sorted(img.records):
            if a > MAX_ADS_AXIS_ID and a not in self._warned_ids:
                self._warned_ids.add(a)
                log.warning("axis %d has no ADS index group (ids above %d cannot be addressed); left out of 0x1100",
                            a, MAX_ADS_AXIS_ID)

    def _nc_restarted(self, why: str) -> None:
        dropped = self.supplies.end_all()
        with self._lock:
            self._names.clear()
        log.warning("NC %s restarted (%s)%s", self.nc, why,
                    f": PLCTONC supply of axes {dropped} ended (write PLCTONC again to claim)" if dropped else "")

    def fresh_image(self) -> Image:
        """The newest frame if it is fresh.

        Raises:
            AdsError: 0x707 no frame for ``stale_after`` seconds (or none yet).
        """
        img = self._image
        if img is None:
            raise AdsError(ADSERR_DEVICE_NOTREADY, f"no status frame from NC {self.nc} yet")
        if time.monotonic() - img.received > self.stale_after:
            raise AdsError(ADSERR_DEVICE_NOTREADY, f"NC {self.nc} unreachable: no status frame for "
                           f"{time.monotonic() - img.received:.1f} s")
        return img

    def add_change_listener(self, cb: Callable[[], None]) -> None:
        with self._lock:
            self._listeners.append(cb)

    def read_state(self) -> tuple[int, int]:
        try:
            self.fresh_image()
        except AdsError:
            return ADSSTATE_ERROR, 0
        return ADSSTATE_RUN, 0

    # ---- PLCTONC supply ---------------------------------------------------------------------------------------
    def _supply_loop(self) -> None:
        """Every supply_period: liveliness and claims events, then one PLCTONC frame with every held axis."""
        nxt = time.monotonic()
        while not self._closed.is_set():
            try:
                self._take_events()
                self._publish_supply()
            except Exception:
                if self._closed.is_set():
                    return
                log.exception("supply cycle failed")
            nxt += self.supply_period
            delay = nxt - time.monotonic()
            if delay < -self.supply_period:
                nxt = time.monotonic()  # late: skip, never replay
                delay = 0.0
            self._closed.wait(max(0.0, delay))

    def _take_events(self) -> None:
        for ev in self.link.take_events():
            if ev.kind == GONE:  # not a restart (see the module doc); stale frames then: 0x707
                log.warning("NC %s unreachable (its liveliness token disappeared)", self.nc)
            elif ev.kind == RESTART:  # another instance id; the same one back is none
                self._nc_restarted(ev.why)
        m = self.link.take_claims()
        if m is None:
            return
        self._claims_map = cycle, claims = m
        for a in self.supplies.end_lost(cycle, claims, self.client_id):
            log.warning("axis %d: the NC no longer counts nc-ads as its holder (lost by the NC's rules); supply ended", a)

    def _publish_supply(self) -> None:
        if not self.supplies or self.link.pub is None:
            return
        with self._publish_lock:  # one PLC cycle number per frame (the supply thread and ADS writes publish)
            items, release = self.supplies.due()
            if not items:
                return
            self._plc_cycle += 1
            frame = encode_plc_records(self._plc_cycle, items)
        self.link.publish(frame)
        for a in release:
            threading.Thread(target=self._release, args=(a, None), daemon=True).start()

    def _release(self, axis: int, conn_id: int | None) -> None:
        """Release ``axis`` (if still supplied by ``conn_id``; None: any)."""
        with self._claim_lock:
            if self.supplies.take(axis, conn_id) is None:
                return
            try:
                self._command("Release", axis)
                log.info("axis %d released", axis)
            except AdsError as exc:
                log.warning("axis %d: Release failed: %s", axis, exc)

    def _supply(self, axis: int, src: AdsSource, change: Callable[[bytearray], None]) -> None:
        """Claim ``axis`` if needed, apply ``change`` to its PLCTONC and supply it for ``src``'s connection.

        Raises:
            AdsError: 0x723 the role cannot (or the NC refused the claim: another holder), 0x707/0x719 no NC.
        """
        self._allow("op", src)
        self.fresh_image()
        if self._closing:
            raise AdsError(ADSERR_DEVICE_NOTREADY, "nc-ads is shutting down")
        with self._claim_lock:
            prev = self.supplies.change(axis, change, src.conn_id)
            if prev is None:
                rec = _default_plctonc()
                change(rec)
                reply = self._command("Claim", axis)  # raises with the NC's 0x723 naming the holder
                self.supplies.start(axis, rec, src.conn_id, int(reply.get("cycle", 0)))
                log.info("axis %d claimed for ADS connection %d (%s)", axis, src.conn_id, src.peer)
            elif prev != src.conn_id:
                log.info("axis %d: PLCTONC now supplied by ADS connection %d (was %d)", axis, src.conn_id, prev)
        self._publish_supply()  # at once: the write takes effect in the NC's next cycle

    def connection_closed(self, conn_id: int) -> None:
        """The TCP connection ended: each axis it supplied stops as for a lost client (see the module doc)."""
        if self._closing:
            return  # nc-ads is stopping: close() released everything in order
        mine = self.supplies.owned_by(conn_id)
        for axis, enabled in mine:
            if enabled:
                try:
                    self._command("SetExternalError", axis, ErrorCode=ErrorCodes.ZNC_CLIENT_LOST)
                    log.warning("axis %d: its ADS connection %d closed: error 0x%04X, stop, release", axis, conn_id,
                                ErrorCodes.ZNC_CLIENT_LOST)
                except AdsError as exc:
                    log.warning("axis %d: SetExternalError after connection %d closed failed: %s", axis, conn_id, exc)
            self._release(axis, conn_id)

    # ---- commands ---------------------------------------------------------------------------------------------
    def _allow(self, cls: str, src: AdsSource) -> None:
        if not src.may_write:
            raise AdsError(ADSERR_DEVICE_ACCESSDENIED, f"write policy: {src.net_id} ({src.peer.rsplit(':', 1)[0]}) is not in "
                                                       "nc-ads --allow-write")
        if cls not in self.classes:
            need = " or ".join(r for r, c in ROLE_CLASSES.items() if cls in c)
            raise AdsError(ADSERR_DEVICE_ACCESSDENIED, f"role: nc-ads runs as {self.role}; this write is of class "
                                                       f"{cls!r}, which needs {need} (--role)")

    def _command(self, cmd: str, axis: int | None, **args: Any) -> dict[str, Any]:
        """Send ``cmd`` and wait for the reply (``NcLink.request``); NC error codes raise AdsError with that code.

        Raises:
            AdsError: the NC's code; 0x707 no session or zenoh ended the query without a reply early;
                0x706 a malformed reply; 0x719 no reply within query_timeout.
        """
        try:
            return self.link.request(cmd, axis, **args)
        except CommandError as exc:
            raise AdsError(exc.code, exc.message) from None

    # ---- addressing -------------------------------------------------------------------------------------------
    def _axis(self, group: int) -> tuple[int, int]:
        """(kind, axis id) of an axis group 0x4000..0x43FF whose axis exists.

        Raises:
            AdsError: 0x702 another group or an axis the NC does not have; 0x707 no fresh frame (also for
                commands: a frozen NC would otherwise hold a worker for every query's full timeout).
        """
        kind, axis = group & 0xFF00, group & 0xFF
        if kind not in (IG_AXIS_PARAM, IG_AXIS_STATE, IG_AXIS_FUNC, IG_AXIS_CYCLIC) or group > 0x43FF or axis == 0:
            raise AdsError(ADSERR_DEVICE_INVALIDGRP, f"index group {group:#x} is not served")
        if axis not in self.fresh_image().records:
            raise AdsError(ADSERR_DEVICE_INVALIDGRP, f"index group {group:#x}: NC {self.nc} has no axis {axis}")
        return kind, axis

    def nonblocking(self, group: int, offset: int, write: bool = False) -> bool:
        """Reads answered from the newest frame (0x1100, 0x4100+ID, 0x4300+ID once the axis's applied PLCTONC is
        known) never block: the server runs them on its loop. Writes, parameters and functions send commands."""
        if write:
            return False
        if group == IG_R0_STATE:
            return True
        kind, axis = group & 0xFF00, group & 0xFF
        if group > 0x43FF:
            return False
        if kind == IG_AXIS_STATE:
            return True
        if kind == IG_AXIS_CYCLIC:  # the first read of an axis's applied PLCTONC may wait for its first sample
            return offset == IO_NCTOPLC or axis in self._applied_latest or axis in self._supplies
        return False

    def _axis_ids(self, img: Image) -> list[int]:
        return sorted(a for a in img.records if 0 < a <= MAX_ADS_AXIS_ID)

    # ---- read -------------------------------------------------------------------------------------------------
    def read(self, group: int, offset: int, length: int, src: AdsSource) -> bytes:
        if group == IG_R0_STATE:
            return self._read_r0(offset, length)
        kind, axis = self._axis(group)
        if kind == IG_AXIS_PARAM:
            return self._read_param(axis, offset, length)
        if kind == IG_AXIS_FUNC:
            raise AdsError(ADSERR_DEVICE_INVALIDACCESS, "axis functions (0x4200+ID) are written, not read")
        return self._cyclic(kind, axis, offset, length, blocking=True)

    def sample(self, group: int, offset: int, length: int) -> bytes:
        if group == IG_R0_STATE:
            return self._read_r0(offset, length)
        kind, axis = self._axis(group)
        if kind in (IG_AXIS_PARAM, IG_AXIS_FUNC):
            raise AdsError(ADSERR_DEVICE_SRVNOTSUPP, f"index group {group:#x} cannot be notified (state 0x4100+ID "
                                                      "and cyclic data 0x4300+ID can)")
        return self._cyclic(kind, axis, offset, length, blocking=False)

    def _read_r0(self, offset: int, length: int) -> bytes:
        ids = self._axis_ids(self.fresh_image())
        if offset in (0x03, 0x04, 0x05, 0x06):  # axis / encoder / controller / drive count
            data = struct.pack("<I", len(ids))
        elif offset in (0x01, 0x02, 0x0A):  # channels, groups, tables: none
            data = struct.pack("<I", 0)
        elif offset in (0x33, 0x34, 0x35, 0x36):  # their ids: one encoder/controller/drive per axis, same id
            data = struct.pack(f"<{len(ids)}I", *ids)
            return data[:length]  # a tool may read fewer ids than there are
        else:
            raise AdsError(ADSERR_DEVICE_INVALIDOFFSET, f"0x1100 offset {offset:#x} is not served (0x03 axis count, "
                                                         "0x33 axis ids)")
        _size(length, len(data))
        return data

    def _read_param(self, axis: int, offset: int, length: int) -> bytes:
        if offset == IO_AXIS_NAME:
            name = self._axis_name(axis).encode("latin-1", "replace")[:AXIS_NAME_SIZE - 1]
            return (name + bytes(AXIS_NAME_SIZE - len(name)))[:length]
        e = PARAMETERS.ads_axis_offset(offset)
        if e is None:
            raise AdsError(ADSERR_DEVICE_INVALIDOFFSET, f"axis parameter offset {offset:#x} is not in the parameter table")
        assert e.ads is not None
        _size(length, e.ads.size, e.name)
        reply = self._command("ReadParameter", axis, ParameterNumber=e.number)
        try:
            return encode_ads(e, reply.get("Value"))
        except (ValueError, TypeError) as exc:
            raise AdsError(ADSERR_DEVICE_INVALIDDATA, f"{e.name}: {exc}") from None

    def _axis_name(self, axis: int) -> str:
        if axis not in self._names:
            value = self._command("Info", None).get("Value") or {}
            names = {int(a["AxisId"]): str(a.get("Name", "")) for a in value.get("axes", [])}
            with self._lock:
                self._names = names
        return self._names.get(axis, "")

    def _cyclic(self, kind: int, axis: int, offset: int, length: int, blocking: bool) -> bytes:
        img = self.fresh_image()
        rec = img.records[axis]
        if kind == IG_AXIS_STATE:
            if offset == 0:
                if length > ONLINE_SIZE:
                    raise AdsError(ADSERR_DEVICE_INVALIDSIZE, f"the online structure is {ONLINE_SIZE} bytes")
                return online_struct(rec, self._override(axis))[:length]  # a TC2 tool reads a prefix
            f = STATE_FIELDS.get(offset)
            if f is None:
                raise AdsError(ADSERR_DEVICE_INVALIDOFFSET, f"axis state offset {offset:#x} is not served")
            name, fmt = f
            _size(length, struct.calcsize(fmt), name)
            if name == "@Cycle":
                return struct.pack(fmt, img.cycle & 0xFFFFFFFF)
            if name == "@SetDirection":
                v = _field(rec, "SetVelo")
                return struct.pack(fmt, 1.0 if v > 0 else -1.0 if v < 0 else 0.0)
            return struct.pack(fmt, _field(rec, name))
        # IG_AXIS_CYCLIC
        if offset == IO_NCTOPLC:
            if length > NCTOPLC_SIZE:
                raise AdsError(ADSERR_DEVICE_INVALIDSIZE, f"NCTOPLC_AXIS_REF is {NCTOPLC_SIZE} bytes")
            return bytes(rec[:length])
        plc = self._plctonc(axis, blocking)
        if offset == 0:
            if length > PLCTONC_SIZE:
                raise AdsError(ADSERR_DEVICE_INVALIDSIZE, f"PLCTONC_AXIS_REF is {PLCTONC_SIZE} bytes")
            return bytes(plc[:length])
        if offset in CYCLIC_FIELDS:
            off, fmt = CYCLIC_FIELDS[offset]
            _size(length, struct.calcsize(fmt))
            return bytes(plc[off:off + struct.calcsize(fmt)])
        if offset in CYCLIC_BITS:
            _size(length, 2)
            return struct.pack("<H", (struct.unpack_from("<I", plc, _CONTROL_DWORD)[0] >> CYCLIC_BITS[offset]) & 1)
        if offset == IO_EXT_SETPOINT:
            if length not in (28, 32):
                raise AdsError(ADSERR_DEVICE_INVALIDSIZE, "the external set-point is 28 bytes (32 padded)")
            return (bytes(plc[_EXT_SETPOINT]) + bytes(4))[:length]
        raise AdsError(ADSERR_DEVICE_INVALIDOFFSET, f"cyclic data offset {offset:#x} is not served")

    def _plctonc(self, axis: int, blocking: bool) -> bytes:
        """The PLCTONC applied to ``axis``: what nc-ads supplies, else the NC's ``axis/<id>/plctonc`` (subscribed
        on first use; ``blocking`` waits up to 0.5 s for its first sample), else the default."""
        rec = self.supplies.record(axis)
        if rec is not None:
            return rec
        with self._lock:
            sub = self._applied.get(axis)
        s = self._session
        if sub is None and s is not None:
            sub = s.declare_subscriber(self.keys.axis_plctonc(axis), RingChannel(1))
            with self._lock:
                self._applied[axis] = sub
        latest = self._applied_latest
        deadline = time.monotonic() + (0.5 if blocking else 0.0)
        while sub is not None:
            smp = sub.try_recv()
            if smp is not None:
                latest[axis] = smp.payload.to_bytes()[:PLCTONC_SIZE]
                continue
            if axis in latest or time.monotonic() >= deadline:
                break
            time.sleep(0.005)
        return latest.get(axis) or bytes(_default_plctonc())

    def _override(self, axis: int) -> int:
        supplied = self.supplies.override(axis)
        if supplied is not None:
            return supplied
        rec = self._applied_latest.get(axis)
        return struct.unpack_from("<I", rec, _OVERRIDE)[0] if rec else 0

    # ---- write ------------------------------------------------------------------------------------------------
    def write(self, group: int, offset: int, data: bytes, src: AdsSource) -> None:
        if group == IG_R0_STATE:
            raise AdsError(ADSERR_DEVICE_INVALIDACCESS, "the Ring-0 state (0x1100) is read-only")
        kind, axis = self._axis(group)
        if kind == IG_AXIS_PARAM:
            self._write_param(axis, offset, data, src)
        elif kind == IG_AXIS_STATE:
            raise AdsError(ADSERR_DEVICE_INVALIDACCESS, "the axis state (0x4100+ID) is read-only")
        elif kind == IG_AXIS_FUNC:
            self._function(axis, offset, data, src)
        else:
            self._write_cyclic(axis, offset, data, src)

    def read_write(self, group: int, offset: int, length: int, data: bytes, src: AdsSource) -> bytes:
        """0x4200+ID: the function, answered with CmdNo, CmdState (2 x UINT, as Tc2_MC2's start response);
        other groups: a read when no data is written, else 0x701."""
        if group & 0xFF00 == IG_AXIS_FUNC and group <= 0x42FF:
            reply = self._function(self._axis(group)[1], offset, data, src)
            cmd_no = int(reply.get("CmdNo", 0))
            return struct.pack("<HH", cmd_no & 0xFFFF, 0)[:length]
        if not data:
            return self.read(group, offset, length, src)
        raise AdsError(ADSERR_DEVICE_SRVNOTSUPP, "ReadWrite with data is only served for axis functions (0x4200+ID)")

    def _write_param(self, axis: int, offset: int, data: bytes, src: AdsSource) -> None:
        if offset == IO_AXIS_NAME:
            raise AdsError(ADSERR_DEVICE_INVALIDACCESS, "the axis name is read-only")
        e = PARAMETERS.ads_axis_offset(offset)
        if e is None:
            raise AdsError(ADSERR_DEVICE_INVALIDOFFSET, f"axis parameter offset {offset:#x} is not in the parameter table")
        if not e.writable:
            raise AdsError(ADSERR_DEVICE_INVALIDACCESS, f"{e.name} is read-only")
        assert e.ads is not None
        _size(len(data), e.ads.size, e.name)
        value = decode_ads(e, data)
        if not e.is_bool and not math.isfinite(value):
            raise AdsError(ADSERR_DEVICE_INVALIDDATA, f"{e.name}: {value} is not finite")
        if e.ads.type == "UINT16" and data not in (b"\0\0", b"\1\0"):
            raise AdsError(ADSERR_DEVICE_INVALIDDATA, f"{e.name}: a UINT16 flag is 0 or 1")
        self._allow(COMMAND_CLASS["WriteParameter"], src)
        self._command("WriteParameter", axis, ParameterNumber=e.number, Value=value)

    def _function(self, axis: int, offset: int, data: bytes, src: AdsSource) -> dict[str, Any]:
        entry = FUNCTIONS.get(offset)
        if entry is None:
            raise AdsError(ADSERR_DEVICE_INVALIDOFFSET, f"axis function {offset:#x} is not served "
                           f"(served: {', '.join(f'{k:#x}' for k in FUNCTIONS)})")
        _, decode = entry
        if offset in (0x50, 0x51):
            _void(data)
            if offset == 0x51:
                self._supply(axis, src, _set_control(CONTROL_ENABLE_ALL, CONTROL_ENABLE_ALL))
            else:
                self._disable(axis, src)
            return {}
        if offset == 0x1A:
            call = self._set_actual_position(axis, data)
        else:
            assert decode is not None
            call = decode(data)
        self._allow(COMMAND_CLASS[call.cmd], src)
        return self._command(call.cmd, axis, **call.args)

    def _set_actual_position(self, axis: int, data: bytes) -> _Call:
        typ, pos = _unpack_variants(data, {12: "<Id", 16: "<I4xd"})
        _finite(pos)
        if typ == 1:
            return _Call("SetActualPosition", Position=pos)
        if typ == 2:
            return _Call("SetActualPosition", Position=_field(self.fresh_image().records[axis], "ActPos") + pos)
        raise AdsError(ErrorCodes.NC_START_TYPE_NOT_ALLOWED, f"actual position type {typ}: 1 absolute or 2 relative")

    def _disable(self, axis: int, src: AdsSource) -> None:
        """Enables off (Enable, feed enables) for a few supply periods, then Release."""
        self._allow("op", src)
        self.supplies.disable(axis, src.conn_id, periods=3)  # False: nc-ads does not hold it, nothing to disable

    def _write_cyclic(self, axis: int, offset: int, data: bytes, src: AdsSource) -> None:
        change: Callable[[bytearray], None]  # what the write does to the axis's PLCTONC record
        if offset == IO_NCTOPLC:
            raise AdsError(ADSERR_DEVICE_INVALIDACCESS, "NCTOPLC_AXIS_REF (0x4300+ID IO 0x80) is read-only")
        if offset == 0:
            _size(len(data), PLCTONC_SIZE, "PLCTONC_AXIS_REF")
            _check_plctonc(data)

            def change(rec: bytearray) -> None:
                rec[:] = data
        elif offset in CYCLIC_FIELDS:
            off, fmt = CYCLIC_FIELDS[offset]
            _size(len(data), struct.calcsize(fmt))
            (v,) = struct.unpack(fmt, data)
            if offset == 0x21 and v > OVERRIDE_100:
                raise AdsError(ADSERR_DEVICE_INVALIDDATA, f"override {v} above 1000000 (100 %)")
            if fmt == "<d" and not math.isfinite(v):
                raise AdsError(ADSERR_DEVICE_INVALIDDATA, "non-finite REAL64")

            def change(rec: bytearray) -> None:
                rec[off:off + len(data)] = data
        elif offset in CYCLIC_BITS:
            _size(len(data), 2)
            (v,) = struct.unpack("<H", data)
            if v not in (0, 1):
                raise AdsError(ADSERR_DEVICE_INVALIDDATA, "an enable flag is 0 or 1")
            bit = 1 << CYCLIC_BITS[offset]
            change = _set_control(bit, bit if v else 0)
        elif offset == IO_EXT_SETPOINT:
            if len(data) not in (28, 32):
                raise AdsError(ADSERR_DEVICE_INVALIDSIZE, "the external set-point is 28 bytes (32 padded)")
            pos, velo, acc, direction = struct.unpack_from("<dddi", data)
            _finite(pos, velo, acc)

            def change(rec: bytearray) -> None:
                rec[_EXT_SETPOINT] = data[:28]
        else:
            raise AdsError(ADSERR_DEVICE_INVALIDOFFSET, f"cyclic data offset {offset:#x} is not served")
        self._supply(axis, src, change)

    # ---- symbols ----------------------------------------------------------------------------------------------
    def symbols(self) -> Mapping[str, Symbol]:
        """``Axis<id>.NcToPlc`` / ``.PlcToNc`` / ``.State`` and a few LREALs of every axis with an index group."""
        img = self._image
        out: dict[str, Symbol] = {}
        for a in self._axis_ids(img) if img is not None else []:
            out[f"Axis{a}.NcToPlc"] = Symbol(IG_AXIS_CYCLIC + a, IO_NCTOPLC, NCTOPLC_SIZE, "NCTOPLC_AXIS_REF")
            out[f"Axis{a}.PlcToNc"] = Symbol(IG_AXIS_CYCLIC + a, 0, PLCTONC_SIZE, "PLCTONC_AXIS_REF")
            out[f"Axis{a}.State"] = Symbol(IG_AXIS_STATE + a, 0, ONLINE_SIZE, "NCAXISSTATE_ONLINESTRUCT")
            for name, io in (("ActPos", 0x10002), ("SetPos", 0x0A), ("ActVelo", 0x10005), ("SetVelo", 0x0E)):
                out[f"Axis{a}.NcToPlc.{name}"] = Symbol(IG_AXIS_STATE + a, io, 8, "LREAL")
        return out


def _size(got: int, want: int, what: str = "") -> None:
    if got != want:
        raise AdsError(ADSERR_DEVICE_INVALIDSIZE, f"{what + ': ' if what else ''}{want} bytes, got {got}")


def _set_control(mask: int, bits: int) -> Callable[[bytearray], None]:
    def change(rec: bytearray) -> None:
        cw = struct.unpack_from("<I", rec, _CONTROL_DWORD)[0]
        struct.pack_into("<I", rec, _CONTROL_DWORD, (cw & ~mask) | (bits & mask))
    return change


def _check_plctonc(data: bytes) -> None:
    """A whole PLCTONC as the NC would take it: override <= 100 %, finite REAL64s.

    Raises:
        AdsError: 0x706.
    """
    override = struct.unpack_from("<I", data, _OVERRIDE)[0]
    if override > OVERRIDE_100:
        raise AdsError(ADSERR_DEVICE_INVALIDDATA, f"PLCTONC.Override {override} above 1000000 (100 %)")
    for off in _REAL64_OFFSETS:
        if not math.isfinite(struct.unpack_from("<d", data, off)[0]):
            raise AdsError(ADSERR_DEVICE_INVALIDDATA, f"PLCTONC: non-finite REAL64 at offset {off}")


__all__ = ["NcDevice", "Image", "parse_frame", "online_struct", "FUNCTIONS", "STATE_FIELDS", "START_TYPES",
           "CYCLIC_FIELDS", "CYCLIC_BITS"]
