"""Command key layout seen through ``nc_schema.Keys`` (duck-typed: imports nothing of the project).

Protocol version 2 puts the command class and the client id into the key
(``nc/<nc>/axis/<axis>/cmd/<class>/<client>``, ``Keys.command_key`` / ``parse_cmd_key -> (axis, cls,
client)``); version 1 had ``nc/<nc>/axis/<axis>/cmd`` and the client id in the request only. The
targets build and check keys through these helpers, so they fuzz whichever layout the tree has.
"""
from __future__ import annotations

from typing import Any

#: the command classes of protocol version 2 (observer / operator / engineer)
CLASSES = ("read", "op", "eng")


def v2(keys: Any) -> bool:
    """Whether ``keys`` has the class/client command keys."""
    return hasattr(keys, "command_key")


def command_key(keys: Any, cmd: str, axis: int | None, client: str) -> str:
    """The key ``cmd`` is sent on for ``axis`` (None: an NC command) by ``client``."""
    if v2(keys):
        return keys.command_key(cmd, axis, client)
    return keys.cmd if axis is None else keys.axis_cmd(axis)


def class_key(keys: Any, axis: int | None, cls: str, client: str) -> str:
    """The command key of class ``cls`` (v1: there is one command key per axis)."""
    if v2(keys):
        return keys.cmd(cls, client) if axis is None else keys.axis_cmd(axis, cls, client)
    return keys.cmd if axis is None else keys.axis_cmd(axis)


def rebuild(keys: Any, parsed: Any) -> str:
    """The key ``keys.parse_cmd_key`` returned ``parsed`` for (its inverse)."""
    if v2(keys):
        axis, cls, client = parsed
        return class_key(keys, axis, cls, client)
    return keys.cmd if parsed is None else keys.axis_cmd(parsed)


def parsed_axis(keys: Any, parsed: Any) -> int | None:
    """The axis id of a ``parse_cmd_key`` result."""
    return parsed[0] if v2(keys) else parsed
