"""The two mesh engines of synth.renderer.raycast.nearest_hits (numba on the CPU, torch elsewhere) give the
same nearest hits as each other and as an independent dense ray-triangle solve, on meshes and on
the hard cases: degenerate triangles, triangles behind or crossing the device plane, rays in a
triangle's plane, empty inputs, non-finite rays, rays far apart."""
import numpy as np
import pytest
import torch

from synth import SynthError
from synth.scenes.meshes import sphere_mesh, steps_mesh
from synth.renderer.raycast import nearest_hits, numba_engine_available

pytestmark = pytest.mark.skipif(not numba_engine_available(), reason="numba is not installed")


def dense_nearest(tri, xy, margin=1e-9):
    """Independent reference: every ray against every triangle by solving the 3x3 system
    ``s d = v0 + b1 e1 + b2 e2`` (numpy.linalg.solve). Returns (s, index, robust): robust is False
    for rays with a candidate within ``margin`` of a triangle's edge or another hit at the same
    depth (where the two sides of an edge may legitimately differ)."""
    d = np.concatenate([xy, np.ones((len(xy), 1))], axis=1)
    v0, e1, e2 = tri[:, 0], tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    M = np.empty((len(xy), len(tri), 3, 3))
    M[..., 0] = d[:, None, :]
    M[..., 1] = -e1[None]
    M[..., 2] = -e2[None]
    det = np.linalg.det(M)
    solvable = np.abs(det) > 1e-9 * np.linalg.norm(e1, axis=1) * np.linalg.norm(e2, axis=1)
    sol = np.full(M.shape[:2] + (3,), np.nan)
    sol[solvable] = np.linalg.solve(M[solvable], np.broadcast_to(v0, M.shape[:2] + (3,))[solvable][..., None])[..., 0]
    s, b1, b2 = sol[..., 0], sol[..., 1], sol[..., 2]
    inside = (b1 >= 0) & (b2 >= 0) & (b1 + b2 <= 1) & (s > 1e-9)
    near_edge = ((np.abs(b1) < margin) | (np.abs(b2) < margin) | (np.abs(b1 + b2 - 1) < margin)) & (s > 0)
    s_in = np.where(inside, s, np.inf)
    idx = np.argmin(s_in, axis=1)
    best = s_in[np.arange(len(xy)), idx]
    idx = np.where(np.isfinite(best), idx, -1)
    with np.errstate(invalid="ignore"):  # inf - inf for rays without a hit: no tie
        ties = (np.abs(s_in - best[:, None]) <= 1e-9 * np.abs(best[:, None])).sum(1) > 1
    robust = ~near_edge.any(1) & ~ties
    return best, idx, robust


def _grid(lo, hi, n):
    g = torch.linspace(lo, hi, n, dtype=torch.float64)
    return torch.stack(torch.meshgrid(g, g, indexing="xy"), -1).reshape(-1, 2)


def _assert_same(a, b, rel=1e-12):
    s1, i1, b1 = a
    s2, i2, b2 = b
    assert torch.equal(i1 >= 0, i2 >= 0)
    h = i1 >= 0
    assert torch.isinf(s1[~h]).all() and torch.isinf(s2[~h]).all()
    assert float(((s1[h] - s2[h]) / s2[h]).abs().max()) <= rel if bool(h.any()) else True
    same = i1 == i2
    # a different triangle only at an exact tie (a ray through a shared edge or vertex)
    assert float(((s1[~same] - s2[~same]) / s2[~same]).abs().max()) <= rel if bool((~same).any()) else True
    assert float((b1[same & h] - b2[same & h]).abs().max()) < 1e-9 if bool((same & h).any()) else True
    return same


def test_numba_and_torch_engines_agree_on_a_faceted_ball_and_on_steps():
    V, F = sphere_mesh(30.0, 96, 48)
    ball = torch.tensor(V[F]) + torch.tensor([5.0, -3.0, 500.0])
    xy = _grid(-0.08, 0.08, 150)
    n = nearest_hits(ball, xy, 1e-3, engine="numba")
    t = nearest_hits(ball, xy, 1e-3, engine="torch")
    same = _assert_same(n, t)
    assert int((n[1] >= 0).sum()) > 5000 and float(same.float().mean()) > 0.99
    V, F = steps_mesh((160, 120), [0.0, 30.0, 0.0, 15.0], 2)
    steps = torch.tensor(V[F]) + torch.tensor([0.0, 0.0, 400.0])
    xy = _grid(-0.25, 0.25, 160)
    _assert_same(nearest_hits(steps, xy, 2e-3, engine="numba"), nearest_hits(steps, xy, 2e-3, engine="torch"))


