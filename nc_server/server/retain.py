"""The retain file: what an NC keeps across a restart (opt-in: ``[nc] retain_file`` / ``--retain``).

Kept per axis (every entry carries the axis's ``Name``):

* the actual position, the homed flag (StateDWord.Homed), a standstill flag and the modulo setting
  of every axis whose TwinCAT parameter ``AxisEnDataPersistence`` is TRUE ("persistent" axes);
* the parameters written at run time (MC_WriteParameter): every stored parameter whose value differs
  from the configuration's, together with that configured value. The configuration stays the base:
  a parameter written back to its configured value is not kept.

File format (version :data:`FORMAT_VERSION`)::

    offset  size  field
    0       8     magic b"ZNCRTN\\r\\n"   (the CR LF catches text-mode mangling)
    8       2     format version, uint16 little-endian
    10      4     body length, uint32 little-endian (at most max_body(configured axes))
    14      32    sha256 of the body
    46      n     body: msgpack map (maps, strings, numbers and booleans only: no arrays, no bin)
                  {"nc": str, "saved_ns": int,
                   "axes": {AxisId: {"name": str,
                                     # persistent axes (all four or none):
                                     "position": float, "homed": bool, "standstill": bool,
                                     "modulo": float,         # AxisEncoderModuloValue, 0.0: not Modulo
                                     "params": {name: {"value": float | bool,
                                                       "configured": float | bool}}}}}

The magic and the version stay where they are in every future version; a reader refuses a version
it does not know before it looks at anything else (version 1, the first weeks' format without names,
standstill flags and configured values, is refused that way).

Writing. The cycle thread never touches the disk. Every :data:`SNAPSHOT_PERIOD`, and within
:data:`STANDSTILL_CHECK_PERIOD` when an axis starts or stops standing, it copies the actual
positions, the homed and standstill flags and the references of the (immutable) parameter objects
(:meth:`RetainKeeper.tick`, microseconds) and hands them to the retain thread, which builds a
:class:`RetainData` and writes the file (:func:`write_atomic`) when its content changed: at once for
a change of a homed or standstill flag, of a parameter or of a standing axis's position (by more
than :data:`STANDSTILL_TOLERANCE` x its AxisTargetPositionWindow: smaller ones wait for another
change); while axes move (only their positions changed) at most every :data:`MOVING_WRITE_PERIOD`
(flash wear); once more at shutdown, after the cycle ended, with whatever changed.

Acknowledged means kept. A request of :data:`DURABLE_COMMANDS` answered with no error (WriteParameter,
also MC_WriteBoolParameter's; SetActualPosition(OnTheFly), SetReferenceFlag on a persistent axis only:
:meth:`RetainKeeper.keeps`; on another axis they change nothing in the file and reply at once) is in the
file, written and fsync'ed, before its reply goes out: the cycle thread calls :meth:`RetainKeeper.commit` after the
requests of one idle slice ran (a snapshot, microseconds, no I/O) and hands their replies to the I/O
thread tagged with the commit's number; the retain thread writes every snapshot whose commit number
is above :attr:`RetainKeeper.durable` at once (whatever kind of change) and then raises ``durable``
(and ``settled``) and calls ``on_settled`` (the I/O thread's wake-up), which sends the held replies.
Group commit: every snapshot carries the newest commit number taken before it, so commits made while
a write runs share the next write and its fsyncs. A write that fails settles its commits without
making them durable: their replies become 0x4002 errors (the value is applied, it is not kept); so does
every such reply while the NC does not write its file this run (``writing_disabled``): a reply must not
claim a durability it lacks. A reply waits at most ``transport.HOLD_MAX`` (0.8 s, below the clients' 1 s
command timeout), then goes out as 0x4002 too (not confirmed kept: a slow fsync may still put it in the
file); only that reply waits, never another one of the same client, never the cycle. A position the
reader would not restore (not finite, ``|pos| >= 1e9``) is left out with its homed flag (logged once
per axis), and every file is parsed before it is written: the file never holds what its reader refuses.

An axis "stands" when it has no job, ``|SetVelo| <= 1e-9`` and ``|ActVelo| <=``
:data:`STANDSTILL_VELOCITY`. A position taken while the axis moved is restored, but the axis is not
referenced (Homed FALSE): after a SIGKILL or a power cut mid-move the file lags the axis.

Loading, in two steps. :meth:`RetainKeeper.load` (before the cycle starts) takes an exclusive lock
on ``<file>.lock`` for the life of the process (a second NC on the same file fails to start:
:class:`RetainLockError`), reads and checks the file. :meth:`RetainKeeper.apply` (the cycle thread,
right after the first ``core.step()``, when the drive has been read once, before any command or
PLCTONC and before the first snapshot) applies it through the commands a client would use:
parameters through WriteParameter, positions through SetActualPosition, homed flags through
SetReferenceFlag.

Refusals. A file that cannot be used (corrupt, another NC's, an unknown format version) or cannot
be read (an OSError such as EIO or EACCES) is refused with one error line (0x4002, TwinCAT's "NC
retain data error"), renamed to ``<file>.rejected`` (``.rejected.1``, ... : never overwritten) and
the NC starts with its configuration; the next write creates a fresh file. If it cannot even be
renamed, the NC does not write the retain file during this run (it would overwrite what may still
be rescued) and says so.

In a hot-standby pair (``[redundancy] enabled``, docs/standby.md), only the active NC keeps its file:
:meth:`RetainKeeper.follow` makes the keeper one that holds no lock and writes nothing until
:meth:`RetainKeeper.resume` (a takeover in step, or a retake: the retain thread takes the lock, at once, and
writes the current state with the next snapshot; the file is not applied, the NC's state is newer) and
again nothing after :meth:`RetainKeeper.suspend` (a demotion: the retain thread finishes a write in progress,
then releases the lock; the file stays the last complete snapshot). While the lock is held by another
process (the old active NC frozen on the same host, same path) the NC drives without its file: warned once,
the lock tried again every :data:`LOCK_RETRY_S`, and the replies of durable commands go out as 0x4002 (not
kept), as with ``writing_disabled``. Only a cold start (``start = "active"``, or a standby that takes over
without having followed anyone) loads and applies the file, as a single NC does.

Homed flags of persistent axes come from the file only: once a retain file exists, a persistent
axis for which the file holds no usable position taken at standstill (refused or unreadable file,
axis missing, another ``Name``, another modulo setting, a position out of range, SetActualPosition
refused, a snapshot taken while it moved) starts with Homed FALSE (a 0x4002 warning: the axis must be
referenced again). Only the first start (no file yet) keeps the configured ``Homed``.
"""
from __future__ import annotations

