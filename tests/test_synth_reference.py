"""Reference checks of the optional effects, each against something independent of the renderer:
Blender's thin-lens depth of field (camera defocus), closed forms (projector defocus: the
contrast of a fringe of period p under a Gaussian blur of sigma s is exp(-2 pi^2 s^2 / p^2) of
the sharp one; projector gamma: the N-step phase error of a gamma-distorted fringe from its
Fourier harmonics; vignetting: the cos^4 law from the true 3D points; quantisation: error RMS
step / sqrt 12) and statistics (Poisson-Gaussian noise)."""
import math
import sys

import numpy as np
import pytest
import torch

from synth import Plane, Scene, phase_sequence, render
from synth.effects.spec import Defocus, Effects, Noise
from synth.scenes.poses import rotation_xyz_deg
from synth.effects.sensor import add_noise, quantise
from synth.scenes.sequence import PatternSpec

from synth_helpers import nstep_phase, small_system, wrap


def _modulation(stack):
    from unwrap.phase_shift import wrapped_phase

    return np.asarray(wrapped_phase(np.asarray(stack, dtype=np.float64), saturation=None, fill_invalid=False).B)


# --- camera defocus: Blender's thin lens --------------------------------------------------------

@pytest.mark.blender
def test_camera_defocus_matches_blender_thin_lens_depth_of_field_up_to_the_gaussian_vs_disc_mtf():
    """Blender (Cycles, 32 samples, circular aperture 25 mm, focus 600 mm) blurs the fringes on a
    plane at 800-900 mm by the thin-lens disc; we blur by a Gaussian of the disc's second moment
    (sigma = c / 4). Their contrasts then differ exactly by the ratio of the two transfer
    functions at the local fringe frequency nu: exp(-2 pi^2 sigma^2 nu^2) / (2 J1(pi c nu) / (pi c nu)).
    (With sigma = c / (2 sqrt 2), the radial RMS, the ratio would be ~0.67 instead of ~1.04.)"""
    from scipy.special import j1

    from synth.blender_twin import blender_available
    from experiments.blender_parity import parity, parity_system
    from synth.renderer.truth import phase_truth

    if not blender_available(sys.executable):
        pytest.skip("bpy not installed (make test installs it)")
    aperture, focus = 25.0, 600.0
    r = parity("plane", scale=4, steps=4, frequency=24, python=sys.executable,
               camera_defocus=Defocus(aperture, focus, 8), samples=32)
    g = r["geometry"]
    H, W = r["mask"].shape
    f_px = parity_system(4).camera.fx
    depth = g.depth.reshape(H, W).numpy()
    Phi, _, valid = phase_truth(g, (912, 1140), "v", 24)
    gy, gx = np.gradient(np.where(valid, Phi, np.nan))
    nu = np.hypot(gx, gy) / (2 * np.pi)                        # cycles per camera pixel
    c = aperture * f_px * np.abs(1 / depth - 1 / focus)        # blur disc diameter (px)
    x = np.pi * c * nu
    predicted = np.exp(-2 * np.pi ** 2 * (c / 4) ** 2 * nu ** 2) / (2 * j1(x) / x)
    m = r["mask"].copy()
    m[:6], m[-6:], m[:, :6], m[:, -6:] = False, False, False, False  # blur reaches the image border
    m &= np.isfinite(predicted)
    measured = r["amp_ours"][m] / r["amp_blender"][m]
    rel = measured / predicted[m] - 1
    print(f"camera defocus vs Blender DOF: c {c[m].min():.2f}-{c[m].max():.2f} px, contrast ratio ours/Blender "
          f"median {np.median(measured):.4f}, predicted {np.median(predicted[m]):.4f}, "
          f"rel. error median {np.median(rel):+.4f}, 5-95 % [{np.percentile(rel, 5):+.4f}, "
          f"{np.percentile(rel, 95):+.4f}], {m.sum()} px; MAD {r['mad_8bit']:.2f} levels")
    assert m.sum() > 10000
    assert np.median(c[m]) > 5 and np.median(measured) > 1.02  # strong blur: shapes differ visibly
    assert abs(np.median(rel)) < 0.01
    assert np.percentile(np.abs(rel), 90) < 0.05  # Cycles' 32-sample noise


# --- projector defocus: closed form --------------------------------------------------------------

