"""Print the import edges between the repository's packages (``package -> package``), from the source.

Every ``import x`` / ``from x import ...`` of every module (also inside functions: a lazy import is an
edge too) is read with ``ast``; relative imports resolve to their own package. An edge is printed with
the number of import statements that make it and, with ``-v``, where they are.

    python bench/import_graph.py            # the edges
    python bench/import_graph.py -v         # and the modules that make them
    python bench/import_graph.py --check    # exit 1 if a client package imports nc_server

Used by tests/test_import_graph.py (the same rule as ``--check``).
"""
from __future__ import annotations

import argparse
import ast
import sys
from collections import defaultdict
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
#: the repository's top-level Python packages
PACKAGES = ("nc_schema", "nc_link", "plc_client", "nc_ads", "nc_tools", "nc_opcua", "nc_web", "nc_server", "nc_sim")
#: packages that may never import nc_server (issue 16: no client -> server edge)
CLIENTS = ("nc_schema", "nc_link", "plc_client", "nc_ads", "nc_tools", "nc_opcua", "nc_web")
FORBIDDEN = {(c, "nc_server") for c in CLIENTS}


def _imported(tree: ast.AST, module: str, is_pkg: bool) -> list[tuple[str, int]]:
    """(absolute module name, line) of every import in ``tree`` of ``module``."""
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out += [(a.name, node.lineno) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                parts = module.split(".")
                base = parts if is_pkg else parts[:-1]
                base = base[:len(base) - (node.level - 1)]
                name = ".".join(base + ([node.module] if node.module else []))
            else:
                name = node.module or ""
            out.append((name, node.lineno))
    return out


def edges(root: Path = ROOT) -> dict[tuple[str, str], list[str]]:
    """(from package, to package) -> ["path:line", ...] for every import between two packages."""
    found: dict[tuple[str, str], list[str]] = defaultdict(list)
    for pkg in PACKAGES:
        for path in sorted((root / pkg).rglob("*.py")):
            rel = path.relative_to(root)
            is_pkg = path.name == "__init__.py"
            module = ".".join(rel.with_suffix("").parts[:-1] if is_pkg else rel.with_suffix("").parts)
            tree = ast.parse(path.read_text(encoding="utf-8"), str(rel))
            for name, line in _imported(tree, module, is_pkg):
                top = name.split(".")[0]
                if top in PACKAGES and top != pkg:
                    found[(pkg, top)].append(f"{rel}:{line}")
    return dict(found)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("-v", "--verbose", action="store_true", help="list the imports that make each edge")
    ap.add_argument("--check", action="store_true", help="exit 1 on a client -> nc_server edge")
    args = ap.parse_args(argv)
    e = edges()
    for (a, b), where in sorted(e.items()):
        bad = "   <- forbidden" if (a, b) in FORBIDDEN else ""
        print(f"{a} -> {b}  ({len(where)}){bad}")
        if args.verbose:
            for w in where:
                print(f"    {w}")
    bad = sorted(k for k in e if k in FORBIDDEN)
    if args.check and bad:
        print("client -> server edges: " + ", ".join(f"{a} -> {b}" for a, b in bad), file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
