"""What a board detection returns, its error type, and the input checks every detector shares.

Pixel coordinates follow DESIGN.md (OpenCV): x right, y down, pixel centres at integers.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..errors import DetectionError  # noqa: F401  (defined in calib.errors, re-exported)


@dataclass
class BoardDetection:
    """The features of one board found in one image.

    - ids: (N,) int64 feature ids ``row * cols + col`` (calib.board.Board), sorted ascending.
    - q: (N, 2) float64 pixel positions (x right, y down) of the features; for circles the image
      of the circle CENTRE (ellipse centre corrected for the perspective bias).
    - points_board: (N, 3) float64 board-frame positions in mm (``board.points_board(ids)``).
    - feature_px: (N,) float64 local feature size in pixels: mean semi-axis of a circle's fitted
      ellipse, or half the local corner spacing of a checkerboard / ChArUco corner.
    - homography: (3, 3) board (x, y) mm -> pixels, fitted to all found features, H[2,2] = 1.
    - method: how the features were found; notes: what was corrected or dropped, and why.
    - image_size: (W, H) of the image.
    """

    ids: np.ndarray
    q: np.ndarray
    points_board: np.ndarray
    feature_px: np.ndarray
    homography: np.ndarray
    method: str
    notes: list = field(default_factory=list)
    image_size: tuple = (0, 0)

    def __len__(self) -> int:
        return int(self.ids.shape[0])

    def reprojection_rms_px(self) -> float:
        """RMS distance (px) between ``q`` and the homography's image of ``points_board``."""
        return float(np.sqrt(np.mean(np.sum((apply_homography(self.homography, self.points_board[:, :2])
                                             - self.q) ** 2, axis=1))))


def apply_homography(H, xy) -> np.ndarray:
    """Map (N, 2) points through the (3, 3) homography H; returns (N, 2) float64."""
    xy = np.asarray(xy, dtype=np.float64)
    p = np.c_[xy, np.ones(len(xy))] @ np.asarray(H, dtype=np.float64).T
    return p[:, :2] / p[:, 2:3]


def image_as_float(image, what: str = "image") -> np.ndarray:
    """Validate a grey image and return it as a (H, W) float64 array (original scale).

    Accepts (H, W) uint8 / uint16 / float arrays, or (H, W, 1). Colour, empty, tiny, non-finite or
    constant images raise DetectionError naming the problem.
    """
    a = np.asarray(image)
    if a.ndim == 3 and a.shape[2] == 1:
        a = a[:, :, 0]
    if a.ndim != 2:
        raise DetectionError(f"{what}: expected a (H, W) grey image, got shape {a.shape}")
    h, w = a.shape
    if h < 16 or w < 16:
        raise DetectionError(f"{what}: image of {w}x{h} px is too small (at least 16x16)")
    if a.dtype == bool or not (np.issubdtype(a.dtype, np.integer) or np.issubdtype(a.dtype, np.floating)):
        raise DetectionError(f"{what}: expected uint8, uint16 or float pixels, got dtype {a.dtype}")
    f = a.astype(np.float64)
    if not np.all(np.isfinite(f)):
        raise DetectionError(f"{what} ({w}x{h} px): {int(np.sum(~np.isfinite(f)))} non-finite pixels")
    if float(f.max() - f.min()) <= 0:
        raise DetectionError(f"{what} ({w}x{h} px): the image is constant ({f.flat[0]:g}); no board in it")
    return f


def to_uint8(f: np.ndarray, lo_pct: float = 0.5, hi_pct: float = 99.5) -> np.ndarray:
    """Stretch a float image to uint8 between two percentiles (OpenCV's detectors want 8 bits)."""
    lo, hi = np.percentile(f, [lo_pct, hi_pct])
    if hi <= lo:
        lo, hi = float(f.min()), float(f.max())
    return np.clip(np.round((f - lo) * (255.0 / (hi - lo))), 0, 255).astype(np.uint8)


def size_text(f: np.ndarray) -> str:
    return f"{f.shape[1]}x{f.shape[0]} px"