@pytest.mark.parametrize("sampling, tol", [("analytic", 1e-6), ("bilinear", 1e-2)])
def test_projector_defocus_attenuates_fringe_contrast_by_exp_minus_2pi2_s2_over_p2(sampling, tol):
    """A plane tilted 55 deg through the focus distance: sigma goes from 0 to ~2.7 projector px
    with depth. The contrast (N-step modulation) of each pixel, defocused over sharp, equals
    exp(-2 pi^2 s^2 / p^2) with p = W_p / f and s = c / 4 from the true projector depth. The
    bilinear route blurs the projector image itself (kornia, interpolated blur levels)."""
    system = small_system(4)
    prj = system.projector
    aperture, focus, f = 25.0, 820.0, 48
    seq = phase_sequence(("v",), (f,), 4)
    plane = [Plane("p", rotation_xyz_deg([0, 55, 0]), [0, 0, 0])]
    sharp = render(Scene(system, plane, seq, Effects(fringe_sampling=sampling)), quantised=False)
    blur = render(Scene(system, plane, seq, Effects(fringe_sampling=sampling,
                                                    projector_defocus=Defocus(aperture, focus, 6))), quantised=False)
    lit = blur.geometry.lit.numpy()
    z = blur.geometry.z_prj.numpy()[lit]
    s = aperture * prj.fx * np.abs(1 / z - 1 / focus) / 4
    predicted = np.exp(-2 * np.pi ** 2 * s ** 2 / (prj.width / f) ** 2)
    ratio = (_modulation(blur.images.numpy()).ravel()[lit] / _modulation(sharp.images.numpy()).ravel()[lit])
    rel = np.abs(ratio / predicted - 1)
    print(f"projector defocus ({sampling}): sigma {s.min():.3f}-{s.max():.2f} px, contrast {predicted.min():.3f}-"
          f"{predicted.max():.3f}, max rel. error {rel.max():.2e}")
    assert s.min() < 0.05 and s.max() > 2.0 and predicted.min() < 0.8
    assert rel.max() < tol


# --- projector gamma: harmonic formula -----------------------------------------------------------

def _gamma_phase_error(Phi, N, gamma, A=0.5, B=0.5):
    """N-step phase error of I_n = (A + B cos(Phi - 2 pi n/N))^gamma. With the cosine series
    (A + B cos t)^gamma = sum_k b_k cos(k t), sum_n I_n sin d_n = N/2 sum_k b_k sin(k Phi)
    ([k = 1 mod N] - [k = -1 mod N]) and sum_n I_n cos d_n = N/2 sum_k b_k cos(k Phi)
    ([k = 1 mod N] + [k = -1 mod N]): only harmonics k = mN +- 1 reach the phase."""
    M = 4096
    t = 2 * np.pi * np.arange(M) / M
    b = 2 * np.fft.rfft((A + B * np.cos(t)) ** gamma).real / M
    S = np.zeros_like(Phi)
    C = np.zeros_like(Phi)
    for k in range(1, 200):
        plus, minus = k % N == 1, k % N == N - 1
        S += b[k] * np.sin(k * Phi) * (plus - minus)
        C += b[k] * np.cos(k * Phi) * (plus + minus)
    return wrap(np.arctan2(S, C) - Phi)


@pytest.mark.parametrize("N, gamma", [(3, 2.2), (4, 2.2), (4, 0.6), (12, 2.2)])
def test_projector_gamma_phase_error_equals_the_harmonic_formula(N, gamma):
    system = small_system(4)
    f = 8
    seq = phase_sequence(("v",), (f,), N)
    res = render(Scene(system, [Plane("p", np.eye(3), [0, 0, 0])], seq, Effects(projector_gamma=gamma)),
                 quantised=False)
    Phi, _, valid = res.truth((912, 1140), seq)["v"][8.0]
    err = wrap(nstep_phase(res.images.numpy()) - Phi)[valid]
    predicted = _gamma_phase_error(Phi[valid], N, gamma)
    diff = np.abs(wrap(err - predicted))
    print(f"gamma {gamma}, N {N}: phase error up to {np.abs(predicted).max():.2e} rad; "
          f"measured - predicted max {diff.max():.1e} rad")
    if N < 12:
        assert np.abs(predicted).max() > 0.005  # a visible effect the check would miss if gamma were dropped
    assert diff.max() < 2e-5  # float32 images


# --- vignetting: cos^4 -------------------------------------------------------------------------

