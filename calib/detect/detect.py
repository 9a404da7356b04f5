"""``detect_board``: one entry point for every board kind of calib.board."""
from __future__ import annotations

import cv2
import numpy as np

from ..board import Board
from .result import BoardDetection, DetectionError, image_as_float


def detect_board(image, board: Board, *, min_points: int = 6, camera=None) -> BoardDetection:
    """Find ``board`` in a grey camera ``image`` and return its features with their ids.

    ARGUMENTS
    - image: (H, W) grey array, uint8 / uint16 / float (e.g. the white frame or the
      phase-shift mean A). Pixel centres at integer coordinates (OpenCV).
    - board: calib.board.Board ("circles", "checkerboard" or "charuco").
    - min_points: fewer identified features than this raise DetectionError.
    - camera: optional ``calib.device.DeviceModel`` of this camera (e.g. a first calibration's):
      circle centres are then corrected for the lens bias as well (``circles.lens_centre_bias``).
      Corners need no such correction (a corner images to a point) and ignore it.

    RETURNED VALUE: BoardDetection (ids sorted ascending, q (N, 2) px, points_board (N, 3) mm,
    feature_px (N,), homography board mm -> px, method, notes).

    Circles: partial boards keep every complete circle with its identity (cut circles are
    dropped and listed in ``notes``); centres are corrected for the perspective bias.
    Checkerboards must be fully in view (their corners carry no identity); a 180-degree turn of a
    board whose rows + cols is even cannot be seen in the image and is resolved by a convention
    (board +y points up in the image), stated in ``notes``.
    """
    if not isinstance(board, Board):
        raise DetectionError(f"board: expected a calib.board.Board, got {type(board).__name__}")
    if not isinstance(min_points, int) or min_points < 1:
        raise DetectionError(f"min_points: expected a positive integer, got {min_points!r}")
    f = image_as_float(image)
    try:
        if board.kind == "circles":
            from .circles import detect_circles
            return detect_circles(f, board, min_points=min_points, camera=camera)
        if board.kind == "checkerboard":
            from .chessboard import detect_checkerboard
            return detect_checkerboard(f, board, min_points=min_points)
        from .chessboard import detect_charuco
        return detect_charuco(f, board, min_points=min_points)
    except (np.linalg.LinAlgError, cv2.error) as exc:  # a degenerate configuration, never a traceback
        raise DetectionError(f"{board.kind} board {board.rows}x{board.cols} in a {f.shape[1]}x{f.shape[0]} px "
                             f"image: numerical failure while fitting ({type(exc).__name__}: "
                             f"{str(exc).strip().splitlines()[-1] if str(exc).strip() else exc})") from None
