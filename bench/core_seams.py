"""How wide the NC core's seam is: NcCore's size and the members of it other modules use.

Parses the tree (ast, nothing imported or run) and prints:

* NcCore's lines, methods and attributes (``self.<name> = ...`` in its methods; properties count
  as methods);
* per module outside ``nc_server/core/nc.py``: the NcCore members it uses as ``core.<name>``,
  ``self.core.<name>``, ``ctx.<name>`` or ``nc.<name>`` (the names the code base gives an NcCore or its
  context), with counts; then the distinct members over all modules and how many are private (``_x``).

Usage::

    python bench/core_seams.py [--root .] [--json] [--only nc_server/core]

``--only``: count the uses in modules under that path only (e.g. ``nc_server/core``: the job kinds and
stages). A name that is no member of NcCore (e.g. ``nc.<x>`` on another object) is not counted.
"""
from __future__ import annotations

import argparse
import ast
import json
import sys
from collections import Counter
from pathlib import Path
from typing import Any

NC_FILE = "nc_server/core/nc.py"
#: names under which modules hold an NcCore (or the narrow context it hands to jobs and stages)
HOLDERS = frozenset({"core", "ctx", "nc"})
SKIP_DIRS = frozenset({".cache", ".venv", ".git", "__pycache__", "build", "dist", ".mypy_cache"})


def _nccore_class(tree: ast.Module) -> ast.ClassDef:
    for node in tree.body:
        if isinstance(node, ast.ClassDef) and node.name == "NcCore":
            return node
    raise SystemExit(f"no class NcCore in {NC_FILE}")


def nccore_members(root: Path) -> dict[str, Any]:
    """Lines, methods and attributes of NcCore (its methods, the class attributes, ``self.x =``)."""
    tree = ast.parse((root / NC_FILE).read_text())
    cls = _nccore_class(tree)
    methods: set[str] = set()
    attrs: set[str] = set()
    for node in cls.body:
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            methods.add(node.name)
            for sub in ast.walk(node):
                targets: list[ast.expr] = []
                if isinstance(sub, ast.Assign):
                    targets = list(sub.targets)
                elif isinstance(sub, (ast.AnnAssign, ast.AugAssign)):
                    targets = [sub.target]
                for t in targets:
                    elts = t.elts if isinstance(t, ast.Tuple) else [t]
                    for e in elts:
                        if isinstance(e, ast.Attribute) and isinstance(e.value, ast.Name) and e.value.id == "self":
                            attrs.add(e.attr)
        elif isinstance(node, (ast.Assign, ast.AnnAssign)):
            targets = node.targets if isinstance(node, ast.Assign) else [node.target]
            attrs.update(t.id for t in targets if isinstance(t, ast.Name))
    attrs -= methods
    lines = (cls.end_lineno or cls.lineno) - cls.lineno + 1
    return {"lines": lines, "file_lines": len((root / NC_FILE).read_text().splitlines()),
            "methods": sorted(methods), "attributes": sorted(attrs)}


def _holder(node: ast.expr) -> bool:
    """``core`` / ``ctx`` / ``nc`` or ``self.core`` / ``self.ctx`` / ``self.nc``."""
    if isinstance(node, ast.Name):
        return node.id in HOLDERS
    return (isinstance(node, ast.Attribute) and node.attr in HOLDERS and isinstance(node.value, ast.Name)
            and node.value.id == "self")


def uses(root: Path, members: set[str], only: str | None) -> dict[str, Counter[str]]:
    """Per module (path relative to root): NcCore member -> number of uses."""
    out: dict[str, Counter[str]] = {}
    for path in sorted(root.rglob("*.py")):
        rel = path.relative_to(root).as_posix()
        if rel == NC_FILE or SKIP_DIRS.intersection(path.relative_to(root).parts):
            continue
        if only is not None and not rel.startswith(only.rstrip("/") + "/") and rel != only:
            continue
        try:
            tree = ast.parse(path.read_text(), filename=rel)
        except (SyntaxError, UnicodeDecodeError):
            continue
        c: Counter[str] = Counter()
        for node in ast.walk(tree):
            if isinstance(node, ast.Attribute) and node.attr in members and _holder(node.value):
                c[node.attr] += 1
        if c:
            out[rel] = c
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--root", default=str(Path(__file__).resolve().parent.parent))
    ap.add_argument("--only", default=None, help="count uses only in modules under this path")
    ap.add_argument("--json", action="store_true", help="print one JSON map instead of the table")
    args = ap.parse_args(argv)
    root = Path(args.root)
    core = nccore_members(root)
    members = set(core["methods"]) | set(core["attributes"])
    per_module = uses(root, members, args.only)
    total: Counter[str] = Counter()
    for c in per_module.values():
        total.update(c)
    private = sorted(n for n in total if n.startswith("_") and not n.startswith("__"))
    summary = {"nccore_lines": core["lines"], "nc_py_lines": core["file_lines"], "methods": len(core["methods"]),
               "attributes": len(core["attributes"]), "members_used_outside": len(total),
               "private_used_outside": len(private), "private_uses": sum(total[n] for n in private),
               "private_names": private, "modules": len(per_module)}
    if args.json:
        json.dump({"summary": summary, "members": total, "per_module": per_module}, sys.stdout, indent=1,
                  sort_keys=True, default=dict)
        print()
        return 0
    for rel, c in per_module.items():
        print(f"{rel}: " + ", ".join(f"{n} x{k}" for n, k in sorted(c.items(), key=lambda x: (-x[1], x[0]))))
    print()
    print(f"NcCore: {summary['nccore_lines']} lines (nc.py {summary['nc_py_lines']}), {summary['methods']} methods, "
          f"{summary['attributes']} attributes")
    print(f"members used outside nc.py: {summary['members_used_outside']} in {summary['modules']} modules; "
          f"private: {summary['private_used_outside']} names, {summary['private_uses']} uses {private}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
