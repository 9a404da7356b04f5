"""Probability that the traditional fringe order is wrong, bias included (issue 21).

The reliability model's error probability (:func:`unwrap.spatial_orders.traditional_error_probability`)
follows from the phase noise alone, so it calls a pixel reliable whenever its prior sits near an
integer - also where interreflection, defocus across an occlusion edge or subsurface scattering
has shifted the coarse phase coherently by most of a fringe, and the prior sits near the *wrong*
integer. This model adds the probability of such a bias flip from physical cues of the pixel,
never from the identity of a capture:

    p = 1 - (1 - p_noise) (1 - s),   s = sigmoid(c0 + sum_k c_k x_k)

with the features (per valid pixel; :func:`features`):

- ``log_mod_low``: ln of the coarse (unit) pattern's modulation B_lo (fraction of full scale,
  floored at 1e-4): indirect light carries another projector column's phase, and it weighs more
  where the direct modulation is small;
- ``log_mod_high``: ln B_hi, the same for the high pattern (defocus and dark surfaces);
- ``log_edge_distance``: ln(1 + d), d the Euclidean distance (camera px, capped at
  :data:`MAX_DISTANCE`) to the nearest invalid pixel (shadow, background, low modulation):
  interreflection between object and wall, and the PSF's mixing across an occlusion edge, bias
  the coarse phase in bands along outlines and beside cast shadows;
- ``local_bias``: |arg(mean exp(2 pi i r))| / 2 pi over the valid pixels of a
  :data:`WINDOW` x :data:`WINDOW` window, r the prior (fringes of the high frequency): the
  neighbourhood's coherent offset of the prior from an integer, in [0, 1/2] fringe. Noise averages
  out of it; a bias of the coarse phase does not, and near 1/2 half the pixels round the wrong way;
- ``local_bias_wide``: the same over :data:`WIDE_WINDOW` x :data:`WIDE_WINDOW` (a band of bias
  wider than the small window, whose centre has already flipped).

The first term, ``p_noise`` (the noise model's probability, the first feature column), enters
as it is, so where no bias cue speaks (a flat lit plane far from edges, high modulation, the prior
centred on integers) ``p`` equals the noise model's up to ``s``, which the fit drives to the
order of the validation error rate there (1.5e-3 with the shipped coefficients, modulation 0.4).
The coefficients are bounded so that the model is monotone where physics says it must be: more
modulation or more distance from an invalid pixel never raises ``p`` (``c <= 0``), a larger local
bias never lowers it (``c >= 0``).

:data:`MODEL` holds the coefficients fitted by ``python -m bench.decision_error_fit`` (or
``python -m bench.spatial_unwrap --calibrate``) on twin **validation** scenes only: the gate's
calibration scenes (``bench/data/spatial_val.toml``, noise-dominated) and bias-dominated ones
(``bench/data/decision_error_val.toml``: training meshes before a wall with the physically
based interreflection of :mod:`synth.effects.interreflection`, defocus, subsurface, high SNR).

SYNOPSIS

    >>> import numpy as np
    >>> from unwrap.decision_error import error_probability
    >>> valid = np.ones((40, 40), bool); valid[:, :3] = False          # an invalid strip on the left
    >>> prior = np.full((40, 40), 7.0); p_noise = np.full((40, 40), 1e-9)
    >>> p = error_probability(p_noise, prior, valid, np.full((40, 40), 0.3), np.full((40, 40), 0.3))
    >>> bool(p[20, 4] > p[20, 35] >= 1e-9)                               # near the edge: less sure
    True
"""
from __future__ import annotations

import math

import numpy as np

from .errors import UnwrapError

