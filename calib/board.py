"""Calibration boards: circle grids with large orientation markers, and checkerboards.

Board frame (DESIGN.md): origin at the board centre, board plane z = 0, z out of the printed
face; seen from the front x runs right and y runs up. Feature (row, col) sits at

    x = (col - (cols - 1) / 2) * spacing_mm,   y = (row - (rows - 1) / 2) * spacing_mm,   z = 0

so row 0 is the bottom row seen from the front. For a checkerboard ``rows`` x ``cols`` count
inner corners. Feature ids are ``row * cols + col``.

SYNOPSIS

    >>> from calib.board import Board
    >>> b = Board(kind="checkerboard", rows=3, cols=4, spacing_mm=10.0)
    >>> b.points_board().shape
    (12, 3)
    >>> b.points_board()[0].tolist()
    [-15.0, -10.0, 0.0]
    >>> paper_board().to_dict()["large_markers"][0]
    [4, 5]
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .errors import BoardError

KINDS = ("circles", "checkerboard", "charuco")
POLARITIES = ("dark-on-light", "light-on-dark")

#: The large orientation circles of the paper's board, in DESIGN.md's marker layout (row, col).
PAPER_LARGE_MARKERS = ((4, 5), (4, 6), (4, 7), (3, 5), (2, 5))


def _rot90_cells(cells: set, rows: int, cols: int, k: int) -> set:
    """Cells (row, col) of a grid after ``k`` quarter turns about the centre (square grids only)."""
    out = set(cells)
    for _ in range(k % 4):
        out = {(c, rows - 1 - r) for r, c in out}
    return out


@dataclass(frozen=True)
class Board:
    """A planar calibration target.

    ARGUMENTS
    - kind: "circles" (grid with large orientation markers), "checkerboard" (inner corners) or
      "charuco" (inner chessboard corners of an ArUco-marked board; ``aruco_dictionary`` names
      the OpenCV dictionary).
    - rows, cols: grid size (features, i.e. inner corners for a checkerboard), each >= 2.
    - spacing_mm: centre-to-centre (corner-to-corner) distance, mm, > 0.
    - large_diameter_mm, small_diameter_mm: circle diameters (circles only).
    - large_markers: (row, col) of the large circles; their pattern must not map onto itself
      under a 180-degree turn (or 90-degree turns on a square grid), so the board's orientation
      is unambiguous.
    - polarity: "dark-on-light" or "light-on-dark".
    """

    kind: str
    rows: int
    cols: int
    spacing_mm: float
    large_diameter_mm: float | None = None
    small_diameter_mm: float | None = None
    large_markers: tuple = ()
    polarity: str = "dark-on-light"
    aruco_dictionary: str = "DICT_5X5_1000"
    extra: dict = field(default_factory=dict, compare=False)

    def __post_init__(self):
        if self.kind not in KINDS:
            raise BoardError(f"board.kind: expected one of {KINDS}, got {self.kind!r}")
        for key in ("rows", "cols"):
            v = getattr(self, key)
            if not isinstance(v, (int, np.integer)) or isinstance(v, bool) or v < 2:
                raise BoardError(f"board.{key}: expected an integer >= 2, got {v!r}")
        s = self.spacing_mm
        if not isinstance(s, (int, float)) or not np.isfinite(s) or s <= 0:
            raise BoardError(f"board.spacing_mm: expected a positive number (mm), got {s!r}")
        if self.polarity not in POLARITIES:
            raise BoardError(f"board.polarity: expected one of {POLARITIES}, got {self.polarity!r}")
        markers = tuple(tuple(int(v) for v in m) for m in self.large_markers)
        for r, c in markers:
            if not (0 <= r < self.rows and 0 <= c < self.cols):
                raise BoardError(f"board.large_markers: ({r}, {c}) lies outside the {self.rows} x "
                                 f"{self.cols} grid")
        object.__setattr__(self, "large_markers", markers)
        if self.kind == "circles":
            for key in ("small_diameter_mm",):
                v = getattr(self, key)
                if v is None or not v > 0 or v >= self.spacing_mm:
                    raise BoardError(f"board.{key}: expected 0 < diameter < spacing "
                                     f"({self.spacing_mm} mm), got {v!r}")
            if markers:
                big = self.large_diameter_mm
                if big is None or not self.small_diameter_mm < big < self.spacing_mm:
                    raise BoardError(f"board.large_diameter_mm: expected small diameter "
                                     f"({self.small_diameter_mm}) < large < spacing ({self.spacing_mm}), "
                                     f"got {big!r}")
                self._check_marker_asymmetry(markers)

    def _check_marker_asymmetry(self, markers) -> None:
        cells = set(markers)
        turns = (1, 2, 3) if self.rows == self.cols else (2,)
        for k in turns:
            if _rot90_cells(cells, self.rows, self.cols, k) == cells:
                raise BoardError(f"board.large_markers {sorted(cells)} map onto themselves under a "
                                 f"{90 * k}-degree turn: the board orientation would be ambiguous")

    # -- geometry ---------------------------------------------------------------------------
    @property
    def n_points(self) -> int:
        return self.rows * self.cols

    def grid_indices(self) -> np.ndarray:
        """(N, 2) int (row, col) of every feature, in id order (id = row * cols + col)."""
        r, c = np.meshgrid(np.arange(self.rows), np.arange(self.cols), indexing="ij")
        return np.stack([r.ravel(), c.ravel()], axis=-1)

    def points_board(self, ids=None) -> np.ndarray:
        """Feature positions in the board frame, (N, 3) mm, z = 0; ``ids`` selects a subset."""
        rc = self.grid_indices()
        if ids is not None:
            ids = np.asarray(ids, dtype=int)
            if ids.size and (ids.min() < 0 or ids.max() >= self.n_points):
                raise BoardError(f"feature ids must lie in [0, {self.n_points}), got {ids.min()}..{ids.max()}")
            rc = rc[ids]
        x = (rc[:, 1] - (self.cols - 1) / 2.0) * self.spacing_mm
        y = (rc[:, 0] - (self.rows - 1) / 2.0) * self.spacing_mm
        return np.stack([x, y, np.zeros_like(x)], axis=-1).astype(np.float64)

    def is_large(self) -> np.ndarray:
        """(N,) bool: which features are large orientation circles."""
        flags = np.zeros(self.n_points, bool)
        for r, c in self.large_markers:
            flags[r * self.cols + c] = True
        return flags

    def extent_mm(self) -> tuple[float, float]:
        """(width, height) of the feature grid, mm."""
        return ((self.cols - 1) * self.spacing_mm, (self.rows - 1) * self.spacing_mm)

    # -- construction -----------------------------------------------------------------------
    @classmethod
    def from_dict(cls, d: dict, source: str = "capture.toml [board]") -> "Board":
        """Build from the ``[board]`` table of capture.toml (DESIGN.md keys)."""
        if not isinstance(d, dict):
            raise BoardError(f"{source}: expected a table, got {type(d).__name__}")
        missing = [k for k in ("kind", "rows", "cols", "spacing_mm") if k not in d]
        if missing:
            raise BoardError(f"{source}: missing key(s) {missing}; found {sorted(d)}")
        known = {"kind", "rows", "cols", "spacing_mm", "large_diameter_mm", "small_diameter_mm",
                 "large_markers", "polarity", "aruco_dictionary"}
        kw = {k: v for k, v in d.items() if k in known}
        if "spacing_mm" in kw and isinstance(kw["spacing_mm"], int):
            kw["spacing_mm"] = float(kw["spacing_mm"])
        extra = {k: v for k, v in d.items() if k not in known}
        return cls(**kw, extra=extra)

    def to_dict(self) -> dict:
        d = {"kind": self.kind, "rows": self.rows, "cols": self.cols, "spacing_mm": self.spacing_mm,
             "polarity": self.polarity}
        if self.kind == "circles":
            d["small_diameter_mm"] = self.small_diameter_mm
            if self.large_markers:
                d["large_diameter_mm"] = self.large_diameter_mm
                d["large_markers"] = [list(m) for m in self.large_markers]
        if self.kind == "charuco":
            d["aruco_dictionary"] = self.aruco_dictionary
        return d


def paper_board(**changes) -> Board:
    """The paper's calibration board (supplementary section 2): 9 x 11 circles at 20 mm pitch,
    2 mm circles and 5 mm orientation circles in DESIGN.md's marker layout, dark on light.
    ``changes`` replace any of these (e.g. ``large_markers=()``)."""
    kw = dict(kind="circles", rows=9, cols=11, spacing_mm=20.0, large_diameter_mm=5.0, small_diameter_mm=2.0,
              large_markers=PAPER_LARGE_MARKERS, polarity="dark-on-light")
    kw.update(changes)
    return Board(**kw)
