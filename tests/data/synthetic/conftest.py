"""Shared tiny synthetic subjects for the synthetic-benchmark tests."""
from __future__ import annotations

import pytest

from gpja.data.synthetic import SynthConfig, synthesize_subject

#: Tiny but complete settings: default scan voxel (edge-length checks need it),
#: coarse render mesh, small images, two expressions.
TINY = SynthConfig(seed=3, image_size=96, n_views=8, supersample=1, render_voxel_mm=1.6,
                   expressions=("1_neutral", "3_mouth_stretch"))


def run_tiny(root, cfg=TINY, subject="1", index=0):
    roots = {k: root / k for k in ("images", "scans", "gt", "raw")}
    summary = synthesize_subject(subject, index, cfg, roots["images"], roots["scans"], roots["gt"], roots["raw"],
                                 root / "sheet.png", progress=lambda s: None)
    return roots, summary


@pytest.fixture(scope="session")
def tiny_subject(tmp_path_factory):
    root = tmp_path_factory.mktemp("synth_tiny")
    roots, summary = run_tiny(root)
    return root, roots, summary
