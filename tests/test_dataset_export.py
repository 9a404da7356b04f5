"""The dataset export (synth.export.dataset): determinism across shards, resume after kill -9 and
after a full disk, combine, configs refused by name, labels checked against traditional TPU."""
import json
import os
import resource
import signal
import subprocess
import sys
import time
from pathlib import Path

import h5py
import numpy as np
import pytest

from synth.export.config import ExportConfigError, config_from_dict, load_config
from synth.export.dataset import export_dataset
from synth.export.writer import ExportError, combine, shard_from_environment, shard_path, shard_range

from dataset_helpers import REPO, arrays_of, assert_same_arrays, tiny_config

ENV = {**os.environ, "PYTHONPATH": str(REPO)}


def _cli(*args, preexec=None, timeout=300):
    return subprocess.run([sys.executable, "-m", "sltwin.cli", "export", *map(str, args), "-q"], env=ENV,
                          capture_output=True, text=True, timeout=timeout, preexec_fn=preexec)


def test_one_shard_and_three_shards_hold_bit_identical_samples(tmp_path):
    cfg = tiny_config(tmp_path, samples=4, effects="noise = {full_well_e = [2000, 8000], read_noise_e = 3}")
    whole = export_dataset(cfg, tmp_path / "one.h5", progress=False)
    assert whole["samples"] == 4
    for i in range(3):
        export_dataset(cfg, tmp_path / "three.h5", shard=(i, 3), progress=False)
    shards = sorted(tmp_path.glob("three-*-of-00003.h5"))
    assert [s.name for s in shards] == [shard_path("three.h5", i, 3).name for i in range(3)]
    combined = combine(shards, tmp_path / "combined.h5")
    a, b = arrays_of(tmp_path / "one.h5"), arrays_of(combined)
    assert_same_arrays(a, b)
    assert list(a["sample_index"]) == [0, 1, 2, 3]
    # a sample depends only on (seed, index): shard 1 of 3 holds exactly samples 1 of the whole
    part = arrays_of(shards[1])
    assert list(part["sample_index"]) == list(shard_range(4, 1, 3))
    for k in ("v/phase", "v/coordinate", "masks"):
        assert part[k].tobytes() == a[k][1:2].tobytes()


def test_killed_export_resumes_and_equals_an_uninterrupted_one_bit_for_bit(tmp_path):
    cfg = tiny_config(tmp_path, samples=10, effects="noise = {full_well_e = 4000, read_noise_e = 3}")
    ref = tmp_path / "ref.h5"
    export_dataset(cfg, ref, progress=False)
    out = tmp_path / "killed.h5"
    parts = tmp_path / "killed.h5.parts"
    proc = subprocess.Popen([sys.executable, "-m", "sltwin.cli", "export", str(cfg), "-o", str(out), "-q"], env=ENV,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    # killed on a concrete state (3 finished parts on disk), however fast or slow the machine: no
    # deadline; the state is polled every 2 ms and a tiny sample takes far longer than that
    while proc.poll() is None and not (parts.exists() and len(list(parts.glob("sample_*.h5"))) >= 3):
        time.sleep(0.002)
    assert proc.poll() is None, "the export ended before 3 samples were on disk: no interruption was tested"
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    done = sorted(parts.glob("sample_*.h5"))
    assert not out.exists(), "the export finished before it could be killed: no interruption was tested"
    assert 3 <= len(done) < 10
    # every part that exists is a whole sample: it opens and holds its sample index
    for p in done:
        with h5py.File(p, "r") as h5:
            assert int(h5["sample_index"][0]) == int(p.stem.split("_")[1])
    summary = export_dataset(cfg, out, progress=False)
    assert summary["rendered_now"] == 10 - len(done)
    assert not parts.exists()
    assert_same_arrays(arrays_of(ref), arrays_of(out))
    assert ref.read_bytes() == out.read_bytes()


@pytest.mark.parametrize("where", ["sample", "shard file"])
def test_full_disk_is_a_clear_error_keeps_finished_samples_and_resumes(tmp_path, where):
    cfg = tiny_config(tmp_path, samples=3)
    ref = tmp_path / "ref.h5"
    export_dataset(cfg, ref, progress=False)
    part_size = ref.stat().st_size / 3
    limit = int(part_size / 4) if where == "sample" else int(part_size * 1.6)

    def small_disk():  # files above `limit` bytes cannot grow: writes fail with EFBIG
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))

    out = tmp_path / "out.h5"
    r = _cli(cfg, "-o", out, preexec=small_disk)
    assert r.returncode == 2, r.stderr
    assert "cannot write" in r.stderr and "rerun the same command to resume" in r.stderr
    assert ("file size limit" in r.stderr) if where == "shard file" else ("File too large" in r.stderr
                                                                           or "file size limit" in r.stderr)
    assert "Traceback" not in r.stderr
    assert not out.exists() and not list(tmp_path.glob("*.tmp")) and not list(tmp_path.glob("*/*.tmp"))
    kept = len(list((tmp_path / "out.h5.parts").glob("sample_*.h5")))
    assert kept == (0 if where == "sample" else 3)
    r = _cli(cfg, "-o", out)
    assert r.returncode == 0, r.stderr
    assert_same_arrays(arrays_of(ref), arrays_of(out))


