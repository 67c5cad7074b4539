"""Claim table and watchdog with fake time (no zenoh, no clock)."""
from __future__ import annotations

import pytest

from nc_schema import NcError
from nc_server.server.claims import (
    ACCESS_DENIED, LEASE_STALL_GRACE, ZNC_CLIENT_LOST, ZNC_PLCTONC_TIMEOUT, ClaimTable, Loss,
)


def faults(losses: list[Loss]) -> list[tuple[int, int]]:
    """The (axis_id, code) pairs of the axes the losses fault."""
    return sorted((a, loss.code) for loss in losses for a in loss.faulted)


@pytest.fixture
def table() -> ClaimTable:
    return ClaimTable([1, 2, 3], watchdog_timeout=0.5)


def test_claim_needs_liveliness_token(table: ClaimTable) -> None:
    with pytest.raises(NcError) as ei:
        table.claim(1, "plc1", now=0.0)
    assert ei.value.code == ACCESS_DENIED == 0x723
    assert "liveliness" in str(ei.value) and "nc/<nc>/client/plc1" in str(ei.value)
    table.client_alive("plc1")
    table.claim(1, "plc1", now=0.0)
    assert table.holder(1) == "plc1"


def test_second_claimant_refused_until_released(table: ClaimTable) -> None:
    table.client_alive("a")
    table.client_alive("b")
    table.claim(1, "a", 0.0)
    table.claim(1, "a", 0.1)  # idempotent for the holder
    with pytest.raises(NcError) as ei:
        table.claim(1, "b", 0.2)
    assert ei.value.code == 0x723 and "'a'" in str(ei.value)
    with pytest.raises(NcError):
        table.release(1, "b")  # not the holder
    assert table.release(1, "a") is True
    assert table.release(1, "a") is False  # nothing to release: no error
    table.claim(1, "b", 0.3)
    assert table.claims() == {1: "b"}


def test_unknown_axis(table: ClaimTable) -> None:
    table.client_alive("a")
    with pytest.raises(NcError) as ei:
        table.claim(9, "a", 0.0)
    assert ei.value.code == 0x4012


def test_client_lost_faults_and_releases(table: ClaimTable) -> None:
    table.client_alive("a")
    table.claim(1, "a", 0.0)
    table.claim(2, "a", 0.0)
    assert table.check(0.1) == []
    table.client_gone("a", 0.15)
    assert table.check(0.2) == [Loss("a", ZNC_CLIENT_LOST, (1, 2))]
    assert table.claims() == {} and table.check(0.3) == []
    assert table.clients() == []
    # A token that comes back may claim again.
    table.client_alive("a")
    table.claim(1, "a", 0.4)


def test_plctonc_timeout(table: ClaimTable) -> None:
    table.client_alive("a")
    table.client_alive("b")
    table.claim(1, "a", 0.0)
    table.claim(3, "b", 0.0)
    # Not armed before the holder's first frame: a claim alone is never faulted.
    assert table.check(10.0) == []
    table.plctonc_arrived("a", 10.0)
    table.plctonc_arrived("b", 10.0)
    assert table.check(10.5) == []  # exactly the timeout: still fine
    table.plctonc_arrived("b", 10.4)
    assert faults(table.check(10.51)) == [(1, ZNC_PLCTONC_TIMEOUT)]
    assert table.holder(1) is None and table.holder(3) == "b"
    assert table.check(10.89) == []
    assert faults(table.check(10.91)) == [(3, ZNC_PLCTONC_TIMEOUT)]


def test_frame_before_claim_does_not_arm(table: ClaimTable) -> None:
    table.client_alive("a")
    table.plctonc_arrived("a", 1.0)
    table.claim(1, "a", 5.0)  # the frame at 1.0 predates the claim
    assert table.check(6.0) == []
    table.plctonc_arrived("a", 6.0)
    assert faults(table.check(6.6)) == [(1, ZNC_PLCTONC_TIMEOUT)]


def test_grace_after_nc_stall(table: ClaimTable) -> None:
    table.client_alive("a")
    table.claim(1, "a", 0.0)
    table.plctonc_arrived("a", 0.1)
    table.grace(3.0)  # the NC itself was stopped: nobody is blamed for the gap
    assert table.check(3.2) == []
    assert faults(table.check(3.6)) == [(1, ZNC_PLCTONC_TIMEOUT)]


