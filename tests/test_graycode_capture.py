"""Gray-code-only sessions: the capture layouts (DESIGN.md kind = "graycode", kamino410's
procam-calibration folders), the decoder (block index -> block centre) and the refusals that name
the real limitation."""
import cv2
import numpy as np
import pytest

from sltwin.cli import main
from unwrap import UnwrapError
from unwrap.capture import load_capture
from unwrap.graycode import gray_code_bits
from unwrap.graycode_capture import gray_bits
from unwrap.patterns import projector_coordinate
from unwrap.pipeline import unwrap_capture

PRJ = (40, 24)          # projector W x H
SCALE = 3               # camera pixels per projector pixel (the camera sees the projector straight on)


def _code_frames(orientation, block):
    """(bits, H_cam, W_cam) uint8 frames of the Gray code of projector blocks, seen by the camera."""
    W, H = PRJ
    n = gray_bits(W if orientation == "v" else H, block)
    idx = np.arange(W if orientation == "v" else H) // block
    bits = gray_code_bits(idx, n)                               # (n, extent)
    if orientation == "v":
        img = np.broadcast_to(bits[:, None, :], (n, H, W))
    else:
        img = np.broadcast_to(bits[:, :, None], (n, H, W))
    img = np.repeat(np.repeat(img, SCALE, axis=1), SCALE, axis=2)
    return (30 + 180 * img).astype(np.uint8)


def _write_design(folder, block=1, inverse=True, pattern_extra=""):
    pose = folder / "pose_00"
    pose.mkdir(parents=True)
    (folder / "capture.toml").write_text(
        f'[pattern]\nkind = "graycode"\nblock_px = {block}\ninverse = {"true" if inverse else "false"}\n'
        f"{pattern_extra}\n[projector]\nsize = [{PRJ[0]}, {PRJ[1]}]\n")
    shape = (PRJ[1] * SCALE, PRJ[0] * SCALE)
    cv2.imwrite(str(pose / "white.png"), np.full(shape, 210, np.uint8))
    cv2.imwrite(str(pose / "black.png"), np.full(shape, 30, np.uint8))
    for o in "vh":
        for b, frame in enumerate(_code_frames(o, block)):
            cv2.imwrite(str(pose / f"{o}_gray_b{b:02d}.png"), frame)
            if inverse:
                cv2.imwrite(str(pose / f"{o}_gray_b{b:02d}_inv.png"), 240 - frame)
    return folder


def _true_centre(o, block):
    W, H = PRJ
    extent = W if o == "v" else H
    x = np.arange(extent)
    start = x // block * block
    centre = 0.5 * (start + np.minimum(start + block, extent) - 1)   # a last, partial block: its part inside
    line = np.repeat(centre, SCALE)
    return np.broadcast_to(line[None, :] if o == "v" else line[:, None], (H * SCALE, W * SCALE))


@pytest.mark.parametrize("block, inverse", [(1, True), (4, True), (1, False)])
def test_design_graycode_session_decodes_every_pixel_to_its_block_centre(tmp_path, block, inverse):
    res = unwrap_capture(_write_design(tmp_path, block, inverse))    # method: the capture's own (gray)
    for o in "vh":
        r = res[o]
        assert r.result.valid.all() and r.quantisation_px == block
        coord = projector_coordinate(r.result.phase, r.result.frequency, r.width)
        np.testing.assert_allclose(coord, _true_centre(o, block), atol=1e-9)


def test_gray_only_refusals_name_the_limitation(tmp_path, capsys):
    root = _write_design(tmp_path / "s")
    assert main(["unwrap", str(root), "--method", "mf", "-o", str(tmp_path / "o")]) == 2
    assert "holds Gray code only" in capsys.readouterr().err
    assert main(["unwrap", str(root), "-o", str(tmp_path / "o")]) == 0
    (root / "pose_00" / "h_gray_b02_inv.png").unlink()
    with pytest.raises(UnwrapError, match=r"orientation h: .*missing \['h_gray_b02_inv'\]"):
        load_capture(root)
    bad = _write_design(tmp_path / "b", pattern_extra="frequencies = [1, 8]")
    with pytest.raises(UnwrapError, match="do not apply to kind"):
        load_capture(bad)
    # a phase-shift description without frequencies, or with none, says how to describe Gray code
    for text, message in (('[pattern]\nsteps = 4\n', "no 'frequencies'.*kind = \"graycode\""),
                          ('[pattern]\nsteps = 4\nfrequencies = []\n', r"frequencies = \[\].*kind = \"graycode\"")):
        d = tmp_path / f"p{len(text)}"
        d.mkdir()
        (d / "capture.toml").write_text(text + "[projector]\nsize = [40, 24]\n")
        assert main(["unwrap", str(d), "--method", "gray", "-o", str(tmp_path / "o")]) == 2
        err = capsys.readouterr().err
        assert "Traceback" not in err and __import__("re").search(message, err), err


def _write_procam(folder, block=1):
    """A procam-calibration pose folder: OpenCV's own GrayCodePattern frames, white, black."""
    W, H = PRJ
    gw, gh = (W - 1) // block + 1, (H - 1) // block + 1
    ok, patterns = cv2.structured_light.GrayCodePattern.create(gw, gh).generate()
    frames = [np.repeat(np.repeat(p, block, 0), block, 1)[:H, :W] for p in patterns]
    frames += [np.full((H, W), 255, np.uint8), np.zeros((H, W), np.uint8)]
    pose = folder / "capture_0"
    pose.mkdir(parents=True)
    for i, f in enumerate(frames):
        img = np.repeat(np.repeat(f, SCALE, 0), SCALE, 1)
        cv2.imwrite(str(pose / f"graycode_{i:02d}.png"), (20 + 0.8 * img).astype(np.uint8))
    return pose


@pytest.mark.parametrize("block", [1, 3])
def test_procam_graycode_folder_in_opencv_order_decodes_with_the_projector_size_given(tmp_path, block):
    pose = _write_procam(tmp_path, block)
    with pytest.raises(UnwrapError, match=r"projector size"):
        load_capture(pose)                                       # recognised, but the split is unknown
    (tmp_path / "capture.toml").write_text(f"[pattern]\nblock_px = {block}\n[projector]\nsize = [{PRJ[0]}, {PRJ[1]}]\n")
    cap = load_capture(pose)                                     # capture.toml of the parent folder
    assert cap.preset == "procam-graycode" and cap.default_method == "gray"
    res = unwrap_capture(pose)
    for o in "vh":
        r = res[o]
        coord = projector_coordinate(r.result.phase, r.result.frequency, r.width)
        np.testing.assert_allclose(coord[r.result.valid], _true_centre(o, block)[r.result.valid], atol=1e-9)
        assert r.result.valid.all()
    last = sorted(pose.glob("graycode_*.png"))[-1]
    last.rename(pose / "graycode_99.png")
    with pytest.raises(UnwrapError, match="numbered"):
        load_capture(pose)
    (pose / "graycode_99.png").unlink()
    with pytest.raises(UnwrapError, match=r"needs \d+ frames .*found \d+"):
        load_capture(pose)


def test_kamino_preset_keeps_its_former_name_and_says_what_it_reads(tmp_path):
    from unwrap.capture import PRESET_ALIASES

    assert PRESET_ALIASES == {"kamino": "kamino-phaseshift"}


def test_exporting_a_gray_only_capture_as_phase_data_is_refused_by_name(tmp_path):
    from synth.errors import SynthError
    from synth.export.capture import export_capture

    root = _write_design(tmp_path / "s")
    with pytest.raises(SynthError, match="Gray code only"):
        export_capture(root, tmp_path / "real.h5")
