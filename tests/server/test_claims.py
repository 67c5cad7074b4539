"""Claim table and watchdog with fake time (no zenoh, no clock)."""
from __future__ import annotations

import pytest

from nc_schema import NcError
from nc_server.server.claims import ACCESS_DENIED, ZNC_CLIENT_LOST, ZNC_PLCTONC_TIMEOUT, ClaimTable


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
    table.client_gone("a")
    assert sorted(table.check(0.2)) == [(1, ZNC_CLIENT_LOST), (2, ZNC_CLIENT_LOST)]
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
    assert table.check(10.51) == [(1, ZNC_PLCTONC_TIMEOUT)]
    assert table.holder(1) is None and table.holder(3) == "b"
    assert table.check(10.89) == []
    assert table.check(10.91) == [(3, ZNC_PLCTONC_TIMEOUT)]


def test_frame_before_claim_does_not_arm(table: ClaimTable) -> None:
    table.client_alive("a")
    table.plctonc_arrived("a", 1.0)
    table.claim(1, "a", 5.0)  # the frame at 1.0 predates the claim
    assert table.check(6.0) == []
    table.plctonc_arrived("a", 6.0)
    assert table.check(6.6) == [(1, ZNC_PLCTONC_TIMEOUT)]


def test_grace_after_nc_stall(table: ClaimTable) -> None:
    table.client_alive("a")
    table.claim(1, "a", 0.0)
    table.plctonc_arrived("a", 0.1)
    table.grace(3.0)  # the NC itself was stopped: nobody is blamed for the gap
    assert table.check(3.2) == []
    assert table.check(3.6) == [(1, ZNC_PLCTONC_TIMEOUT)]


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