#: Feature names, in the order of :func:`features`' columns after ``p_noise``.
FEATURES = ("log_mod_low", "log_mod_high", "log_edge_distance", "local_bias", "local_bias_wide")
#: Sign constraints of the coefficients (monotonicity): -1 <= 0, +1 >= 0.
SIGNS = {"log_mod_low": -1, "log_mod_high": -1, "log_edge_distance": -1, "local_bias": +1, "local_bias_wide": +1}
#: The optional feature of :data:`MODEL_GLOBAL`: ln(1 + rho), rho the global / direct ratio of
#: :func:`unwrap.global_light.bias_bound` (more global light never lowers p).
GLOBAL_FEATURE = "log_global_ratio"
SIGNS[GLOBAL_FEATURE] = +1
#: Windows (px) of the local bias; cap (px) of the distance to an invalid pixel; modulation floor.
WINDOW = 7
WIDE_WINDOW = 15
MAX_DISTANCE = 64.0
MIN_MODULATION = 1e-4

#: Fitted coefficients (``python -m bench.decision_error_fit``; validation scenes only, see the
#: module docstring). version: bumped whenever the features change.
MODEL = {"version": 1, "intercept": -4.410076,
         "coef": {"log_mod_low": 0.0, "log_mod_high": -0.361502, "log_edge_distance": -0.580831,
                  "local_bias": 6.112529, "local_bias_wide": 6.331591},
         "fitted_on": "bench.decision_error_fit (refitted by bench.spatial_unwrap --calibrate-gate with the "
                      "width-8 gate): 12 validation scenes (6 of spatial_val.toml, 6 of decision_error_val.toml with "
                      "interreflection), 3373676 pixels, 76769 traditional errors; log loss 0.0661 per pixel "
                      "(ridge-penalised objective 0.0668); the twin scenes' noise from capture_noise with the "
                      "centre pixel's plane dof sqrt(25/24) (before: sqrt(25/22), intercept -4.377)"}


#: The model with the global / direct ratio as a sixth feature (``python -m bench.decision_error_fit
#: --global``; the same 12 validation scenes, whose offsets were re-rendered): used by
#: :func:`error_probability` when ``global_ratio`` is given. Not yet behind any gate threshold.
MODEL_GLOBAL = {"version": 1, "intercept": -5.298233,
                "coef": {"log_mod_low": 0.0, "log_mod_high": 0.0, "log_edge_distance": -0.320344,
                         "local_bias": 5.18841, "local_bias_wide": 6.27402, "log_global_ratio": 3.684625},
                "fitted_on": "bench.decision_error_fit --global (refitted with the twin scenes' noise from "
                             "capture_noise with the centre pixel's plane dof sqrt(25/24), as MODEL; before: "
                             "intercept -5.306): 12 validation scenes (6 of spatial_val.toml, "
                             "6 of decision_error_val.toml with interreflection), 3373676 pixels; log loss 0.0620 "
                             "per pixel, ridge-penalised objective 0.0627 (MODEL on the same pixels: 0.0661)"}


def _names(model: dict) -> tuple:
    return FEATURES + ((GLOBAL_FEATURE,) if GLOBAL_FEATURE in model["coef"] else ())


def _check(p_noise, prior, valid, modulation_low, modulation_high):
    arrs = [np.asarray(a) for a in (p_noise, prior, valid, modulation_low, modulation_high)]
    if any(a.ndim != 2 or a.shape != arrs[0].shape for a in arrs):
        raise UnwrapError("decision error: expected one (H, W) shape for p_noise, prior, valid and the modulations, "
                          "got " + ", ".join(str(a.shape) for a in arrs))
    return arrs


def local_bias(prior, valid, window: int = WINDOW) -> np.ndarray:
    """(H, W) float64 in [0, 1/2]: |arg(mean over the valid window pixels of exp(2 pi i r))| / 2 pi
    (module docstring); 0 at invalid or non-finite pixels and where the window's mean vector vanishes."""
    from scipy.ndimage import uniform_filter

    prior = np.asarray(prior, dtype=np.float64)
    v = np.asarray(valid, dtype=bool) & np.isfinite(prior)   # a non-finite prior is no vote, not a vote for 0
    r = np.where(v, prior, 0.0)
    ang = 2 * math.pi * r
    c = uniform_filter(np.where(v, np.cos(ang), 0.0), window, mode="constant")
    s = uniform_filter(np.where(v, np.sin(ang), 0.0), window, mode="constant")
    return np.where(v, np.abs(np.arctan2(s, c)) / (2 * math.pi), 0.0)


