import numpy as np
import pytest

from gpja.register.snap import normal_offsets, snap_to_scan
from gpja.surface import vertex_normals
from tests.render.scenes import sphere
from tests.tolerances import CLOSEST_POINT_F32_MM, ICOSPHERE5_SAGITTA_MM


def grid(n: int = 21, size: float = 20.0, z: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """An ``n x n`` grid in the plane ``z``, ``size`` mm wide, normals along +z."""
    x = np.linspace(-size / 2, size / 2, n)
    X, Y = np.meshgrid(x, x)
    V = np.column_stack([X.ravel(), Y.ravel(), np.full(n * n, z)])
    idx = np.arange(n * n).reshape(n, n)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel()
    F = np.concatenate([np.column_stack([a, b, d]), np.column_stack([a, d, c])])
    return V, F


def test_a_parallel_plane_snaps_exactly_onto_the_scan_from_either_side():
    scan = grid(size=40.0)
    for z in (0.3, -0.4):
        V, F = grid(z=z)
        out, entry = snap_to_scan(V, F, *scan, max_mm=1.0)
        np.testing.assert_allclose(out[:, 2], 0.0, atol=CLOSEST_POINT_F32_MM)
        np.testing.assert_allclose(out[:, :2], V[:, :2], atol=1e-12)  # along the normals only
        assert entry["hit_fraction"] == 1.0 and entry["gap_median_mm"] == pytest.approx(abs(z), abs=1e-5)


def test_a_mesh_on_the_scan_does_not_move():
    V, F = grid()
    out, entry = snap_to_scan(V, F, V, F, max_mm=1.0)
    np.testing.assert_allclose(out, V, atol=CLOSEST_POINT_F32_MM)
    assert entry["moved_max_mm"] <= CLOSEST_POINT_F32_MM


def test_a_scan_beyond_reach_or_facing_away_is_not_a_hit():
    V, F = grid(z=0.3)
    far = grid(size=40.0, z=2.0)
    out, entry = snap_to_scan(V, F, *far, max_mm=1.0)
    assert entry["hit_fraction"] == 0.0
    np.testing.assert_allclose(out, V, atol=1e-9)
    # the same plane with its faces turned over (the back of a lip seen from the mouth's inside)
    scan_V, scan_F = grid(size=40.0)
    offsets, hit = normal_offsets(V, vertex_normals(V, F), scan_V, scan_F[:, ::-1], 1.0)
    assert not hit.any() and not offsets.any()


def test_vertices_without_a_hit_follow_their_neighbours_smoothly():
    # the scan covers x <= -2 mm only (its faces left of x = 0): the rest moves with it, tapering off, without a step
    V, F = grid(z=0.5)
    scan_V, scan_F = grid(size=40.0)
    keep = (scan_V[scan_F][:, :, 0] < -1e-9).all(axis=1)
    out, entry = snap_to_scan(V, F, scan_V, scan_F[keep], max_mm=1.0)
    covered = V[:, 0] < -2.5
    assert entry["hit_fraction"] == pytest.approx(covered.mean(), abs=1.0 / 21 + 1e-9)  # the edge column may miss
    np.testing.assert_allclose(out[covered, 2], 0.0, atol=0.05)
    step = np.abs(np.diff(out[:, 2].reshape(21, 21), axis=1))
    assert step.max() < 0.1  # 1 mm apart: no crease at the scan's edge
    assert (out[:, 2] <= 0.5 + 1e-9).all() and out[~covered, 2].max() > out[covered, 2].max()


def test_a_sphere_inside_its_scan_comes_out_onto_it():
    # regression: a coarse sphere 0.4 mm inside a fine one ends on it, within the fine one's facets
    scan_V, scan_F = sphere(subdivisions=5, radius=100.0)
    V, F = sphere(subdivisions=3, radius=99.6)
    out, entry = snap_to_scan(V, F, scan_V, scan_F, max_mm=1.0)
    radius = np.linalg.norm(out, axis=1)
    assert entry["hit_fraction"] == 1.0
    assert np.abs(radius - 100.0).max() <= ICOSPHERE5_SAGITTA_MM


def test_bad_settings_are_refused():
    V, F = grid()
    with pytest.raises(ValueError, match="max_mm"):
        snap_to_scan(V, F, V, F, max_mm=0.0)
    with pytest.raises(ValueError, match="smoothness"):
        snap_to_scan(V, F, V, F, max_mm=1.0, smoothness=-1.0)
