"""Bouguet "Camera Calibration Toolbox for MATLAB" results (``.mat``, read with scipy).

Toolbox convention: ``x = KK * distort(Rc_i X + Tc_i)`` with ``KK = [[fc1, alpha_c*fc1, cc1],
[0, fc2, cc2], [0, 0, 1]]``, pixel coordinates 0-based (as ours), ``kc = (k1, k2, p1, p2, k3)``
(OpenCV order). A projector calibrated as an inverse camera uses the same file layout.

The world frame of a system read from a camera + projector pair is the board at pose 1
(``Rc_1``, ``Tc_1`` of each file), as the paper's tables S2 and S4 do.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..device import DeviceModel
from ..errors import FormatError
from ..system import SystemModel


@dataclass(frozen=True)
class BouguetResult:
    """Everything we use from one toolbox result file.

    - size: (nx, ny) pixels; KK (3,3); kc (5,); fc, cc (2,), alpha_c (scalar skew / fc1);
    - fc_error, cc_error (2,), kc_error (5,), alpha_c_error: the toolbox's 3-sigma errors;
    - err_std (2,): reprojection error standard deviation, px;
    - R_dev_board, t_dev_board: per-view board -> device poses, (n, 3, 3) and (n, 3) mm;
    - points_board: per-view board points (list of (N_i, 3) mm, z = 0);
    - points_px: per-view observed pixels (list of (N_i, 2)), 0-based;
    - active: (n,) bool, views the toolbox used.
    """

    path: str
    size: tuple
    KK: np.ndarray
    kc: np.ndarray
    fc: np.ndarray
    cc: np.ndarray
    alpha_c: float
    fc_error: np.ndarray
    cc_error: np.ndarray
    kc_error: np.ndarray
    alpha_c_error: float
    err_std: np.ndarray
    R_dev_board: np.ndarray
    t_dev_board: np.ndarray
    points_board: list
    points_px: list
    active: np.ndarray

    def device(self, kind: str, view: int = 0, *, repair_rotation: bool = False) -> DeviceModel:
        """The device with board view ``view`` (0-based) as world."""
        return DeviceModel(size=self.size, K=self.KK, distortion=self.kc, R=self.R_dev_board[view],
                           t=self.t_dev_board[view], kind=kind, name=kind, repair_rotation=repair_rotation)


def read_bouguet(path) -> BouguetResult:
    """Read one toolbox result file (``Calib_Results.mat`` layout)."""
    import scipy.io

    path = Path(path)
    try:
        m = scipy.io.loadmat(str(path))
    except FileNotFoundError:
        raise FormatError(f"{path}: no such file") from None
    except Exception as exc:  # scipy raises several types for a broken file
        raise FormatError(f"{path}: not a readable MATLAB .mat file ({exc})") from None
    need = ["KK", "kc", "fc", "cc", "alpha_c", "nx", "ny", "n_ima"]
    missing = [k for k in need if k not in m]
    if missing:
        raise FormatError(f"{path}: not a Bouguet toolbox result: missing {missing}")

    def vec(key, n=None, default=np.nan):
        if key not in m:
            return np.full(n or 1, default)
        return np.asarray(m[key], dtype=np.float64).reshape(-1)

    n_ima = int(vec("n_ima")[0])
    active = vec("active_images", n_ima, 1).astype(bool) if "active_images" in m else np.ones(n_ima, bool)
    Rs, ts, Xs, xs = [], [], [], []
    for i in range(1, n_ima + 1):
        for key in (f"Rc_{i}", f"Tc_{i}", f"X_{i}", f"x_{i}"):
            if key not in m:
                raise FormatError(f"{path}: view {i} lacks {key}")
        Rs.append(np.asarray(m[f"Rc_{i}"], dtype=np.float64))
        ts.append(vec(f"Tc_{i}"))
        Xs.append(np.asarray(m[f"X_{i}"], dtype=np.float64).T.copy())
        xs.append(np.asarray(m[f"x_{i}"], dtype=np.float64).T.copy())
    kc = vec("kc")
    return BouguetResult(
        path=str(path), size=(int(vec("nx")[0]), int(vec("ny")[0])),
        KK=np.asarray(m["KK"], dtype=np.float64), kc=kc, fc=vec("fc"), cc=vec("cc"),
        alpha_c=float(vec("alpha_c")[0]), fc_error=vec("fc_error", 2), cc_error=vec("cc_error", 2),
        kc_error=vec("kc_error", kc.size), alpha_c_error=float(vec("alpha_c_error")[0]),
        err_std=vec("err_std", 2), R_dev_board=np.stack(Rs), t_dev_board=np.stack(ts),
        points_board=Xs, points_px=xs, active=active)


def read_bouguet_pair(camera_path, projector_path, *, view: int = 0,
                      repair_rotation: bool = False) -> SystemModel:
    """Camera + projector toolbox results -> SystemModel, board view ``view`` (0-based) as world."""
    cam = read_bouguet(camera_path)
    prj = read_bouguet(projector_path)
    if len(cam.R_dev_board) != len(prj.R_dev_board):
        raise FormatError(f"{camera_path} has {len(cam.R_dev_board)} views, {projector_path} has "
                          f"{len(prj.R_dev_board)}: not the same calibration session")
    meta = {"source": {"format": "bouguet-mat", "camera": str(camera_path), "projector": str(projector_path),
                       "world": f"board pose {view + 1}"}}
    return SystemModel(cam.device("camera", view, repair_rotation=repair_rotation),
                       prj.device("projector", view, repair_rotation=repair_rotation), meta)
