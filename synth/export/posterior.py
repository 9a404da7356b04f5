"""Systems drawn from a calibration's posterior: the twin sees the uncertainty of the real system
instead of one point estimate.

``calib run`` writes ``covariance`` into calibration.json: the joint covariance of the device
intrinsics (``camera.fx``, ``projector.k1``, ...) and the rig transform ``prj_cam`` (rotation
increment ``w`` in rad with ``R_prj_cam = R0 Exp(w)``, translation ``t`` in mm), as estimated by the
bundle adjustment. A draw adds ``delta ~ N(0, cov)`` to those parameters; the camera keeps its
world pose and the projector's follows from the perturbed rig.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from calib.system import SystemModel

from ..errors import SynthError

_DIST = ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6", "s1", "s2", "s3", "s4")


def _exp_so3(w) -> np.ndarray:
    th = float(np.linalg.norm(w))
    Kx = np.array([[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]])
    if th < 1e-12:
        return np.eye(3) + Kx
    return np.eye(3) + np.sin(th) / th * Kx + (1 - np.cos(th)) / th ** 2 * Kx @ Kx


class PosteriorSampler:
    """``PosteriorSampler(system, calibration_json_path)(rng)`` -> a perturbed SystemModel."""

    def __init__(self, system: SystemModel, path):
        path = Path(path)
        try:
            d = json.loads(path.read_text())
        except (OSError, ValueError) as exc:
            raise SynthError(f"system.perturb: cannot read {path} ({exc})") from None
        cov = d.get("covariance")
        if not cov or "names" not in cov or "matrix" not in cov:
            raise SynthError(f"system.perturb = 'posterior': {path} has no 'covariance' (write it with "
                             "`calib run` of this version)")
        self.names = list(cov["names"])
        C = np.asarray(cov["matrix"], dtype=np.float64)
        if C.shape != (len(self.names),) * 2 or not np.all(np.isfinite(C)):
            raise SynthError(f"system.perturb: {path}: covariance matrix is not a finite "
                             f"{len(self.names)}x{len(self.names)} matrix")
        vals, vecs = np.linalg.eigh((C + C.T) / 2)
        if vals.min() < -1e-9 * max(vals.max(), 1e-300):
            raise SynthError(f"system.perturb: {path}: covariance is not positive semi-definite "
                             f"(eigenvalue {vals.min():.3g})")
        self.L = vecs * np.sqrt(np.clip(vals, 0, None))
        self.system = system

    def __call__(self, rng) -> SystemModel:
        delta = dict(zip(self.names, self.L @ rng.normal(size=len(self.names))))
        devs = {}
        for kind, dev in (("camera", self.system.camera), ("projector", self.system.projector)):
            K = np.array(dev.K, dtype=np.float64)
            for n, (r, c) in {"fx": (0, 0), "fy": (1, 1), "cx": (0, 2), "cy": (1, 2), "skew": (0, 1)}.items():
                K[r, c] += delta.get(f"{kind}.{n}", 0.0)
            dist = np.array(dev.distortion, dtype=np.float64)
            for j, n in enumerate(_DIST[:dist.size]):
                dist[j] += delta.get(f"{kind}.{n}", 0.0)
            devs[kind] = dev.with_(K=K, distortion=dist)
        cam, prj = devs["camera"], devs["projector"]
        R_pc = prj.R @ cam.R.T
        t_pc = prj.t - R_pc @ cam.t
        w = np.array([delta.get(f"prj_cam.w{j}", 0.0) for j in range(3)])
        t = np.array([delta.get(f"prj_cam.t{j}", 0.0) for j in range(3)])
        R_pc = R_pc @ _exp_so3(w)
        t_pc = t_pc + t
        prj = prj.with_(R=R_pc @ cam.R, t=R_pc @ cam.t + t_pc)
        return SystemModel(cam, prj, dict(self.system.meta))
