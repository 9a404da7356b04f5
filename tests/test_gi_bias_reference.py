"""experiments.gi_bias.save_reference writes atomically (unwrap.safe_output.atomic_path): the
reference round-trips through load_reference, and a write that fails half way leaves the previous
file and no temporary file behind."""
import numpy as np
import pytest

from experiments import gi_bias
from experiments.gi_bias import load_reference, save_reference


def _reference():
    rng = np.random.default_rng(3)
    mask = rng.uniform(size=(7, 9)) < 0.6
    return rng.normal(0, 0.1, (7, 9)), mask


def test_a_reference_round_trips(tmp_path):
    bias, mask = _reference()
    save_reference(tmp_path / "ref.npz", "ball-wall", bias, mask, {"samples": 64})
    ref, m, meta = load_reference(tmp_path / "ref.npz")
    assert np.array_equal(m, mask) and meta["samples"] == 64
    assert np.allclose(ref[mask], bias[mask], atol=1e-3) and not ref[~mask].any()
    assert [p.name for p in tmp_path.iterdir()] == ["ref.npz"]


def test_a_failed_write_leaves_the_previous_reference(tmp_path, monkeypatch):
    path = tmp_path / "ref.npz"
    path.write_bytes(b"previous")

    def failing(file, **arrays):
        (open(file, "wb") if isinstance(file, (str, type(path))) else file).write(b"PK partial")
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(gi_bias.np, "savez_compressed", failing)
    bias, mask = _reference()
    with pytest.raises(OSError):
        save_reference(path, "ball-wall", bias, mask, {})
    assert [p.name for p in tmp_path.iterdir()] == ["ref.npz"] and path.read_bytes() == b"previous"
