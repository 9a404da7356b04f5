"""The compiled lens inversion (calib._undistort_kernel) keeps the numpy reference's contract:
the same points to 1e-12 wherever a preimage exists, the same points flagged where none does,
NaN input flagged, with an analytic Jacobian equal to finite differences of ``distort``."""
import numpy as np
import pytest

from calib import ModelError, default_system
from calib.distortion import FAST_MIN_POINTS, distort, undistort, undistort_fast_available

pytestmark = pytest.mark.skipif(not undistort_fast_available(), reason="numba is not installed")


def _pixel_grid(size):
    W, H = size
    v, u = np.meshgrid(np.arange(H, dtype=np.float64), np.arange(W, dtype=np.float64), indexing="ij")
    return np.stack([u.ravel(), v.ravel()], axis=1)


def _random_model(rng, n):
    """A random n-term OpenCV model of a plausible lens (invertible over |xy| <= 0.4)."""
    scale = np.array([0.15, 0.05, 2e-3, 2e-3, 0.02, 0.05, 0.02, 0.01, 2e-3, 1e-3, 2e-3, 1e-3])
    return rng.uniform(-1, 1, 12)[:n] * scale[:n]


@pytest.mark.parametrize("device", ["camera", "projector"])
def test_fast_undistort_equals_the_reference_over_the_whole_image_of_the_real_system(device):
    dev = getattr(default_system(), device)
    xyd = dev.pixels_to_normalized(_pixel_grid(dev.size))
    xy_ref, ok_ref = undistort(xyd, dev.distortion, fast=False)
    xy, ok = undistort(xyd, dev.distortion)  # "auto": the kernel for an image's worth of points
    assert len(xyd) >= FAST_MIN_POINTS and ok_ref.all() and np.array_equal(ok, ok_ref)
    assert np.abs(xy - xy_ref).max() <= 1e-12
    assert np.abs(distort(xy, dev.distortion) - xyd).max() < 1e-12


@pytest.mark.parametrize("n_terms", [4, 5, 8, 12])
def test_fast_undistort_equals_the_reference_on_random_models(n_terms):
    rng = np.random.default_rng(n_terms)
    for _ in range(5):
        c = _random_model(rng, n_terms)
        xy_true = rng.uniform(-0.4, 0.4, size=(5000, 2))
        xyd = distort(xy_true, c)
        xy_ref, ok_ref = undistort(xyd, c, fast=False)
        xy, ok = undistort(xyd, c, fast=True)
        assert ok_ref.all() and ok.all()
        assert np.abs(xy - xy_ref).max() <= 1e-12 and np.abs(xy - xy_true).max() <= 1e-12


def test_analytic_jacobian_equals_finite_differences_of_distort():
    from calib._undistort_kernel import distort_jacobian_array

    rng = np.random.default_rng(3)
    h = 1e-6
    for _ in range(5):
        c = _random_model(rng, 12) * 3  # every term large enough to matter
        xy = rng.uniform(-0.5, 0.5, size=(2000, 2))
        out = np.empty((len(xy), 6))
        distort_jacobian_array(xy, c, out)
        np.testing.assert_allclose(out[:, :2], distort(xy, c), rtol=0, atol=1e-15)
        jx = (distort(xy + [h, 0], c) - distort(xy - [h, 0], c)) / (2 * h)
        jy = (distort(xy + [0, h], c) - distort(xy - [0, h], c)) / (2 * h)
        fd = np.stack([jx[:, 0], jy[:, 0], jx[:, 1], jy[:, 1]], axis=1)  # dxd/dx, dxd/dy, dyd/dx, dyd/dy
        assert np.abs(out[:, 2:] - fd).max() < 1e-8


def test_points_without_a_preimage_are_flagged_exactly_as_the_reference_flags_them():
    # rational model r / (1 + r^2) (k4 = 1): distorted radii above 1/2 have no preimage at all
    c = [0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0]
    g = np.linspace(-0.9, 0.9, 301)
    xyd = np.stack(np.meshgrid(g, g, indexing="ij"), -1).reshape(-1, 2)
    xy_ref, ok_ref = undistort(xyd, c, fast=False)
    xy, ok = undistort(xyd, c, fast=True)
    rd = np.linalg.norm(xyd, axis=1)
    assert not ok[rd > 0.5].any() and ok[rd < 0.49].all()
    assert np.array_equal(ok, ok_ref)
    assert np.abs(xy[ok] - xy_ref[ok]).max() <= 1e-12
    assert np.abs(distort(xy[ok], c) - xyd[ok]).max() < 1e-12


def test_folding_lens_agrees_inside_the_fold_and_returns_only_true_preimages_beyond_it():
    # barrel r (1 - 0.5 r^2) is monotone up to r = sqrt(2/3) (distorted radius 0.544) and folds
    # beyond: there a distorted point has several preimages (r > 0.816) and which one Newton
    # reaches, if any, depends on its path, so the two implementations may flag differently;
    # both return only points that distort back to the input
    c = [-0.5, 0.0, 0.0, 0.0]
    g = np.linspace(-0.9, 0.9, 301)
    xyd = np.stack(np.meshgrid(g, g, indexing="ij"), -1).reshape(-1, 2)
    xy_ref, ok_ref = undistort(xyd, c, fast=False)
    xy, ok = undistort(xyd, c, fast=True)
    inside = np.linalg.norm(xyd, axis=1) < 0.544
    assert ok[inside].all() and ok_ref[inside].all()
    assert np.abs(xy[inside] - xy_ref[inside]).max() <= 1e-12
    assert np.abs(distort(xy[ok], c) - xyd[ok]).max() < 1e-12
    assert np.abs(distort(xy_ref[ok_ref], c) - xyd[ok_ref]).max() < 1e-12


def test_non_finite_input_is_flagged_and_leaves_the_other_points_alone():
    dev = default_system().camera
    xyd = dev.pixels_to_normalized(_pixel_grid(dev.size))
    bad = np.arange(0, len(xyd), 997)
    xyd[bad, 0] = np.nan
    xyd[bad[::2], 1] = np.inf
    xy_ref, ok_ref = undistort(xyd, dev.distortion, fast=False)
    xy, ok = undistort(xyd, dev.distortion, fast=True)
    assert not ok[bad].any() and ok.sum() == len(xyd) - len(bad)
    assert np.array_equal(ok, ok_ref) and np.abs(xy[ok] - xy_ref[ok]).max() <= 1e-12


def test_fast_undistort_keeps_the_input_shape_and_refuses_bad_arguments():
    c = [-0.13, -0.56, -0.0014, -0.0004, 0.0]
    xy_true = np.random.default_rng(0).uniform(-0.2, 0.2, size=(3, 7, 2))
    xy, ok = undistort(distort(xy_true, c), c, fast=True)
    assert xy.shape == (3, 7, 2) and ok.shape == (3, 7) and ok.all()
    assert np.abs(xy - xy_true).max() <= 1e-12
    with pytest.raises(ModelError, match="fast must be"):
        undistort(xy_true, c, fast="yes")
    with pytest.raises(ModelError, match=r"\(\.\.\., 2\)"):
        undistort(np.zeros((4, 3)), c)
