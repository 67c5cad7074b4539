"""The retain file: what an NC keeps across a restart (opt-in: ``[nc] retain_file`` / ``--retain``).

Kept per axis:

* the actual position and the homed flag (StateDWord.Homed) of every axis whose TwinCAT parameter
  ``AxisEnDataPersistence`` is TRUE (a homed flag without its position would claim a reference the
  axis no longer has: for the other axes the configuration's ``Homed`` decides, e.g. for an
  absolute encoder);
* the parameters written at run time (MC_WriteParameter): every stored parameter whose value differs
  from the configuration's. The configuration stays the base: a parameter written back to its
  configured value is not kept.

File format (version :data:`FORMAT_VERSION`)::

    offset  size  field
    0       8     magic b"ZNCRTN\\r\\n"   (the CR LF catches text-mode mangling)
    8       2     format version, uint16 little-endian
    10      4     body length, uint32 little-endian
    14      32    sha256 of the body
    46      n     body: msgpack map {"nc": str, "saved_ns": int,
                                     "axes": {AxisId: {"position": float, "homed": bool,
                                                       "params": {name: float | bool}}}}

The magic and the version stay where they are in every future version; a reader refuses a version
it does not know before it looks at anything else.

Threads: the cycle thread never touches the disk. Every :data:`SNAPSHOT_PERIOD` it copies the
actual positions, the homed flags and the references of the (immutable) parameter objects
(:meth:`RetainKeeper.tick`, a few microseconds) and hands them to the retain thread, which builds a
:class:`RetainData`, and writes the file (:func:`write_atomic`) only when its content changed; once
more at shutdown, after the cycle ended. After a SIGKILL the file holds the state of at most one
snapshot period (plus one write) ago.

At startup (:meth:`RetainKeeper.load`, before the cycle starts, the axes disabled) the file's
parameters go through WriteParameter (its validation: a value the configuration rejects is logged
and skipped), then the positions through SetActualPosition and the homed flags through
SetReferenceFlag, for the axes that are persistent by then. A file that cannot be used (corrupt,
another NC's, an unknown format version) is refused with one error line (0x4002, TwinCAT's "NC
retain data error"), renamed to ``<file>.rejected`` (``.rejected.1``, ... if that exists: it is never
overwritten) and the NC starts with its configuration; the next write creates a fresh file.
"""
from __future__ import annotations

import hashlib
import logging
import math
import os
import struct
import threading
import time
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any, Collection, Mapping

import msgpack
import numpy as np

from nc_schema import ErrorCodes, MC_AxisPara, NcError, error_name, make_request, parse_request

from nc_server.core.params import AxisParams

__all__ = ["AxisRetain", "RetainData", "RetainError", "RetainKeeper", "encode_retain", "parse_retain",
           "write_atomic", "FORMAT_VERSION", "MAGIC", "SNAPSHOT_PERIOD"]

log = logging.getLogger("nc_server.server")

#: First bytes of every retain file.
MAGIC = b"ZNCRTN\r\n"
#: The format this module writes and reads.
FORMAT_VERSION = 1
#: magic, version, body length, sha256(body)
_HEADER = struct.Struct("<8sHI32s")
#: Largest body read [bytes] (65535 axes with a few parameters each stay far below).
MAX_BODY = 16 * 1024 * 1024
#: Largest |position| kept (the NC's MAX_POSITION).
MAX_POSITION = 1e9
#: The cycle hands a snapshot to the retain thread this often [s].
SNAPSHOT_PERIOD = 0.1
#: Error code of a refused file (TwinCAT: NC retain (persistent) data error).
RETAIN_ERROR_CODE = 0x4002

_PARAM_KINDS: dict[str, str] = {f.name: f.metadata["kind"] for f in fields(AxisParams)}


class RetainError(ValueError):
    """A retain file that cannot be used.

    Attributes:
        kind: ``"corrupt"`` (checksum, length or structure), ``"foreign"`` (another NC's file, or none
            of its axes is configured here) or ``"version"`` (a format version this NC cannot read).
    """

    def __init__(self, kind: str, message: str) -> None:
        super().__init__(f"{kind}: {message}")
        self.kind = kind


