"""sltwin unwrap: fringe patterns, N-step phase, temporal phase unwrapping, reliability theory,
phase maps on disk.

Public surface:

- patterns and conventions: ``fringe_pattern``, ``fringe_intensity``, ``phase_shift``,
  ``absolute_phase``, ``projector_coordinate``.
- N-step phase: ``wrapped_phase`` (least squares, numpy/torch) -> ``WrappedPhase``;
  ``equal_shifts``, ``least_squares_weights``, ``phase_noise_gain``, ``fit_noise_sigma`` (the noise
  per frame from the fit residuals).
- temporal unwrapping, each returning ``Unwrapped`` (phase, order, valid, the physics prior):
  ``mf_unwrap``, ``mw_unwrap``, ``nt_unwrap`` (``nt_lookup_table``), ``gray_unwrap``,
  ``complementary_gray_unwrap``, ``gray_coarse_unwrap``, ``gray_code_unwrap`` (Gray code
  alone; ``binarize``, ``gray_to_index``,
  ``gray_code_bits``); ``base_phase``, ``refine`` (one hierarchical step).
- the in-memory decoder: ``mf_unwrap_stacks`` (phase-shift stacks of every frequency -> absolute
  phase, order, A and B; one fused pass for 8/16-bit frames).
- reliability: ``error_rate``, ``phase_error_pdf``, ``phase_sigma``, ``plan_fringes``,
  ``monte_carlo_error_rate``, ``modulation_threshold`` (the modulation for a target error rate),
  ``prior_check`` (is a decode consistent with its frames).
- captures and files: ``unwrap_capture`` / ``write_results`` (capture folders -> ``unwrap.h5``),
  ``read_phase`` / ``write_phase_file`` (the one phase-map reader and writer).
- ``UnwrapError`` (a ValueError), ``UnreliableFringesWarning``.

Progress goes to the `unwrap` logger.
"""
from .consistency import prior_check
from .errors import UnreliableFringesWarning, UnwrapError
from .fused_mf import mf_unwrap_stacks
from .graycode import (binarize, complementary_gray_unwrap, gray_coarse_unwrap, gray_code_bits, gray_code_unwrap,
                       gray_to_index, gray_unwrap)
from .monte_carlo import monte_carlo_error_rate
from .patterns import absolute_phase, fringe_intensity, fringe_pattern, phase_shift, projector_coordinate
from .phase_io import read_phase, write_phase_file
from .phase_shift import WrappedPhase, equal_shifts, least_squares_weights, phase_noise_gain, wrapped_phase
from .pipeline import unwrap_capture, write_results
from .plan import plan_fringes
from .reliability import error_rate, fit_noise_sigma, modulation_threshold, phase_error_pdf, phase_sigma
from .temporal import Unwrapped, base_phase, mf_unwrap, mw_unwrap, nt_lookup_table, nt_unwrap, refine

__all__ = [
    "fringe_pattern", "fringe_intensity", "phase_shift", "absolute_phase", "projector_coordinate",
    "wrapped_phase", "WrappedPhase", "equal_shifts", "least_squares_weights", "phase_noise_gain", "fit_noise_sigma",
    "Unwrapped", "mf_unwrap", "mw_unwrap", "nt_unwrap", "nt_lookup_table", "gray_unwrap",
    "complementary_gray_unwrap", "gray_coarse_unwrap", "gray_code_unwrap", "binarize", "gray_to_index", "gray_code_bits",
    "base_phase", "refine", "mf_unwrap_stacks",
    "error_rate", "phase_error_pdf", "phase_sigma", "plan_fringes", "monte_carlo_error_rate", "modulation_threshold",
    "prior_check",
    "unwrap_capture", "write_results", "read_phase", "write_phase_file",
    "UnwrapError", "UnreliableFringesWarning",
]