def test_vignetting_follows_the_cos4_law_of_the_true_ray_angle():
    """White light, vignetting strength s: image / image without vignetting = 1 - s (1 - cos^4 theta),
    theta the angle between the pixel's ray and the optical axis, from the true 3D points (the
    system has lens distortion: theta is that of the undistorted ray)."""
    system = small_system(4)
    white = [PatternSpec("white", "white")]
    plane = [Plane("p", np.eye(3), [0, 0, 0])]
    s = 0.7
    a = render(Scene(system, plane, white, Effects(vignetting=s)), quantised=False)
    b = render(Scene(system, plane, white, Effects()), quantised=False)
    lit = a.geometry.lit.numpy()
    p = a.geometry.points_cam.numpy()[lit]
    cos_theta = p[:, 2] / np.linalg.norm(p, axis=1)
    ratio = a.images.numpy()[0].ravel()[lit] / b.images.numpy()[0].ravel()[lit]
    expected = 1 - s * (1 - cos_theta ** 4)
    print(f"vignetting: factor {expected.min():.4f}-{expected.max():.4f}, max error {np.abs(ratio - expected).max():.1e}")
    assert expected.min() < 0.97
    np.testing.assert_allclose(ratio, expected, rtol=1e-6)


# --- gain, saturation, quantisation ------------------------------------------------------------

@pytest.mark.parametrize("bits", [8, 10, 12, 16])
def test_gain_saturation_and_quantisation_follow_the_closed_form(bits):
    rng = np.random.default_rng(bits)
    v = rng.uniform(-0.1, 1.2, 200_000).astype(np.float32)
    gain, sat = 1.3, 0.9
    top = 2 ** bits - 1
    q = quantise(torch.tensor(v), bits, gain, sat).numpy().astype(np.int64)
    expected = np.round(np.clip(v.astype(np.float64) * gain, 0, sat) * top)
    assert np.abs(q - expected).max() <= 1  # float32 rounding at exact half-steps
    assert (q != expected).mean() < 2.0 ** (bits - 22)
    assert q.max() == round(sat * top) and q.min() == 0
    # within range, the quantisation error is uniform over one step: RMS = step / sqrt(12)
    inside = (v * gain > 0.01) & (v * gain < sat - 0.01)
    e = q[inside] / top - v[inside].astype(np.float64) * gain
    rms = np.sqrt(np.mean(e ** 2)) * top
    print(f"{bits} bits: quantisation error RMS {rms:.4f} steps (1/sqrt 12 = {1 / math.sqrt(12):.4f})")
    assert abs(rms * math.sqrt(12) - 1) < 0.01


# --- Poisson-Gaussian noise ---------------------------------------------------------------------

@pytest.mark.parametrize("engine", ["cpu kernel", "torch"])
@pytest.mark.parametrize("value, full_well, read", [(0.3, 10000.0, 5.0), (0.002, 10000.0, 5.0), (0.0003, 10000.0, 0.0),
                                                    (0.0, 10000.0, 5.0)])
def test_poisson_gaussian_noise_has_mean_e_and_variance_e_plus_read_squared(value, full_well, read, engine):
    """In electrons e = value * full_well: mean e, variance e + read^2 (shot noise exact Poisson
    below 50 e-: with no read noise the counts are integers with P(0) = exp(-e)); for the CPU
    kernel (its own random numbers) and the torch version alike."""
    from synth.effects.sensor import _add_noise_torch

    if engine == "cpu kernel":
        _noise_kernel()
    n = 400_000
    gen = torch.Generator().manual_seed(1)
    noisy = add_noise if engine == "cpu kernel" else _add_noise_torch
    out = noisy(torch.full((n,), value, dtype=torch.float32), Noise(full_well, read), gen).numpy()
    e = out.astype(np.float64) * full_well
    mean_e = value * full_well
    var = mean_e + read ** 2
    print(f"e = {mean_e:g}, read {read}: mean {e.mean():.4f}, variance {e.var():.4f} (expected {var:g})")
    assert abs(e.mean() - mean_e) < 5 * math.sqrt(var / n)
    assert abs(e.var() / var - 1) < 5 * math.sqrt(2 / n) * 1.5
    if read == 0:
        assert np.allclose(e, np.round(e), atol=1e-3)
        p0 = np.mean(np.round(e) == 0)
        assert abs(p0 - math.exp(-mean_e)) < 5 * math.sqrt(p0 * (1 - p0) / n)


def _noise_kernel():
    from synth.effects.sensor import _noise_kernel_available

    if not _noise_kernel_available():
        pytest.skip("numba is not installed")
    from synth.effects import _noise_kernel
    return _noise_kernel


