"""gpja.apply.remesh: expressions on one common triangulation, located through the template's texture space.

The fixture is a UV-mapped lat-long sphere (radius 50 mm): welded positions, a seam column of duplicated
texture coordinates (u = 0 and u = 1 of one meridian) and poles with one texture coordinate per fan triangle,
so every pole spoke is a seam edge too. Expressions are refinements of it (``refine_by_factor``: the same atlas,
another triangulation) moved by an affine map, which commutes with barycentric interpolation: remeshing one
onto a triangulation built from the template gives the affine image of that triangulation, exactly.
"""
from __future__ import annotations

import signal
from contextlib import contextmanager

import numpy as np
import pytest

from gpja.apply import remesh as R
from gpja.apply.remesh import (SEAM_AGREEMENT_MM, UV_OFF_ATLAS, ChordErrorCache, barycentric_2d, chord_errors,
                               common_triangulation,
                               UVIndex, edge_uv_midpoints, fit_triangulation, locate_uv, offsets_at_uv,
                               positions_at_uv, remesh_onto)
from gpja.errors import InputError
from gpja.mesh import TexturedMesh, unique_edges
from gpja.register.remesh import refine_by_factor, split_edges
from gpja.surface import prepare_surface
from tests.tolerances import CLOSEST_POINT_F32_MM, EXACT_F64

#: float64 identities through remeshing (affine images, the template onto itself, chords of flat faces) of
#: ~100 mm coordinates, mm (measured <= 5e-14).
REMESH_EXACT_MM = EXACT_F64
#: Barycentric weights of exact float64 configurations (corners, centroid).
BARYCENTRIC_EXACT = 1e-12
#: A texture coordinate of the atlas located in it: float64 distance of the clipped barycentric point, UV units.
LOCATED_ON_ATLAS_UV = 1e-12
#: Outward shift of one side of the seam in the broken copy, UV units: the last column (0.075 wide) grows by
#: 13 %, so its seam vertices land millimetres away from the other chart's, far above SEAM_AGREEMENT_MM.
SEAM_SHIFT_UV = 0.01
#: Chord tolerance for fitting the bumped sphere, mm (the coarse common misses it by 2.6 mm; measured to
#: converge in 5 rounds to ~220 vertices).
FIT_TOLERANCE_MM = 0.1
#: Chord error of edges on the far (z < 0) side of the bump, mm: its tail there is at most
#: 0.2 * 55 mm * exp(-5000 / 400) = 4e-5 mm at either end (measured 1.6e-5).
FAR_FROM_BUMP_MM = 1e-4
#: Rounds allowed to the fit: far more than it needs, so stopping means convergence.
FIT_MAX_ROUNDS = 30

RADIUS_MM = 50.0
N_LAT, N_LON = 6, 12  # rings between the poles, meridians
UV_MARGIN = 0.05  # the atlas spans [0.05, 0.95]^2
SEAM_U = UV_MARGIN + (1.0 - 2.0 * UV_MARGIN) * 1.0  # u of the seam's second side, as uv_sphere rounds it
#: An affine map: anisotropic scaling, shear and translation (mm).
AFFINE_A = np.array([[1.3, 0.2, 0.0], [0.0, 0.8, 0.1], [0.05, 0.0, 1.1]])
AFFINE_B = np.array([5.0, -3.0, 12.0])


