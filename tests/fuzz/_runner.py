"""How the atheris fuzz targets run: the targets' list, their entry point, a byte reader, the runner.

Nothing of the project is imported here: a target imports the project inside
``atheris.instrument_imports`` (:data:`PROJECT`), which instruments only modules imported for the
first time, so this module must not have imported them before.

A target module ``tests/fuzz/fuzz_<name>.py`` defines ``test_one(data: bytes) -> None`` (raises on a
finding) and ``seeds() -> list[bytes]`` and ends with ``main("<name>", test_one, seeds)``. Run one::

    python -m tests.fuzz.fuzz_command [libFuzzer args] [CORPUS_DIR | CRASH_FILE ...]

Without a corpus directory or file argument the target fuzzes ``build/fuzz/corpus/<name>/`` (created
and seeded at start; the seeds are made from valid messages by ``seeds()``, so none are committed).
A finding is written by libFuzzer to ``-artifact_prefix`` (default here: ``build/fuzz/<name>/``) as
``crash-<sha1>`` (an exception) or ``timeout-<sha1>`` (``-timeout=S`` exceeded); passing that file
instead of a directory runs just that input again, with the traceback.
"""
from __future__ import annotations

import hashlib
import logging
import os
import re
import struct
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Sequence

#: the fuzz targets, ``tests/fuzz/fuzz_<name>.py``
TARGETS: tuple[str, ...] = ("command", "plctonc", "keys", "client", "retain", "ads")
#: the project's packages (instrumented for coverage)
PROJECT: list[str] = ["nc_schema", "nc_server", "plc_client", "nc_ads"]
ROOT = Path(__file__).resolve().parents[2]
#: default working folder of the runner (corpora, crash files): ignored by git (``build/``)
WORK = ROOT / "build" / "fuzz"
#: exit status of a target that cannot run here (e.g. the module it fuzzes does not exist yet)
SKIPPED = 5
#: exit statuses of atheris/libFuzzer: an uncaught Python exception, a -timeout
CRASHED, TIMED_OUT = 77, 70
#: names of libFuzzer's finding files (``slow-unit-*`` are not findings: -report_slow_units)
FINDINGS = ("crash-", "timeout-", "oom-", "leak-")


def instrument():  # type: ignore[no-untyped-def]
    """``with instrument(): import ...``: the project's modules imported inside are instrumented
    (``atheris.instrument_imports(include=PROJECT)``)."""
    import atheris

    _patch_cmp()
    return atheris.instrument_imports(include=PROJECT)


def _patch_cmp() -> None:
    """Work around a leak of atheris 3.0's comparison hook.

    The instrumented code calls ``atheris._trace_cmp(a, b, op, ...)`` for every comparison (looked up
    at each call); the native hook keeps a reference to its operands or result when they are not
    plain values, so every numpy array comparison in the core leaked an array (about 0.2 MB per NC
    input: a long run hit libFuzzer's RSS limit). Plain values (int, float, str, bytes, ...) still go
    to the native hook (their operands guide the fuzzer: CMP tracing); anything else is compared
    directly. ``atheris.Fuzz()`` binds the native hook again, so :func:`main` repeats this at its
    first input.
    """
    import operator

    import atheris
    from atheris.version_dependent import CMP_OP_SHIFT_AMOUNT

    current = atheris._trace_cmp
    if getattr(current, "_znc_patched", False):
        return
    ops = (operator.lt, operator.le, operator.eq, operator.ne, operator.gt, operator.ge)
    plain = frozenset((int, float, str, bytes, bool, type(None)))

    def _trace_cmp(a, b, opid, counter, is_const, native=current):  # type: ignore[no-untyped-def]
        if type(a) in plain and type(b) in plain:
            return native(a, b, opid, counter, is_const)
        return ops[opid >> CMP_OP_SHIFT_AMOUNT](a, b)

    _trace_cmp._znc_patched = True  # type: ignore[attr-defined]
    atheris._trace_cmp = _trace_cmp


class Finding(AssertionError):
    """A target's check failed (besides an exception escaping the code under test)."""


