"""bench.retrain_compare's dataset items: every held (method, pair) of a file, and the sensor
noise (a pass over every scene of the file) read once per orientation and frequency."""
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from dataset_helpers import tiny_config  # noqa: E402


def test_dataset_items_read_the_noise_once_per_frequency(tmp_path, monkeypatch):
    import importlib

    LP = importlib.import_module("experiments.learned_parity")   # the module (the package exports a function of that name)
    from bench.retrain_compare import _dataset_items
    from synth.export.dataset import export_dataset

    cfg = tiny_config(tmp_path, samples=1, frequencies="[1, 7, 8]", steps=4)
    export_dataset(cfg, tmp_path / "set.h5", progress=False)
    calls = []
    real = LP.capture_noise
    monkeypatch.setattr(LP, "capture_noise", lambda *a, **k: calls.append(a) or real(*a, **k))
    items = _dataset_items(tmp_path / "set.h5", [8.0], ["mf", "mw", "nt"])
    assert sorted(it["name"].split()[1] for it in items) == ["MF", "MW", "NT"]
    assert [it["freqs"] for it in items] == [(1.0, 8.0), (7.0, 8.0), (7.0, 8.0)]
    assert len(calls) == 1                     # one orientation, one frequency: one pass, not one per method
    assert all(it["sigma_I"] == items[0]["sigma_I"] > 0 for it in items)
