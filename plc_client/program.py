"""Loading a PLC program file: its entry point, the axes it declares, its arguments.

A program file (``plc-run prog.py``) defines ``def cycle(plc)`` or a class ``Program`` (instantiated
once without arguments; ``cycle(plc)`` or ``cycle()`` is called each PLC cycle).

**Axes are bound at load** (zenoh-nc choice, as a TwinCAT PLC's AXIS_REF variables are linked to their
NC axes when the project is loaded): every :class:`~plc_client.axis_ref.AXIS_REF` created while the
file is executed and its ``Program`` is instantiated, and every AXIS_REF found in the module's globals
and the Program object's attributes (also inside lists, tuples, sets and dict values, one level deep;
e.g. imported from a neighbouring module), is bound to the PLC task before the first cycle. Its
``NcToPlc`` and ``Status`` are refreshed every cycle from then on, so ``X.Status.Valid`` turns TRUE
once the NC's data arrives and a monitor-only program needs no block call. An AXIS_REF created later,
in a cycle (e.g. on first use), is bound to the running task when it is created, so it reads valid data
from that cycle on as well; one created outside any cycle and load (e.g. by a helper thread) is bound
the first time a block is called with it.

**Program arguments** (``plc-run prog.py --arg speed=300 --arg axis=2``): the program asks for them
with :func:`program_args`, at module level or in ``Program.__init__`` (the values are there while the
file loads, so an axis id can come from one)::

    from plc_client import AXIS_REF, program_args

    args = program_args(speed=200.0, axis=1, nc="nc1", verbose=False)   # the defaults declare the names
    X = AXIS_REF(nc=args.nc, axis_id=args.axis)                        # args.speed, args["speed"]

Each value is converted to the type of its default: ``float`` (a finite number), ``int`` (decimal or
``0x..``), ``bool`` (``true``/``false``/``1``/``0``, any case) or ``str`` (as given); a default of
``None`` takes the value untyped (an integer, a number, true/false, else the text). An argument the
program does not declare, one that does not convert, a malformed ``--arg`` (not ``NAME=VALUE``, NAME
not an identifier, NAME given twice), or ``--arg`` for a program that never calls ``program_args``
is a :class:`ProgramArgsError`: ``plc-run`` prints one line naming it and exits with 2 before
connecting to any NC. ``program_args()`` without defaults accepts any names (untyped). Outside
``plc-run`` (a test importing the program) ``program_args`` returns the defaults.
"""
from __future__ import annotations

import importlib.util
import math
import re
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable, Iterator, Mapping, Sequence

from .axis_ref import AXIS_REF, collect_axes

__all__ = ["ProgramArgs", "ProgramArgsError", "LoadedProgram", "load", "load_program", "parse_program_args",
           "program_args", "find_axes"]

_NAME_RE = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")


class ProgramArgsError(ValueError):
    """A bad program argument (``--arg``): the message names it."""


class ProgramArgs(Mapping[str, Any]):
    """The program's arguments: a read-only mapping with attribute access (``args.speed``)."""

    def __init__(self, values: Mapping[str, Any]) -> None:
        object.__setattr__(self, "_values", dict(values))

    def __getitem__(self, name: str) -> Any:
        return self._values[name]

    def __iter__(self) -> Iterator[str]:
        return iter(self._values)

    def __len__(self) -> int:
        return len(self._values)

    def __getattr__(self, name: str) -> Any:
        try:
            return self._values[name]
        except KeyError:
            raise AttributeError(f"no program argument {name!r} (declared: {', '.join(self._values) or 'none'})") \
                from None

    def __setattr__(self, name: str, value: Any) -> None:
        raise AttributeError("program arguments are read-only")

    def __repr__(self) -> str:
        return f"ProgramArgs({self._values!r})"


@dataclass
class _Loading:
    """The arguments of the program being loaded and what it declared."""

    given: dict[str, str]
    declared: set[str] = field(default_factory=set)
    open_ended: bool = False  # program_args() without defaults: any name is taken
    asked: bool = False
    values: dict[str, Any] = field(default_factory=dict)


_loading: list[_Loading] = []


def parse_program_args(items: Sequence[str] | None) -> dict[str, str]:
    """``["speed=300", "axis=2"]`` -> ``{"speed": "300", "axis": "2"}`` (the raw texts).

    Raises:
        ProgramArgsError: an item without ``=``, a NAME that is not an identifier, a NAME given twice.
    """
    out: dict[str, str] = {}
    for item in items or []:
        name, sep, value = item.partition("=")
        name = name.strip()
        if not sep or not _NAME_RE.match(name):
            raise ProgramArgsError(f"--arg {item!r}: expected NAME=VALUE with NAME a Python identifier, "
                                   f"e.g. --arg speed=300")
        if name in out:
            raise ProgramArgsError(f"--arg {name} given twice")
        out[name] = value
    return out


def _untyped(text: str) -> Any:
    t = text.strip()
    low = t.lower()
    if low in ("true", "false"):
        return low == "true"
    try:
        return int(t, 0)
    except ValueError:
        pass
    try:
        v = float(t)
    except ValueError:
        return text
    return v if math.isfinite(v) else text


