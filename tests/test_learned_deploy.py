"""Learned inference at deployment speed (issue 22): the numpy features and decoding agree with
the torch ones the model was trained with, ONNX (onnxruntime) gives the torch orders, an ONNX
model runs without torch, and batches of captures stream through one loaded model."""
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))

ROOT = Path(__file__).resolve().parent.parent


def _torch_batch(method, s, prior, order_trad, valid, freqs):
    """The torch batch the learned path built before issue 22 (float32 maps, one item)."""
    import torch

    from unwrap.learned import features as Fe

    z = lambda a: torch.from_numpy(np.where(valid, np.nan_to_num(np.asarray(a, dtype=np.float64)), 0.0)  # noqa: E731
                                   .astype(np.float32))[None, None]
    return {"prior": z(prior), "phase_low": z(s["phase_low"]), "phase_high": z(s["phase_high"]),
            "modulation_low": z(s["modulation_low"]), "modulation_high": z(s["modulation_high"]),
            "order_traditional": torch.from_numpy(order_trad)[None], "valid": torch.from_numpy(valid)[None],
            "frequency_low": torch.tensor([float(freqs[0])], dtype=torch.float64),
            "frequency_high": torch.tensor([float(freqs[1])], dtype=torch.float64),
            "method": torch.tensor([Fe.METHOD_INDEX[method]])}


def _scene(method="mf", freqs=(1, 48), size=(120, 160), index=3):
    from unwrap.learned.synthetic import synthetic_sample
    from unwrap.temporal import decode_pair as traditional

    s = synthetic_sample(index, size=size, method=method, frequencies=freqs)
    valid = np.asarray(s["valid"], bool) & np.isfinite(s["phase_low"]) & np.isfinite(s["phase_high"])
    prior, order_trad, valid = traditional(method, np.nan_to_num(s["phase_low"]), np.nan_to_num(s["phase_high"]),
                                           *freqs, 912.0, valid)
    return s, prior, order_trad, valid


def _near_rounding_boundary(batch, ok, tol=1e-4):
    """Pixels whose prior or smoothed priors sit within ``tol`` of a rounding boundary (float32 ties)."""
    import torch

    from unwrap.learned import features as Fe

    near = np.zeros(ok.shape, bool)
    priors = [batch["prior"].double()] + [Fe.smoothed_prior(batch, torch.from_numpy(ok)[None], w)[0].double()
                                          for w in Fe.SMOOTH_WINDOWS]
    for p in priors:
        frac = (p - torch.floor(p)).numpy()[0, 0]
        near |= np.abs(frac - 0.5) < tol
    return near


@pytest.mark.parametrize("method,freqs", [("mf", (1, 48)), ("mw", (47, 48)), ("nt", (47, 48))])
def test_numpy_features_match_the_torch_features(method, freqs):
    from unwrap.learned import fast_features as FF
    from unwrap.learned import features as Fe

    s, prior, order_trad, valid = _scene(method, freqs)
    batch = _torch_batch(method, s, prior, order_trad, valid, freqs)
    for kind in ("physics", "prior_free"):
        x_old, ok_old = Fe.make_inputs(batch, kind)
        x_new, ok_new = FF.make_inputs(kind, method, prior, s["phase_low"], s["phase_high"], s["modulation_low"],
                                       s["modulation_high"], order_trad, valid, freqs)
        assert x_new.dtype == np.float32 and x_new.shape == tuple(x_old.shape)
        assert np.array_equal(ok_new, ok_old[0].numpy())
        diff = np.abs(x_new - x_old.numpy())
        # channels 1-4 (smoothed priors) may flip only where a smoothed prior is a float32 tie
        near = _near_rounding_boundary(batch, ok_new) if kind == "physics" else np.zeros_like(ok_new)
        for c in range(x_new.shape[1]):
            bad = (diff[0, c] > 2e-5) & ~near
            assert not bad.any(), (kind, c, int(bad.sum()), float(diff[0, c].max()))


