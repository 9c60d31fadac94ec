
import numpy as np
import trimesh

from gpja.data.synthetic.head import (HeadParams, OP_UNION, _row, build_head_program, evaluate_sdf,
                                      extract_rest_mesh, sample_head_params)

SDF_TOL_MM = 1e-9
AREA_REL_TOL = 0.02
COARSE_VOXEL_MM = 1.5


def test_sphere_sdf_is_exact():
    prog = np.stack([_row(OP_UNION, 0.0, (1.0, 2.0, 3.0), (10.0, 10.0, 10.0))])
    P = np.random.default_rng(0).uniform(-30, 30, (500, 3))
    d = evaluate_sdf(P, prog)
    assert np.allclose(d, np.linalg.norm(P - (1, 2, 3), axis=1) - 10.0, atol=SDF_TOL_MM)


def test_sdf_gradient_is_unit_near_surface():
    p = HeadParams()
    prog = build_head_program(p)["head"]
    V, _ = extract_rest_mesh(prog, COARSE_VOXEL_MM)
    X = V[:: max(1, len(V) // 2000)]
    h = 1e-3
    g = np.stack([(evaluate_sdf(X + e, prog) - evaluate_sdf(X - e, prog)) / (2 * h) for e in np.eye(3) * h], 1)
    n = np.linalg.norm(g, axis=1)
    assert np.median(n) > 0.85 and np.median(n) < 1.15


def test_head_is_genus_zero_adult_sized_and_seed_dependent():
    for seed in (0, 1):
        p = sample_head_params(np.random.default_rng(seed))
        V, F = extract_rest_mesh(build_head_program(p)["head"], COARSE_VOXEL_MM)
        m = trimesh.Trimesh(V, F, process=False)
        assert m.is_watertight and m.euler_number == 2 and m.volume > 0
        # head (above the neck) sizes in mm
        assert 140 < V[:, 0].max() - V[:, 0].min() < 185  # ears included
        assert 190 < V[:, 2].max() - V[:, 2].min() < 240
    a = sample_head_params(np.random.default_rng(0))
    b = sample_head_params(np.random.default_rng(1))
    assert a != b


def test_regression_default_head_volume():
    V, F = extract_rest_mesh(build_head_program(HeadParams())["head"], COARSE_VOXEL_MM)
    vol = trimesh.Trimesh(V, F, process=False).volume
    # litres: a bust with neck
    assert 3.6e6 < vol < 4.6e6
