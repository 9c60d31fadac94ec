"""Tests of gpja.surface: closest points, the rim convention (welded), normals and areas."""
from __future__ import annotations

import numpy as np
import pytest
import trimesh

from gpja.surface import (
    coincident_vertex_ids,
    interpolate,
    load_open3d,
    open_edges,
    prepare_surface,
    rim,
    vertex_areas,
    vertex_normals,
)
from tests.tolerances import CLOSEST_POINT_F32_MM, EXACT_F64

# --- closest points ---------------------------------------------------------------------------


def test_closest_points_on_a_unit_triangle():
    V = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]])
    F = np.array([[0, 1, 2]])
    surface = prepare_surface(V, F)
    P = np.array([[0.2, 0.3, 0.5],    # above the interior
                  [0.5, -2.0, 0.0],   # beyond edge 0-1
                  [2.0, 2.0, 0.0],    # beyond the hypotenuse 1-2
                  [-1.0, -1.0, 1.0]])  # beyond corner 0
    hit = surface.closest(P)
    expected = np.array([[0.2, 0.3, 0.0], [0.5, 0.0, 0.0], [0.5, 0.5, 0.0], [0.0, 0.0, 0.0]])
    np.testing.assert_allclose(hit.point, expected, atol=CLOSEST_POINT_F32_MM)
    np.testing.assert_allclose(hit.distance, np.linalg.norm(P - expected, axis=1), atol=CLOSEST_POINT_F32_MM)
    np.testing.assert_allclose(hit.barycentric[0], [0.5, 0.2, 0.3], atol=CLOSEST_POINT_F32_MM)
    np.testing.assert_allclose(hit.barycentric.sum(axis=1), 1.0, atol=EXACT_F64)
    np.testing.assert_array_equal(hit.face, 0)
    np.testing.assert_array_equal(hit.normal, [[0.0, 0.0, 1.0]] * 4)
    np.testing.assert_array_equal(hit.on_boundary, [False, True, True, True])  # a lone triangle is all rim
    np.testing.assert_allclose(interpolate(surface, hit, surface.V), expected, atol=CLOSEST_POINT_F32_MM)


def tetrahedron() -> tuple[np.ndarray, np.ndarray]:
    """The unit corner tetrahedron, faces outward."""
    V = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])
    F = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    return V, F


def test_closest_points_on_a_tetrahedron():
    V, F = tetrahedron()
    surface = prepare_surface(V, F)
    assert not surface.boundary_edge.any() and not surface.boundary_vertex.any()  # closed
    hit = surface.closest(np.array([[1.0, 1, 1], [0.1, 0.2, 0.3], [-1.0, 0.25, 0.25]]))
    third = 1.0 / 3.0
    np.testing.assert_allclose(hit.point[0], [third] * 3, atol=CLOSEST_POINT_F32_MM)  # on the slanted face
    np.testing.assert_allclose(hit.distance, [2.0 / np.sqrt(3.0), 0.1, 1.0], atol=CLOSEST_POINT_F32_MM)
    np.testing.assert_allclose(hit.point[1], [0.0, 0.2, 0.3], atol=CLOSEST_POINT_F32_MM)  # nearest face x = 0
    assert hit.face[0] == 3 and hit.face[1] == 2 and hit.face[2] == 2
    np.testing.assert_allclose(hit.normal[0], [np.sqrt(third)] * 3, atol=EXACT_F64)
    np.testing.assert_array_equal(hit.normal[2], [-1.0, 0.0, 0.0])
    assert not hit.on_boundary.any()


def test_the_origin_shift_keeps_float32_precision_far_from_zero():
    """A triangle 100 m from the world origin: a point 1 mm above it is still 1 mm away."""
    far = np.array([1e5, -2e5, 3e5])
    V = np.array([[0.0, 0, 0], [50, 0, 0], [0, 50, 0]]) + far
    P = np.array([[10.0, 10.0, 1.0]]) + far
    hit = prepare_surface(V, np.array([[0, 1, 2]])).closest(P)
    assert abs(hit.distance[0] - 1.0) < CLOSEST_POINT_F32_MM


