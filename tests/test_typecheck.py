"""mypy over the packages of pyproject.toml's ``[tool.mypy]`` (issue 16): 0 errors, so CI (``make test``)
keeps them so. ``make typecheck`` runs the same command."""
from __future__ import annotations

import importlib.util
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
#: error lines shown in the failure message (CI shows about the last 180 lines of a run)
SHOWN = 40


@pytest.mark.timeout(900)
def test_mypy_finds_no_errors() -> None:
    if importlib.util.find_spec("mypy") is None:
        pytest.skip("mypy is not installed (it comes with the dev extra: pip install -e '.[dev]')")
    # the repository's configuration (pyproject.toml: files, strictness per package) and its cache
    run = subprocess.run([sys.executable, "-m", "mypy"], cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert run.returncode in (0, 1), f"mypy did not run (exit {run.returncode}):\n{run.stdout}\n{run.stderr}"
    errors = [line for line in run.stdout.splitlines() if ": error: " in line]
    shown = "\n".join(errors[:SHOWN])
    more = f"\n... and {len(errors) - SHOWN} more" if len(errors) > SHOWN else ""
    assert len(errors) == 0, f"mypy: {len(errors)} error(s) (make typecheck):\n{shown}{more}"
    assert run.returncode == 0, f"mypy failed without an error line:\n{run.stdout[-3000:]}\n{run.stderr[-3000:]}"
