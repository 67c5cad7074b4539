"""Hot-standby replication of an NC (pure: no zenoh, no threads, no clocks; docs/standby.md).

State-machine replication: the core is pure and cycle-stepped, so a standby core fed with the same inputs in the
same order reaches the same state. The active NC wraps its core in a :class:`CoreRecorder` (every call that
changes the core is noted) and its drives in a :class:`RecordingDrive` (everything the core reads from the
drives is noted); per cycle :meth:`CoreRecorder.take` gives one :class:`CycleLog`: the calls applied before and
in that step, the drive's answers, the handler's changes (claims, reply cache) and a digest of the state after
the step. A :class:`Follower` replays the logs on its own core with a :class:`ReplayDrive` (it drives nothing)
and compares the digests; on a gap or a different digest it asks for a :func:`snapshot` and restarts from it.

A snapshot is the pickled core (its drive replaced by a :class:`ReplayDrive` with the drive's current answers),
the claim table, the reply cache and the handler's bookkeeping. It is exchanged between the two NC processes
only (the ha keys' access rules: docs/standby.md); never unpickle data from anyone else.
"""
from __future__ import annotations

import collections
import copy
import ctypes
import hashlib
import io
import operator
import pickle
import pickletools
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np

#: the drive attributes the core reads (DriveABC's); noted after every recorded drive call
DRIVE_STATE = ("act_pos", "act_velo", "act_acc", "ready", "io_valid", "device_error", "following", "comm_error",
               "error_code", "input_age", "faulty")
#: the drive's DRIVE_STATE values, as a tuple
_drive_state = operator.attrgetter(*DRIVE_STATE)
#: the drive methods the core calls; their results (and the drive's state after them) are noted
DRIVE_CALLS = frozenset(("step", "configure", "reset", "set_torque_offset", "torque_fields", "latch_sync_pulse",
                         "probe_input", "arm_probe", "latch_probe", "set_probe_signal", "terminal_status", "set_stall",
                         "set_terminal_error"))


#: logs a follower keeps while it waits for a snapshot (a snapshot older than the newest of them is caught up)
HELD_LOGS = 2048


class ReplicationError(Exception):
    """A log that does not fit the follower's core (a gap, another call order, a different digest): re-sync
    from a snapshot."""


# ---- the software fingerprint: a pair runs one NC software (docs/standby.md, "One software version") ----------

#: bumped when the wire format of snapshots and logs changes in a way the sources alone would not show
REPLICATION_FORMAT = 1


def _modules(base: Path) -> list[Path]:
    """The modules under ``base``: each one's .py, or where an install has no source (bytecode only) its .pyc beside
    it (never __pycache__'s: those are of each interpreter, the .py is there)."""
    py = {p.with_suffix("") for p in base.rglob("*.py")}
    return sorted([p.with_suffix(".py") for p in py]
                  + [p for p in base.rglob("*.pyc") if p.parent.name != "__pycache__" and p.with_suffix("") not in py])


def _fingerprint_files() -> list[tuple[str, Path]]:
    """The sources whose objects (or whose layouts) snapshots and logs carry: the core, the drives, the replication
    itself, the handler state it pickles (claims, reply cache) and the contract (nc_schema: the records' dtypes)."""
    import nc_schema.layout  # (nc_schema imports nothing of nc_server: no cycle)

    pkg = Path(__file__).resolve().parents[1]  # nc_server
    schema = Path(nc_schema.layout.__file__).resolve().parent
    files = [("nc_server", pkg, p) for sub in ("core", "drives") for p in _modules(pkg / sub)]
    files += [("nc_server", pkg, p) for p in _modules(pkg / "server") if p.stem in ("replication", "claims", "handler")]
    files += [("nc_schema", schema, p) for p in _modules(schema)]
    contract = Path(str(nc_schema.layout.CONTRACT_DIR))
    files += [("contract", contract, p) for p in contract.glob("*.json")]
    # (named relative to their package: the same software installed elsewhere has the same fingerprint)
    return sorted((f"{top}/{p.relative_to(base).as_posix()}", p) for top, base, p in files)