def edge_distance(valid) -> np.ndarray:
    """(H, W) float64: Euclidean distance (px) of each valid pixel to the nearest invalid one
    (:data:`MAX_DISTANCE` where there is none, and the cap); 0 at invalid pixels. The image
    border is not an edge."""
    from scipy.ndimage import distance_transform_edt

    v = np.asarray(valid, dtype=bool)
    if v.all():
        return np.full(v.shape, MAX_DISTANCE)
    return np.minimum(distance_transform_edt(v), MAX_DISTANCE)


def features(p_noise, prior, valid, modulation_low, modulation_high, global_ratio=None) -> np.ndarray:
    """(H, W, 1 + K) float64: ``p_noise`` then the :data:`FEATURES` (module docstring), then
    :data:`GLOBAL_FEATURE` when ``global_ratio`` is given.

    ARGUMENTS: p_noise (H, W) the noise model's error probability; prior (H, W) the temporal
    prior r (fringes of the high frequency); valid (H, W) bool; modulations (H, W) of the coarse
    and high patterns as fractions of full scale (B / the sensor's maximum); global_ratio (H, W)
    the global / direct ratio rho (:func:`unwrap.global_light.bias_bound`), optional."""
    p_noise, prior, valid, m_lo, m_hi = _check(p_noise, prior, valid, modulation_low, modulation_high)
    if global_ratio is not None and np.shape(global_ratio) != prior.shape:
        raise UnwrapError(f"decision error: global_ratio {np.shape(global_ratio)}, expected {prior.shape}")
    v = valid.astype(bool)
    cols = [np.clip(np.nan_to_num(p_noise.astype(np.float64)), 0.0, 1.0),
            np.log(np.maximum(np.nan_to_num(m_lo.astype(np.float64)), MIN_MODULATION)),
            np.log(np.maximum(np.nan_to_num(m_hi.astype(np.float64)), MIN_MODULATION)),
            np.log1p(edge_distance(v)),
            local_bias(prior, v),
            local_bias(prior, v, WIDE_WINDOW)]
    if global_ratio is not None:
        cols.append(np.log1p(np.maximum(np.nan_to_num(np.asarray(global_ratio, dtype=np.float64)), 0.0)))
    return np.stack(cols, axis=-1)


def _sigmoid(z):
    return 0.5 * (1.0 + np.tanh(0.5 * z))


def probability_from_features(X, model: dict | None = None) -> np.ndarray:
    """``p`` (X.shape[:-1]) from a feature array of :func:`features` (module docstring)."""
    model = MODEL if model is None else model
    X = np.asarray(X, dtype=np.float64)
    names = _names(model)
    if X.shape[-1] != 1 + len(names):
        raise UnwrapError(f"decision error: {X.shape[-1]} feature columns for a model of {1 + len(names)} "
                          f"({', '.join(('p_noise',) + names)})")
    coef = np.array([model["coef"][k] for k in names])
    s = _sigmoid(model["intercept"] + X[..., 1:] @ coef)
    return 1.0 - (1.0 - X[..., 0]) * (1.0 - s)


def error_probability(p_noise, prior, valid, modulation_low, modulation_high, *, model: dict | None = None,
                      global_ratio=None):
    """(H, W) float64 in [0, 1]: the probability that the traditional order is wrong (module
    docstring); 0 at invalid pixels. ``model``: coefficients (default :data:`MODEL`, or
    :data:`MODEL_GLOBAL` when ``global_ratio`` is given)."""
    if model is None:
        model = MODEL if global_ratio is None else MODEL_GLOBAL
    if (GLOBAL_FEATURE in model["coef"]) != (global_ratio is not None):
        raise UnwrapError("decision error: give global_ratio exactly when the model has the feature "
                          f"{GLOBAL_FEATURE!r}")
    X = features(p_noise, prior, valid, modulation_low, modulation_high, global_ratio)
    return np.where(np.asarray(valid, dtype=bool), probability_from_features(X, model), 0.0)


