"""The core's seams (issue 16): jobs and stages see the NC through CoreContext only, and the cycle
is a pipeline readable at run time with per-stage timing."""
from __future__ import annotations

import ast
import importlib.util
import sys
from pathlib import Path

import pytest

from nc_server.core.context import CoreContext
from znc_testing.nc_core import powered

ROOT = Path(__file__).resolve().parents[2]
CORE = ROOT / "nc_server" / "core"


def _seams():  # type: ignore[no-untyped-def]
    spec = importlib.util.spec_from_file_location("core_seams", ROOT / "bench" / "core_seams.py")
    mod = importlib.util.module_from_spec(spec)  # type: ignore[arg-type]
    sys.modules["core_seams"] = mod
    spec.loader.exec_module(mod)  # type: ignore[union-attr]
    return mod


def _context_members() -> set[str]:
    tree = ast.parse((CORE / "context.py").read_text())
    cls = next(n for n in tree.body if isinstance(n, ast.ClassDef) and n.name == "CoreContext")
    out = set()
    for node in cls.body:
        if isinstance(node, ast.FunctionDef):
            out.add(node.name)
        elif isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name):
            out.add(node.target.id)
    return out


def test_nccore_has_every_member_of_the_context() -> None:
    core = powered(2)
    missing = [m for m in _context_members() if not hasattr(core, m)]
    assert not missing
    assert all(not m.startswith("_") for m in _context_members())


def test_jobs_and_stages_use_only_the_context() -> None:
    seams = _seams()
    members = seams.nccore_members(ROOT)
    names = set(members["methods"]) | set(members["attributes"])
    allowed = _context_members()
    for sub in ("jobs", "stages"):
        per_module = seams.uses(ROOT, names, f"nc_server/core/{sub}")
        for module, used in per_module.items():
            assert set(used) <= allowed, (module, sorted(set(used) - allowed))
        for path in (CORE / sub).glob("*.py"):
            assert "from ..nc import" not in path.read_text(), path


def test_no_private_member_of_nccore_is_used_in_the_core_modules() -> None:
    seams = _seams()
    members = seams.nccore_members(ROOT)
    names = set(members["methods"]) | set(members["attributes"])
    used = seams.uses(ROOT, names, "nc_server")
    private = {(m, n) for m, c in used.items() for n in c if n.startswith("_") and not n.startswith("__")}
    assert not private


def test_the_pipeline_is_the_cycle_order_and_times_its_stages() -> None:
    core = powered(2)
    names = [s.name for s in core.pipeline]
    assert names == ["inputs", "profile", "plan ends", "set-points", "jobs", "drive", "probe", "monitoring", "output"]
    for _ in range(3):
        core.step()
    times = core.stage_times()
    assert [t["name"] for t in times] == names
    assert all(t["max_us"] >= t["last_us"] >= 0 for t in times)
    assert sum(t["max_us"] for t in times) > 0


def test_a_bug_in_a_stage_without_axes_leaves_the_step() -> None:
    core = powered(2)

    class Broken:
        name = "broken"

        def run(self, core: CoreContext) -> None:
            raise RuntimeError("injected")

        def rows_at_fault(self, core: CoreContext) -> None:
            return None

    core.pipeline.insert(1, Broken())  # type: ignore[arg-type]
    core.stage_last_ns.append(0)
    core.stage_max_ns.append(0)
    with pytest.raises(RuntimeError):
        core.step()