def uv_sphere(n_lat: int = N_LAT, n_lon: int = N_LON, radius: float = RADIUS_MM) -> TexturedMesh:
    """A lat-long sphere: 2 poles + n_lat rings of n_lon vertices (welded), y up, outward faces.

    UVs: u = meridian / n_lon, with meridian n_lon a copy of meridian 0 (the seam); v = 1 at the north pole,
    0 at the south; each pole has one texture coordinate per fan triangle, at the middle of its column. All
    mapped into [UV_MARGIN, 1 - UV_MARGIN].
    """
    phi = np.pi * np.arange(1, n_lat + 1) / (n_lat + 1)
    lam = 2 * np.pi * np.arange(n_lon) / n_lon
    P, L = np.meshgrid(phi, lam, indexing="ij")
    ring = radius * np.stack([np.sin(P) * np.cos(L), np.cos(P), -np.sin(P) * np.sin(L)], -1).reshape(-1, 3)
    V = np.concatenate([[[0.0, radius, 0.0]], ring, [[0.0, -radius, 0.0]]])
    north, south = 0, len(V) - 1

    def vid(i, j):
        return 1 + i * n_lon + j % n_lon

    def uid(i, j):
        return i * (n_lon + 1) + j

    U, W = np.meshgrid(np.arange(n_lon + 1) / n_lon, 1.0 - np.arange(1, n_lat + 1) / (n_lat + 1))
    centre = (np.arange(n_lon) + 0.5) / n_lon
    UV = np.concatenate([np.stack([U, W], -1).reshape(-1, 2),
                         np.stack([centre, np.ones(n_lon)], 1), np.stack([centre, np.zeros(n_lon)], 1)])
    UV = UV_MARGIN + (1.0 - 2.0 * UV_MARGIN) * UV
    north_uv, south_uv = n_lat * (n_lon + 1), n_lat * (n_lon + 1) + n_lon
    F, F_uv = [], []
    for j in range(n_lon):
        F += [[north, vid(0, j), vid(0, j + 1)], [south, vid(n_lat - 1, j + 1), vid(n_lat - 1, j)]]
        F_uv += [[north_uv + j, uid(0, j), uid(0, j + 1)], [south_uv + j, uid(n_lat - 1, j + 1), uid(n_lat - 1, j)]]
        for i in range(n_lat - 1):
            a, b, c, d = (i, j), (i, j + 1), (i + 1, j + 1), (i + 1, j)
            for tri in ((a, d, c), (a, c, b)):
                F.append([vid(*x) for x in tri])
                F_uv.append([uid(*x) for x in tri])
    return TexturedMesh(V, np.array(F), UV, np.array(F_uv))


def affine(V: np.ndarray) -> np.ndarray:
    return V @ AFFINE_A.T + AFFINE_B


def bumped(mesh: TexturedMesh, amplitude: float = 0.2, width_mm: float = 20.0) -> TexturedMesh:
    """``mesh`` with a smooth radial bump: r *= 1 + amplitude exp(-|x - x0|^2 / width^2), x0 on the +z side."""
    x0 = np.array([0.0, 0.0, RADIUS_MM])
    gain = 1.0 + amplitude * np.exp(-((mesh.V - x0) ** 2).sum(1) / width_mm**2)
    return mesh.with_vertices(mesh.V * gain[:, None])


def seam_vertices(mesh: TexturedMesh) -> np.ndarray:
    """Indices of the vertices with two or more distinct texture coordinates among their corners."""
    pairs = np.unique(np.column_stack([mesh.F.ravel(), mesh.F_uv.ravel()]), axis=0)
    counts = np.bincount(pairs[:, 0], minlength=len(mesh.V))
    return np.flatnonzero(counts >= 2)


@pytest.fixture(scope="module")
def template() -> TexturedMesh:
    return uv_sphere()


@pytest.fixture(scope="module")
def expression_rest(template) -> TexturedMesh:
    """The template refined twice (3x, then 2x): the same atlas and surface, another triangulation."""
    return refine_by_factor(refine_by_factor(template, 3.0), 2.0)


@pytest.fixture(scope="module")
def expression(expression_rest) -> TexturedMesh:
    return expression_rest.with_vertices(affine(expression_rest.V))


@pytest.fixture(scope="module")
def common2(template) -> TexturedMesh:
    return common_triangulation(template, 2 * len(template.V))


def test_fixture_is_a_closed_seamed_sphere(template, expression_rest, common2):
    t = template
    edges, face_edge = unique_edges(t.F)
    assert (np.bincount(face_edge.ravel()) == 2).all()
    assert len(t.V) - len(edges) + len(t.F) == 2
    assert (np.einsum("ij,ij->i", t.face_normals(), t.V[t.F].mean(1)) > 0).all()  # outward
    tri = t.UV[t.F_uv]
    e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    assert (e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0] > 0).all()  # counter-clockwise, no fold in the atlas
    np.testing.assert_allclose(np.linalg.norm(t.V, axis=1), RADIUS_MM, rtol=1e-15)
    # the expression is really another triangulation than the commons
    assert len(expression_rest.V) not in (len(t.V), len(common2.V))
    t.validate("template")


