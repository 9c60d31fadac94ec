"""An artist's mesh carried onto every expression through the template's texture space (gpja/apply/reparam.py).

The "template" is a lat-long sphere of radius 50 mm with a UV seam; "expressions" are known maps of it that keep
its F, UV and F_uv (and a refined copy, which keeps its atlas but not its triangulation). The artist mesh is the
stand-in :func:`make_standin_artist_mesh` makes: the sphere decimated and unwrapped again by xatlas.
"""
import numpy as np
import pytest
from scipy import ndimage

from gpja.apply.reparam import (
    ARTIST_MAX_MEDIAN_MM, artist_on_template, carry_to_expression, check_artist_mesh, flipped_faces,
    make_standin_artist_mesh, resample_texture, template_uv_of_points, uv_signed_areas,
)
from gpja.folds import untangle_on_surface
from tests.test_folds import flat_grid, pushed
from gpja.apply.remesh import locate_uv, positions_at_uv
from gpja.errors import InputError
from gpja.mesh import TexturedMesh
from tests.apply import spheres as _spheres
from gpja.register.remesh import refine_by_factor
from gpja.surface import interpolate, prepare_surface
from tests.tolerances import CLOSEST_POINT_F32_MM, REMAP_POSITION_PX

#: A carried vertex lies on the expression's float64 triangles: a barycentric combination (weights summing to 1)
#: of one face's corners, measured here by an exact float64 point-triangle distance (float64 rounding), mm.
ON_SURFACE_MM = 1e-6
#: A carried vertex vs the expected point (the known map of the corners, combined with the closest point's
#: barycentrics), mm. Both are exact float64 combinations, except where ``locate_uv``'s float32 face search
#: (UVs shifted by 0.5: half an ulp is 3e-8 UV units) puts a texture coordinate that close to an edge in the
#: neighbouring face and clamps it onto the edge: at most ~3e-8 UV x ~350 mm per UV unit (the sphere's
#: circumference, stretched 1.1 times) = 1e-5 mm (measured 4e-7 mm).
CARRY_MM = 5e-5
#: The stand-in's vertices off the template's surface: the quadric collapse places them optimally for the
#: coarse faces, off the faceted sphere (measured 0.89 mm max, 0.42 mm median, for 768 -> 300 faces), mm.
STANDIN_NEAR_MM = 1.5
#: Texture coordinates of a point on the template vs its spherical angles (u = longitude / 2 pi,
#: v = 1 - polar angle / pi) away from the poles and the seam: the lat-long faceting interpolates the angles
#: linearly and the stand-in's points sit up to 0.9 mm off the sphere (measured 2.1e-3), UV units.
LATLONG_UV = 5e-3
#: The artist mesh rendered with the resampled texture vs the template with the shared one, mean over pixels
#: inside both silhouettes (eroded by 2 px), [0, 1] units: the ray meets the artist's surface, not the template's,
#: and the texture is resampled twice (measured 0.0013; the result shifted by half a texel: 0.0045; mirrored:
#: 0.3).
RENDER_MATCH = 0.003

#: A float32 mean of up to 8 equal values vs the value (a few ulps of 1), [0, 1] units.
MEAN_F32 = 1e-6

RADIUS = 50.0
N_LAT, N_LON = 16, 24  # rings between the poles, segments around: 386 positions, 768 faces
STANDIN_FACES = 300
TEXTURE = 64  # side of the shared texture, texels
ARTIST_TEXTURE = 96  # side of the resampled one (not a multiple: texel centres fall between the shared texels)


def texel_centres(size: int) -> np.ndarray:
    """(size * size, 2) texture coordinates of a (size, size) image's texel centres, row-major, row 0 at the top:
    u = (c + 0.5) / size, v = 1 - (r + 0.5) / size."""
    rows, cols = np.mgrid[0:size, 0:size]
    return np.column_stack([(cols.ravel() + 0.5) / size, 1.0 - (rows.ravel() + 0.5) / size])


def latlong_sphere() -> TexturedMesh:
    """A lat-long sphere of radius 50 mm (y up), outward counter-clockwise faces.

    UVs: u = longitude / 2 pi (the column u = 1 repeats the positions of u = 0: a seam), v = 1 - polar
    angle / pi; each pole has one UV per segment (u at the segment's middle).
    """
    return _spheres.latlong_sphere(N_LAT, N_LON, RADIUS)


