"""Tests of gpja.render.targets: scan targets rendered once, cached, and the cache checked on load."""
from __future__ import annotations

import logging

import numpy as np
import pytest
import torch

from gpja.errors import InputError
from gpja.render import render_scan_targets, render_views
from gpja.render.targets import CACHE_KEYS
from tests.render.scenes import ring_cameras, sphere


@pytest.fixture()
def scene():
    V, F = sphere(subdivisions=2)
    return V, F, ring_cameras(2, 32)


def test_scan_targets_are_cached(tmp_path, scene):
    V, F, cams = scene
    first = render_scan_targets(V, F, cams, tmp_path / "targets.npz")
    stamp = (tmp_path / "targets.npz").stat().st_mtime_ns
    second = render_scan_targets(V, F, cams, tmp_path / "targets.npz")
    assert (tmp_path / "targets.npz").stat().st_mtime_ns == stamp
    for k in ("depth", "normal", "coverage"):
        assert torch.equal(first[k], second[k]) and second[k].dtype == torch.float32
    other = render_scan_targets(V, F, ring_cameras(3, 32), tmp_path / "targets.npz")  # other views: re-rendered
    assert other["depth"].shape[0] == 3


def test_targets_are_the_renderers_dense_passes(scene):
    V, F, cams = scene
    targets = render_scan_targets(V, F, cams)
    out = render_views(torch.tensor(V, dtype=torch.float32), torch.tensor(F), cams, passes=("depth", "normal"))
    assert set(targets) == {"depth", "normal", "coverage"}
    for k in targets:
        assert torch.equal(targets[k], out.dense(k))


def test_the_render_function_is_used(scene):
    V, F, cams = scene
    calls = []

    def spy(*args, **kwargs):
        calls.append(kwargs.get("passes"))
        return render_views(*args, **kwargs)

    assert torch.equal(render_scan_targets(V, F, cams, render=spy)["depth"], render_scan_targets(V, F, cams)["depth"])
    assert calls == [("depth", "normal")]


def _truncated(path, good):
    path.write_bytes(good[: len(good) // 2])


def _not_a_zip(path, good):
    path.write_bytes(b"this is not an npz file at all")


def _foreign_keys(path, good):
    np.savez(path, depth_map=np.zeros((2, 32, 32, 1), np.float32), something_else=np.arange(3))


def _a_npy(path, good):
    with open(path, "wb") as fh:
        np.save(fh, np.zeros(3))


def _rewrite(**changes):
    def mutate(path, good):
        with np.load(path) as cached:
            arrays = {k: cached[k] for k in cached.files}
        arrays.update(changes)
        with open(path, "wb") as fh:
            np.savez(fh, **arrays)
    return mutate


@pytest.mark.parametrize("damage, reason", [
    (_truncated, "unreadable"),
    (_not_a_zip, "unreadable"),
    (_foreign_keys, "missing views_key"),
    (_a_npy, "not an .npz archive"),
    (_rewrite(depth=np.zeros((3, 32, 32, 1), np.float32)), "depth has shape"),
    (_rewrite(normal=np.zeros((2, 32, 32, 3), np.float64)), "normal is float64"),
    (_rewrite(coverage=np.full((2, 32, 32, 1), np.nan, np.float32)), "coverage holds NaN"),
    (_rewrite(n_vertices=np.arange(3)), "made for another scan"),
    (_rewrite(n_vertices=np.int64(7)), "made for another scan"),
    (_rewrite(views_key=np.zeros(4, np.uint8)), "made for other views"),
])
def test_a_bad_cache_is_rebuilt_with_a_warning(tmp_path, scene, caplog, damage, reason):
    V, F, cams = scene
    path = tmp_path / "targets.npz"
    expected = render_scan_targets(V, F, cams, path)
    damage(path, path.read_bytes())
    with caplog.at_level(logging.WARNING, logger="gpja.render.targets"):
        rebuilt = render_scan_targets(V, F, cams, path)
    for k in expected:
        assert torch.equal(rebuilt[k], expected[k])
    assert any(str(path) in r.getMessage() and reason in r.getMessage() for r in caplog.records), caplog.text
    with np.load(path) as cached:  # written back: the next load takes it as it is
        assert set(cached.files) == set(CACHE_KEYS)
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="gpja.render.targets"):
        render_scan_targets(V, F, cams, path)
    assert not caplog.records


def test_a_cache_that_cannot_be_written_names_the_file(tmp_path, scene):
    V, F, cams = scene
    blocked = tmp_path / "not_a_dir"
    blocked.write_text("a file where a folder should be")
    with pytest.raises(InputError, match="not_a_dir.*cannot write the scan targets"):
        render_scan_targets(V, F, cams, blocked / "targets.npz")