# --- 1. analytic: an affine expression --------------------------------------------------------------

@pytest.mark.parametrize("which", ["template", "common x2", "common x2 refined"])
def test_affine_expression_is_its_affine_image_exactly(which, template, expression, common2):
    common = {"template": template, "common x2": common2,
              # vertices strictly inside the expression's UV triangles too
              "common x2 refined": refine_by_factor(refine_by_factor(common2, 2.5), 2.5)}[which]
    out = remesh_onto(common, expression, "expression.obj")
    np.testing.assert_allclose(out.mesh.V, affine(common.V), rtol=0, atol=REMESH_EXACT_MM)
    assert out.seam_disagreement_mm <= REMESH_EXACT_MM
    assert out.off_atlas_uv <= LOCATED_ON_ATLAS_UV
    # the result carries the common triangulation itself
    for name in ("F", "UV", "F_uv"):
        np.testing.assert_array_equal(getattr(out.mesh, name), getattr(common, name))


# --- 2. identity and the common triangulation -------------------------------------------------------

def test_template_onto_itself_is_the_identity(template):
    out = remesh_onto(template, template)
    np.testing.assert_allclose(out.mesh.V, template.V, rtol=0, atol=REMESH_EXACT_MM)
    assert out.seam_disagreement_mm <= REMESH_EXACT_MM


@pytest.mark.parametrize("factor", [1, 2])
def test_common_triangulation_refines_the_template_on_its_surface(template, factor):
    n = factor * len(template.V)
    common = common_triangulation(template, n)
    assert len(common.V) >= n
    np.testing.assert_array_equal(common.V[: len(template.V)], template.V)  # the template's vertices first
    np.testing.assert_array_equal(common.UV[: len(template.UV)], template.UV)
    common.validate("common")
    hit = prepare_surface(template.V, template.F, find_boundary=False).closest(common.V)
    assert hit.distance.max() <= CLOSEST_POINT_F32_MM
    # and its texture coordinates are inside the template's atlas
    assert locate_uv(template, common.UV).distance.max() <= LOCATED_ON_ATLAS_UV


def test_common_triangulation_rejects_fewer_vertices_and_no_uvs(template):
    with pytest.raises(ValueError, match="at least"):
        common_triangulation(template, len(template.V) - 1)
    with pytest.raises(ValueError, match="texture coordinates"):
        common_triangulation(TexturedMesh(template.V, template.F), len(template.V))


@contextmanager
def alarm_after(seconds: int = 20):
    """Make a stuck refinement loop fail instead of hang."""
    def alarm(*_):
        raise TimeoutError(f"common_triangulation still running after {seconds} s")

    previous = signal.signal(signal.SIGALRM, alarm)
    signal.alarm(seconds)
    try:
        yield
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)


@pytest.mark.parametrize("target", [3 * 74, 10 * 74])
def test_common_triangulation_terminates_on_tied_edge_lengths(template, target):
    # the sphere's longest edges tie: a split by a length threshold would add none of them and loop forever
    assert len(template.V) == 74
    with alarm_after():
        common = common_triangulation(template, target)
    assert len(common.V) == target


# --- locating texture coordinates -----------------------------------------------------------------------

def test_locate_uv_finds_the_atlas_points(template, expression_rest):
    # every texture coordinate of a refinement lies in the template's atlas, on the right 3-D point
    where = locate_uv(template, expression_rest.UV)
    assert where.distance.max() <= LOCATED_ON_ATLAS_UV
    assert (where.barycentric >= 0).all()
    np.testing.assert_allclose(where.barycentric.sum(1), 1.0, rtol=0, atol=BARYCENTRIC_EXACT)
    at = positions_at_uv(template, where)
    corner_v = np.zeros(len(expression_rest.UV), dtype=np.int64)
    corner_v[expression_rest.F_uv.ravel()] = expression_rest.F.ravel()
    np.testing.assert_allclose(at, expression_rest.V[corner_v], rtol=0, atol=REMESH_EXACT_MM)
    # points outside get a positive distance
    assert (locate_uv(template, np.array([[0.5, 0.01], [0.99, 0.5], [0.5, 0.99]])).distance > 0.03).all()
    with pytest.raises(ValueError, match="texture coordinates"):
        locate_uv(TexturedMesh(template.V, template.F), template.UV)