def _convert(name: str, text: str, default: Any) -> Any:
    """``text`` as the type of ``default`` (see the module docstring)."""
    t = text.strip()
    if isinstance(default, bool):
        low = t.lower()
        if low in ("true", "1"):
            return True
        if low in ("false", "0"):
            return False
        raise ProgramArgsError(f"--arg {name}={text}: {name} must be true or false (default {default})")
    if isinstance(default, int):
        try:
            return int(t, 0) if not t.lstrip("+-").startswith("0") or t.lstrip("+-")[1:2].isalpha() else int(t, 10)
        except ValueError:
            raise ProgramArgsError(f"--arg {name}={text}: {name} must be an integer (default {default})") from None
    if isinstance(default, float):
        try:
            v = float(t)
        except ValueError:
            v = math.nan
        if not math.isfinite(v):
            raise ProgramArgsError(f"--arg {name}={text}: {name} must be a finite number (default {default})")
        return v
    if isinstance(default, str):
        return text
    return _untyped(text)  # default None


def program_args(**defaults: Any) -> ProgramArgs:
    """The program's arguments (``plc-run --arg NAME=VALUE``), each typed like its default.

    Call it while the program loads (module level or ``Program.__init__``); see the module docstring.

    Raises:
        ProgramArgsError: a given value does not convert to its default's type.
        TypeError: a default of a type other than bool, int, float, str or None (a program bug).
    """
    ctx = _loading[-1] if _loading else None
    given = ctx.given if ctx is not None else {}
    if ctx is not None:
        ctx.asked = True
        ctx.declared.update(defaults)
        ctx.open_ended = ctx.open_ended or not defaults
    values = {}
    for name, default in defaults.items():
        if not isinstance(default, (bool, int, float, str, type(None))):
            raise TypeError(f"program_args: the default of {name} must be a bool, int, float, str or None, "
                            f"got {type(default).__name__}")
        values[name] = _convert(name, given[name], default) if name in given else default
    if not defaults:
        values = {name: _untyped(text) for name, text in given.items()}
    if ctx is not None:
        ctx.values.update(values)
    return ProgramArgs(values)


def find_axes(*roots: Any) -> list[AXIS_REF]:
    """The AXIS_REFs among ``roots``' values (module globals / object attributes), one container level deep."""
    found: list[AXIS_REF] = []

    def add(v: Any) -> None:
        if isinstance(v, AXIS_REF):
            found.append(v)

    for root in roots:
        values: Iterable[Any] = root.values() if isinstance(root, Mapping) else vars(root).values()
        for v in list(values):
            add(v)
            if isinstance(v, (list, tuple, set, frozenset)):
                for x in v:
                    add(x)
            elif isinstance(v, dict):
                for x in v.values():
                    add(x)
    return found


@dataclass
class LoadedProgram:
    """What :func:`load` found: the entry point, the axes to bind, the arguments, the module."""

    program: Any
    axes: list[AXIS_REF]
    args: ProgramArgs
    module: Any


def load(path: str, args: Mapping[str, str] | None = None) -> LoadedProgram:
    """Import the program file ``path`` with the raw arguments ``args`` (``parse_program_args``).

    Raises:
        ProgramArgsError: a bad argument (see the module docstring).
        ValueError: the file defines neither ``cycle`` nor ``Program``.
        OSError, SyntaxError, Exception: the file cannot be imported.
    """
    p = Path(path)
    spec = importlib.util.spec_from_file_location(p.stem.replace("-", "_") or "program", p)
    if spec is None or spec.loader is None:
        raise ValueError(f"{path}: not a Python file")
    mod = importlib.util.module_from_spec(spec)
    sys.path.insert(0, str(p.resolve().parent))  # the program may import its neighbours
    ctx = _Loading(dict(args or {}))
    _loading.append(ctx)
    try:
        with collect_axes() as created:
            spec.loader.exec_module(mod)
            if hasattr(mod, "Program"):
                program = mod.Program()
            elif callable(getattr(mod, "cycle", None)):
                program = mod.cycle
            else:
                raise ValueError(f"{path}: define `def cycle(plc)` or a `Program` class with a cycle() method")
    finally:
        _loading.remove(ctx)
    if ctx.given:
        if not ctx.asked:
            raise ProgramArgsError(f"{path} takes no arguments (it does not call program_args() while it loads: "
                                   f"call it at module level or in Program.__init__, not in a cycle); "
                                   f"given: {', '.join(ctx.given)}")
        unknown = [n for n in ctx.given if n not in ctx.declared]
        if unknown and not ctx.open_ended:
            raise ProgramArgsError(f"--arg {unknown[0]}: {path} has no argument {unknown[0]!r} "
                                   f"(it declares: {', '.join(sorted(ctx.declared))})")
    axes: list[AXIS_REF] = []
    seen: set[int] = set()
    roots: list[Any] = [vars(mod)]
    if hasattr(mod, "Program") and hasattr(program, "__dict__"):
        roots.append(program)
    for ax in [r() for r in created] + find_axes(*roots):
        if ax is not None and id(ax) not in seen:
            seen.add(id(ax))
            axes.append(ax)
    return LoadedProgram(program, axes, ProgramArgs(ctx.values), mod)


def load_program(path: str, args: Mapping[str, str] | None = None) -> Any:
    """Import ``path`` and return what the runtime should call each cycle (see :func:`load`)."""
    return load(path, args).program
