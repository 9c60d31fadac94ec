"""End to end on a tiny synthetic subject: template from the mouth-open scan, then registration of another expression."""
import numpy as np
import pytest

from gpja.errors import InputError
from gpja.mesh import TexturedMesh
from gpja.register.hra import Switches
from gpja.register.multiscale import Schedule
from gpja.register.pipeline import check_units, expression_targets, lighting_for, read_template, register, write_template
from gpja.register.template import TemplateSettings, create_template
from tests.render.test_passes import surface_distance

#: The pipeline must cut the scan-to-mesh distance at least this much, from the placed bust to the
#: registered expression. Issue 4 asks 5x; at these CI-sized settings (128 px, 2 x 90 iterations)
#: we measure 2.7x (3.47 -> 1.27 mm), so this guards the current behaviour against regressions.
MIN_CHAMFER_REDUCTION = 2.5

pytestmark = pytest.mark.slow


def chamfer(mesh, scan):
    """Mean distance of the scan's points to the mesh (the paper's point-of-GT-to-mesh direction).

    The other direction needs a rule for mesh regions over the scan's holes
    (the metrics' job); here the template's skull back would dominate it.
    """
    return surface_distance(scan.V, mesh.V, mesh.F).mean()


@pytest.fixture(scope="module")
def subject(tmp_path_factory):
    from gpja.cli import subject_seed_index
    from gpja.data.facescape import load_expression
    from gpja.data.synthetic import SynthConfig, synthesize_subject

    root = tmp_path_factory.mktemp("tiny")
    expressions = ("3_mouth_stretch", "13_lip_funneler")
    synthesize_subject("S01", subject_seed_index("S01"), SynthConfig(seed=2, image_size=128, scan_voxel_mm=1.5,
                                                                   expressions=expressions, raw_variant=False),
                       root / "i", root / "s", root / "g", root / "r", root / "c.png", progress=lambda m: None)
    data = {e: load_expression(root / "i", "S01", e, scans_root=root / "s") for e in expressions}
    targets = {e: expression_targets(data[e], root / "t" / f"{e}.npz", lighting_for("S01", e, root / "g")) for e in expressions}
    return root, data, targets


def test_template_then_registration_cuts_chamfer(subject, tmp_path):
    root, data, targets = subject
    settings = TemplateSettings(bust_edge_mm=8.0, schedule=Schedule(lambdas=(200.0, 120.0), iterations=(90, 90)),
                                texture_size=128, texture_iterations=60, template_faces=8000)
    template = create_template(data["3_mouth_stretch"].scan.V, targets["3_mouth_stretch"], settings, progress=lambda m: None)
    write_template(template, tmp_path / "template")
    mesh, mask = read_template(tmp_path / "template")
    scan = data["13_lip_funneler"].scan
    start = chamfer(template.stages["bust"], scan)
    registered, log = register(mesh, mask, targets["13_lip_funneler"], Schedule(lambdas=(200.0, 120.0), iterations=(90, 90)),
                               Switches(), progress=lambda m: None)
    end = chamfer(registered, scan)
    assert start / end >= MIN_CHAMFER_REDUCTION, (start, end)
    assert set(log.levels[0]["losses"]) == {"color", "depth", "normal"}
    np.testing.assert_array_equal(registered.F_uv[: len(mesh.F_uv)].shape, mesh.F_uv.shape)


def test_template_and_scan_in_different_units_are_refused(subject):
    _, data, _ = subject
    scan = data["13_lip_funneler"].scan
    metres = TexturedMesh(scan.V / 1000.0, scan.F)
    with pytest.raises(InputError, match="different units"):
        check_units(metres, scan.V, scan.path)
