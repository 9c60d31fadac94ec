import numpy as np
import pytest

from gpja.render.uv_raster import rasterize_uv, seam_copies, uv_charts, uv_to_texel
from tests.register.test_remesh import seamed_sphere
from tests.tolerances import EXACT_F64, UV_RASTER_BARY


def texel_centres(texels):
    return np.stack([(texels.cols + 0.5) / texels.size, 1.0 - (texels.rows + 0.5) / texels.size], axis=1)


def test_half_square_analytic():
    # the triangle below the anti-diagonal u + v <= 1: texel (r, c) is inside iff (c + 0.5) + (T - r - 0.5) < T
    UV = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
    T = 16
    tx = rasterize_uv(UV, np.array([[0, 1, 2]]), T)
    r, c = np.mgrid[0:T, 0:T]
    inside = (c + 0.5) / T + 1.0 - (r + 0.5) / T < 1.0
    off_edge = c != r  # centres on the hypotenuse go to one side by the fill rule
    assert np.array_equal((tx.face_image >= 0)[off_edge], inside[off_edge])
    # barycentrics give back the texel centre (affine map)
    np.testing.assert_allclose(tx.bary @ UV, texel_centres(tx), atol=EXACT_F64)
    np.testing.assert_allclose(tx.bary.sum(1), 1.0, atol=EXACT_F64)


def test_surface_points_of_a_flat_atlas_are_the_texel_centres():
    # a unit square in UV mapped to a 100 mm square: texel centre (u, v) is the point (100 u, 100 v, 0)
    UV = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    F = np.array([[0, 1, 2], [0, 2, 3]])
    V = np.concatenate([UV * 100.0, np.zeros((4, 1))], axis=1)
    tx = rasterize_uv(UV, F, 32)
    assert len(tx.rows) == 32 * 32  # shared diagonal: every texel exactly once
    np.testing.assert_allclose(tx.surface(V, F)[:, :2], 100.0 * texel_centres(tx), atol=1e-9)
    image = tx.scatter(tx.surface(V, F)[:, 0])
    assert image.shape == (32, 32) and image[0, 0] == pytest.approx(100.0 * 0.5 / 32)


def test_every_texel_belongs_to_one_face_of_a_closed_atlas():
    m = seamed_sphere(3)
    tx = rasterize_uv(m.UV, m.F_uv, 64)
    assert len(np.unique(tx.flat)) == len(tx.flat)
    assert tx.bary.min() >= -UV_RASTER_BARY and tx.bary.max() <= 1 + UV_RASTER_BARY
    # the texel count matches the atlas area (up to the texels along the outline)
    e1, e2 = m.UV[m.F_uv[:, 1]] - m.UV[m.F_uv[:, 0]], m.UV[m.F_uv[:, 2]] - m.UV[m.F_uv[:, 0]]
    area = 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]).sum() * 64 * 64
    assert abs(len(tx.rows) - area) < 4 * 64


def test_charts_are_uv_connected_components_in_first_face_order():
    # faces 0 and 2 share UV rows 4 and 5; face 1 uses rows of its own
    F_uv = np.array([[3, 4, 5], [0, 1, 2], [4, 6, 5]])
    assert uv_charts(F_uv).tolist() == [0, 1, 0]
    assert uv_charts(F_uv, n_uv=9).tolist() == [0, 1, 0]  # unused UV rows form no chart
    assert np.unique(uv_charts(seamed_sphere(3).F_uv)).tolist() == [0]


def test_seam_copies_pair_distinct_uvs_of_one_vertex():
    m = seamed_sphere(3)
    pairs = seam_copies(m.F, m.F_uv)
    assert len(pairs) > 0 and (pairs[:, 0] != pairs[:, 1]).all()
    vertex_of = np.empty(len(m.UV), np.int64)
    vertex_of[m.F_uv.ravel()] = m.F.ravel()
    assert np.array_equal(vertex_of[pairs[:, 0]], vertex_of[pairs[:, 1]])
    # the sphere's seam copies sit one atlas width (1 / 1.5) apart in u
    np.testing.assert_allclose(np.abs(m.UV[pairs[:, 0], 0] - m.UV[pairs[:, 1], 0]), 1 / 1.5, atol=EXACT_F64)
    # a mesh without seams has none
    assert seam_copies(m.F, m.F).shape == (0, 2)


def test_uv_to_texel_puts_texel_centres_at_integers():
    xy = uv_to_texel(np.array([[0.5 / 8, 1 - 0.5 / 8], [1.0, 0.0]]), 8)
    np.testing.assert_allclose(xy, [[0.0, 0.0], [7.5, 7.5]], atol=EXACT_F64)