def smooth_map(P: np.ndarray) -> np.ndarray:
    """The known "expression" map: anisotropic scaling and a 4 mm Gaussian bump (sigma 15 mm) in +z near the
    front (its largest slope, 0.16, keeps it one to one)."""
    bump = 4.0 * np.exp(-((P - np.array([0.0, 0.0, RADIUS])) ** 2).sum(axis=1) / (2 * 15.0 ** 2))
    Q = P * np.array([1.1, 0.9, 1.05])
    Q[:, 2] += bump
    return Q


AFFINE = np.array([[1.1, 0.1, 0.0], [0.0, 0.9, 0.05], [0.02, 0.0, 1.05]])
SHIFT = np.array([1.0, 2.0, 3.0])


def affine_map(P: np.ndarray) -> np.ndarray:
    return P @ AFFINE.T + SHIFT


def linear_texture(size: int = TEXTURE) -> np.ndarray:
    """(size, size, 3) float32: R = u, G = v of each texel centre (row 0 at the top: v near 1), B = 0."""
    uv = texel_centres(size).reshape(size, size, 2)
    return np.concatenate([uv, np.zeros((size, size, 1))], axis=-1).astype(np.float32)


def bilinear_of_linear(uv: np.ndarray, size: int = TEXTURE) -> np.ndarray:
    """What bilinear lookups of :func:`linear_texture` give at ``uv`` (..., 2): the UV itself, clamped to the
    outermost texel centres (the border texel repeats)."""
    return np.clip(uv, 0.5 / size, 1.0 - 0.5 / size)


def point_triangle_distance(P: np.ndarray, A: np.ndarray, B: np.ndarray, C: np.ndarray) -> np.ndarray:
    """Exact float64 distances (q, m) from points P (q, 3) to triangles (A, B, C) (m, 3) each: the distance to
    the plane where the projection falls inside, else to the nearest of the three edges."""
    P = P[:, None]
    n = np.cross(B - A, C - A)
    n = n / np.linalg.norm(n, axis=1, keepdims=True)
    height = ((P - A) * n).sum(-1)
    foot = P - height[..., None] * n
    inside = np.ones(height.shape, dtype=bool)
    for a, b in ((A, B), (B, C), (C, A)):
        inside &= (np.cross(b - a, foot - a) * n).sum(-1) >= 0
    best = np.where(inside, np.abs(height), np.inf)
    for a, b in ((A, B), (B, C), (C, A)):
        t = np.clip(((P - a) * (b - a)).sum(-1) / ((b - a) ** 2).sum(-1), 0.0, 1.0)
        best = np.minimum(best, np.linalg.norm(P - (a + t[..., None] * (b - a)), axis=-1))
    return best


def distance_to_mesh(P: np.ndarray, mesh: TexturedMesh) -> np.ndarray:
    """(q,) exact float64 distance from each of P (q, 3) to the mesh's surface (brute force over its faces)."""
    tri = mesh.V[mesh.F]
    return point_triangle_distance(P, tri[:, 0], tri[:, 1], tri[:, 2]).min(axis=1)


@pytest.fixture(scope="module")
def template() -> TexturedMesh:
    return latlong_sphere()


@pytest.fixture(scope="module")
def artist(template) -> TexturedMesh:
    return make_standin_artist_mesh(template, STANDIN_FACES)


@pytest.fixture(scope="module")
def template_uv(artist, template) -> np.ndarray:
    return artist_on_template(artist, template)


@pytest.fixture(scope="module")
def closest(artist, template):
    """The artist's closest template points: the surface, the Open3D hits."""
    surface = prepare_surface(template.V, template.F, find_boundary=False)
    return surface, surface.closest(artist.V)


# --- the fixtures themselves ----------------------------------------------------------------------------

def test_template_sphere_is_outward_seamed_and_counter_clockwise_in_uv(template):
    centroids = template.V[template.F].mean(axis=1)
    assert ((template.face_normals() * centroids).sum(axis=1) > 0).all()
    assert (uv_signed_areas(template.UV, template.F_uv) > 0).all()
    assert len(template.UV) > len(template.V)  # seam and poles split texture coordinates


# --- the stand-in artist mesh ---------------------------------------------------------------------------