import collections
import errno
import fcntl
import hashlib
import logging
import math
import os
import stat
import struct
import tempfile
import threading
import time
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any, Callable, Collection, Mapping

import msgpack
import numpy as np

from nc_schema import ErrorCodes, MC_AxisPara, NcError, error_name, make_request, parse_request

from nc_server.core.params import AxisParams

__all__ = ["AxisRetain", "RetainData", "RetainError", "RetainKeeper", "RetainLockError", "encode_retain",
           "parse_retain", "write_atomic", "max_body", "FORMAT_VERSION", "MAGIC", "SNAPSHOT_PERIOD",
           "MOVING_WRITE_PERIOD", "STANDSTILL_CHECK_PERIOD", "STANDSTILL_TOLERANCE", "STANDSTILL_VELOCITY",
           "DURABLE_COMMANDS", "POSITION_COMMANDS"]

log = logging.getLogger("nc_server.server")

#: First bytes of every retain file.
MAGIC = b"ZNCRTN\r\n"
#: The format this module writes and reads.
FORMAT_VERSION = 2
#: magic, version, body length, sha256(body)
_HEADER = struct.Struct("<8sHI32s")
#: Body bound: this much [bytes] ...
BODY_BASE = 64 * 1024
#: ... plus this much per configured axis (an axis with every parameter written and a 64-character
#: Name encodes to about 4 KiB).
BODY_PER_AXIS = 8 * 1024
#: Longest string in a body [bytes]: a ``Name`` of 64 characters in UTF-8.
MAX_STR = 256
#: Most entries of one msgpack map (the axes map: AxisIds are 1..65535).
MAX_MAP = 65535
#: Largest |position| kept (the NC's MAX_POSITION: SetActualPosition refuses more).
MAX_POSITION = 1e9
#: The cycle hands a snapshot to the retain thread this often [s] (and at once when a standstill flag changes).
SNAPSHOT_PERIOD = 0.1
#: The cycle looks for axes that started or stopped standing this often [s] (a snapshot at once when
#: one did; a check costs a few microseconds, so not every cycle).
STANDSTILL_CHECK_PERIOD = 0.01
#: While only positions of moving axes changed, the file is written at most this often [s].
MOVING_WRITE_PERIOD = 1.0
#: An axis without job and set velocity stands when |ActVelo| is at most this [u/s] (over one snapshot
#: period it moves less than 1e-4 u); a noisier encoder counts as moving: the safe side.
STANDSTILL_VELOCITY = 1e-3
#: A standing axis's position change up to this fraction of its AxisTargetPositionWindow is not worth
#: a write of its own (the settling tail, encoder noise); it goes with the next change or the final write.
STANDSTILL_TOLERANCE = 0.1
#: Error code of a refused file (TwinCAT: NC retain (persistent) data error).
RETAIN_ERROR_CODE = 0x4002
#: Commands whose reply (no error) waits until their effect is in the file (MC_WriteBoolParameter sends
#: WriteParameter too). Homing is not one: its reply comes before the axis is homed; the next
#: snapshot keeps the flag.
DURABLE_COMMANDS = frozenset({"WriteParameter", "SetActualPosition", "SetActualPositionOnTheFly", "SetReferenceFlag"})
#: Those of DURABLE_COMMANDS that change what is kept of persistent axes only (AxisEnDataPersistence).
POSITION_COMMANDS = frozenset({"SetActualPosition", "SetActualPositionOnTheFly", "SetReferenceFlag"})
#: (a hot-standby pair) An active NC whose retain file's lock is held by another process tries again this often [s].
LOCK_RETRY_S = 1.0
#: Set velocities up to this count as zero (the core's own threshold) [u/s].
_EPS_V = 1e-9

_PARAM_KINDS: dict[str, str] = {f.name: f.metadata["kind"] for f in fields(AxisParams)}
_AXIS_KEYS = frozenset({"name", "position", "homed", "standstill", "modulo", "params"})
_POS_KEYS = frozenset({"position", "homed", "standstill", "modulo"})
_DIR_SYNC_UNSUPPORTED = frozenset({errno.EINVAL, errno.ENOTSUP, errno.EOPNOTSUPP})


def max_body(n_axes: int) -> int:
    """Largest body [bytes] a reader with ``n_axes`` configured axes accepts (bounds its memory too)."""
    return BODY_BASE + BODY_PER_AXIS * max(1, int(n_axes))


def _short(s: Any, n: int = 40) -> str:
    """``repr(s)`` cut to ``n`` characters (names from a hostile file go into log lines)."""
    r = repr(s)
    return r if len(r) <= n else r[:n - 3] + "..."


class RetainError(ValueError):
    """A retain file that cannot be used.

    Attributes:
        kind: ``"corrupt"`` (checksum, length or structure), ``"foreign"`` (another NC's file, or none
            of its axes is configured here) or ``"version"`` (a format version this NC cannot read).
    """

    def __init__(self, kind: str, message: str) -> None:
        super().__init__(f"{kind}: {message}")
        self.kind = kind


class RetainLockError(RuntimeError):
    """The retain file cannot be locked for this process: another process holds ``<file>.lock`` (two NCs
    must not share one retain file), or the lock file cannot be created."""


@dataclass(frozen=True)
class AxisRetain:
    """What is kept of one axis.

    Attributes:
        name: the axis's ``Name`` when it was written (an axis renamed since is skipped).
        position: actual position [u] (persistent axes only), None: not kept.
        homed: StateDWord.Homed (with ``position``).
        standstill: the axis stood when the position was taken (with ``position``); FALSE: it is
            restored unreferenced.
        modulo: AxisEncoderModuloValue when ``Modulo`` was TRUE, 0.0 otherwise [u] (with ``position``).
        params: parameters written at run time, by TwinCAT name: (value, configured value then),
            e.g. ``{"AxisVeloMax": (400.0, 1000.0)}``.
        unknown: parameter names of the file this NC does not know (parsing only; skipped).
    """

    name: str
    position: float | None = None
    homed: bool | None = None
    standstill: bool | None = None
    modulo: float | None = None
    params: Mapping[str, tuple[float | bool, float | bool]] = field(default_factory=dict)
    unknown: tuple[str, ...] = field(default=(), compare=False)