def test_uv_index_answers_from_memory_what_a_fresh_index_answers(template, expression_rest):
    # identity: overlapping, repeated and shuffled queries to one index give exactly the fresh answers
    rng = np.random.default_rng(5)
    uv = expression_rest.UV
    first, second = uv[: len(uv) // 2], uv[rng.permutation(len(uv))]
    queries = np.concatenate([second[:50], second[:50], [[0.5, 0.01]]])  # duplicates and a point off the atlas
    index = UVIndex(template)
    for query in (first, second, queries):
        got, want = index.locate(query), UVIndex(template).locate(query)
        np.testing.assert_array_equal(got.face, want.face)
        np.testing.assert_array_equal(got.barycentric, want.barycentric)
        np.testing.assert_array_equal(got.distance, want.distance)
    assert len(index._keys) == len(np.unique(uv[:, 0] + 1j * uv[:, 1])) + 1  # each coordinate located once


def test_uv_index_answers_right_when_every_coordinate_shares_one_hash(template, expression_rest, monkeypatch):
    # the memory's keys are hashes: with the worst hash (one key for all) the answers are still a fresh index's
    monkeypatch.setattr(R, "hash_uv", lambda uv: np.zeros(len(uv), dtype=np.uint64))
    uv = expression_rest.UV
    index = UVIndex(template)
    for query in (uv[:40], uv[20:90], uv[::-1]):
        got, want = index.locate(query), R.UVIndex._locate(index, query)
        np.testing.assert_array_equal(got.face, want.face)
        np.testing.assert_array_equal(got.barycentric, want.barycentric)
        np.testing.assert_array_equal(got.distance, want.distance)


def distance_to_atlas(mesh: TexturedMesh, p: np.ndarray) -> float:
    """Exact float64 distance from the point ``p`` (2,) to the union of ``mesh``'s UV triangles (brute force)."""
    tri = mesh.UV[mesh.F_uv]  # counter-clockwise (test_fixture_is_a_closed_seamed_sphere)
    side = [(tri[:, (k + 1) % 3, 0] - tri[:, k, 0]) * (p[1] - tri[:, k, 1])
            - (tri[:, (k + 1) % 3, 1] - tri[:, k, 1]) * (p[0] - tri[:, k, 0]) for k in range(3)]
    if (np.stack(side, 1) >= 0).all(1).any():
        return 0.0
    best = np.inf
    for k in range(3):
        a, b = tri[:, k], tri[:, (k + 1) % 3]
        t = np.clip(((p - a) * (b - a)).sum(1) / ((b - a) ** 2).sum(1), 0.0, 1.0)
        best = min(best, float(np.linalg.norm(a + t[:, None] * (b - a) - p, axis=1).min()))
    return best


def test_locate_uv_distance_is_the_distance_to_the_atlas(template):
    queries = np.array([[0.5, 0.03], [0.97, 0.5], [0.3, 0.99], [0.5, 0.5]])
    got = locate_uv(template, queries).distance
    want = [distance_to_atlas(template, q) for q in queries]
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-6)  # float32 BVH picks the face (of equal distance)


def test_edge_uv_midpoints_are_the_midpoints_of_each_edge(template):
    edges, _ = unique_edges(template.F)
    mid = edge_uv_midpoints(template)
    assert mid.shape == (len(edges), 2)
    # on the (flat-faced) template each lands on the 3-D midpoint, whichever chart a seam edge took
    at = positions_at_uv(template, locate_uv(template, mid))
    np.testing.assert_allclose(at, 0.5 * (template.V[edges[:, 0]] + template.V[edges[:, 1]]), rtol=0,
                               atol=REMESH_EXACT_MM)


# --- 3. seams ---------------------------------------------------------------------------------------------