def test_standin_is_coarser_near_the_template_and_unwrapped(artist, template):
    assert len(artist.F) < len(template.F) and len(artist.V) < len(template.V)
    assert abs(len(artist.F) - STANDIN_FACES) <= 0.05 * STANDIN_FACES
    artist.validate("stand-in")
    assert artist.has_uv and artist.texture is None
    assert (artist.UV >= 0).all() and (artist.UV <= 1).all()
    assert len(artist.UV) > len(artist.V)  # xatlas cut seams: the welded positions are shared by several UVs
    # every face keeps its 3-D orientation (outward) in UV: counter-clockwise with v up (OBJ convention)
    centroids = artist.V[artist.F].mean(axis=1)
    assert ((artist.face_normals() * centroids).sum(axis=1) > 0).all()
    assert (uv_signed_areas(artist.UV, artist.F_uv) > 0).mean() >= 0.99
    # its own triangulation, every vertex close to the template's surface
    assert distance_to_mesh(artist.V, template).max() <= STANDIN_NEAR_MM
    check_artist_mesh(artist, template, "stand-in.obj")  # passes the import checks


def test_standin_is_deterministic_and_the_seed_changes_it(artist, template):
    again = make_standin_artist_mesh(template, STANDIN_FACES)
    for name in ("V", "F", "UV", "F_uv"):
        np.testing.assert_array_equal(getattr(again, name), getattr(artist, name))
    other = make_standin_artist_mesh(template, STANDIN_FACES, seed=1)
    assert other.V.shape != artist.V.shape or not np.array_equal(other.V, artist.V)


def test_regression_standin_counts(artist):
    """Pinned outputs of pymeshlab 2025.7.post1 and xatlas 0.0.11 (re-pin after upgrading either)."""
    assert (len(artist.V), len(artist.F), len(artist.UV)) == (152, 300, 211)


# --- the map through texture space ------------------------------------------------------------------------

def test_tiny_analytic_square():
    """A flat 100 mm square (UV = xy / 100): points above it map to their xy / 100; an affine expression moves
    them to the affine image of their foot."""
    V = np.array([[0, 0, 0], [100, 0, 0], [100, 100, 0], [0, 100, 0]], dtype=float)
    F = np.array([[0, 1, 2], [0, 2, 3]])
    square = TexturedMesh(V, F, V[:, :2] / 100.0, F)
    P = np.array([[10, 20, 0.3], [75, 40, -0.2], [50, 50, 0.1], [33, 90, 0.0]])
    artist = TexturedMesh(P, np.array([[0, 1, 2], [0, 2, 3]]), np.array([[0, 0], [1, 0], [1, 1]], float),
                          np.array([[0, 1, 2], [0, 2, 1]]))
    uv = artist_on_template(artist, square)
    np.testing.assert_allclose(uv, P[:, :2] / 100.0, atol=CLOSEST_POINT_F32_MM / 100.0)
    carried = carry_to_expression(artist, uv, square.with_vertices(affine_map(V)), "square")
    foot = np.column_stack([P[:, :2], np.zeros(len(P))])
    np.testing.assert_allclose(carried.V, affine_map(foot), atol=CLOSEST_POINT_F32_MM)
    for name in ("F", "UV", "F_uv"):
        np.testing.assert_array_equal(getattr(carried, name), getattr(artist, name))


def test_identity_projects_the_artist_onto_the_template(artist, template, template_uv, closest):
    surface, hit = closest
    carried = carry_to_expression(artist, template_uv, template, "template")
    np.testing.assert_array_equal(carried.F, artist.F)
    np.testing.assert_array_equal(carried.UV, artist.UV)
    # the closest template point (Open3D's barycentrics on the float64 triangles)
    np.testing.assert_allclose(carried.V, interpolate(surface, hit, template.V), rtol=0, atol=CARRY_MM)
    assert distance_to_mesh(carried.V, template).max() <= ON_SURFACE_MM
    # and it is the closest point: its distance to the artist vertex is the exact distance to the surface
    np.testing.assert_allclose(np.linalg.norm(carried.V - artist.V, axis=1), distance_to_mesh(artist.V, template),
                               rtol=0, atol=CLOSEST_POINT_F32_MM)


