"""Every ``calib`` sub-command on a table of bad inputs: exit code 2, a message naming the input,
no traceback (issue 15). Adding a command or a case is one row of ``CASES``:

    (case id, command line, text the error message must contain)

Placeholders in the command line: ``{bad}`` (a folder of broken files, built below), ``{cap}``
(a folder of small DESIGN.md captures, phase-shift and Gray-code-only, one good and one per
defect), ``{out}`` (a fresh output
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


GRAY_TOML = """
[pattern]
kind = "graycode"
block_px = {block}
inverse = true

[camera]
size = [{w}, 32]

[projector]
size = [16, 8]
"""


def _write_gray_capture(folder, *, block=1, width=64, contrast=180):
    """A Gray-code-only DESIGN.md capture of one pose: projector 16x8 seen at 4 camera px per
    projector px (64x32), column and row bits with inverses, white, black; 8-bit."""
    from unwrap.graycode import gray_code_bits
    from unwrap.graycode_capture import gray_bits

    pose = folder / "pose_00"
    pose.mkdir(parents=True)
    (folder / "capture.toml").write_text(GRAY_TOML.format(block=block, w=width))
    cv2.imwrite(str(pose / "white.png"), np.full((32, 64), 30 + contrast, np.uint8))
    cv2.imwrite(str(pose / "black.png"), np.full((32, 64), 30, np.uint8))
    for o, extent in (("v", 16), ("h", 8)):
        bits = gray_code_bits(np.arange(extent) // block, gray_bits(extent, block))     # (n, extent)
        for b, row in enumerate(bits):
            line = np.repeat(30 + contrast * row, 4).astype(np.uint8)
            frame = np.broadcast_to(line[None, :] if o == "v" else line[:, None], (32, 64))
            cv2.imwrite(str(pose / f"{o}_gray_b{b:02d}.png"), frame)
            cv2.imwrite(str(pose / f"{o}_gray_b{b:02d}_inv.png"), (2 * 30 + contrast - frame).astype(np.uint8))
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
    (bad / "corrupt.pt").write_text("not a torch checkpoint")
    (bad / "train_unknown_key.toml").write_text("[optim]\nstpes = 10\n")
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
    _write_capture(cap / "no_frequencies")
    (cap / "no_frequencies" / "capture.toml").write_text("[pattern]\nsteps = 4\nfrequencies = []\n"
                                                         "[projector]\nsize = [912, 1140]\n")
    _write_capture(cap / "bad_kind", extra='kind = "speckle"')
    # Gray-code-only captures: the same frame checks as phase-shift ones
    _write_gray_capture(cap / "gray")
    pose = _write_gray_capture(cap / "gray_mixed_depth")
    cv2.imwrite(str(pose / "h_gray_b01.png"), cv2.imread(str(pose / "h_gray_b01.png"), -1).astype(np.uint16) * 257)
    _write_gray_capture(cap / "gray_size_mismatch", width=100)
    pose = _write_gray_capture(cap / "gray_extra_bit")
    shutil.copy(pose / "v_gray_b03.png", pose / "v_gray_b04.png")
    pose = _write_gray_capture(cap / "gray_with_fringes")
    shutil.copy(pose / "white.png", pose / "v_f001_n00.png")
    _write_gray_capture(cap / "gray_all_black", contrast=0)
    _write_gray_capture(cap / "gray_block_0", block=1)
    toml = cap / "gray_block_0" / "capture.toml"
    toml.write_text(toml.read_text().replace("block_px = 1", "block_px = 0"))
    # every description is strict (unwrap.strict): a typo names the closest key, a wrong type the expected one
    _write_capture(cap / "typo", extra="shift_sing = -1")
    _write_capture(cap / "steps_string")
    toml = cap / "steps_string" / "capture.toml"
    toml.write_text(toml.read_text().replace("steps = 4", 'steps = "4"'))
    (bad / "export_typo.toml").write_text("[export]\nsamples = 1\nsed = 3\n")
    (bad / "export_steps_float.toml").write_text("[export]\nsamples = 1\n[patterns]\nsteps = 4.0\n")
    (bad / "export_ok.toml").write_text("[export]\nsamples = 1\n")
    (bad / "scene_typo.toml").write_text("[[objects]]\nkind = 'sphere'\nradius = 3\n" + SCENE.split("\n", 3)[3])
    (bad / "scene_a_string.toml").write_text(SCENE.replace("[[patterns.sequence]]",
                                                           "[patterns]\nA = 'x'\n[[patterns.sequence]]"))
    procam = cap / "procam_no_toml" / "capture_0"
    procam.mkdir(parents=True)
    for i in range(18):
        cv2.imwrite(str(procam / f"graycode_{i:02d}.png"), np.zeros((32, 64), np.uint8))
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
    ("reconstruct-both-of-one-map", "reconstruct --phase {bad}/all_nan.npy --frequency 96 --orientation both "
     "--calibration {bad}/default.json -o {out}.ply", "all_nan.npy holds one phase map"),
    ("reconstruct-orientation-not-stored", "reconstruct --phase {bad}/unwrap48.h5 --orientation h --calibration "
     "{bad}/default.json -o {out}.ply", "unwrap48.h5 holds orientation(s) ['v']"),
    ("reconstruct-orientation-unknown", "reconstruct --phase {bad}/unwrap48.h5 --orientation diagonal "
     "--calibration {bad}/default.json -o {out}.ply", "--orientation"),
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
    ("unwrap-empty-frequencies", "unwrap {cap}/no_frequencies -o {out}", "frequencies = []"),
    ("unwrap-unknown-kind", "unwrap {cap}/bad_kind -o {out}", "kind = 'speckle'"),
    ("unwrap-unknown-preset", "unwrap {cap}/good --preset kaminski -o {out}", "--preset"),
    # calib unwrap of Gray-code-only captures (issue 16's layout) under issue 15's checks
    ("unwrap-gray-method-mf", "unwrap {cap}/gray --method mf -o {out}", "holds Gray code only"),
    ("unwrap-gray-max-error-rate", "unwrap {cap}/gray --max-error-rate 1e-3 -o {out}", "Gray code without phase"),
    ("unwrap-gray-min-modulation-absurd", "unwrap {cap}/gray --min-modulation 1e9 -o {out}", "exceeds the largest"),
    ("unwrap-gray-mixed-bit-depth", "unwrap {cap}/gray_mixed_depth -o {out}", "h_gray_b01.png: uint16 frame"),
    ("unwrap-gray-camera-size", "unwrap {cap}/gray_size_mismatch -o {out}", "[camera] size says 100x32"),
    ("unwrap-gray-extra-bit", "unwrap {cap}/gray_extra_bit -o {out}", "v_gray_b04.png"),
    ("unwrap-gray-stray-fringe-frame", "unwrap {cap}/gray_with_fringes -o {out}", "v_f001_n00.png"),
    ("unwrap-gray-all-black", "unwrap {cap}/gray_all_black -o {out}", "no valid pixel"),
    ("unwrap-gray-block-0", "unwrap {cap}/gray_block_0 -o {out}", "block_px"),
    ("unwrap-capture-unknown-key", "unwrap {cap}/typo -o {out}", "did you mean 'pattern.shift_sign'"),
    ("unwrap-capture-steps-string", "unwrap {cap}/steps_string -o {out}", "pattern.steps = '4': expected an integer"),
    ("run-capture-unknown-key", "run {cap}/typo -o {out}", "did you mean 'pattern.shift_sign'"),
    ("export-unknown-key", "export {bad}/export_typo.toml -o {out}.h5", "did you mean 'export.seed'"),
    ("export-steps-float", "export {bad}/export_steps_float.toml -o {out}.h5",
     "patterns.steps = 4.0: expected an integer"),
    ("export-unknown-override", "export {bad}/export_ok.toml --set export.smaples=2 -o {out}.h5",
     "did you mean 'export.samples'"),
    ("render-scene-unknown-key", "render {bad}/scene_typo.toml -o {out}", "did you mean 'objects[0].radius_mm'"),
    ("render-scene-a-string", "render {bad}/scene_a_string.toml -o {out}", "patterns.A = 'x': expected a number"),
    ("train-steps-float", "train optim.steps=4.0 -o {out}", "optim.steps = 4.0: expected an integer"),
    ("train-steps-string", 'train optim.steps="4" -o {out}', "optim.steps = '4': expected an integer"),
    ("unwrap-procam-no-projector-size", "unwrap {cap}/procam_no_toml/capture_0 -o {out}", "projector size"),
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
    ("render-board-gray-block-0", "render-board --pattern graycode --gray-block 0 -o {out}", "--gray-block"),
    ("render-board-unknown-pattern", "render-board --pattern speckle -o {out}", "--pattern"),
    # calib run
    ("run-output-is-file", "run {cap}/good -o {bad}/afile", "afile"),
    ("run-no-folder", "run {cap}/nowhere -o {out}", "nowhere"),
    ("run-text-mat-observations", "run --observations {bad}/text.mat {bad}/text.mat -o {out}", "text.mat"),
    ("run-no-input", "run -o {out}", "CAPTURES"),
    ("run-uncertainty-unknown", "run {cap}/good --uncertainty guess -o {out}", "--uncertainty"),
    ("run-board-warp-unknown", "run {cap}/good --board-warp maybe -o {out}", "--board-warp"),
    ("run-draws-2", "run {cap}/good --uncertainty bootstrap --draws 2 -o {out}", "--draws"),
    # calib export (issue 12's command)
    ("export-output-is-dir", "export --capture {cap}/good -o {bad}/adir", "adir"),
    # calib train / eval / unwrap --model (issue 13's commands)
    ("train-unknown-key", "train {bad}/train_unknown_key.toml -o {out}", "optim.stpes"),
    ("train-unknown-override", "train optim.stpes=10 -o {out}", "optim.stpes"),
    ("train-missing-config", "train {bad}/nowhere.toml -o {out}", "nowhere.toml"),
    ("train-resume-nothing", "train --resume {bad}/adir", "adir"),
    ("eval-corrupt-checkpoint", "eval --model {bad}/corrupt.pt --synthetic 1 --no-speed -o {out}", "corrupt.pt"),
    ("eval-no-test", "eval -o {out}", "--test"),
    ("eval-missing-test", "eval --test {bad}/nowhere.h5 --no-speed -o {out}", "nowhere.h5"),
    ("unwrap-model-corrupt", "unwrap {cap}/good --model {bad}/corrupt.pt -o {out}", "corrupt.pt"),
    ("unwrap-model-gray", "unwrap {cap}/good --model learned --method gray -o {out}", "--method"),
    ("unwrap-model-max-error-rate", "unwrap {cap}/good --model learned --max-error-rate 1e-3 -o {out}",
     "--max-error-rate"),
]


@pytest.mark.parametrize("case, line, expected", CASES, ids=[c[0] for c in CASES])
def test_bad_input_is_exit_2_with_a_message_naming_it_and_no_traceback(case, line, expected, files, tmp_path,
                                                                         capsys):
    if "{dp}" in line and not (SHARED_DATA / "dp-tpu").exists():
        pytest.skip("the paper's dp-tpu data are not present")
    argv = line.format(bad=files["bad"], cap=files["cap"], dp=SHARED_DATA / "dp-tpu", out=tmp_path / case).split()
    try:
        code = main(argv)
    except SystemExit as exc:       # argparse's usage errors (an unknown choice) exit from the parser
        code = exc.code
    captured = capsys.readouterr()
    assert code == 2, (argv, captured.err)
    assert expected in captured.err, captured.err
    assert "Traceback" not in captured.err + captured.out
    assert f"calib {argv[0]}: error: " in captured.err


def test_every_command_has_a_bad_input_case():
    from sltwin.cli import COMMANDS

    covered = {line.split()[0] for _, line, _ in CASES}
    assert {name for name, _ in COMMANDS} <= covered, {name for name, _ in COMMANDS} - covered
