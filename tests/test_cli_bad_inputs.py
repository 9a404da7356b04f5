"""Every ``calib`` sub-command on a table of bad inputs: exit code 2, a message naming the input,
no traceback (issue 15). Adding a command or a case is one row of ``CASES``:

    (case id, command line, text the error message must contain)

Placeholders in the command line: ``{bad}`` (a folder of broken files, built below), ``{cap}``
(a folder of small DESIGN.md captures, one good and one per defect), ``{out}`` (a fresh output
path of the case) and ``{dp}`` (the paper's dp-tpu data; the case is skipped without it).
"""
import json
import shutil

import cv2
import h5py
import numpy as np
import pytest

from calib import default_system
from sltwin.cli import main
from unwrap.patterns import absolute_phase, fringe_intensity
from unwrap.phase_io import write_phase_file

from conftest import SHARED_DATA

SCENE = """
[[objects]]
kind = "plane"
[[patterns.sequence]]
kind = "white"
"""

CAPTURE_TOML = """
[pattern]
steps = 4
frequencies = [1, 8]
{extra}
[camera]
size = [{w}, 48]

[projector]
size = [912, 1140]
"""


def _write_capture(folder, *, extra="", width=64, frames=None):
    """A DESIGN.md capture of one pose: 64x48 px, frequencies 1 and 8, 4 steps, 8-bit."""
    pose = folder / "pose_00"
    pose.mkdir(parents=True)
    (folder / "capture.toml").write_text(CAPTURE_TOML.format(extra=extra, w=width))
    y, x = np.mgrid[0:48, 0:64].astype(np.float64)
    coords = {"v": (5.0 + 14.1 * x + 0.3 * y, 912), "h": (8.0 + 23.2 * y + 0.2 * x, 1140)}
    for o, (c, extent) in coords.items():
        for f in (1, 8):
            for n in range(4):
                image = (frames or _our_frames)(absolute_phase(c, f, extent), n)
                cv2.imwrite(str(pose / f"{o}_f{f:03d}_n{n:02d}.png"), image)
    return pose


def _our_frames(phase, n):
    return np.round(fringe_intensity(phase, n, 4, A=120, B=90)).astype(np.uint8)


def _pi_offset_frames(phase, n):   # another lab's convention: A + B cos(Phi + pi + 2 pi n/N)
    return np.round(120 + 90 * np.cos(phase + np.pi + 2 * np.pi * n / 4)).astype(np.uint8)


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    root = tmp_path_factory.mktemp("bad_inputs")
    bad = root / "bad"
    bad.mkdir()
    (bad / "empty.xml").write_text("")
    (bad / "empty.yml").write_text("")
    (bad / "truncated.xml").write_text('<?xml version="1.0"?>\n<opencv_storage>\n<Kc type_id="opencv-matrix">\n'
                                       "<rows>3</rows><cols>3</cols><dt>d</dt><data>\n 2592. 0. 30")
    (bad / "imagelist.xml").write_text('<?xml version="1.0"?>\n<opencv_storage>\n<imagelist>\n"left01.jpg"\n'
                                       '"right01.jpg"</imagelist>\n</opencv_storage>\n')
    (bad / "text.mat").write_text("this is not a MATLAB file\n")
    (bad / "afile").write_text("x")
    (bad / "adir").mkdir()
    (bad / "scene_bad.toml").write_text("[[objects]]\nkind = 'teapot-of-doom'\n")
    (bad / "scene.toml").write_text(SCENE)
    good = default_system().to_dict()
    (bad / "default.json").write_text(json.dumps(good))
    variants = {"fx_string": ("camera", lambda d: d["K"][0].__setitem__(0, "2592.2")),
                "fx_huge": ("camera", lambda d: d["K"][0].__setitem__(0, 1e300)),
                "zero_baseline": ("projector", lambda d: d.update(R=good["camera"]["R"], t=good["camera"]["t"]))}
    for name, (device, change) in variants.items():
        d = json.loads(json.dumps(good))
        change(d[device])
        (bad / f"{name}.json").write_text(json.dumps(d))
    np.save(bad / "all_nan.npy", np.full((480, 640), np.nan))
    write_phase_file(bad / "unwrap48.h5", {"v": {"phase": np.full((480, 640), 100.0)}}, frequency=48.0)
    np.save(bad / "small.npy", np.ones((48, 64)))
    cap = root / "cap"
    _write_capture(cap / "good")
    pose = _write_capture(cap / "mixed_depth")
    cv2.imwrite(str(pose / "v_f008_n02.png"), cv2.imread(str(pose / "v_f008_n02.png"), -1).astype(np.uint16) * 257)
    pose = _write_capture(cap / "extra_frame")
    shutil.copy(pose / "v_f008_n03.png", pose / "v_f008_n04.png")
    _write_capture(cap / "size_mismatch", width=100)
    _write_capture(cap / "all_black", frames=lambda phase, n: np.zeros(phase.shape, np.uint8))
    _write_capture(cap / "pi_offset", frames=_pi_offset_frames)
    _write_capture(cap / "bad_sign", extra="shift_sign = 2")
    _write_capture(cap / "bad_toml")
    (cap / "bad_toml" / "capture.toml").write_text("[pattern\nsteps = 4\n")
    return {"bad": bad, "cap": cap}


