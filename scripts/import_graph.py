"""The floor plan of sltwin, derived from the source: static imports between packages and modules,
import cycles, upward imports, and functions longer than a limit.

Every ``import`` / ``from ... import`` statement counts, wherever it stands (module level or
inside a function: a deferred import is still an arrow), except those inside ``if TYPE_CHECKING:``.
Imports written as strings (``importlib.import_module("...")``) are not seen; the layering test
refuses them in the packages so that no arrow hides.

Layers, bottom to top (a package may import only packages below it)::

    unwrap < calib < twin_mapping < synth < experiments < reports < sltwin

``bench`` (benchmarks) sits above all of them; tests and scripts are not part of the plan.

    python scripts/import_graph.py              # package graph, cycles, upward imports
    python scripts/import_graph.py --functions  # also the functions longer than 80 lines
"""
from __future__ import annotations

import argparse
import ast
import sys
from collections import defaultdict
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
LAYERS = ("unwrap", "calib", "twin_mapping", "synth", "experiments", "reports", "sltwin", "bench")
"""Packages from the bottom layer to the top one."""
DRIVERS = ("twin_mapping/blender_template.py", "twin_mapping/blender_driver.py")
"""Files that run inside Blender's Python (never imported by the toolkit)."""


def package_files(repo: Path = REPO) -> dict[str, Path]:
    """{module name: path} of every Python file of the layered packages (drivers left out)."""
    out = {}
    for pkg in LAYERS:
        root = repo / pkg
        if not root.is_dir():
            continue
        for path in sorted(root.rglob("*.py")):
            rel = path.relative_to(repo).as_posix()
            if rel in DRIVERS:
                continue
            parts = list(path.relative_to(repo).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts = parts[:-1]
            out[".".join(parts)] = path
    return out


def _is_type_checking(node: ast.If) -> bool:
    t = node.test
    return (isinstance(t, ast.Name) and t.id == "TYPE_CHECKING") or (
        isinstance(t, ast.Attribute) and t.attr == "TYPE_CHECKING")


def _import_nodes(tree: ast.AST):
    stack = [tree]
    while stack:
        node = stack.pop()
        if isinstance(node, ast.If) and _is_type_checking(node):
            stack.extend(node.orelse)
            continue
        if isinstance(node, (ast.Import, ast.ImportFrom)):
            yield node
        stack.extend(ast.iter_child_nodes(node))


def module_imports(name: str, path: Path, modules: dict) -> set[str]:
    """Modules of the plan that ``name`` imports (``from pkg import mod`` resolves to ``pkg.mod``
    when that is a module, else to the package ``pkg``)."""
    is_pkg = path.name == "__init__.py"
    here = name.split(".") if is_pkg else name.split(".")[:-1]
    found = set()
    for node in _import_nodes(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        else:
            if node.level:
                base = here[:len(here) - node.level + 1]
                mod = ".".join(base + ([node.module] if node.module else []))
            else:
                mod = node.module
            targets = [f"{mod}.{a.name}" if f"{mod}.{a.name}" in modules else mod for a in node.names]
        for t in targets:
            while t and t not in modules:      # "calib.io.loader.x" -> "calib.io.loader"
                t = t.rpartition(".")[0]
            if t and t != name:
                found.add(t)
    return found


def module_graph(repo: Path = REPO) -> dict[str, set[str]]:
    modules = package_files(repo)
    return {name: module_imports(name, path, modules) for name, path in modules.items()}


def package_graph(graph: dict) -> dict[str, dict[str, int]]:
    """{package: {imported package: number of importing modules}}."""
    out = defaultdict(lambda: defaultdict(int))
    for mod, deps in graph.items():
        a = mod.split(".")[0]
        for b in {d.split(".")[0] for d in deps}:
            if b != a:
                out[a][b] += 1
    return {a: dict(v) for a, v in out.items()}


def upward_imports(graph: dict) -> list[tuple[str, str]]:
    """(module, imported module) pairs where the imported package sits above the importer's."""
    rank = {p: i for i, p in enumerate(LAYERS)}
    return sorted((m, d) for m, deps in graph.items() for d in deps
                  if rank[d.split(".")[0]] > rank[m.split(".")[0]])


def cycles(graph: dict) -> list[list[str]]:
    """Strongly connected components of more than one module (Tarjan), each sorted."""
    index, low, on, stack, out = {}, {}, set(), [], []
    counter = [0]

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in graph.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    sys.setrecursionlimit(10000)
    for v in sorted(graph):
        if v not in index:
            visit(v)
    return sorted(out)


def string_imports(repo: Path = REPO) -> list[str]:
    """``module: line`` of every ``importlib.import_module`` / ``__import__`` call in the packages."""
    out = []
    for name, path in package_files(repo).items():
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Call):
                f = node.func
                fn = f.attr if isinstance(f, ast.Attribute) else getattr(f, "id", "")
                if fn in ("import_module", "__import__"):
                    out.append(f"{name}:{node.lineno}")
    return out


def long_functions(limit: int = 80, repo: Path = REPO, extra=("tests", "scripts")) -> list[tuple[int, str]]:
    """(lines, 'path:function') of every function longer than ``limit`` lines, longest first."""
    paths = list(package_files(repo).values())
    for d in extra:
        paths += sorted((repo / d).rglob("*.py"))
    out = []
    for path in paths:
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                n = node.end_lineno - node.lineno + 1
                if n > limit:
                    out.append((n, f"{path.relative_to(repo).as_posix()}:{node.name}"))
    return sorted(out, reverse=True)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repo", default=str(REPO), help="repository root (default: this one)")
    ap.add_argument("--functions", action="store_true", help="also list functions over --limit lines")
    ap.add_argument("--limit", type=int, default=80)
    args = ap.parse_args(argv)
    repo = Path(args.repo)
    graph = module_graph(repo)
    print(f"{len(graph)} modules; package graph (importer -> imported: number of importing modules):")
    for a, deps in sorted(package_graph(graph).items(), key=lambda kv: LAYERS.index(kv[0])):
        print(f"  {a:13} -> " + ", ".join(f"{b} ({n})" for b, n in sorted(deps.items(),
                                                                          key=lambda kv: LAYERS.index(kv[0]))))
    up = upward_imports(graph)
    print(f"upward imports: {len(up)}")
    for m, d in up:
        print(f"  {m} -> {d}")
    cyc = cycles(graph)
    print(f"import cycles: {len(cyc)}")
    for c in cyc:
        print("  " + " <-> ".join(c))
    s = string_imports(repo)
    print(f"imports by string: {len(s)}" + (" (" + ", ".join(s) + ")" if s else ""))
    if args.functions:
        fl = long_functions(args.limit, repo)
        print(f"functions over {args.limit} lines: {len(fl)}")
        for n, f in fl:
            print(f"  {n:4d}  {f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
