"""zenoh access control from a roles file (``nc-acl roles.toml`` prints it as JSON).

:func:`access_control` returns the ``access_control`` section of a zenoh config (zenoh 1.x format):
default deny, one subject per listed id matched by its TLS certificate's common name, and for each
subject exactly the key expressions of its identity (docs/roles.md has the table):

* every listed client reads the NCs' cyclic data: ``nc/*/frame``, ``nc/*/frame/*`` (the frame once per
  period, what PLC clients take), ``nc/*/status``, ``nc/*/stats``, ``nc/*/claims``,
  ``nc/*/axis/*/nctoplc``, ``nc/*/axis/*/plctonc`` and the NCs' liveliness ``nc/*/alive`` and
  ``nc/*/alive/*`` (each NC process's instance token: how clients tell a restart from a flapping token) and
  the hot-standby nodes' status ``nc/*/ha/status/*`` (nc-status's ``ha:`` line; docs/standby.md);
* every listed client declares its own view token ``nc/*/select/<id>/**`` and reads its own view
  ``nc/*/view/<id>`` (the frames of the axes it listed);
* a client queries only its own command keys ``nc/*/[axis/*/]cmd/<class>/<id>`` of the classes
  its role allows, and gets the replies on them;
* operators and engineers also put their own PLCTONC ``nc/*/plctonc/<id>`` and declare their own
  liveliness token ``nc/*/client/<id>``;
* an NC server ``[nc.<name>]`` may declare its queryable, publish, subscribe and declare liveliness
  (``nc/<name>/alive``, ``nc/<name>/alive/<instance>``) only below its own prefix ``nc/<name>/**``, and is
  sent the queries and PLCTONC for it; the one query it may send is ``nc/<name>/ha/snapshot`` (a hot-standby
  node asking the active node of its NC for a snapshot, docs/standby.md);
* an NC with ``masters = ["nc1"]`` (coupling across NCs) may also subscribe to and receive the per-axis
  samples ``nc/nc1/axis/*/nctoplc`` of those NCs, nothing else of theirs;
* a router ``[router.<id>]`` (another router connecting to this one) may forward everything below ``nc/**``;
* a drive host ``[drive.<host>]`` (``nc-drive-sim --host <host>``) of NC ``<nc>`` subscribes to its outputs
  ``nc/<nc>/drive/<host>/rx``, puts its inputs ``.../tx`` and its ``.../status`` and declares its token
  ``.../alive``, nothing else (the NC reaches them through its own ``nc/<nc>/**`` rules); every listed client
  may read the drive hosts' status ``nc/*/drive/*/status``.
* a door (``door = true``, roles.py) also uses the command keys, PLCTONC and liveliness token of its users' ids
  ``<id>.<user>`` (key expressions ``.../<id>.$*``), with its own role's classes.

It respects what was verified on eclipse-zenoh 1.10.2 (../shared/reference/zenoh-security-notes.md):
rules match by *inclusion* (a rule's key expression must include the message's or declaration's,
not merely intersect it); both directions need rules (ingress from the sender, egress to the
receiver); a writer with a declared publisher drops its own puts unless the *egress*
``declare_subscriber`` of the other side's subscriber (e.g. the NC's ``nc/nc1/plctonc/*``) reaches it,
so those are allowed; liveliness tokens, liveliness subscribers and liveliness queries are separate
message types.
"""
from __future__ import annotations

import argparse
import json
import sys
from typing import Any, Sequence

from nc_schema import ROLE_CLASSES

from .roles import Roles, RolesError, load_roles

__all__ = ["access_control", "with_local_publisher", "READ_KEYS", "NC_ALIVE", "main"]

#: What every listed client may subscribe to and receive.
READ_KEYS: tuple[str, ...] = ("nc/*/frame", "nc/*/frame/*", "nc/*/status", "nc/*/stats", "nc/*/claims",
                              "nc/*/axis/*/nctoplc", "nc/*/axis/*/plctonc", "nc/*/drive/*/status",
                              "nc/*/ha/status/*")
#: The NCs' liveliness tokens: reachable, and one per NC process (its instance id; a rule must *include*
#: the watched key, so ``nc/*/alive`` alone would not let a client see ``nc/nc1/alive/<instance>``).
NC_ALIVE: tuple[str, ...] = ("nc/*/alive", "nc/*/alive/*")

