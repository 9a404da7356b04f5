"""The floor plan holds: no import cycles, no upward imports, no imports hidden in strings, the
package docstrings name exactly the public names, every package's errors derive from one
``ValueError`` root, and ``make bench`` runs every benchmark."""
import ast
import importlib
import re
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "scripts"))
import import_graph  # noqa: E402

PACKAGES = ("unwrap", "calib", "twin_mapping", "synth", "experiments", "reports", "sltwin")
ERROR_ROOTS = {"unwrap": "UnwrapError", "calib": "CalibError", "twin_mapping": "TwinError", "synth": "SynthError",
               "experiments": "ExperimentError", "reports": "ReportError", "sltwin": "CommandError"}


@pytest.fixture(scope="module")
def graph():
    return import_graph.module_graph()


def test_no_import_cycles(graph):
    assert import_graph.cycles(graph) == []


def test_no_package_imports_a_package_above_it(graph):
    assert import_graph.upward_imports(graph) == []
    # the layering is not vacuous: each layer does use the ones below
    pg = import_graph.package_graph(graph)
    assert "unwrap" in pg["calib"] and "calib" in pg["twin_mapping"] and "twin_mapping" in pg["synth"]
    assert "synth" in pg["experiments"] and "experiments" in pg["reports"] and "reports" in pg["sltwin"]
    assert "unwrap" not in pg


def test_no_import_is_hidden_in_a_string():
    assert import_graph.string_imports() == []


def test_no_library_package_holds_a_command_line():
    for name, path in import_graph.package_files().items():
        if name.split(".")[0] in ("unwrap", "calib", "twin_mapping", "synth", "experiments", "reports"):
            tree = ast.parse(path.read_text())
            imported = {a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names}
            assert "argparse" not in imported, name


def test_experiments_take_no_command_line_and_import_no_report(graph):
    """The experiments floor computes; the reports above it lay out what it returns (nothing in
    experiments may reach up into reports, nor parse arguments: the commands do)."""
    names = [n for n in import_graph.package_files() if n.split(".")[0] == "experiments"]
    assert len(names) >= 6, names
    for name in names:
        tree = ast.parse(import_graph.package_files()[name].read_text())
        imported = {a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names}
        imported |= {n.module or "" for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)}
        assert "argparse" not in imported, name
        assert not any(m == "reports" or m.startswith("reports.") for m in imported), name


def test_functions_stay_readable_in_one_sitting():
    long = {f for _, f in import_graph.long_functions(80)}
    assert not long, long


@pytest.mark.parametrize("package", PACKAGES)
def test_package_docstring_names_exactly_the_public_names(package):
    module = importlib.import_module(package)
    named = set(re.findall(r"``([A-Za-z_][A-Za-z0-9_]*)``", module.__doc__))
    public = set(module.__all__)
    assert named == public, {"in the docstring only": sorted(named - public),
                             "in __all__ only": sorted(public - named)}
    assert all(hasattr(module, n) for n in public)


@pytest.mark.parametrize("package", PACKAGES)
def test_every_error_of_a_package_derives_from_its_one_root(package):
    """Error types live in the package's errors.py (a sub-package may have its own errors.py) and
    derive from the package's one root, a ValueError."""
    root = getattr(importlib.import_module(f"{package}.errors"), ERROR_ROOTS[package])
    assert issubclass(root, ValueError)
    for name, path in import_graph.package_files().items():
        if name.split(".")[0] != package:
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ClassDef) and node.name.endswith("Error"):
                assert name.endswith(".errors"), f"{node.name} is defined in {name}, not in an errors.py"
                assert issubclass(getattr(importlib.import_module(name), node.name), root), (name, node.name)


def test_make_bench_runs_every_benchmark():
    from bench.__main__ import BENCHMARKS

    modules = {p.stem for p in (REPO / "bench").glob("*.py") if p.stem not in ("__init__", "__main__")}
    assert {name for name, _, _ in BENCHMARKS} == modules
    assert all("--quick" in args for _, _, args in BENCHMARKS)
