"""Printed calibration boards as anti-aliased albedo textures (board frame of DESIGN.md).

The board itself (kind, grid, pitch, circle sizes, markers, polarity) is ``calib.board.Board``,
the one board type of the toolkit; this module only prints it: :class:`BoardTexture` adds the
sheet's margin and the albedo of paper and ink, and renders the albedo at board points.

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

from calib.board import PAPER_LARGE_MARKERS, Board, paper_board
from unwrap.strict import check_keys
from calib.errors import BoardError

from ..errors import SynthError

TEXTURE_KINDS = ("circles", "checkerboard")
"""Board kinds the renderer can print (a ChArUco board's markers are not rendered)."""


@dataclass(frozen=True)
class BoardTexture:
    """How a board is printed: ``board`` (``calib.board.Board``, default the paper's), a white
    ``margin_mm`` around the feature grid, and the albedo of paper (``albedo_light``) and ink
    (``albedo_dark``) in [0, 1]."""

    board: Board = field(default_factory=paper_board)
    margin_mm: float = 20.0
    albedo_light: float = 0.9
    albedo_dark: float = 0.05

    def __post_init__(self):
        if not isinstance(self.board, Board):
            raise SynthError(f"board: expected a calib.board.Board, got {type(self.board).__name__}")
        if self.board.kind not in TEXTURE_KINDS:
            raise SynthError(f"board.kind: expected one of {TEXTURE_KINDS} to render, got {self.board.kind!r}")
        if not (np.isfinite(self.margin_mm) and self.margin_mm >= 0):
            raise SynthError(f"board.margin_mm: expected a finite number >= 0, got {self.margin_mm!r}")
        for key in ("albedo_light", "albedo_dark"):
            if not 0 <= getattr(self, key) <= 1:
                raise SynthError(f"board.{key}: expected within [0, 1], got {getattr(self, key)!r}")

    @property
    def size_mm(self) -> tuple[float, float]:
        """(width, height) of the printed sheet (mm), margin included."""
        b = self.board
        extra = 1 if b.kind == "checkerboard" else 0  # outer squares extend one pitch
        return ((b.cols - 1 + extra) * b.spacing_mm + 2 * self.margin_mm,
                (b.rows - 1 + extra) * b.spacing_mm + 2 * self.margin_mm)

    def albedo(self, xy: torch.Tensor, footprint_mm: torch.Tensor) -> torch.Tensor:
        """Albedo (N,) at board points ``xy`` (N,2) mm, box-filtered over ``footprint_mm`` (N,)."""
        w = footprint_mm.clamp(min=1e-6)
        if self.board.kind == "circles":
            ink = self._circle_coverage(xy, w)
            if self.board.polarity == "light-on-dark":
                ink = 1.0 - ink
        else:
            ink = self._checker_coverage(xy, w)
        return self.albedo_light + (self.albedo_dark - self.albedo_light) * ink

    def _circle_coverage(self, xy, w):
        b = self.board
        sp = b.spacing_mm
        col = torch.round(xy[:, 0] / sp + (b.cols - 1) / 2).clamp(0, b.cols - 1)
        row = torch.round(xy[:, 1] / sp + (b.rows - 1) / 2).clamp(0, b.rows - 1)
        cx = (col - (b.cols - 1) / 2) * sp
        cy = (row - (b.rows - 1) / 2) * sp
        radius = torch.full_like(cx, b.small_diameter_mm / 2)
        large = torch.zeros(b.rows, b.cols, dtype=torch.bool, device=xy.device)
        for r, c in b.large_markers:
            large[int(r), int(c)] = True
        if b.large_markers:
            radius = torch.where(large[row.long(), col.long()], torch.full_like(radius, b.large_diameter_mm / 2),
                                 radius)
        dist = torch.hypot(xy[:, 0] - cx, xy[:, 1] - cy) - radius
        return (0.5 - dist / w).clamp(0.0, 1.0)

    def _checker_coverage(self, xy, w):
        b = self.board
        sp = b.spacing_mm
        u = xy[:, 0] / sp + (b.cols - 1) / 2  # inner corners at integer u, squares u in [-1, cols]
        v = xy[:, 1] / sp + (b.rows - 1) / 2
        wu = w / sp

        def tri(t):  # antiderivative of the square wave (-1)^floor(t)
            m = torch.remainder(t, 2.0)
            return 1.0 - (m - 1.0).abs()

        def box_square(t):
            return (tri(t + wu / 2) - tri(t - wu / 2)) / wu

        def inside(t, n):  # box-filtered indicator of t in [-1, n]
            return ((torch.minimum(t + 1.0, n - t)) / wu + 0.5).clamp(0.0, 1.0)

        q = box_square(u) * box_square(v)  # +1: corner-type (black) squares
        return inside(u, b.cols) * inside(v, b.rows) * (1.0 + q) / 2.0


def BoardSpec(kind: str = "circles", rows: int = 9, cols: int = 11, spacing_mm: float = 20.0,
              large_diameter_mm: float = 5.0, small_diameter_mm: float = 2.0, large_markers=PAPER_LARGE_MARKERS,
              polarity: str = "dark-on-light", margin_mm: float = 20.0, albedo_light: float = 0.9,
              albedo_dark: float = 0.05) -> BoardTexture:
    """A printed board from flat keys (capture.toml's ``[board]`` keys plus the print keys), the
    paper's board by default: ``BoardTexture(Board(...), margin_mm, albedo_light, albedo_dark)``.
    Raises SynthError naming the key. Circle sizes and markers apply to circle boards only."""
    if kind != "circles":
        large_markers, large_diameter_mm, small_diameter_mm = (), None, None
    try:
        board = Board(kind=kind, rows=rows, cols=cols, spacing_mm=spacing_mm, large_diameter_mm=large_diameter_mm,
                      small_diameter_mm=small_diameter_mm, large_markers=large_markers, polarity=polarity)
    except BoardError as exc:
        raise SynthError(str(exc)) from None
    return BoardTexture(board, margin_mm, albedo_light, albedo_dark)


BOARD_TABLE_KEYS = ("kind", "rows", "cols", "spacing_mm", "large_diameter_mm", "small_diameter_mm",
                    "large_markers", "polarity", "margin_mm", "albedo_light", "albedo_dark")


def board_from_table(d: dict, key: str = "board") -> BoardTexture:
    """A ``[board]`` TOML table (capture.toml keys plus margin_mm, albedo_light, albedo_dark)."""
    check_keys(d, BOARD_TABLE_KEYS, "description", SynthError, prefix=f"{key}.")
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
    if isinstance(kw.get("spacing_mm"), int):
        kw["spacing_mm"] = float(kw["spacing_mm"])
    return BoardSpec(**kw)