_ALL_MESSAGES = ["put", "delete", "declare_subscriber", "query", "declare_queryable", "reply",
                 "liveliness_token", "declare_liveliness_subscriber", "liveliness_query"]


def _rule(rid: str, flow: str, messages: Sequence[str], keys: Sequence[str]) -> dict[str, Any]:
    return {"id": rid, "permission": "allow", "flows": [flow], "messages": list(messages), "key_exprs": list(keys)}


def command_keys(client: str, classes: Sequence[str]) -> list[str]:
    """The command keys ``client`` may query with ``classes``, on every NC (axis and NC level)."""
    out = []
    for cls in classes:
        out += [f"nc/*/cmd/{cls}/{client}", f"nc/*/axis/*/cmd/{cls}/{client}"]
    return out


def access_control(roles: Roles) -> dict[str, Any]:
    """The zenoh ``access_control`` section for ``roles`` (see the module docstring).

    Subjects match the certificate common name only, so the listener must use mutual TLS
    (:mod:`nc_schema.tls`): without a client certificate nothing matches and zenoh's
    default (deny) applies.

    Raises:
        ValueError: ``roles`` lists nothing (zenoh refuses an access control without subjects).
    """
    if not roles.clients and not roles.ncs and not roles.routers and not roles.drives:
        raise ValueError(f"{roles.source}: no clients, NCs or routers listed")
    rules: list[dict[str, Any]] = []
    subjects: list[dict[str, Any]] = []
    policies: list[dict[str, Any]] = []
    shared: set[str] = set()

    def share(rule: dict[str, Any]) -> str:
        if rule["id"] not in shared:
            shared.add(rule["id"])
            rules.append(rule)
        return rule["id"]

    def subject(kind: str, ident: str, rule_ids: list[str]) -> None:
        sid = f"{kind}:{ident}"
        subjects.append({"id": sid, "cert_common_names": [ident]})
        policies.append({"id": f"policy:{sid}", "rules": rule_ids, "subjects": [sid]})

    for client, role in roles.clients.items():
        classes = ROLE_CLASSES[role]
        ids = [
            share(_rule("read:subscribe", "ingress", ["declare_subscriber"], READ_KEYS)),
            share(_rule("read:receive", "egress", ["put", "delete"], READ_KEYS)),
            share(_rule("alive:watch", "ingress", ["declare_liveliness_subscriber", "liveliness_query"], NC_ALIVE)),
            share(_rule("alive:receive", "egress", ["liveliness_token", "reply"], NC_ALIVE)),
            # a declared querier (declare_querier) sends only while it sees a matching queryable
            share(_rule("see:queryables", "egress", ["declare_queryable"], ["nc/**"])),
        ]
        # its own view (protocol.json view_select / view): the token that asks for it, the frames it gets
        view = [f"nc/*/view/{client}"]
        rules.append(_rule(f"client:{client}:view-token", "ingress", ["liveliness_token"], [f"nc/*/select/{client}/**"]))
        rules.append(_rule(f"client:{client}:view-subscribe", "ingress", ["declare_subscriber"], view))
        rules.append(_rule(f"client:{client}:view-receive", "egress", ["put", "delete"], view))
        ids += [f"client:{client}:view-token", f"client:{client}:view-subscribe", f"client:{client}:view-receive"]
        door = client in roles.doors
        keys = command_keys(client, classes) + (command_keys(f"{client}.$*", classes) if door else [])
        rules.append(_rule(f"client:{client}:query", "ingress", ["query"], keys))
        rules.append(_rule(f"client:{client}:reply", "egress", ["reply"], keys))
        ids += [f"client:{client}:query", f"client:{client}:reply"]
        if "op" in classes:
            users = [f"{client}.$*"] if door else []
            rules.append(_rule(f"client:{client}:plctonc", "ingress", ["put"],
                               [f"nc/*/plctonc/{c}" for c in (client, *users)]))
            rules.append(_rule(f"client:{client}:token", "ingress", ["liveliness_token"],
                               [f"nc/*/client/{c}" for c in (client, *users)]))
            ids += [f"client:{client}:plctonc", f"client:{client}:token",
                    # its declared PLCTONC publisher drops puts unless it sees the NC's subscriber nc/<nc>/plctonc/*
                    share(_rule("see:plctonc-subscribers", "egress", ["declare_subscriber"], ["nc/*/plctonc/*"]))]
        subject("client", client, ids)
    for nc in roles.ncs:
        own = [f"nc/{nc}/**"]
        rules.append(_rule(f"nc:{nc}:in", "ingress", [m for m in _ALL_MESSAGES if m != "query"], own))
        rules.append(_rule(f"nc:{nc}:out", "egress", ["put", "delete", "query", "liveliness_token", "reply"], own))
        # its declared publishers (frame, stats, per axis) drop puts unless they see the subscribers
        # a hot-standby node (docs/standby.md) asks the active node of its NC for a snapshot: its one query
        rules.append(_rule(f"nc:{nc}:ha-query", "ingress", ["query"], [f"nc/{nc}/ha/snapshot"]))
        ids = [f"nc:{nc}:in", f"nc:{nc}:out", f"nc:{nc}:ha-query",
               share(_rule("see:subscribers", "egress", ["declare_subscriber"], ["nc/**"]))]
        masters = [f"nc/{m}/axis/*/nctoplc" for m in roles.nc_masters.get(nc, ())]
        if masters:  # coupling across NCs: the masters' per-axis samples
            rules.append(_rule(f"nc:{nc}:masters-subscribe", "ingress", ["declare_subscriber"], masters))
            rules.append(_rule(f"nc:{nc}:masters-receive", "egress", ["put"], masters))
            ids += [f"nc:{nc}:masters-subscribe", f"nc:{nc}:masters-receive"]
        subject("nc", nc, ids)
    for router in roles.routers:
        ids = [share(_rule("router:in", "ingress", _ALL_MESSAGES, ["nc/**"])),
               share(_rule("router:out", "egress", _ALL_MESSAGES, ["nc/**"]))]
        subject("router", router, ids)
    for host, nc in roles.drives.items():
        p = f"nc/{nc}/drive/{host}"
        rules.append(_rule(f"drive:{host}:in-put", "ingress", ["put"], [f"{p}/tx", f"{p}/status"]))
        rules.append(_rule(f"drive:{host}:in-sub", "ingress", ["declare_subscriber"], [f"{p}/rx"]))
        rules.append(_rule(f"drive:{host}:token", "ingress", ["liveliness_token"], [f"{p}/alive"]))
        rules.append(_rule(f"drive:{host}:out", "egress", ["put"], [f"{p}/rx"]))
        # its declared publishers (tx, status) drop puts unless they see the NC's (and observers') subscribers
        rules.append(_rule(f"drive:{host}:see", "egress", ["declare_subscriber"], [f"{p}/tx", f"{p}/status"]))
        subject("drive", host, [f"drive:{host}:{r}" for r in ("in-put", "in-sub", "token", "out", "see")])
    return {"enabled": True, "default_permission": "deny", "rules": rules, "subjects": subjects,
            "policies": policies}