def test_numpy_plane_filter_matches_torch_smoothing():
    import torch

    from unwrap.learned.fast_features import plane_filter
    from unwrap.learned.smoothing import smooth_phase

    rng = np.random.default_rng(1)
    H, W = 70, 90
    y, x = np.mgrid[0:H, 0:W].astype(float)
    Phi = 0.03 * x - 0.02 * y + 0.1 * np.sin(x / 7) + rng.normal(0, 0.05, (H, W))
    valid = (rng.random((H, W)) > 0.2) & ((x - 40) ** 2 + (y - 30) ** 2 < 900)
    new = plane_filter(Phi, valid, (7, 15))
    for fit in ("plane", "mean"):
        got = plane_filter(Phi, valid, (7, 15), fit)
        for w in (7, 15):
            ref = smooth_phase(torch.from_numpy(Phi)[None, None], torch.from_numpy(valid)[None, None], w, fit)
            np.testing.assert_allclose(got[w], ref[0, 0].numpy(), rtol=0, atol=1e-9)
    assert np.allclose(new[7][valid], plane_filter(Phi, valid, (7,))[7][valid])


def test_learned_orders_identical_to_the_torch_path_on_a_fixed_scene():
    """The shipped model: the new path (numpy features, inference mode) gives the old path's
    orders (torch features + torch decode) on every valid pixel, save float32 ties (counted)."""
    from unwrap.learned.infer import predict, resolve_model, unwrap_learned

    net, ck = resolve_model("learned")
    for index in (0, 5):
        s, prior, order_trad, valid = _scene("mf", (1, 48), size=(160, 224), index=index)
        batch = _torch_batch("mf", s, prior, order_trad, valid, (1, 48))
        old, conf_old = predict(net, ck, batch)
        r = unwrap_learned("mf", s["phase_low"], s["phase_high"], s["modulation_low"], s["modulation_high"],
                           s["valid"], (1, 48), width=912, model="learned", on_outside="ignore")
        old = old[0].numpy()
        differ = r.order != old
        near = _near_rounding_boundary(batch, r.valid)
        assert int((differ & ~near).sum()) == 0, int(differ.sum())
        assert int(differ.sum()) <= max(2, int(near.sum()))
        np.testing.assert_allclose(r.confidence[~differ], conf_old[0].numpy()[~differ], atol=2e-4)


@pytest.mark.parametrize("method,freqs", [("mf", (1, 48)), ("mw", (47, 48))])
def test_filtered_baseline_orders_unchanged(method, freqs):
    """The filtered 15x15 baseline (numpy box filters now) gives the torch smoothing's orders."""
    import torch

    from unwrap._xp import round_order
    from unwrap.learned.baselines import filtered_order
    from unwrap.learned.smoothing import smoothed_prior

    s, _, _, valid = _scene(method, freqs, size=(160, 200), index=2)
    for fit in ("plane", "mean"):
        got = filtered_order(method, s["phase_low"], s["phase_high"], freqs, valid, window=15, fit=fit, width=912)
        t = lambda a: torch.from_numpy(np.where(valid, np.nan_to_num(a), 0.0))[None, None]  # noqa: E731
        one = lambda f: torch.full((1, 1, 1, 1), float(f), dtype=torch.float64)  # noqa: E731
        p, _ = smoothed_prior(t(s["phase_low"]), t(s["phase_high"]), one(freqs[0]), one(freqs[1]),
                              torch.tensor(method == "mf").reshape(1, 1, 1, 1), torch.from_numpy(valid)[None, None],
                              window=15, fit=fit, width=912)
        p = p[0, 0].numpy()
        ref = np.where(valid, np.clip(round_order(p), 0, round(freqs[1])), -1)
        tie = np.abs(p - np.floor(p) - 0.5) < 1e-6
        assert ((got != ref) & ~tie).sum() == 0 and (got >= 0).sum() > 1000


@pytest.fixture(scope="module")
def onnx_model(tmp_path_factory):
    from sltwin.cli import main

    out = tmp_path_factory.mktemp("onnx") / "model.onnx"
    assert main(["export-model", "learned", "-o", str(out), "-q"]) == 0
    return out


@pytest.fixture(scope="module")
def capture(tmp_path_factory):
    from bench.deploy_speed import write_capture

    return write_capture(tmp_path_factory.mktemp("cap") / "scene", size=(320, 240), seed=4)