def _fingerprint() -> str:
    """Sources hashed with CRLF as LF (a Windows checkout pairs with a Linux one); a bytecode-only install's .pyc
    without its 16-byte header (its timestamp); a file that cannot be read, or a failure of the whole, falls back to
    the package version (never a failure at import: the pair then pairs up on the version, not the code)."""
    h = hashlib.sha256(f"zenoh-nc replication format {REPLICATION_FORMAT}\n".encode())
    try:
        files = _fingerprint_files()
    except Exception as exc:
        files = []
        h.update(f"no sources ({exc.__class__.__name__}): version {_version()}\n".encode())
    for name, p in files:
        try:
            data = p.read_bytes()
            data = data[16:] if p.suffix == ".pyc" else data.replace(b"\r\n", b"\n")
        except OSError:
            data = f"missing: version {_version()}".encode()
        h.update(f"{name}\0{len(data)}\0".encode())
        h.update(data)
    return h.hexdigest()


def _version() -> str:
    try:
        from importlib.metadata import version
        return version("zenoh-nc")
    except Exception:
        return "unknown"


#: sha256 (hex) of REPLICATION_FORMAT and the sources of :func:`_fingerprint_files`, computed once at import: a
#: snapshot or log sample stamped with another one comes from other NC software and is never unpickled
FINGERPRINT = _fingerprint()
#: the stamp before every snapshot and log sample: a tag and the fingerprint's 32 bytes
_TAG = b"zncR"
STAMP = _TAG + bytes.fromhex(FINGERPRINT)


class SoftwareMismatch(ReplicationError):
    """The peer NC runs other NC software (another fingerprint, or none: a release before the stamp).

    Attributes:
        theirs: the peer's fingerprint (hex; "" when its data carries none).
    """

    def __init__(self, theirs: str, what: str = "snapshot") -> None:
        self.theirs = theirs
        super().__init__(f"a {what} of NC software {theirs[:12] or 'unknown (unstamped)'}, this NC runs "
                         f"{FINGERPRINT[:12]}: a pair must run the same NC software, it is not loaded")


def stamp(data: bytes) -> bytes:
    """``data`` (a pickle) behind this NC's :data:`STAMP`."""
    return STAMP + data


def peer_fingerprint(data: bytes) -> str:
    """The fingerprint (hex) a stamped ``data`` carries; "" when it has no stamp."""
    n = len(STAMP)
    return data[len(_TAG):n].hex() if len(data) >= n and data.startswith(_TAG) else ""


def unstamp(data: bytes, what: str = "snapshot") -> bytes:
    """The pickle behind the stamp of ``data``, checked before anything of it is unpickled.

    Raises:
        SoftwareMismatch: ``data`` is not stamped with this NC's fingerprint.
    """
    if not data.startswith(STAMP):
        raise SoftwareMismatch(peer_fingerprint(data), what)
    return data[len(STAMP):]


class _PlainUnpickler(pickle.Unpickler):
    def find_class(self, module: str, name: str) -> Any:
        raise pickle.UnpicklingError(f"{module}.{name} in plain data")


def loads_plain(data: bytes, bounded: bool = False) -> Any:
    """Unpickle builtins only (no class, no function: nothing of any release's code), e.g. a log sample's
    (epoch, cycle, bytes) headers of a peer of other software. ``bounded``: first walk the opcodes (pickletools reads
    a counted argument only as far as ``data`` goes): a size beyond ``data`` raises instead of the unpickler
    allocating it first (BINBYTES8 of 8 GiB in a 12-byte pickle)."""
    if bounded:
        for _ in pickletools.genops(data):
            pass
    return _PlainUnpickler(io.BytesIO(data)).load()


