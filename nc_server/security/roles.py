"""The roles file: who may do what on the NCs (docs/roles.md).

A TOML file, e.g. ``deploy/roles.toml``::

    [client.plc1]
    role = "operator"        # observer | operator | engineer
    [client.eng1]
    role = "engineer"
    [client.status]
    role = "observer"
    [client.opcua]
    role = "engineer"
    door = true              # acts for its users as opcua.<user>, never above its own role
    [nc.nc1]                 # an NC server (its certificate CN = its NC name)
    [router.router]          # a router that may connect to this one (router-to-router link)
    [drive.drives1]          # a drive host (nc-drive-sim --host drives1) of NC nc1
    nc = "nc1"

The ids are the certificates' common names (``deploy/certs/make-certs.sh``), the client ids of
``plc-run --client-id`` and the NC names. Roles and the command classes they may send
(``nc_schema.ROLE_CLASSES``): observer ``read``; operator ``read``, ``op``; engineer ``read``,
``op``, ``eng``.

Doors (``door = true``: nc-opcua, nc-web): a door acts for each of its users under the client id
``<door>.<user>`` (``<door>`` followed by a dot and at least one more character). Such an id is not listed:
it has the door's role (the door enforces each user's own, lower or equal, role itself); the generated access
control lets the door's certificate use those ids' keys (command keys, PLCTONC, liveliness token) and no other
certificate. Decision: the roles file lists no identity under a door's prefix (``[client."opcua.visitor"]``,
a door ``opcua.sub`` nested in door ``opcua``, an NC, router or drive host ``opcua.x``): the door's
certificate may use every ``<door>.$*`` key, so such an entry would be one the door can act as (a narrowing
of a door's user is the door's users file's job). :func:`parse_roles` refuses it.
"""
from __future__ import annotations

import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterator, Mapping

from nc_schema import ROLE_CLASSES, Keys, check_client_id

__all__ = ["Roles", "RolesError", "ClientRoles", "load_roles", "parse_roles", "door_of", "ROLES"]

#: The roles, lowest privilege first.
ROLES: tuple[str, ...] = tuple(ROLE_CLASSES)


#: client ids a roles file may not list: a hot-standby node's view of the active NC's frames is ``ha-<node>``
HA_CLIENT_PREFIX = "ha-"


class RolesError(ValueError):
    """A roles file that cannot be used.

    Attributes:
        file: the file (or ``"<roles>"`` for parsed data).
        key: the offending entry, e.g. ``client.plc1.role`` (``""`` for the file as a whole).
        message: what is wrong.
    """

    def __init__(self, file: str, key: str, message: str) -> None:
        self.file, self.key, self.message = file, key, message
        super().__init__(f"{file}: {key}: {message}" if key else f"{file}: {message}")


@dataclass(frozen=True)
class Roles:
    """A checked roles file.

    Attributes:
        clients: client id -> role (``observer``, ``operator``, ``engineer``).
        ncs: the NC servers that may connect (their NC names = certificate CNs).
        routers: routers that may connect to this one (certificate CNs).
        drives: drive host (certificate CN, ``nc-drive-sim --host``) -> the NC whose drives it hosts.
        source: where it was read from.
        nc_masters: NC -> the other NCs whose per-axis samples it may read (``[nc.nc2] masters = ["nc1"]``: its
            slaves couple to axes of nc1, docs/coupling-across-ncs.md).
    """

    clients: Mapping[str, str] = field(default_factory=dict)
    ncs: tuple[str, ...] = ()
    routers: tuple[str, ...] = ()
    drives: Mapping[str, str] = field(default_factory=dict)
    source: str = "<roles>"
    doors: tuple[str, ...] = ()
    nc_masters: Mapping[str, tuple[str, ...]] = field(default_factory=dict)

    def role_of(self, client: str) -> str | None:
        """The client's role (a door's user ``<door>.<user>``: the door's), None if it is not listed."""
        return self.client_roles().get(client)

    def classes_of(self, client: str) -> tuple[str, ...]:
        """The command classes the client may send (none if unlisted)."""
        role = self.role_of(client)
        return ROLE_CLASSES[role] if role else ()

    def client_roles(self) -> "ClientRoles":
        """client id -> role as the NC checks it (listed clients, and the users of doors)."""
        return ClientRoles(dict(self.clients), self.doors)


def door_of(client: str, doors: tuple[str, ...] | frozenset[str]) -> str | None:
    """The door ``client`` is a user id of (``<door>.<user>``; the longest such door), None if none."""
    best = None
    for d in doors:
        if len(client) > len(d) + 1 and client.startswith(d + ".") and (best is None or len(d) > len(best)):
            best = d
    return best


class ClientRoles(Mapping[str, str]):
    """The roles of the listed clients (iteration, ``len``), and for ``get``/``[]`` also of the door user ids
    ``<door>.<user>`` (the door's role; see the module docstring)."""

    def __init__(self, clients: dict[str, str], doors: tuple[str, ...] = ()) -> None:
        self._clients, self._doors = clients, tuple(doors)

    def __getitem__(self, client: str) -> str:
        role = self._clients.get(client)
        if role is None:
            door = door_of(client, self._doors)
            if door is None:
                raise KeyError(client)
            role = self._clients[door]
        return role

    def __iter__(self) -> Iterator[str]:
        return iter(self._clients)

    def __len__(self) -> int:
        return len(self._clients)


def _table(v: Any, file: str, key: str) -> Mapping[str, Any]:
    if not isinstance(v, Mapping):
        raise RolesError(file, key, f"must be a table, got {type(v).__name__}")
    return v


