"""Command keys of protocol version 2 through ``nc_schema.Keys`` (duck-typed: imports nothing of the
project): ``nc/<nc>/[axis/<axis>/]cmd/<class>/<client>``; ``parse_cmd_key -> (axis, cls, client)``."""
from __future__ import annotations

from typing import Any

#: the command classes (observer / operator / engineer)
CLASSES = ("read", "op", "eng")


def command_key(keys: Any, cmd: str, axis: int | None, client: str) -> str:
    """The key ``client`` sends ``cmd`` on for ``axis`` (None: an NC command)."""
    return keys.command_key(cmd, axis, client)


def class_key(keys: Any, axis: int | None, cls: str, client: str) -> str:
    """The command key of class ``cls`` (right or wrong for the command sent on it)."""
    return keys.cmd(cls, client) if axis is None else keys.axis_cmd(axis, cls, client)


def rebuild(keys: Any, parsed: Any) -> str:
    """The key ``keys.parse_cmd_key`` returned ``parsed`` for (its inverse)."""
    axis, cls, client = parsed
    return class_key(keys, axis, cls, client)


def parsed_axis(keys: Any, parsed: Any) -> int | None:
    """The axis id of a ``parse_cmd_key`` result."""
    return parsed[0]