def state_digest(core: Any) -> int:
    """64-bit digest of what the PLC sees and what continues the jobs: NCTOPLC, the job records, the applied
    PLCTONC and the set-point state of every axis (positions, velocities, accelerations)."""
    h = hashlib.blake2b(digest_size=8)
    h.update(core.nctoplc.tobytes())
    h.update(core.ncjobs.tobytes())
    h.update(core.plctonc.tobytes())
    a = core.axes
    for col in (a.set_pos, a.set_velo, a.set_acc):
        h.update(np.ascontiguousarray(col).tobytes())
    h.update(int(core.cycle).to_bytes(8, "little", signed=True))
    return int.from_bytes(h.digest(), "little")


def _copy(v: Any) -> Any:
    if isinstance(v, np.ndarray):
        return v.copy()
    if isinstance(v, tuple):
        return tuple(_copy(x) for x in v)
    return v


def _copy_or(v: Any, prev: Any) -> Any:
    """``v`` copied (:func:`_copy`), or ``prev`` itself when it is an array of the same dtype, shape and bytes: the
    drive's state after each call of a cycle is mostly the state after the one before, and pickle writes an object
    referenced again only once (a log held 44 arrays, pickled and unpickled every cycle, where 11 differ)."""
    if isinstance(v, np.ndarray):
        if (isinstance(prev, np.ndarray) and prev.dtype == v.dtype and prev.shape == v.shape
                and prev.tobytes() == v.tobytes()):
            return prev
        return v.copy()
    return _copy(v)


@dataclass(slots=True)
class DriveCall:
    """One drive call the core made: its name, its result and the drive's state after it (DRIVE_STATE order)."""

    name: str
    result: Any
    state: tuple[Any, ...]


class RecordingDrive:
    """The active NC's drive: forwards everything to ``drive`` and notes each call of :data:`DRIVE_CALLS` with
    its result and the drive's state after it (:attr:`tape`, emptied by :meth:`CoreRecorder.take`)."""

    def __init__(self, drive: Any) -> None:
        self.__dict__["inner"] = drive
        self.__dict__["tape"] = []

    def __getattr__(self, name: str) -> Any:
        value = getattr(self.inner, name)
        if name in DRIVE_CALLS:
            def call(*args: Any, **kwargs: Any) -> Any:
                result = value(*args, **kwargs)
                now = _drive_state(self.inner)
                if self.tape:  # (the values the call before left unchanged: the same objects, pickled once)
                    state = tuple(map(_copy_or, now, self.tape[-1].state))
                else:
                    state = tuple(map(_copy, now))
                self.tape.append(DriveCall(name, _copy(result), state))
                return result
            return call
        return value

    def __setattr__(self, name: str, value: Any) -> None:
        setattr(self.inner, name, value)


class ReplayDrive:
    """The standby's drive: answers the core's calls from the active NC's tape (:meth:`feed`), in order;
    commands nothing. A call the tape does not have next raises :class:`ReplicationError`.

    Args:
        state: the drive's state (DRIVE_STATE order) to start from.
        simulated_axes: per axis, its drive is simulated (OpModeDWord).
    """

    simulated = False

    def __init__(self, state: tuple[Any, ...], simulated_axes: np.ndarray, cycle_time: float) -> None:
        self.cycle_time = cycle_time
        self._simulated = np.asarray(simulated_axes, dtype=bool).copy()
        self._tape: list[DriveCall] = []
        self._at = 0
        self._set(state)

    @classmethod
    def of(cls, drive: Any) -> ReplayDrive:
        """A replay drive in ``drive``'s current state (for a snapshot)."""
        inner = getattr(drive, "inner", drive)
        return cls(tuple(_copy(getattr(inner, s)) for s in DRIVE_STATE), inner.simulated_axes, inner.cycle_time)

    @property
    def simulated_axes(self) -> np.ndarray:
        return self._simulated

    def _set(self, state: tuple[Any, ...], prev: tuple[Any, ...] | None = None) -> None:
        """The drive's state after a call; ``prev``: the state of the call before on the same tape (set then): its
        objects that the log shares with ``state`` (the values that call left unchanged, :func:`_copy_or`) are
        set already (the core only reads the drive's arrays)."""
        for name, v, p in zip(DRIVE_STATE, state, prev or state):
            if prev is None or v is not p:
                # (new objects: the core keeps the previous act_pos array as its prev_act_pos)
                setattr(self, name, _copy(v))

    def feed(self, calls: list[DriveCall]) -> None:
        """The drive calls of the next cycle's log."""
        self._tape = calls
        self._at = 0

    def pending(self) -> int:
        """Calls of the fed tape not made yet (0 after a faithful replay)."""
        return len(self._tape) - self._at

    def __getattr__(self, name: str) -> Any:
        if name not in DRIVE_CALLS:
            raise AttributeError(name)

        def call(*args: Any, **kwargs: Any) -> Any:
            if self._at >= len(self._tape) or self._tape[self._at].name != name:
                got = self._tape[self._at].name if self._at < len(self._tape) else "nothing"
                raise ReplicationError(f"the core called drive.{name}, the log has {got} next")
            c = self._tape[self._at]
            self._set(c.state, self._tape[self._at - 1].state if self._at else None)
            self._at += 1
            return _copy(c.result)
        return call

    def close(self) -> None:
        """Nothing to close (it drives nothing)."""


