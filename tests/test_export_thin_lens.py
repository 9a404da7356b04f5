"""The thin lens in the dataset export (synth.export.defocus_model, issue 21): ``samples`` in the
defocus tables validated by name, drawn per sample and recorded, the thin lens run when asked and
its blur disc is worth it (and then different from the blur at outlines), the blur otherwise, and
configs without ``samples`` unchanged."""
import json

import numpy as np
import pytest

from synth.export.config import ExportConfigError, config_from_dict, load_config
from synth.export.dataset import base_system, export_dataset
from synth.export.defocus_model import THIN_LENS_MIN_DISC_PX
from synth.export.sample import make_sample
from synth.export.scenes import draw_scene

from dataset_helpers import arrays_of, assert_same_arrays, tiny_config

BIG = "aperture_mm = 20, focus_offset_mm = 250"      # discs of several px on the 160x120 system
TINY = "aperture_mm = 0.002, focus_offset_mm = 250"  # discs far under half a pixel


def _cfg(tmp_path, camera: str, projector: str | None = None, samples: int = 2, **kw):
    tmp_path.mkdir(parents=True, exist_ok=True)
    eff = f"camera_defocus = {{{camera}}}" + (f"\nprojector_defocus = {{{projector}}}" if projector else "")
    return load_config(tiny_config(tmp_path, samples=samples, effects=eff, procedural='["sphere", "blobs"]',
                                   scene='layouts = ["wall"]', **kw))


def _tiny(folder, **kw):
    folder.mkdir(parents=True, exist_ok=True)
    return tiny_config(folder, **kw)


def _params(path):
    return [json.loads(p) for p in arrays_of(path)["params"]]


@pytest.mark.parametrize("value, words", [
    (2.5, "whole number"), (-1, "outside"), (2000, "outside"), ([32, 8], "impossible range"),
    ([4, 8.5], "whole number"), ("16", "samples"), (True, "samples")])
@pytest.mark.parametrize("device", ["camera_defocus", "projector_defocus"])
def test_bad_samples_are_refused_naming_the_key(device, value, words):
    d = {"export": {"samples": 1}, "effects": {device: {"aperture_mm": 3, "samples": value}}}
    with pytest.raises(ExportConfigError, match=f"effects.{device}.samples") as exc:
        config_from_dict(d)
    assert words in str(exc.value)


def test_samples_are_drawn_per_sample_recorded_and_fixed_ones_draw_nothing(tmp_path):
    rng_cfg = _cfg(tmp_path, BIG + ", samples = [3, 9]")
    plain = _cfg(tmp_path, BIG)
    fixed = _cfg(tmp_path, BIG + ", samples = 5")
    assert "samples" not in plain.to_dict()["effects"]["camera_defocus"]  # old configs keep their fingerprint
    system, _ = base_system(plain)
    drawn = []
    for i in range(12):
        rng = lambda: np.random.default_rng([7, i, 0])  # noqa: E731
        _, p_plain = draw_scene(plain, system, rng())
        _, p_fixed = draw_scene(fixed, system, rng())
        _, p_rng = draw_scene(rng_cfg, system, rng())
        drawn.append(p_rng["effects"]["camera_defocus"]["samples"])
        assert p_plain["effects"]["camera_defocus"]["samples"] == 0
        assert p_fixed["effects"]["camera_defocus"]["samples"] == 5
        # a fixed count consumes no random number: the same scene, effects and all, as without it
        p_fixed["effects"]["camera_defocus"]["samples"] = 0
        assert p_fixed == p_plain
    assert set(drawn) <= set(range(3, 10)) and len(set(drawn)) >= 3


