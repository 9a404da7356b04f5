"""unwrap.reliability.plane_residual_noise reads a known noise back from the centre pixel's plane
residual (the factor sqrt(n / (n - 1)) of plane_centre_dof, not the window's sqrt(n / (n - 3)))."""
import math

import numpy as np
import pytest
import torch

from unwrap.errors import UnwrapError
from unwrap.learned.smoothing import smooth_phase
from unwrap.reliability import plane_centre_dof, plane_residual_noise


def _interior_residuals(sigma, window, shape=(400, 400), seed=0):
    """Residuals of a tilted plane plus white noise ``sigma`` (rad) from the least-squares plane of
    each pixel's ``window`` box (the estimator's own smoothing), interior pixels only."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:shape[0], 0:shape[1]].astype(np.float64)
    Phi = 0.3 * x + 0.11 * y + 2.0 + rng.normal(0.0, sigma, shape)
    ok = torch.ones(shape, dtype=torch.bool)[None, None]
    P = torch.from_numpy(Phi)[None, None]
    r = (P - smooth_phase(P, ok, window, "plane"))[0, 0].numpy()
    h = window // 2
    return r[h:-h, h:-h].reshape(-1)


def test_centre_dof_is_one_over_the_box_leverage():
    assert plane_centre_dof(5) == pytest.approx(math.sqrt(25.0 / 24.0), rel=1e-12)
    assert plane_centre_dof(3) == pytest.approx(math.sqrt(9.0 / 8.0), rel=1e-12)
    for bad in (4, 1, 0):
        with pytest.raises(UnwrapError, match="odd"):
            plane_centre_dof(bad)


@pytest.mark.parametrize("window", [3, 5, 7])
def test_plane_residual_noise_reads_the_known_noise_back(window):
    """White phase noise of sigma 0.05 rad on 156,816+ interior pixels: the estimate is within 1.5 %
    (its own scatter here is ~0.5 %). The old 5x5 factor sqrt(25 / 22) reads 4.4 % high, the
    window-mean factor sqrt(n / (n - 3)) of a 3x3 box 15 % high; both fail this bound."""
    sigma, steps, B = 0.05, 3, 0.4
    r = _interior_residuals(sigma, window)
    got = plane_residual_noise(r, np.full(r.shape, B), steps, window=window)
    assert got["sigma_phase_rad"] == pytest.approx(sigma, rel=0.015)
    # the intensity noise it implies: sigma_phase * B * sqrt(N / 2)
    assert got["sigma_I"] == pytest.approx(sigma * B * math.sqrt(steps / 2.0), rel=0.015)
    n = window * window
    old = plane_residual_noise(r, np.full(r.shape, B), steps, dof=math.sqrt(n / (n - 3.0)))
    if window <= 5:                         # 7x7: the window factor is only 2 % off, inside the scatter bound
        assert abs(old["sigma_phase_rad"] / sigma - 1.0) > 0.03


def test_the_default_is_the_five_by_five_centre_factor():
    r = _interior_residuals(0.02, 5, shape=(200, 200), seed=1)
    B = np.full(r.shape, 0.3)
    assert plane_residual_noise(r, B, 4)["sigma_phase_rad"] == pytest.approx(
        plane_residual_noise(r, B, 4, dof=math.sqrt(25.0 / 24.0))["sigma_phase_rad"], rel=1e-12)


def test_noise_from_phase_of_a_three_step_capture_reads_the_known_noise():
    """unwrap.spatial_capture.noise_from_phase (the 3-step path of `calib unwrap --spatial`) goes
    through the same estimator: intensity noise sigma_phase * B * sqrt(N / 2) back within 1.5 %,
    with an invalid border (only interior pixels count)."""
    from unwrap.spatial_capture import noise_from_phase

    rng = np.random.default_rng(2)
    shape, sigma, B, N = (400, 400), 0.03, 0.25, 3
    y, x = np.mgrid[0:shape[0], 0:shape[1]].astype(np.float64)
    phase = 0.2 * x - 0.05 * y + rng.normal(0.0, sigma, shape)
    valid = np.zeros(shape, bool)
    valid[10:-10, 10:-10] = True
    got = noise_from_phase(np.where(valid, phase, np.nan), valid, np.full(shape, B), N)
    assert got == pytest.approx(sigma * B * math.sqrt(N / 2.0), rel=0.015)
