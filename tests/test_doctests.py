"""Docstring examples are run, so documentation cannot rot."""
import doctest
import importlib

import pytest

MODULES = ["calib.device", "calib.distortion", "calib.rotation", "calib.marker_phase", "unwrap.patterns", "twin_mapping.euler",
           "calib.ba_kernel", "calib.ba_normal", "calib._blas_threads"]


@pytest.mark.parametrize("name", MODULES)
def test_docstring_examples_run(name):
    result = doctest.testmod(importlib.import_module(name))
    assert result.attempted > 0 and result.failed == 0
