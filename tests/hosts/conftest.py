"""Fixtures of the tests across hosts: the images (built once per session by the cached
deploy/images/build.sh) and the figures they measured (printed at the end of the run).

Skips, each with its reason: no docker engine / compose tool (Docker tests), no root or no
``ip netns`` (namespace tests), an image build that could not download what it needs.
"""
from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import time
from pathlib import Path
from typing import Any, Iterator

import pytest

from znc_testing.hostlib import BUILD_SH, FIGURES, docker_unavailable


@pytest.fixture(scope="session")
def znc_image() -> str:
    """The app image tag (``zenoh-nc:<hash>``), built or reused by deploy/images/build.sh."""
    reason = docker_unavailable()
    if reason:
        pytest.skip(reason)
    t0 = time.monotonic()
    r = subprocess.run(["bash", str(BUILD_SH)], env=dict(os.environ, PYTHON=sys.executable),
                       capture_output=True, text=True, timeout=3600)
    dt = time.monotonic() - t0
    out = (r.stdout + r.stderr).strip()
    if r.returncode == 3:
        pytest.skip(f"docker engine not reachable (build.sh): {out.splitlines()[-1:]}")
    if r.returncode == 4:
        pytest.skip(f"image build needs the network and could not download: {out.splitlines()[-1:]}")
    if r.returncode != 0:
        pytest.fail(f"deploy/images/build.sh failed ({r.returncode}):\n{out[-3000:]}")
    FIGURES["builds"].append({"seconds": round(dt, 1), "log": [ln for ln in r.stdout.splitlines()
                                                               if ln.startswith("build.sh: ")]})
    m = re.search(r"(zenoh-nc:[0-9a-f]{16}) \(= zenoh-nc:latest\)", r.stdout)
    assert m, f"build.sh printed no image tag:\n{out[-2000:]}"
    return m.group(1)


@pytest.fixture(scope="session")
def figures() -> Iterator[dict[str, list[dict[str, Any]]]]:
    yield FIGURES


def pytest_terminal_summary(terminalreporter: Any) -> None:
    """Print the measured figures (image build, reaction and recovery times)."""
    if not (FIGURES["scenarios"] or FIGURES["builds"]):
        return
    tr = terminalreporter
    tr.section("tests across hosts: figures")
    for b in FIGURES["builds"]:
        tr.write_line(f"images: {b['seconds']:.1f} s ({'; '.join(x[len('build.sh: '):] for x in b['log'])})")
    if FIGURES["scenarios"]:
        tr.write_line(f"{'where':8} {'scenario':34} {'reaction [s]':>12} {'recovery [s]':>12}  notes")
        for s in FIGURES["scenarios"]:
            react = "-" if s.get("react_s") is None else f"{s['react_s']:.2f}"
            rec = "-" if s.get("recover_s") is None else f"{s['recover_s']:.2f}"
            tr.write_line(f"{s['where']:8} {s['scenario']:34} {react:>12} {rec:>12}  {s.get('notes', '')}")
    path = os.environ.get("ZNC_HOSTS_FIGURES")
    if path:
        Path(path).write_text(json.dumps(FIGURES, indent=1))