@dataclass(frozen=True)
class RetainData:
    """The content of a retain file.

    Attributes:
        nc_name: the NC that wrote it (``[nc] name``).
        axes: AxisId -> what is kept of that axis (axes with nothing kept are left out).
        saved_ns: CLOCK_REALTIME when the snapshot was taken [ns] (not part of the comparison).
    """

    nc_name: str
    axes: Mapping[int, AxisRetain] = field(default_factory=dict)
    saved_ns: int = field(default=0, compare=False)


# ---- encoding / parsing -----------------------------------------------------------------------
def _num(v: float | bool) -> float | bool:
    return v if isinstance(v, bool) else float(v)


def encode_retain(data: RetainData) -> bytes:
    """The file bytes of ``data`` (header + msgpack body; axes and parameters in sorted order, so equal
    data gives equal bytes apart from ``saved_ns``)."""
    axes: dict[int, dict[str, Any]] = {}
    for axis_id in sorted(data.axes):
        a = data.axes[axis_id]
        d: dict[str, Any] = {"name": str(a.name)}
        if a.position is not None:
            d.update(position=float(a.position), homed=bool(a.homed), standstill=bool(a.standstill),
                     modulo=float(a.modulo or 0.0))
        if a.params:
            d["params"] = {k: {"value": _num(v), "configured": _num(c)} for k, (v, c) in sorted(a.params.items())}
        axes[int(axis_id)] = d
    body = msgpack.packb({"nc": data.nc_name, "saved_ns": int(data.saved_ns), "axes": axes}, use_bin_type=True)
    return _HEADER.pack(MAGIC, FORMAT_VERSION, len(body), hashlib.sha256(body).digest()) + body


def parse_retain(raw: bytes, nc_name: str, axis_ids: Collection[int]) -> RetainData:
    """Check and decode a retain file written by :func:`encode_retain`.

    Never raises anything but :class:`RetainError`, whatever ``raw`` holds (a fuzz target), and its
    memory stays bounded: a body above :func:`max_body` is refused before it is decoded, msgpack
    arrays and binaries are refused, strings are at most :data:`MAX_STR` bytes. Values are judged
    when applied (a position out of range costs that axis its position, not the file).

    Args:
        raw: the file's bytes.
        nc_name: this NC's name; a file of another NC is foreign.
        axis_ids: this NC's axes (their count bounds the body); a file with axes of which none is
            configured here is foreign (axes of the file that are not configured stay in the
            result: the caller reports them).

    Raises:
        RetainError: ``corrupt`` (wrong magic, truncated, too long, checksum mismatch, not msgpack,
            wrong structure), ``version`` (unknown format version), ``foreign`` (see above).
    """
    try:
        return _parse(bytes(raw), nc_name, axis_ids)
    except RetainError:
        raise
    except Exception as exc:  # a case the checks below missed: still a refusal, never a crash
        raise RetainError("corrupt", f"unreadable ({type(exc).__name__}: {_short(str(exc), 80)})") from None


def _parse(raw: bytes, nc_name: str, axis_ids: Collection[int]) -> RetainData:
    if len(raw) < len(MAGIC) or raw[:len(MAGIC)] != MAGIC:
        raise RetainError("corrupt", f"not a zenoh-nc retain file (magic {raw[:len(MAGIC)]!r}, expected {MAGIC!r})")
    if len(raw) < len(MAGIC) + 2:
        raise RetainError("corrupt", f"truncated header ({len(raw)} bytes)")
    (version,) = struct.unpack_from("<H", raw, len(MAGIC))
    if version != FORMAT_VERSION:
        raise RetainError("version", f"format version {version}, this NC reads version {FORMAT_VERSION}")
    if len(raw) < _HEADER.size:
        raise RetainError("corrupt", f"truncated header ({len(raw)} of {_HEADER.size} bytes)")
    _, _, length, digest = _HEADER.unpack_from(raw)
    ids = {int(a) for a in axis_ids}
    limit = max_body(len(ids))
    if length > limit:
        raise RetainError("corrupt", f"body length {length} above {limit} (the bound for {len(ids)} axes)")
    body = raw[_HEADER.size:]
    if len(body) != length:
        raise RetainError("corrupt", f"truncated or padded: body has {len(body)} bytes, header says {length}")
    if hashlib.sha256(body).digest() != digest:
        raise RetainError("corrupt", "checksum mismatch (sha256 of the body)")
    try:
        doc = msgpack.unpackb(body, raw=False, strict_map_key=False, use_list=False, max_str_len=MAX_STR,
                              max_bin_len=0, max_array_len=0, max_map_len=MAX_MAP, max_ext_len=0)
    except Exception as exc:
        raise RetainError("corrupt", f"body is not msgpack of this format ({type(exc).__name__}: "
                                     f"{_short(str(exc), 80)})") from None
    data = _structure(doc)
    if data.nc_name != nc_name:
        raise RetainError("foreign", f"written by NC {_short(data.nc_name)}, this is NC {nc_name!r}")
    if data.axes and not ids.intersection(data.axes):
        raise RetainError("foreign", f"none of its axes {sorted(data.axes)[:8]} is configured here "
                                     f"(axes {sorted(ids)[:8]})")
    return data


