"""Tests of gpja.baselines.alignment: the similarity fit and NICP's correspondence rules."""
from __future__ import annotations

import numpy as np

from gpja.baselines.alignment import find_correspondences, similarity_transform
from gpja.baselines.nicp import NicpSettings
from gpja.surface import open_edges, prepare_surface, vertex_normals
from tests.baselines.test_nicp import bump, crop_back, ellipsoid, rigid_offset, unweld
from tests.tolerances import EXACT_F64


def test_similarity_transform_recovers_a_known_similarity():
    P = np.random.default_rng(0).normal(size=(20, 3)) * 50
    th = 0.3
    R = np.array([[np.cos(th), -np.sin(th), 0], [np.sin(th), np.cos(th), 0], [0, 0, 1]])
    Q = 1.2 * P @ R.T + [1.0, 2.0, 3.0]
    s, R2, t2 = similarity_transform(P, Q, allow_scale=True)
    assert abs(s - 1.2) < EXACT_F64 and np.abs(R2 - R).max() < EXACT_F64 and np.abs(t2 - [1, 2, 3]).max() < 1e-7
    s, _, _ = similarity_transform(P, Q, allow_scale=False)
    assert s == 1.0


def test_correspondences_reject_the_rim_the_same_on_an_unwelded_scan():
    V4, F4 = ellipsoid(4)
    V_s, F_s = crop_back(rigid_offset(bump(V4)), F4, z_min_mm=-30.0)
    V_u, F_u = unweld(V_s, F_s)
    assert open_edges(F_u).all()  # unwelded, every edge looks open: all of the scan would be rim
    V, F = ellipsoid(3)
    X = rigid_offset(bump(V))
    normals = vertex_normals(X, F)
    settings = NicpSettings()
    U_w, valid_w, dist_w = find_correspondences(prepare_surface(V_s, F_s), X, normals, settings)
    U_u, valid_u, dist_u = find_correspondences(prepare_surface(V_u, F_u), X, normals, settings)
    assert 0.3 < valid_w.mean() < 0.9  # the back of the template has no scan under it
    np.testing.assert_array_equal(valid_u, valid_w)
    np.testing.assert_array_equal(U_u, U_w)
    np.testing.assert_array_equal(dist_u, dist_w)
    _, kept, _ = find_correspondences(prepare_surface(V_u, F_u), X, normals, NicpSettings(reject_boundary=False))
    assert kept.mean() > valid_w.mean()  # it is the rim rule that rejects the back