def test_override_permission(table: ClaimTable) -> None:
    table.may_override(1, "anyone")  # unclaimed
    table.client_alive("a")
    table.claim(1, "a", 0.0)
    table.may_override(1, "a")
    with pytest.raises(NcError) as ei:
        table.may_override(1, "b")
    assert ei.value.code == 0x723


def test_held_since_follows_changes(table: ClaimTable) -> None:
    inf = float("inf")
    table.client_alive("a")
    assert table.held_since("a").tolist() == [inf, inf, inf] and table.holders() == frozenset()
    table.claim(2, "a", 5.0)
    assert table.held_since("a").tolist() == [inf, 5.0, inf] and table.holders() == {"a"}
    table.release(2, "a")
    assert table.held_since("a").tolist() == [inf, inf, inf] and table.holders() == frozenset()


def test_frames_of_unknown_clients_are_ignored(table: ClaimTable) -> None:
    table.plctonc_arrived("ghost", 1.0)
    assert table.clients() == []


def test_claim_records_holder_time_and_version(table: ClaimTable) -> None:
    """_set_holder stores the claimant and the claim time it is given (the watchdog arms from it)."""
    table.client_alive("a")
    v = table.version
    table.claim(2, "a", 7.5)
    assert table.version == v + 1 and table.holder(2) == "a"
    assert table.held_since("a")[1] == 7.5
    table.claim(2, "a", 9.0)  # idempotent for the holder: the original claim time stays
    assert table.version == v + 1 and table.held_since("a")[1] == 7.5


# ---- client loss -------------------------------------------------------------------------------
def test_a_lost_commander_is_reported_although_it_holds_nothing(table: ClaimTable) -> None:
    """A client that only commands (no claim) is reported once, so its motions can be stopped."""
    table.client_alive("op")
    table.client_gone("op", 1.0)
    assert table.clients() == []
    assert table.check(1.001) == [Loss("op", ZNC_CLIENT_LOST)]
    assert table.check(1.002) == []


def test_a_timed_out_holder_loses_all_its_claims(table: ClaimTable) -> None:
    """0x8F02 on what it supplied; a claim it never supplied is released without a fault."""
    table.client_alive("a")
    table.claim(1, "a", 0.0)
    table.plctonc_arrived("a", 1.0)
    table.claim(2, "a", 1.2)  # after its last frame: never supplied
    assert table.check(1.5) == []
    assert table.check(1.51) == [Loss("a", ZNC_PLCTONC_TIMEOUT, (1,), (2,))]
    assert table.claims() == {} and table.clients() == ["a"]  # still alive: it may claim again


def test_a_token_that_comes_back_before_the_check_is_no_loss(table: ClaimTable) -> None:
    table.client_alive("a")
    table.claim(1, "a", 0.0)
    table.client_gone("a", 1.0)
    table.client_alive("a")
    assert table.check(1.001) == [] and table.holder(1) == "a"


# ---- the NC's own stall (issue 8: 0x8F02 12 ms after resuming) ----------------------------------
def test_regression_older_frame_after_grace_does_not_fault(table: ClaimTable) -> None:
    """The bug: the NC was frozen 0.7 s; at the first cycle after it, grace() set the holder's
    PLCTONC time to 'now', then a frame that had arrived before the stall (HLC-corrected arrival
    0.69 s earlier) was processed and set it back: 0x8F02 a few ms after resuming, blamed on a
    live client. The arrival time never goes backwards now."""
    table.client_alive("a")
    table.claim(1, "a", 0.0)
    table.plctonc_arrived("a", 10.000)  # the last frame processed before the stall
    # the NC is frozen from 10.005 to 10.705; first cycle after it:
    table.grace(10.705, since=10.005)
    table.plctonc_arrived("a", 10.008)  # queued before the stall, processed after it
    assert table.check(10.717) == []    # 12 ms after resuming: the observed fault
    assert table.check(11.2) == []      # nothing is blamed within a watchdog timeout of the resume
    table.plctonc_arrived("a", 10.72)   # the client's fresh frames
    assert table.check(11.21) == []
    assert faults(table.check(11.221)) == [(1, ZNC_PLCTONC_TIMEOUT)]  # and a real silence still faults


