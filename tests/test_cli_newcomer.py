"""What a newcomer to the command line needs (issue 15, item 6): a version, tracebacks only when asked
for, no torch import for commands that render nothing, calibrations written back out in OpenCV's
format, scanner presets in BMP, ``calib render`` output that ``calib unwrap`` reads as it is."""
import json
import math
import subprocess
import sys

import cv2
import numpy as np
import pytest

from calib import default_system, load_system, save_system
from sltwin.cli import main
from unwrap.patterns import absolute_phase, fringe_intensity, projector_coordinate
from unwrap.pipeline import unwrap_capture

from conftest import REPO


def _calib(*args, cwd=None):
    """The real entry point in a fresh interpreter (what a user's shell runs)."""
    return subprocess.run([sys.executable, "-m", "sltwin", *args], capture_output=True, text=True, cwd=cwd,
                          env={"PYTHONPATH": str(REPO), "PATH": "/usr/bin:/bin"})


def test_version(capsys):
    with pytest.raises(SystemExit) as exit_:
        main(["--version"])
    assert exit_.value.code == 0
    assert capsys.readouterr().out.startswith("calib (sltwin) ")


def test_debug_shows_the_traceback_of_an_error_and_only_then(tmp_path):
    (tmp_path / "empty.xml").write_text("")
    plain = _calib("twin", "empty.xml", "-o", "t.json", cwd=tmp_path)
    assert plain.returncode == 2 and "Traceback" not in plain.stderr and "empty.xml" in plain.stderr
    for args in (("--debug", "twin", "empty.xml"), ("twin", "empty.xml", "-v")):   # before or after the command
        debug = _calib(*args, "-o", "t.json", cwd=tmp_path)
        assert debug.returncode == 2 and "Traceback" in debug.stderr and "FormatError" in debug.stderr
        assert "sltwin" in debug.stderr and "Python" in debug.stderr   # versions for the bug report


def test_a_bug_is_one_line_asking_for_debug_not_a_traceback(monkeypatch, capsys):
    from sltwin.commands import plan_fringes

    def broken(args):
        raise TypeError("unsupported operand")

    monkeypatch.setattr(plan_fringes, "run", broken)
    assert main(["plan-fringes"]) == 1
    err = capsys.readouterr().err
    assert "internal error: TypeError: unsupported operand" in err and "--debug" in err and "Traceback" not in err
    with pytest.raises(TypeError):
        main(["--debug", "plan-fringes"])


def test_running_out_of_memory_is_an_error_with_a_hint_not_a_bug(monkeypatch, capsys):
    from sltwin.commands import plan_fringes, unwrap as unwrap_command

    def exhausted(args):
        raise MemoryError()

    monkeypatch.setattr(plan_fringes, "run", exhausted)
    assert main(["plan-fringes"]) == 2
    err = capsys.readouterr().err
    assert "error: out of memory" in err and "bug" not in err and "--low-memory" not in err
    monkeypatch.setattr(unwrap_command, "run", exhausted)
    assert main(["unwrap", "somewhere", "-o", "elsewhere"]) == 2
    assert "out of memory (try --low-memory)" in capsys.readouterr().err

    def numpy_exhausted(args):      # numpy says how much it wanted: kept
        raise MemoryError("Unable to allocate 3.20 GiB for an array with shape (700, 900, 682) and data type float64")

    monkeypatch.setattr(plan_fringes, "run", numpy_exhausted)
    assert main(["plan-fringes"]) == 2
    assert "out of memory: Unable to allocate 3.20 GiB" in capsys.readouterr().err