def test_numba_engine_equals_an_independent_dense_solve_on_a_random_triangle_soup():
    rng = np.random.default_rng(7)
    T = 250
    centres = np.column_stack([rng.uniform(-60, 60, T), rng.uniform(-60, 60, T), rng.uniform(50, 400, T)])
    tri = centres[:, None, :] + rng.normal(0, 15, size=(T, 3, 3))
    tri[:10, 0, 2] = -30.0  # ten triangles cross the device plane
    tri[10:15, :, 2] = -rng.uniform(10, 50, size=(5, 3))  # five lie wholly behind it
    xy = rng.uniform(-0.6, 0.6, size=(500, 2))
    s_ref, i_ref, robust = dense_nearest(tri, xy)
    s, i, bary = nearest_hits(torch.tensor(tri), torch.tensor(xy), 0.01, engine="numba")
    s, i = s.numpy(), i.numpy()
    assert robust.sum() > 450 and (i_ref[robust] >= 0).sum() > 200
    assert np.array_equal(i[robust], i_ref[robust])
    h = robust & (i_ref >= 0)
    assert np.abs(s[h] - s_ref[h]).max() <= 1e-9 * s_ref[h].max()
    assert not np.isin(i, np.arange(10, 15)).any()  # never a triangle behind the camera
    assert np.isin(i, np.arange(10)).any()  # triangles crossing the plane are seen where in front
    # the barycentric weights rebuild the hit point
    hit = i >= 0
    P = tri[i[hit], 0] + bary[hit, :1].numpy() * (tri[i[hit], 1] - tri[i[hit], 0]) \
        + bary[hit, 1:].numpy() * (tri[i[hit], 2] - tri[i[hit], 0])
    np.testing.assert_allclose(P, np.column_stack([xy[hit], np.ones(hit.sum())]) * s[hit, None], rtol=1e-9, atol=1e-9)


def test_degenerate_and_edge_on_triangles_never_hit_and_ties_go_to_the_lower_index():
    tri = torch.tensor([
        [[0.0, 0, 100], [0, 0, 100], [0, 0, 100]],       # a point
        [[-10.0, 0, 100], [0, 0, 100], [10, 0, 100]],    # a segment
        [[0.0, -10, 50], [0, 10, 50], [0, 0, 150]],      # in the plane x = 0, which holds the rays x = 0
        [[-10.0, -10, 200], [10, -10, 200], [0, 10, 200]],  # a plain triangle behind all three
        [[-10.0, -10, 200], [10, -10, 200], [0, 10, 200]],  # its exact duplicate: a tie at every ray
    ], dtype=torch.float64)
    xy = torch.tensor([[0.0, 0.0], [0.0, 0.01], [0.0, -0.02], [0.02, 0.0]], dtype=torch.float64)
    s, i, _ = nearest_hits(tri, xy, 1e-3, engine="numba")
    assert i.tolist() == [3, 3, 3, 3]
    assert torch.allclose(s, torch.full((4,), 200.0, dtype=torch.float64), rtol=0, atol=1e-12)
    st, it, _ = nearest_hits(tri, xy, 1e-3, engine="torch")
    assert set(it.tolist()) <= {3, 4} and torch.equal(s, st)