def test_plctonc_time_never_goes_backwards(table: ClaimTable) -> None:
    table.client_alive("a")
    table.claim(1, "a", 0.0)
    table.plctonc_arrived("a", 2.0)
    table.plctonc_arrived("a", 1.0)  # processed late, arrived earlier
    assert table.check(2.5) == [] and faults(table.check(2.51)) == [(1, ZNC_PLCTONC_TIMEOUT)]


def test_token_lost_across_an_nc_stall_gets_time_to_come_back(table: ClaimTable) -> None:
    """A stall longer than the clients' view of the NC's lease drops their links; their tokens
    vanish and come back within milliseconds of the resume. Not a loss."""
    table.client_alive("a")
    table.client_alive("b")
    table.claim(1, "a", 0.0)
    table.plctonc_arrived("a", 10.0)
    table.grace(10.8, since=10.0)
    table.client_gone("a", 10.805)
    table.client_gone("b", 10.806)
    assert table.check(10.806) == [] and table.holder(1) == "a"
    table.client_alive("a")  # reconnected
    table.plctonc_arrived("a", 10.82)
    assert table.check(11.2) == []
    assert table.check(11.31) == [Loss("b", ZNC_CLIENT_LOST)]  # b did not come back
    assert table.holder(1) == "a"


def test_token_lost_across_a_stall_is_not_blamed_for_a_second_stall_right_after() -> None:
    """The NC stopped twice in a row (a router test stopped it again right after its resume): the token lost across
    the first stall could not come back while the second one lasted; the second stall must not take the first one's
    excuse away (it replaced it: the holder was blamed with 0x8F01)."""
    t = held_by_a()
    t.plctonc_arrived("a", 9.99)
    t.grace(11.0, since=10.0)            # a lease stall: 2 s to come back
    t.client_gone("a", 11.01)            # its link dropped across it
    t.grace(12.9, since=11.2)            # stopped again right after
    assert t.check(12.91) == [] and t.holder(1) == "a"
    assert t.check(14.89) == []          # 2 s from the second stall's end
    t.client_alive("a", 14.0)
    assert t.check(14.01) == [] and t.holder(1) == "a"


def test_a_token_lost_across_two_stalls_that_does_not_come_back_is_a_loss() -> None:
    t = held_by_a()
    t.grace(11.0, since=10.0)
    t.client_gone("a", 11.01)
    t.grace(11.3, since=11.2)            # a short one within the first one's window (0.1 s: its own window 0.5 s)
    assert t.check(13.29) == []          # the first one's 2 s, from the second one's end (it could not come back then)
    assert t.check(13.31) == [Loss("a", ZNC_CLIENT_LOST, (1,))]


def test_token_lost_long_after_a_stall_is_a_loss_at_once(table: ClaimTable) -> None:
    table.client_alive("a")
    table.claim(1, "a", 0.0)
    table.grace(10.8, since=10.0)
    table.client_gone("a", 20.0)
    assert table.check(20.001) == [Loss("a", ZNC_CLIENT_LOST, (1,))]


def test_token_lost_across_a_lease_stall_gets_2_s_and_a_restarted_watchdog() -> None:
    """Issue 8: a stall of at least half the NC's lease (its own session could not renew or
    process the links meanwhile) drops every link; a client behind a router may take well over a
    watchdog timeout to come back. It gets LEASE_STALL_GRACE (2 s): no loss reaction meanwhile, and
    when its token is seen again the watchdog of its claims counts from then (its frames could not
    arrive while it was disconnected)."""
    t = ClaimTable([1, 2, 3], watchdog_timeout=0.5, lease=0.5)
    assert LEASE_STALL_GRACE == 2.0
    for c in ("a", "b"):
        t.client_alive(c, 0.0)
    t.claim(1, "a", 0.0)
    t.claim(2, "b", 0.0)
    t.plctonc_arrived("a", 10.0)
    t.plctonc_arrived("b", 10.0)
    t.grace(10.25, since=10.0)           # exactly half the lease
    t.client_gone("a", 10.26)            # the links dropped: both tokens gone after the resume
    t.client_gone("b", 10.27)
    assert t.check(10.3) == [] and t.check(11.9) == []   # far beyond the watchdog (0.5 s): no reaction
    assert t.holder(1) == "a" and t.holder(2) == "b"
    t.client_alive("a", 12.0)            # a back 1.74 s after it vanished
    # its watchdog restarted at 12.0: no 0x8F02 for the frames it could not send meanwhile
    assert t.check(12.01) == [] and t.check(12.26) == []  # b is still within its window too
    assert t.check(12.28) == [Loss("b", ZNC_CLIENT_LOST, (2,))]  # b never came back: loss at 10.27 + 2 s
    assert t.check(12.5) == []
    assert faults(t.check(12.501)) == [(1, ZNC_PLCTONC_TIMEOUT)]  # a real silence after the return still faults