@dataclass(slots=True)
class CycleLog:
    """What the active NC's core did in one cycle (the ``nc/<nc>/ha/log`` sample).

    Attributes:
        cycle: the cycle the step completed (``core.cycle`` after it).
        calls: the core calls before and including the step, in order: (name, args).
        drive: the drive's answers in this cycle, in order.
        digest: :func:`state_digest` after the step.
        handler: the handler's changes: reply-cache entries put or clients forgotten, in order; the claim
            table when it changed; the handler's bookkeeping (pickled: see :class:`HandlerState`).
        epoch: the active NC's epoch.
    """

    cycle: int
    calls: list[tuple[str, tuple[Any, ...]]]
    drive: list[DriveCall]
    digest: int
    handler: bytes = b""
    epoch: int = 0


#: the core methods that change it (the replayed ones); everything else is read through
_RECORDED = ("execute", "prepare", "activate", "set_plctonc", "set_plctonc_many", "set_remote_samples", "fault",
             "set_preparing", "inputs_changed", "write_parameter", "step")


class CoreRecorder:
    """The active NC's core as the server sees it: every call that changes the core is noted before it is
    forwarded, everything else is read through. The drive is wrapped in a :class:`RecordingDrive`.

    Only the outermost call is noted (the core's internal calls, e.g. execute -> prepare, are replayed by it).
    ``prepare`` is noted only when it ran the command (its reply is a map); an ``activate`` that happened is
    noted as its request, prepared and activated again on the follower (its prediction held: the same state).
    """

    def __init__(self, core: Any) -> None:
        d = self.__dict__
        d["core"] = core
        d["calls"] = []
        d["_prepared"] = {}  # id(Prepared) -> (Prepared, request): what an activation replays
        if not isinstance(core.drive, RecordingDrive):
            core.drive = RecordingDrive(core.drive)
        d["drive"] = core.drive

    def __getattr__(self, name: str) -> Any:
        return getattr(self.core, name)

    def __setattr__(self, name: str, value: Any) -> None:
        setattr(self.core, name, value)

    def attach_drive(self, drive: RecordingDrive | None) -> None:
        """The core's drive changed (a takeover: the real drives, recorded; a demotion: None, nothing recorded)."""
        self.__dict__["drive"] = drive if drive is not None else RecordingDrive(None)

    def execute(self, request: dict[str, Any], axis_id: int | None) -> dict[str, Any]:
        self.calls.append(("execute", (copy.deepcopy(request), axis_id)))
        return dict(self.core.execute(request, axis_id))

    def prepare(self, request: dict[str, Any], axis_id: int | None) -> Any:
        mark = len(self.drive.tape)
        at = len(self.calls)
        req = copy.deepcopy(request)  # (as it came: the core may add to it)
        got = self.core.prepare(request, axis_id)
        if isinstance(got, dict):  # it ran (or was refused) now: replay it the same way
            self.calls.insert(at, ("prepare", (req, axis_id)))
        elif len(self.drive.tape) != mark:  # (a preparation reads no drive; never expected)
            raise ReplicationError("a preparation called the drive")
        else:
            self._prepared[id(got)] = (got, req)
        return got

    def activate(self, prepared: Any) -> dict[str, Any] | None:
        # noted before it runs: the drive calls it makes belong after it in the log
        at = len(self.calls)
        entry = self._prepared.pop(id(prepared), None)
        if entry is None or entry[0] is not prepared:
            raise ReplicationError("activating a command not prepared through the recorder")
        self.calls.append(("activate", (entry[1], prepared.i)))
        reply = self.core.activate(prepared)
        if reply is None:  # its prediction failed: nothing changed, nothing to replay
            del self.calls[at]
        return reply

    def set_plctonc(self, index: int, record: Any) -> None:
        self.calls.append(("set_plctonc", (int(index), np.asarray(record).tobytes())))
        self.core.set_plctonc(index, record)

    def set_plctonc_many(self, index: np.ndarray, records: np.ndarray) -> None:
        self.calls.append(("set_plctonc_many", (np.array(index), np.array(records))))
        self.core.set_plctonc_many(index, records)

    def set_remote_samples(self, samples: Any) -> None:
        # the remote masters' samples (coupling across NCs) are an input like PLCTONC: the standby gets them
        # from the log, never from its own subscription (it would see other samples at other times)
        samples = list(samples)
        self.calls.append(("set_remote_samples", (samples,)))
        self.core.set_remote_samples(samples)

    def fault(self, i: int, code: int) -> None:
        self.calls.append(("fault", (int(i), int(code))))
        self.core.fault(i, code)

    def set_preparing(self, axis_id: int, on: bool) -> None:
        self.calls.append(("set_preparing", (int(axis_id), bool(on))))
        self.core.set_preparing(axis_id, on)

    def inputs_changed(self) -> None:
        self.calls.append(("inputs_changed", ()))
        self.core.inputs_changed()

    def write_parameter(self, i: int, number: int, value: float | bool) -> None:
        self.calls.append(("write_parameter", (int(i), int(number), value)))
        self.core.write_parameter(i, number, value)

    def step(self, nc_time_ns: int | None = None) -> None:
        if self._prepared:  # (preparations refused, never activated: stale after this step)
            for k in [k for k, (p, _) in self._prepared.items() if p.cycle <= self.core.cycle + 1]:
                del self._prepared[k]
        self.core.step(nc_time_ns)
        self.calls.append(("step", (int(self.core.nc_time_ns),)))

    def take(self, handler: bytes = b"", epoch: int = 0) -> CycleLog:
        """The log of the cycle just stepped (the calls and drive answers since the last take)."""
        log = CycleLog(int(self.core.cycle), list(self.calls), list(self.drive.tape), state_digest(self.core),
                       handler, epoch)
        self.calls.clear()
        self.drive.tape.clear()
        return log


