"""The bundle adjustment's machinery: compiled point kernels (and their virtual-machine fallback),
the Schur-complement normal equations, Newton's second-order term, convergence from a Zhang seed in
few iterations, and the flags on parameters the observations hardly determine.

Real data: the paper's own board observations (../shared/data/dp-tpu, DP-TPU repository, MIT
licence); skipped when absent.
"""
import logging

import numpy as np
import pytest

from calib import default_system
from calib.adjustment import kernel as ba_kernel
from calib.adjustment.kernel import KernelSpec, point_kernel
from calib.adjustment.normal import NormalEquations
from calib.adjustment.solver import solve
from calib.board import Board
from calib.adjustment.problem import BAConfig, DeviceConfig, build_problem
from calib.calibrate import run_calibration, start_state
from calib.observations import from_bouguet
from calib.rotation import matrix_from_rotvec
from calib.simulate import simulate_observations
from calib.zhang import init_device
from tests.conftest import shared_data

CIRCLES = Board("circles", 9, 11, 20.0, 5.0, 2.0, [[4, 5], [4, 6], [4, 7], [3, 5], [2, 5]])


def _compiler_or_skip():
    if ba_kernel.c_compiler() is None:
        pytest.skip("no C compiler: only the virtual-machine kernels can run here")


def _kernel_inputs(spec, n, rng):
    intr = np.r_[2000.0, 2100.0, 320.0, 240.0, 0.3, rng.normal(0, 0.05, spec.n_distortion)]
    R1 = np.stack([matrix_from_rotvec(rng.normal(0, 0.3, 3)).ravel() for _ in range(n)])
    t1 = np.c_[rng.normal(0, 10, (n, 2)), 600 + rng.normal(0, 10, n)]
    pose2 = [matrix_from_rotvec([0.01, 0.2, 0.0]).ravel(), np.array([100.0, 0.0, 10.0])] if spec.chain == 2 else []
    X = np.c_[rng.uniform(-100, 100, (n, 2)), np.zeros(n)]
    return [intr, R1, t1] + pose2 + [X, rng.uniform(0, 1, (n, 2)), np.array([0.1, -0.2])]


# -- kernels ---------------------------------------------------------------------------------
@pytest.mark.parametrize("n_distortion,chain", [(0, 1), (4, 2), (5, 1), (8, 2), (12, 1), (12, 2)])
def test_kernel_jacobian_is_the_derivative_of_its_prediction(n_distortion, chain):
    """Central differences of q over every local variable (rotations as right increments)."""
    spec = KernelSpec(n_distortion, chain)
    k = point_kernel(spec)
    rng = np.random.default_rng(n_distortion + chain)
    inputs = _kernel_inputs(spec, 20, rng)
    L = spec.n_local
    J = k.evaluate(inputs)[:, 3:].reshape(20, 2, L)
    blocks = spec.local_blocks

    def moved(j, h):
        x = [np.array(a, copy=True) for a in inputs]
        name, off = next((b, j - a) for b, (a, e) in blocks.items() if a <= j < e)
        if name == "intr":
            x[0][off] += h
        elif name == "warp":
            x[-1][off] += h
        else:
            R_i, t_i = (1, 2) if name == "pose1" else (3, 4)
            if off < 3:
                w = np.zeros(3)
                w[off] = h
                x[R_i] = (x[R_i].reshape(-1, 3, 3) @ matrix_from_rotvec(w)).reshape(x[R_i].shape)
            else:
                x[t_i][..., off - 3] += h
        return k.evaluate(x)[:, :2]

    for j in range(L):
        h = 1e-6 * max(1.0, abs(inputs[0][j])) if j < spec.n_intr else 1e-6
        fd = (moved(j, h) - moved(j, -h)) / (2 * h)
        scale = np.max(np.abs(fd)) + 1e-12
        assert np.max(np.abs(fd - J[:, :, j])) < 1e-5 * scale, (spec, j)


def test_compiled_and_virtual_machine_kernels_agree():
    _compiler_or_skip()
    for spec in (KernelSpec(5, 2), KernelSpec(4, 1), KernelSpec(5, 2, hessian=True)):
        inputs = _kernel_inputs(spec, 300, np.random.default_rng(1))
        if spec.hessian:
            inputs.append(np.random.default_rng(2).normal(size=(300, 2)))
        a = point_kernel(spec, "compiled").evaluate(inputs)
        b = point_kernel(spec, "vm").evaluate(inputs)
        assert np.allclose(a, b, rtol=1e-12, atol=1e-12 * np.abs(b).max())
        if spec.hessian:   # summed per row (pose block)
            rows = np.repeat(np.arange(3), 100)
            sa = point_kernel(spec, "compiled").evaluate(inputs, rows=rows, n_rows=3, accumulate=True)
            sb = point_kernel(spec, "vm").evaluate(inputs, rows=rows, n_rows=3, accumulate=True)
            assert np.allclose(sa, b.reshape(3, 100, -1).sum(axis=1), rtol=1e-10, atol=1e-9 * np.abs(sa).max())
            assert np.allclose(sa, sb, rtol=1e-10, atol=1e-9 * np.abs(sa).max())


