"""The users file of the user-facing doors (nc-opcua, nc-web): user names, their role and a salted scrypt hash of their password.

A TOML file given by path (``nc-opcua --users FILE``), beside the NC's roles file::

    [user.alice]
    role = "operator"                       # observer | operator | engineer (docs/roles.md)
    password = "scrypt$16384$8$1$<salt b64>$<hash b64>"

Make an entry with ``nc-opcua user FILE NAME --role ROLE`` or ``nc-web user ...`` (:func:`user_main`) (the password is read from the terminal or
stdin, never from the command line) or :func:`hash_password`.

Decisions: the hash is ``hashlib.scrypt`` (RFC 7914; n=2**14, r=8, p=1, 16-byte random salt, 32-byte key),
stored with its parameters so they can be raised later; verification is constant-time
(``hmac.compare_digest``). A user name is also a client id suffix (``<door>.<user>``), so it follows the
client id rule (letters, digits, ``_``, ``.``, ``-``; the door id and the name together at most 64).

May import: ``nc_schema`` and the standard library.
"""
from __future__ import annotations

import argparse
import asyncio
import base64
import getpass
import hashlib
import hmac
import os
import re
import sys
import time
import tomllib
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Mapping

from nc_schema import ROLE_CLASSES, check_client_id

__all__ = ["User", "UsersError", "hash_password", "verify_password", "load_users", "add_user", "ROLES", "role_min",
           "Verifier", "user_main", "check_door_config"]

#: The roles, lowest privilege first.
ROLES: tuple[str, ...] = tuple(ROLE_CLASSES)
_NAME_RE = re.compile(r"[A-Za-z0-9_.\-]{1,48}")
_N, _R, _P, _DKLEN = 2**14, 8, 1, 32


class UsersError(ValueError):
    """A users file that cannot be used (the message names the file and the entry)."""


@dataclass(frozen=True)
class User:
    """One OPC UA user: ``name``, ``role`` (observer / operator / engineer), ``password_hash`` (see the module)."""

    name: str
    role: str
    password_hash: str


def role_min(a: str, b: str) -> str:
    """The lower of two roles (a door never grants more than its own role)."""
    return a if ROLES.index(a) <= ROLES.index(b) else b


def check_door_config(door_id: str, users: Mapping[str, object], role: str) -> None:
    """Check a user-facing door's identity before it starts (nc-opcua, nc-web).

    Raises:
        ValueError: the door id is no valid client id, a user's ``<door>.<user>`` client id is invalid (at most 64
            characters), or ``role`` is no role of ROLE_CLASSES.
    """
    check_client_id(door_id)
    for name in users:
        try:
            check_client_id(f"{door_id}.{name}")
        except ValueError:
            raise ValueError(f"user {name!r}: the client id {door_id}.{name} is not a valid client id "
                             "(at most 64 characters: a shorter --client-id or user name)") from None
    if role not in ROLE_CLASSES:
        raise ValueError(f"role must be one of {', '.join(ROLE_CLASSES)}, got {role!r}")


def hash_password(password: str, salt: bytes | None = None) -> str:
    """The stored form of ``password``: ``scrypt$n$r$p$salt$hash`` (base64)."""
    salt = salt if salt is not None else os.urandom(16)
    dk = hashlib.scrypt(password.encode(), salt=salt, n=_N, r=_R, p=_P, dklen=_DKLEN)
    return f"scrypt${_N}${_R}${_P}${_b64(salt)}${_b64(dk)}"


def _b64(b: bytes) -> str:
    return base64.b64encode(b).decode()


def verify_password(password: str, stored: str) -> bool:
    """True if ``password`` matches ``stored`` (:func:`hash_password`'s form); False for a malformed entry."""
    try:
        scheme, n, r, p, salt, dk = stored.split("$")
        if scheme != "scrypt":
            return False
        want = base64.b64decode(dk)
        got = hashlib.scrypt(password.encode(), salt=base64.b64decode(salt), n=int(n), r=int(r), p=int(p),
                             dklen=len(want), maxmem=128 * int(n) * int(r) * 2 + 1024 * 1024)
    except (ValueError, TypeError):
        return False
    return hmac.compare_digest(got, want)