class ExceptionLog(logging.Handler):
    """Catches every log record that carries an exception (``log.exception``): the project answers
    some of its own bugs with an error reply or a fault instead of raising (e.g. 0x4000 from
    ``RequestHandler.handle``), and a target must see those as findings.

    Install once per process (:meth:`install`); :meth:`check` raises the first caught exception.
    """

    def __init__(self) -> None:
        super().__init__(logging.ERROR)
        self.caught: list[logging.LogRecord] = []

    def emit(self, record: logging.LogRecord) -> None:
        if record.exc_info and record.exc_info[1] is not None:
            self.caught.append(record)

    @classmethod
    def install(cls) -> ExceptionLog:
        """Catch exceptions logged anywhere; other log output is dropped (it would slow the fuzzer)."""
        h = cls()
        root = logging.getLogger()
        for old in list(root.handlers):
            root.removeHandler(old)
        root.addHandler(h)
        root.setLevel(logging.ERROR)
        return h

    def check(self, what: str = "") -> None:
        """Raise a :class:`Finding` chained to the first exception logged since the last check."""
        if self.caught:
            rec, self.caught = self.caught[0], []
            raise Finding(f"exception logged{' ' + what if what else ''}: {rec.getMessage()}") from rec.exc_info[1]


def main(name: str, test_one: Callable[[bytes], None], seeds: Callable[[], list[bytes]],
         argv: Sequence[str] | None = None, skip: str | None = None) -> None:
    """Entry point of one target: seed the corpus, then hand over to libFuzzer (does not return).

    Args:
        name: the target's name (its default corpus is ``build/fuzz/corpus/<name>/``).
        test_one: runs one input; any exception is a finding.
        seeds: valid inputs, written into the first corpus directory (the one libFuzzer adds to; further
            ones, e.g. committed regression inputs, are only read).
        argv: ``sys.argv`` (libFuzzer flags, corpus directories or input files).
        skip: if set, print why the target cannot run and exit with :data:`SKIPPED`.
    """
    if skip:
        print(f"fuzz_{name}: skipped: {skip}", file=sys.stderr)
        sys.exit(SKIPPED)
    import atheris

    args = list(sys.argv if argv is None else argv)
    if not any(a.startswith("-artifact_prefix=") for a in args):
        (WORK / name).mkdir(parents=True, exist_ok=True)
        args.insert(1, f"-artifact_prefix={WORK / name}{os.sep}")
    paths = [Path(a) for a in args[1:] if not a.startswith("-")]
    if not paths:
        corpus = WORK / "corpus" / name
        args.append(str(corpus))
        paths = [corpus]
    if paths[0].is_dir() or not paths[0].exists():  # the corpus libFuzzer adds to (not a file to reproduce)
        write_seeds(paths[0], seeds())

    def one(data: bytes) -> None:
        if not getattr(atheris._trace_cmp, "_znc_patched", False):
            _patch_cmp()
        test_one(data)

    atheris.Setup(args, one)
    atheris.Fuzz()


def write_seeds(folder: Path, inputs: list[bytes]) -> int:
    """Write each input as ``seed-<sha1>`` into ``folder`` (created); returns how many were new."""
    folder.mkdir(parents=True, exist_ok=True)
    n = 0
    for data in inputs:
        f = folder / f"seed-{hashlib.sha1(data).hexdigest()}"
        if not f.exists():
            f.write_bytes(data)
            n += 1
    return n


class Reader:
    """Consumes a fuzz input field by field; past its end every field reads as zero.

    The structured targets decode their inputs with it, and build their seeds with :class:`Writer`
    (the same fields in the same order), so a seed is a valid scenario the fuzzer mutates.
    """

    def __init__(self, data: bytes) -> None:
        self.data = data
        self.pos = 0

    def left(self) -> int:
        return len(self.data) - self.pos

    def take(self, n: int) -> bytes:
        b = self.data[self.pos:self.pos + max(0, n)]
        self.pos += len(b)
        return b

    def _int(self, n: int, fmt: str) -> int:
        return struct.unpack(fmt, self.take(n).ljust(n, b"\0"))[0]

    def u8(self) -> int:
        return self._int(1, "<B")

    def u16(self) -> int:
        return self._int(2, "<H")

    def u32(self) -> int:
        return self._int(4, "<I")

    def i32(self) -> int:
        return self._int(4, "<i")

    def u64(self) -> int:
        return self._int(8, "<Q")

    def f64(self) -> float:
        return struct.unpack("<d", self.take(8).ljust(8, b"\0"))[0]

    def pick(self, seq: Sequence):  # type: ignore[no-untyped-def]
        return seq[self.u8() % len(seq)]

    def blob(self) -> bytes:
        """A length-prefixed (u16) byte string."""
        return self.take(self.u16())