def replay(core: Any, log: CycleLog) -> None:
    """Apply one cycle's log to a follower's core (its drive a :class:`ReplayDrive`).

    Raises:
        ReplicationError: the log is not the next cycle, the core's calls do not match the log, or the digest
            after the step differs (the follower must re-sync from a snapshot).
    """
    if log.cycle != core.cycle + 1:
        raise ReplicationError(f"log of cycle {log.cycle}, the follower is at {core.cycle}")
    drive = core.drive
    if not isinstance(drive, ReplayDrive):
        raise ReplicationError("the follower's drive is not a ReplayDrive")
    drive.feed(log.drive)
    for name, args in log.calls:
        if name == "activate":
            request, i = args
            got = core.prepare(copy.deepcopy(request), int(core.axis_ids[i]))
            if isinstance(got, dict) or core.activate(got) is None:
                raise ReplicationError(f"cycle {log.cycle}: {request.get('cmd')} did not activate as on the active NC")
        elif name == "set_plctonc_many":
            core.set_plctonc_many(*args)
        elif name == "step":
            core.step(args[0])
        elif name in ("execute", "prepare"):
            getattr(core, name)(copy.deepcopy(args[0]), args[1])
        else:
            getattr(core, name)(*args)
    if drive.pending():
        raise ReplicationError(f"cycle {log.cycle}: {drive.pending()} drive calls of the log were not made")
    got = state_digest(core)
    if got != log.digest:
        raise ReplicationError(f"cycle {log.cycle}: state digest {got:016x}, the active NC's {log.digest:016x}")


