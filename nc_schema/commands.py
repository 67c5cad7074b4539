"""The contract's commands as typed, frozen specs: protocol.json ``commands`` and ``command_properties``.

:data:`COMMAND_SPECS` maps each command name to its :class:`CommandSpec` (scope, class, arguments and the
properties the NC and the clients derive their command sets from: motion, amends, stop, slot, undo,
layer). It is built once at import and checked: a property the contract does not document, a value of
the wrong type or an ``undo`` naming an unknown command is a contract bug and fails the import.

``nc_schema.COMMANDS`` stays the raw JSON (request parsing reads its ``args``); this is the typed view
for code that asks *what* a command is. Imports only :mod:`nc_schema.messages`.
"""
from __future__ import annotations

from dataclasses import dataclass
from types import MappingProxyType
from typing import Any, Final, Literal, Mapping, cast

from .messages import PROTOCOL

Scope = Literal["axis", "nc"]
CommandClass = Literal["read", "op", "eng"]
Layer = Literal["core", "server"]
Slot = Literal["Super", "Probe"]

#: the properties protocol.json documents for a command (``command_properties``) and ``args``/``doc``
PROPERTIES: Final[frozenset[str]] = frozenset(PROTOCOL["command_properties"]) - {"doc"}
_KNOWN = PROPERTIES | {"args", "doc"}
_SCOPES: Final = ("axis", "nc")
_CLASSES: Final = ("read", "op", "eng")
_LAYERS: Final = ("core", "server")
_SLOTS: Final = ("Super", "Probe")


@dataclass(frozen=True, slots=True)
class CommandSpec:
    """One command of the contract (protocol.json ``command_properties`` documents each field).

    Attributes:
        name: the command (the request's ``cmd``).
        scope: ``"axis"`` (axis key) or ``"nc"`` (NC key).
        cls: the command class, ``"read"`` / ``"op"`` / ``"eng"`` (``class`` in the JSON).
        args: the argument names, in the contract's order.
        motion: starts or changes a motion by itself (refused after an NC stall unless a stop; undone by
            a client that lost track of it).
        amends: changes the running motion command instead of starting one.
        stop: a plain stop (MC_Stop, MC_Halt): executed after an NC stall too, never undone.
        slot: the NCJOBS slot its CmdNo numbers (``"Super"``, ``"Probe"``), None: the axis's job queue.
        undo: the commands that stop its motion and nothing else (``("Halt",)`` for a motion command
            unless the contract names others; ``()`` for stops and commands without motion).
        layer: ``"core"`` (the NC core executes it) or ``"server"`` (the NC's request handler).
        doc: the contract's description.
    """

    name: str
    scope: Scope
    cls: CommandClass
    args: tuple[str, ...]
    motion: bool
    amends: bool
    stop: bool
    slot: Slot | None
    undo: tuple[str, ...]
    layer: Layer
    doc: str


def _choice(name: str, key: str, value: object, allowed: tuple[str, ...]) -> str:
    if value not in allowed:
        raise ValueError(f"protocol.json commands.{name}.{key}: {value!r} is not one of {allowed}")
    return str(value)


def _flag(name: str, key: str, raw: Mapping[str, Any]) -> bool:
    value = raw.get(key, False)
    if not isinstance(value, bool):
        raise ValueError(f"protocol.json commands.{name}.{key}: {value!r} is not a boolean")
    return value


def _spec(name: str, raw: Mapping[str, Any], names: frozenset[str]) -> CommandSpec:
    unknown = set(raw) - _KNOWN
    if unknown:
        raise ValueError(f"protocol.json commands.{name}: properties {sorted(unknown)} are not documented in "
                         "command_properties")
    motion, amends, stop = _flag(name, "motion", raw), _flag(name, "amends", raw), _flag(name, "stop", raw)
    if amends and motion:
        raise ValueError(f"protocol.json commands.{name}: an amendment starts no motion ('motion' and 'amends')")
    if stop and not motion:
        raise ValueError(f"protocol.json commands.{name}: a 'stop' is a motion command")
    slot = raw.get("slot")
    if slot is not None:
        _choice(name, "slot", slot, _SLOTS)
    if "undo" in raw:
        undo = raw["undo"]
        if not motion or stop or not isinstance(undo, list) or not undo or any(u not in names for u in undo):
            raise ValueError(f"protocol.json commands.{name}.undo: {undo!r}: a non-empty list of commands, "
                             "for a motion command that is no stop")
        undo_t: tuple[str, ...] = tuple(undo)
    else:
        undo_t = ("Halt",) if motion and not stop else ()
    return CommandSpec(
        name=name,
        scope=cast(Scope, _choice(name, "scope", raw.get("scope", "axis"), _SCOPES)),
        cls=cast(CommandClass, _choice(name, "class", raw.get("class"), _CLASSES)),
        args=tuple(raw.get("args", {})),
        motion=motion, amends=amends, stop=stop, slot=cast("Slot | None", slot), undo=undo_t,
        layer=cast(Layer, _choice(name, "layer", raw.get("layer", "core"), _LAYERS)),
        doc=str(raw.get("doc", "")),
    )


def _load(commands: Mapping[str, Mapping[str, Any]]) -> Mapping[str, CommandSpec]:
    names = frozenset(commands)
    return MappingProxyType({name: _spec(name, raw, names) for name, raw in commands.items()})


#: command name -> its spec, in the contract's order (read-only)
COMMAND_SPECS: Final[Mapping[str, CommandSpec]] = _load(PROTOCOL["commands"])

__all__ = ["COMMAND_SPECS", "CommandSpec", "PROPERTIES"]
