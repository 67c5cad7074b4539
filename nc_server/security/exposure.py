"""What the NC's security settings mean for who can command it, said once at start.

An NC with neither TLS nor a roles file accepts every command from anyone who reaches one of its
listen endpoints (docs/roles.md). On loopback only that is the host's users: an INFO line, so the
demo stays quiet. Beyond loopback it is every host on the network: one WARNING naming the risk and
the fix.
"""
from __future__ import annotations

import logging
from collections.abc import Sequence

from nc_schema.endpoints import endpoint_is_local


def exposure(listen: Sequence[str], tls_dir: str | None, has_roles: bool) -> tuple[int, str] | None:
    """The log level and line for an NC listening on ``listen`` with these settings, or None.

    Returns:
        ``(logging.WARNING, text)`` when an endpoint reaches beyond loopback and there is neither TLS
        nor a roles file; ``(logging.INFO, text)`` for the same on loopback only; None when TLS or a
        roles file is set (their own warnings cover half-configured cases) or nothing is listened on.
    """
    if tls_dir or has_roles or not listen:
        return None
    wide = [e for e in listen if not endpoint_is_local(e)]
    if wide:
        return logging.WARNING, (
            f"listening on {', '.join(wide)} without TLS and without a roles file: every host that reaches "
            "this address may claim, enable and move every axis and write parameters under any client id. "
            "Fix: --tls-dir DIR --roles FILE (docs/roles.md), or listen on 127.0.0.1 only behind an nc-router "
            "that has them")
    return logging.INFO, (f"listening on loopback only ({', '.join(listen)}) without TLS or roles: every "
                          "process on this host may command the NC (docs/roles.md)")