def test_unwritable_output_is_a_clear_error(tmp_path):
    cfg = tiny_config(tmp_path, samples=1)
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    r = _cli(cfg, "-o", blocker / "data.h5")
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert "nothing can be written below it" in r.stderr and str(blocker) in r.stderr   # checked before any work


def test_combine_refuses_missing_incomplete_and_foreign_shards_and_leaves_nothing_when_interrupted(tmp_path):
    cfg = tiny_config(tmp_path, samples=3)
    for i in range(3):
        export_dataset(cfg, tmp_path / "d.h5", shard=(i, 3), progress=False)
    shards = sorted(tmp_path.glob("d-*.h5"))
    with pytest.raises(ExportError, match=r"shard\(s\) \[1\] of 3 missing"):
        combine([shards[0], shards[2]], tmp_path / "c.h5")
    with pytest.raises(ExportError, match="given twice"):
        combine([shards[0], shards[0], shards[1], shards[2]], tmp_path / "c.h5")
    before = shards[1].read_bytes()
    with pytest.raises(ExportError, match="is one of the shards"):  # joined into itself: a crash on reading
        combine(shards, shards[1])
    assert shards[1].read_bytes() == before
    with h5py.File(shards[2], "r+") as h5:
        h5.attrs["complete"] = False
    with pytest.raises(ExportError, match="did not finish"):
        combine(shards, tmp_path / "c.h5")
    with h5py.File(shards[2], "r+") as h5:
        h5.attrs["complete"] = True
    other = tiny_config(tmp_path / "o", samples=3, seed=8) if (tmp_path / "o").mkdir() is None else None
    export_dataset(other, tmp_path / "o" / "d.h5", shard=(1, 3), progress=False)
    with pytest.raises(ExportError, match="different exports"):
        combine([shards[0], tmp_path / "o" / "d-00001-of-00003.h5", shards[2]], tmp_path / "c.h5")
    assert not (tmp_path / "c.h5").exists()

    def interrupt(name):
        raise KeyboardInterrupt
    with pytest.raises(KeyboardInterrupt):
        combine(shards, tmp_path / "c.h5", progress=interrupt)
    assert not (tmp_path / "c.h5").exists() and not (tmp_path / "c.h5.tmp").exists()
    # a good combine reads back, and a missing source file is noticed by the reader's schema
    combine(shards, tmp_path / "c.h5")
    with h5py.File(tmp_path / "c.h5", "r") as h5:
        assert h5["v/phase"].is_virtual and h5["v/phase"].shape[0] == 3


def test_shard_from_torchrun_and_slurm_environment():
    assert shard_from_environment({}) is None
    assert shard_from_environment({"RANK": "2", "WORLD_SIZE": "4"}) == (2, 4)
    assert shard_from_environment({"SLURM_ARRAY_TASK_ID": "5", "SLURM_ARRAY_TASK_MIN": "1",
                                   "SLURM_ARRAY_TASK_COUNT": "8", "RANK": "0", "WORLD_SIZE": "2"}) == (4, 8)
    with pytest.raises(ExportError, match="0 <= i < n"):
        shard_from_environment({"RANK": "4", "WORLD_SIZE": "4"})
    sizes = [len(shard_range(10, i, 3)) for i in range(3)]
    assert sizes == [3, 3, 4] and [shard_range(10, i, 3).start for i in range(3)] == [0, 3, 6]


