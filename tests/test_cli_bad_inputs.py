"""Every ``calib`` sub-command on a table of bad inputs: exit code 2, a message naming the input,
no traceback (issue 15). Adding a command or a case is one row of ``CASES``:

    (case id, command line, text the error message must contain)

Placeholders in the command line: ``{bad}`` (a folder of broken files, built below), ``{cap}``
(a folder of small DESIGN.md captures, phase-shift and Gray-code-only, one good and one per
defect), ``{out}`` (a fresh output
path of the case) and ``{dp}`` (the paper's dp-tpu data; the case is skipped without it).
"""
import json
import re
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
    (bad / "corrupt.onnx").write_text("not an onnx model")
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
    _hardening_3_files(bad, cap)
    return {"bad": bad, "cap": cap}


def _hardening_3_files(bad, cap):
    """Issue 23's inputs: outputs that are inputs, locked outputs, outputs of another kind,
    duplicated and floating-point frames, HDF5 files of the wrong kind, a prior-free checkpoint."""
    import os
    import socket

    import torch

    from unwrap.learned.checkpoint import build_model, read_checkpoint, save_atomic
    from unwrap.learned.features import input_channels, output_channels
    from unwrap.learned.infer import shipped_model_path

    os.link(bad / "default.json", bad / "hardlink.json")
    os.symlink(bad / "default.json", bad / "symlink.json")
    # a live process (this test's parent) holds these outputs
    for name in ("locked_out", "locked.h5", "locked.ply", "locked.json"):
        (bad / f".{name}.lock").write_text(f"{os.getppid()} {socket.gethostname()}\n")
    session = bad / "session"               # what calib render-board leaves: [board] + 9 poses
    for i in range(9):
        (session / f"pose_{i:02d}").mkdir(parents=True)
    (session / "capture.toml").write_text("[board]\nkind = 'circles'\n[pattern]\nsteps = 12\n")
    render_out = bad / "render_out"          # what calib render leaves
    render_out.mkdir()
    (render_out / "truth.h5").write_bytes(b"")
    (render_out / "white.png").write_bytes(b"")
    (bad / "nonempty").mkdir()
    (bad / "nonempty" / "notes.txt").write_text("mine")
    (bad / "scene_dup.toml").write_text(SCENE.replace('kind = "white"', 'kind = "phase"\nfrequencies = [1, 8, 8.0]\n'
                                                                        "steps = 4"))
    (bad / "scene_huge.toml").write_text(SCENE.replace('kind = "white"', 'kind = "phase"\nfrequencies = [1, 8]\n'
                                                                         "steps = 10000000"))
    (bad / "scene_alias.toml").write_text(SCENE.replace('kind = "white"', 'kind = "phase"\nfrequencies = [1, 8, '
                                                                          "2000]\nsteps = 4"))
    with h5py.File(bad / "truth.h5", "w") as f:            # a render's ground truth
        f["depth"] = np.zeros((4, 4))
        f["masks/object"] = np.zeros((4, 4), bool)
    with h5py.File(bad / "foreign.h5", "w") as f:          # someone else's HDF5, a schema attribute of two values
        f["data"] = np.zeros(10)
        f.attrs["schema"] = np.array([b"a", b"b"])
    data = (bad / "unwrap48.h5").read_bytes()
    (bad / "truncated.h5").write_bytes(data[: len(data) // 3])
    ck = read_checkpoint(shipped_model_path())                # the prior-free kind, same size
    arch = dict(ck["arch"], kind="prior_free", in_channels=input_channels("prior_free"),
                out_channels=output_channels("prior_free", ck["arch"]["max_correction"]))
    torch.manual_seed(0)
    save_atomic(dict(ck, arch=arch, model=build_model(arch).state_dict()), bad / "pf.pt")
    pose = _write_capture(cap / "dup_frame")
    shutil.copy(pose / "v_f008_n02.png", pose / "v_f008_n03.png")
    pose = _write_capture(cap / "dup_h1")
    shutil.copy(pose / "h_f001_n00.png", pose / "h_f001_n01.png")
    pose = _write_capture(cap / "near_dup")
    frame = cv2.imread(str(pose / "v_f008_n01.png"), -1).astype(np.int16)
    noise = np.random.default_rng(0).integers(-1, 2, frame.shape)
    cv2.imwrite(str(pose / "v_f008_n02.png"), np.clip(frame + noise, 0, 255).astype(np.uint8))
    for name, change in (("float_tiff", lambda a: a), ("nan_tiff", lambda a: np.where(a > 0.7, np.nan, a))):
        pose = _write_capture(cap / name)
        for png in sorted(pose.glob("*.png")):
            image = cv2.imread(str(png), -1).astype(np.float32) / 255
            cv2.imwrite(str(png.with_suffix(".tif")), change(image).astype(np.float32))
            png.unlink()


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
    ("export-ladder-no-redundancy", "export --capture {cap}/good --reference ladder -o {out}.h5", "three or more"),
    ("train-init-other-kind", "train model.kind=prior_free data.synthetic_samples=4 data.synthetic_size=[32,32] "
     "--init learned -o {out}", "prior_free"),
    ("train-init-other-width", "train model.width=16 data.synthetic_samples=4 data.synthetic_size=[32,32] "
     "--init learned -o {out}", "width: checkpoint 8, run 16"),
    ("train-init-corrupt", "train data.synthetic_samples=4 --init {bad}/corrupt.pt -o {out}", "corrupt.pt"),
    ("eval-corrupt-checkpoint", "eval --model {bad}/corrupt.pt --synthetic 1 --no-speed -o {out}", "corrupt.pt"),
    ("eval-no-test", "eval -o {out}", "--test"),
    ("eval-missing-test", "eval --test {bad}/nowhere.h5 --no-speed -o {out}", "nowhere.h5"),
    ("unwrap-model-corrupt", "unwrap {cap}/good --model {bad}/corrupt.pt -o {out}", "corrupt.pt"),
    ("unwrap-model-gray", "unwrap {cap}/good --model learned --method gray -o {out}", "--method"),
    ("unwrap-model-max-error-rate", "unwrap {cap}/good --model learned --max-error-rate 1e-3 -o {out}",
     "--max-error-rate"),
    # calib unwrap --spatial (issue 21)
    ("unwrap-spatial-gray", "unwrap {cap}/good --spatial graphcut --method gray -o {out}", "--method"),
    ("unwrap-no-gate-alone", "unwrap {cap}/good --no-gate -o {out}", "--no-gate"),
    ("unwrap-spatial-max-error-rate", "unwrap {cap}/good --spatial graphcut --max-error-rate 1e-3 -o {out}",
     "--max-error-rate"),
    # issue 23, data loss: an output that is also an input (same path, hard or symbolic link, a folder
    # holding an input, a path inside an input folder), refused before any work
    ("export-combine-output-is-input", "export --combine {bad}/unwrap48.h5 {bad}/foreign.h5 -o {bad}/unwrap48.h5",
     "is also an input"),
    ("export-config-output-is-input", "export {bad}/scene.toml -o {bad}/scene.toml", "is also an input"),
    ("export-capture-output-in-capture", "export --capture {cap}/good -o {cap}/good/real.h5",
     "inside the input folder"),
    ("convert-output-is-input", "convert {bad}/default.json -o {bad}/default.json", "is also an input"),
    ("convert-output-hard-link", "convert {bad}/default.json -o {bad}/hardlink.json", "is also an input"),
    ("convert-output-symlink", "convert {bad}/default.json -o {bad}/symlink.json", "is also an input"),
    ("twin-output-is-input", "twin {bad}/default.json -o {bad}/default.json", "is also an input"),
    ("twin-script-is-input", "twin {bad}/default.json -o {out}.json --blender-script {bad}/default.json",
     "is also an input"),
    ("reconstruct-output-is-phase", "reconstruct --phase {bad}/all_nan.npy --frequency 96 --calibration "
     "{bad}/default.json -o {bad}/all_nan.npy", "is also an input"),
    ("reconstruct-output-is-calibration", "reconstruct --phase {bad}/all_nan.npy --frequency 96 --calibration "
     "{bad}/default.json -o {bad}/default.json", "is also an input"),
    ("unwrap-output-is-capture", "unwrap {cap}/good -o {cap}/good", "is also an input"),
    ("unwrap-output-inside-capture", "unwrap {cap}/good -o {cap}/good/pose_00", "inside the input folder"),
    ("unwrap-output-holds-model", "unwrap {cap}/good --model {bad}/pf.pt -o {bad}", "holds the input"),
    ("run-output-is-capture", "run {cap}/good -o {cap}/good", "is also an input"),
    ("run-output-holds-observations", "run --observations {bad}/text.mat {bad}/text.mat -o {bad}", "holds the input"),
    ("render-output-holds-scene", "render {bad}/scene.toml -o {bad}", "holds the input"),
    ("render-board-output-holds-system", "render-board {bad}/default.json -o {bad}", "holds the input"),
    ("report-output-holds-input", "report --real {bad}/default.json --twin {bad}/default.json -o {bad}",
     "holds the input"),
    ("eval-output-holds-test", "eval --test {bad}/unwrap48.h5 --no-speed -o {bad}", "holds the input"),
    ("train-output-holds-config", "train {bad}/train_unknown_key.toml -o {bad}", "holds the input"),
    # issue 23, data loss: two writers of one output (the lock of a live process)
    ("train-output-locked", "train optim.steps=1 -o {bad}/locked_out", "another process is writing it (pid"),
    ("train-resume-locked", "train --resume {bad}/locked_out", "another process is writing it (pid"),
    ("export-output-locked", "export --capture {cap}/good -o {bad}/locked.h5", "another process is writing it"),
    ("export-combine-output-locked", "export --combine {bad}/unwrap48.h5 -o {bad}/locked.h5",
     "another process is writing it"),
    ("export-config-output-locked", "export {bad}/scene.toml -o {bad}/locked.h5", "another process is writing it"),
    ("unwrap-output-locked", "unwrap {cap}/good -o {bad}/locked_out", "another process is writing it"),
    ("eval-output-locked", "eval --synthetic 1 --no-speed -o {bad}/locked_out", "another process is writing it"),
    ("reconstruct-output-locked", "reconstruct --phase {bad}/all_nan.npy --frequency 96 --calibration "
     "{bad}/default.json -o {bad}/locked.ply", "another process is writing it"),
    ("render-output-locked", "render {bad}/scene.toml -o {bad}/locked_out", "another process is writing it"),
    ("render-board-output-locked", "render-board -o {bad}/locked_out", "another process is writing it"),
    ("run-output-locked", "run {cap}/good -o {bad}/locked_out", "another process is writing it"),
    ("report-output-locked", "report --real {bad}/default.json --twin {bad}/default.json -o {bad}/locked_out",
     "another process is writing it"),
    ("twin-output-locked", "twin -o {bad}/locked.json", "another process is writing it"),
    ("convert-output-locked", "convert {bad}/default.json -o {bad}/locked.json", "another process is writing it"),
    ("demo-output-locked", "demo -o {bad}/locked_out", "another process is writing it"),
    # issue 23, data loss: an output folder holding an output of another kind (or anything)
    ("render-into-board-session", "render {bad}/scene.toml -o {bad}/session", "a calibration session of 9 pose(s)"),
    ("render-board-into-larger-session", "render-board --poses 2 -o {bad}/session", "a calibration session of 9"),
    ("render-board-into-render", "render-board -o {bad}/render_out", "holds a render"),
    ("render-into-render", "render {bad}/scene.toml -o {bad}/render_out", "--overwrite"),
    ("render-into-folder-of-files", "render {bad}/scene.toml -o {bad}/nonempty", "notes.txt"),
    ("render-board-into-capture", "render-board -o {cap}/good", "a capture of 1 pose(s)"),
    # issue 23, crashes: numbers no computation can use, refused by the option's name
    ("run-outlier-threshold-negative", "run {cap}/good --outlier-threshold -1 -o {out}", "--outlier-threshold"),
    ("run-loss-scale-0", "run {cap}/good --loss-scale 0 -o {out}", "--loss-scale"),
    ("run-skew-tol-negative", "run {cap}/good --skew-tol -0.5 -o {out}", "--skew-tol"),
    ("render-board-poses-0", "render-board --poses 0 -o {out}", "--poses"),
    ("render-board-frequency-negative", "render-board --frequencies 1 -8 48 -o {out}", "--frequencies"),
    ("render-board-frequency-nan", "render-board --frequencies 1 nan -o {out}", "--frequencies"),
    ("plan-sigma-0", "plan-fringes --sigma 0", "--sigma"),
    ("plan-modulation-negative", "plan-fringes --modulation -60", "--modulation"),
    ("plan-max-error-rate-0", "plan-fringes --max-error-rate 0", "--max-error-rate"),
    ("reconstruct-camera-size-0", "reconstruct --phase {bad}/all_nan.npy --frequency 96 --calibration "
     "{bad}/default.json --camera-size 0 480 -o {out}.ply", "--camera-size"),
    ("twin-projector-size-negative", "twin --projector-size -912 1140 -o {out}.json", "--projector-size"),
    ("convert-skew-tol-0", "convert {bad}/default.json -o {out}.json --skew-tol 0", "--skew-tol"),
    ("unwrap-noise-sigma-0", "unwrap {cap}/good --noise-sigma 0 -o {out}", "--noise-sigma"),
    ("report-frequency-0", "report --real {bad}/default.json --twin {bad}/default.json --frequency 0 -o {out}",
     "--frequency"),
    ("eval-synthetic-negative", "eval --synthetic -2 -o {out}", "--synthetic"),
    # issue 23, crashes: sizes that cannot fit, refused before allocating, naming the key
    ("train-max-correction-absurd", "train data.synthetic_samples=8 model.max_correction=1000000 -o {out}",
     "model.max_correction = 1000000"),
    ("train-depth-absurd", "train data.synthetic_samples=8 model.depth=12 -o {out}", "model.depth = 12"),
    ("train-batch-absurd", "train data.synthetic_samples=8 optim.batch_size=100000 -o {out}",
     "optim.batch_size = 100000"),
    ("render-board-steps-absurd", "render-board --steps 100000 -o {out}", "600000 fringe images"),
    ("render-steps-absurd", "render {bad}/scene_huge.toml -o {out}", "at most 10000 per sequence"),
    ("train-width-absurd", "train data.synthetic_samples=8 model.width=4096 model.max_width=4096 -o {out}", "GB"),
    # issue 23, silently wrong: duplicated frames, models of the other kind, inputs giving empty tables
    ("unwrap-duplicated-frame", "unwrap {cap}/dup_frame -o {out}", "v_f008_n03.png: identical to"),
    ("unwrap-duplicated-frame-h-unit", "unwrap {cap}/dup_h1 -o {out}", "h_f001_n01.png: identical to"),
    ("unwrap-near-duplicate-frame", "unwrap {cap}/near_dup -o {out}", "v_f008_n02.png: nearly identical"),
    ("unwrap-model-duplicated-frame", "unwrap {cap}/dup_frame --model learned -o {out}", "identical to"),
    ("export-capture-duplicated-frame", "export --capture {cap}/dup_frame -o {out}.h5", "identical to"),
    ("unwrap-model-prior-free", "unwrap {cap}/good --model {bad}/pf.pt -o {out}",
     "a prior-free model; --model takes a physics-aware one"),
    ("eval-model-prior-free", "eval --model {bad}/pf.pt --synthetic 1 --no-speed -o {out}",
     "--model takes a physics-aware one (give it as --prior-free)"),
    ("eval-prior-free-physics", "eval --prior-free learned --synthetic 1 --no-speed -o {out}",
     "--prior-free takes a prior-free one (give it as --model)"),
    ("eval-mse-only-prior-free", "eval --mse-only {bad}/pf.pt --synthetic 1 --no-speed -o {out}",
     "--mse-only takes a physics-aware one"),
    ("eval-test-unwrap-h5", "eval --test {bad}/unwrap48.h5 --no-speed -o {out}", "is a phase file"),
    ("eval-test-truth-h5", "eval --test {bad}/truth.h5 --no-speed -o {out}", "a render's ground truth"),
    ("eval-real-unwrap-h5", "eval --synthetic 1 --real {bad}/unwrap48.h5 --no-speed -o {out}",
     "calib export --capture"),
    ("eval-max-samples-0", "eval --synthetic 1 --max-samples 0 -o {out}", "--max-samples"),
    ("eval-max-samples-negative", "eval --synthetic 1 --max-samples -1 -o {out}", "--max-samples"),
    ("eval-s5-0", "eval --synthetic 1 --s5 0 -o {out}", "--s5"),
    ("eval-s5-unit", "eval --synthetic 1 --s5 1 -o {out}", "--s5 1"),
    ("eval-s6-negative", "eval --synthetic 1 --s6 -16 -o {out}", "--s6"),
    ("eval-window-0", "eval --synthetic 1 --window 0 -o {out}", "--window"),
    ("eval-training-run-not-a-run", "eval --synthetic 1 --no-speed --training-run x={bad}/adir -o {out}",
     "no metrics.json"),
    ("eval-training-run-missing", "eval --synthetic 1 --no-speed --training-run x={bad}/nowhere -o {out}",
     "no such folder"),
    ("report-learned-real-unwrap-h5", "report --real {bad}/default.json --twin {bad}/default.json --learned-real "
     "{bad}/unwrap48.h5 --learned-twin {bad}/unwrap48.h5 -o {out}", "is a phase file"),
    ("report-learned-real-truncated", "report --real {bad}/default.json --twin {bad}/default.json --learned-real "
     "{bad}/truncated.h5 --learned-twin {bad}/unwrap48.h5 -o {out}", "truncated.h5: not a readable HDF5 file"),
    ("render-board-duplicate-frequencies", "render-board --frequencies 1 8 8 48 -o {out}",
     "frequency 8 is given twice"),
    ("render-board-duplicate-float-frequency", "render-board --frequencies 1 8 8.0 -o {out}", "given twice"),
    ("render-board-aliased-frequency", "render-board --frequencies 1 8 2000 -o {out}", "alias"),
    ("render-duplicate-frequencies", "render {bad}/scene_dup.toml -o {out}", "given twice"),
    ("render-aliased-frequency", "render {bad}/scene_alias.toml -o {out}", "alias"),
    # issue 23, unclear messages: HDF5 files of the wrong kind named, frames named by their type,
    # outputs that are devices
    ("eval-test-truncated", "eval --test {bad}/truncated.h5 --no-speed -o {out}", "not a readable HDF5 file"),
    ("eval-test-foreign", "eval --test {bad}/foreign.h5 --no-speed -o {out}", "foreign.h5"),
    ("train-data-truncated", "train data.train=['{bad}/truncated.h5'] -o {out}", "truncated.h5: not a readable HDF5"),
    ("train-data-foreign", "train data.train=['{bad}/foreign.h5'] -o {out}", "foreign.h5: not a readable"),
    ("report-phase-truncated", "report --real {bad}/default.json --twin {bad}/default.json --phase-real "
     "{bad}/truncated.h5 -o {out}", "truncated.h5: not a readable HDF5 file"),
    ("reconstruct-phase-truncated", "reconstruct --phase {bad}/truncated.h5 --calibration {bad}/default.json "
     "-o {out}.ply", "truncated.h5: not a readable HDF5 file"),
    ("reconstruct-phase-foreign", "reconstruct --phase {bad}/foreign.h5 --frequency 48 --calibration "
     "{bad}/default.json -o {out}.ply", "foreign.h5"),
    ("unwrap-float-tiff", "unwrap {cap}/float_tiff -o {out}", "floating-point (float32) frame"),
    ("unwrap-nan-tiff", "unwrap {cap}/nan_tiff -o {out}", "NaN/inf pixel"),
    ("export-capture-float-tiff", "export --capture {cap}/float_tiff -o {out}.h5", "floating-point (float32) frame"),
    ("twin-output-dev-null", "twin -o /dev/null", "not a regular file"),
    ("convert-output-dev-null", "convert {bad}/default.json -o /dev/null", "not a regular file"),
    ("reconstruct-output-dev-null", "reconstruct --phase {bad}/all_nan.npy --frequency 96 --calibration "
     "{bad}/default.json -o /dev/null", "not a regular file"),
    ("export-output-dev-null", "export --capture {cap}/good -o /dev/null", "not a regular file"),
    ("export-combine-output-dev-null", "export --combine {bad}/unwrap48.h5 -o /dev/null", "not a regular file"),
    ("unwrap-output-dev-null", "unwrap {cap}/good -o /dev/null", "not a regular file or folder"),
    ("render-output-dev-null", "render {bad}/scene.toml -o /dev/null", "not a regular file or folder"),
    ("render-board-output-dev-null", "render-board -o /dev/null", "not a regular file or folder"),
    ("run-output-dev-null", "run {cap}/good -o /dev/null", "not a regular file or folder"),
    ("report-output-dev-null", "report --real {bad}/default.json --twin {bad}/default.json -o /dev/null",
     "not a regular file or folder"),
    ("eval-output-dev-null", "eval --synthetic 1 -o /dev/null", "not a regular file or folder"),
    ("train-output-dev-null", "train optim.steps=1 -o /dev/null", "not a regular file or folder"),
    ("demo-output-dev-null", "demo -o /dev/null", "not a regular file or folder"),
    # issue 23, friction: the built-in system by name (the error is then about the phase, not the file)
    ("reconstruct-builtin-calibration", "reconstruct --phase {bad}/all_nan.npy --frequency 96 --calibration builtin "
     "-o {out}.ply", "no valid pixel"),
    # calib export-model / unwrap --model model.onnx (issue 22)
    ("export-model-corrupt", "export-model {bad}/corrupt.pt -o {out}.onnx", "corrupt.pt"),
    ("export-model-not-onnx", "export-model learned -o {out}.pt", ".onnx"),
    ("unwrap-model-onnx-missing", "unwrap {cap}/good --model {bad}/nowhere.onnx -o {out}", "nowhere.onnx"),
    ("unwrap-model-onnx-foreign", "unwrap {cap}/good --model {bad}/corrupt.onnx -o {out}", "corrupt.onnx"),
]


@pytest.mark.parametrize("case, line, expected", [pytest.param(*c, marks=pytest.mark.realdata) if "{dp}" in c[1] else c
                                                   for c in CASES], ids=[c[0] for c in CASES])
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
    unknown = set(re.findall(r"(?<![\w/.-])--[a-z][a-z0-9-]*", captured.err)) - _all_options()
    assert not unknown, f"the message suggests option(s) no command has: {unknown}: {captured.err}"


def _all_options() -> set:
    """Every option string of every ``calib`` command (a message may name another command's)."""
    from sltwin.cli import build_parser

    parser = build_parser()
    sub = next(a for a in parser._actions if a.dest == "command")
    return {o for p in sub.choices.values() for a in p._actions for o in a.option_strings} | \
        {o for a in parser._actions for o in a.option_strings}


def test_readme_counts_the_rows():
    from conftest import REPO

    text = (REPO / "README.md").read_text()
    counts = [int(n) for n in re.findall(r"on a table of (\d+) broken inputs", text)]
    assert counts == [len(CASES)], (counts, len(CASES))


def test_every_command_has_a_bad_input_case():
    from sltwin.cli import COMMANDS

    covered = {line.split()[0] for _, line, _ in CASES}
    assert {name for name, _ in COMMANDS} <= covered, {name for name, _ in COMMANDS} - covered