@dataclass(frozen=True)
class AxisRetain:
    """What is kept of one axis.

    Attributes:
        position: actual position [u] (persistent axes only), None: not kept.
        homed: StateDWord.Homed (persistent axes only), None: not kept.
        params: parameters written at run time, by TwinCAT name (``AxisVeloMax``: 400.0).
    """

    position: float | None = None
    homed: bool | None = None
    params: Mapping[str, float | bool] = field(default_factory=dict)


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
def encode_retain(data: RetainData) -> bytes:
    """The file bytes of ``data`` (header + msgpack body; axes and parameters in sorted order, so equal
    data gives equal bytes apart from ``saved_ns``)."""
    axes: dict[int, dict[str, Any]] = {}
    for axis_id in sorted(data.axes):
        a = data.axes[axis_id]
        d: dict[str, Any] = {}
        if a.position is not None:
            d["position"] = float(a.position)
        if a.homed is not None:
            d["homed"] = bool(a.homed)
        if a.params:
            d["params"] = {k: (v if isinstance(v, bool) else float(v)) for k, v in sorted(a.params.items())}
        axes[int(axis_id)] = d
    body = msgpack.packb({"nc": data.nc_name, "saved_ns": int(data.saved_ns), "axes": axes}, use_bin_type=True)
    return _HEADER.pack(MAGIC, FORMAT_VERSION, len(body), hashlib.sha256(body).digest()) + body


def parse_retain(raw: bytes, nc_name: str, axis_ids: Collection[int]) -> RetainData:
    """Check and decode a retain file written by :func:`encode_retain`.

    Never raises anything but :class:`RetainError`, whatever ``raw`` holds (a fuzz target).

    Args:
        raw: the file's bytes.
        nc_name: this NC's name; a file of another NC is foreign.
        axis_ids: this NC's axes; a file with axes of which none is configured here is foreign
            (axes of the file that are not configured stay in the result: the caller reports them).

    Raises:
        RetainError: ``corrupt`` (wrong magic, truncated, checksum mismatch, not msgpack, wrong
            structure), ``version`` (unknown format version), ``foreign`` (see above).
    """
    try:
        return _parse(bytes(raw), nc_name, axis_ids)
    except RetainError:
        raise
    except Exception as exc:  # a case the checks below missed: still a refusal, never a crash
        raise RetainError("corrupt", f"unreadable ({type(exc).__name__}: {exc})") from None


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
    body = raw[_HEADER.size:]
    if length > MAX_BODY:
        raise RetainError("corrupt", f"body length {length} above {MAX_BODY}")
    if len(body) != length:
        raise RetainError("corrupt", f"truncated or padded: body has {len(body)} bytes, header says {length}")
    if hashlib.sha256(body).digest() != digest:
        raise RetainError("corrupt", "checksum mismatch (sha256 of the body)")
    try:
        doc = msgpack.unpackb(body, raw=False, strict_map_key=False, use_list=True,
                              max_str_len=MAX_BODY, max_bin_len=MAX_BODY, max_array_len=1 << 20, max_map_len=1 << 20,
                              max_ext_len=0)
    except Exception as exc:
        raise RetainError("corrupt", f"body is not msgpack ({type(exc).__name__}: {exc})") from None
    data = _structure(doc)
    if data.nc_name != nc_name:
        raise RetainError("foreign", f"written by NC {data.nc_name!r}, this is NC {nc_name!r}")
    ids = {int(a) for a in axis_ids}
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
        raise bad(f"keys {sorted(map(repr, doc))}, expected 'axes', 'nc', 'saved_ns'")
    nc, saved, axes = doc["nc"], doc["saved_ns"], doc["axes"]
    if not isinstance(nc, str) or not nc:
        raise bad(f"nc must be a non-empty string, got {nc!r}")
    if isinstance(saved, bool) or not isinstance(saved, int) or saved < 0:
        raise bad(f"saved_ns must be an integer >= 0, got {saved!r}")
    if not isinstance(axes, dict):
        raise bad(f"axes must be a map, got {type(axes).__name__}")
    out: dict[int, AxisRetain] = {}
    for axis_id, a in axes.items():
        if isinstance(axis_id, bool) or not isinstance(axis_id, int) or not 1 <= axis_id <= 65535:
            raise bad(f"axis id {axis_id!r} is not an integer 1..65535")
        where = f"axis {axis_id}"
        if not isinstance(a, dict) or not set(a) <= {"position", "homed", "params"}:
            raise bad(f"{where}: expected a map with position, homed, params")
        pos = a.get("position")
        if pos is not None:
            if not _is_number(pos) or not abs(pos) < MAX_POSITION:
                raise bad(f"{where}: position {pos!r} is not a number within +/-{MAX_POSITION:g}")
            pos = float(pos)
        homed = a.get("homed")
        if homed is not None and not isinstance(homed, bool):
            raise bad(f"{where}: homed {homed!r} is not a boolean")
        params = a.get("params", {})
        if not isinstance(params, dict):
            raise bad(f"{where}: params must be a map")
        clean: dict[str, float | bool] = {}
        for name, v in params.items():
            if not isinstance(name, str) or not name:
                raise bad(f"{where}: parameter name {name!r} is not a string")
            if not (isinstance(v, bool) or _is_number(v)):
                raise bad(f"{where}: parameter {name} = {v!r} is not a finite number or a boolean")
            clean[name] = v if isinstance(v, bool) else float(v)
        out[axis_id] = AxisRetain(pos, homed, clean)
    return RetainData(nc, out, saved)