@pytest.mark.parametrize("doc, message", [
    ({"export": {"samples": 3, "sed": 1}}, r"unknown key 'export.sed' \(did you mean 'export.seed'\?\)"),
    ({"export": {"samples": 3}, "effects": {"noise": {"full_well_e": [9000, 100]}}},
     r"effects.noise.full_well_e: impossible range \[9000.0, 100.0\]"),
    ({"export": {"samples": 3}, "effects": {"camera_defocus": {"apperture_mm": 2}}},
     r"unknown key 'effects.camera_defocus.apperture_mm' \(did you mean 'effects.camera_defocus.aperture_mm'\?\)"),
    ({"export": {"samples": 3}, "effects": {"global_illumination": {"subsurface": [0, 1.5]}}},
     r"effects.global_illumination.subsurface: 1.5 outside \[0.0, 1.0\]"),
    ({"export": {"samples": 3}, "scene": {"size_mm": [0, 10]}}, r"scene.size_mm: 0 outside"),
    ({"export": {}}, "export.samples: missing"),
    ({"export": {"samples": 3}, "patterns": {"frequencies": [48, 1]}}, "patterns.frequencies: expected strictly"),
    ({"export": {"samples": 3}, "scene": {"mesh_fraction": 0.5}}, "scene.mesh_fraction: 0.5 but scene.meshes is empty"),
    ({"export": {"samples": 3}, "bogus": {}}, r"unknown section \[bogus\]"),
    ({"export": {"samples": 3}, "patterns": {"steps": 4.0}}, "patterns.steps = 4.0: expected an integer"),
    ({"export": {"samples": "3"}}, "export.samples = '3': expected an integer, got a string"),
])
def test_config_with_unknown_key_or_impossible_range_is_refused_naming_the_key(doc, message):
    with pytest.raises(ExportConfigError, match=message):
        config_from_dict(doc)


def test_missing_or_unreadable_mesh_is_named(tmp_path):
    (tmp_path / "broken.ply").write_bytes(b"not a ply file at all")
    for name, message in (("nowhere.obj", "nowhere.obj: no such file"), ("broken.ply", "broken.ply: not a PLY")):
        cfg = tiny_config(tmp_path, samples=1, scene=f'meshes = ["{name}"]\nmesh_fraction = 0.5')
        with pytest.raises(ExportConfigError, match=f"scene.meshes: mesh file .*{message}"):
            export_dataset(cfg, tmp_path / "x.h5", progress=False)
        r = _cli(cfg, "-o", tmp_path / "x.h5")
        assert r.returncode == 2 and name in r.stderr


def test_objects_outside_the_view_are_redrawn_not_written_empty(tmp_path):
    # objects placed 0-2000 mm behind the board: most draws are too small to cover 5 % of the image
    cfg = tiny_config(tmp_path, samples=4, scene="depth_mm = [0, 2500]\nbackground = 0.0", procedural='["sphere"]')
    export_dataset(cfg, tmp_path / "d.h5", progress=False)
    with h5py.File(tmp_path / "d.h5", "r") as h5:
        params = [json.loads(p) for p in h5["params"][...]]
        masks = h5["masks"][...]
    assert max(p["attempt"] for p in params) > 0, "no draw was redrawn: the test does not test redrawing"
    for p, m in zip(params, masks):
        assert p["object_fraction"] >= 0.05 and ((m & 2) != 0).mean() >= 0.05
    impossible = tiny_config(tmp_path, samples=1, scene="depth_mm = [4900, 4900]\nbackground = 0.0",
                             procedural='["sphere"]')
    with pytest.raises(ExportError.__bases__[0], match="min_object_fraction"):
        export_dataset(impossible, tmp_path / "e.h5", progress=False)