def _structure(doc: Any) -> RetainData:
    def bad(msg: str) -> RetainError:
        return RetainError("corrupt", f"structure: {msg}")

    if not isinstance(doc, dict):
        raise bad(f"the body is a {type(doc).__name__}, expected a map")
    if set(doc) != {"nc", "saved_ns", "axes"}:
        raise bad(f"keys {[_short(k) for k in list(doc)[:8]]}, expected 'axes', 'nc', 'saved_ns'")
    nc, saved, axes = doc["nc"], doc["saved_ns"], doc["axes"]
    if not isinstance(nc, str) or not nc:
        raise bad(f"nc must be a non-empty string, got {_short(nc)}")
    if isinstance(saved, bool) or not isinstance(saved, int) or saved < 0:
        raise bad(f"saved_ns must be an integer >= 0, got {_short(saved)}")
    if not isinstance(axes, dict):
        raise bad(f"axes must be a map, got {type(axes).__name__}")
    out: dict[int, AxisRetain] = {}
    for axis_id, a in axes.items():
        if isinstance(axis_id, bool) or not isinstance(axis_id, int) or not 1 <= axis_id <= 65535:
            raise bad(f"axis id {_short(axis_id)} is not an integer 1..65535")
        where = f"axis {axis_id}"
        if not isinstance(a, dict) or not set(a) <= _AXIS_KEYS:
            raise bad(f"{where}: expected a map with name, position, homed, standstill, modulo, params")
        name = a.get("name")
        if not isinstance(name, str):
            raise bad(f"{where}: name {_short(name)} is not a string")
        pos = homed = standstill = modulo = None
        present = _POS_KEYS.intersection(a)
        if present and present != _POS_KEYS:
            raise bad(f"{where}: position, homed, standstill and modulo come together, got {sorted(present)}")
        if present:
            pos, homed, standstill, modulo = a["position"], a["homed"], a["standstill"], a["modulo"]
            if not _is_number(pos):
                raise bad(f"{where}: position {_short(pos)} is not a number")
            if not isinstance(homed, bool) or not isinstance(standstill, bool):
                raise bad(f"{where}: homed {_short(homed)} / standstill {_short(standstill)} are not booleans")
            if not _is_number(modulo):
                raise bad(f"{where}: modulo {_short(modulo)} is not a number")
            pos, modulo = float(pos), float(modulo)
        params = a.get("params", {})
        if not isinstance(params, dict):
            raise bad(f"{where}: params must be a map")
        if len(params) > len(_PARAM_KINDS):
            raise bad(f"{where}: {len(params)} parameters, an axis has {len(_PARAM_KINDS)}")
        clean: dict[str, tuple[float | bool, float | bool]] = {}
        unknown: list[str] = []
        for pname, entry in params.items():
            if not isinstance(pname, str) or not pname:
                raise bad(f"{where}: parameter name {_short(pname)} is not a string")
            if not isinstance(entry, dict) or set(entry) != {"value", "configured"}:
                raise bad(f"{where}: parameter {_short(pname)} must be a map with value and configured")
            v, c = entry["value"], entry["configured"]
            for x in (v, c):
                if not (isinstance(x, bool) or _is_number(x)):
                    raise bad(f"{where}: parameter {_short(pname)} = {_short(x)} is not a number or a boolean")
            if pname not in _PARAM_KINDS:
                unknown.append(pname)
                continue
            clean[pname] = (_num(v), _num(c))
        out[axis_id] = AxisRetain(name, pos, homed, standstill, modulo, clean, tuple(unknown))
    return RetainData(nc, out, saved)


def _is_number(v: Any) -> bool:
    """An int or a float (also inf/nan: a value out of range is judged where it is applied)."""
    return not isinstance(v, bool) and isinstance(v, (int, float))


def _keepable(pos: float) -> bool:
    """A position the reader restores (finite, within +/-MAX_POSITION)."""
    return math.isfinite(pos) and abs(pos) < MAX_POSITION


# ---- the file ---------------------------------------------------------------------------------
def write_atomic(path: str | os.PathLike[str], data: bytes) -> bool:
    """Replace ``path`` by ``data`` so that a crash at any point leaves either the old or the new file.

    Writes a temporary file of its own (``mkstemp`` in the same directory: ``<name>.XXXXXXXX.tmp``,
    so two writers never share one), fsyncs it, ``os.replace``s it over ``path`` and fsyncs the
    directory (the rename itself is then durable).

    Returns:
        True; False when the file system cannot fsync a directory (EINVAL/ENOTSUP after the
        rename): the new file is in place, only the rename's durability is the file system's.

    Raises:
        OSError: the write failed (the temporary file is removed, ``path`` is untouched), or the
            directory fsync failed otherwise (the new file is in place).
    """
    p = Path(path)
    fd, tmp = tempfile.mkstemp(prefix=p.name + ".", suffix=".tmp", dir=p.parent)
    try:
        try:
            os.fchmod(fd, 0o644)
            view = memoryview(data)
            while view:
                n = os.write(fd, view)
                view = view[n:]
            os.fsync(fd)
        finally:
            os.close(fd)
        os.replace(tmp, p)
    except BaseException:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        raise
    try:
        dfd = os.open(p.parent, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0))
        try:
            os.fsync(dfd)
        finally:
            os.close(dfd)
    except OSError as exc:
        if exc.errno in _DIR_SYNC_UNSUPPORTED:
            return False
        raise
    return True


def _set_aside(path: Path) -> Path:
    """Rename a refused file to ``<path>.rejected`` (or ``.rejected.N``: an older one is kept)."""
    target = path.with_name(path.name + ".rejected")
    n = 0
    while os.path.lexists(target):
        n += 1
        target = path.with_name(f"{path.name}.rejected.{n}")
    os.rename(path, target)
    return target


def _read_file(path: Path, limit: int) -> bytes:
    """At most ``limit`` bytes of a regular file (never blocks on a FIFO).

    Raises:
        FileNotFoundError: no file.
        OSError: unreadable, or not a regular file (EINVAL).
    """
    fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            raise OSError(errno.EINVAL, "not a regular file")
        chunks: list[bytes] = []
        left = limit
        while left > 0:
            b = os.read(fd, min(left, 1 << 20))
            if not b:
                break
            chunks.append(b)
            left -= len(b)
        return b"".join(chunks)
    finally:
        os.close(fd)


# ---- the server's part ------------------------------------------------------------------------
@dataclass
class _Snapshot:
    """What the cycle hands over: copies of the columns, references to the parameter objects."""

    act_pos: np.ndarray
    homed: np.ndarray
    standing: np.ndarray
    params: tuple[AxisParams, ...]
    time_ns: int
    seq: int = 0
    #: the newest commit taken before it (:meth:`RetainKeeper.commit`): it holds their state
    commit: int = 0


def param_number(name: str) -> int | None:
    """The MC_AxisPara number WriteParameter takes for parameter ``name`` (None: not writable)."""
    try:
        return int(MC_AxisPara[name])
    except KeyError:
        return None


def _command(core: Any, axis_id: int, cmd: str, **args: Any) -> dict[str, Any]:
    """Run one command on ``core`` as if it came over zenoh (the same parsing and checks); its reply map."""
    try:
        req = parse_request(make_request(cmd, "retain", **args))
    except NcError as exc:
        return {"error": exc.code, "text": str(exc)}
    return core.execute(req, axis_id)


def standing(core: Any) -> np.ndarray:
    """Per axis: no job, ``|SetVelo| <= 1e-9`` and ``|ActVelo| <=`` :data:`STANDSTILL_VELOCITY`."""
    a = core.axes
    logical = ~(a.has_job | a.traj_on | (np.abs(a.set_velo) > _EPS_V))
    return logical & (np.abs(core.drive.act_velo) <= STANDSTILL_VELOCITY)