def test_analytic_expression_gets_the_map_of_the_closest_points(artist, template, template_uv, closest):
    """The expression is the template's vertices mapped (same F, UV, F_uv): a point inside a template triangle
    goes to the same barycentric combination of the mapped corners, exactly (no chord error to allow for)."""
    _, hit = closest
    mapped = smooth_map(template.V)
    expression = template.with_vertices(mapped)
    carried = carry_to_expression(artist, template_uv, expression, "2_smile.obj")
    expected = np.einsum("qk,qkc->qc", hit.barycentric, mapped[template.F[hit.face]])
    np.testing.assert_allclose(carried.V, expected, rtol=0, atol=CARRY_MM)
    assert distance_to_mesh(carried.V, expression).max() <= ON_SURFACE_MM


def test_refined_expression_with_another_triangulation(artist, template, template_uv, closest):
    """The expression refines the template (other faces, same atlas): an affine map commutes with the midpoint
    splits, so the carried vertices are the affine image of the closest points; under the smooth map they still
    lie on the refined expression's surface."""
    surface, hit = closest
    refined = refine_by_factor(template, 2.5)
    assert len(refined.F) > len(template.F)
    on_template = interpolate(surface, hit, template.V)
    carried = carry_to_expression(artist, template_uv, refined.with_vertices(affine_map(refined.V)), "refined")
    np.testing.assert_allclose(carried.V, affine_map(on_template), rtol=0, atol=CARRY_MM)
    bumped = refined.with_vertices(smooth_map(refined.V))
    carried = carry_to_expression(artist, template_uv, bumped, "refined_bumped")
    assert distance_to_mesh(carried.V, bumped).max() <= ON_SURFACE_MM
    assert flipped_faces(affine_map(on_template), carried.V, artist.F) == 0


def test_carry_rejects_a_mesh_without_the_template_atlas(artist, template, template_uv):
    with pytest.raises(InputError, match=r"bare\.obj: the mesh has no texture coordinates"):
        carry_to_expression(artist, template_uv, TexturedMesh(template.V, template.F), "bare.obj")
    shrunk = TexturedMesh(template.V, template.F, 0.5 * template.UV, template.F_uv)
    with pytest.raises(InputError, match=r"other\.obj: .* outside the mesh's atlas: the mesh does not "
                                         r"share the template's texture parametrisation"):
        carry_to_expression(artist, template_uv, shrunk, "other.obj")
    nan = template.V.copy()
    nan[3, 1] = np.nan
    with pytest.raises(InputError, match=r"nan\.obj: 1 vertices have NaN"):
        carry_to_expression(artist, template_uv, template.with_vertices(nan), "nan.obj")


# --- flipped faces --------------------------------------------------------------------------------------

def test_flipped_faces_analytic_on_a_flat_grid():
    """A flat grid (every normal +z): a rotation about z flips nothing, a mirror or a half turn about x flips
    every face, one vertex pushed across its neighbour flips its fan."""
    x, y = np.meshgrid(np.arange(4.0), np.arange(4.0))
    V = np.column_stack([x.ravel(), y.ravel(), np.zeros(16)])
    F = np.array([[i * 4 + j, i * 4 + j + 1, i * 4 + j + 5] for i in range(3) for j in range(3)]
                 + [[i * 4 + j, i * 4 + j + 5, i * 4 + j + 4] for i in range(3) for j in range(3)])
    c, s = np.cos(2.0), np.sin(2.0)
    assert flipped_faces(V, V @ np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]).T, F) == 0
    assert flipped_faces(V, V * np.array([-1.0, 1.0, 1.0]), F) == len(F)
    assert flipped_faces(V, V * np.array([1.0, -1.0, -1.0]), F) == len(F)
    moved = V.copy()
    moved[5, 0] = 2.5  # vertex (1, 1) past (2, 1): the faces on its right turn over
    expected = int(((np.cross(moved[F[:, 1]] - moved[F[:, 0]], moved[F[:, 2]] - moved[F[:, 0]]))[:, 2] < 0).sum())
    assert flipped_faces(V, moved, F) == expected > 0
    assert flipped_faces(V, np.zeros_like(V), F) == 0  # degenerate faces count as not flipped


def test_flipped_faces_on_the_sphere(artist, template, template_uv):
    on_template = carry_to_expression(artist, template_uv, template, "template").V
    assert flipped_faces(on_template, on_template, artist.F) == 0
    smiled = carry_to_expression(artist, template_uv, template.with_vertices(smooth_map(template.V)), "smile").V
    assert flipped_faces(on_template, smiled, artist.F) == 0
    assert flipped_faces(template.V, smooth_map(template.V), template.F) == 0
    assert flipped_faces(on_template, on_template * np.array([-1.0, 1.0, 1.0]), artist.F) > 0