def test_labels_equal_traditional_tpu_on_the_clean_render_and_effects_are_counted_apart(tmp_path):
    cfg = tiny_config(tmp_path, samples=2, frequencies="[1, 16]", steps=6,
                      effects="global_illumination = {subsurface = [0.5, 0.6], scatter_mm = 4}\n"
                              "camera_defocus = {aperture_mm = 6, focus_offset_mm = 300}")
    s = export_dataset(cfg, tmp_path / "d.h5", progress=False)
    chk = s["label_check"]["v 1->16"]
    assert chk["clean_interior"] == 0 and chk["clean_edge"] == 0
    with h5py.File(tmp_path / "d.h5", "r") as h5:
        plans = [json.loads(p)["plan"] for p in h5["params"][...]]
    assert all(any(line.startswith("global illumination: object") for line in p) for p in plans)
    assert all(any("sensor noise: skipped (not asked for)" in line for line in p) for p in plans)


def test_default_configs_parse_and_keep_test_meshes_out_of_training():
    train = load_config(REPO / "synth" / "data" / "export_train.toml")
    test = load_config(REPO / "synth" / "data" / "export_test.toml")
    names = lambda c: {Path(m).name for m in c.meshes}  # noqa: E731
    assert names(train) and names(test) and not names(train) & names(test)
    assert {"global_illumination", "projector_defocus", "camera_defocus", "noise"} <= set(train.effects)
    assert test.frequencies == (1.0, 15.0, 16.0, 31.0, 32.0, 47.0, 48.0, 63.0, 64.0, 79.0, 80.0, 95.0, 96.0)


@pytest.mark.realdata
def test_default_configs_name_meshes_that_exist_and_load():
    from synth.export.scenes import check_meshes
    from tests.conftest import shared_data

    shared_data("meshes")                                       # skipped, and said so, without the data
    for name in ("export_train.toml", "export_test.toml"):
        cfg = load_config(REPO / "synth" / "data" / name)
        assert all(Path(m).is_file() for m in cfg.meshes), cfg.meshes
        check_meshes(cfg)


def test_export_command_shard_combine_and_capture_passing_cases(tmp_path, design_capture, capsys):
    """`calib export CONFIG --shard i/n`, `--combine` and `--capture` as a user runs them: the shards
    combined hold exactly the samples of one whole export; a capture exports its decoded phases
    (here the noise-free DESIGN.md capture: the phase of every frequency to its int16 storage step)."""
    from sltwin.cli import main
    from unwrap.dataset_schema import decode_phase
    from unwrap.patterns import absolute_phase

    cfg = tiny_config(tmp_path, samples=2)
    assert main(["export", str(cfg), "-o", str(tmp_path / "whole.h5"), "-q"]) == 0
    for i in range(2):
        assert main(["export", str(cfg), "--shard", f"{i}/2", "-o", str(tmp_path / "s.h5"), "-q"]) == 0
    shards = [shard_path(tmp_path / "s.h5", i, 2) for i in range(2)]
    assert all(s.is_file() for s in shards)
    capsys.readouterr()
    assert main(["export", "--combine", *map(str, shards), "-o", str(tmp_path / "joined.h5")]) == 0
    assert "combined 2 shard(s)" in capsys.readouterr().out
    assert_same_arrays(arrays_of(tmp_path / "whole.h5"), arrays_of(tmp_path / "joined.h5"))

    root, coords = design_capture
    assert main(["export", "--capture", str(root), "-o", str(tmp_path / "real.h5")]) == 0
    assert "1 capture sample(s)" in capsys.readouterr().out
    a = arrays_of(tmp_path / "real.h5")
    with h5py.File(tmp_path / "real.h5", "r") as h5:
        assert h5.attrs["kind"] == "capture" and [float(f) for f in h5.attrs["frequencies"]] == [1.0, 8.0, 48.0]
    for o, (c, extent) in coords.items():
        phase = decode_phase(a[f"{o}/phase"][0])                  # (3 frequencies, 48, 64)
        assert phase.shape == (3, 48, 64)
        for j, f in enumerate((1, 8, 48)):
            err = np.angle(np.exp(1j * (phase[j] - absolute_phase(c, f, extent))))
            assert np.abs(err).max() < 2e-4, (o, f, np.abs(err).max())   # measured 6.4e-5 (int16 storage)
        assert (a[f"{o}/reference_order"] == -1).all()              # no Gray code: no reference order
