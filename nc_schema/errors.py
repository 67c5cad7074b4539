"""Error codes of the wire contract (``errors.json``) and the exception that carries one.

``ERRORS`` (code -> name, class, text) and ``ErrorCodes`` are generated into :mod:`nc_schema.generated`
(``python -m nc_schema.generate``); this module adds the look-ups and :class:`NcError`.
"""
from __future__ import annotations

from dataclasses import dataclass, field

from .generated import ERRORS, ErrorCodes

__all__ = ["ERRORS", "ErrorCodes", "NcError", "error_name", "error_text"]


def error_name(code: int) -> str:
    """The symbolic name of ``code`` (``"0x1234"`` if unknown)."""
    e = ERRORS.get(code)
    return e[0] if e else f"0x{code:04X}"


def error_text(code: int) -> str:
    """Beckhoff's (shortened) text for ``code``, or a generic one."""
    e = ERRORS.get(code)
    return e[2] if e else f"error 0x{code:04X}"


@dataclass
class NcError(Exception):
    """A rejected request or an axis fault, with its TwinCAT error code.

    Attributes:
        code: the TwinCAT/ADS/zenoh-nc error code (errors.json).
        detail: what exactly was wrong, for humans.
        request_id, cmd: set by ``parse_request`` on a refused request when they could be read (so
            the reply carries them); None otherwise. Not constructor arguments, not compared.
    """

    code: int
    detail: str = ""
    request_id: int | str | None = field(default=None, init=False, repr=False, compare=False)
    cmd: str | None = field(default=None, init=False, repr=False, compare=False)

    def __str__(self) -> str:
        base = f"0x{self.code:04X} {error_name(self.code)}: {error_text(self.code)}"
        return f"{base} ({self.detail})" if self.detail else base
