"""The command registry: every command of the wire contract, registered once where it is implemented.

A command's properties (scope, class, motion, amends, layer, ...) live in the contract
(``schema/protocol.json``, typed as ``nc_schema.COMMAND_SPECS``). The code that executes a command
registers it here, next to that code:

* a job kind (:mod:`.jobs`): each of its ``commands`` (:func:`register_kind`, called by the jobs package
  for every kind its family modules list): the command becomes a job of the axis's queue
  (``JobEngine.motion``);
* an amendment, ``@core_command(..., how="amendment")``: it changes the running job (``JobEngine.amend``);
* any other command of the core, ``@core_command(...)``: a function ``(core, i, req) -> result`` beside
  what it changes (nc.py's admin commands, the stages' commands, GearOut, ExtSetPointGenDisable);
* a command of the NC's request handler (layer ``server``: claims, Info):
  :mod:`nc_server.server.handler` registers it with ``REGISTRY.register(..., layer="server")``, and a
  check it makes before the core runs a command (SetOverride's claim check) with :meth:`CommandRegistry.guard`.

Every registration is checked against the contract at once: the command exists, it is registered once,
and its layer, ``amends`` (an amendment) and ``motion`` (a job kind's :attr:`JobKind.motion`, a function's
``motion=``) agree; a mismatch fails the import. With the server's registrations every contract command
is registered (tests/core/test_command_registry.py). :meth:`NcCore.execute <.nc.NcCore.execute>` finds a
command's handler with one dict lookup (:data:`CORE_HANDLERS`).

It may import: ``nc_schema``; the core's types for annotations only.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Callable, Final, Iterator, Literal, Mapping, TypeVar

from nc_schema import COMMAND_SPECS, CommandSpec

if TYPE_CHECKING:
    from .jobs.base import JobKind
    from .nc import NcCore

Layer = Literal["core", "server"]
#: how the core executes a command: a job of the queue, an amendment of the running job, a function
How = Literal["job", "amendment", "function"]
#: a command of the core: ``(core, axis row, parsed request) -> {"cmd_no": .., "value": ..}`` (both optional)
CoreHandler = Callable[["NcCore", int, dict[str, Any]], dict[str, Any]]
H = TypeVar("H", bound=Callable[..., dict[str, Any]])


class RegistryError(ValueError):
    """A registration that contradicts the contract (an unknown command, a second registration, another
    layer, amends or motion than protocol.json says)."""


@dataclass(frozen=True, slots=True)
class Registration:
    """One command's implementation.

    Attributes:
        spec: the contract's description.
        layer: who executes it (``"core"``: NcCore.execute; ``"server"``: the request handler).
        how: ``"job"`` (a job kind: ``kind``), ``"amendment"`` or ``"function"``.
        motion: the implementation starts or changes a motion by itself (equals ``spec.motion``).
        where: the implementing object (``module.qualname``), for messages and the docs.
        kind: the job kind (``how == "job"``), else None.
    """

    spec: CommandSpec
    layer: Layer
    how: How
    motion: bool
    where: str
    kind: JobKind | None = None


class CommandRegistry(Mapping[str, Registration]):
    """Command name -> its :class:`Registration`, checked against ``contract`` as it is filled.

    Args:
        contract: command name -> spec (``nc_schema.COMMAND_SPECS``).
    """

    def __init__(self, contract: Mapping[str, CommandSpec]) -> None:
        self.contract = contract
        self._regs: dict[str, Registration] = {}
        self._guards: dict[str, tuple[str, ...]] = {}

    def __getitem__(self, name: str) -> Registration:
        return self._regs[name]

    def __iter__(self) -> Iterator[str]:
        return iter(self._regs)

    def __len__(self) -> int:
        return len(self._regs)

    def _spec(self, name: str, where: str) -> CommandSpec:
        spec = self.contract.get(name)
        if spec is None:
            raise RegistryError(f"{name} ({where}): not a command of the contract (schema/protocol.json)")
        return spec

    def register(self, name: str, *, where: str, layer: Layer = "core", how: How = "function",
                 motion: bool = False, kind: JobKind | None = None) -> Registration:
        """Register ``name``'s implementation (once).

        Raises:
            RegistryError: ``name`` is no contract command, is registered already, or its layer, amends
                or motion differ from the contract's; a job without its kind.
        """
        spec = self._spec(name, where)
        old = self._regs.get(name)
        if old is not None:
            raise RegistryError(f"{name}: registered twice ({old.where} and {where})")
        wrong = []
        if layer != spec.layer:
            wrong.append(f"layer {layer!r}, the contract says {spec.layer!r}")
        if (how == "amendment") != spec.amends:
            wrong.append(f"registered as {how!r}, the contract's amends is {spec.amends}")
        if motion != spec.motion:
            wrong.append(f"motion {motion}, the contract's is {spec.motion}")
        if (how == "job") != (kind is not None):
            wrong.append("a job needs its kind, and only a job has one")
        if wrong:
            raise RegistryError(f"{name} ({where}): " + "; ".join(wrong))
        reg = Registration(spec, layer, how, motion, where, kind)
        self._regs[name] = reg
        return reg

    def guard(self, name: str, *, layer: Layer, where: str) -> None:
        """Record that ``layer`` checks ``name`` before the command's own layer executes it.

        Raises:
            RegistryError: ``name`` is no contract command, or the guard is in the command's own layer.
        """
        spec = self._spec(name, where)
        if layer == spec.layer:
            raise RegistryError(f"{name} ({where}): a guard of the layer that executes it")
        self._guards[name] = self._guards.get(name, ()) + (layer,)

    @property
    def guards(self) -> Mapping[str, tuple[str, ...]]:
        """Command -> the layers that check it before it runs (e.g. SetOverride: the server's claim check)."""
        return dict(self._guards)

    def unregistered(self) -> list[str]:
        """The contract's commands nobody registered (empty once the core and the server are imported)."""
        return [n for n in self.contract if n not in self._regs]

    def kinds(self) -> dict[str, JobKind]:
        """Command -> its job kind, for the commands that are jobs."""
        return {n: r.kind for n, r in self._regs.items() if r.kind is not None}


#: the one registry of the NC's commands (the core's, and the server's once nc_server.server.handler is imported)
REGISTRY: Final = CommandRegistry(COMMAND_SPECS)
#: the core's dispatch table: command -> handler (NcCore.execute: one lookup per command)
CORE_HANDLERS: Final[dict[str, CoreHandler]] = {}


def _where(obj: object) -> str:
    return f"{getattr(obj, '__module__', '?')}.{getattr(obj, '__qualname__', type(obj).__qualname__)}"


def core_command(*names: str, how: How = "function", motion: bool = False) -> Callable[[H], H]:
    """Decorator: the function implements the core commands ``names`` (see the module docstring).

    Raises:
        RegistryError: see :meth:`CommandRegistry.register`.
    """
    def register(fn: H) -> H:
        for name in names:
            REGISTRY.register(name, where=_where(fn), how=how, motion=motion)
            CORE_HANDLERS[name] = fn
        return fn
    return register


def register_kind(kind: JobKind) -> None:
    """Register job kind ``kind`` for each of its ``commands``: each becomes a job of the axis's queue.

    Raises:
        RegistryError: see :meth:`CommandRegistry.register`.
    """
    def start(core: NcCore, i: int, req: dict[str, Any]) -> dict[str, Any]:
        return core.engine.motion(i, kind, req)

    for name in kind.commands:
        REGISTRY.register(name, where=f"{_where(kind)} ({kind.name})", how="job", motion=kind.motion, kind=kind)
        CORE_HANDLERS[name] = start


__all__ = ["CORE_HANDLERS", "REGISTRY", "CommandRegistry", "CoreHandler", "Registration", "RegistryError",
           "core_command", "register_kind"]