def test_kernel_normal_deviates_are_standard_normal_in_moments_tails_and_distribution():
    """The CPU noise pass draws its own normals (ziggurat, splitmix64 streams per block): their
    moments, the tail beyond the ziggurat's R = 3.44 (a separate branch), a Kolmogorov-Smirnov
    test and the correlation at lag 1 and across blocks are those of N(0, 1)."""
    from scipy import stats

    K = _noise_kernel()
    n = 4_000_000
    z = np.empty(n)
    K.normal_array(np.uint64(20240611), z, K.ZIG_X, K.ZIG_RATIO)
    se = 1 / math.sqrt(n)
    assert abs(z.mean()) < 5 * se and abs(z.var() - 1) < 5 * math.sqrt(2) * se
    assert abs(stats.skew(z)) < 5 * math.sqrt(6) * se and abs(stats.kurtosis(z)) < 5 * math.sqrt(24) * se
    for a in (1.0, 2.0, 3.0, K._ZIG_R, 4.0):
        p = 2 * stats.norm.sf(a)
        assert abs(np.mean(np.abs(z) > a) - p) < 5 * math.sqrt(p * (1 - p) / n), a
    assert stats.kstest(z[:1_000_000], "norm").pvalue > 1e-3
    for lag in (1, K.BLOCK):
        assert abs(np.corrcoef(z[:-lag], z[lag:])[0, 1]) < 5 * se
    z2 = np.empty(n)
    K.normal_array(np.uint64(20240612), z2, K.ZIG_X, K.ZIG_RATIO)
    assert abs(np.corrcoef(z, z2)[0, 1]) < 5 * se  # neighbouring seeds: independent streams


@pytest.mark.parametrize("lam", [0.3, 3.0, 20.0, 49.9])
def test_kernel_poisson_counts_follow_the_poisson_law(lam):
    from scipy import stats

    K = _noise_kernel()
    n = 1_000_000
    k = np.empty(n, dtype=np.int64)
    K.poisson_array(np.uint64(99), lam, k)
    top = int(lam + 6 * math.sqrt(lam) + 6)
    observed = np.bincount(np.minimum(k, top), minlength=top + 1)
    expected = stats.poisson.pmf(np.arange(top + 1), lam) * n
    expected[-1] = stats.poisson.sf(top - 1, lam) * n
    keep = expected > 20
    chi2 = ((observed[keep] - expected[keep]) ** 2 / expected[keep]).sum()
    assert stats.chi2.sf(chi2, keep.sum() - 1) > 1e-3
    assert abs(k.mean() - lam) < 5 * math.sqrt(lam / n)


def test_cpu_noise_is_reproducible_independent_of_threads_and_keeps_nan_and_dark_pixels():
    import numba

    _noise_kernel()
    img = torch.rand((4, 120, 160), generator=torch.Generator().manual_seed(3), dtype=torch.float32)
    img[0, :10] = float("nan")
    img[1] = -0.5  # clamps to 0: read noise only
    runs = []
    before = numba.get_num_threads()
    try:
        for threads in (1, before):
            numba.set_num_threads(threads)
            runs.append(add_noise(img.clone(), Noise(), torch.Generator().manual_seed(8)))
    finally:
        numba.set_num_threads(before)
    a, b = runs
    assert torch.equal(torch.isnan(a), torch.isnan(b)) and torch.equal(a[~torch.isnan(a)], b[~torch.isnan(b)])
    assert bool(torch.isnan(a[0, :10]).all()) and not bool(torch.isnan(a[1:]).any())
    dark = a[1].double() * 1e4  # N(0, 5^2) electrons
    assert abs(float(dark.mean())) < 5 * 5 / math.sqrt(dark.numel()) and abs(float(dark.std()) / 5 - 1) < 0.02
    c = add_noise(img.clone(), Noise(), torch.Generator().manual_seed(9))
    assert not torch.equal(c[1:], a[1:])  # another seed, another draw


# --- the fused fast path equals the staged path ------------------------------------------------

@pytest.mark.parametrize("ambient, gamma", [(0.0, 1.0), (0.05, 2.2)])
def test_fused_pattern_and_quantisation_stage_equals_quantising_the_linear_images(ambient, gamma):
    """Without camera defocus or noise the renderer quantises chunks of lit pixels as it computes
    them; that must equal quantising the full linear stack (Gray code and white included)."""
    from synth import Sphere, gray_sequence

    system = small_system(4)
    seq = phase_sequence(("v",), (8,), 4) + gray_sequence("v", (912, 1140), 4) + [PatternSpec("white", "white")]
    objs = [Plane("wall", np.eye(3), [0, 0, -60]), Sphere("ball", np.eye(3), [0, 0, 0], radius_mm=30)]
    eff = Effects(ambient=ambient, projector_gamma=gamma, gain=1.2, saturation=0.95, bits=10)
    fused = render(Scene(system, objs, seq, eff))
    staged = render(Scene(system, objs, seq, eff), keep_linear=True, geometry=fused.geometry)  # not fused
    assert any("fused" in line for line in fused.plan) and not any("fused" in line for line in staged.plan)
    assert int(fused.images.max()) > 500 and bool(fused.geometry.shadow.any())
    assert torch.equal(fused.images, staged.images)
