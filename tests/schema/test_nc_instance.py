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


# ---- the epoch (protocol 5): the highest epoch of the instance is followed -------------------------------------
E1, E2 = (1 << 16) | 0x1234, (2 << 16) | 0x0042  # two epochs of a hot-standby pair: E2 took over from E1


def test_a_lower_epoch_frame_is_dropped_and_is_no_restart() -> None:
    """After a link cut the old active NC (E1), back on the network, publishes its own frames (its own Cycle
    count, behind its successor's) until it sees E2: dropped, counted, no restart, the Cycle followed stays."""
    inst = NcInstance()
    inst.token(A)
    for c in range(1, 1000, 5):
        assert inst.take(c, E1, now=c / 1000) == (True, None)
    assert inst.take(1001, E2, now=1.001) == (True, None)  # the takeover: the Cycle count continues
    assert (inst.epoch, inst.epoch_rises, inst.restarts) == (E2, 1, 0)
    for k, c in enumerate(range(990, 1400, 5)):  # the old active's frames (its Cycle behind, then ahead)
        assert inst.take(c, E1, now=1.002 + k / 1000) == (False, None)
        assert inst.take(1002 + k, E2, now=1.002 + k / 1000) == (True, None)
    assert inst.stale_frames == len(range(990, 1400, 5)) and inst.restarts == 0 and inst.epoch == E2
    assert inst.cycle == 1002 + len(range(990, 1400, 5)) - 1  # only the followed epoch's Cycle counts


def test_a_higher_epoch_is_taken_at_once_and_its_cycle_going_back_is_a_restart() -> None:
    """A higher epoch is taken with its first frame; the Cycle rule applies to it as to any frame: a successor
    whose Cycle is behind what the client saw did not know those cycles (their commands are lost): a restart."""
    inst = NcInstance()
    inst.token(A)
    assert inst.take(500, 0) == (True, None)
    assert inst.take(501, E1) == (True, None) and inst.epoch == E1  # no redundancy before: 0, then a pair
    taken, why = inst.take(400, E2)
    assert taken and why == "its cycle counter went back" and inst.restarts == 1 and inst.epoch == E2


def test_a_restarted_pair_at_a_lower_epoch_is_followed_after_its_new_instance_token() -> None:
    """The whole pair (or an NC without redundancy in its place) restarted: a new instance, epoch 0 again. Its
    instance token opens the epoch: its first frame is taken (one restart, counted by the token)."""
    inst = NcInstance()
    inst.token(A)
    for c in range(1, 100):
        inst.take(c, E2)
    assert inst.take(3, 0) == (False, None)  # before the token: a lower epoch, dropped
    assert inst.token(B) is not None and inst.restarts == 1
    assert inst.take(100, E2) == (True, None)  # a frame of the old instance still held: taken, epoch kept
    assert inst.take(4, 0) == (True, None)  # the new instance's first frame: its token counted it
    assert (inst.epoch, inst.epoch_falls, inst.restarts) == (0, 1, 1)
    assert inst.take(101, E2) == (True, None) and inst.epoch_rises == 1  # (a higher epoch is always taken)
    assert inst.take(5, 0) == (False, None)  # the epoch is closed again: lower ones are dropped


def test_a_new_instance_at_the_same_epoch_closes_the_epoch_with_its_first_frame() -> None:
    inst = NcInstance()
    inst.token(A)
    for c in range(1, 100):
        inst.take(c, 0)
    assert inst.token(B) is not None
    assert inst.take(2, 0) == (True, None) and inst.restarts == 1  # its first frame (the Cycle went back)
    assert inst.take(3, E1) == (True, None)  # it became a pair
    assert inst.take(4, 0) == (False, None)  # a lower epoch afterwards: dropped


def test_a_lower_epoch_is_taken_after_the_hold_without_the_followed_one() -> None:
    """No frame of the epoch followed for EPOCH_HOLD_S (the higher-epoch NC gone for good, no new instance
    token seen): the lower epoch is all there is and is taken; until then it is dropped."""
    from nc_schema.instance import EPOCH_HOLD_S
    inst = NcInstance()
    inst.token(A)
    assert inst.take(1000, E2, now=10.0) == (True, None)
    t = 10.0
    while t < 10.0 + EPOCH_HOLD_S - 0.05:
        t += 0.1
        assert inst.take(1001, E1, now=t) == (False, None)
    # (the first lower-epoch frame came at 10.1: the hold counts from there)
    assert inst.take(1002, E1, now=10.1 + EPOCH_HOLD_S) == (True, None)
    assert (inst.epoch, inst.epoch_falls, inst.restarts) == (E1, 1, 0)
    assert inst.take(1003, E1, now=10.1 + EPOCH_HOLD_S + 0.01) == (True, None)
    inst2 = NcInstance()  # without a clock the hold never ends (only a new instance opens the epoch)
    inst2.take(5, E2)
    assert inst2.take(6, E1) == (False, None)


def test_a_client_that_stalled_for_the_hold_does_not_take_the_old_nodes_next_frame() -> None:
    """The hold needs EPOCH_HOLD_S of lower-epoch frames, not merely that long since the last frame taken: a
    client that stood still for 10 s and then gets one frame of the old active node (epoch E1) drops it, and the
    active NC's next frame (epoch E2, its Cycle count going on) is no restart."""
    from nc_schema.instance import EPOCH_HOLD_S
    inst = NcInstance()
    inst.token(A)
    assert inst.take(100, E2, now=0.0) == (True, None)
    assert inst.take(200, E1, now=10.0) == (False, None)  # the old node's, after the client's own stall
    assert inst.take(101, E2, now=10.001) == (True, None)
    assert (inst.epoch, inst.restarts, inst.epoch_falls) == (E2, 0, 0)
    # the hold starts again with the next lower-epoch frame after a frame taken
    assert inst.take(201, E1, now=10.002) == (False, None)
    assert inst.take(202, E1, now=10.002 + EPOCH_HOLD_S - 0.01) == (False, None)
    assert inst.take(203, E1, now=10.002 + EPOCH_HOLD_S) == (True, None) and inst.epoch == E1


def test_frame_without_epoch_keeps_the_old_rule() -> None:
    inst = NcInstance()
    assert inst.frame(5) is None and inst.epoch is None
    assert inst.take(6, 0) == (True, None) and inst.epoch == 0