class Verifier:
    """Password checks for logins (asyncua's ``get_user``): :meth:`check`.

    * an unknown user name costs one scrypt of the default parameters too (:func:`dummy_verify`), so the time of
      a refusal does not tell which names exist;
    * a successful check is remembered as an HMAC-SHA256 of (user, password, stored hash) under a random key
      that lives only in this object: the same user with the same password again costs no scrypt (a client that
      reconnects, many sessions of one HMI). A wrong password always costs one scrypt.

    Thread-safe enough for asyncua (one dict assignment per success).
    """

    def __init__(self, users: Mapping[str, User]) -> None:
        self.users = users
        self._key = os.urandom(32)
        self._ok: dict[str, bytes] = {}
        self._refused: dict[bytes, float] = {}  # (name, password) MACs :meth:`precheck` refused -> until when

    def precheck(self, name: str, password: str) -> bool:
        """:meth:`check` on a worker thread before a caller that must decide without blocking (asyncua's
        ActivateSession): a success is remembered as by :meth:`check`; a refusal is remembered for one later
        :meth:`check` of the same name and password within 30 s, which then costs no scrypt either."""
        if self.check(name, password):
            return True
        now = time.monotonic()
        self._refused = {m: t for m, t in self._refused.items() if t > now}
        self._refused[self._mac(name, password, "")] = now + 30.0
        return False

    def _mac(self, name: str, password: str, stored: str) -> bytes:
        return hmac.new(self._key, b"\0".join(x.encode() for x in (name, password, stored)), hashlib.sha256).digest()

    def check(self, name: str, password: str) -> bool:
        """True if ``name`` is a user and ``password`` is its password."""
        if self._refused.pop(self._mac(name, password, ""), 0.0) > time.monotonic():
            return False  # refused by :meth:`precheck` just before: no second scrypt
        u = self.users.get(name)
        if u is None:
            dummy_verify(password)
            return False
        mac = self._mac(name, password, u.password_hash)
        known = self._ok.get(name)
        if known is not None and hmac.compare_digest(known, mac):
            return True
        if not verify_password(password, u.password_hash):
            return False
        self._ok[name] = mac
        return True


class LoginsBusy(Exception):
    """Too many password checks running or waiting: refused at once (HTTP 429, OPC UA BadTooManyOperations)."""


class PasswordGate:
    """A door's password checks (scrypt: ~16 MiB and 0.1-1 s each) on their own ``workers`` threads, apart from
    asyncio's default executor and the NC commands' threads (a login flood never delays a Stop); at most
    ``limit`` running or waiting, more are refused at once (:class:`LoginsBusy`). Used from one event loop."""

    def __init__(self, verifier: Verifier, workers: int = 2, limit: int = 8) -> None:
        self.verifier = verifier
        self._pool = ThreadPoolExecutor(workers, thread_name_prefix="password")
        self._limit, self.pending = limit, 0

    async def _run(self, fn: Callable[[str, str], bool], name: str, password: str) -> bool:
        if self.pending >= self._limit:
            raise LoginsBusy(f"{self.pending} password checks running or waiting")
        self.pending += 1
        try:
            return await asyncio.get_running_loop().run_in_executor(self._pool, fn, name, password)
        finally:
            self.pending -= 1

    async def check(self, name: str, password: str) -> bool:
        """:meth:`Verifier.check` on the gate's threads.

        Raises:
            LoginsBusy: ``limit`` checks are running or waiting already.
        """
        return await self._run(self.verifier.check, name, password)

    async def precheck(self, name: str, password: str) -> bool:
        """:meth:`Verifier.precheck` on the gate's threads (raises as :meth:`check`)."""
        return await self._run(self.verifier.precheck, name, password)

    def close(self) -> None:
        self._pool.shutdown(wait=False, cancel_futures=True)


