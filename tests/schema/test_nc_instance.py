"""nc_schema.NcInstance: the one restart rule of the clients (PLC runtime, nc-ads, nc-status).

A restart is a new NC process instance: an instance token ``nc/<nc>/alive/<id>`` with another id, or the
frames' cycle counter going back. The same id coming back (a zenoh link dropped for a lease while the same
NC ran on) is none; one restart is one step whichever evidence comes first.
"""
from __future__ import annotations

import pytest

from nc_schema import Keys, NcInstance, new_instance_id, parse_alive_instance
from nc_schema.instance import FRAMES_OWED, INSTANCE_RE, TOKEN_OWED_FRAMES

A, B, C = "0123456789abcdef", "fedcba9876543210", "00000000000000ff"


def feed(inst: NcInstance, first: int, last: int, step: int = 5) -> set[str | None]:
    """Frames of cycles first..last every ``step`` cycles; the set of what ``frame`` returned."""
    return {inst.frame(c) for c in range(first, last + 1, step)}


def test_the_same_instance_through_gaps_and_stalls_is_no_restart() -> None:
    inst = NcInstance()
    assert inst.token(A) is None  # the first id: the client starts following that NC
    assert feed(inst, 1, 6000) == {None}
    assert inst.frame(6000) is None  # the same frame again
    assert feed(inst, 28000, 28100) == {None}  # a client that saw nothing for 20 s
    assert inst.restarts == 0 and inst.instance == A


def test_the_same_id_flapping_is_no_restart() -> None:
    inst = NcInstance()
    inst.token(A)
    for k in range(5):  # the token goes (not fed: a DELETE) and comes back with the same id
        assert inst.token(A) is None
        feed(inst, 1 + 1000 * k, 1000 * (k + 1))
    assert inst.restarts == 0


def test_a_new_id_is_a_restart_even_with_a_higher_cycle() -> None:
    """The defect: the old NC ran 1 s (Cycle ~990), the new one's first frame came with Cycle 1500. The
    frames alone show nothing (before: no restart at all, claims kept 'held' that the new NC does not know)."""
    inst = NcInstance()
    inst.token(A)
    feed(inst, 1, 990)
    assert inst.frame(1500) is None  # the frames alone: nothing to see
    why = inst.token(B)
    assert why is not None and B in why and A in why
    assert inst.restarts == 1 and inst.instance == B
    assert feed(inst, 1505, 3000) == {None}
    assert inst.token(B) is None and inst.restarts == 1  # B's token flapping afterwards


def test_token_first_then_the_cycle_going_back_counts_once() -> None:
    inst = NcInstance()
    inst.token(A)
    feed(inst, 1, 3000)
    assert inst.token(B) is not None
    assert inst.frame(3005) is None  # a frame of the old instance the client still held
    assert inst.frame(7) is None  # the new instance's first frame: its token counted it already
    assert feed(inst, 12, 500) == {None}
    assert inst.restarts == 1


def test_frames_first_then_the_new_id_counts_once() -> None:
    inst = NcInstance()
    inst.token(A)
    feed(inst, 1, 3000)
    assert inst.frame(7) == "its cycle counter went back"
    assert inst.restarts == 1
    assert inst.token(B) is None  # the instance the frames showed: not counted again
    assert inst.restarts == 1 and inst.instance == B
    assert inst.token(C) is not None and inst.restarts == 2  # the next one counts


def test_the_wait_for_the_frames_ends() -> None:
    """After a token restart whose frames did not go back, a later cycle going back is a restart again
    (an NC without instance tokens replacing it): counted, not taken for the earlier one."""
    inst = NcInstance()
    inst.token(A)
    feed(inst, 1, 990)
    inst.token(B)
    for c in range(1500, 1500 + FRAMES_OWED):
        assert inst.frame(c) is None
    assert inst.frame(3) is not None and inst.restarts == 2


def test_the_wait_for_the_token_ends() -> None:
    """After a restart the frames showed and whose token never came (an NC without instance tokens), a later
    restart announced by its token first is counted, not taken for the earlier one."""
    inst = NcInstance()
    inst.token(A)
    feed(inst, 1, 3000)
    assert inst.frame(7) is not None and inst.restarts == 1  # the frames: a restart, token owed
    for c in range(8, 8 + TOKEN_OWED_FRAMES):  # ... which never comes
        inst.frame(c)
    assert inst.token(B) is not None and inst.restarts == 2


def test_without_instance_tokens_the_frames_decide() -> None:
    """An older NC (no instance token): the cycle going back only; a higher Cycle is not seen."""
    inst = NcInstance()
    feed(inst, 1, 3000)
    assert inst.frame(7) == "its cycle counter went back"
    assert inst.frame(2) is not None
    assert inst.restarts == 2 and inst.instance is None


def test_two_restarts_in_every_order_count_two() -> None:
    inst = NcInstance()
    inst.token(A)
    feed(inst, 1, 100)
    inst.token(B)  # token first
    inst.frame(3)
    feed(inst, 8, 100)
    assert inst.frame(2) is not None  # frames first
    inst.token(C)
    feed(inst, 7, 100)
    assert inst.restarts == 2 and inst.instance == C


def test_instance_ids_and_keys() -> None:
    ids = {new_instance_id() for _ in range(100)}
    assert len(ids) == 100 and all(INSTANCE_RE.fullmatch(i) for i in ids)
    k = Keys("nc1")
    assert k.alive_instance(A) == f"nc/nc1/alive/{A}" and k.alive_instance_any == "nc/nc1/alive/*"
    assert parse_alive_instance(k.alive_instance(A)) == ("nc1", A)
    for bad in ("nc/nc1/alive", f"nc/nc1/alive/{A}/x", "nc/nc1/alive/XYZ", "nc/nc1/alive/0123", f"x/nc1/alive/{A}",
                f"nc/nc1/client/{A}", f"nc/bad name/alive/{A}", 42):
        assert parse_alive_instance(bad) is None, bad
    for bad in ("", "ABCDEF0123456789", "0123", None):
        with pytest.raises(ValueError):
            k.alive_instance(bad)  # type: ignore[arg-type]
        with pytest.raises(ValueError):
            NcInstance().token(bad)  # type: ignore[arg-type]