def test_compiled_kernel_is_cached_on_disk_and_a_missing_compiler_falls_back_with_a_note(
        tmp_path, monkeypatch, caplog):
    _compiler_or_skip()
    monkeypatch.setenv("SLTWIN_CACHE_DIR", str(tmp_path))
    monkeypatch.setattr(ba_kernel, "_KERNELS", {})
    monkeypatch.setattr(ba_kernel, "_NOTED", set())
    spec = KernelSpec(0, 1)
    lib = ba_kernel.compile_kernel(spec)
    assert lib.exists() and lib.parent == tmp_path / "ba_kernels"
    # a second build finds it: no C source is generated again
    monkeypatch.setattr(ba_kernel, "c_source", lambda s: pytest.fail("recompiled a cached kernel"))
    assert ba_kernel.compile_kernel(spec) == lib
    monkeypatch.setattr(ba_kernel, "_KERNELS", {})
    monkeypatch.setenv("CC", "no-such-compiler-here")
    with caplog.at_level(logging.WARNING, logger="calib.adjustment.kernel"):
        k = point_kernel(KernelSpec(4, 2), "auto")
        point_kernel(KernelSpec(5, 2), "auto")
    assert k.backend == "vm"
    notes = [r for r in caplog.records if "virtual machine" in r.getMessage()]
    assert len(notes) == 1 and "\n" not in notes[0].getMessage()


def test_compiled_and_virtual_machine_paths_give_the_same_calibration():
    _compiler_or_skip()
    obs, _ = simulate_observations(default_system(), CIRCLES, 5, 0.06, np.random.default_rng(3),
                                   noise_prj_px=0.05, projector_from_camera=True)
    cfg = dict(camera=DeviceConfig(5), projector=DeviceConfig(4, estimate_skew=True), board_warp=True,
               loss="huber")
    a = run_calibration(obs, BAConfig(backend="compiled", **cfg))
    b = run_calibration(obs, BAConfig(backend="vm", **cfg))
    assert a.ba.backend == "compiled" and b.ba.backend == "vm"
    for d in ("camera", "projector"):
        da, db = getattr(a.system, d), getattr(b.system, d)
        assert np.allclose(da.K, db.K, rtol=1e-9, atol=1e-9) and np.allclose(da.distortion, db.distortion,
                                                                              rtol=1e-7, atol=1e-12)
    assert a.ba.std["projector.fy"] == pytest.approx(b.ba.std["projector.fy"], rel=1e-7)
    assert np.array_equal(a.ba.inlier, b.ba.inlier)


# -- problem, normal equations, second-order term ----------------------------------------------
def _problem(cfg, n_views=5, seed=3):
    obs, _ = simulate_observations(default_system(), Board("checkerboard", 5, 7, 20.0), n_views, 0.05,
                                   np.random.default_rng(seed), noise_prj_px=0.01, projector_from_camera=True)
    seeds = {d: init_device([v.points_board[v.seen(d)] for v in obs.views], [v.q[d][v.seen(d)] for v in obs.views],
                            obs.sizes[d], n_distortion=cfg.device(d).n_distortion, refine=False)
            for d in ("camera", "projector")}
    state, _ = start_state(obs, seeds, cfg)
    return build_problem(obs, state, cfg)


def _dense(problem, ev):
    S, G = problem.n_slots, ev.Jg.shape[1]
    J = np.zeros((len(ev.r), G + 6 * S))
    J[:, :G] = ev.Jg
    rows = np.arange(len(ev.r)).reshape(S, -1)
    for s in range(S):
        J[rows[s], G + 6 * s:G + 6 * s + 6] = ev.Jv[rows[s]]
    return J * problem.inv_sigma_rows[:, None]


def _moved(problem, state, x):
    G = len(problem.global_free_index)
    return state.moved(problem, x[:G], x[G:].reshape(problem.n_slots, 6))


CFG_ALL = BAConfig(board_warp=True, camera=DeviceConfig(12, True), projector=DeviceConfig(8, True))


