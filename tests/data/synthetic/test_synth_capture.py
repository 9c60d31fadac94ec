import math

import numpy as np
import pytest
import trimesh

from gpja.camera import Camera
from gpja.data.synthetic.capture import (BACKGROUND_RGB, RayBundle, build_scene, make_rig, make_sh, render_view,
                                         vertex_normals)
from gpja.lighting import irradiance_over_pi, uniform_sh

COLOUR_TOL = 2e-3


def _sphere_camera(size=48):
    K = np.array([[60.0, 0, (size - 1) / 2], [0, 60.0, (size - 1) / 2], [0, 0, 1]])
    return Camera.look_at((0, 0, 100.0), (0, 0, 0), (0, 1, 0), K, size, size)


def test_uniform_light_sphere_renders_albedo():
    s = trimesh.creation.icosphere(subdivisions=4, radius=10.0)
    V, F = np.asarray(s.vertices), np.asarray(s.faces)
    cam = _sphere_camera()
    img = render_view(build_scene(V, F), RayBundle(cam, 1), V, vertex_normals(V, F), F,
                      lambda X: np.full((len(X), 3), 0.5), uniform_sh(), np.ones(3))
    c = (cam.width - 1) // 2
    assert np.allclose(img[c, c], 0.5, atol=COLOUR_TOL)
    assert np.allclose(img[0, 0], BACKGROUND_RGB, atol=COLOUR_TOL)
    # disc radius: 60 px * 10 / sqrt(100^2 - 10^2)
    covered = (np.abs(img - BACKGROUND_RGB).sum(-1) > 1e-3).sum()
    r = 60.0 * 10.0 / math.sqrt(100.0 ** 2 - 10.0 ** 2)
    assert covered == pytest.approx(math.pi * r * r, rel=0.05)


def test_rig_looks_at_the_head_and_sh_is_positive():
    rng = np.random.default_rng(0)
    cams = make_rig(rng, 8, 64, 600.0)
    assert len(cams) == 8 and [c.name for c in cams] == [str(i) for i in range(8)]
    for c in cams:
        uv, z = c.project(np.array([[0.0, -20.0, 40.0]]))
        assert 0.3 * c.width < uv[0, 0] < 0.7 * c.width and 550 < z[0] < 650
        assert np.any(c.distortion != 0)
    sh = make_sh(rng)
    n = np.random.default_rng(1).normal(size=(2000, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    e = irradiance_over_pi(n, sh)
    assert e.min() > 0.2 and e.max() < 2.5


def test_rays_pass_through_distorted_pixels():
    cam = make_rig(np.random.default_rng(2), 1, 32, 600.0)[0]
    b = RayBundle(cam, 1)
    X = b.rays[:, :3].astype(np.float64) + 500.0 * b.rays[:, 3:].astype(np.float64)
    uv, _ = cam.project(X)
    grid = np.stack(np.meshgrid(np.arange(32.0), np.arange(32.0)), -1).reshape(-1, 2)
    assert np.abs(uv - grid).max() < 1e-3
