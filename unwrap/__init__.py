"""sltwin unwrap: fringe patterns, N-step phase, temporal phase unwrapping, physics-aware model."""
from .patterns import (absolute_phase, fringe_intensity, fringe_pattern,  # noqa: F401
                       phase_shift, projector_coordinate)