def test_empty_meshes_non_finite_rays_and_the_chunked_torch_engine():
    V, F = sphere_mesh(30.0, 48, 24)
    ball = torch.tensor(V[F]) + torch.tensor([0.0, 0.0, 300.0])
    xy = _grid(-0.12, 0.12, 90)
    xy[::7] = float("nan")
    xy[3::11, 0] = float("inf")
    s, i, bary = nearest_hits(ball[:0], xy, 1e-3, engine="numba")
    assert (i == -1).all() and torch.isinf(s).all() and (bary == 0).all()
    s, i, _ = nearest_hits(ball, torch.full((5, 2), float("nan"), dtype=torch.float64), 1e-3, engine="numba")
    assert (i == -1).all() and torch.isinf(s).all()
    s, i, _ = nearest_hits(ball, xy, 1e-3, engine="numba")
    bad = ~torch.isfinite(xy).all(1)
    assert (i[bad] == -1).all() and int((i >= 0).sum()) > 1000
    s2, i2, _ = nearest_hits(ball, xy, 1e-3, engine="torch", max_pairs=20000)  # the torch engine in chunks
    _assert_same((s, i, _), (s2, i2, _))
    _assert_same((s, i, _), nearest_hits(ball, xy, 1e-3, engine="torch"))
    with pytest.raises(SynthError, match="engine"):
        nearest_hits(ball, xy, 1e-3, engine="cuda")


def test_rays_spread_far_apart_get_a_bounded_grid_and_the_same_hits():
    # a few rays 10^6 cells apart: the grid would be 10^12 cells; coarser cells keep it bounded
    tri = torch.tensor([[[-1e4, -1e4, 10.0], [1e4, -1e4, 10.0], [0.0, 1e4, 10.0]]], dtype=torch.float64)
    xy = torch.tensor([[0.0, 0.0], [500.0, -400.0], [-700.0, 900.0], [0.3, 0.2]], dtype=torch.float64)
    s, i, _ = nearest_hits(tri, xy, 1e-3, engine="numba")
    assert i.tolist() == [0, 0, -1, 0]
    assert torch.allclose(s[i >= 0], torch.full((3,), 10.0, dtype=torch.float64), rtol=1e-15)


@pytest.mark.parametrize("smooth", [True, False])
def test_fused_mesh_hit_pass_equals_the_torch_post_processing(smooth, monkeypatch):
    import synth.scenes.objects as objects
    from synth import Mesh, blobs_heights, heightfield_mesh
    from synth.renderer.geometry import camera_rays

    from synth_helpers import small_system

    V, F = heightfield_mesh(blobs_heights((220, 170), (60, 60), 10, 8.0, 20.0, 0), (220, 170))
    R = np.array([[1.0, 0, 0], [0, 0.8, -0.6], [0, 0.6, 0.8]])
    mesh = Mesh("relief", R, [5, -3, -40], V, F, smooth=smooth)
    rays, _ = camera_rays(small_system(4).camera, True)
    a = mesh.intersect(rays)
    monkeypatch.setattr(objects, "numba_engine_available", lambda: False)
    b = mesh.intersect(rays)
    h = torch.isfinite(b.t)
    assert int(h.sum()) > 1000 and torch.equal(torch.isfinite(a.t), h)
    assert float(((a.t[h] - b.t[h]) / b.t[h]).abs().max()) <= 1e-15
    assert float((a.normal[h] - b.normal[h]).abs().max()) <= 1e-15
    assert float((a.local - b.local).abs().max()) <= 1e-12


def test_huge_coordinates_and_non_finite_triangles_neither_overflow_nor_hit():
    # a triangle barely in front of the device plane projects to ~1e21 normalised units; rays at
    # 1e15 would overflow 64-bit cell indices without the guards
    tri = torch.tensor([[[-1e4, -1e4, 10.0], [1e4, -1e4, 10.0], [0.0, 1e4, 10.0]],
                        [[1e12, 0.0, 2e-9], [1e12, 1.0, 2e-9], [1e12 + 1, 0.0, 2e-9]],
                        [[0.0, 0.0, float("nan")], [1.0, 0.0, 5.0], [0.0, 1.0, 5.0]]], dtype=torch.float64)
    xy = torch.tensor([[0.0, 0.0], [0.1, 0.1], [1e15, 0.0], [5e20, 1e13]], dtype=torch.float64)
    s, i, _ = nearest_hits(tri, xy, 1e-3, engine="numba")
    assert i.tolist()[:2] == [0, 0] and torch.allclose(s[:2], torch.full((2,), 10.0, dtype=torch.float64))
    assert (i[2:] != 2).all()
    d = dense_nearest(tri.numpy()[:2], xy.numpy())
    assert i.tolist() == d[1].tolist()
