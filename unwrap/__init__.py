"""sltwin unwrap: fringe patterns, N-step phase, temporal phase unwrapping, physics-aware model.

Public surface: ``wrapped_phase`` (N-step least squares, numpy/torch), ``mf_unwrap``,
``mw_unwrap``, ``nt_unwrap``, ``gray_unwrap``, ``complementary_gray_unwrap``,
``gray_coarse_unwrap`` (each returns ``Unwrapped`` with phase, order, valid and the physics prior),
``error_rate`` / ``plan_fringes`` (reliability theory), ``unwrap_capture`` / ``write_results``
(capture folders), ``UnwrapError``.
"""
from .errors import UnreliableFringesWarning, UnwrapError  # noqa: F401
from .graycode import (binarize, complementary_gray_unwrap, gray_coarse_unwrap,  # noqa: F401
                       gray_code_bits, gray_to_index, gray_unwrap)
from .patterns import (absolute_phase, fringe_intensity, fringe_pattern,  # noqa: F401
                       phase_shift, projector_coordinate)
from .phase_shift import (WrappedPhase, equal_shifts, least_squares_weights,  # noqa: F401
                          phase_noise_gain, wrapped_phase)
from .plan import plan_fringes  # noqa: F401
from .monte_carlo import monte_carlo_error_rate  # noqa: F401
from .reliability import error_rate, phase_error_pdf, phase_sigma  # noqa: F401
from .temporal import (Unwrapped, base_phase, mf_unwrap, mw_unwrap, nt_lookup_table,  # noqa: F401
                       nt_unwrap, refine)


def unwrap_capture(*args, **kwargs):
    """See :func:`unwrap.pipeline.unwrap_capture` (imported lazily: it needs OpenCV)."""
    from .pipeline import unwrap_capture as f
    return f(*args, **kwargs)


def write_results(*args, **kwargs):
    """See :func:`unwrap.pipeline.write_results` (imported lazily: it needs h5py/matplotlib)."""
    from .pipeline import write_results as f
    return f(*args, **kwargs)