def test_commands_that_render_nothing_do_not_import_torch(tmp_path):
    code = ("import sys; from sltwin.cli import main; "
            f"main(['twin', '-o', {str(tmp_path / 't.json')!r}]); main(['plan-fringes', '--steps', '12']); "
            f"main(['convert', {str(tmp_path / 't.json')!r}, '-o', {str(tmp_path / 'x.json')!r}]); "
            "print('torch imported:', 'torch' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         env={"PYTHONPATH": str(REPO), "PATH": "/usr/bin:/bin"})
    assert "torch imported: False" in out.stdout, out.stdout + out.stderr


@pytest.mark.parametrize("suffix", [".yml", ".xml"])
def test_a_calibration_written_as_opencv_storage_reads_back_the_same_rig(tmp_path, suffix):
    s = default_system()
    back = load_system(save_system(s, tmp_path / f"rig{suffix}")[0])
    for a, b in ((s.camera, back.camera), (s.projector, back.projector)):
        np.testing.assert_allclose(b.K, a.K, rtol=1e-14, atol=1e-12)
        np.testing.assert_allclose(b.distortion, a.distortion, rtol=1e-14, atol=1e-15)
        assert b.size == a.size
    R = lambda sys_: sys_.projector.R @ sys_.camera.R.T   # noqa: E731  the rig does not depend on the world
    np.testing.assert_allclose(R(back), R(s), atol=1e-12)
    t = lambda sys_: sys_.projector.t - R(sys_) @ sys_.camera.t   # noqa: E731
    np.testing.assert_allclose(t(back), t(s), atol=1e-9)
    np.testing.assert_allclose(back.camera.R, np.eye(3), atol=0)   # an OpenCV rig's world is its camera


def test_calib_convert_between_formats(tmp_path, capsys):
    save_system(default_system(), tmp_path / "in.json")
    assert main(["convert", str(tmp_path / "in.json"), "-o", str(tmp_path / "rig.xml")]) == 0
    assert main(["convert", str(tmp_path / "rig.xml"), "-o", str(tmp_path / "c.cameramodel"),
                 str(tmp_path / "p.cameramodel"), "--skew-tol", "1"]) == 0
    assert "wrote" in capsys.readouterr().out
    back = load_system([tmp_path / "c.cameramodel", tmp_path / "p.cameramodel"])
    assert back.projector.fy == pytest.approx(default_system().projector.fy, rel=1e-9)


def test_slstudio_layout_reads_bmp_frames(tmp_path):
    # SLStudio's own frames: 3-step 16 periods then the 1-period cue, columns then rows, BMP
    y, x = np.mgrid[0:40, 0:60].astype(np.float64)
    u, v = 20.0 + 29.0 * x + 0.5 * y, 10.0 + 27.0 * y
    frames = []
    for c, extent in ((u, 1824), (v, 1140)):
        for f in (16, 1):
            frames += [fringe_intensity(absolute_phase(c, f, extent), n, 3, 120, 90) for n in range(3)]
    for i, img in enumerate(frames):
        cv2.imwrite(str(tmp_path / f"frameSeq_{i:02d}.bmp"), np.round(img).astype(np.uint8))
    res = unwrap_capture(tmp_path)
    assert set(res) == {"v", "h"}
    assert np.abs(projector_coordinate(res["v"].result.phase, 16, 1824) - u).max() < 0.5


def test_calib_render_output_is_read_by_calib_unwrap_as_it_is(tmp_path, capsys):
    scene = """
    name = "plane"
    [[objects]]
    kind = "plane"
    [[patterns.sequence]]
    kind = "phase"
    orientation = "both"
    frequencies = [1, 8]
    steps = 4
    """
    (tmp_path / "scene.toml").write_text("\n".join(line.strip() for line in scene.splitlines()))
    assert main(["render", str(tmp_path / "scene.toml"), "-o", str(tmp_path / "out"), "-q", "--no-truth"]) == 0
    assert "[pattern]" in (tmp_path / "out" / "capture.toml").read_text()
    assert main(["unwrap", str(tmp_path / "out"), "-o", str(tmp_path / "u"), "-q", "--no-previews"]) == 0
    assert "v: method mf, frequency 8" in capsys.readouterr().out


def test_calib_render_of_a_gray_code_scene_is_read_by_calib_unwrap_as_it_is(tmp_path, capsys):
    scene = """
    name = "plane"
    [[objects]]
    kind = "plane"
    [[patterns.sequence]]
    kind = "white"
    [[patterns.sequence]]
    kind = "black"
    [[patterns.sequence]]
    kind = "gray"
    orientation = "both"
    inverse = true
    block_px = 4
    """
    (tmp_path / "scene.toml").write_text("\n".join(line.strip() for line in scene.splitlines()))
    assert main(["render", str(tmp_path / "scene.toml"), "-o", str(tmp_path / "out"), "-q", "--no-truth"]) == 0
    assert 'kind = "graycode"' in (tmp_path / "out" / "capture.toml").read_text()
    assert main(["unwrap", str(tmp_path / "out"), "-o", str(tmp_path / "u"), "-q", "--no-previews"]) == 0
    out = capsys.readouterr().out
    assert "v: method gray" in out and "quantised to 4 px" in out


def test_the_compile_message_is_only_shown_when_the_kernel_is_not_cached(design_capture, monkeypatch, caplog):
    import logging

    from unwrap import pipeline
    from unwrap.fused_mf import fast_available, mf_unwrap_stacks

    if not fast_available():
        pytest.skip("numba not installed")
    stacks = [np.full((3, 4, 4), 100, np.uint8)] * 2
    mf_unwrap_stacks(stacks, (1, 8))
    assert pipeline._kernel_cold() is False   # compiled (and cached) now
    root, _ = design_capture
    message = "first use of the fused kernel on this machine (compiled once and cached"
    for cold in (True, False):
        monkeypatch.setattr(pipeline, "_kernel_cold", lambda: cold)
        caplog.clear()
        with caplog.at_level(logging.INFO, logger="unwrap"):
            out = unwrap_capture(root, progress=True)
        shown = [r.getMessage() for r in caplog.records if message in r.getMessage()]
        assert len(shown) == (2 if cold else 0), shown           # once per orientation (v, h) when cold
        assert set(out) == {"v", "h"} and all(o.result.valid.any() for o in out.values())
    caplog.clear()
    with caplog.at_level(logging.INFO, logger="unwrap"):
        unwrap_capture(root)                                     # without progress: never
    assert not any(message in r.getMessage() for r in caplog.records)


def test_a_cameramodel_that_cannot_be_written_is_a_warning_that_says_so(tmp_path, caplog):
    import logging

    from calib.board import Board
    from calib.adjustment.problem import BAConfig, DeviceConfig
    from calib.pipeline import calibrate_observations
    from calib.simulate import simulate_observations

    obs, _ = simulate_observations(default_system(), Board("checkerboard", 5, 7, 20.0), 6, 0.05,
                                   np.random.default_rng(3))
    config = BAConfig(camera=DeviceConfig(5, True), projector=DeviceConfig(5, True), outlier_threshold=None)
    with caplog.at_level(logging.INFO, logger="calib"):
        run = calibrate_observations(obs, tmp_path / "out", config)
    assert str(run.written["projector.cameramodel"]).startswith("not written: ")
    warning = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert any(m.startswith("projector.cameramodel not written: ") for m in warning), warning
    assert not any("wrote projector.cameramodel" in r.getMessage() for r in caplog.records)
    assert math.isfinite(json.loads((tmp_path / "out" / "calibration.json").read_text())["camera"]["K"][0][0])


def test_calib_help_imports_no_heavy_package():
    code = ("import sys; from sltwin.cli import build_parser; build_parser().format_help(); "
            "print(sorted(m for m in ('torch', 'cv2', 'scipy', 'calib', 'synth', 'numba') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         env={"PYTHONPATH": str(REPO), "PATH": "/usr/bin:/bin"})
    assert out.stdout.strip() == "[]", out.stdout + out.stderr


def test_torch_out_of_memory_is_an_error_not_a_bug(monkeypatch, capsys):
    """torch's CPU allocator refuses with a RuntimeError, not a MemoryError (the learned forward, the
    peak of ``calib unwrap --model``): the same exit 2 as a MemoryError; no --low-memory hint
    where it was given; other RuntimeErrors stay bugs."""
    from sltwin.commands import unwrap as unwrap_command

    def exhausted(args):
        raise RuntimeError("[enforce fail at alloc_cpu.cpp:127] err == 0. DefaultCPUAllocator: can't allocate "
                           "memory: you tried to allocate 1125899906842624 bytes. Error code 12")

    monkeypatch.setattr(unwrap_command, "run", exhausted)
    assert main(["unwrap", "somewhere", "-o", "elsewhere"]) == 2
    err = capsys.readouterr().err
    assert "out of memory (try --low-memory)" in err and "bug" not in err
    assert main(["unwrap", "somewhere", "-o", "elsewhere", "--low-memory"]) == 2
    err = capsys.readouterr().err
    assert "error: out of memory" in err and "--low-memory" not in err

    def broken(args):
        raise RuntimeError("a shape mismatch")

    monkeypatch.setattr(unwrap_command, "run", broken)
    assert main(["unwrap", "somewhere", "-o", "elsewhere"]) == 1