def test_seam_vertices_exist_once_and_agree(template, common2, expression):
    seams = seam_vertices(common2)
    # the template's seam: the meridian's rings and both poles; refinement adds seam midpoints
    assert set(seam_vertices(template)) == {0, len(template.V) - 1} | set(range(1, 1 + N_LAT * N_LON, N_LON))
    assert set(seams) >= set(seam_vertices(template))
    assert len(common2.UV) > len(common2.V)
    out = remesh_onto(common2, expression)
    V = out.mesh.V
    assert len(np.unique(V, axis=0)) == len(V)  # welded: no vertex twice in 3-D, seams included
    assert out.seam_disagreement_mm <= REMESH_EXACT_MM
    # every chart of a seam vertex put it where the result has it
    at_uv = positions_at_uv(expression, locate_uv(expression, common2.UV))
    corners = np.isin(common2.F, seams)
    np.testing.assert_allclose(at_uv[common2.F_uv[corners]], V[common2.F[corners]], rtol=0, atol=REMESH_EXACT_MM)


def shifted_seam_side(mesh: TexturedMesh, du: float) -> TexturedMesh:
    """A copy of ``mesh`` whose texture coordinates on the u = 1 side of the seam move by ``du`` in u."""
    UV = mesh.UV.copy()
    side = UV[:, 0] == SEAM_U
    assert side.sum() >= N_LAT
    UV[side, 0] += du
    return TexturedMesh(mesh.V, mesh.F, UV, mesh.F_uv)


def test_a_seam_whose_charts_disagree_is_rejected(common2, expression):
    # outward: the last column widens, every common texture coordinate stays in the atlas, but the u = 1
    # chart now puts the seam vertices millimetres away from the u = 0 chart
    broken = shifted_seam_side(expression, +SEAM_SHIFT_UV)
    assert locate_uv(broken, common2.UV).distance.max() <= UV_OFF_ATLAS
    with pytest.raises(InputError, match="seam") as err:
        remesh_onto(common2, broken, "broken.obj")
    assert err.value.path == "broken.obj"
    assert "outside the mesh's atlas" not in str(err.value)


def test_a_seam_side_moved_inward_leaves_the_atlas(common2, expression):
    # inward: the common's u = 1 coordinates are SEAM_SHIFT_UV outside the atlas, reported first
    broken = shifted_seam_side(expression, -SEAM_SHIFT_UV)
    with pytest.raises(InputError, match="texture parametrisation") as err:
        remesh_onto(common2, broken, "broken.obj")
    assert "outside the mesh's atlas" in str(err.value) and "seam" not in str(err.value)


def test_seam_agreement_threshold_is_what_it_says(common2, expression):
    # a shift whose seam disagreement is below SEAM_AGREEMENT_MM passes and is reported
    out = remesh_onto(common2, shifted_seam_side(expression, +1e-8))
    assert 0 < out.seam_disagreement_mm <= SEAM_AGREEMENT_MM


# --- 4. input errors --------------------------------------------------------------------------------------

def test_another_parametrisation_is_rejected(common2, expression):
    halved = TexturedMesh(expression.V, expression.F, 0.5 * expression.UV, expression.F_uv)
    with pytest.raises(InputError, match="texture parametrisation") as err:
        remesh_onto(common2, halved, "halved.obj")
    assert err.value.path == "halved.obj" and str(err.value).startswith("halved.obj: ")


def test_mesh_without_uvs_is_rejected(common2, expression):
    with pytest.raises(InputError, match="no texture coordinates") as err:
        remesh_onto(common2, TexturedMesh(expression.V, expression.F), "plain.ply")
    assert err.value.path == "plain.ply"


def test_nan_vertex_is_rejected(common2, expression):
    V = expression.V.copy()
    V[7, 1] = np.nan
    with pytest.raises(InputError, match="NaN") as err:
        remesh_onto(common2, expression.with_vertices(V), "nan.obj")
    assert err.value.path == "nan.obj"


# --- 5. barycentric_2d ------------------------------------------------------------------------------------

