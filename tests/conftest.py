"""Shared test fixtures: where the real data sets live, and skipping cleanly without them."""
from pathlib import Path

import numpy as np
import pytest

try:       # property tests run the same examples on every machine and every run (no example database)
    from hypothesis import settings as _hypothesis_settings

    _hypothesis_settings.register_profile("sltwin", derandomize=True, database=None)
    _hypothesis_settings.load_profile("sltwin")
except ImportError:
    pass

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = REPO.parent / "shared" / "data"


_RUNNING = {}


@pytest.hookimpl(tryfirst=True)
def pytest_runtest_setup(item):
    _RUNNING["item"] = item            # before any fixture of the test is set up


def shared_data(*parts) -> Path:
    """Path of a real data set under ../shared/data, or skip the test when it is absent. A test
    that reads it must carry the ``realdata`` marker (``-m "not realdata"`` must leave it out)."""
    item = _RUNNING.get("item")
    if item is not None and item.get_closest_marker("realdata") is None:
        pytest.fail(f"{item.nodeid} reads ../shared/data ({'/'.join(parts)}) without @pytest.mark.realdata")
    path = SHARED_DATA.joinpath(*parts)
    if not path.exists():
        pytest.skip(f"real data not present: {path}")
    return path


@pytest.fixture
def dp_tpu_dir() -> Path:
    return shared_data("dp-tpu")


DESIGN_CAPTURE_TOML = """
[pattern]
steps = [12, 12, 12]
frequencies = [1, 8, 48]

[camera]
size = [64, 48]

[projector]
size = [912, 1140]
"""


@pytest.fixture
def design_capture(tmp_path):
    """A noise-free 16-bit capture in the DESIGN.md layout (1, 8, 48 periods, both orientations,
    64x48 camera); returns (root, {orientation: (true projector coordinate, pattern width)})."""
    import cv2

    from unwrap.patterns import absolute_phase, fringe_intensity
    root = tmp_path / "captures"
    pose = root / "pose_00"
    pose.mkdir(parents=True)
    (root / "capture.toml").write_text(DESIGN_CAPTURE_TOML)
    y, x = np.mgrid[0:48, 0:64].astype(np.float64)
    coords = {"v": (5.0 + 14.1 * x + 0.3 * y, 912), "h": (8.0 + 23.2 * y + 0.2 * x, 1140)}
    for o, (c, extent) in coords.items():
        for f in (1, 8, 48):
            for n in range(12):
                I = fringe_intensity(absolute_phase(c, f, extent), n, 12, A=30000, B=25000)
                cv2.imwrite(str(pose / f"{o}_f{f:03d}_n{n:02d}.png"), np.round(I).astype(np.uint16))
    return root, coords