# --- untangling the carried mesh ------------------------------------------------------------------------

def test_untangle_is_the_identity_without_folds_or_rounds(artist, template, template_uv):
    """A fold-free carried mesh comes back bit for bit; 0 rounds returns a folded one unchanged."""
    surface = prepare_surface(template.V, template.F, find_boundary=False)
    on_template = carry_to_expression(artist, template_uv, template, "template").V
    out, log = untangle_on_surface(on_template, artist.F, surface, iterations=100, rings=1)
    np.testing.assert_array_equal(out, on_template)
    assert log == {"folded_before": 0, "folded_after": 0, "rounds": 0, "moved_vertices": 0, "max_move_mm": 0.0}
    V, F = flat_grid()
    moved = pushed(V)
    out, log = untangle_on_surface(moved, F, surface, iterations=0, rings=1)
    np.testing.assert_array_equal(out, moved)
    assert log["folded_before"] == log["folded_after"] > 0 and log["rounds"] == 0


# --- the shared texture in the artist's layout ----------------------------------------------------------

def test_resample_onto_the_template_itself_gives_the_texel_centres(template):
    """The template as its own "artist": texel (r, c) is the texture coordinate ((c + 0.5) / S,
    1 - (r + 0.5) / S), so R = u and G = v of the linear texture come back there; row 0 is the top (v near 1)."""
    out, covered = resample_texture(template, template, linear_texture(), ARTIST_TEXTURE, padding=0)
    assert out.shape == (ARTIST_TEXTURE, ARTIST_TEXTURE, 3) and out.dtype == np.float32
    assert covered.shape == (ARTIST_TEXTURE, ARTIST_TEXTURE) and covered.dtype == bool
    assert covered.mean() > 0.9  # the lat-long atlas fills the square but for the poles' saw teeth
    expected = bilinear_of_linear(texel_centres(ARTIST_TEXTURE).reshape(ARTIST_TEXTURE, ARTIST_TEXTURE, 2))
    np.testing.assert_allclose(out[..., :2][covered], expected[covered], rtol=0, atol=REMAP_POSITION_PX / TEXTURE)
    assert (out[0, covered[0], 1] > 0.98).all() and (out[-1, covered[-1], 1] < 0.02).all()  # row 0 = top
    assert (out[covered[:, 0], 0, 0] < 0.02).all() and (out[covered[:, -1], -1, 0] > 0.98).all()  # column 0 = left
    assert (out[~covered] == 0).all()  # no padding: the gutter stays black


def test_resample_standin_shows_the_template_uv_of_each_texel(artist, template):
    texture = linear_texture()
    out, covered = resample_texture(artist, template, texture, ARTIST_TEXTURE, padding=0)
    assert covered.mean() > 0.3
    # each covered texel's 3-D point on the artist mesh and its template texture coordinate
    location = locate_uv(artist, texel_centres(ARTIST_TEXTURE))
    points = positions_at_uv(artist, location).reshape(ARTIST_TEXTURE, ARTIST_TEXTURE, 3)[covered]
    uv = template_uv_of_points(template, points)
    np.testing.assert_allclose(out[covered][:, :2], bilinear_of_linear(uv), rtol=0, atol=REMAP_POSITION_PX / TEXTURE)
    # independently of that route: the template's UVs are the points' longitude and latitude (nearly)
    u = (np.arctan2(-points[:, 2], points[:, 0]) / (2 * np.pi)) % 1.0
    v = 1.0 - np.arccos(np.clip(points[:, 1] / np.linalg.norm(points, axis=1), -1, 1)) / np.pi
    away = (np.abs(points[:, 1]) < 0.8 * RADIUS) & (u > 0.02) & (u < 0.98)
    assert away.sum() > 1000
    np.testing.assert_allclose(out[covered][away, :2], np.column_stack([u, v])[away], rtol=0, atol=LATLONG_UV)


