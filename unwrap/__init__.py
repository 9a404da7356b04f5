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
import sys

# Light modules (numpy only) at once. ``phase_shift`` names both a submodule and patterns'
# function: the submodule is loaded first, so that the package attribute stays the function.
from .errors import UnreliableFringesWarning, UnwrapError
from .phase_shift import WrappedPhase, equal_shifts, least_squares_weights, phase_noise_gain, wrapped_phase
from .patterns import absolute_phase, fringe_intensity, fringe_pattern, phase_shift, projector_coordinate

# The other public names, by submodule. PEP 562: a name's submodule is imported at its first use,
# so ``import unwrap.safe_output`` (calib's atomic writes) loads neither scipy.special nor the
# capture pipeline.
_HOME = {
    "consistency": ("prior_check",),
    "fused_mf": ("mf_unwrap_stacks",),
    "graycode": ("binarize", "complementary_gray_unwrap", "gray_coarse_unwrap", "gray_code_bits",
                 "gray_code_unwrap", "gray_to_index", "gray_unwrap"),
    "monte_carlo": ("monte_carlo_error_rate",),
    "phase_io": ("read_phase", "write_phase_file"),
    "pipeline": ("unwrap_capture", "write_results"),
    "plan": ("plan_fringes",),
    "reliability": ("error_rate", "fit_noise_sigma", "modulation_threshold", "phase_error_pdf", "phase_sigma"),
    "temporal": ("Unwrapped", "base_phase", "mf_unwrap", "mw_unwrap", "nt_lookup_table", "nt_unwrap", "refine"),
}


def __getattr__(name):
    """The public name ``name``, imported from its submodule at first use (PEP 562)."""
    home = next((m for m, names in _HOME.items() if name in names), None)
    if home is None:
        raise AttributeError(f"module 'unwrap' has no attribute {name!r}")
    if home == "consistency":
        from . import consistency as module
    elif home == "fused_mf":
        from . import fused_mf as module
    elif home == "graycode":
        from . import graycode as module
    elif home == "monte_carlo":
        from . import monte_carlo as module
    elif home == "phase_io":
        from . import phase_io as module
    elif home == "pipeline":
        from . import pipeline as module
    elif home == "plan":
        from . import plan as module
    elif home == "reliability":
        from . import reliability as module
    else:
        from . import temporal as module
    value = getattr(module, name)
    setattr(sys.modules[__name__], name, value)
    return value


def __dir__():
    return sorted(set(globals()) | set(__all__))


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
