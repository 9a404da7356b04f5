"""Board detection in grey camera images: circle grids with large orientation markers,
checkerboards (OpenCV's SB detector) and ChArUco boards (opencv-contrib's aruco module).

SYNOPSIS

    >>> from calib.board import Board
    >>> from calib.detect import detect_board, DetectionError
    >>> import numpy as np
    >>> board = Board(kind="checkerboard", rows=3, cols=4, spacing_mm=10.0)
    >>> try:
    ...     detect_board(np.full((64, 64), 128, np.uint8), board)
    ... except DetectionError as exc:
    ...     print(exc)
    image (64x64 px): the image is constant (128); no board in it

``detect_board(image, board, *, min_points=6, camera=None) -> BoardDetection`` (ids, q, points_board,
feature_px, homography, method, notes); ``DetectionError`` when the board is not found, too few
features are identified, or the orientation is ambiguous.
"""
from .result import BoardDetection, DetectionError  # noqa: F401
from .detect import detect_board  # noqa: F401
from .circles import circle_image_centre, lens_centre_bias, perspective_bias  # noqa: F401
