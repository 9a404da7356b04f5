import numpy as np
import pytest

from calib import DeviceModel, ModelError, default_system
from calib.distortion import distort, undistort


def test_default_system_is_the_papers_real_system_at_full_precision():
    s = default_system()
    assert s.camera.size == (640, 480) and s.projector.size == (912, 1140)
    assert s.camera.fx == pytest.approx(2592.1560458702, abs=1e-9)
    assert s.projector.fy == pytest.approx(3463.3285235585, abs=1e-9)
    # S2 prints skew -0.2332 / -0.9514 (px): KK(1,2) = alpha_c * fc(1)
    assert s.camera.skew == pytest.approx(-0.2332, abs=5e-5)
    assert s.projector.skew == pytest.approx(-0.9514, abs=5e-5)


def test_projection_round_trip_with_distortion_and_skew():
    s = default_system()
    rng = np.random.default_rng(1)
    for dev in (s.camera, s.projector):
        q = rng.uniform([0, 0], dev.size, size=(500, 2))
        rays, ok = dev.unproject(q)
        assert ok.all()
        X_dev = rays * rng.uniform(500, 1500, size=(500, 1))
        X_world = (X_dev - dev.t) @ dev.R  # R^T (x - t)
        np.testing.assert_allclose(dev.project(X_world), q, atol=1e-9)


def test_points_behind_the_device_project_to_nan_not_to_a_mirror_image():
    cam = DeviceModel(size=(640, 480), K=[[1000, 0, 320], [0, 1000, 240], [0, 0, 1]])
    q = cam.project(np.array([[10.0, 0, -100.0], [10.0, 0, 100.0]]))
    assert np.isnan(q[0]).all() and np.isfinite(q[1]).all()


@pytest.mark.parametrize("coeffs", [[-0.13, -0.56, -0.0014, -0.0004, 0.0], [0.1, 0.01, 0, 0],
                                    [0.2, -0.1, 0.001, 0.002, 0.01, 0.05, -0.01, 0.002],
                                    [0.1, 0.02, 0.001, -0.001, 0.0, 0, 0, 0, 0.001, -0.001, 0.002, 0.0005]])
def test_undistort_inverts_distort(coeffs):
    xy = np.random.default_rng(0).uniform(-0.3, 0.3, size=(1000, 2))
    back, ok = undistort(distort(xy, coeffs), coeffs)
    assert ok.all()
    np.testing.assert_allclose(back, xy, atol=1e-12)


def test_distort_runs_on_torch_tensors_with_gradients():
    torch = pytest.importorskip("torch")
    coeffs = [-0.13, -0.56, -0.0014, -0.0004, 0.0]
    xy = torch.tensor([[0.1, -0.05]], dtype=torch.float64, requires_grad=True)
    out = distort(xy, coeffs)
    out.sum().backward()
    np.testing.assert_allclose(out.detach().numpy(), distort(xy.detach().numpy(), coeffs), atol=1e-15)
    assert torch.isfinite(xy.grad).all()


@pytest.mark.parametrize("K, message", [
    ([[0, 0, 320], [0, 1000, 240], [0, 0, 1]], "focal lengths must be > 0"),
    ([[1000, 0, 320], [0, -5, 240], [0, 0, 1]], "focal lengths must be > 0"),
    ([[1000, 0, np.nan], [0, 1000, 240], [0, 0, 1]], "non-finite"),
    ([[1000, 0, 320], [0, 1000, 240], [0, 0, 2]], "expected"),
    ([[1000, 0], [0, 1000]], "shape"),
])
def test_invalid_intrinsics_are_refused_with_a_message_naming_the_defect(K, message):
    with pytest.raises(ModelError, match=message):
        DeviceModel(size=(640, 480), K=K)


@pytest.mark.parametrize("size", [(0, 480), (640.5, 480), ("a", 3), (640,)])
def test_invalid_sizes_are_refused(size):
    with pytest.raises(ModelError, match="size"):
        DeviceModel(size=size, K=np.eye(3))


def test_invalid_distortion_lengths_are_refused():
    with pytest.raises(ModelError, match="3 coefficients"):
        DeviceModel(size=(640, 480), K=np.eye(3), distortion=[0.1, 0.2, 0.3])