class Writer:
    """Builds an input for :class:`Reader` (seeds)."""

    def __init__(self) -> None:
        self.parts: list[bytes] = []

    def raw(self, b: bytes) -> Writer:
        self.parts.append(bytes(b))
        return self

    def u8(self, v: int) -> Writer:
        return self.raw(struct.pack("<B", v & 0xFF))

    def u16(self, v: int) -> Writer:
        return self.raw(struct.pack("<H", v & 0xFFFF))

    def u32(self, v: int) -> Writer:
        return self.raw(struct.pack("<I", v & 0xFFFFFFFF))

    def i32(self, v: int) -> Writer:
        return self.raw(struct.pack("<i", v))

    def u64(self, v: int) -> Writer:
        return self.raw(struct.pack("<Q", v & (2**64 - 1)))

    def f64(self, v: float) -> Writer:
        return self.raw(struct.pack("<d", v))

    def index(self, seq: Sequence, item: object) -> Writer:  # type: ignore[type-arg]
        """The byte that makes :meth:`Reader.pick` return ``item``."""
        return self.u8(list(seq).index(item))

    def blob(self, b: bytes) -> Writer:
        return self.u16(len(b)).raw(b)

    def bytes(self) -> bytes:
        return b"".join(self.parts)


# ---- the runner (make fuzz, the bounded test) ----------------------------------------------------
@dataclass
class Result:
    """One run of one target.

    Attributes:
        target: its name.
        returncode: the process's exit status (0 ok, :data:`SKIPPED`, :data:`CRASHED`, :data:`TIMED_OUT`, ...).
        output: stdout + stderr (libFuzzer writes to stderr).
        artifacts: crash/timeout files written meanwhile.
        runs, cov, ft, corpus: libFuzzer's final figures (executions, coverage counters, features,
            corpus entries), -1 when not printed.
    """

    target: str
    returncode: int
    output: str
    artifacts: list[Path] = field(default_factory=list)
    runs: int = -1
    cov: int = -1
    ft: int = -1
    corpus: int = -1

    @property
    def skipped(self) -> bool:
        return self.returncode == SKIPPED

    @property
    def ok(self) -> bool:
        return self.returncode in (0, SKIPPED) and not self.artifacts

    def summary(self) -> str:
        if self.skipped:
            return f"{self.target}: skipped ({self.output.strip().splitlines()[-1]})"
        state = "ok" if self.ok else f"FAILED (exit {self.returncode})"
        return (f"{self.target}: {state}, {self.runs} runs, cov {self.cov}, ft {self.ft}, corpus {self.corpus}"
                + "".join(f"\n  {a}" for a in self.artifacts))

    def report(self) -> str:
        """What a failure shows: the figures, each artifact (hex and repr), the end of the output."""
        out = [self.summary()]
        for a in self.artifacts:
            data = a.read_bytes()
            out.append(f"--- {a.name} ({len(data)} bytes): {data[:512].hex()}\n    {data[:256]!r}")
            out.append(f"    reproduce: PYTHONPATH=. python -m tests.fuzz.fuzz_{self.target} {a}")
        out.append("--- output (end):\n" + "\n".join(self.output.splitlines()[-60:]))
        return "\n".join(out)


_DONE = re.compile(r"^#(\d+)\s+DONE\s+cov: (\d+) ft: (\d+) corp: (\d+)", re.M)
_LAST = re.compile(r"^#(\d+)\s+\w+\s+cov: (\d+) ft: (\d+) corp: (\d+)", re.M)


