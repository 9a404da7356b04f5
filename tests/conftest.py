"""Shared test fixtures: where the real data sets live, and skipping cleanly without them."""
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = REPO.parent / "shared" / "data"


def shared_data(*parts) -> Path:
    """Path of a real data set under ../shared/data, or skip the test when it is absent."""
    path = SHARED_DATA.joinpath(*parts)
    if not path.exists():
        pytest.skip(f"real data not present: {path}")
    return path


@pytest.fixture
def dp_tpu_dir() -> Path:
    return shared_data("dp-tpu")
