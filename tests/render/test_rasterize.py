import numpy as np
import open3d as o3d
import pytest
import torch

from gpja.render import project_to_screen, rasterize
from gpja.render.rasterize import rasterize_with_facing
from tests.render.scenes import ring_cameras, sphere
from tests.tolerances import TRI_ID_MISMATCH


def coverage(xy, faces, size=12):
    screen = np.concatenate([np.asarray(xy, float), np.full((len(xy), 1), 100.0)], 1)[None]
    tri, _ = rasterize(screen, np.asarray(faces), size, size)
    return tri[0]


def test_square_split_along_diagonal_covers_each_pixel_once():
    # pixel centres strictly inside [1.5, 6.5]^2 are x, y in 2..6; the diagonal passes through centres
    xy = [[1.5, 1.5], [6.5, 1.5], [6.5, 6.5], [1.5, 6.5]]
    a = coverage(xy, [[0, 2, 1]]) >= 0
    b = coverage(xy, [[0, 3, 2]]) >= 0
    expected = np.zeros((12, 12), bool)
    expected[2:7, 2:7] = True
    assert not (a & b).any()  # no pixel twice
    np.testing.assert_array_equal(a | b, expected)  # no pinhole on the shared edge


def test_random_fan_is_watertight():
    rng = np.random.default_rng(0)
    k = 9
    angles = np.sort(rng.uniform(0, 2 * np.pi, k))
    ring = np.stack([20 + 15 * np.cos(angles), 20 + 15 * np.sin(angles)], 1) + rng.uniform(-0.5, 0.5, (k, 2))
    xy = np.concatenate([[[20.13, 19.77]], ring])
    faces = [[0, 1 + i, 1 + (i + 1) % k] for i in range(k)]
    count = sum((coverage(xy, [f], size=40) >= 0).astype(int) for f in faces)
    assert count.max() == 1
    # every pixel centre strictly inside the polygon (away from its outline) is covered
    from matplotlib.path import Path

    yy, xx = np.mgrid[0:40, 0:40]
    inside = Path(ring).contains_points(np.stack([xx.ravel(), yy.ravel()], 1), radius=-0.01).reshape(40, 40)
    assert (count[inside] == 1).all()


def test_depth_order_nearest_wins():
    xy = np.array([[2, 2], [10, 2], [2, 10.0]] * 2)
    screen = np.concatenate([xy, [[100], [100], [100], [50], [50], [50]]], 1)[None]
    tri, depth = rasterize(screen, np.array([[0, 2, 1], [3, 5, 4]]), 12, 12)
    assert (tri[0][tri[0] >= 0] == 1).all()
    assert np.allclose(depth[0][tri[0] >= 0], 50)


def test_equal_depths_go_to_the_lower_face_index_in_any_visiting_order():
    # the same triangle twice (exact ties), and a third in the same plane over part of it
    xy = np.array([[2, 2], [10, 2], [2, 10.0], [2, 2], [10, 2], [2, 10.0], [4, 4], [9, 4], [4, 9.0]])
    screen = np.concatenate([xy, np.full((9, 1), 100.0)], 1)[None]
    faces = np.array([[3, 5, 4], [0, 2, 1], [6, 8, 7]])
    expected = rasterize_with_facing(screen, faces, 12, 12)
    assert 1 not in expected[0]  # face 1 is face 0 again: it never wins a pixel
    for ids in ([2, 1, 0], [1, 2, 0], [1, 0, 2]):
        ids = np.array(ids)
        got = rasterize_with_facing(screen, faces, 12, 12, visit=(ids, faces[ids]))
        for a, b in zip(got, expected):
            np.testing.assert_array_equal(a, b)
    assert expected[2].tolist() == [[True, True, True]]


def test_any_visiting_order_gives_the_same_output():
    V, F = sphere(subdivisions=3)
    screen = project_to_screen(torch.tensor(V), ring_cameras(3, 64)).numpy()
    F = np.concatenate([F, F[:40]])  # duplicated faces: exact ties on every pixel they cover
    expected = rasterize_with_facing(screen, F, 64, 64, cull_backfaces=True)
    for seed in range(3):
        ids = np.random.default_rng(seed).permutation(len(F))
        got = rasterize_with_facing(screen, F, 64, 64, cull_backfaces=True, visit=(ids, F[ids]))
        for a, b in zip(got, expected):
            np.testing.assert_array_equal(a, b)
    with pytest.raises(ValueError, match="visit order"):
        rasterize_with_facing(screen, F, 64, 64, visit=(np.arange(3), F[:3]))


def test_backface_culling():
    xy = [[2, 2], [10, 2], [2, 10]]
    # (0, 2, 1) is front-facing (negative area in y-down pixels), (0, 1, 2) faces away
    assert (coverage(xy, [[0, 2, 1]]) >= 0).any()
    screen = np.concatenate([np.array(xy, float), np.full((3, 1), 100.0)], 1)[None]
    assert (rasterize(screen, np.array([[0, 1, 2]]), 12, 12, cull_backfaces=True)[0] < 0).all()
    assert (rasterize(screen, np.array([[0, 2, 1]]), 12, 12, cull_backfaces=True)[0] >= 0).any()


def test_triangle_ids_match_open3d_ray_casting():
    V, F = sphere(subdivisions=4)
    cams = ring_cameras(3, 96)
    screen = project_to_screen(torch.tensor(V), cams).numpy()
    tri, _ = rasterize(screen, F, 96, 96)
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(V.astype(np.float32)), o3d.core.Tensor(F.astype(np.uint32)))
    for b, cam in enumerate(cams):
        v, u = np.mgrid[0:96, 0:96]
        o, d = cam.pixel_rays(np.stack([u.ravel(), v.ravel()], 1))
        hit = scene.cast_rays(o3d.core.Tensor(np.concatenate([o, d], 1).astype(np.float32)))
        ids = hit["primitive_ids"].numpy().astype(np.int64)
        ids[ids == o3d.t.geometry.RaycastingScene.INVALID_ID] = -1
        assert (ids != tri[b].ravel()).mean() <= TRI_ID_MISMATCH


def test_zero_size_image_rejected():
    with pytest.raises(ValueError, match="image size must be positive"):
        rasterize(np.zeros((1, 3, 3)), np.array([[0, 1, 2]]), 0, 10)


def test_regression_sphere_coverage():
    V, F = sphere(subdivisions=3)
    screen = project_to_screen(torch.tensor(V), ring_cameras(1, 64)).numpy()
    tri, depth = rasterize(screen, F, 64, 64)
    assert int((tri >= 0).sum()) == REGRESSION_COVERED
    assert abs(float(depth[depth < np.inf].min()) - REGRESSION_NEAREST) < 1e-3


REGRESSION_COVERED = 556
REGRESSION_NEAREST = 344.677  # camera 400 mm away, 0.15 elevation, faceted r = 60 sphere
