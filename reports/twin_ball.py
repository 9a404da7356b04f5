"""The twin ball experiment moved to :mod:`synth.twin_ball` (reports only lays out what others
computed: :mod:`reports.twin_ball_section`); its names are re-exported here for existing callers."""
from synth.twin_ball import (BALL_FREQUENCIES, BALL_STEPS, READ_NOISE_E, fit_ball_pose,  # noqa: F401
                             phase_noise_rad, render_twin_ball_phase, write_twin_ball_phase)