def test_barycentric_2d_corners_centroid_and_degenerate():
    a, b, c = np.array([[0.1, 0.2]]), np.array([[0.9, 0.3]]), np.array([[0.4, 0.8]])
    for k, p in enumerate((a, b, c)):
        np.testing.assert_allclose(barycentric_2d(p, a, b, c), np.eye(3)[[k]], rtol=0, atol=BARYCENTRIC_EXACT)
    np.testing.assert_allclose(barycentric_2d((a + b + c) / 3, a, b, c), [[1 / 3] * 3], rtol=0,
                               atol=BARYCENTRIC_EXACT)
    # batched, and outside the triangle: weights may be negative, and reproduce the point
    rng = np.random.default_rng(0)
    A, B, C, P = (rng.uniform(-1, 2, (50, 2)) for _ in range(4))
    w = barycentric_2d(P, A, B, C)
    np.testing.assert_allclose(w.sum(1), 1.0, rtol=0, atol=BARYCENTRIC_EXACT)
    np.testing.assert_allclose(w[:, :1] * A + w[:, 1:2] * B + w[:, 2:] * C, P, rtol=0, atol=1e-9)
    # degenerate: all corners equal, or collinear
    for tri in ((a, a, a), (a, b, 2 * b - a)):
        np.testing.assert_array_equal(barycentric_2d(np.array([[0.5, 0.5]]), *tri), [[1.0, 0.0, 0.0]])


# --- 6. chord errors -------------------------------------------------------------------------------------

def test_chord_errors_vanish_for_an_affine_expression(template, common2, expression):
    # the template's faces are flat and every common edge lies in one of them: so do its affine images
    for common in (template, common2, refine_by_factor(common2, 2.5)):
        errors = chord_errors(common, [expression])
        assert errors.shape == (len(unique_edges(common.F)[0]),)
        assert errors.max() <= REMESH_EXACT_MM


def test_chord_errors_see_a_bump(template, common2, expression, expression_rest):
    bump = bumped(expression_rest)
    errors = chord_errors(common2, [bump])
    assert errors.max() > 1.0  # measured 2.6 mm: coarse edges across a 10 mm bump
    # only near the bump: edges far from it (on the -z side) nearly lie on the flat template faces
    edges, _ = unique_edges(common2.F)
    far = (common2.V[edges, 2] < 0).all(1)
    assert far.any() and errors[far].max() <= FAR_FROM_BUMP_MM
    # over several meshes: the worst of each (the affine one adds nothing)
    np.testing.assert_allclose(chord_errors(common2, [expression, bump]), errors, rtol=0, atol=REMESH_EXACT_MM)


def flat_grid(n: int = 6, size_mm: float = 30.0) -> TexturedMesh:
    """A square grid in the plane z = 0 (n x n cells, two triangles each), UV = x / size, y / size."""
    t = np.linspace(0.0, 1.0, n + 1)
    X, Y = np.meshgrid(t, t, indexing="ij")
    UV = np.column_stack([X.ravel(), Y.ravel()])
    idx = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    F = np.concatenate([np.column_stack([a, b, c]), np.column_stack([a, c, d])])
    return TexturedMesh(np.column_stack([size_mm * UV, np.zeros(len(UV))]), F, UV, F.copy())


def test_offsets_at_uv_split_a_known_offset(template):
    # analytic: a point moved off its landing point by a along the face normal and b within the face's plane
    index = UVIndex(template)
    uv = edge_uv_midpoints(template)[:30]
    location = index.locate(uv)
    corners = template.V[template.F[location.face]]
    normal = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    in_plane = corners[:, 1] - corners[:, 0]
    in_plane /= np.linalg.norm(in_plane, axis=1, keepdims=True)
    a, b = np.linspace(-0.3, 0.3, 30), np.linspace(0.0, 0.5, 30)
    points = positions_at_uv(template, location) + a[:, None] * normal + b[:, None] * in_plane
    along, within = offsets_at_uv(template, index, uv, points)
    np.testing.assert_allclose(along, np.abs(a), rtol=0, atol=REMESH_EXACT_MM)
    np.testing.assert_allclose(within, b, rtol=0, atol=REMESH_EXACT_MM)