# ---- snapshots: pickling that keeps numpy views views ----------------------------------------------------------

def _owner(a: Any) -> Any:
    """The object that owns ``a``'s memory (through numpy bases and memoryviews)."""
    b: Any = a
    while True:
        if isinstance(b, memoryview):
            b = b.obj
        elif isinstance(b, np.ndarray) and b.base is not None:
            b = b.base
        else:
            return b


def _view(buf: bytearray, offset: int, shape: tuple[int, ...], strides: tuple[int, ...], dtype: np.dtype) -> np.ndarray:
    return np.ndarray(shape, dtype, buffer=buf, offset=offset, strides=strides)


def _memview(a: np.ndarray) -> memoryview:
    return a.data


class _Pickler(pickle.Pickler):
    """Pickles every ndarray as a window on its memory owner's bytes, each owner's bytes once: arrays that share
    memory (the core's columns of one table, the job records' byte view, views of views) share it after loading,
    whatever generation of snapshot the core comes from. ``root`` (the core) is pickled as a reference: its state is
    pickled beside it and loaded into whichever core the follower has (:func:`load_snapshot`)."""

    def __init__(self, file: io.BytesIO, root: Any = None) -> None:
        super().__init__(file, protocol=pickle.HIGHEST_PROTOCOL)
        self.root = root
        self._buffers: dict[int, tuple[bytearray, int, Any]] = {}  # id(owner) -> (its bytes, address, owner)

    def persistent_id(self, obj: Any) -> Any:
        return "core" if self.root is not None and obj is self.root else None

    def reducer_override(self, obj: Any) -> Any:
        if isinstance(obj, memoryview) and isinstance(obj.obj, np.ndarray):
            return _memview, (obj.obj,)
        if isinstance(obj, np.ndarray) and obj.size and not obj.dtype.hasobject:
            owner = _owner(obj)
            got = self._buffers.get(id(owner))
            if got is None:
                if isinstance(owner, np.ndarray):
                    if not (owner.flags.c_contiguous or owner.flags.f_contiguous):
                        return NotImplemented
                    addr, size = owner.ctypes.data, owner.nbytes
                elif isinstance(owner, (bytearray, bytes)):
                    addr, size = np.frombuffer(owner, dtype=np.uint8).ctypes.data, len(owner)
                else:
                    return NotImplemented
                got = self._buffers[id(owner)] = (bytearray(ctypes.string_at(addr, size)), addr, owner)
            return _view, (got[0], obj.ctypes.data - got[1], obj.shape, obj.strides, obj.dtype)
        return NotImplemented


class _Unpickler(pickle.Unpickler):
    def __init__(self, file: io.BytesIO, root: Any) -> None:
        super().__init__(file)
        self.root = root

    def persistent_load(self, pid: Any) -> Any:
        if pid != "core":
            raise pickle.UnpicklingError(f"unknown reference {pid!r}")
        return self.root


def dumps(obj: Any, root: Any = None) -> bytes:
    """Pickle ``obj`` keeping numpy views (see :class:`_Pickler`)."""
    buf = io.BytesIO()
    _Pickler(buf, root).dump(obj)
    return buf.getvalue()


def loads(data: bytes, root: Any = None) -> Any:
    """The object of :func:`dumps` (only from the peer NC: it is pickle)."""
    return _Unpickler(io.BytesIO(data), root).load()


