"""`calib unwrap` and `calib plan-fringes` on a synthetic capture in the DESIGN.md layout."""
import numpy as np
import pytest

from sltwin.cli import main
from unwrap.patterns import absolute_phase

def test_calib_unwrap_writes_the_design_hdf5_layout_with_exact_orders(design_capture, tmp_path, capsys):
    import h5py
    root, coords = design_capture
    out = tmp_path / "out"
    assert main(["unwrap", str(root), "--method", "mf", "-o", str(out)]) == 0
    assert (out / "v_unwrap.png").exists() and (out / "h_unwrap.png").exists()
    with h5py.File(out / "unwrap.h5") as h5:
        for o, (c, extent) in coords.items():
            g = h5[o]
            assert g["phase"].dtype == np.float64 and g["order"].dtype == np.int32
            assert g["valid"].dtype == bool and g["valid"][()].all()
            truth = absolute_phase(c, 48, extent)
            phase = g["phase"][()]
            assert np.abs(phase - truth).max() < 1e-4  # 16-bit quantisation (measured 1.9e-5); any k error is 2 pi
            # k is the order of the stored phase: phase - 2 pi k is the wrapped phase in [-pi, pi]
            assert np.abs(phase - 2 * np.pi * g["order"][()]).max() <= np.pi + 1e-9
            assert np.abs(g["projector_coordinate"][()] - c).max() < 3e-4   # measured 7.2e-5 px
            assert g.attrs["method"] == "mf" and g.attrs["frequency"] == 48
    err = capsys.readouterr().err
    assert "orientation v" in err and "f = 48" in err  # progress


def test_calib_unwrap_reports_missing_frames_and_unknown_layouts_cleanly(design_capture, tmp_path, capsys):
    root, _ = design_capture
    (root / "pose_00" / "v_f048_n07.png").unlink()
    assert main(["unwrap", str(root), "-o", str(tmp_path / "o")]) == 2
    assert "found 11 of 12 frames v_f048_nNN" in capsys.readouterr().err
    empty = tmp_path / "empty"
    empty.mkdir()
    assert main(["unwrap", str(empty), "-o", str(tmp_path / "o")]) == 2
    assert "not a known scanner layout" in capsys.readouterr().err
    assert main(["unwrap", str(root), "--method", "gray", "-o", str(tmp_path / "o")]) == 2


def test_calib_plan_fringes_prints_error_rate_vs_images(capsys):
    assert main(["plan-fringes", "--sigma", "3", "--modulation", "50", "--steps", "3", "12",
                 "--sets", "mf:1,8,48", "mf:1,96"]) == 0
    out = capsys.readouterr().out
    assert "| mf:1,96 | 3 | 6 |" in out and "over limit" in out


def _two_frequency_capture(root, frequencies=(47, 48), steps=4):
    """A noise-free 16-bit capture in the DESIGN.md layout with the pair MW and NT take."""
    import cv2

    from unwrap.patterns import fringe_intensity
    pose = root / "pose_00"
    pose.mkdir(parents=True)
    (root / "capture.toml").write_text(f"[pattern]\nsteps = {[steps] * len(frequencies)}\n"
                                       f"frequencies = {list(frequencies)}\n\n[camera]\nsize = [64, 48]\n\n"
                                       "[projector]\nsize = [912, 1140]\n")
    y, x = np.mgrid[0:48, 0:64].astype(np.float64)
    coords = {"v": (5.0 + 14.1 * x + 0.3 * y, 912), "h": (8.0 + 23.2 * y + 0.2 * x, 1140)}
    for o, (c, extent) in coords.items():
        for f in frequencies:
            for n in range(steps):
                I = fringe_intensity(absolute_phase(c, f, extent), n, steps, A=30000, B=25000)
                cv2.imwrite(str(pose / f"{o}_f{f:03d}_n{n:02d}.png"), np.round(I).astype(np.uint16))
    return coords


@pytest.mark.parametrize("method", ["mw", "nt"])
def test_calib_unwrap_mw_and_nt_give_exact_orders_on_a_47_48_capture(method, tmp_path):
    """The passing case of --method mw / nt (the pair one period apart: a beat of one period for
    MW, coprime for NT): every pixel valid, the absolute phase of 48 periods to the 16-bit
    quantisation (measured 2.6e-5 rad, 1.0e-4 projector px), no order wrong (an order error is 2 pi)."""
    import h5py

    coords = _two_frequency_capture(tmp_path / "cap")
    out = tmp_path / method
    assert main(["unwrap", str(tmp_path / "cap"), "--method", method, "-o", str(out), "-q", "--no-previews"]) == 0
    with h5py.File(out / "unwrap.h5") as h5:
        for o, (c, extent) in coords.items():
            g = h5[o]
            assert g.attrs["method"] == method and g.attrs["frequency"] == 48
            assert g["valid"][()].all()
            assert np.abs(g["phase"][()] - absolute_phase(c, 48, extent)).max() < 1e-4
            assert np.abs(g["projector_coordinate"][()] - c).max() < 4e-4
