"""A CI-sized open-to-closed mouth through the real workflow (issue 15's test).

The template is built from the mouth-open expression (``3_mouth_stretch``); the target, ``1_neutral``,
has its lips closed, about 20 mm above where the template's lower lip is. Sized for CI: one subject,
three expressions at 256^2 (a pixel ~2 mm), the default's template and registration switches with
CI's two levels. The default reaches the closed mouth through the registration tree (``13_lip_funneler``
on the way, chosen from the scans alone) and the flow stage; the paper's schedule, from the template,
keeps the open mouth. At 128^2 (``config/ci.yaml``) neither closes it (docs/experiments.md, "A CI-sized
open-to-closed mouth").

The lower lip: template vertices of the mouth region (the ground truth's labels, read only here)
below the template expression's inner lip. Both the correspondence error, over the vertices it
scores, and the position error, which drops none of the registered side, must be within the bound;
at least half the lower lip must be scored, so a lip left off the scan cannot pass.
"""
from __future__ import annotations

import json
import subprocess
from pathlib import Path

import numpy as np
import pytest
import yaml

from tests.test_project import ROOT, SNAKEMAKE, copy_workflow, workflow_env
from tests.tolerances import LOWER_LIP_CLOSED_MM

SUBJECT = "S01"
CLOSED = "1_neutral"
DATASET = "synthetic-open-to-closed"
METHODS = ("gpja", "gpja-paper")


def open_to_closed_config() -> dict:
    """config/ci.yaml at 256^2 with the default's template and registration switches (CI's two levels)."""
    ci = yaml.safe_load((ROOT / "config/ci.yaml").read_text())
    default = yaml.safe_load((ROOT / "config/config.yaml").read_text())
    cfg = json.loads(json.dumps(ci).replace(ci["dataset"], DATASET))
    cfg["expressions"] = [CLOSED, "3_mouth_stretch", "13_lip_funneler"]
    cfg["synthetic"].update(image_size=256, scan_voxel_mm=default["synthetic"]["scan_voxel_mm"])
    reg = cfg["registration"]
    reg["template"] = default["registration"]["template"]
    levels = len(ci["registration"]["gpja"]["lambdas"])
    per_level = {k: v[:levels] for k, v in default["registration"]["gpja"].items()  # the default's first levels
                 if k in ("views_per_iteration", "image_factor", "color_pool") and v is not None}
    reg["gpja"] = {**default["registration"]["gpja"], **per_level, "lambdas": ci["registration"]["gpja"]["lambdas"],
                   "iterations": ci["registration"]["gpja"]["iterations"]}
    reg["ablations"] = {"variants": ["gpja-paper"], "subjects": None, "expressions": [CLOSED]}
    cfg["baselines"]["nicp"]["enabled"] = False
    return cfg


@pytest.fixture(scope="module")
def open_to_closed(tmp_path_factory) -> Path:
    """Runs the workflow to both methods' metrics of the closed expression; returns the work directory."""
    work = copy_workflow(tmp_path_factory.mktemp("open_to_closed"))
    (work / "config/open_to_closed.yaml").write_text(yaml.safe_dump(open_to_closed_config(), sort_keys=False))
    targets = [f"results/{DATASET}/{SUBJECT}/{method}/metrics/{CLOSED}.json" for method in METHODS]
    out = subprocess.run([*SNAKEMAKE, "--cores", "2", *targets, "--configfile", "config/open_to_closed.yaml"],
                         cwd=work, capture_output=True, text=True, timeout=900, env=workflow_env())
    assert out.returncode == 0, out.stderr[-3000:]
    return work


def lower_lip_errors(work: Path, method: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Correspondence errors (mm) of the scored lower-lip vertices, position errors (mm), and the lower lip's mask."""
    from gpja.mesh import read_obj

    template = read_obj(work / f"results/{DATASET}/{SUBJECT}/template/template.obj", load_texture=False)
    open_mouth = np.load(work / f"data/{DATASET}/ground_truth/{SUBJECT}/3_mouth_stretch.npz")["landmarks"]
    with np.load(work / f"results/{DATASET}/{SUBJECT}/{method}/metrics/{CLOSED}/correspondence_errors.npz") as e:
        mouth = e["vertex_region"] == list(e["region_names"]).index("mouth")
        lower = mouth & (template.V[:, 1] < open_mouth[60:68, 1].mean())  # below the open mouth's inner lip
        corr = e["vertex_error_mm"][lower & e["vertex_used"]]
        position = e["vertex_position_error_mm"][lower]
    return corr, position[np.isfinite(position)], lower


def assert_lower_lip_closed(work: Path, method: str) -> None:
    corr, position, lower = lower_lip_errors(work, method)
    assert lower.sum() >= 20, f"{method}: only {lower.sum()} lower-lip vertices"
    assert len(corr) >= 0.5 * lower.sum(), f"{method}: {len(corr)} of {lower.sum()} lower-lip vertices scored"
    assert np.median(corr) < LOWER_LIP_CLOSED_MM, f"{method}: lower lip correspondence median {np.median(corr):.2f} mm"
    assert np.median(position) < LOWER_LIP_CLOSED_MM, f"{method}: lower lip position median {np.median(position):.2f} mm"


@pytest.mark.slow
def test_the_default_closes_the_open_templates_mouth(open_to_closed):
    order = json.loads((open_to_closed / f"results/{DATASET}/{SUBJECT}/registration_order.json").read_text())
    assert order["parent"][CLOSED] == "13_lip_funneler"  # through the tree, from the scans alone
    assert_lower_lip_closed(open_to_closed, "gpja")


@pytest.mark.slow
@pytest.mark.xfail(strict=True, reason="the paper's schedule (from the template, one Adam, small constant steps) keeps "
                   "the open template's lower lip about 35 mm from the closed lip at this size")
def test_the_papers_schedule_keeps_the_open_templates_mouth(open_to_closed):
    log = json.loads((open_to_closed / f"results/{DATASET}/{SUBJECT}/gpja-paper/{CLOSED}.json").read_text())
    assert log["start"] == "template"
    assert_lower_lip_closed(open_to_closed, "gpja-paper")