def held_by_a() -> ClaimTable:
    """A table with a lease of 0.5 s (the NC's default) whose axis 1 client "a" claimed at 0 s."""
    t = ClaimTable([1], watchdog_timeout=0.5, lease=0.5)
    t.client_alive("a", 0.0)
    t.claim(1, "a", 0.0)
    return t


def test_restarted_watchdog_follows_the_returned_clients_frames() -> None:
    t = held_by_a()
    t.plctonc_arrived("a", 10.0)
    t.grace(11.0, since=10.0)
    t.client_gone("a", 11.01)
    t.client_alive("a", 12.5)
    t.plctonc_arrived("a", 12.6)
    assert t.check(13.1) == [] and faults(t.check(13.11)) == [(1, ZNC_PLCTONC_TIMEOUT)]


def test_short_stall_keeps_the_watchdog_window_not_2_s() -> None:
    """A stall shorter than half the lease (a loaded machine: the links stayed up): a token that
    vanishes right after it gets only reconnect_grace (watchdog_timeout), not 2 s."""
    t = held_by_a()
    t.grace(10.2, since=10.0)            # 0.2 s < 0.25 s
    t.client_gone("a", 10.21)
    assert t.check(10.70) == []
    assert t.check(10.711) == [Loss("a", ZNC_CLIENT_LOST, (1,))]


def test_unarmed_claim_stays_unwatched_after_a_return() -> None:
    """A holder that never sent PLCTONC is not watched; its return after a stall does not arm it."""
    t = held_by_a()
    t.grace(11.0, since=10.0)
    t.client_gone("a", 11.01)
    t.client_alive("a", 12.0)
    assert t.check(20.0) == [] and t.holder(1) == "a"


def test_token_lost_without_a_stall_is_a_loss_at_once_with_a_lease() -> None:
    t = held_by_a()
    t.client_gone("a", 5.0)
    assert t.check(5.001) == [Loss("a", ZNC_CLIENT_LOST, (1,))]


def test_a_lease_stall_is_never_blamed_even_when_the_token_outlives_the_watchdog() -> None:
    """Without the restart, a holder back 1 s after a lease stall would fault with 0x8F02 the
    moment its token is seen (its last frame is older than the watchdog): the NC's stall blamed
    on the client."""
    t = held_by_a()
    t.plctonc_arrived("a", 9.99)
    t.grace(10.6, since=10.0)
    t.client_gone("a", 10.61)
    t.client_alive("a", 11.6)
    assert t.check(11.6) == [] and t.check(11.601) == []


# ---- hand-over ---------------------------------------------------------------------------------
def test_hand_over_moves_the_claim_and_arms_the_watchdog(table: ClaimTable) -> None:
    table.client_alive("a")
    table.client_alive("b")
    table.claim(1, "a", 0.0)
    table.plctonc_arrived("a", 1.0)
    v = table.version
    assert table.hand_over(1, "a", "b", 1.1) is True
    assert table.holder(1) == "b" and table.version == v + 1
    assert table.held_since("b")[0] == 1.1 and table.held_since("a")[0] == float("inf")
    # the new holder's watchdog counts from the hand-over, even before its first frame
    assert table.check(1.6) == []
    assert table.check(1.61) == [Loss("b", ZNC_PLCTONC_TIMEOUT, (1,))]


def test_hand_over_then_the_new_holders_frames_feed_the_watchdog(table: ClaimTable) -> None:
    table.client_alive("a")
    table.client_alive("b")
    table.claim(1, "a", 0.0)
    table.plctonc_arrived("b", 1.05)  # before the hand-over: does not count for the claim
    table.hand_over(1, "a", "b", 1.1)
    table.plctonc_arrived("b", 1.2)
    assert table.check(1.7) == []
    assert faults(table.check(1.71)) == [(1, ZNC_PLCTONC_TIMEOUT)]