def _is_number(v: Any) -> bool:
    return not isinstance(v, bool) and isinstance(v, (int, float)) and math.isfinite(v)


# ---- the file ---------------------------------------------------------------------------------
def write_atomic(path: str | os.PathLike[str], data: bytes) -> None:
    """Replace ``path`` by ``data`` so that a crash at any point leaves either the old or the new file.

    Writes ``<path>.tmp`` in the same directory, fsyncs it, ``os.replace``s it over ``path`` and
    fsyncs the directory (the rename itself is then durable). One fixed temporary name: a crash
    leaves at most one stale ``.tmp``, which the next write replaces.

    Raises:
        OSError: the write failed (the temporary file is removed, ``path`` is untouched).
    """
    p = Path(path)
    tmp = p.with_name(p.name + ".tmp")
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC | getattr(os, "O_CLOEXEC", 0), 0o644)
    try:
        try:
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
    dfd = os.open(p.parent, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0))
    try:
        os.fsync(dfd)
    finally:
        os.close(dfd)


def _set_aside(path: Path) -> Path:
    """Rename a refused file to ``<path>.rejected`` (or ``.rejected.N``: an older one is kept)."""
    target = path.with_name(path.name + ".rejected")
    n = 0
    while target.exists():
        n += 1
        target = path.with_name(f"{path.name}.rejected.{n}")
    os.rename(path, target)
    return target


# ---- the server's part ------------------------------------------------------------------------
@dataclass
class _Snapshot:
    """What the cycle hands over: copies of the columns, references to the parameter objects."""

    act_pos: np.ndarray
    homed: np.ndarray
    params: tuple[AxisParams, ...]
    time_ns: int


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


