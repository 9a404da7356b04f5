"""sltwin experiments: the computations that compare, evaluate and match, above the renderer and
below the reports (the reports lay out what these return; the commands call an experiment, then a
report).

Public surface:

- the twin ball of the paper's Fig. 3: ``render_twin_ball_phase`` (rendered at the real ball's
  fitted pose with the real phase's noise), ``twin_ball_for_report`` (what the twin-equivalence
  report lays out).
- parity of the renderer with Blender Cycles: ``blender_parity`` (plane / sphere phase against
  Cycles), ``gi_versus_cycles`` (the global-illumination effect against Cycles' path tracing);
  the unit-phase bias of the physically based interreflection against Cycles is in
  `experiments.gi_bias` (``python -m bench.gi_bias``).
- the learned unwrapping: ``TestSource`` and ``score`` (error rates of models and baselines on a
  test set), ``evaluate_models`` (``calib eval``: tables S5 / S6 beside the paper's, confidence,
  real captures, speed), ``learned_parity`` (twin renders with the capture's noise vs the real
  capture), ``slstudio_parity`` (the whole check on SLStudio's skull); the twin built from what a
  capture measures is `experiments.pixel_twin` (its own A, B per pixel, the fitted sensor, its
  unit-phase bias), the interreflection rendered on a capture's own geometry
  `experiments.capture_gi`, the plane estimator's noise split on a twin `experiments.noise_split`
  (``python -m bench.skull_parity``).
- ``ExperimentError`` (a ValueError).

Experiments take no command line and import nothing from reports; progress goes to the
`experiments` logger (and to the loggers of the packages they call).
"""
from .blender_parity import parity as blender_parity
from .errors import ExperimentError
from .gi_reference import gi_versus_cycles
from .learned_eval import evaluate_models
from .learned_evaluation import TestSource, score
from .learned_parity import parity as learned_parity
from .learned_parity import slstudio_parity
from .twin_ball import render_twin_ball_phase, twin_ball_for_report

__all__ = [
    "render_twin_ball_phase", "twin_ball_for_report", "blender_parity", "gi_versus_cycles",
    "TestSource", "score", "evaluate_models", "learned_parity", "slstudio_parity", "ExperimentError",
]