def run_target(name: str, corpus: Path, artifacts: Path, max_time: int, runs: int | None = None,
               timeout: int = 60, extra: Sequence[str] = (), wall_timeout: float | None = None,
               python: str = sys.executable) -> Result:
    """Run one target in a subprocess of its own (a finding ends libFuzzer's process).

    Args:
        name: a :data:`TARGETS` name.
        corpus: the corpus folder (seeded by the target, new inputs are added to it).
        artifacts: where crash/timeout files go (created), and ``fuzz.log``, the target's output.
        max_time: libFuzzer ``-max_total_time`` [s].
        runs: libFuzzer ``-runs`` (None: unbounded, ``max_time`` ends it).
        timeout: libFuzzer ``-timeout`` [s]: one input taking longer is a finding (a stall).
        extra: more libFuzzer arguments, or input folders that are only read (e.g. committed regression inputs).
        wall_timeout: kill the process after this long [s] (default: max_time + 5 timeouts + 120).

    Raises:
        subprocess.TimeoutExpired: the process outlived ``wall_timeout`` (it is killed first).
    """
    artifacts.mkdir(parents=True, exist_ok=True)
    before = set(artifacts.iterdir())
    cmd = [python, "-m", f"tests.fuzz.fuzz_{name}", f"-max_total_time={int(max_time)}", f"-timeout={int(timeout)}",
           f"-artifact_prefix={artifacts}{os.sep}", "-print_final_stats=1", "-report_slow_units=3600"]
    if runs is not None:
        cmd.append(f"-runs={int(runs)}")
    cmd.append(str(corpus))  # first: the folder libFuzzer adds new inputs to (and the target seeds)
    cmd += list(extra)
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT)] + [p for p in env.get("PYTHONPATH", "").split(os.pathsep) if p])
    log = artifacts / "fuzz.log"  # the target's whole output (libFuzzer's progress lines), while it runs
    with open(log, "w", encoding="utf-8", errors="replace") as f:
        proc = subprocess.Popen(cmd, cwd=ROOT, env=env, stdout=f, stderr=subprocess.STDOUT, start_new_session=True)
        try:
            proc.wait(timeout=wall_timeout or max_time + 5 * timeout + 120)
        finally:
            if proc.poll() is None:  # outlived its wall timeout (TimeoutExpired goes on up)
                os.killpg(proc.pid, 9)
                proc.wait()
    out = log.read_text(encoding="utf-8", errors="replace")
    found = [a for a in sorted(set(artifacts.iterdir()) - before) if a.name.startswith(FINDINGS)]
    res = Result(name, proc.returncode, out, found)
    m = _DONE.findall(out) or _LAST.findall(out)
    if m:
        res.runs, res.cov, res.ft, res.corpus = (int(x) for x in m[-1])
    st = re.search(r"stat::number_of_executed_units: (\d+)", out)
    if st:
        res.runs = int(st.group(1))
    return res


def cli(argv: Sequence[str] | None = None) -> int:
    """``python -m tests.fuzz [--time S] [--timeout S] [--work DIR] [TARGET ...] [-- libFuzzer args]``.

    Runs each target (default: all) for ``--time`` seconds, one after the other, with the corpus
    ``DIR/corpus/<target>/`` kept between runs and crash files in ``DIR/<target>/``; prints the
    figures and the findings. Exit status 1 if any target found something.
    """
    import argparse

    args = list(sys.argv[1:] if argv is None else argv)
    extra: list[str] = []
    if "--" in args:
        k = args.index("--")
        args, extra = args[:k], args[k + 1:]
    ap = argparse.ArgumentParser(prog="python -m tests.fuzz", description=cli.__doc__)
    ap.add_argument("--time", type=int, default=600, help="seconds per target (default 600)")
    ap.add_argument("--timeout", type=int, default=60, help="seconds one input may take (a stall, default 60)")
    ap.add_argument("--work", type=Path, default=WORK, help=f"corpora and crash files (default {WORK})")
    ap.add_argument("targets", nargs="*", metavar="TARGET", help=f"some of {', '.join(TARGETS)} (default all)")
    ns = ap.parse_args(args)
    unknown = [t for t in ns.targets if t not in TARGETS]
    if unknown:
        ap.error(f"unknown target(s) {unknown}: choose from {', '.join(TARGETS)}")
    failed = 0
    for name in ns.targets or TARGETS:
        print(f"fuzzing {name} for {ns.time} s ...", flush=True)
        r = run_target(name, ns.work / "corpus" / name, ns.work / name, ns.time, timeout=ns.timeout, extra=extra)
        print(r.report() if not r.ok else r.summary(), flush=True)
        failed += not r.ok
    return 1 if failed else 0