def test_onnxruntime_gives_the_torch_orders_on_every_valid_pixel_of_a_capture(onnx_model, capture):
    from unwrap.learned.capture import unwrap_capture_learned
    from unwrap.learned.runtime import OnnxPredictor, load_predictor

    pred = load_predictor(onnx_model)
    assert isinstance(pred, OnnxPredictor) and pred.arch == load_predictor("learned").arch
    assert load_predictor(onnx_model) is pred                     # loaded once per process
    via_torch = unwrap_capture_learned(capture, "mf", "learned")
    via_ort = unwrap_capture_learned(capture, "mf", onnx_model)
    for o in ("v", "h"):
        a, b = via_torch[o], via_ort[o]
        assert np.array_equal(a.result.valid, b.result.valid) and a.result.valid.sum() > 50000
        differ = (a.result.order != b.result.order) & a.result.valid
        # a differing pixel is only acceptable where the two most probable corrections tie in float32
        conf_t = a.extras["confidence"]
        assert int(differ.sum()) == 0 or bool((conf_t[differ] < 0.5 + 1e-4).all()), int(differ.sum())
        np.testing.assert_allclose(a.extras["confidence"], b.extras["confidence"], atol=1e-4)


def test_onnx_thread_pool_spins_only_on_an_idle_machine(onnx_model, monkeypatch):
    """Spinning pool threads are faster alone and much slower beside other jobs (docs/speed.md):
    by default the session spins only when the load average is below the number of cores; an
    explicit choice wins, and the logits do not depend on it."""
    import os

    from unwrap.learned.runtime import OnnxPredictor

    cores = os.cpu_count() or 1
    monkeypatch.setattr(os, "getloadavg", lambda: (cores + 3.0, 0.0, 0.0))
    busy = OnnxPredictor(onnx_model)
    monkeypatch.setattr(os, "getloadavg", lambda: (0.0, 0.0, 0.0))
    idle = OnnxPredictor(onnx_model)
    entry = "session.intra_op.allow_spinning"
    assert busy.spin is False and idle.spin is True
    assert busy.session.get_session_options().get_session_config_entry(entry) == "0"
    assert idle.session.get_session_options().get_session_config_entry(entry) == "1"
    assert OnnxPredictor(onnx_model, spin=False).session.get_session_options().get_session_config_entry(entry) == "0"
    x = np.random.default_rng(1).standard_normal((1, busy.session.get_inputs()[0].shape[1], 64, 64)).astype(np.float32)
    name = busy.session.get_inputs()[0].name
    np.testing.assert_allclose(busy.session.run(None, {name: x})[0], idle.session.run(None, {name: x})[0],
                               rtol=0, atol=1e-5)


def test_calib_unwrap_with_an_onnx_model_never_imports_torch(onnx_model, capture, tmp_path):
    code = ("import sys\nfrom sltwin.cli import main\n"
            f"rc = main(['unwrap', {str(capture)!r}, '--model', {str(onnx_model)!r}, '-o', {str(tmp_path / 'o')!r}, "
            "'--no-previews', '-q'])\n"
            "assert rc == 0, rc\nassert 'torch' not in sys.modules, 'torch was imported'\nprint('ok')\n")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, timeout=600,
                          env={**__import__("os").environ, "PYTHONPATH": str(ROOT)})
    assert proc.returncode == 0 and proc.stdout.strip().endswith("ok"), proc.stderr[-2000:]
    import h5py
    with h5py.File(tmp_path / "o" / "unwrap.h5") as f:
        assert "confidence" in f["v"] and "order_traditional" in f["h"]


def test_onnx_path_keeps_the_hardening(onnx_model, capture, tmp_path):
    """The frequency checks and the prior check run on the ONNX path as on the torch path."""
    from unwrap.learned.errors import ModelError
    from unwrap.learned.infer import unwrap_learned
    from unwrap.learned.synthetic import synthetic_sample

    s = synthetic_sample(0, size=(48, 64), method="mf", frequencies=(1, 400))
    with pytest.raises(ModelError, match="frequency ratio 400"):
        unwrap_learned("mf", s["phase_low"], s["phase_high"], s["modulation_low"], s["modulation_high"], s["valid"],
                       (1, 400), width=912, model=onnx_model)


