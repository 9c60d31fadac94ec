"""Tests of gpja.register.bust_placement: the bust placed over a scan."""
from __future__ import annotations

import hashlib

import numpy as np
import pytest

from gpja.errors import InputError
from gpja.register.bust_placement import fit_placement, place_bust
from tests.register.test_bust import bust_digest

#: Placed bust bounding box vs scan bounding box, relative to the scan's extent, per axis.
BBOX_REL_TOL = 0.15
#: Mean distance from scan points to the placed bust surface, mm.
SCAN_TO_BUST_MM = 10.0
#: Placement of the bust on its own front half (trimmed ICP on discrete samples; the neck slides in Y).
IDENTITY_SCALE, IDENTITY_SHIFT_MM, IDENTITY_MEAN_MM = 0.02, 3.0, 1.5


@pytest.fixture(scope="module")
def synthetic_scan():
    """Front part of a synthetic mouth-stretch head (marching cubes at 2.5 mm), like an MVS scan."""
    from gpja.data.synthetic.expressions import map_to_expression
    from gpja.data.synthetic.head import build_head_program, extract_rest_mesh, sample_head_params

    p = sample_head_params(np.random.default_rng(3))
    V, F = extract_rest_mesh(build_head_program(p)["head"], 2.5)
    V = map_to_expression(V, p, "3_mouth_stretch")
    n = np.zeros_like(V)
    fn = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    for k in range(3):
        np.add.at(n, F[:, k], fn)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    keep = (V[:, 1] > -165) & (n[:, 2] > -0.2) & ~((V[:, 1] > 60) & (n[:, 1] > 0.5)) & (n[:, 1] > -0.7)
    return V[keep]


def _dist_to_mesh(P, mesh):
    import open3d as o3d

    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(mesh.V.astype(np.float32)), o3d.core.Tensor(mesh.F.astype(np.uint32)))
    return scene.compute_distance(o3d.core.Tensor(P.astype(np.float32))).numpy()


def test_place_bust_overlaps_a_synthetic_scan(bust, synthetic_scan):
    scan = synthetic_scan
    # shift and shrink the scan: placement must follow
    scan = scan * 0.93 + np.array([4.0, -12.0, 7.0])
    placed = place_bust(bust, scan)
    d = _dist_to_mesh(scan, placed.mesh)
    assert d.mean() < SCAN_TO_BUST_MM
    lo_s, hi_s = scan.min(0), scan.max(0)
    ext = hi_s - lo_s
    # the bust is a whole head: compare where the scan is complete (X, front Z, the face's Y range)
    Vb = placed.mesh.V
    assert abs(Vb[:, 0].min() - lo_s[0]) < BBOX_REL_TOL * ext[0]
    assert abs(Vb[:, 0].max() - hi_s[0]) < BBOX_REL_TOL * ext[0]
    assert abs(Vb[:, 2].max() - hi_s[2]) < BBOX_REL_TOL * ext[2]
    assert Vb[:, 1].max() > hi_s[1] - BBOX_REL_TOL * ext[1] and Vb[:, 1].min() < lo_s[1] + BBOX_REL_TOL * ext[1]
    # the slit lands near the synthetic mouth (rest y -54 * face_length, shifted)
    assert placed.landmarks["mouth"][2] > placed.landmarks["pocket_end"][2]


def test_place_bust_identity_on_its_own_surface(bust):
    own = bust.mesh.V[bust.mesh.V[:, 2] > -20]
    s, t = fit_placement(bust, own)
    assert abs(s - 1) < IDENTITY_SCALE and np.linalg.norm(t) < IDENTITY_SHIFT_MM
    assert _dist_to_mesh(own, bust.transformed(s, t).mesh).mean() < IDENTITY_MEAN_MM


@pytest.mark.parametrize("scan", [np.zeros((0, 3)), np.full((500, 3), np.nan)])
def test_place_bust_rejects_an_empty_scan(bust, scan):
    with pytest.raises(InputError, match="scan"):
        place_bust(bust, scan)


def test_place_bust_rejects_a_scan_in_metres(bust, synthetic_scan):
    with pytest.raises(InputError, match="millimetres"):
        place_bust(bust, synthetic_scan / 1000.0)


#: sha256 of the (scale, translation) and ``bust_digest`` of the placed bust for the small bust's own front,
#: shrunk and shifted, computed with the code before the split of bust.py (x86-64, numpy 2.4).
PLACEMENT_SHA256 = "4161c9e447666d6f24e9a295564d701395f4e2b2d124230567c091c28739ccbf"
PLACED_BUST_SHA256 = "5f307a5caaa829077b52e21c16d4bc668940363097b31b3516688ed9ddeb87f3"


def test_placement_is_bitwise_unchanged(small_bust):
    own = small_bust.mesh.V[small_bust.mesh.V[:, 2] > -20] * 0.93 + np.array([4.0, -12.0, 7.0])
    s, t = fit_placement(small_bust, own)
    assert hashlib.sha256(np.float64(s).tobytes() + t.tobytes()).hexdigest() == PLACEMENT_SHA256
    assert bust_digest(place_bust(small_bust, own)) == PLACED_BUST_SHA256
