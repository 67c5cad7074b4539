"""``count_nonzero(a)``: numpy's C function behind ``np.count_nonzero`` for a whole array.

``np.count_nonzero`` is a Python wrapper (array-function dispatch, the ``axis`` and ``keepdims`` arguments)
around the C function; on the small arrays of a drive's cycle (one entry per axis) the wrapper costs several
times the count itself, and the simulated drives count about ten times per NC cycle, the core (output, monitoring) a few times more. The result is the same
(the wrapper calls this function when no axis is given). Where numpy does not offer it under either of its
module names (numpy 2: ``numpy._core``, 1.26: ``numpy.core``), the public function.

It may import: numpy.
"""
from __future__ import annotations

import importlib
from typing import Any, Callable, cast

import numpy as np


def _find() -> Callable[[Any], int]:
    for module in ("numpy._core.multiarray", "numpy.core.multiarray"):
        try:
            f = getattr(importlib.import_module(module), "count_nonzero", None)
        except ImportError:
            continue
        if callable(f):
            return cast(Callable[[Any], int], f)
    return np.count_nonzero  # pragma: no cover


count_nonzero: Callable[[Any], int] = _find()
