"""`make demo`'s job: twin -> calibration session rendered in the twin -> calib run on the images -> report."""
import json

from sltwin.cli import main


def test_demo_recovers_the_twins_true_intrinsics_within_predicted_3_sigma(tmp_path, capsys):
    assert main(["demo", "-o", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "8 of 8 intrinsics within the predicted 3 sigma" in out
    for name in ("twin.json", "twin_scene.py", "twin_calibration/calibration.json",
                 "twin_calibration/camera.cameramodel", "twin_calibration/projector.cameramodel",
                 "twin_calibration/observations.json", "twin_calibration/detections.png",
                 "captures/capture.toml", "captures/pose_08/white.png", "report/report.html", "report/report.md"):
        assert (tmp_path / name).exists(), name
    cal = json.loads((tmp_path / "twin_calibration" / "calibration.json").read_text())
    assert cal["units"] == "mm" and "uncertainties_1sigma" in cal
