"""Docstring examples are run, so documentation cannot rot: every module of every package whose
docstrings hold an example (``>>>``) is collected here, none listed by hand."""
import doctest
import importlib
import sys

import pytest

sys.path.insert(0, str(__import__("pathlib").Path(__file__).resolve().parents[1] / "scripts"))
import import_graph  # noqa: E402

MODULES = sorted(name for name, path in import_graph.package_files().items()
                 if not name.startswith("bench") and ">>>" in path.read_text())


def test_the_package_modules_carry_examples():
    assert len(MODULES) >= 23, MODULES


@pytest.mark.parametrize("name", MODULES)
def test_docstring_examples_run(name):
    module = importlib.import_module(name)   # not getattr(package, ...): synth.renderer.render is also a function
    finder = doctest.DocTestFinder()
    runner = doctest.DocTestRunner(optionflags=doctest.ELLIPSIS)
    tests = [t for t in finder.find(module) if t.examples]
    for t in tests:
        runner.run(t)
    result = runner.summarize(verbose=False)
    assert result.attempted > 0 and result.failed == 0, f"{name}: {result.failed} of {result.attempted} failed"