@dataclass(slots=True)
class HandlerState:
    """What of the request handler a standby keeps in step (a snapshot's, or a log's changes).

    Attributes:
        cache: reply-cache changes in order: ("put", client, id, packed) or ("forget", client).
        claims: the claim table when it changed (None: unchanged).
        seen, last_command: the handler's bookkeeping (None: unchanged).
        instance: the NC instance id its clients follow (a snapshot's; a standby that takes over keeps it).
    """

    cache: list[tuple[Any, ...]] = field(default_factory=list)
    claims: Any = None
    seen: dict[str, int] | None = None
    last_command: dict[int, tuple[str, str, int]] | None = None
    instance: str = ""


def snapshot(core: Any, handler_state: Any = None) -> bytes:
    """A snapshot of ``core`` (unwrapped from its recorder; its drive as a :class:`ReplayDrive`) and the
    handler's state (any picklable object), to start a follower from: the core's class, then its state and the
    handler's (references to the core inside its state are loaded as the core that receives it)."""
    inner = getattr(core, "core", core)
    drive = inner.drive
    inner.drive = ReplayDrive.of(drive)
    try:
        return stamp(pickle.dumps((type(inner), dumps((dict(inner.__dict__), handler_state), root=inner)),
                                  protocol=pickle.HIGHEST_PROTOCOL))
    finally:
        inner.drive = drive


def load_snapshot(data: bytes, into: Any = None) -> tuple[Any, Any]:
    """(core, handler state) of a :func:`snapshot`; the core's state goes into ``into`` (the same object stays the
    core: whatever holds it, holds the snapshot's), else into a new core of the snapshot's class.

    Raises:
        SoftwareMismatch: the snapshot is of other NC software (checked before anything is unpickled).
    """
    cls, body = pickle.loads(unstamp(data))
    if into is not None and type(into) is not cls:
        raise ReplicationError(f"a snapshot of a {cls.__name__}, the follower has a {type(into).__name__}")
    core = into if into is not None else cls.__new__(cls)
    state, hs = loads(body, root=core)
    core.__dict__.clear()
    core.__dict__.update(state)
    return core, hs


class Follower:
    """A standby's core, kept in step with the active NC's logs.

    Args:
        on_resync: called with the reason when the follower needs a snapshot (a gap, a divergence).

    Attributes:
        core: the follower's core (None until the first snapshot).
        handler_state: the replicated handler state (the snapshot's, updated by the logs' changes).
        applied, resyncs: cycles replayed and snapshots taken.
        lag: the newest log's cycle less the follower's (cycles).
    """

    def __init__(self, on_resync: Callable[[str], None] | None = None,
                 on_handler: Callable[[Any, bytes], None] | None = None, core: Any = None) -> None:
        #: the core snapshots are loaded into (None: a new one at each snapshot)
        self.into = core
        self.core: Any = None
        self.handler_state: Any = None
        self.on_resync = on_resync or (lambda reason: None)
        self.on_handler = on_handler
        self.applied = 0
        self.resyncs = 0
        self.diverged = 0
        self.lag = 0
        self.epoch = 0
        self.waiting = True  # for a snapshot
        #: logs that came while waiting for a snapshot, replayed after it (at most HELD_LOGS)
        self._held: collections.deque[CycleLog] = collections.deque(maxlen=HELD_LOGS)

    def load(self, data: bytes) -> None:
        """Start from a snapshot (:func:`snapshot`)."""
        core, hs = load_snapshot(data, self.into)
        if not isinstance(core.drive, ReplayDrive):
            raise ReplicationError("a snapshot's drive must be a ReplayDrive")
        self.core, self.handler_state = core, hs
        self.resyncs += 1
        self.waiting = False
        held = list(self._held)
        self._held.clear()
        for lg in held:
            if lg.cycle <= core.cycle:  # (older than the snapshot, or a repeat)
                continue
            if not self.apply(lg):
                break

    def apply(self, log: CycleLog) -> bool:
        """Replay one log; False when it was skipped (older than the core, or waiting for a snapshot) or the
        follower fell out of step (:attr:`waiting` then: ``on_resync`` was called)."""
        self.epoch = max(self.epoch, log.epoch)
        if self.waiting or self.core is None:
            self._held.append(log)  # (the snapshot asked for may be older: these follow it)
            return False
        self.lag = log.cycle - int(self.core.cycle)
        if log.cycle <= self.core.cycle:
            return False  # (a snapshot newer than the log)
        try:
            replay(self.core, log)
        except ReplicationError as exc:
            self.lose(str(exc), diverged="digest" in str(exc))
            return False
        except Exception as exc:  # the replay met a bug: the core is unknown now
            self.lose(f"replay failed: {exc.__class__.__name__}: {exc}", diverged=True)
            return False
        self.lag = 0
        self.applied += 1
        if log.handler and self.on_handler is not None:
            self.on_handler(self.handler_state, log.handler)
        return True

    def lose(self, reason: str, diverged: bool) -> None:
        """Out of step: wait for a snapshot (``on_resync(reason)``); ``diverged``: the replay disagreed with the
        active NC (a digest, a bug), counted in :attr:`diverged`."""
        self.waiting = True
        if diverged:
            self.diverged += 1
        self.on_resync(reason)