@pytest.mark.parametrize("learned", [False, True])
def test_a_folder_of_captures_streams_with_one_model_and_a_summary(onnx_model, capture, tmp_path, capsys, learned):
    import shutil

    import h5py

    from sltwin.cli import main
    from unwrap.pipeline import unwrap_capture

    batch = tmp_path / "batch"
    for name in ("a", "b"):
        shutil.copytree(capture, batch / name)
    (batch / "c_broken").mkdir()
    (batch / "c_broken" / "capture.toml").write_text("[pattern]\n")
    model = ["--model", str(onnx_model)] if learned else []
    rc = main(["unwrap", str(batch), *model, "-o", str(tmp_path / "out"), "--no-previews"])
    cap = capsys.readouterr()
    assert rc == 2 and "c_broken" in cap.err and "2 of 3 captures unwrapped" in cap.out
    assert "capture/s" in cap.err                                              # the progress bar
    single = unwrap_capture(capture) if not learned else None
    for name in ("a", "b"):
        with h5py.File(tmp_path / "out" / name / "unwrap.h5") as f:
            assert ("confidence" in f["v"]) == learned
            if single is not None:
                assert np.array_equal(f["v"]["order"][()], single["v"].result.order)
    assert not (tmp_path / "out" / "c_broken").exists()
    # a list of captures works the same, and all good is exit 0
    assert main(["unwrap", str(batch / "a"), str(batch / "b"), *model, "-o", str(tmp_path / "out2"),
                 "--no-previews", "-q"]) == 0
    assert (tmp_path / "out2" / "b" / "unwrap.h5").is_file()


def test_plane_filter_numba_kernel_and_numpy_replica_agree(monkeypatch):
    """plane_filter's two engines (docs/speed.md, session 9): the same bits."""
    pytest.importorskip("numba")
    from unwrap.learned import _plane_kernel
    from unwrap.learned import fast_features as FF
    from unwrap.learned._plane_numpy import plane_filter_numpy

    rng = np.random.default_rng(7)
    y, x = np.mgrid[0:50, 0:61].astype(float)
    Phi = 0.05 * x + 0.01 * y + rng.normal(0, 0.1, x.shape)
    valid = rng.random(x.shape) > 0.3
    valid[:, :3] = False
    monkeypatch.setattr(FF, "_kernel", lambda: _plane_kernel.plane_filter_kernel)
    fast = FF.plane_filter(Phi, valid, (7, 15))
    monkeypatch.setattr(FF, "_kernel", lambda: plane_filter_numpy)
    slow = FF.plane_filter(Phi, valid, (7, 15))
    for w in (7, 15):
        assert fast[w].tobytes() == slow[w].tobytes()


def test_sliding_plane_kernel_matches_direct_sums_over_many_blocks(monkeypatch):
    """The sliding kernel (exact restart every BLOCK outputs) on a frame several blocks wide and
    high, with holes and invalid borders, against the torch smoothing's direct box sums, and
    independent of the block length (the restart only bounds the rounding drift)."""
    import torch

    pytest.importorskip("numba")
    from unwrap.learned import _plane_kernel as K
    from unwrap.learned.smoothing import smooth_phase

    rng = np.random.default_rng(3)
    H, W = 150, 333
    y, x = np.mgrid[0:H, 0:W].astype(float)
    Phi = 2 * np.pi * (0.002 * x + 0.001 * y) + 0.3 * np.sin(x / 11) + rng.normal(0, 0.05, (H, W))
    valid = rng.random((H, W)) > 0.25
    valid[40:60, 100:180] = False
    valid[:, -2:] = False
    valid[:4] = False
    for r in (3, 7):
        ref = smooth_phase(torch.from_numpy(Phi)[None, None], torch.from_numpy(valid)[None, None], 2 * r + 1,
                           "plane")[0, 0].numpy()
        got = K.plane_filter_kernel(Phi, valid, r)
        # the torch reference's own cumulative sums over the frame round at ~1e-11 rad
        np.testing.assert_allclose(got, ref, rtol=0, atol=5e-11)
        monkeypatch.setattr(K, "BLOCK", 7)
        np.testing.assert_allclose(K.plane_filter_kernel(Phi, valid, r), got, rtol=0, atol=1e-11)
        monkeypatch.setattr(K, "BLOCK", 10_000)                   # one run per row / column: the most drift
        np.testing.assert_allclose(K.plane_filter_kernel(Phi, valid, r), got, rtol=0, atol=1e-11)
        monkeypatch.undo()
