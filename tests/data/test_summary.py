"""gpja.data.summary: the check-data summary, and the checks and preview of an expression's scan targets."""
from __future__ import annotations

import logging
from types import SimpleNamespace

import numpy as np
import pytest

from gpja.data.source import DataSource
from gpja.data.summary import check_one_image_size, summarize_expression, targets_preview, warn_on_empty_targets
from gpja.errors import InputError


def test_summary_of_a_facescape_expression(facescape_root):
    r = facescape_root
    data = DataSource(images_root=r["images"], scans_root=r["scans"]).load(r["subject"], r["expression"])
    summary = summarize_expression(data)
    assert [v["name"] for v in summary["views"]] == ["0", "1", "2"]  # the invalid view 9 is dropped
    assert all(v["scan_fraction_in_view"] == 1.0 for v in summary["views"])  # the sphere is in every view
    V, F = r["scan"]
    assert summary["scan"]["n_vertices"] == len(V) and summary["scan"]["n_faces"] == len(F)
    assert summary["scan"]["bbox_max_mm"] == pytest.approx(V.max(axis=0), abs=1e-3)
    assert summary["rt_scale"] is None


def fake_data(*sizes):
    views = [SimpleNamespace(camera=SimpleNamespace(width=w, height=h)) for w, h in sizes]
    return SimpleNamespace(subject="S01", expression="1_neutral", views=views)


def test_views_must_share_one_size():
    assert check_one_image_size(fake_data((8, 6), (8, 6)), "root") == (8, 6)
    with pytest.raises(InputError, match=r"root: S01/1_neutral: views differ in size \[\(8, 6\), \(9, 6\)\]"):
        check_one_image_size(fake_data((8, 6), (9, 6)), "root")


def test_views_without_scan_pixels_are_named(caplog):
    coverage = np.zeros((2, 3, 4), np.float32)
    coverage[1, 1, 1] = 0.5
    with caplog.at_level(logging.WARNING):
        assert warn_on_empty_targets(["a", "b"], coverage) == ["a"]
    assert "view a: the scan covers no pixel" in caplog.text


def test_preview_rows_show_image_normals_and_depth():
    n, H, W = 2, 4, 5
    images = [np.full((H, W, 3), 0.25, np.float32) for _ in range(n)]
    normal = np.zeros((n, H, W, 3), np.float32)
    normal[..., 2] = 1.0
    depth = np.tile(np.linspace(500, 600, W, dtype=np.float32), (n, H, 1))  # near on the left
    coverage = np.ones((n, H, W), np.float32)
    coverage[1] = 0.0  # the second view sees no scan
    out = targets_preview(images, normal, depth, coverage)
    assert out.shape == (n * H, 3 * W, 3)
    first, second = out[:H], out[H:]
    assert np.all(first[:, :W] == 0.25)
    assert np.allclose(first[:, W:2 * W], [0.5, 0.5, 1.0])  # +Z normal
    shade = first[0, 2 * W:, 0]
    assert np.all(np.diff(shade) < 0) and 0.15 <= shade.min() and shade.max() <= 1.0  # near = bright
    assert np.all(second[:, W:] == 0)  # nothing covered: black normals and depth