CASES = [
    # calib twin: unreadable OpenCV files, broken models, outputs of the wrong kind
    ("twin-empty-xml", "twin {bad}/empty.xml -o {out}.json", "empty.xml"),
    ("twin-empty-yml", "twin {bad}/empty.yml -o {out}.json", "empty.yml"),
    ("twin-truncated-xml", "twin {bad}/truncated.xml -o {out}.json", "truncated.xml"),
    ("twin-image-list", "twin {bad}/imagelist.xml -o {out}.json", "imagelist.xml"),
    ("twin-fx-string", "twin {bad}/fx_string.json -o {out}.json", "camera.K: holds text"),
    ("twin-fx-1e300", "twin {bad}/fx_huge.json -o {out}.json", "not finite"),
    ("twin-zero-baseline", "twin {bad}/zero_baseline.json -o {out}.json", "coincide"),
    ("twin-swapped-mat", "twin {dp}/PrjCalibResult_real.mat {dp}/CamCalibResult_real.mat -o {out}.json", "swapped"),
    ("twin-three-files", "twin {bad}/default.json {bad}/default.json {bad}/default.json -o {out}.json",
     "cannot tell the format"),
    ("twin-missing-file", "twin {bad}/nowhere.json -o {out}.json", "nowhere.json"),
    ("twin-output-is-dir", "twin -o {bad}/adir", "adir"),
    ("twin-output-under-file", "twin -o {bad}/afile/twin.json", "afile"),
    ("twin-script-is-dir", "twin -o {out}.json --blender-script {bad}/adir", "adir"),
    # calib convert
    ("convert-unknown-output", "convert {bad}/default.json -o {out}.txt", "output format"),
    ("convert-output-is-dir", "convert {bad}/default.json -o {bad}/adir", "adir"),
    ("convert-broken-input", "convert {bad}/truncated.xml -o {out}.json", "truncated.xml"),
    # calib reconstruct
    ("reconstruct-text-mat", "reconstruct --phase {bad}/text.mat --frequency 96 --calibration {bad}/default.json "
     "-o {out}.ply", "text.mat"),
    ("reconstruct-frequency-0", "reconstruct --phase {bad}/all_nan.npy --frequency 0 --calibration "
     "{bad}/default.json -o {out}.ply", "--frequency"),
    ("reconstruct-frequency-negative", "reconstruct --phase {bad}/all_nan.npy --frequency -96 --calibration "
     "{bad}/default.json -o {out}.ply", "--frequency"),
    ("reconstruct-no-frequency", "reconstruct --phase {bad}/all_nan.npy --calibration {bad}/default.json "
     "-o {out}.ply", "all_nan.npy does not store the fringe frequency"),
    ("reconstruct-contradicting-frequency", "reconstruct --phase {bad}/unwrap48.h5 --frequency 96 --calibration "
     "{bad}/default.json -o {out}.ply", "contradicts the frequency 48"),
    ("reconstruct-all-nan", "reconstruct --phase {bad}/all_nan.npy --frequency 96 --calibration {bad}/default.json "
     "-o {out}.ply", "no valid pixel"),
    ("reconstruct-wrong-size", "reconstruct --phase {bad}/small.npy --frequency 96 --calibration {bad}/default.json "
     "-o {out}.ply", "small.npy"),
    ("reconstruct-wrong-frequency", "reconstruct --phase {dp}/standardball_phase_real.mat --frequency 48 "
     "--calibration {dp}/CamCalibResult_real.mat {dp}/PrjCalibResult_real.mat -o {out}.ply", "outside the projector"),
    ("reconstruct-output-is-dir", "reconstruct --phase {bad}/all_nan.npy --frequency 96 --calibration "
     "{bad}/default.json -o {bad}/adir", "adir"),
    # calib report
    ("report-text-mat-phase", "report --real {dp}/CamCalibResult_real.mat {dp}/PrjCalibResult_real.mat --twin "
     "{dp}/CamCalibResult_sim.mat {dp}/PrjCalibResult_sim.mat --phase-real {bad}/text.mat -o {out}", "text.mat"),
    ("report-output-is-file", "report --real {bad}/default.json --twin {bad}/default.json -o {bad}/afile", "afile"),
    ("report-missing-input", "report --real {bad}/nowhere.json --twin {bad}/default.json -o {out}", "nowhere.json"),
    # calib demo
    ("demo-output-is-file", "demo -o {bad}/afile", "afile"),
    # calib unwrap: outputs, layouts, frames, options
    ("unwrap-output-is-file", "unwrap {cap}/good -o {bad}/afile", "afile"),
    ("unwrap-no-folder", "unwrap {cap}/nowhere -o {out}", "nowhere"),
    ("unwrap-mixed-bit-depth", "unwrap {cap}/mixed_depth -o {out}", "v_f008_n02.png: uint16 frame"),
    ("unwrap-extra-frame", "unwrap {cap}/extra_frame -o {out}", "v_f008_n04.png"),
    ("unwrap-camera-size", "unwrap {cap}/size_mismatch -o {out}", "[camera] size says 100x48"),
    ("unwrap-all-black", "unwrap {cap}/all_black -o {out}", "no valid pixel"),
    ("unwrap-min-modulation-negative", "unwrap {cap}/good --min-modulation -1 -o {out}", "min_modulation"),
    ("unwrap-min-modulation-absurd", "unwrap {cap}/good --min-modulation 1e9 -o {out}", "exceeds the largest"),
    ("unwrap-max-error-rate-absurd", "unwrap {cap}/good --max-error-rate 2 -o {out}", "max_error_rate"),
    ("unwrap-other-convention", "unwrap {cap}/pi_offset -o {out}", "phase_offset"),
    ("unwrap-bad-shift-sign", "unwrap {cap}/bad_sign -o {out}", "shift_sign"),
    ("unwrap-bad-toml", "unwrap {cap}/bad_toml -o {out}", "not valid TOML"),
    # calib plan-fringes: ladders calib unwrap refuses
    ("plan-mf-not-absolute", "plan-fringes --sets mf:8,48", "mf:8,48"),
    ("plan-mf-decreasing", "plan-fringes --sets mf:48,8,1", "mf:48,8,1"),
    ("plan-nt-equal", "plan-fringes --sets nt:48,48", "nt:48,48"),
    ("plan-syntax", "plan-fringes --sets mf", "'mf'"),
    ("plan-two-steps", "plan-fringes --steps 2", "steps"),
    # calib render / render-board
    ("render-missing-scene", "render {bad}/nowhere.toml -o {out}", "nowhere.toml"),
    ("render-bad-scene", "render {bad}/scene_bad.toml -o {out}", "teapot-of-doom"),
    ("render-output-is-file", "render {bad}/scene.toml -o {bad}/afile", "afile"),
    ("render-board-output-is-file", "render-board -o {bad}/afile", "afile"),
    ("render-board-two-steps", "render-board --steps 2 -o {out}", "--steps"),
    ("render-board-broken-system", "render-board {bad}/truncated.xml -o {out}", "truncated.xml"),
    # calib run
    ("run-output-is-file", "run {cap}/good -o {bad}/afile", "afile"),
    ("run-no-folder", "run {cap}/nowhere -o {out}", "nowhere"),
    ("run-text-mat-observations", "run --observations {bad}/text.mat {bad}/text.mat -o {out}", "text.mat"),
    ("run-no-input", "run -o {out}", "CAPTURES"),
    # calib export (issue 12's command)
    ("export-output-is-dir", "export --capture {cap}/good -o {bad}/adir", "adir"),
]


@pytest.mark.parametrize("case, line, expected", CASES, ids=[c[0] for c in CASES])
def test_bad_input_is_exit_2_with_a_message_naming_it_and_no_traceback(case, line, expected, files, tmp_path,
                                                                         capsys):
    if "{dp}" in line and not (SHARED_DATA / "dp-tpu").exists():
        pytest.skip("the paper's dp-tpu data are not present")
    argv = line.format(bad=files["bad"], cap=files["cap"], dp=SHARED_DATA / "dp-tpu", out=tmp_path / case).split()
    code = main(argv)
    captured = capsys.readouterr()
    assert code == 2, (argv, captured.err)
    assert expected in captured.err, captured.err
    assert "Traceback" not in captured.err + captured.out
    assert f"calib {argv[0]}: error: " in captured.err


def test_every_command_has_a_bad_input_case():
    from sltwin.cli import COMMANDS

    covered = {line.split()[0] for _, line, _ in CASES}
    assert {name for name, _ in COMMANDS} <= covered, {name for name, _ in COMMANDS} - covered
