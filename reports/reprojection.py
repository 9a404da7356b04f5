"""Cross reprojection moved to :mod:`calib.board_pose` (the board-pose fit is calibration
work); re-exported here for existing callers."""
from calib.board_pose import cross_reprojection, fit_board_pose  # noqa: F401
