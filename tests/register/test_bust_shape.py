"""Tests of gpja.register.bust_shape: the implicit bust surface and its ray sampling."""
from __future__ import annotations

import numpy as np

from gpja.register.bust_shape import BustShape, bust_sdf, project_to_surface, ray_dirs, surface_points

#: Largest |sdf| of a ray-cast or projected surface point, mm (22 bisections of a 2.5 mm step).
ON_SURFACE_MM = 1e-3


def test_rays_from_the_centre_hit_the_surface():
    shape = BustShape()
    theta, alpha = np.meshgrid(np.linspace(-np.pi, np.pi, 13), np.linspace(-0.8, 1.2, 7))
    P = surface_points(shape, shape.ray_centre(), theta, alpha)
    assert P.shape == (theta.size, 3)
    assert np.abs(bust_sdf(P, shape)).max() < ON_SURFACE_MM
    assert bust_sdf(shape.ray_centre(), shape) < 0


def test_directions_are_unit_and_face_forward_at_zero():
    D = ray_dirs(np.array([0.0, 0.5 * np.pi]), np.array([0.0, 0.0]))
    np.testing.assert_allclose(D, [[0, 0, 1], [1, 0, 0]], atol=1e-15)
    np.testing.assert_allclose(np.linalg.norm(ray_dirs(np.random.default_rng(0).normal(size=20),
                                                        np.random.default_rng(1).normal(size=20)), axis=1), 1.0)


def test_projection_takes_nearby_points_onto_the_surface():
    shape = BustShape()
    P = surface_points(shape, shape.ray_centre(), np.array([0.3, 2.0]), np.array([0.2, -0.3]))
    moved = P + np.array([[1.5, -1.0, 0.5], [-1.0, 0.5, 1.0]])
    assert np.abs(bust_sdf(project_to_surface(moved, shape), shape)).max() < ON_SURFACE_MM
