import numpy as np
import pytest
import torch

from gpja.mesh import TexturedMesh
from gpja.register.hra import ExpressionTargets, Switches
from gpja.register.multiscale import RegistrationDiverged, Schedule, optimise
from gpja.render import render_scan_targets
from tests.render.scenes import sphere, spherical_uv
from tests.render.test_passes import surface_distance, tetrahedral_cameras

#: A fast registration must cut the Chamfer distance at least this much (issue 4: 5x in CI).
MIN_CHAMFER_REDUCTION = 5.0


def ellipsoid_targets(size=80):
    Vt, Ft = sphere(subdivisions=5, radius=1.0)
    Vt = Vt * np.array([75.0, 60.0, 45.0])
    cams = tetrahedral_cameras(size)
    t = render_scan_targets(Vt, Ft, cams)
    images = torch.zeros(len(cams), size, size, 3)
    return Vt, Ft, ExpressionTargets(cams, images, t["depth"], t["normal"], t["coverage"], torch.zeros(9, 3))


def start_mesh():
    V, F = sphere(subdivisions=2, radius=55.0)
    return TexturedMesh(V, F, spherical_uv(V), F)


def chamfer(mesh, Vt, Ft):
    return 0.5 * (surface_distance(mesh.V, Vt, Ft).mean() + surface_distance(Vt, mesh.V, mesh.F).mean())


def test_two_level_registration_converges_and_refines():
    Vt, Ft, targets = ellipsoid_targets()
    mesh = start_mesh()
    schedule = Schedule(lambdas=(20.0, 10.0), iterations=(120, 120), lr_fraction=0.1)
    out, log = optimise(mesh, targets, Switches(color=False), schedule, texture=torch.ones(4, 4, 3),
                        mask_texture=torch.ones(4, 4, 1), progress_every=0)
    assert chamfer(mesh, Vt, Ft) / chamfer(out, Vt, Ft) >= MIN_CHAMFER_REDUCTION
    assert [lvl["vertices"] for lvl in log.levels] == [len(mesh.V), len(out.V)]
    assert 2.2 < len(out.V) / len(mesh.V) < 2.8
    assert set(log.levels[0]["losses"]) == {"depth", "normal"}
    assert len(log.levels[0]["losses"]["depth"]) == 60  # rotation: one constraint per iteration
    np.testing.assert_array_equal(out.UV[: len(mesh.UV)], mesh.UV)  # parametrisation kept


def test_nan_names_level_and_iteration():
    Vt, Ft, targets = ellipsoid_targets(size=32)
    targets.depth = targets.depth.clone()
    targets.depth[0, 16, 16, 0] = float("nan")
    with pytest.raises(RegistrationDiverged, match=r"level 0, iteration \d+: the depth loss is nan"):
        optimise(start_mesh(), targets, Switches(color=False, normal=False), Schedule(lambdas=(20.0,), iterations=(5,)),
                 texture=torch.ones(4, 4, 3), mask_texture=torch.ones(4, 4, 1), progress_every=0)


def test_learning_rate_decays_geometrically_within_a_level():
    constant = Schedule(lambdas=(10.0,), iterations=(5,))
    assert [constant.learning_rate(2.0, i, 5) for i in range(5)] == [2.0] * 5  # the paper: constant
    decayed = Schedule(lambdas=(10.0,), iterations=(5,), lr_decay=0.01)
    rates = [decayed.learning_rate(2.0, i, 5) for i in range(5)]
    np.testing.assert_allclose(rates, 2.0 * 0.01 ** (np.arange(5) / 4))
    assert rates[0] == 2.0 and abs(rates[-1] - 0.02) < 1e-12
    with pytest.raises(ValueError, match="lr_decay"):
        Schedule(lambdas=(10.0,), iterations=(5,), lr_decay=1.5)