def fit(X, wrong, *, note: str = "", l2: float = 1e-3, names: tuple = FEATURES) -> dict:
    """Maximum-likelihood coefficients (log loss, a small ridge ``l2`` on the coefficients) of the
    model on pooled pixels: ``X`` (N, 1 + K) of :func:`features`, ``wrong`` (N,) bool (the
    traditional order differs from the reference). The sign constraints :data:`SIGNS` are bounds
    of the optimiser (L-BFGS-B), so the fitted model is monotone by construction. Features are
    standardised for the optimiser and the coefficients returned in the raw units. ``names``: the
    feature columns after ``p_noise`` (:data:`FEATURES`, optionally + :data:`GLOBAL_FEATURE`).

    RETURNED VALUE: a model dict like :data:`MODEL` (``version``, ``intercept``, ``coef``,
    ``fitted_on``, plus ``log_loss``: the plain log loss per pixel at the fitted coefficients,
    ``objective``: the ridge-penalised value the optimiser minimised, and ``pixels``)."""
    from scipy.optimize import minimize

    X = np.asarray(X, dtype=np.float64)
    y = np.asarray(wrong, dtype=bool).astype(np.float64)
    names = tuple(names)
    if any(k not in SIGNS for k in names):
        raise UnwrapError(f"decision error fit: unknown features {[k for k in names if k not in SIGNS]}")
    if X.ndim != 2 or X.shape[1] != 1 + len(names) or y.shape != X.shape[:1]:
        raise UnwrapError(f"decision error fit: expected X (N, {1 + len(names)}) and wrong (N,), got "
                          f"{X.shape}, {y.shape}")
    if y.sum() < 10 or (1 - y).sum() < 10:
        raise UnwrapError(f"decision error fit: needs at least 10 right and 10 wrong pixels, got {int(y.sum())} wrong "
                          f"of {y.size}")
    pn = X[:, 0]
    F = X[:, 1:]
    mu, sd = F.mean(axis=0), F.std(axis=0)
    sd = np.where(sd > 0, sd, 1.0)
    Z = (F - mu) / sd
    n = y.size

    def plain(theta):
        s = _sigmoid(theta[0] + Z @ theta[1:])
        p = np.clip(1.0 - (1.0 - pn) * (1.0 - s), 1e-15, 1.0)
        log1mp = np.log(np.clip(1.0 - pn, 1e-300, 1.0)) + np.log(np.clip(1.0 - s, 1e-300, 1.0))
        return -(y * np.log(p) + (1 - y) * log1mp).sum() / n, s, p

    def loss(theta):
        L, s, p = plain(theta)
        L += l2 * (theta[1:] ** 2).sum()
        dz = (-y * (1.0 - pn) * s * (1.0 - s) / p + (1 - y) * s) / n
        g = np.concatenate([[dz.sum()], Z.T @ dz + 2 * l2 * theta[1:]])
        return L, g

    bounds = [(None, None)] + [((None, 0.0) if SIGNS[k] < 0 else (0.0, None)) for k in names]
    theta0 = np.zeros(1 + len(names))
    theta0[0] = math.log(max(y.mean(), 1e-6))
    r = minimize(loss, theta0, jac=True, method="L-BFGS-B", bounds=bounds, options={"maxiter": 500})
    t = r.x
    coef = t[1:] / sd
    intercept = float(t[0] - (coef * mu).sum())
    return {"version": MODEL["version"], "intercept": round(intercept, 6),
            "coef": {k: round(float(c), 6) for k, c in zip(names, coef)},
            "fitted_on": note, "log_loss": float(plain(t)[0]), "objective": float(r.fun), "pixels": int(n)}


__all__ = ["FEATURES", "GLOBAL_FEATURE", "MAX_DISTANCE", "MODEL", "MODEL_GLOBAL", "SIGNS", "WIDE_WINDOW", "WINDOW",
           "edge_distance", "error_probability", "features", "fit", "local_bias", "probability_from_features"]