# ---- the request handler's part ---------------------------------------------------------------------------------

class HandlerRecorder:
    """Notes what of the active NC's :class:`~nc_server.server.handler.RequestHandler` a standby needs: the
    reply cache's changes (a repeated request after a takeover gets the cached reply, it is not executed
    twice), the claim table and the last commands when they changed."""

    def __init__(self, handler: Any) -> None:
        self.handler = handler
        handler.cache.journal = []
        self._versions = (-1, -1, -1)
        self.instance = ""  # the NC instance id (nc_schema.instance), for snapshots

    def _now(self) -> tuple[int, int, int]:
        h = self.handler
        return int(h.claims.version), int(h.clients_version), int(h.commands_version)

    def full(self) -> HandlerState:
        """The whole state (for a snapshot); the journal restarts."""
        h = self.handler
        h.cache.journal = []
        self._versions = self._now()
        return HandlerState([("put", c, rid, r) for (c, rid), r in h.cache.items()], h.claims, dict(h.seen),
                            dict(h.last_command), self.instance)

    def take(self) -> bytes:
        """The changes since the last call, pickled (b"": none)."""
        h = self.handler
        st = HandlerState(list(h.cache.journal or ()))
        if h.cache.journal:
            h.cache.journal.clear()
        now = self._now()
        if now != self._versions:
            self._versions = now
            st.claims, st.seen, st.last_command = h.claims, dict(h.seen), dict(h.last_command)
        if not st.cache and st.claims is None:
            return b""
        return dumps(st)


def merge_handler(state: HandlerState, data: bytes) -> None:
    """Apply a log's handler changes (:meth:`HandlerRecorder.take`) to the replicated ``state``."""
    change: HandlerState = loads(data)
    state.cache.extend(change.cache)
    if len(state.cache) > 4 * 4096:  # (the cache is an LRU: what it has evicted need not be kept)
        del state.cache[:-4096]
    if change.claims is not None:
        state.claims, state.seen, state.last_command = change.claims, change.seen, change.last_command


def install_handler(handler: Any, state: HandlerState) -> None:
    """At a takeover: the replicated state becomes ``handler``'s (its reply cache, claims, bookkeeping)."""
    for entry in state.cache:
        if entry[0] == "put":
            handler.cache.put(entry[1], entry[2], entry[3])
        else:
            handler.cache.forget_client(entry[1])
    if state.claims is not None:  # (in place: the cycle inputs and the server share the table)
        handler.claims.__dict__.update(state.claims.__dict__)
    if state.seen is not None:
        handler.seen = dict(state.seen)
    if state.last_command is not None:
        handler.last_command = dict(state.last_command)