def test_thin_lens_runs_when_asked_and_differs_from_the_blur_at_outlines(tmp_path):
    blur = _cfg(tmp_path / "b", BIG, BIG)
    lens = _cfg(tmp_path / "l", BIG + ", samples = 4", BIG + ", samples = 4")
    system, _ = base_system(blur)
    a, b = make_sample(blur, system, 0), make_sample(lens, system, 0)
    rec = b.params["defocus"]
    for dev in ("camera_defocus", "projector_defocus"):
        assert rec[dev]["model"] == "thin lens" and rec[dev]["samples"] == 4
        assert rec[dev]["max_disc_px"] >= THIN_LENS_MIN_DISC_PX
        assert b.params["effects"][dev]["samples"] == 4
    assert any("camera defocus: thin lens, 4 aperture sample(s)" in line for line in b.params["plan"])
    assert "defocus" not in a.params
    assert a.params["objects"] == b.params["objects"] and a.params["layout"] == b.params["layout"]
    # same scene, same labels; the images differ, and most where the thin lens differs by design:
    # near the outlines (object / depth edges), where the lens sees round what the centre sees
    for k in ("masks", "v/coordinate", "v/order"):
        np.testing.assert_array_equal(a.arrays[k], b.arrays[k])
    diff = np.abs(a.arrays["v/phase"][0].astype(np.int32) - b.arrays["v/phase"][0].astype(np.int32))
    diff = np.minimum(diff, 65536 - diff)  # int16 phase wraps
    import cv2
    edge = (a.arrays["masks"] & 8) > 0
    near = cv2.dilate(edge.astype(np.uint8), np.ones((9, 9), np.uint8)) > 0
    lit = (a.arrays["masks"] & 2) > 0
    assert diff[lit & near].mean() > 3 * diff[lit & ~near].mean() > 0


def test_blur_disc_under_half_a_pixel_gets_the_blur_bit_for_bit(tmp_path):
    plain = _tiny(tmp_path / "p", samples=2, effects=f"camera_defocus = {{{TINY}}}\n"
                        "noise = {full_well_e = 5000, read_noise_e = 3}")
    asked = _tiny(tmp_path / "a", samples=2, effects=f"camera_defocus = {{{TINY}, samples = 8}}\n"
                        "noise = {full_well_e = 5000, read_noise_e = 3}")
    export_dataset(plain, tmp_path / "plain.h5", progress=False)
    export_dataset(asked, tmp_path / "asked.h5", progress=False)
    a, b = arrays_of(tmp_path / "plain.h5"), arrays_of(tmp_path / "asked.h5")
    pa, pb = _params(tmp_path / "plain.h5"), _params(tmp_path / "asked.h5")
    for p, q in zip(pa, pb):
        rec = q.pop("defocus")["camera_defocus"]
        assert rec["model"] == "blur" and rec["samples"] == 8 and 0 < rec["max_disc_px"] < THIN_LENS_MIN_DISC_PX
        assert any(line.startswith("camera defocus: blur instead of the thin lens") for line in q["plan"])
        assert not any("thin lens," in line for line in q["plan"])
        q["plan"] = [line for line in q["plan"] if "instead of the thin lens" not in line]
        q["effects"]["camera_defocus"]["samples"] = 0
        assert p == q
    a.pop("params"), b.pop("params")
    assert_same_arrays(a, b)


def test_samples_zero_is_the_blur_and_no_samples_records_nothing(tmp_path):
    plain = _tiny(tmp_path / "p", samples=2, effects=f"camera_defocus = {{{BIG}}}")
    zero = _tiny(tmp_path / "z", samples=2, effects=f"camera_defocus = {{{BIG}, samples = 0}}")
    export_dataset(plain, tmp_path / "plain.h5", progress=False)
    export_dataset(zero, tmp_path / "zero.h5", progress=False)
    a, b = arrays_of(tmp_path / "plain.h5"), arrays_of(tmp_path / "zero.h5")
    for p, q in zip(_params(tmp_path / "plain.h5"), _params(tmp_path / "zero.h5")):
        assert "defocus" not in p
        rec = q.pop("defocus")["camera_defocus"]
        assert rec["model"] == "blur" and rec["samples"] == 0 and rec["max_disc_px"] > THIN_LENS_MIN_DISC_PX
        assert p == q
    a.pop("params"), b.pop("params")
    assert_same_arrays(a, b)


@pytest.mark.realdata
def test_the_real_like_config_asks_for_the_thin_lens_on_its_old_scenes():
    from tests.conftest import shared_data

    from dataset_helpers import REPO

    shared_data("meshes")
    path = REPO / "synth" / "data" / "export_real.toml"
    lens = load_config(path)
    blur = load_config(path, [f"effects.{d}.samples=0" for d in ("camera_defocus", "projector_defocus")])
    system, _ = base_system(lens)
    asked = 0
    for i in range(6):
        _, p = draw_scene(lens, system, np.random.default_rng([lens.seed, i, 0]))
        _, q = draw_scene(blur, system, np.random.default_rng([lens.seed, i, 0]))
        for d in ("camera_defocus", "projector_defocus"):
            if p["effects"][d] is not None:
                assert p["effects"][d]["samples"] == 8
                p["effects"][d]["samples"] = 0
                asked += 1
        assert p == q
    assert asked >= 6