class RetainKeeper:
    """Load the retain file at startup, keep it up to date while the NC runs (one thread).

    Args:
        path: the retain file (its directory must exist).
        nc_name: this NC's name (written into the file, checked when loading).
        core: the NcCore; its parameters now are the configured base.
    """

    def __init__(self, path: str | os.PathLike[str], nc_name: str, core: Any) -> None:
        self.path = Path(path)
        self.nc_name = nc_name
        self.axis_ids = [int(a) for a in np.asarray(core.axis_ids).tolist()]
        self._base: tuple[AxisParams, ...] = tuple(core.params)  # replaced on every write, never changed
        self._period_cycles = max(1, round(SNAPSHOT_PERIOD / float(core.cycle_time)))
        self._due = 0
        self._pending: _Snapshot | None = None
        self._wake = threading.Event()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._written: RetainData | None = None
        self._write_lock = threading.Lock()  # the retain thread and stop()'s final write never overlap
        self._last_error = ""
        self.writes = 0  # files written
        self.write_errors = 0  # writes that failed (logged once per kind of failure)
        self.loaded: RetainData | None = None  # what load() applied
        self.rejected: Path | None = None  # where load() put a refused file

    # -- startup (before the cycle starts) -------------------------------------------------------
    def load(self, core: Any) -> RetainData | None:
        """Read the file and apply it to ``core`` (axes disabled, no cycle running).

        A missing file is the first start; a refused one is logged (0x4002) and set aside. Never raises
        for the file's content.

        Returns:
            what was applied, or None (no file, refused, unreadable).
        """
        path = self.path
        try:
            with open(path, "rb") as f:
                raw = f.read(_HEADER.size + MAX_BODY + 1)
        except FileNotFoundError:
            log.info("retain file %s does not exist yet: the NC starts with its configuration", path)
            return None
        except OSError as exc:
            log.error("retain file %s: 0x%04X NC retain data error: cannot read it (%s); the NC starts with "
                      "its configuration", path, RETAIN_ERROR_CODE, exc.strerror or exc)
            return None
        try:
            data = parse_retain(raw, self.nc_name, self.axis_ids)
        except RetainError as exc:
            try:
                aside = _set_aside(path)
                kept = f"kept as {aside}"
                self.rejected = aside
            except OSError as oe:
                kept = f"could not be renamed ({oe.strerror or oe}): it will be overwritten"
            log.error("retain file %s refused: 0x%04X NC retain data error: %s; the NC starts with its "
                      "configuration; the file is %s", path, RETAIN_ERROR_CODE, exc, kept)
            return None
        self._apply(core, data)
        self.loaded = data
        return data

    def _apply(self, core: Any, data: RetainData) -> None:
        known = set(self.axis_ids)
        for axis_id in sorted(set(data.axes) - known):
            log.warning("retain file %s: axis %d is not configured: skipped", self.path, axis_id)
        # parameters first (AxisEnDataPersistence may be one of them); a pass that fails on an order
        # dependence (AxisMinSoftPosLimit < AxisMaxSoftPosLimit) is retried after the others
        n_params = 0
        for axis_id in sorted(known.intersection(data.axes)):
            todo: list[tuple[str, int, float | bool]] = []
            for name, value in data.axes[axis_id].params.items():
                number = param_number(name)
                if number is None:
                    code = ErrorCodes.ADSERR_DEVICE_INVALIDOFFSET
                    log.warning("retain file %s: axis %d parameter %s = %r skipped: 0x%04X %s (no such "
                                "MC_AxisPara)", self.path, axis_id, name, value, code, error_name(code))
                    continue
                todo.append((name, number, value))
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
                if len(left) == len(todo):
                    break
                todo = left
            for name, r in failed.items():
                log.warning("retain file %s: axis %d parameter %s = %r skipped (the configuration rejects it): "
                            "0x%04X %s", self.path, axis_id, name, data.axes[axis_id].params[name],
                            int(r["error"]), r.get("text", ""))
        restored: list[int] = []
        for axis_id in sorted(known.intersection(data.axes)):
            a = data.axes[axis_id]
            i = self.axis_ids.index(axis_id)
            if a.position is None and a.homed is None:
                continue
            if not core.params[i].AxisEnDataPersistence:
                log.warning("retain file %s: axis %d is not persistent (AxisEnDataPersistence FALSE): its "
                            "position and homed flag are not restored", self.path, axis_id)
                continue
            steps: list[tuple[str, dict[str, Any]]] = []
            if a.position is not None:
                steps.append(("SetActualPosition", {"Position": a.position}))
            if a.homed is not None:
                steps.append(("SetReferenceFlag", {"ReferenceFlag": a.homed}))
            for cmd, args in steps:
                r = _command(core, axis_id, cmd, **args)
                if r.get("error"):
                    log.warning("retain file %s: axis %d %s %s skipped: 0x%04X %s", self.path, axis_id, cmd, args,
                                int(r["error"]), r.get("text", ""))
            restored.append(axis_id)
        saved = time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(data.saved_ns / 1e9)) if data.saved_ns else "?"
        log.info("retain file %s loaded (saved %s): positions and homed flags of axes %s, %d parameter(s)",
                 self.path, saved, restored or "none", n_params)

    # -- running ---------------------------------------------------------------------------------
    def start(self) -> None:
        """Start the retain thread (it writes the file when a snapshot differs from the file)."""
        if self._thread is None:
            self._stop.clear()
            self._thread = threading.Thread(target=self._run, name="nc-retain", daemon=True)
            self._thread.start()

    def tick(self, core: Any) -> None:
        """Cycle thread, every cycle: hand a snapshot over every SNAPSHOT_PERIOD (no I/O, no encoding)."""
        if core.cycle < self._due:
            return
        self._due = core.cycle + self._period_cycles
        self._pending = self._snapshot(core)
        self._wake.set()

    def _snapshot(self, core: Any) -> _Snapshot:
        return _Snapshot(np.array(core.act_pos, dtype=float), core.axes.homed.copy(), tuple(core.params),
                         time.time_ns())

    def stop(self, core: Any | None = None) -> None:
        """End the retain thread; with ``core`` (its cycle ended) write its final state first (idempotent)."""
        t = self._thread
        self._thread = None
        if t is not None:
            self._stop.set()
            self._wake.set()
            t.join(10)
        if core is not None:
            self._write(self._snapshot(core))

    def _run(self) -> None:
        while True:
            self._wake.wait()
            self._wake.clear()
            snap, self._pending = self._pending, None
            if snap is not None:
                self._write(snap)
            if self._stop.is_set():
                return

    def data_of(self, snap: _Snapshot) -> RetainData:
        """The file content of a snapshot (retain thread)."""
        axes: dict[int, AxisRetain] = {}
        for i, axis_id in enumerate(self.axis_ids):
            p, base = snap.params[i], self._base[i]
            changed: dict[str, float | bool] = {}
            if p is not base:
                for name in _PARAM_KINDS:
                    v = getattr(p, name)
                    if v != getattr(base, name):
                        changed[name] = v
            if p.AxisEnDataPersistence:
                axes[axis_id] = AxisRetain(float(snap.act_pos[i]), bool(snap.homed[i]), changed)
            elif changed:
                axes[axis_id] = AxisRetain(None, None, changed)
        return RetainData(self.nc_name, axes, snap.time_ns)

    def _write(self, snap: _Snapshot) -> None:
        if not self._write_lock.acquire(timeout=10.0):  # a write hanging on a dead disk: give up on this one
            log.error("retain file %s: 0x%04X NC retain data error: a write hangs; this state is not kept",
                      self.path, RETAIN_ERROR_CODE)
            return
        try:
            self._write_locked(snap)
        finally:
            self._write_lock.release()

    def _write_locked(self, snap: _Snapshot) -> None:
        try:
            data = self.data_of(snap)
            if data == self._written and self.path.exists():
                return
            write_atomic(self.path, encode_retain(data))
        except Exception as exc:  # a full disk must not end the NC: say it once per kind of failure
            self.write_errors += 1
            msg = f"{type(exc).__name__}: {exc}"
            if msg != self._last_error:
                self._last_error = msg
                log.error("retain file %s: 0x%04X NC retain data error: cannot write it (%s); retrying with "
                          "the next change", self.path, RETAIN_ERROR_CODE, msg)
            self._written = None
            return
        if self._last_error:
            log.info("retain file %s written again", self.path)
            self._last_error = ""
        self._written = data
        self.writes += 1
