"""Bounded runs of the atheris fuzz targets (``make test``; the long run is ``make fuzz``).

Each target (``tests/fuzz/fuzz_<name>.py``) runs in a subprocess of its own for at most
``FUZZ_BOUND_TIME`` seconds (default 4) or ``FUZZ_BOUND_RUNS`` inputs, with a fixed libFuzzer seed,
on a fresh corpus made from its seeds plus the committed regression inputs of
``tests/fuzz/regressions/<name>/`` (if any). A crash or a stall fails the
test with the input (hex) and the target's output.
One input taking more than 120 s counts as a stall (generous: the machine may be loaded). Skipped when atheris is not installed; the retain
target is skipped until ``nc_server.server.retain`` exists.
"""
from __future__ import annotations

import importlib.util
import os
from pathlib import Path

import pytest

from tests.fuzz import _runner

pytestmark = pytest.mark.skipif(importlib.util.find_spec("atheris") is None,
                                reason="atheris is not installed (pip install -e '.[dev]')")

BOUND_TIME = int(os.environ.get("FUZZ_BOUND_TIME", "4"))
BOUND_RUNS = int(os.environ.get("FUZZ_BOUND_RUNS", "20000"))
REGRESSIONS = Path(__file__).resolve().parent / "regressions"


@pytest.mark.timeout(600)
@pytest.mark.parametrize("target", _runner.TARGETS)
def test_bounded_fuzz_run_finds_nothing(target: str, tmp_path: Path) -> None:
    extra = ["-seed=1"]
    reg = REGRESSIONS / target
    if reg.is_dir():
        extra.append(str(reg))  # read at start (libFuzzer adds new inputs to the first folder only)
    res = _runner.run_target(target, tmp_path / "corpus", tmp_path / "artifacts", BOUND_TIME, runs=BOUND_RUNS,
                             timeout=120, extra=extra, wall_timeout=540)
    if res.skipped:
        pytest.skip(res.output.strip().splitlines()[-1])
    assert res.ok, res.report()
    assert res.runs > 0, res.report()  # it really ran inputs
