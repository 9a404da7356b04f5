"""Regenerate calib/data/default_system.json from the paper's real Bouguet results.

Source: github.com/nomineee/DP-TPU (MIT), data/calib/{Cam,Prj}CalibResult_real.mat, read in place
from ../shared/data/dp-tpu. Board pose 1 is the world frame (as tables S2/S4 of the paper).
Usage: .venv/bin/python scripts/make_default_system.py [DP_TPU_DIR]
"""
import json
import sys
from pathlib import Path

import numpy as np

from calib.io.bouguet import read_bouguet

root = Path(__file__).resolve().parents[1]
src = Path(sys.argv[1]) if len(sys.argv) > 1 else root.parent / "shared" / "data" / "dp-tpu"
cam = read_bouguet(src / "CamCalibResult_real.mat")
prj = read_bouguet(src / "PrjCalibResult_real.mat")


def device(r):
    return {"size": list(r.size), "K": r.KK.tolist(), "distortion": r.kc.tolist(),
            "R": r.R_dev_board[0].tolist(), "t": r.t_dev_board[0].tolist(),
            "uncertainty_3sigma": {"fc": r.fc_error.tolist(), "cc": r.cc_error.tolist(),
                                   "kc": r.kc_error.tolist(), "alpha_c": r.alpha_c_error},
            "reprojection_err_std_px": r.err_std.tolist()}


out = {
    "units": "mm",
    "camera": device(cam),
    "projector": device(prj),
    "name": "DP-TPU real system (paper's table S2, full precision)",
    "source": {"format": "bouguet-mat", "origin": "github.com/nomineee/DP-TPU @ d4a902cb, data/calib/"
               "CamCalibResult_real.mat + PrjCalibResult_real.mat (MIT licence)",
               "world": "board pose 1"},
    "datasheets": {
        "camera": {"model": "Basler acA640-750um", "resolution_px": [640, 480], "pixel_pitch_um": [4.8, 4.8]},
        "projector": {"model": "TI DLP4500", "resolution_px": [912, 1140], "dmd_size_mm": [10.8, 6.8]},
    },
}
dst = root / "calib" / "data" / "default_system.json"
dst.write_text(json.dumps(out, indent=2) + "\n")
print(f"wrote {dst}")
