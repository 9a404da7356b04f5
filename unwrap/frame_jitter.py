"""Per-frame intensity fluctuation of a phase-shifted fringe set: estimate it, predict the phase
bias it causes, correct the frames.

Model of frame n at pixel p (the convention of :mod:`unwrap.phase_shift`, grey levels):

    I_n(p) = o_n + g_n * (A(p) + B(p) cos(phi(p) - delta_n) + B(p) * sum_k h_k(phi(p) - delta_n))

``o_n`` a per-frame additive offset (grey), ``g_n`` a per-frame gain (mean 1), ``h_k`` optional
harmonics of a waveform shared by every pixel (a projector's response curve: the projector sends
the same waveform to every pixel, the camera scales and offsets it). Causes of o_n / g_n: the light
source's or the exposure's fluctuation, exposure not synchronised with the projector's refresh,
auto-exposure.

What a set can tell (the identifiability this module enforces):

- The per-pixel fit of ``[A, C, S]`` (``C + iS = B e^{i phi}``) absorbs, at every pixel, the
  components of ``o`` in span{1, cos delta, sin delta}. The rest, ``o_perp = Q o`` (Q the
  projector onto the N - 3 dimensional residual space), shows in every pixel's residual the same
  way and is estimated from the residuals of many pixels. ``o_perp`` does NOT bias the phase at
  all (the N-step phase sees only the first harmonic); it measures the size of the fluctuation.
  N = 3 leaves no residual: :class:`FrameJitterError`.
- The first harmonic of ``o`` (``z_o = (P o)[1] + i (P o)[2]``, P the least-squares weights) adds
  the same complex number to ``C + iS`` at every pixel and is what biases the phase:
  ``dphi ~= Im(z_o e^{-i phi}) / B`` (rad), a ripple of one period per fringe, largest where B is
  small. Per pixel it cannot be told from the fringe; across pixels it can: (a) with a
  ``reference_phase`` (e.g. a redundant MF ladder's absolute phase), by regressing
  ``Im((C + iS) e^{-i phi_ref})`` on ``(-sin phi_ref, cos phi_ref)``; (b) in a high-frequency set
  whose phases cover the period evenly, as the spatial low-pass of ``C + iS`` (a Gaussian of one
  fringe period removes the carrier, exp(-2 pi^2) ~ 3e-9, and leaves the constant); (c) otherwise
  it is not identified (``how`` says why; also when it is below ``SIGNIFICANT`` jackknife
  standard errors: on real captures the spatial low-pass and the reference both see more than a
  constant) and :func:`expected_bias_rms` gives the bias it causes
  in expectation, if the frames' offsets are independent with the size measured by ``o_perp``.
- Gains act through their product with the fringe: ``(g_n - 1) B cos(phi - delta_n)`` has
  components outside span{1, cos, sin} that depend on phi, so every gain but their mean is
  identified where the phases of the pixels are diverse.
- Residual means are confounded with the waveform's harmonics unless the phases cover the period
  evenly (a high-frequency set over the whole frame: harmonics average out); otherwise the shared
  harmonic model (``harmonics`` > 0) separates them; with neither, :class:`FrameJitterError`.

Uncertainties are delete-one-tile jackknife standard errors over a 4 x 4 grid of image tiles (the
errors of the model are spatially correlated; a per-pixel noise formula would understate them).

SYNOPSIS

    >>> import numpy as np
    >>> from unwrap.frame_jitter import estimate_frame_jitter
    >>> N, (H, W) = 8, (96, 128)
    >>> d = 2 * np.pi * np.arange(N) / N
    >>> x = np.arange(W)[None, :] * np.ones((H, 1))
    >>> phi = 2 * np.pi * x / 12.0 + np.arange(H)[:, None] / 20  # 10.7 periods across
    >>> o = np.array([0, 2, -1, 0, 1, -3, 0, 1.0])              # grey
    >>> I = o[:, None, None] + 100 + 60 * np.cos(phi[None] - d[:, None, None])
    >>> j = estimate_frame_jitter(I, d, min_modulation=10)
    >>> bool(np.allclose(j.offsets, o - o.mean(), atol=0.05)), j.how
    (True, 'spatial low-pass')
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .errors import FrameJitterError, UnwrapError
from .phase_shift import least_squares_weights

TWO_PI = 2 * math.pi
#: pixels the residual regression needs at least (well-modulated, unsaturated)
MIN_PIXELS = 2000
#: a set's phases cover the period evenly when its 12-bin histogram's min / max is at least this
UNIFORM_MIN_RATIO = 0.5
#: a first harmonic is reported only when it exceeds this many jackknife standard errors
SIGNIFICANT = 3.0
#: a set whose median background A is below this fraction of its median modulation B is refused:
#: intensities are >= 0, so A >= B (contrast <= 1) up to noise and the response curve
MIN_BACKGROUND = 0.5
#: calib unwrap's warning: RMS of the per-frame offsets (o_perp) above this fraction of the background
WARN_FRACTION = 0.01


@dataclass
class FrameJitter:
    """Per-frame offsets and gains of one fringe set (float64, N = frames).

    - offsets (N,): grey, ``o_perp`` plus, when identified, the first harmonic ``z_o`` (mean 0);
      offsets_std (N,): jackknife standard errors.
    - gains (N,): mean 1; gains_std (N,).
    - first_harmonic: ``z_o`` (complex, grey, added to ``C + iS``) or None when not identified;
      first_harmonic_std: its standard error (grey); how: "spatial low-pass", "reference phase"
      or "not identified: <why>".
    - sigma: RMS size of one frame's offset implied by ``o_perp`` (``|o_perp| / sqrt(N - 3)``,
      grey): the scale of the fluctuation whatever part is identified.
    - background: median A of the pixels used (grey; relative numbers divide by it); pixels:
      how many were used; uniform: whether their phases cover the period evenly; harmonics:
      {k: h_k relative to B} of the shared waveform, the term ``B (Re h_k cos k t + Im h_k sin k t)``,
      t = phi - delta_n.
    """
    shifts: np.ndarray
    offsets: np.ndarray
    offsets_std: np.ndarray
    gains: np.ndarray
    gains_std: np.ndarray
    first_harmonic: complex | None
    first_harmonic_std: float | None
    how: str
    sigma: float
    background: float
    pixels: int
    uniform: bool
    harmonics: dict = field(default_factory=dict)

    @property
    def offsets_rel(self) -> np.ndarray:
        """Offsets as fractions of the background."""
        return self.offsets / self.background

    @property
    def sigma_rel(self) -> float:
        return self.sigma / self.background


def _check_stack(frames, shifts):
    I = np.asarray(frames, dtype=np.float64)
    if I.ndim == 4:                                   # colour frames of a grey scene
        I = I.mean(-1)
    d = np.asarray(shifts, dtype=np.float64).reshape(-1)
    if I.ndim != 3 or I.shape[0] != d.size:
        raise FrameJitterError(f"frames of shape {I.shape} with {d.size} shifts: expected (N, H, W) with N = "
                               "len(shifts)")
    if d.size < 4:
        raise FrameJitterError(f"{d.size} frames: a per-frame fluctuation needs N >= 4 (with N = 3 the "
                               "per-pixel fit of A, B, phi leaves no residual to see it in)")
    return I, d


def _harmonic_orders(N: int, count: int) -> list:
    """Harmonic orders k >= 2 that the N-step fit does not absorb (k mod N not in {0, 1, N-1}),
    one per alias class, the first ``count``."""
    ks, seen = [], set()
    for k in range(2, 4 * N):
        r = k % N
        cls = min(r, N - r)
        if r in (0, 1, N - 1) or cls in seen:
            continue
        seen.add(cls)
        ks.append(k)
        if len(ks) == count:
            break
    return ks


def _phase_uniform(phi) -> bool:
    h, _ = np.histogram(np.mod(phi, TWO_PI), bins=12, range=(0, TWO_PI))
    return h.max() > 0 and h.min() / h.max() >= UNIFORM_MIN_RATIO


def _tiles(shape, mask, n=4):
    H, W = shape
    ty = np.minimum(np.arange(H) * n // H, n - 1)
    tx = np.minimum(np.arange(W) * n // W, n - 1)
    return (ty[:, None] * n + tx[None, :])[mask]


def _normal_equations(J, d, Q, ks, tile, n_tiles, harm=None, chunk=8192):
    from threadpoolctl import threadpool_limits

    with threadpool_limits(1):       # many small products: BLAS threads only contend (20x slower on a busy machine)
        return _normal_equations_1(J, d, Q, ks, tile, n_tiles, harm, chunk)


def _normal_equations_1(J, d, Q, ks, tile, n_tiles, harm, chunk):
    """Per-tile normal equations of the residual regression (module docstring) at the sampled
    pixels: J (N, n) frames, ``tile`` (n,) sorted tile indices, ``harm`` (2K,) the previous
    pass's harmonic amplitudes (the gains multiply the whole waveform); returns XtX (T, p, p),
    Xty (T, p)."""
    N, n = J.shape
    P3 = least_squares_weights(d)
    M = np.stack([np.ones(N), np.cos(d), np.sin(d)], 1)
    coef = P3 @ J                                       # (3, n)
    F = M @ coef                                        # (N, n) fitted sinusoid
    B = np.hypot(coef[1], coef[2])
    phi = np.arctan2(coef[2], coef[1])
    r = Q @ J                                           # (N, n) residual
    p = 2 * N + 2 * len(ks)
    XtX = np.zeros((n_tiles, p, p))
    Xty = np.zeros((n_tiles, p))
    for k in np.unique(tile):                           # tile: sorted, each tile a contiguous run
        lo, hi = np.searchsorted(tile, [k, k + 1])
        for s in range(lo, hi, chunk):
            sl = slice(s, min(s + chunk, hi))
            m = sl.stop - sl.start
            X = np.empty((m, N, p))
            X[:, :, :N] = Q[None]
            Fm = F[:, sl].T                                   # (m, N)
            if ks:
                arg = np.array(ks)[None, None, :] * (phi[sl][:, None, None] - d[None, :, None])   # (m, N, K)
                Hm = np.concatenate([np.cos(arg), np.sin(arg)], 2) * B[sl][:, None, None]
                X[:, :, 2 * N:] = np.matmul(Q, Hm)
                if harm is not None:
                    Fm = Fm + Hm @ harm
            np.multiply(Q[None], Fm[:, None, :], out=X[:, :, N:2 * N])
            X2 = X.reshape(-1, p)
            XtX[k] += X2.T @ X2
            Xty[k] += X2.T @ r[:, sl].T.reshape(-1)
    return XtX, Xty


def _solve(XtX, Xty):
    """Minimum-norm solution (of the column-scaled system); the gauge directions (o in span{1,
    cos, sin}, the mean gain) are exact null directions, fixed again by the caller."""
    # columns scaled to unit diagonal first: offsets (grey) and gains (x F^2) differ by ~F^2, 1e9
    # for 16-bit frames, and an unscaled cut-off would drop the offsets
    dg = np.diag(XtX)
    D = np.where(dg > 0, 1.0 / np.sqrt(np.where(dg > 0, dg, 1.0)), 0.0)
    A = XtX * D[:, None] * D[None, :]
    return D * (np.linalg.pinv(A, rcond=1e-9, hermitian=True) @ (D * Xty))


def _jackknife(XtX_t, Xty_t, keep):
    tot_A, tot_b = XtX_t[keep].sum(0), Xty_t[keep].sum(0)
    full = _solve(tot_A, tot_b)
    idx = np.flatnonzero(keep)
    if idx.size < 3:
        return full, np.full_like(full, np.nan)
    loo = np.stack([_solve(tot_A - XtX_t[t], tot_b - Xty_t[t]) for t in idx])
    T = idx.size
    return full, np.sqrt((T - 1) / T * ((loo - loo.mean(0)) ** 2).sum(0))


def _gaussian_lowpass(x, m, sigma):
    import cv2

    k = int(min(2 * round(3 * sigma) + 1, 2 * (min(x.shape) // 2) - 1))
    num = cv2.GaussianBlur(np.where(m, x, 0.0), (k, k), sigma, borderType=cv2.BORDER_CONSTANT)
    den = cv2.GaussianBlur(m.astype(np.float64), (k, k), sigma, borderType=cv2.BORDER_CONSTANT)
    return num / np.maximum(den, 1e-12), den


def _first_harmonic(J, d, mask, tile_img, reference_phase, uniform):
    """z_o (complex grey), its jackknife std, how (module docstring, (a) - (c))."""
    P3 = least_squares_weights(d)
    C = np.tensordot(P3[1], J, 1)
    S = np.tensordot(P3[2], J, 1)
    Z = C + 1j * S
    if reference_phase is not None:
        ref = np.asarray(reference_phase, dtype=np.float64)
        m = mask & np.isfinite(ref)
        if m.sum() < MIN_PIXELS:
            return None, None, f"not identified: {int(m.sum())} pixels with a reference phase (< {MIN_PIXELS})"
        e = np.exp(-1j * ref[m])
        y = (Z[m] * e).imag
        X = np.stack([e.imag, (1j * e).imag], 1)            # a (-sin phi), b (cos phi)
        t = tile_img[m]
        sols, ab = [], np.linalg.lstsq(X, y, rcond=None)[0]
        for k in np.unique(t):
            w = t != k
            sols.append(np.linalg.lstsq(X[w], y[w], rcond=None)[0])
        sols = np.array(sols)
        T = len(sols)
        std = float(np.sqrt((T - 1) / T * ((sols - sols.mean(0)) ** 2).sum(0).sum() / 2)) if T >= 3 else None
        return complex(ab[0], ab[1]), std, "reference phase"
    if not uniform:
        return None, None, "not identified: the phases do not cover the period evenly (give a reference phase)"
    phi = np.angle(Z)
    gy, gx = np.gradient(np.unwrap(np.unwrap(phi, axis=0), axis=1))
    grad = np.hypot(gx, gy)[mask]
    period = TWO_PI / max(float(np.median(grad)), 1e-9)
    if not np.isfinite(period) or period > min(J.shape[1:]) / 6:
        return None, None, f"not identified: a fringe period of {period:.0f} px is too long for the spatial low-pass"
    lo_re, den = _gaussian_lowpass(Z.real, mask, period)
    lo_im, _ = _gaussian_lowpass(Z.imag, mask, period)
    inner = mask & (den > 0.9)
    if inner.sum() < MIN_PIXELS:
        return None, None, f"not identified: {int(inner.sum())} pixels inside well-modulated areas for the low-pass"
    lo = (lo_re + 1j * lo_im)[inner]
    z = complex(np.median(lo.real), np.median(lo.imag))
    t = tile_img[inner]
    loo = np.array([complex(np.median(lo.real[t != k]), np.median(lo.imag[t != k])) for k in np.unique(t)])
    T = loo.size
    std = float(np.sqrt((T - 1) / T * (np.abs(loo - loo.mean()) ** 2).sum() / 2)) if T >= 3 else None
    return z, std, "spatial low-pass"


def _usable(I, coef, min_modulation, saturation, valid):
    """(mask, count) of the pixels the regression may use; FrameJitterError when too few."""
    B = np.hypot(coef[1], coef[2])
    mask = (B >= min_modulation) & np.all(np.isfinite(I), 0)
    if saturation is not None:
        mask &= I.max(0) < saturation
    if valid is not None:
        mask &= np.asarray(valid, dtype=bool)
    n_px = int(mask.sum())
    if n_px < MIN_PIXELS:
        raise FrameJitterError(f"{n_px} pixels with modulation >= {min_modulation} grey: the per-frame fluctuation "
                               f"needs at least {MIN_PIXELS}")
    return mask, n_px


def _solve_tiles(XtX, Xty, N, gains):
    """Solution and jackknife errors of the stacked normal equations; without ``gains`` the gain
    columns are left out (0 +- 0)."""
    keep = np.array([np.trace(a) > 0 for a in XtX])
    if gains:
        return _jackknife(XtX, Xty, keep)
    cols = np.r_[0:N, 2 * N:XtX.shape[1]]
    s_, sd_ = _jackknife(XtX[:, cols][:, :, cols], Xty[:, cols], keep)
    sol, std = np.zeros(XtX.shape[1]), np.zeros(XtX.shape[1])
    sol[cols], std[cols] = s_, sd_
    return sol, std


def estimate_frame_jitter(frames, shifts, *, valid=None, min_modulation: float = 3.0, saturation: float | None = None,
                          harmonics: int = 3, reference_phase=None, max_pixels: int = 50_000, iterations: int = 3,
                          seed: int = 0, gains: bool | None = None,
                          first_harmonic: bool = True) -> FrameJitter:
    """Per-frame offsets and gains of one fringe set (module docstring).

    ARGUMENTS
    - frames: (N, H, W) (or (N, H, W, 3)) intensities, grey levels; shifts: (N,) delta_n (rad,
      :mod:`unwrap.phase_shift`'s convention ``I = A + B cos(phi - delta)``), N >= 4.
    - valid: optional (H, W) bool; min_modulation: B (grey) a pixel needs; saturation: frames
      reaching it are left out (default: none).
    - harmonics: harmonics of the shared waveform in the model (0: none; then the phases must cover
      the period evenly); reference_phase: optional (H, W) phase of this set's fringe known by
      other means (rad, NaN where unknown), to identify the first harmonic.
    - max_pixels: pixels sampled for the residual regression; iterations: Gauss-Newton passes;
      gains: False fits offsets only (gains 1); None (default): gains only where the phases cover
      the period evenly (at a low frequency the gains' signature is collinear with the harmonics':
      on the real pyramid's unit sets they came out at +-30 % with jackknife errors as large);
      first_harmonic: False skips (a) - (b) (the size ``sigma`` alone: a cheap diagnosis).

    RETURNED VALUE: :class:`FrameJitter`. Raises :class:`FrameJitterError` when N < 4, when fewer
    than ``MIN_PIXELS`` pixels qualify, and when the phases are uneven and ``harmonics`` is 0.
    """
    I, d = _check_stack(frames, shifts)
    N, H, W = I.shape
    P3 = least_squares_weights(d)
    M = np.stack([np.ones(N), np.cos(d), np.sin(d)], 1)
    Q = np.eye(N) - M @ P3
    coef = np.tensordot(P3, I, 1)
    mask, n_px = _usable(I, coef, min_modulation, saturation, valid)
    phi = np.arctan2(coef[2], coef[1])
    uniform = _phase_uniform(phi[mask])
    if not uniform and harmonics <= 0:
        raise FrameJitterError("the phases of the well-modulated pixels do not cover the period evenly (a low "
                               "frequency?): per-frame offsets are confounded with the waveform's harmonics; "
                               "use harmonics > 0")
    ks = _harmonic_orders(N, harmonics) if harmonics > 0 else []
    gains = uniform if gains is None else bool(gains)
    tile_img = _tiles((H, W), np.ones((H, W), bool)).reshape(H, W)
    flat = np.flatnonzero(mask)
    rng = np.random.default_rng(seed)
    pick = rng.choice(flat, max_pixels, replace=False) if flat.size > max_pixels else flat
    pick = pick[np.argsort(tile_img.reshape(-1)[pick], kind="stable")]
    Is, tile = I.reshape(N, -1)[:, pick], tile_img.reshape(-1)[pick]
    o, g = np.zeros(N), np.ones(N)
    sol, std, z = None, None, None
    for _ in range(max(1, iterations)):
        # the first harmonic's leak into the fitted phases (and so into the harmonic regressors)
        # is removed by estimating it in the same loop
        o1 = o + (M[:, 1:] @ np.array([z.real, z.imag]) if z is not None else 0.0)
        J = (Is - o1[:, None]) / g[:, None]
        XtX, Xty = _normal_equations(J, d, Q, ks, tile, 16, None if sol is None else sol[2 * N:])
        sol, std = _solve_tiles(XtX, Xty, N, gains)
        o = o + g * sol[:N]
        g = g * (1 + sol[N:2 * N])
        o, g = Q @ o / g.mean(), g / g.mean()
        z, z_std, how = (_first_harmonic((I - o[:, None, None]) / g[:, None, None], d, mask, tile_img,
                                         reference_phase, uniform) if first_harmonic
                         else (None, None, "not identified: not asked for"))
    if z is not None and z_std is not None and abs(z) < SIGNIFICANT * z_std:
        how = (f"not significant: |z_o| = {abs(z):.3g} +- {z_std:.3g} grey by the {how} (< {SIGNIFICANT:g} standard "
               "errors across tiles)")
        z = None
    background = float(np.median(coef[0][mask]))
    modulation = float(np.median(np.hypot(coef[1], coef[2])[mask]))
    if not background >= MIN_BACKGROUND * modulation:
        # intensities are >= 0, so A >= B at every pixel (up to noise); a background far below the
        # modulation (0 up to rounding for zero-centred frames) is no intensity to scale by
        raise FrameJitterError(f"the median background of the {n_px} well-modulated pixels is {background:.3g} grey, "
                               f"below {MIN_BACKGROUND:g} x their median modulation {modulation:.3g}: not intensities "
                               "(zero-centred or over-subtracted frames?); a fluctuation relative to the background is "
                               "undefined")
    offsets = o + (M[:, 1:] @ np.array([z.real, z.imag]) if z is not None else 0.0)
    o_std = np.abs(g) * std[:N]
    harm = {k: complex(sol[2 * N + i], sol[2 * N + len(ks) + i]) for i, k in enumerate(ks)}
    return FrameJitter(d, offsets, o_std, g, std[N:2 * N], z, z_std, how,
                       float(np.linalg.norm(o) / math.sqrt(N - 3)), background, n_px, uniform,
                       harm)


def correct_frames(frames, jitter: FrameJitter) -> np.ndarray:
    """(N, H, W) float64 frames with the estimated offsets subtracted and gains divided out.
    Only ``gains`` and the first harmonic (when identified) change the N-step phase; ``o_perp``
    is invisible to it."""
    I, _ = _check_stack(frames, jitter.shifts)
    return (I - jitter.offsets[:, None, None]) / jitter.gains[:, None, None]


def predicted_bias(A, B, phase, jitter: FrameJitter) -> np.ndarray:
    """Phase bias (rad, wrapped to (-pi, pi]) the estimated offsets and gains cause at pixels of
    background ``A``, modulation ``B`` (grey) and phase ``phase`` (rad), any equal shapes: the
    N-step phase of ``o_n + g_n (A + B cos(phase - delta_n))`` minus ``phase``. Exact (not a
    linearisation); the unidentified first harmonic (``first_harmonic`` None) counts as 0: see
    :func:`expected_bias_rms`."""
    A, B, ph = (np.asarray(x, dtype=np.float64) for x in (A, B, phase))
    P3 = least_squares_weights(jitter.shifts)
    w = (P3[1] + 1j * P3[2]) * jitter.gains                        # (N,) demodulation of g_n F_n
    e = np.exp(1j * ph)
    # sum_n w_n (A + B/2 (e^{i(phi - d)} + e^{-i(phi - d)})) + sum_n (P3[1] + i P3[2]) o_n
    ed = np.exp(-1j * jitter.shifts)
    z = (A * w.sum() + 0.5 * B * (e * (w * ed).sum() + np.conj(e) * (w * np.conj(ed)).sum())
         + ((P3[1] + 1j * P3[2]) * jitter.offsets).sum())
    return np.angle(z * np.conj(e))


def expected_bias_rms(B, jitter: FrameJitter) -> float:
    """RMS phase bias (rad) over pixels of modulation ``B`` (grey, any shape) that independent
    per-frame offsets of RMS ``jitter.sigma`` cause through their first harmonic, in expectation:
    ``sigma * sqrt(g / B^2)`` with ``g`` :func:`unwrap.phase_shift.phase_noise_gain` (2 / N for
    equal shifts): the unit phase's bias when ``first_harmonic`` is not identified."""
    from .phase_shift import phase_noise_gain

    B = np.asarray(B, dtype=np.float64)
    B = B[np.isfinite(B) & (B > 0)]
    return float(jitter.sigma * math.sqrt(phase_noise_gain(jitter.shifts) * np.mean(1.0 / B ** 2))) if B.size else \
        float("nan")


def jitter_line(jitters: dict, top_frequency: float | None = None, threshold: float = WARN_FRACTION) -> str | None:
    """One diagnostic line when a capture's frames fluctuate by more than ``threshold`` of the
    background (``jitters``: {label: FrameJitter}); None otherwise. ``top_frequency``: the
    bias of the unit phase is also stated in periods of that frequency."""
    worst = max(jitters.items(), key=lambda kv: kv[1].sigma_rel, default=None)
    if worst is None or worst[1].sigma_rel <= threshold:
        return None
    label, j = worst
    # the bias of a unit set with the same N and fluctuation: sigma * sqrt(2 / N) / B
    bias = math.sqrt(2 / j.shifts.size) * j.sigma_rel
    line = (f"frames fluctuate: per-frame offsets of {100 * j.sigma_rel:.1f} % of the background RMS ({label}; "
            f"> {100 * threshold:.0f} %), an expected coherent coarse-phase bias of {bias:.3f} rad x (A / B) RMS "
            "(unwrap.frame_jitter)")
    if top_frequency:
        line += f", i.e. {top_frequency * bias / TWO_PI:.3f} periods of f = {top_frequency:g} x (A / B)"
    return line


def capture_jitters(folder, preset=None, pose=None) -> tuple:
    """The per-frame fluctuation of the highest-frequency set with N >= 4 of every orientation of a
    capture (on a grid of ~150000 pixels, 8000 of them sampled, one pass, 2 harmonics, no first
    harmonic): ``(jitters, top, unmeasured)``: {"v, f = 48": FrameJitter}, the capture's top
    frequency (None when no set qualifies) and ["v: why", ...] for each orientation (or the
    capture) that could not be measured. Never raises for the capture's content."""
    from .capture import load_capture, read_stack

    try:
        cap = load_capture(folder, preset, pose)
    except (UnwrapError, OSError) as exc:
        return {}, None, [f"capture: {exc}"]
    jitters, top, unmeasured = {}, None, []
    for o, oc in cap.orientations.items():
        sets = [s for s in oc.sets if len(s.files) >= 4]
        if not sets:
            unmeasured.append(f"{o}: no fringe set of >= 4 steps (with 3 every pixel's fit is exact)")
            continue
        s = max(sets, key=lambda s: s.frequency)
        top = max(top or 0.0, max(x.frequency for x in oc.sets))
        try:
            I = read_stack(s.files)
        except (UnwrapError, OSError) as exc:
            unmeasured.append(f"{o}, f = {s.frequency:g}: {exc}")
            continue
        step = max(1, int(math.sqrt(I.shape[1] * I.shape[2] / 150_000)))   # a sparse grid: the offsets are global
        I = I[:, ::step, ::step]
        sat = 0.98 * float(np.iinfo(I.dtype).max) if I.dtype.kind in "ui" else None
        try:
            jitters[f"{o}, f = {s.frequency:g}"] = estimate_frame_jitter(
                I, s.shifts, saturation=sat, harmonics=2, max_pixels=8000, iterations=1, first_harmonic=False)
        except FrameJitterError as exc:
            unmeasured.append(f"{o}, f = {s.frequency:g}: {exc}")
    return jitters, top, unmeasured


def capture_jitter_line(folder, preset=None, pose=None, threshold: float = WARN_FRACTION) -> str | None:
    """``calib unwrap``'s diagnosis line (:func:`jitter_line` of :func:`capture_jitters`): None when
    the fluctuation is below ``threshold`` or when no set could be measured."""
    jitters, top, _ = capture_jitters(folder, preset, pose)
    return jitter_line(jitters, top, threshold)


def frame_check(folder, preset=None, pose=None, threshold: float = WARN_FRACTION) -> str:
    """``calib unwrap --check-frames``'s line, which always says one of three things: the frames
    fluctuate (:func:`jitter_line`), they are steady (the largest fluctuation measured, below
    ``threshold``), or they could not be measured (why) - never "steady" for what was not measured."""
    jitters, top, unmeasured = capture_jitters(folder, preset, pose)
    line = jitter_line(jitters, top, threshold)
    if line is None and jitters:
        label, j = max(jitters.items(), key=lambda kv: kv[1].sigma_rel)
        line = (f"frames steady: per-frame offsets of {100 * j.sigma_rel:.2f} % of the background RMS ({label}; "
                f"<= {100 * threshold:.0f} %)")
    if unmeasured:
        why = "; ".join(unmeasured)
        line = f"{line}; not measured: {why}" if line else f"frames not measured: {why}"
    return line