def dummy_verify(password: str) -> bool:
    """One scrypt of the default parameters with a random salt (the cost of :func:`verify_password` for an
    entry :func:`hash_password` made), always False: the check of an unknown user name."""
    got = hashlib.scrypt(password.encode(), salt=os.urandom(16), n=_N, r=_R, p=_P, dklen=_DKLEN,
                         maxmem=128 * _N * _R * 2 + 1024 * 1024)
    hmac.compare_digest(got, bytes(_DKLEN))
    return False


def parse_users(data: Mapping[str, object], source: str = "<users>") -> dict[str, User]:
    """The users of a parsed users file.

    Raises:
        UsersError: an unknown section, a bad name, role or password entry (the message names it).
    """
    extra = set(data) - {"user"}
    if extra:
        raise UsersError(f"{source}: unknown section(s) {sorted(extra)}: only [user.<name>] tables")
    users: dict[str, User] = {}
    table = data.get("user", {})
    if not isinstance(table, Mapping):
        raise UsersError(f"{source}: user: must be a table of [user.<name>]")
    for name, entry in table.items():
        key = f"user.{name}"
        if not _NAME_RE.fullmatch(name):
            raise UsersError(f"{source}: {key}: a user name is 1-48 of letters, digits, '_', '.', '-'")
        if not isinstance(entry, Mapping):
            raise UsersError(f"{source}: {key}: must be a table")
        unknown = set(entry) - {"role", "password"}
        if unknown:
            raise UsersError(f"{source}: {key}: unknown key(s) {sorted(unknown)}")
        role = entry.get("role")
        if role not in ROLES:
            raise UsersError(f"{source}: {key}.role: must be one of {', '.join(ROLES)}, got {role!r}")
        pw = entry.get("password")
        if not isinstance(pw, str) or not pw.startswith("scrypt$") or pw.count("$") != 5:
            raise UsersError(f"{source}: {key}.password: a scrypt hash (nc-opcua user FILE NAME --role R makes one)")
        users[name] = User(name, str(role), pw)
    return users


def load_users(path: str | Path) -> dict[str, User]:
    """The users of the file ``path``.

    Raises:
        UsersError: unreadable, not TOML, or a bad entry.
    """
    try:
        data = tomllib.loads(Path(path).read_text())
    except OSError as exc:
        raise UsersError(f"{path}: cannot read the users file: {exc.strerror}") from None
    except tomllib.TOMLDecodeError as exc:
        raise UsersError(f"{path}: not TOML: {exc}") from None
    return parse_users(data, str(path))


def add_user(path: str | Path, name: str, role: str, password: str) -> None:
    """Add or replace user ``name`` in the users file ``path`` (created if missing, mode 0600).

    Raises:
        UsersError: a bad name or role, or the existing file is invalid.
    """
    p = Path(path)
    users = load_users(p) if p.exists() else {}
    users[name] = User(name, role, hash_password(password))
    parse_users({"user": {u.name: {"role": u.role, "password": u.password_hash} for u in users.values()}}, str(p))
    text = "# nc-opcua users (nc_link.users): role observer | operator | engineer, scrypt password hash\n"
    for u in users.values():
        text += f'\n[user.{u.name}]\nrole = "{u.role}"\npassword = "{u.password_hash}"\n'
    fd = os.open(p, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "w") as f:
        f.write(text)


def user_main(prog: str, argv: list[str]) -> int:
    """``<prog> user FILE NAME --role R``: add or replace a user; the password from the terminal or stdin (never
    the command line). Exit status 0, or 2 for an empty password or a bad file/name/role."""
    p = argparse.ArgumentParser(prog=f"{prog} user", description="add or replace a user of a users file")
    p.add_argument("file")
    p.add_argument("name")
    p.add_argument("--role", required=True, choices=ROLES)
    a = p.parse_args(argv)
    pw = getpass.getpass(f"password for {a.name}: ") if sys.stdin.isatty() else sys.stdin.readline().rstrip("\n")
    if not pw:
        print(f"{prog} user: empty password", file=sys.stderr)
        return 2
    try:
        add_user(a.file, a.name, a.role, pw)
    except UsersError as exc:
        print(f"{prog} user: {exc}", file=sys.stderr)
        return 2
    print(f"{a.file}: user {a.name} ({a.role})")
    return 0