# --- rim ----------------------------------------------------------------------------------------

def square_grid(n: int = 5) -> tuple[np.ndarray, np.ndarray]:
    """An open n x n grid of vertices (spacing 1 mm) in z = 0, two triangles per cell."""
    i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    V = np.column_stack([i.ravel(), j.ravel(), np.zeros(n * n)]).astype(np.float64)
    a = (i[:-1, :-1] * n + j[:-1, :-1]).ravel()
    F = np.concatenate([np.column_stack([a, a + n, a + n + 1]), np.column_stack([a, a + n + 1, a + 1])])
    return V, F


def unweld(V: np.ndarray, F: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Every face on its own three vertex copies (as a PLY with per-corner attributes stores it)."""
    return V[F].reshape(-1, 3), np.arange(3 * len(F)).reshape(-1, 3)


def on_border(V: np.ndarray, n: int) -> np.ndarray:
    return (V[:, 0] == 0) | (V[:, 0] == n - 1) | (V[:, 1] == 0) | (V[:, 1] == n - 1)


@pytest.mark.parametrize("welded", [True, False])
def test_rim_of_an_open_square_grid(welded):
    n = 5
    V, F = square_grid(n)
    if not welded:
        V, F = unweld(V, F)
        assert open_edges(F).all()  # without welding, every edge of the file is open
    edge_open, vertex_open = rim(V, F)
    assert edge_open.sum() == 4 * (n - 1)  # the square's four sides, n - 1 edges each
    corners = V[F]  # (m, 3, 3): edge k of a face runs from corner k to corner k + 1
    start, end = corners[edge_open], np.roll(corners, -1, axis=1)[edge_open]
    assert on_border(start, n).all() and on_border(end, n).all()
    # every open edge runs along one side: both ends share an x or a y on the border
    assert (((start[:, 0] == end[:, 0]) & np.isin(start[:, 0], [0, n - 1]))
            | ((start[:, 1] == end[:, 1]) & np.isin(start[:, 1], [0, n - 1]))).all()
    np.testing.assert_array_equal(vertex_open, on_border(V, n))

    surface = prepare_surface(V, F)
    hit = surface.closest(np.array([[2.0, 2.0, 1.0], [2.3, -1.0, 0.5], [-1.0, -1.0, 0.0], [1.5, 1.2, -0.3]]))
    np.testing.assert_array_equal(hit.on_boundary, [False, True, True, False])


def test_rim_agrees_with_trimesh_on_a_cropped_sphere():
    s = trimesh.creation.icosphere(subdivisions=2, radius=100.0)
    V, F = np.asarray(s.vertices), np.asarray(s.faces)
    F = F[(V[F][:, :, 2] > 0.0).all(axis=1)]
    edge_open, vertex_open = rim(V, F)
    mesh = trimesh.Trimesh(V, F, process=False)
    boundary = mesh.edges_sorted[trimesh.grouping.group_rows(mesh.edges_sorted, require_count=1)]
    assert len(boundary) > 0 and edge_open.sum() == len(boundary)
    assert set(np.flatnonzero(vertex_open)) == set(boundary.ravel())


def test_open_edges_analytic():
    # two triangles sharing edge 0-2: every other edge is open
    np.testing.assert_array_equal(open_edges(np.array([[0, 1, 2], [0, 2, 3]])),
                                  [[True, True, False], [False, True, True]])
    _, F = tetrahedron()
    assert not open_edges(F).any()  # closed surface
    # an edge of three faces (non-manifold) counts as closed
    assert not open_edges(np.array([[0, 1, 2], [1, 0, 3], [0, 1, 4]]))[:, 0].any()


def test_coincident_vertices_share_an_id():
    V = np.array([[0.0, 0, 0], [1, 0, 0], [0.0, 0, 0], [1, 0, 1e-12]])
    ids = coincident_vertex_ids(V)
    assert ids[0] == ids[2] and len(set(ids.tolist())) == 3


def test_closest_point_on_open_edge_and_interior():
    V = np.array([[0.0, 0, 0], [10, 0, 0], [0, 10, 0], [10, 10, 0]])
    F = np.array([[0, 1, 2], [1, 3, 2]])
    surface = prepare_surface(V, F, V.mean(axis=0))
    P = np.array([[2.0, 2, 3],      # above the interior: foot inside face 0
                  [5.0, -4, 1],     # beyond the open edge 0-1: foot on it
                  [5.0, 5, 2],      # above the shared (closed) diagonal
                  [-3.0, -3, 0]])   # beyond corner 0 (a boundary vertex)
    cp = surface.closest(P)
    np.testing.assert_allclose(cp.distance, [3.0, np.hypot(4, 1), 2.0, np.hypot(3, 3)], atol=CLOSEST_POINT_F32_MM)
    np.testing.assert_array_equal(cp.on_boundary, [False, True, False, True])
    np.testing.assert_allclose(cp.barycentric.sum(axis=1), 1.0, atol=1e-6)


# --- normals and areas ------------------------------------------------------------------------

def octahedron() -> tuple[np.ndarray, np.ndarray]:
    """The unit octahedron (vertices +-e_i), faces oriented outward."""
    V = np.array([[1.0, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]])
    F = []
    for x in (0, 1):
        for y in (2, 3):
            for z in (4, 5):
                f = [x, y, z]
                if np.cross(V[y] - V[x], V[z] - V[x]) @ V[f].mean(axis=0) < 0:
                    f = [x, z, y]
                F.append(f)
    return V, np.array(F)


def test_vertex_normals_and_areas_of_an_octahedron():
    V, F = octahedron()
    np.testing.assert_allclose(vertex_normals(V, F), V, atol=EXACT_F64)  # by symmetry, along each vertex
    face_area = np.sqrt(3.0) / 2.0  # equilateral, side sqrt(2)
    np.testing.assert_allclose(vertex_areas(V, F), 4 * face_area / 3.0, atol=EXACT_F64)
    np.testing.assert_allclose(vertex_areas(V, F).sum(), 8 * face_area, atol=EXACT_F64)
    flipped = vertex_normals(V, F[:, ::-1])
    np.testing.assert_allclose(flipped, -V, atol=EXACT_F64)


def test_vertex_normals_of_an_isolated_vertex_are_zero():
    V, F = octahedron()
    V = np.vstack([V, [5.0, 5.0, 5.0]])
    assert not vertex_normals(V, F)[-1].any()


# --- load_open3d ----------------------------------------------------------------------------------------------

_LOAD_OPEN3D = r"""
import json, sys
from gpja.surface import closest_points, load_open3d, prepare_surface
import numpy as np
o3d = load_open3d()
V = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
hit = closest_points(prepare_surface(V, np.array([[0, 1, 2]])), np.array([[0.25, 0.25, 2.0]]))
before = {m: m in sys.modules for m in ("plotly", "dash")}
deferred = type(sys.modules["open3d.visualization"]).__name__
draw = o3d.visualization.draw_plotly.__name__  # the first use imports the real package
print(json.dumps({"before": before, "deferred": deferred, "draw": draw,
                  "after": type(sys.modules["open3d.visualization"]).__name__, "point": hit.point.tolist()}))
"""


def test_load_open3d_defers_the_visualisation_package_until_it_is_used():
    """A fresh interpreter: queries work with neither plotly nor dash imported, and the first use of
    ``open3d.visualization`` imports the real package."""
    import json
    import subprocess
    import sys

    run = subprocess.run([sys.executable, "-c", _LOAD_OPEN3D], capture_output=True, text=True, check=True)
    got = json.loads(run.stdout.strip().splitlines()[-1])
    assert got["before"] == {"plotly": False, "dash": False}
    assert got["deferred"] == "_DeferredPackage"
    assert got["draw"] == "draw_plotly"
    assert got["after"] == "module"
    np.testing.assert_allclose(got["point"], [[0.25, 0.25, 0.0]], atol=CLOSEST_POINT_F32_MM)


def test_load_open3d_returns_an_open3d_already_imported():
    import open3d

    assert load_open3d() is open3d