def _modulo(p: AxisParams) -> float:
    return float(p.AxisEncoderModuloValue) if p.Modulo else 0.0


class RetainKeeper:
    """Load the retain file at startup, keep it up to date while the NC runs (one thread).

    Use: :meth:`load` (before the cycle), :meth:`start`, then on the cycle thread :meth:`apply`
    after the first ``core.step()`` and :meth:`tick` every cycle; :meth:`stop` with the core once the
    cycle ended (final write, lock released).

    Args:
        path: the retain file (its directory must exist and be writable).
        nc_name: this NC's name (written into the file, checked when loading).
        core: the NcCore; its parameters now are the configured base.
    """

    def __init__(self, path: str | os.PathLike[str], nc_name: str, core: Any) -> None:
        self.path = Path(path)
        self.lock_path = self.path.with_name(self.path.name + ".lock")
        self.nc_name = nc_name
        self.axis_ids = [int(a) for a in np.asarray(core.axis_ids).tolist()]
        self.names = [str(c.Name) for c in core.configs]
        self._base: tuple[AxisParams, ...] = tuple(core.params)  # replaced on every write, never changed
        self._period_cycles = max(1, round(SNAPSHOT_PERIOD / float(core.cycle_time)))
        self._check_cycles = max(1, round(STANDSTILL_CHECK_PERIOD / float(core.cycle_time)))
        self._due = 0
        self._check_due = 0
        self._last_standing: np.ndarray | None = None
        # the newest snapshot handed over (append and popleft are atomic: a snapshot handed over while the
        # retain thread takes the previous one is never lost)
        self._pending: collections.deque[_Snapshot] = collections.deque(maxlen=1)
        self._wake = threading.Event()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._written: RetainData | None = None
        self._last_write = -math.inf  # _clock() of the last write
        self._clock: Callable[[], float] = time.monotonic
        self._write_lock = threading.Lock()  # the retain thread and stop()'s final write never overlap
        self._last_error = ""
        self._unkept: set[int] = set()  # axes whose position is left out of the file (logged once)
        self._dir_sync_warned = False
        self._lock_fd: int | None = None
        self.status = "new"  # after load(): "missing", "loaded", "refused", "unreadable"
        self.applied = False  # apply() ran: from now on snapshots are taken and written
        self.writing_disabled = False  # an unreadable file could not be set aside: nothing is written
        self.handed = 0  # snapshots handed over by tick() (sequence number of the newest)
        self.processed = 0  # sequence number of the newest snapshot the retain thread has handled
        self.writes = 0  # files written
        self.deferred = 0  # changed snapshots not written (moving axes within MOVING_WRITE_PERIOD, standstill noise)
        self.write_errors = 0  # writes that failed (logged once per kind of failure)
        self.loaded: RetainData | None = None  # what load() read
        self.committed = 0  # newest commit number handed out by commit() (cycle thread)
        self.durable = 0  # newest commit number whose state is in the file (written and fsync'ed)
        self.settled = 0  # newest commit number the retain thread has handled (durable or its write failed)
        #: called by the retain thread after ``settled`` rose (the I/O thread's wake-up; never blocks)
        self.on_settled: Callable[[], None] | None = None
        self.rejected: Path | None = None  # where load() put a refused file
        #: (a hot-standby pair: :meth:`follow`) the lock is the retain thread's to take and release, as the role says
        self.managed = False
        self._want = True  # (managed) this NC is active: hold the lock and write; False: release it, write nothing
        self._lock_warned = False  # (managed) the lock held by another process was said (once per takeover)
        self.lock_waits = 0  # (managed) tries of the lock that found it held by another process

    # -- startup: read (before the cycle starts) -------------------------------------------------
    def load(self) -> RetainData | None:
        """Lock the file for this process, then read and check it (nothing is applied yet: :meth:`apply`).

        A missing file is the first start; a refused or unreadable one is logged (0x4002) and set
        aside (``.rejected``). Never raises for the file's content.

        Returns:
            the file's content, or None (no file, refused, unreadable).

        Raises:
            RetainLockError: another process holds ``<file>.lock``, or it cannot be created.
        """
        if self.status != "new":  # (loaded once per process)
            return self.loaded
        with self._write_lock:  # (a pair's cold takeover: the retain thread runs; its _own must not see the lock
            self._lock()        # held with _want still False and close it)
            self._want = True  # (a pair's cold start: this NC keeps the file from now on)
        self._remove_stale_temporaries()
        path = self.path
        try:
            raw = _read_file(path, _HEADER.size + max_body(len(self.axis_ids)) + 1)
        except FileNotFoundError:
            self.status = "missing"
            log.info("retain file %s does not exist yet: the NC starts with its configuration", path)
            return None
        except OSError as exc:
            self.status = "unreadable"
            self._refuse(f"cannot read it ({exc.strerror or exc})")
            return None
        try:
            data = parse_retain(raw, self.nc_name, self.axis_ids)
        except RetainError as exc:
            self.status = "refused"
            self._refuse(str(exc), verb="refused")
            return None
        self.status = "loaded"
        self.loaded = data
        return data

    def _refuse(self, why: str, verb: str = "unusable") -> None:
        try:
            aside = _set_aside(self.path)
            self.rejected = aside
            kept = f"the file is kept as {aside}"
        except OSError as oe:
            self.writing_disabled = True
            kept = (f"the file could not be renamed ({oe.strerror or oe}): the NC does NOT write the retain file "
                    f"during this run (it would overwrite it); move it away and restart")
        log.error("retain file %s %s: 0x%04X NC retain data error: %s; the NC starts with its configuration "
                  "(persistent axes unreferenced); %s", self.path, verb, RETAIN_ERROR_CODE, why, kept)

    def _lock(self) -> None:
        if self._lock_fd is not None:
            return
        try:
            fd = os.open(self.lock_path, os.O_RDWR | os.O_CREAT | getattr(os, "O_CLOEXEC", 0), 0o644)
        except OSError as exc:
            raise RetainLockError(f"retain file {self.path}: cannot create its lock file {self.lock_path} "
                                  f"({exc.strerror or exc})") from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            try:
                holder = "".join(c for c in os.pread(fd, 32, 0).decode("ascii", "replace") if c.isdigit())[:10] or "?"
            except OSError:
                holder = "?"
            os.close(fd)
            raise RetainLockError(f"retain file {self.path} is in use by another process (pid {holder} "
                                  f"holds {self.lock_path}): two NCs must not share one retain file") from None
        except BaseException:
            os.close(fd)
            raise
        try:
            os.ftruncate(fd, 0)
            os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
        except OSError:
            pass  # (the pid is only for the message of a second NC)
        self._lock_fd = fd

    def close(self) -> None:
        """Release the lock (as the kernel does when the process ends; idempotent, no write)."""
        fd, self._lock_fd = self._lock_fd, None
        if fd is not None:
            os.close(fd)

    def _remove_stale_temporaries(self) -> None:
        """Temporary files a crash left behind (the lock is held: no other writer exists)."""
        prefix = self.path.name + "."
        try:
            names = os.listdir(self.path.parent)
        except OSError:
            return
        for n in names:
            if n.startswith(prefix) and n.endswith(".tmp"):
                try:
                    os.unlink(self.path.parent / n)
                except OSError:
                    pass

    # -- startup: apply (cycle thread, after the first core.step()) ------------------------------
    def apply(self, core: Any) -> None:
        """Apply what :meth:`load` read (cycle thread, after the first ``core.step()``: the drive has been
        read, so SetActualPosition shifts against the real actual position; idempotent).

        Raises:
            RuntimeError: called before the first ``core.step()``.
        """
        if self.applied:
            return
        if int(core.cycle) < 1:
            raise RuntimeError("RetainKeeper.apply() needs one core.step() first (the drive is not read yet)")
        self.applied = True
        if self.status in ("refused", "unreadable"):
            for i, axis_id in enumerate(self.axis_ids):
                if core.params[i].AxisEnDataPersistence:
                    self._unreference(core, axis_id, i, "the retain file was not usable")
        elif self.loaded is not None:
            self._apply(core, self.loaded)

    def _warn(self, axis_id: int, i: int, what: str) -> None:
        log.warning("retain file %s: axis %d %s: %s", self.path, axis_id, _short(self.names[i]), what)

    def _unreference(self, core: Any, axis_id: int, i: int, why: str, claimed: bool = False) -> None:
        """Homed FALSE for a persistent axis the file cannot reference (warned when that changes anything)."""
        if claimed or bool(core.axes.homed[i]):
            self._warn(axis_id, i, f"0x{RETAIN_ERROR_CODE:04X} NC retain data error: {why}: Homed FALSE "
                                   f"(the axis must be referenced again)")
        _command(core, axis_id, "SetReferenceFlag", ReferenceFlag=False)

    def _apply(self, core: Any, data: RetainData) -> None:
        known = set(self.axis_ids)
        extra = sorted(set(data.axes) - known)
        if extra:
            log.warning("retain file %s: %d axis/axes not configured here, skipped: %s%s", self.path, len(extra),
                        extra[:8], " ..." if len(extra) > 8 else "")
        usable: dict[int, AxisRetain] = {}
        a: AxisRetain | None  # (a file entry; below: None if the axis has no usable one)
        for axis_id in sorted(known.intersection(data.axes)):
            a, i = data.axes[axis_id], self.axis_ids.index(axis_id)
            if a.name != self.names[i]:
                self._warn(axis_id, i, f"the file's entry is of axis {_short(a.name)}: skipped (parameters, "
                                       f"position and homed flag)")
                continue
            usable[axis_id] = a
        n_params = self._apply_params(core, usable)
        restored: list[int] = []
        for i, axis_id in enumerate(self.axis_ids):
            if not core.params[i].AxisEnDataPersistence:
                a = usable.get(axis_id)
                if a is not None and a.position is not None:
                    self._warn(axis_id, i, "not persistent (AxisEnDataPersistence FALSE): its position and homed "
                                           "flag are not restored")
                continue
            a = usable.get(axis_id)
            if a is None:
                why = ("its entry is of another axis" if axis_id in data.axes
                       else "the retain file holds nothing of it")
                self._unreference(core, axis_id, i, why)
                continue
            if a.position is None:
                self._unreference(core, axis_id, i, "the retain file holds no position of it")
                continue
            if not _keepable(a.position):
                self._unreference(core, axis_id, i, f"position {a.position!r} is not a number within "
                                                    f"+/-{MAX_POSITION:g}: skipped", claimed=bool(a.homed))
                continue
            if a.modulo != _modulo(core.params[i]):
                self._unreference(core, axis_id, i, f"the modulo setting changed (file {a.modulo:g}, now "
                                                    f"{_modulo(core.params[i]):g}): position skipped",
                                  claimed=bool(a.homed))
                continue
            r = _command(core, axis_id, "SetActualPosition", Position=a.position)
            if r.get("error"):
                self._unreference(core, axis_id, i, f"SetActualPosition {a.position!r} refused: "
                                                    f"0x{int(r['error']):04X} {r.get('text', '')}",
                                  claimed=bool(a.homed))
                continue
            restored.append(axis_id)
            if a.homed and not a.standstill:
                self._unreference(core, axis_id, i, f"its position {a.position:g} was taken while it moved "
                                                    f"(restored)", claimed=True)
            else:
                _command(core, axis_id, "SetReferenceFlag", ReferenceFlag=bool(a.homed))
        try:
            saved = time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(data.saved_ns / 1e9)) if data.saved_ns else "?"
        except (OverflowError, OSError, ValueError):  # (a hostile saved_ns)
            saved = "?"
        log.info("retain file %s loaded (saved %s): positions of axes %s, %d parameter(s)", self.path, saved,
                 restored or "none", n_params)

    def _apply_params(self, core: Any, usable: Mapping[int, AxisRetain]) -> int:
        """WriteParameter for each retained parameter whose configured value is still the configuration's."""
        n_params = 0
        for axis_id, a in usable.items():
            i = self.axis_ids.index(axis_id)
            for name in a.unknown:
                code = ErrorCodes.ADSERR_DEVICE_INVALIDOFFSET
                self._warn(axis_id, i, f"parameter {_short(name)} skipped: 0x{code:04X} {error_name(code)} "
                                       f"(no such parameter)")
            todo: list[tuple[str, int, float | bool]] = []
            for name, (value, configured) in a.params.items():
                number = param_number(name)
                now = getattr(self._base[i], name)
                if number is None:
                    code = ErrorCodes.ADSERR_DEVICE_INVALIDOFFSET
                    self._warn(axis_id, i, f"parameter {name} = {value!r} skipped: 0x{code:04X} {error_name(code)} "
                                           f"(no MC_AxisPara number)")
                    continue
                if type(now) is not type(configured) or now != configured:
                    self._warn(axis_id, i, f"parameter {name}: the configuration changed it from {configured!r} to "
                                           f"{now!r} since {value!r} was written at run time: the configuration's "
                                           f"{now!r} wins")
                    continue
                todo.append((name, number, value))
            # a pass that fails on an order dependence (AxisMinSoftPosLimit < AxisMaxSoftPosLimit) is
            # retried after the others
            failed: dict[str, dict[str, Any]] = {}
            while todo:
                left = []
                for name, number, value in todo:
                    r = _command(core, axis_id, "WriteParameter", ParameterNumber=number, Value=value)
                    if r.get("error"):
                        left.append((name, number, value))
                        failed[name] = r
                    else:
                        failed.pop(name, None)
                        n_params += 1
                        log.info("retain file %s: axis %d parameter %s = %r (configured %r)", self.path, axis_id,
                                 name, value, a.params[name][1])
                if len(left) == len(todo):
                    break
                todo = left
            for name, r in failed.items():
                self._warn(axis_id, i, f"parameter {name} = {a.params[name][0]!r} skipped (the configuration "
                                       f"rejects it): 0x{int(r['error']):04X} {r.get('text', '')}")
        return n_params

    # -- a hot-standby pair (docs/standby.md) ------------------------------------------------------
    def follow(self) -> None:
        """This NC is one of a hot-standby pair, a standby for now: no lock, no write until :meth:`resume`
        (before :meth:`start`; a cold start's :meth:`load` makes it the owner at once)."""
        self.managed = True
        self._want = False

    @property
    def owner(self) -> bool:
        """This process holds the file's lock (it may write the file)."""
        return self._lock_fd is not None

    def resume(self) -> None:
        """(cycle thread, a takeover in step or a retake: no I/O here) Keep the file from now on, with this NC's
        state (the file is not applied): the retain thread takes the lock at once (held by another process: said
        once, tried every LOCK_RETRY_S; replies of durable commands are not kept meanwhile) and the next cycle hands
        a snapshot over, written at once."""
        self.managed = True
        self._want = True
        self._lock_warned = False
        self.applied = True  # (snapshots from now on: tick)
        self._due = self._check_due = 0
        self._last_standing = None
        self._wake.set()

    def suspend(self) -> None:
        """(cycle thread, a demotion: no I/O here) Stop keeping the file: the retain thread writes nothing more
        (a write in progress ends first: the file stays the last complete snapshot) and releases the lock."""
        self.managed = True
        self._want = False
        self.applied = False
        self._pending.clear()
        self._wake.set()

    def _own(self) -> None:
        """(retain thread, managed) Take or release the lock as the role says."""
        if self._want and self._lock_fd is None:
            with self._write_lock:
                try:
                    self._lock()
                except RetainLockError as exc:
                    self.lock_waits += 1
                    if not self._lock_warned:
                        self._lock_warned = True
                        log.warning("%s: this NC drives without its retain file (replies of durable commands: 0x%04X, "
                                    "not kept) and tries the lock every %g s", exc, RETAIN_ERROR_CODE, LOCK_RETRY_S)
                    return
                self._remove_stale_temporaries()
                self._written = None  # (the file holds another state: the next snapshot is written at once)
            log.info("retain file %s: locked by this NC (active): it keeps the file from now on", self.path)
        elif not self._want:
            if self._lock_fd is not None:
                with self._write_lock:  # (after a write in progress)
                    self.close()
                log.info("retain file %s: released (this NC is a standby)", self.path)
            # commits of the active NC not written (or made while it waited for the lock): not kept
            self._settle(self.committed, False)

    # -- running ---------------------------------------------------------------------------------
    def start(self) -> None:
        """Start the retain thread (it writes the file when a snapshot differs from the file)."""
        if self._thread is None:
            self._stop.clear()
            self._thread = threading.Thread(target=self._run, name="nc-retain", daemon=True)
            self._thread.start()

    def tick(self, core: Any) -> None:
        """Cycle thread, every cycle: hand a snapshot over every SNAPSHOT_PERIOD and when a standstill
        flag changed (looked at every STANDSTILL_CHECK_PERIOD; no I/O, no encoding, never blocks).
        Nothing before :meth:`apply`."""
        cycle = core.cycle
        if cycle < self._check_due or not self.applied:
            return
        self._check_due = cycle + self._check_cycles
        st = standing(core)
        last = self._last_standing
        if cycle < self._due and last is not None and np.array_equal(st, last):
            return
        self._last_standing = st
        self._due = cycle + self._period_cycles
        self.handed += 1
        self._pending.append(self._snapshot(core, st, self.handed))
        self._wake.set()

    def keeps(self, core: Any, cmd: str, axis_id: int | None) -> bool:
        """Whether ``cmd`` on ``axis_id``, answered with no error, changes the file's content, so its reply waits
        for the file (:meth:`commit`): a parameter write, always; a position or homed flag, on a persistent
        axis only (the file holds no position of another axis: its reply would claim a keeping that
        never happens, so it goes out at once)."""
        if cmd not in DURABLE_COMMANDS:
            return False
        if cmd not in POSITION_COMMANDS:
            return True
        try:
            return bool(core.params[core.index(axis_id)].AxisEnDataPersistence)
        except (NcError, TypeError):  # (no such axis: the command was refused anyway)
            return False

    def commit(self, core: Any) -> int:
        """Cycle thread, after requests of :data:`DURABLE_COMMANDS` ran: hand a snapshot over that the
        retain thread writes at once (no I/O here, never blocks). Their replies wait until
        :attr:`settled` reaches the returned commit number (:attr:`durable` too: kept)."""
        self.committed += 1
        self.handed += 1
        self._pending.append(self._snapshot(core, seq=self.handed))
        self._wake.set()
        return self.committed

    def take_pending(self) -> _Snapshot | None:
        """The newest snapshot handed over and not taken yet (the retain thread's; None: none)."""
        try:
            return self._pending.popleft()
        except IndexError:
            return None

    def _snapshot(self, core: Any, st: np.ndarray | None = None, seq: int = 0) -> _Snapshot:
        return _Snapshot(np.array(core.act_pos, dtype=float), core.axes.homed.copy(),
                         standing(core) if st is None else st, tuple(core.params), time.time_ns(), seq,
                         self.committed)

    def stop(self, core: Any | None = None) -> None:
        """End the retain thread; with ``core`` (its cycle ended) write its final state first; release
        the lock (idempotent). No write before :meth:`apply` ran: the file stays as loaded."""
        t = self._thread
        self._thread = None
        if t is not None:
            self._stop.set()
            self._wake.set()
            t.join(10)
        try:
            if core is not None and self.applied:
                self._write(self._snapshot(core), final=True)
        finally:
            self.close()
            self._settle(self.committed, False)  # (no-op when the final write made them durable)

    def _run(self) -> None:
        while True:
            self._wake.wait(LOCK_RETRY_S if self.managed and self._want and self._lock_fd is None else None)
            self._wake.clear()
            if self.managed:
                self._own()
            snap = self.take_pending()
            if snap is not None:
                try:
                    self._write(snap)
                finally:
                    self.processed = snap.seq
            if self._stop.is_set():
                return

    def data_of(self, snap: _Snapshot) -> RetainData:
        """The file content of a snapshot (retain thread). Positions the reader would refuse are left out
        (logged once per axis)."""
        axes: dict[int, AxisRetain] = {}
        for i, axis_id in enumerate(self.axis_ids):
            p, base = snap.params[i], self._base[i]
            changed: dict[str, tuple[float | bool, float | bool]] = {}
            if p is not base:
                for name in _PARAM_KINDS:
                    v, c = getattr(p, name), getattr(base, name)
                    if v != c:
                        changed[name] = (v, c)
            name = self.names[i]
            if p.AxisEnDataPersistence:
                pos = float(snap.act_pos[i])
                if _keepable(pos):
                    if axis_id in self._unkept:
                        self._unkept.discard(axis_id)
                        log.info("retain file %s: axis %d position %g is kept again", self.path, axis_id, pos)
                    axes[axis_id] = AxisRetain(name, pos, bool(snap.homed[i]), bool(snap.standing[i]), _modulo(p),
                                               changed)
                    continue
                if axis_id not in self._unkept:
                    self._unkept.add(axis_id)
                    log.warning("retain file %s: axis %d position %r is outside +/-%g: not kept (nor its homed "
                                "flag: the next start has it unreferenced)", self.path, axis_id, pos, MAX_POSITION)
                axes[axis_id] = AxisRetain(name, params=changed)
            elif changed:
                axes[axis_id] = AxisRetain(name, params=changed)
        return RetainData(self.nc_name, axes, snap.time_ns)

    def _change(self, new: RetainData, old: RetainData | None, snap: _Snapshot) -> str:
        """How a changed content is written (retain thread): ``"urgent"`` at once (a homed or standstill
        flag, a parameter, a standing axis's position by more than :data:`STANDSTILL_TOLERANCE` x
        AxisTargetPositionWindow), ``"moving"`` at most every MOVING_WRITE_PERIOD (positions of moving
        axes), ``"noise"`` not before another change or the final write (smaller changes of standing axes)."""
        if old is None or set(new.axes) != set(old.axes):
            return "urgent"
        kind = "noise"
        for axis_id, a in new.axes.items():
            b = old.axes[axis_id]
            if (a.name, a.homed, a.standstill, a.modulo, a.params) != (b.name, b.homed, b.standstill, b.modulo,
                                                                       b.params):
                return "urgent"
            if a.position == b.position:
                continue
            if a.position is None or b.position is None:
                return "urgent"
            if not a.standstill:
                kind = "moving"
                continue
            i = self.axis_ids.index(axis_id)
            if abs(a.position - b.position) > STANDSTILL_TOLERANCE * snap.params[i].AxisTargetPositionWindow:
                return "urgent"
        return kind

    def _write(self, snap: _Snapshot, final: bool = False) -> None:
        if not self._write_lock.acquire(timeout=10.0):  # a write hanging on a dead disk: give up on this one
            log.error("retain file %s: 0x%04X NC retain data error: a write hangs; this state is not kept",
                      self.path, RETAIN_ERROR_CODE)
            self._settle(snap.commit, False)
            return
        try:
            kept = self._write_locked(snap, final or snap.commit > self.durable)
        finally:
            self._write_lock.release()
        self._settle(snap.commit, kept)

    def _settle(self, commit: int, kept: bool) -> None:
        """The commits up to ``commit`` are handled: in the file (``kept``) or not (their write failed)."""
        if kept and commit > self.durable:
            self.durable = commit
        if commit > self.settled:
            self.settled = commit
            if self.on_settled is not None:
                self.on_settled()

    def _write_locked(self, snap: _Snapshot, force: bool) -> bool:
        """Write the snapshot's content if it changed (``force``: at once, else when its kind of change
        is due); whether the file holds it now."""
        if self.writing_disabled or (self.managed and (self._lock_fd is None or not self._want)):
            return False  # (a standby, or an active NC without the lock: not kept)
        try:
            data = self.data_of(snap)
            if data == self._written and self.path.exists():
                return True
            if not force:
                change = self._change(data, self._written, snap)
                if change == "noise" or (change == "moving" and self._clock() - self._last_write < MOVING_WRITE_PERIOD):
                    self.deferred += 1
                    return False
            raw = encode_retain(data)
            parse_retain(raw, self.nc_name, self.axis_ids)  # never write what the reader refuses
            synced = write_atomic(self.path, raw)
        except Exception as exc:  # a full disk must not end the NC: say it once per kind of failure
            self.write_errors += 1
            # one kind of failure: its type and reason (not the random temporary file name)
            msg = f"{type(exc).__name__}: {exc.strerror or exc}" if isinstance(exc, OSError) else \
                f"{type(exc).__name__}: {exc}"
            if msg != self._last_error:
                self._last_error = msg
                log.error("retain file %s: 0x%04X NC retain data error: cannot write it (%s); retrying with "
                          "the next change", self.path, RETAIN_ERROR_CODE, msg)
            self._written = None
            return False
        if not synced and not self._dir_sync_warned:
            self._dir_sync_warned = True
            log.warning("retain file %s: the file system cannot fsync the directory (the rename is written, its "
                        "durability after a power cut is the file system's); said once", self.path)
        if self._last_error:
            log.info("retain file %s written again", self.path)
            self._last_error = ""
        self._written = data
        self._last_write = self._clock()
        self.writes += 1
        return True
