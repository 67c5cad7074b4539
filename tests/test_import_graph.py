"""The package boundaries (issue 16): no client package imports nc_server, and the client link and the
simulation package sit where docs/ARCHITECTURE.md draws them. The edges come from the source
(``bench/import_graph.py``: every import statement, lazy ones inside functions too)."""
from __future__ import annotations

import importlib.util
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def _graph():  # type: ignore[no-untyped-def]
    spec = importlib.util.spec_from_file_location("import_graph", ROOT / "bench" / "import_graph.py")
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_no_client_package_imports_nc_server() -> None:
    g = _graph()
    edges = g.edges()
    bad = {f"{a} -> {b}": where for (a, b), where in edges.items() if (a, b) in g.FORBIDDEN}
    assert not bad, f"client -> server imports: {bad}"


def test_the_link_imports_no_client_and_nothing_imports_the_simulation() -> None:
    edges = _graph().edges()
    assert {b for a, b in edges if a == "nc_link"} <= {"nc_schema"}, edges
    assert {b for a, b in edges if a == "nc_schema"} == set(), edges
    assert not [a for a, b in edges if b == "nc_sim"], edges


def test_the_walk_sees_lazy_and_relative_imports(tmp_path: Path) -> None:
    """A guard that cannot see an import inside a function would pass on the very edge it is for."""
    g = _graph()
    pkg = tmp_path / "plc_client"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("from .a import x\n")
    (pkg / "a.py").write_text("def f():\n    from nc_server.server import claims\n")
    (tmp_path / "nc_server").mkdir()
    (tmp_path / "nc_server" / "__init__.py").write_text("")
    edges = g.edges(tmp_path)
    assert ("plc_client", "nc_server") in edges and edges[("plc_client", "nc_server")] == ["plc_client/a.py:2"]


def test_importing_the_clients_loads_no_nc_server_module() -> None:
    """At run time too: the client packages import without any nc_server module."""
    code = ("import sys, plc_client, plc_client.runtime, nc_ads.nc_device, nc_tools.status, nc_opcua.server,"
            " nc_opcua.cli, nc_web.app, nc_web.cli, nc_link, nc_schema;"
            "print(sorted(m for m in sys.modules if m == 'nc_server' or m.startswith('nc_server.')))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, timeout=60)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "[]", out.stdout