def with_local_publisher(acl: dict[str, Any], nc: str, protocol: str = "unixsock-stream") -> dict[str, Any]:
    """``acl`` plus a subject for the NC's own frame publisher: whatever connects over ``protocol`` (the
    NC's internal unix socket, in a directory only the NC's user can open) gets the rules of NC ``nc``.

    Raises:
        ValueError: ``acl`` has no rules for NC ``nc`` (its roles file does not list it).
    """
    ids = [f"nc:{nc}:in", f"nc:{nc}:out", "see:subscribers"]
    have = {r["id"] for r in acl["rules"]}
    if not set(ids) <= have:
        raise ValueError(f"no access control rules for NC {nc!r} (list it in the roles file)")
    sid = f"nc:{nc}:local-publisher"
    return {**acl, "subjects": [*acl["subjects"], {"id": sid, "link_protocols": [protocol]}],
            "policies": [*acl["policies"], {"id": f"policy:{sid}", "rules": ids, "subjects": [sid]}]}


def main(argv: Sequence[str] | None = None) -> int:
    """``nc-acl roles.toml``: print the access_control section as JSON (exit 2 for a bad roles file)."""
    p = argparse.ArgumentParser(prog="nc-acl", description="Print the zenoh access_control section for a roles file.")
    p.add_argument("roles", help="roles file (TOML), e.g. deploy/roles.toml")
    p.add_argument("--indent", type=int, default=2, help="JSON indentation (0: one line)")
    args = p.parse_args(argv)
    try:
        acl = access_control(load_roles(args.roles))
    except (RolesError, ValueError) as exc:
        print(f"nc-acl: {exc}", file=sys.stderr)
        return 2
    print(json.dumps(acl, indent=args.indent or None))
    return 0


if __name__ == "__main__":
    sys.exit(main())