def parse_roles(data: Mapping[str, Any], source: str = "<roles>") -> Roles:
    """Check parsed TOML data and build :class:`Roles`.

    Raises:
        RolesError: unknown sections or keys, a missing or unknown role, an invalid id, an id used
            twice (a certificate CN names one identity), or nothing listed.
    """
    for k in data:
        if k not in ("client", "nc", "router", "drive"):
            raise RolesError(source, k, "unknown section (allowed: [client.<id>], [nc.<name>], [router.<id>], "
                                        "[drive.<host>])")
    clients: dict[str, str] = {}
    doors: list[str] = []
    owner: dict[str, str] = {}

    def take(section: str, ident: str) -> None:
        key = f"{section}.{ident}"
        try:
            check_client_id(ident)
            if section == "nc":
                Keys(ident)
        except ValueError as exc:
            raise RolesError(source, key, str(exc)) from None
        if section == "client" and ident.startswith(HA_CLIENT_PREFIX):
            # (a hot-standby node watches the active NC's frames as the client ha-<node>: docs/standby.md; a client
            # of that name would take its view, or answer for it)
            raise RolesError(source, key, f"the client id prefix {HA_CLIENT_PREFIX!r} is reserved for the hot-standby "
                                          "nodes' view of the frames (docs/standby.md)")
        if ident in owner:
            raise RolesError(source, key, f"{ident!r} is also [{owner[ident]}]: one certificate CN, one identity")
        owner[ident] = key

    for ident, t in _table(data.get("client", {}), source, "client").items():
        take("client", ident)
        t = _table(t, source, f"client.{ident}")
        for k in t:
            if k not in ("role", "door"):
                raise RolesError(source, f"client.{ident}.{k}", "unknown key (allowed: role, door)")
        if "door" in t:
            if not isinstance(t["door"], bool):
                raise RolesError(source, f"client.{ident}.door", f"must be true or false, got {t['door']!r}")
            if t["door"]:
                doors.append(ident)
        if "role" not in t:
            raise RolesError(source, f"client.{ident}.role", f"missing (one of {', '.join(ROLES)})")
        role = t["role"]
        if role not in ROLES:
            raise RolesError(source, f"client.{ident}.role", f"must be one of {', '.join(ROLES)}, got {role!r}")
        clients[ident] = role
    ncs: list[str] = []
    routers: list[str] = []
    nc_masters: dict[str, tuple[str, ...]] = {}
    for section, out in (("nc", ncs), ("router", routers)):
        for ident, t in _table(data.get(section, {}), source, section).items():
            take(section, ident)
            t = dict(_table(t, source, f"{section}.{ident}"))
            if section == "nc" and "masters" in t:  # coupling across NCs: whose samples it reads
                m = t.pop("masters")
                if not isinstance(m, list) or not all(isinstance(x, str) for x in m):
                    raise RolesError(source, f"nc.{ident}.masters", "must be a list of NC names")
                for x in m:
                    try:
                        Keys(x)
                    except ValueError as exc:
                        raise RolesError(source, f"nc.{ident}.masters", str(exc)) from None
                    if x == ident:
                        raise RolesError(source, f"nc.{ident}.masters", "an NC reads its own axes without it")
                nc_masters[ident] = tuple(m)
            if t:
                allowed = "allowed: masters" if section == "nc" else "the table takes none"
                raise RolesError(source, f"{section}.{ident}.{next(iter(t))}", f"unknown key ({allowed})")
            out.append(ident)
    drives: dict[str, str] = {}
    for ident, t in _table(data.get("drive", {}), source, "drive").items():
        take("drive", ident)
        t = _table(t, source, f"drive.{ident}")
        for k in t:
            if k != "nc":
                raise RolesError(source, f"drive.{ident}.{k}", "unknown key (allowed: nc)")
        nc = t.get("nc")
        try:
            Keys(nc if isinstance(nc, str) else "")
        except ValueError as exc:
            raise RolesError(source, f"drive.{ident}.nc", f"the NC whose drives it hosts: {exc}") from None
        drives[ident] = str(nc)
    if not clients and not ncs:
        raise RolesError(source, "", "lists no [client.<id>] and no [nc.<name>]")
    for ident, key in owner.items():  # the door's certificate may use every <door>.$* id: none is listed
        door = door_of(ident, tuple(doors))
        if door is None:
            continue
        if ident in doors:
            raise RolesError(source, key, f"a door nested in door {door!r}: {door!r}'s certificate could act as it "
                                          "(a door's id must not start with another door's id and a dot)")
        raise RolesError(source, key, f"{ident!r} is under door {door!r} (its users' ids {door}.<user>): the door "
                                      "could act as it; narrow a door's user in the door's users file, or choose "
                                      "an id outside the door's")
    return Roles(clients=clients, ncs=tuple(ncs), routers=tuple(routers), drives=drives, source=source,
                 doors=tuple(doors), nc_masters=nc_masters)


def load_roles(path: str | Path) -> Roles:
    """Read and check a roles file.

    Raises:
        RolesError: unreadable file, TOML syntax error, or any problem :func:`parse_roles` finds.
    """
    p = str(path)
    try:
        text = Path(path).read_text(encoding="utf-8")
    except OSError as exc:
        raise RolesError(p, "", f"cannot read: {exc.strerror or exc}") from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise RolesError(p, "", f"TOML syntax error: {exc}") from None
    return parse_roles(data, p)
