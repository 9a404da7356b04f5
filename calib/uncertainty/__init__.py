"""The uncertainty a calibration reports and the evidence beside it: per-pose error fields, pose resampling, residual diagnostics, the skew check."""