def test_hand_over_refusals(table: ClaimTable) -> None:
    table.client_alive("a")
    table.client_alive("b")
    for args, code in (((1, "a", "b", 0.0), ACCESS_DENIED),   # not claimed
                       ((9, "a", "b", 0.0), 0x4012)):
        with pytest.raises(NcError) as ei:
            table.hand_over(*args)
        assert ei.value.code == code
    table.claim(1, "a", 0.0)
    with pytest.raises(NcError) as ei:
        table.hand_over(1, "b", "b", 0.1)  # b is not the holder
    assert ei.value.code == ACCESS_DENIED and "'a'" in str(ei.value)
    with pytest.raises(NcError) as ei:
        table.hand_over(1, "a", "ghost", 0.1)  # no liveliness token
    assert ei.value.code == ACCESS_DENIED and "ghost" in str(ei.value)
    with pytest.raises(NcError) as ei:
        table.hand_over(1, "a", "no spaces", 0.1)
    assert ei.value.code == 0x706
    assert table.hand_over(1, "a", "a", 0.1) is False and table.holder(1) == "a"


def test_a_quiet_table_loses_a_silent_client_in_the_same_check_as_a_full_one() -> None:
    """check() skips the clients while every one was quiet at the last check and nothing but PLCTONC arrivals
    changed since: a client that goes silent is lost at the same check, to the same float, as when every check
    looks at every client."""
    t = ClaimTable([1, 2, 3], watchdog_timeout=0.5)
    for c in ("a", "b"):
        t.client_alive(c, 0.0)
    t.claim(1, "a", 0.0)
    t.claim(2, "b", 0.0)
    t.plctonc_arrived("a", 0.1)
    t.plctonc_arrived("b", 0.3)
    assert t.check(0.35) == []  # (quiet from here: the oldest arrival is a's, 0.1)
    t.plctonc_arrived("b", 0.55)  # b goes on, a is silent
    assert t.check(0.6) == []  # 0.6 - 0.1 = 0.5: not late yet
    assert [(x.client, x.code, x.faulted) for x in t.check(0.6 + 1e-9)] == [("a", ZNC_PLCTONC_TIMEOUT, (1,))]


def test_a_claim_armed_by_an_earlier_frame_after_a_quiet_check_still_times_out() -> None:
    """A claim whose watchdog is not armed yet (no frame since the claim) keeps check() looking at every client:
    a frame processed later with an earlier arrival time arms it, and the loss comes on time."""
    t = ClaimTable([1], watchdog_timeout=0.5)
    t.client_alive("a", 0.0)
    t.plctonc_arrived("a", 0.0)
    t.claim(1, "a", 1.0)
    assert t.check(1.2) == []
    t.plctonc_arrived("a", 1.1)  # arrived before the check, processed after it
    assert t.check(1.6) == []
    assert faults(t.check(1.65)) == [(1, ZNC_PLCTONC_TIMEOUT)]


def test_the_quiet_watchdog_matches_the_full_one_on_random_histories() -> None:
    """Random tokens, claims, releases, hand-overs, PLCTONC arrivals (some processed late), NC stalls and checks on
    two tables: one as it runs, one that looks at every client in every check. Same losses, same claims."""
    import math
    import random

    rng = random.Random(8)
    for _ in range(60):
        fast, full = ClaimTable([1, 2, 3, 4], 0.5), ClaimTable([1, 2, 3, 4], 0.5)
        now = 0.0
        for _ in range(300):
            now += rng.choice([0.0, 0.01, 0.05, 0.1, 0.2, 0.3])
            op = rng.random()
            client = rng.choice("abc")
            axis, to, age = rng.choice([1, 2, 3, 4]), rng.choice("abc"), rng.choice([0.0, 0.0, 0.05, 0.3])
            for t in (fast, full):
                try:
                    if op < 0.05:
                        t.client_alive(client, now)
                    elif op < 0.08:
                        t.client_gone(client, now)
                    elif op < 0.16:
                        t.claim(axis, client, now)
                    elif op < 0.19:
                        t.release(axis, client)
                    elif op < 0.21:
                        t.hand_over(axis, client, to, now)
                    elif op < 0.55:
                        t.plctonc_arrived(client, now - age)
                    elif op < 0.56:
                        t.grace(now, now - 0.2)
                except NcError:
                    pass
            full._quiet = (-1, -1, math.inf)  # (every client looked at)
            a, b = fast.check(now), full.check(now)
            assert a == b, (now, a, b)
            assert fast.claims() == full.claims() and fast.clients() == full.clients()