def test_problem_jacobian_with_camera_error_transfer_and_warp_is_the_derivative_of_the_residuals():
    problem = _problem(CFG_ALL)
    assert problem.transfer_prj is not None
    state = problem.start
    rng = np.random.default_rng(1)
    state = _moved(problem, state, rng.normal(0, 1e-4, len(problem.global_free_index) + 6 * problem.n_slots))
    J = _dense(problem, problem.evaluate(state))
    for j in rng.choice(J.shape[1], 40, replace=False):
        h = 1e-3 / np.linalg.norm(J[:, j])          # moves the residuals by ~1e-3: above rounding
        e = np.zeros(J.shape[1])
        e[j] = h
        fd = (problem.evaluate(_moved(problem, state, e)).r - problem.evaluate(_moved(problem, state, -e)).r) / (2 * h)
        assert np.max(np.abs(fd - J[:, j])) < 1e-5 * (np.max(np.abs(fd)) + 1e-12), problem.names[j]


def test_schur_complement_step_and_covariance_equal_the_dense_solution():
    rng = np.random.default_rng(0)
    S, R, G = 4, 30, 7
    Jg, Jv, r = rng.normal(size=(S * R, G)), rng.normal(size=(S * R, 6)), rng.normal(size=S * R)
    Jg[:, 0] *= 1e4          # badly scaled columns: the Jacobi scaling must cope
    J = np.zeros((S * R, G + 6 * S))
    J[:, :G] = Jg
    for s in range(S):
        J[s * R:(s + 1) * R, G + 6 * s:G + 6 * s + 6] = Jv[s * R:(s + 1) * R]
    ne = NormalEquations(Jg, Jv, r, S)
    for lam in (0.0, 0.1):
        D = np.diag(np.diag(J.T @ J))
        dense = -np.linalg.solve(J.T @ J + lam * D, J.T @ r)
        step = ne.solve(lam)
        assert np.allclose(np.r_[step.dg, step.dv.ravel()], dense, rtol=1e-9, atol=1e-12)
        assert step.predicted == pytest.approx(r @ r - np.sum((r + J @ dense) ** 2), rel=1e-9)
    full = np.linalg.inv(J.T @ J)
    cov_g, cov_v = ne.covariance()
    assert np.allclose(cov_g, full[:G, :G], rtol=1e-8, atol=1e-14)
    for s in range(S):
        b = slice(G + 6 * s, G + 6 * s + 6)
        assert np.allclose(cov_v[s], full[b, b], rtol=1e-8, atol=1e-14)


def test_newton_second_order_term_is_the_hessian_of_the_weighted_cost():
    """J^T W J + sum mu d2q (our Newton matrix) against central differences of the gradient, in
    the chart w -> R Exp(w) of every rotation (the solver's gradient is taken in the tangent space
    at the moved point: ``g_chart(w) = J_r(w)^T g(R Exp(w))``, ``J_r(w)^T = I + [w]x / 2 + ...``)."""
    problem = _problem(BAConfig(board_warp=True, camera=DeviceConfig(5), projector=DeviceConfig(4, True)), n_views=3)
    state = problem.start
    weights = np.random.default_rng(4).uniform(0.5, 2.0, problem.n_points)
    sw = np.sqrt(problem.point_rows(weights))

    def gradient(st):
        ev = problem.evaluate(st)
        return _dense(problem, ev).T @ (sw ** 2 * ev.r)

    ev = problem.evaluate(state)
    J = _dense(problem, ev) * sw[:, None]
    U2, W2, V2 = problem.second_order(state, ev, weights)
    G, S = U2.shape[0], problem.n_slots
    H = J.T @ J
    H[:G, :G] += U2
    for s in range(S):
        b = slice(G + 6 * s, G + 6 * s + 6)
        H[:G, b] += W2[s]
        H[b, :G] += W2[s].T
        H[b, b] += V2[s]
    scale = 1 / np.sqrt(np.diag(J.T @ J))
    free = list(problem.global_free_index)
    rotations = [[free.index(k) for k in problem.rig_index[:3]]] + [[G + 6 * s + a for a in range(3)] for s in range(S)]
    g0 = gradient(state)
    for j in range(H.shape[0]):
        e = np.zeros(H.shape[0])
        e[j] = 1e-4 * scale[j]
        fd = (gradient(_moved(problem, state, e)) - gradient(_moved(problem, state, -e))) / (2 * e[j])
        for rot in rotations:
            if j in rot:
                fd[rot] += 0.5 * np.cross(np.eye(3)[rot.index(j)], g0[rot])
        assert np.max(np.abs(fd - H[:, j]) * scale) < 1e-6 * np.max(np.abs(H[:, j]) * scale), problem.names[j]


# -- convergence ------------------------------------------------------------------------------
def test_joint_rig_converges_in_few_iterations_from_the_zhang_seed():
    """Before this solver: 71 (9 views) and 54 (30 views) LM iterations on these problems."""
    for n_views in (9, 30):
        obs, _ = simulate_observations(default_system(), CIRCLES, n_views, 0.06, np.random.default_rng(0),
                                       noise_prj_px=0.2)
        cal = run_calibration(obs, BAConfig(camera=DeviceConfig(4), projector=DeviceConfig(4), outlier_threshold=None))
        assert cal.ba.converged and cal.ba.iterations <= 12, cal.ba.log