def test_resample_pads_the_charts_and_leaves_the_rest_black(artist, template):
    texture = linear_texture() + 0.1  # every value positive: a filled texel is non-zero
    bare, covered = resample_texture(artist, template, texture, ARTIST_TEXTURE, padding=0)
    padded, covered_again = resample_texture(artist, template, texture, ARTIST_TEXTURE, padding=3)
    np.testing.assert_array_equal(covered_again, covered)
    np.testing.assert_array_equal(padded[covered], bare[covered])  # the charts are untouched
    ring = ndimage.binary_dilation(covered, structure=np.ones((3, 3), bool), iterations=3)
    assert (padded[ring & ~covered] > 0).all(axis=-1).all()
    assert (padded[~ring] == 0).all()
    lo, hi = bare[covered].min(axis=0), bare[covered].max(axis=0)
    assert ((padded[ring] >= lo - MEAN_F32) & (padded[ring] <= hi + MEAN_F32)).all()  # means of neighbours


def test_render_of_the_artist_matches_the_template(artist, template):
    """The artist mesh rendered with the resampled texture shows what the template shows with the shared one
    (the renderer's texel convention is the one the resampling uses)."""
    from gpja.metrics.photometric import render_with_texture
    from gpja.render import render_scan_targets
    from tests.render.scenes import ring_cameras

    v, u = np.mgrid[0:TEXTURE, 0:TEXTURE].astype(np.float32) / TEXTURE
    shared = np.stack([0.5 + 0.4 * np.sin(4 * np.pi * u), 0.5 + 0.4 * np.cos(3 * np.pi * v),
                       0.5 + 0.3 * np.sin(2 * np.pi * (u + v))], axis=-1)
    resampled, _ = resample_texture(artist, template, shared, 256)
    cameras = ring_cameras(2, 64, distance=250.0)
    sh = np.zeros((9, 3))
    sh[0] = 2.0 * np.sqrt(np.pi)  # uniform white light: radiance = albedo
    reference = render_with_texture(template, shared, cameras, sh)
    render = render_with_texture(artist, resampled, cameras, sh)
    inside = ((render_scan_targets(template.V, template.F, cameras)["coverage"][..., 0].numpy() > 0.999)
              & (render_scan_targets(artist.V, artist.F, cameras)["coverage"][..., 0].numpy() > 0.999))
    inside = np.stack([ndimage.binary_erosion(view, iterations=2) for view in inside])
    assert inside.sum() > 1000
    assert np.abs(render - reference)[inside].mean() < RENDER_MATCH
    mirrored = render_with_texture(artist, np.ascontiguousarray(resampled[::-1]), cameras, sh)
    assert np.abs(mirrored - reference)[inside].mean() > 10 * RENDER_MATCH


# --- bad artist meshes ----------------------------------------------------------------------------------

def test_artist_without_uvs_is_rejected(artist, template):
    with pytest.raises(InputError, match=r"artist\.obj: the artist mesh has no texture coordinates"):
        check_artist_mesh(TexturedMesh(artist.V, artist.F), template, "artist.obj")


def test_artist_in_metres_is_rejected(artist, template):
    metres = artist.with_vertices(artist.V / 1000.0)
    with pytest.raises(InputError, match=r"artist\.obj: the artist mesh looks like it is in different units "
                                         r"\(bounding box diagonal 0\.17\d* mm against the template's 17\d\.?\d* mm\); "
                                         r"the artist mesh must be in millimetres in the template expression's frame"):
        check_artist_mesh(metres, template, "artist.obj")


def test_artist_in_another_frame_is_rejected(artist, template):
    shifted = artist.with_vertices(artist.V + np.array([20.0, 0.0, 0.0]))
    with pytest.raises(InputError, match=r"artist\.obj: the artist mesh is too far from the template's surface: "
                                         r"its vertices are [\d.]+ mm from it \(median\) and [\d.]+ mm \(95th "
                                         r"percentile\), at most 1 mm and 5 mm allowed") as err:
        check_artist_mesh(shifted, template, "artist.obj")
    median = float(err.value.problem.split("vertices are ")[1].split(" mm")[0])
    assert median > ARTIST_MAX_MEDIAN_MM


def test_artist_with_nan_is_rejected(artist, template):
    V = artist.V.copy()
    V[7, 2] = np.nan
    with pytest.raises(InputError, match=r"artist\.obj: 1 vertices have NaN or infinite coordinates "
                                         r"\(first: vertex 7\)"):
        check_artist_mesh(artist.with_vertices(V), template, "artist.obj")
    with pytest.raises(InputError, match=r"artist\.obj: empty mesh"):
        check_artist_mesh(TexturedMesh(np.zeros((0, 3)), np.zeros((0, 3), int)), template, "artist.obj")
