"""End-to-end checks of one tiny synthetic subject in FaceScape's layout."""
import json

import numpy as np
import pytest

from gpja.camera import Camera
from gpja.data.synthetic import SynthConfig
from gpja.data.synthetic.expressions import map_to_expression
from gpja.data.synthetic.head import HeadParams
from gpja.io import read_image, read_npz
from gpja.mesh import read_ply

from .conftest import TINY, run_tiny

GT_TOL_MM = 1e-6
RAW_TOL_MM = 1e-6
DARK_MAX = 0.15
LIPS_MIN = 0.3
pytestmark = pytest.mark.slow


def _head(roots):
    meta = json.loads((roots["gt"] / "1" / "subject.json").read_text())
    return HeadParams(**meta["identity"]), meta


def test_layout(tiny_subject):
    root, roots, summary = tiny_subject
    for e in TINY.expressions:
        d = roots["images"] / "1" / e
        assert sorted(p.name for p in d.iterdir()) == sorted([f"{i}.png" for i in range(8)] + ["params.json"])
        params = json.loads((d / "params.json").read_text())
        for v in map(str, range(8)):
            cam = Camera.from_params(params, v)
            assert cam.width == TINY.image_size and params[f"{v}_valid"] is True
        assert (roots["scans"] / "1" / f"{e}.ply").is_file()
        gt = read_npz(roots["gt"] / "1" / f"{e}.npz")
        assert gt["landmarks"].shape == (68, 3) and gt["sh"].shape == (9, 3) and gt["skin_gain"].shape == (3,)
    assert (root / "sheet.png").is_file()
    assert not list(root.rglob(".*.part*"))


def test_scan_ground_truth_is_exact_and_scan_like(tiny_subject):
    root, roots, _ = tiny_subject
    p, _ = _head(roots)
    for e in TINY.expressions:
        V, F = read_ply(roots["scans"] / "1" / f"{e}.ply")
        gt = read_npz(roots["gt"] / "1" / f"{e}.npz")
        assert np.abs(map_to_expression(gt["scan_rest_coords"], p, e) - V).max() < GT_TOL_MM
        edges = np.linalg.norm(V[F[:, 0]] - V[F[:, 1]], axis=1)
        assert 0.5 <= np.median(edges) <= 1.0
        # covers the face (nose tip), holes at the back and the top of the skull
        assert np.linalg.norm(V - gt["landmarks"][30], axis=1).min() < 1.0
        assert not np.any((V[:, 2] < -60.0) & (np.abs(V[:, 0]) < 20.0))
        assert not np.any((V[:, 1] > 100.0) & (np.abs(V[:, 0]) < 30.0) & (V[:, 2] < 0.0))
        assert V[:, 1].min() > -170.0


def _mouth_pixel(roots, e):
    params = json.loads((roots["images"] / "1" / e / "params.json").read_text())
    cam = Camera.from_params(params, "0")
    gt = read_npz(roots["gt"] / "1" / f"{e}.npz")
    uv, _ = cam.project(gt["landmarks"][[62, 66]].mean(0, keepdims=True))
    img = read_image(roots["images"] / "1" / e / "0.png")
    u, v = np.round(uv[0]).astype(int)
    return img[v, u]


def test_mouth_dark_when_open_closed_in_neutral(tiny_subject):
    _, roots, _ = tiny_subject
    assert _mouth_pixel(roots, "3_mouth_stretch").mean() < DARK_MAX
    assert _mouth_pixel(roots, "1_neutral").mean() > LIPS_MIN


def test_raw_variant_undoes_to_aligned(tiny_subject):
    _, roots, _ = tiny_subject
    table = json.loads((roots["raw"] / "Rt_scale_dict" / "1.json").read_text())
    for e in TINY.expressions:
        s, Rt = table["1"][e.split("_")[0]]
        Rt = np.asarray(Rt)
        assert 0.8 <= s <= 1.2
        Vraw, _ = read_ply(roots["raw"] / "scans" / "1" / f"{e}.ply")
        V, _ = read_ply(roots["scans"] / "1" / f"{e}.ply")
        assert np.abs((s * Vraw) @ Rt[:, :3].T + Rt[:, 3] - V).max() < RAW_TOL_MM
        # raw cameras see the raw scan where the aligned cameras see the aligned scan
        pr = json.loads((roots["raw"] / "images" / "1" / e / "params.json").read_text())
        pa = json.loads((roots["images"] / "1" / e / "params.json").read_text())
        uv_raw, _ = Camera.from_params(pr, "0").project(Vraw[:50])
        uv, _ = Camera.from_params(pa, "0").project(V[:50])
        assert np.abs(uv_raw - uv).max() < 1e-6
        a = (roots["raw"] / "images" / "1" / e / "0.png").read_bytes()
        assert a == (roots["images"] / "1" / e / "0.png").read_bytes()


def test_deterministic_bytes(tmp_path):
    cfg = SynthConfig(seed=5, image_size=48, n_views=3, supersample=1, scan_voxel_mm=2.0, render_voxel_mm=2.0,
                      expressions=("18_eye_closed",))
    run_tiny(tmp_path / "a", cfg)
    run_tiny(tmp_path / "b", cfg)
    files = sorted(p.relative_to(tmp_path / "a") for p in (tmp_path / "a").rglob("*") if p.is_file())
    assert len(files) > 5
    for f in files:
        assert (tmp_path / "a" / f).read_bytes() == (tmp_path / "b" / f).read_bytes(), f
