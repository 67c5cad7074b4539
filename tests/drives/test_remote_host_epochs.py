"""nc-drive-sim's choice of outputs (DriveHost._take_rx, no zenoh: a stand-in subscriber): the highest NC epoch is
followed, lower ones refused; outputs that do not fit the host (slot count, AxisIds) are refused BEFORE their epoch
counts, so a misconfigured NC with a higher epoch cannot lock out the right one (docs/standby.md)."""
from __future__ import annotations


import nc_server.core  # noqa: F401  (before the drives: see nc_server/drives/__init__.py)
import numpy as np

from nc_server.core import AxisParams
from nc_server.drives.cia402.image import RxImage
from nc_server.drives.remote import wire
from nc_server.drives.remote.host import DriveHost
from znc_testing.fake_zenoh import FakeSub


def host() -> tuple[DriveHost, FakeSub]:
    h = DriveHost("nc1", "drives1", [AxisParams(), AxisParams()], [1, 2], 0.002, 0.1, 0.05, connect=None)
    sub = FakeSub()
    h._rx_sub, h._ready = sub, True
    return h, sub


def rx(cycle: int, ids: list[int], epoch: int) -> bytes:
    img = RxImage.zeros(len(ids))
    img.cycle = cycle
    return wire.encode_rx(img, None, np.array(ids, dtype=np.uint32), epoch)


def test_the_highest_epoch_is_followed_and_a_lower_one_refused() -> None:
    h, sub = host()
    sub.put(rx(10, [1, 2], 5))
    assert h._take_rx().epoch == 5 and h.epoch == 5
    sub.put(rx(11, [1, 2], 4))
    assert h._take_rx() is None and h.stale_epoch == 1 and h.epoch == 5
    sub.put(rx(12, [1, 2], 7))
    m = h._take_rx()
    assert m.epoch == 7 and h.epoch == 7 and h.takeovers == 2


def test_outputs_that_do_not_fit_are_refused_before_their_epoch_counts() -> None:
    h, sub = host()
    sub.put(rx(10, [1, 2], 5))
    assert h._take_rx() is not None and h.epoch == 5
    sub.put(rx(11, [1, 2, 3], 9))   # a misconfigured NC: three slots
    sub.put(rx(11, [7, 8], 9))      # another: other AxisIds
    assert h._take_rx() is None
    assert h.refused == 2 and h.epoch == 5 and h.takeovers == 1   # its epoch was not adopted
    sub.put(rx(12, [1, 2], 5))      # the right NC goes on
    m = h._take_rx()
    assert m is not None and int(m.image.cycle) == 12 and h.stale_epoch == 0
