"""Printed calibration boards as anti-aliased albedo textures (board frame of DESIGN.md).

Board frame: origin at the board centre, board plane z = 0, z out of the printed face, x right and
y up seen from the front. A circle or corner (row, col) sits at
``x = (col - (cols-1)/2) * spacing``, ``y = (row - (rows-1)/2) * spacing`` (mm).

Anti-aliasing is analytic: each camera pixel's footprint on the board (width ``w`` mm) box-filters
the print. Circles use the signed distance to the rim (coverage ``clamp(0.5 - d / w)``);
checkerboards use the exact box-filtered square wave along x and y (product of the two).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import torch

from .errors import SynthError

#: The paper's board (supplementary section 2) with DESIGN.md's marker layout.
PAPER_LARGE_MARKERS = ((4, 5), (4, 6), (4, 7), (3, 5), (2, 5))


@dataclass(frozen=True)
class BoardSpec:
    """A printed board. ``rows``/``cols`` count circles, or inner corners of a checkerboard."""

    kind: str = "circles"
    rows: int = 9
    cols: int = 11
    spacing_mm: float = 20.0
    large_diameter_mm: float = 5.0
    small_diameter_mm: float = 2.0
    large_markers: tuple = PAPER_LARGE_MARKERS
    polarity: str = "dark-on-light"
    margin_mm: float = 20.0
    albedo_light: float = 0.9
    albedo_dark: float = 0.05

    def __post_init__(self):
        if self.kind not in ("circles", "checkerboard"):
            raise SynthError(f"board.kind: expected 'circles' or 'checkerboard', got {self.kind!r}")
        if int(self.rows) < 2 or int(self.cols) < 2:
            raise SynthError(f"board rows/cols: expected >= 2, got {self.rows} x {self.cols}")
        if not self.spacing_mm > 0:
            raise SynthError(f"board.spacing_mm: expected > 0, got {self.spacing_mm!r}")
        if self.polarity not in ("dark-on-light", "light-on-dark"):
            raise SynthError(f"board.polarity: expected 'dark-on-light' or 'light-on-dark', got {self.polarity!r}")
        if self.kind == "circles":
            if not 0 < self.small_diameter_mm < self.spacing_mm or not 0 < self.large_diameter_mm < self.spacing_mm:
                raise SynthError(f"board circle diameters must lie in (0, spacing_mm): "
                                 f"{self.small_diameter_mm}, {self.large_diameter_mm}")
            for rc in self.large_markers:
                if not (0 <= rc[0] < self.rows and 0 <= rc[1] < self.cols):
                    raise SynthError(f"board.large_markers: {list(rc)} outside the {self.rows}x{self.cols} grid")
        for key in ("albedo_light", "albedo_dark"):
            if not 0 <= getattr(self, key) <= 1:
                raise SynthError(f"board.{key}: expected within [0, 1], got {getattr(self, key)!r}")

    @property
    def size_mm(self) -> tuple[float, float]:
        """(width, height) of the printed sheet (mm), margin included."""
        extra = 1 if self.kind == "checkerboard" else 0  # outer squares extend one pitch
        return ((self.cols - 1 + extra) * self.spacing_mm + 2 * self.margin_mm,
                (self.rows - 1 + extra) * self.spacing_mm + 2 * self.margin_mm)

    def points_board(self) -> np.ndarray:
        """(rows*cols, 3) circle centres / inner corners in the board frame (mm), row-major."""
        r, c = np.meshgrid(np.arange(self.rows), np.arange(self.cols), indexing="ij")
        x = (c - (self.cols - 1) / 2) * self.spacing_mm
        y = (r - (self.rows - 1) / 2) * self.spacing_mm
        return np.stack([x.ravel(), y.ravel(), np.zeros(x.size)], axis=1)

    def capture_toml_table(self) -> dict:
        """The ``[board]`` table of capture.toml (DESIGN.md keys)."""
        d = {"kind": self.kind, "rows": int(self.rows), "cols": int(self.cols), "spacing_mm": float(self.spacing_mm)}
        if self.kind == "circles":
            d.update(large_diameter_mm=float(self.large_diameter_mm), small_diameter_mm=float(self.small_diameter_mm),
                     large_markers=[list(map(int, rc)) for rc in self.large_markers], polarity=self.polarity)
        return d

    def albedo(self, xy: torch.Tensor, footprint_mm: torch.Tensor) -> torch.Tensor:
        """Albedo (N,) at board points ``xy`` (N,2) mm, box-filtered over ``footprint_mm`` (N,)."""
        w = footprint_mm.clamp(min=1e-6)
        if self.kind == "circles":
            ink = self._circle_coverage(xy, w)
            if self.polarity == "light-on-dark":
                ink = 1.0 - ink
        else:
            ink = self._checker_coverage(xy, w)
        return self.albedo_light + (self.albedo_dark - self.albedo_light) * ink

    def _circle_coverage(self, xy, w):
        sp = self.spacing_mm
        col = torch.round(xy[:, 0] / sp + (self.cols - 1) / 2).clamp(0, self.cols - 1)
        row = torch.round(xy[:, 1] / sp + (self.rows - 1) / 2).clamp(0, self.rows - 1)
        cx = (col - (self.cols - 1) / 2) * sp
        cy = (row - (self.rows - 1) / 2) * sp
        radius = torch.full_like(cx, self.small_diameter_mm / 2)
        large = torch.zeros(self.rows, self.cols, dtype=torch.bool, device=xy.device)
        for r, c in self.large_markers:
            large[int(r), int(c)] = True
        radius = torch.where(large[row.long(), col.long()], torch.full_like(radius, self.large_diameter_mm / 2), radius)
        dist = torch.hypot(xy[:, 0] - cx, xy[:, 1] - cy) - radius
        return (0.5 - dist / w).clamp(0.0, 1.0)

    def _checker_coverage(self, xy, w):
        sp = self.spacing_mm
        u = xy[:, 0] / sp + (self.cols - 1) / 2  # inner corners at integer u, squares u in [-1, cols]
        v = xy[:, 1] / sp + (self.rows - 1) / 2
        wu = w / sp

        def tri(t):  # antiderivative of the square wave (-1)^floor(t)
            m = torch.remainder(t, 2.0)
            return 1.0 - (m - 1.0).abs()

        def box_square(t):
            return (tri(t + wu / 2) - tri(t - wu / 2)) / wu

        def inside(t, n):  # box-filtered indicator of t in [-1, n]
            return ((torch.minimum(t + 1.0, n - t)) / wu + 0.5).clamp(0.0, 1.0)

        q = box_square(u) * box_square(v)  # +1: corner-type (black) squares
        return inside(u, self.cols) * inside(v, self.rows) * (1.0 + q) / 2.0


def board_from_table(d: dict, key: str = "board") -> BoardSpec:
    """A ``[board]`` TOML table (capture.toml keys plus margin_mm, albedo_light, albedo_dark)."""
    allowed = set(BoardSpec.__dataclass_fields__)
    unknown = set(d) - allowed
    if unknown:
        raise SynthError(f"{key}: unknown key(s) {sorted(unknown)}; allowed {sorted(allowed)}")
    kw = dict(d)
    if "large_markers" in kw:
        try:
            kw["large_markers"] = tuple(tuple(int(v) for v in rc) for rc in kw["large_markers"])
            assert all(len(rc) == 2 for rc in kw["large_markers"])
        except (TypeError, ValueError, AssertionError):
            raise SynthError(f"{key}.large_markers: expected a list of [row, col], got {d['large_markers']!r}") from None
    for k in ("spacing_mm", "large_diameter_mm", "small_diameter_mm", "margin_mm", "albedo_light", "albedo_dark"):
        if k in kw and not isinstance(kw[k], (int, float)):
            raise SynthError(f"{key}.{k}: expected a number, got {kw[k]!r}")
    for k in ("rows", "cols"):
        if k in kw and not isinstance(kw[k], int):
            raise SynthError(f"{key}.{k}: expected an integer, got {kw[k]!r}")
    return BoardSpec(**kw)
