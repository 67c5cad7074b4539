"""``count_nonzero(a)``: numpy's C function behind ``np.count_nonzero`` (:mod:`nc_server.core.npcount`, kept here
for the drives' imports).

It may import: nc_server.core.npcount.
"""
from __future__ import annotations

from ..core.npcount import count_nonzero

__all__ = ["count_nonzero"]