def test_chord_errors_split_a_slide_along_a_flat_surface_from_a_deviation():
    # a flat grid warped within its plane (a non-affine slide): every chord lies on the surface, its texture
    # does not: the whole offset sees the slide, the normal part nothing, the tangential part the slide scaled
    grid = flat_grid()
    common = common_triangulation(grid, 2 * len(grid.V))
    fine = refine_by_factor(refine_by_factor(grid, 3.0), 2.0)
    x, y = fine.V[:, 0], fine.V[:, 1]
    slid = fine.with_vertices(np.column_stack([x + 2.0 * np.sin(y / 6.0), y + 1.5 * np.cos(x / 7.0), fine.V[:, 2]]))
    whole = chord_errors(common, [slid])
    assert whole.max() > 0.05  # measured 0.17 mm
    assert chord_errors(common, [slid], tangential_scale=0.0).max() <= REMESH_EXACT_MM
    scaled = chord_errors(common, [slid], tangential_scale=0.25)
    assert (scaled >= 0.25 * whole - REMESH_EXACT_MM).all()  # the edges' own, at least (face centres add to it)
    assert scaled.max() <= 0.25 * 4.0 * whole.max()  # measured 0.042 = 0.25 x 0.17: the centres add nothing here
    # lifted out of the plane by a bump: now the normal part is there too
    bumped_grid = slid.with_vertices(slid.V + np.column_stack([0 * x, 0 * x, 3.0 * np.exp(-((x - 15) ** 2 + (y - 15) ** 2) / 40)]))
    assert chord_errors(common, [bumped_grid], tangential_scale=0.0).max() > 0.05


def test_chord_errors_see_a_fold_inside_a_face_with_four_face_samples():
    # analytic: a narrow bump (1 mm high, sigma 0.4 mm) halfway between one coarse face's centre and a corner;
    # the centre (and every edge midpoint) sees almost nothing of it, the face's samples halfway to the
    # corners see it all
    common = flat_grid(n=6)
    fine = flat_grid(n=100)
    A, B, C = common.V[common.F[0]]
    peak = (2 * A + 0.5 * B + 0.5 * C) / 3.0
    r2 = ((fine.V[:, :2] - peak[:2]) ** 2).sum(1)
    bump = fine.with_vertices(fine.V + np.column_stack([0 * r2, 0 * r2, np.exp(-r2 / (2 * 0.4 ** 2))]))
    centre_only = chord_errors(common, [bump], tangential_scale=0.0, face_samples=1)
    four = chord_errors(common, [bump], tangential_scale=0.0, face_samples=4)
    assert centre_only.max() < 0.05  # measured 0.014: the bump's tail at the nearest edge midpoint
    assert four.max() > 0.5  # measured 0.88 at n=150: the bump's height as the grid samples it
    assert (four >= centre_only - REMESH_EXACT_MM).all()  # the centre is still one of the samples
    with pytest.raises(ValueError):
        chord_errors(common, [bump], tangential_scale=0.0, face_samples=3)


@pytest.mark.parametrize("scale, samples", [(None, 1), (0.25, 1), (0.25, 4)])
def test_chord_error_cache_equals_chord_errors_as_the_triangulation_grows(common2, expression, expression_rest,
                                                                          scale, samples):
    # fit_triangulation's rounds: the cache recomputes only the edges of the faces each split made, and must give
    # the full computation's errors to the bit, seams (the sphere's) included
    meshes = {"bump": bumped(expression_rest), "affine": expression}
    cache = ChordErrorCache(meshes, scale, samples)
    common = common2
    for _ in range(3):
        errors = cache.errors(common)
        np.testing.assert_array_equal(errors, chord_errors(common, meshes, tangential_scale=scale, face_samples=samples))
        split = errors > np.quantile(errors, 0.8)
        assert split.any()
        common = split_edges(common, split)[0]
    # a mesh that did not grow from the last one is computed afresh
    np.testing.assert_array_equal(cache.errors(common2),
                                  chord_errors(common2, meshes, tangential_scale=scale, face_samples=samples))


# --- 7. fit_triangulation ---------------------------------------------------------------------------------

def test_fit_triangulation_converges_below_the_tolerance(template, common2, expression_rest):
    bump = bumped(expression_rest)
    lines: list[str] = []
    fit = fit_triangulation(common2, [bump], FIT_TOLERANCE_MM, max_vertices=100_000, max_rounds=FIT_MAX_ROUNDS,
                            progress=lines.append)
    # stopped by convergence: neither the round limit nor the vertex limit
    assert len(lines) < FIT_MAX_ROUNDS and lines[-1].endswith(f"0 edges above {FIT_TOLERANCE_MM:g} mm")
    assert chord_errors(fit, [bump]).max() <= FIT_TOLERANCE_MM
    assert len(fit.V) > len(common2.V)
    np.testing.assert_array_equal(fit.V[: len(common2.V)], common2.V)  # the common's, hence the template's, first
    np.testing.assert_array_equal(fit.V[: len(template.V)], template.V)
    fit.validate("fit")
    # it stays on the template's surface and atlas, and every expression goes onto it
    assert prepare_surface(template.V, template.F, find_boundary=False).closest(fit.V).distance.max() \
        <= CLOSEST_POINT_F32_MM
    out = remesh_onto(fit, bump)
    assert out.seam_disagreement_mm <= REMESH_EXACT_MM


