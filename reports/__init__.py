"""sltwin reports: generated reports, the layout of what the packages below computed.

Public surface:

- ``write_twin_report``: the twin-equivalence report (real vs twin calibration, the paper's
  tables, residuals, cross reprojection, the ball's Fig. 3 matrix) as ``report.html``
  (self-contained, figures embedded), ``report.md`` and ``summary.json``;
  ``build_twin_report``: its sections and summary.
- ``ReportError`` (a ValueError).

Reports lay out results they are given: the numbers come from calib (calibration records,
board-pose fits, triangulation), experiments (the twin ball, the learned evaluation and parity)
and twin_mapping (the paper's tables); progress goes to the `reports` logger.
"""
from .errors import ReportError
from .twin_report import build_twin_report, write_twin_report

__all__ = ["write_twin_report", "build_twin_report", "ReportError"]
