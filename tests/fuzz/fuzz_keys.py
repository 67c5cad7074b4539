"""Fuzz target: key expressions and client ids (``nc_schema.Keys``, ``check_client_id``, the liveliness
key -> client id of ``transport.liveliness_client``).

One input is a selector byte and a string (UTF-8, invalid bytes replaced; or the bytes' Latin-1
text, so every code point below 256 is reachable). Checks:

* ``Keys(name)`` raises only ValueError; an accepted name gives keys that all start with
  ``nc/<name>/`` and parse back (every axis key round-trips through ``parse_cmd_key``);
* ``check_client_id`` raises only ValueError and returns the id unchanged; an accepted id makes
  client keys (liveliness, PLCTONC in, command keys) that contain it verbatim and parse back;
* ``Keys.parse_cmd_key`` raises only NcError (0x4012); a key it accepts is rebuilt exactly from
  the parsed parts (no two spellings of one axis, e.g. ``axis/01``), with a configured-range axis id;
* ``liveliness_client`` returns None or a valid id, and exactly the id whose key it was given;
  the claim table and ``RequestHandler`` (liveliness, then an Info request) take it.

Run: ``python -m tests.fuzz.fuzz_keys [libFuzzer args] [CORPUS_DIR | CRASH_FILE ...]``.
"""
from __future__ import annotations

from tests.fuzz._runner import Finding, Reader, Writer, instrument, main

with instrument():
    from nc_schema import Keys, NcError, check_client_id, make_request
    from nc_server.server.transport import liveliness_client
    from tests.fuzz import _layout
    from tests.fuzz._nc import FuzzNc

KEYS = Keys("nc1")
NAME, CLIENT, CMD_KEY, LIVELINESS, PREFIXED_CMD, PREFIXED_LIVELINESS = range(6)
N_MODES = 6


def text(r: Reader) -> str:
    b = r.take(r.left())
    return b.decode("latin-1") if r.data[:1] and r.data[0] & 0x80 else b.decode("utf-8", "replace")


def check_name(name: str) -> None:
    try:
        k = Keys(name)
    except ValueError:
        return
    p = f"nc/{name}/"
    for key in (k.frame, k.stats, k.status, k.claims, k.alive, k.axis_nctoplc(1), k.axis_plctonc(7),
                k.client_alive("plc1"), k.plctonc_in("plc1"), _layout.command_key(k, "MoveAbsolute", 3, "plc1"),
                _layout.command_key(k, "Info", None, "plc1")):
        if not key.startswith(p) or any(c in key for c in "*$#?\n\r ") or "//" in key or key.endswith("/"):
            raise Finding(f"Keys({name!r}) made {key!r}, not a plain key expression of that NC")
    for axis in (1, 2, 9999):
        key = _layout.command_key(k, "MoveAbsolute", axis, "plc1")
        parsed = k.parse_cmd_key(key)
        if _layout.parsed_axis(k, parsed) != axis or _layout.rebuild(k, parsed) != key:
            raise Finding(f"{key!r} parsed as {parsed!r}")


def check_client(client: str) -> None:
    try:
        got = check_client_id(client)
    except ValueError:
        for make in (KEYS.client_alive, KEYS.plctonc_in):
            try:
                key = make(client)
            except ValueError:
                continue
            raise Finding(f"invalid client id {client!r} accepted in {key!r}")
        return
    if got != client:
        raise Finding(f"check_client_id({client!r}) returned {got!r}")
    alive = KEYS.client_alive(client)
    if liveliness_client(KEYS, alive) != client:
        raise Finding(f"liveliness key {alive!r} not parsed back to {client!r}")
    if not KEYS.plctonc_in(client).endswith("/" + client):
        raise Finding(f"PLCTONC key of {client!r}: {KEYS.plctonc_in(client)!r}")
    if any(c in client for c in "*$#?/\n\r "):
        raise Finding(f"client id {client!r} accepted")
    key = _layout.command_key(KEYS, "Reset", 1, client)
    parsed = KEYS.parse_cmd_key(key)
    if _layout.rebuild(KEYS, parsed) != key:
        raise Finding(f"{key!r} parsed as {parsed!r}")


def check_cmd_key(key: str) -> None:
    try:
        parsed = KEYS.parse_cmd_key(key)
    except NcError as err:
        if err.code != 0x4012:
            raise Finding(f"parse_cmd_key({key!r}): {err}") from err
        return
    axis = _layout.parsed_axis(KEYS, parsed)
    if axis is not None and (type(axis) is not int or not 0 <= axis < 10**9):
        raise Finding(f"parse_cmd_key({key!r}) gave axis {axis!r}")
    if _layout.rebuild(KEYS, parsed) != key:
        raise Finding(f"parse_cmd_key({key!r}) = {parsed!r}, which is the key {_layout.rebuild(KEYS, parsed)!r}")


def check_liveliness(key: str) -> None:
    client = liveliness_client(KEYS, key)
    if client is None:
        return
    check_client_id(client)
    if KEYS.client_alive(client) != key:
        raise Finding(f"liveliness key {key!r} taken as client {client!r}")
    nc = FuzzNc(held=[])
    nc.handler.client_alive(client)
    info = nc.request(_layout.command_key(KEYS, "Info", None, "plc1"), make_request("Info", 1, "plc1"))
    if client not in info.get("Value", {}).get("clients", ()):
        raise Finding(f"client {client!r} (liveliness {key!r}) not listed by Info: {info!r}")
    nc.handler.client_gone(client)


def test_one(data: bytes) -> None:
    r = Reader(data)
    mode = r.u8() % N_MODES
    s = text(r)
    if mode == NAME:
        check_name(s)
    elif mode == CLIENT:
        check_client(s)
    elif mode == CMD_KEY:
        check_cmd_key(s)
    elif mode == LIVELINESS:
        check_liveliness(s)
    elif mode == PREFIXED_CMD:
        check_cmd_key(f"{KEYS.prefix}/{s}")
    else:
        check_liveliness(f"{KEYS.prefix}/client/{s}")


def seeds() -> list[bytes]:
    def w(mode: int, s: str) -> bytes:
        return Writer().u8(mode).raw(s.encode()).bytes()

    out = [w(NAME, "nc1"), w(NAME, "cell-2.nc_A"), w(NAME, "a" * 64), w(CLIENT, "plc1"), w(CLIENT, "plc-host-1234"),
           w(CLIENT, "x" * 64), w(LIVELINESS, KEYS.client_alive("plc1")), w(PREFIXED_LIVELINESS, "plc2"),
           w(CMD_KEY, "nc/nc1/axis/01/cmd/op/plc1"), w(PREFIXED_CMD, "axis/1/cmd/op/plc1"), w(CLIENT, "plc1\n")]
    for axis in (None, 1, 4, 999999999):
        for cls in _layout.CLASSES:
            key = _layout.class_key(KEYS, axis, cls, "plc1")
            out.append(w(CMD_KEY, key))
            out.append(w(PREFIXED_CMD, key[len(KEYS.prefix) + 1:]))
    return out


if __name__ == "__main__":
    main("keys", test_one, seeds)
