"""Helpers of the dataset tests: a small system on disk and small export configs."""
import json
from pathlib import Path

import numpy as np

from calib.io.calibration_json import system_to_dict

from synth_helpers import small_system

REPO = Path(__file__).resolve().parents[1]
MESHES = REPO.parent / "shared" / "data" / "meshes"


def small_system_file(folder, scale: int = 4) -> Path:
    """calibration.json of the default system with the camera reduced ``scale`` times."""
    path = Path(folder) / "system.json"
    path.write_text(json.dumps(system_to_dict(small_system(scale))))
    return path


def tiny_config(folder, samples: int = 3, extra: str = "", effects: str = "", **kw) -> Path:
    """An export TOML on the 160x120 system: spheres, blobs and planes, two frequencies, v only."""
    folder = Path(folder)
    small_system_file(folder)
    freqs = kw.get("frequencies", "[1, 8]")
    steps = kw.get("steps", 4)
    text = f"""
[export]
samples = {samples}
seed = {kw.get('seed', 7)}
min_object_fraction = 0.05
{extra}
[system]
file = "system.json"
[patterns]
orientations = {kw.get('orientations', '["v"]')}
frequencies = {freqs}
steps = {steps}
[scene]
objects = [1, 2]
procedural = {kw.get('procedural', '["sphere", "blobs", "plane"]')}
size_mm = [60, 100]
{kw.get('scene', '')}
[effects]
{effects}
"""
    path = folder / "export.toml"
    path.write_text(text)
    return path


def arrays_of(path) -> dict:
    """{dataset name: numpy array} of a dataset file (strings as a list)."""
    import h5py

    out = {}
    with h5py.File(path, "r") as h5:
        def visit(name, obj):
            if isinstance(obj, h5py.Dataset):
                out[name] = obj[...]
        h5.visititems(visit)
    return out


def assert_same_arrays(a: dict, b: dict):
    assert sorted(a) == sorted(b)
    for k in a:
        if a[k].dtype == object:
            assert list(a[k]) == list(b[k]), k
        else:
            assert a[k].dtype == b[k].dtype and a[k].shape == b[k].shape, k
            assert a[k].tobytes() == b[k].tobytes(), k


def wrap(x):
    return np.angle(np.exp(1j * np.asarray(x)))