@pytest.fixture(scope="module")
def dp_obs():
    return from_bouguet(shared_data("dp-tpu", "CamCalibResult_real.mat"),
                        shared_data("dp-tpu", "PrjCalibResult_real.mat"))


@pytest.mark.realdata
def test_paper_observations_converge_in_few_iterations_and_k3_is_flagged_not_silent(dp_obs):
    """The paper's 9 x 35 real points, default 5-term model: 105 (outliers kept) and 113 (rejected)
    LM iterations before. The projector's k3 = 5236 +- 2003 is finite and flagged."""
    kept = run_calibration(dp_obs, BAConfig(outlier_threshold=None))
    assert kept.ba.converged and kept.ba.iterations <= 10, kept.ba.log
    cal = run_calibration(dp_obs, BAConfig())
    assert cal.ba.converged and cal.ba.iterations <= 22, cal.ba.log
    k3 = cal.system.projector.distortion[4]
    assert np.isfinite(k3) and np.isfinite(cal.ba.std["projector.k3"]) and abs(k3) > 1000
    flagged = {f["name"]: f for f in cal.ba.poorly_determined}
    assert "projector.k3" in flagged and "not distinguishable from 0" in flagged["projector.k3"]["reasons"][0]
    assert not any(n.endswith((".fx", ".fy", ".cx", ".cy")) for n in flagged)
    from calib.io.outputs import summary_table
    table = summary_table(cal)
    assert any(line.startswith("projector.k3") and "poorly determined" in line for line in table.splitlines())


def test_k3_of_a_narrow_field_projector_is_finite_and_flagged():
    obs, _ = simulate_observations(default_system(), CIRCLES, 9, 0.06, np.random.default_rng(1), noise_prj_px=0.2)
    cal = run_calibration(obs, BAConfig(camera=DeviceConfig(5), projector=DeviceConfig(5)))
    flagged = {f["name"] for f in cal.ba.poorly_determined}
    assert "projector.k3" in flagged
    assert all(np.isfinite(v) for v in cal.ba.std.values())
    assert not flagged & {f"{d}.{p}" for d in ("camera", "projector") for p in ("fx", "fy", "cx", "cy")}


def test_a_degenerate_parameter_is_flagged_by_its_correlation():
    """A parameter the data cannot separate from another: k1 and k2 on points of one radius."""
    from calib.adjustment.solver import poorly_determined

    cov = np.array([[1.0, 0.99999], [0.99999, 1.0]]) * 1e-6
    flags = poorly_determined(["camera.k1", "camera.k2"], np.array([0.5, 0.2]), cov)
    assert [f["name"] for f in flags] == ["camera.k1", "camera.k2"]
    assert "correlation +0.99999 with k2" in flags[0]["reasons"][0]
    assert poorly_determined(["camera.fx", "camera.cx"], np.array([2000.0, 320.0]), np.diag([4.0, 4.0]),
                             {"camera": (640, 480)}) == []


def test_solve_reports_iterations_and_keeps_fixed_parameters():
    problem = _problem(BAConfig(camera=DeviceConfig(5, values=(("cx", 312.5),)), projector=DeviceConfig(4)))
    res = solve(problem)
    assert res.converged and res.state.K["camera"][0, 2] == 312.5 and "camera.cx" not in res.std
    assert res.cov.shape == (len(res.cov_names),) * 2 and "camera.cx" not in res.cov_names


def test_a_singular_direction_is_named_by_its_parameters():
    """The refusal of a numerically singular problem names what the views do not determine."""
    from types import SimpleNamespace

    from calib.adjustment.solver import _undetermined

    rng = np.random.default_rng(0)
    S, R = 3, 20
    Jg = rng.normal(size=(S * R, 4))
    Jg[:, 3] = Jg[:, 1] * 2.0                      # k4 only ever acts as 2 k1
    ne = NormalEquations(Jg, rng.normal(size=(S * R, 6)), rng.normal(size=S * R), S)
    problem = SimpleNamespace(pose_names=["cam_board/0", "cam_board/1", "cam_board/2"],
                              global_names=["camera.fx", "camera.k1", "camera.k2", "camera.k4"],
                              global_free_index=np.arange(4))
    with pytest.raises(np.linalg.LinAlgError):
        ne.covariance()
    assert _undetermined(problem, ne) == "the combination of camera.k1, camera.k4"
    Jv = rng.normal(size=(S * R, 6))
    Jv[R:2 * R, 5] = 0.0                           # a pose whose depth no point sees
    ne = NormalEquations(rng.normal(size=(S * R, 4)), Jv, rng.normal(size=S * R), S)
    assert _undetermined(problem, ne) == "the board pose cam_board/1"