def test_fit_triangulation_with_a_tangential_tolerance_converges_on_fewer_vertices(common2, expression_rest):
    bump = bumped(expression_rest)
    quiet = dict(max_vertices=100_000, max_rounds=FIT_MAX_ROUNDS, progress=lambda s: None)
    whole = fit_triangulation(common2, [bump], FIT_TOLERANCE_MM, **quiet)
    split = fit_triangulation(common2, [bump], FIT_TOLERANCE_MM, tangential_tolerance_mm=4 * FIT_TOLERANCE_MM, **quiet)
    assert chord_errors(split, [bump], tangential_scale=0.25).max() <= FIT_TOLERANCE_MM
    assert len(common2.V) < len(split.V) < len(whole.V)
    np.testing.assert_array_equal(split.V[: len(common2.V)], common2.V)


def test_fit_triangulation_respects_max_vertices(common2, expression_rest):
    bump = bumped(expression_rest)
    limit = len(common2.V) + 10  # the first round alone wants 47 splits at 0.1 mm
    fit = fit_triangulation(common2, [bump], FIT_TOLERANCE_MM, max_vertices=limit, max_rounds=FIT_MAX_ROUNDS,
                            progress=lambda s: None)
    assert len(fit.V) == limit  # the worst edges, up to the limit, and no further
    assert chord_errors(fit, [bump]).max() > FIT_TOLERANCE_MM
    # already at the limit: nothing to do
    same = fit_triangulation(fit, [bump], FIT_TOLERANCE_MM, max_vertices=limit, progress=lambda s: None)
    assert same is fit


def test_fit_triangulation_leaves_an_affine_expression_alone(common2, expression):
    assert fit_triangulation(common2, [expression], 1e-6, 100_000, progress=lambda s: None) is common2


# --- 8. regression ------------------------------------------------------------------------------------------

def test_regression_seeded_noise():
    """Pinned numbers, computed once with this code (numpy 2.4, Open3D 0.20, x86-64):

        template = uv_sphere(); rng = np.random.default_rng(7)
        rest = refine_by_factor(template, 2.5)
        noisy = rest.with_vertices(rest.V + rng.normal(scale=1.0, size=rest.V.shape))
        common = common_triangulation(template, 2 * 74)
        out = remesh_onto(common, noisy)
        len(out.mesh.V), out.mesh.V.sum(0).round(6), np.linalg.norm(out.mesh.V, axis=1).sum().round(6),
        len(fit_triangulation(common, [noisy], 0.5, 10_000, progress=lambda s: None).V)
    """
    template = uv_sphere()
    rng = np.random.default_rng(7)
    rest = refine_by_factor(template, 2.5)
    noisy = rest.with_vertices(rest.V + rng.normal(scale=1.0, size=rest.V.shape))
    common = common_triangulation(template, 2 * len(template.V))
    out = remesh_onto(common, noisy, "noisy")
    V = out.mesh.V
    assert (len(rest.V), len(V)) == (PINNED["rest"], PINNED["vertices"])
    np.testing.assert_allclose(V.sum(0), PINNED["sum"], rtol=0, atol=1e-6)
    np.testing.assert_allclose(np.linalg.norm(V, axis=1).sum(), PINNED["norm_sum"], rtol=0, atol=1e-6)
    assert out.seam_disagreement_mm <= REMESH_EXACT_MM  # noise on welded positions keeps seams consistent
    fit = fit_triangulation(common, [noisy], 0.5, 10_000, progress=lambda s: None)
    assert len(fit.V) == PINNED["fit_vertices"]


PINNED = {"rest": 174, "vertices": 148, "sum": [175.00531, -4.413204, -53.241744], "norm_sum": 7228.052873,
          "fit_vertices": 175}
