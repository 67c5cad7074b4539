"""A router between the clients and the NC (``nc-router``, real processes on 127.0.0.1): the router
restarted (SIGKILL, started again on the same port), and the client's link cut (connections reset)
or blackholed (nothing carried: only the leases notice), then back. Everything recovers without
restarting the NC or the client; the NC's reaction to losing its client meanwhile follows
ClientLossReaction (0x8F01, stop, disable). The recovery times are printed (bench/recovery.py
repeats them), never asserted."""
from __future__ import annotations

from pathlib import Path

import pytest

from failsafe_recovery import SCENARIOS, measure


@pytest.mark.parametrize("scenario", SCENARIOS)
def test_recovery_without_restarting_nc_or_client(tmp_path: Path, scenario: str) -> None:
    out = measure(tmp_path, scenario, log=lambda s: print("\n" + s))
    assert all(v >= 0 for v in out.values()), out
