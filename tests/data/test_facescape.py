import json
import os

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from gpja.data.facescape import expression_number, load_expression, read_rt_scale
from gpja.errors import InputError
from gpja.io import read_image, write_image
from gpja.mesh import write_ply
from tests.conftest import EXPRESSION, SUBJECT
from tests.tolerances import IMAGE_ROUNDTRIP_RATIO_8BIT


def load(fs, **kw):
    return load_expression(fs["images"], SUBJECT, EXPRESSION, scans_root=fs["scans"], **kw)


def test_loads_valid_views_undistorted_with_scan(facescape_root):
    fs = facescape_root
    data = load(fs)
    assert [v.name for v in data.views] == ["0", "1", "2"]  # view 9 has valid=false
    for view in data.views:
        assert not view.camera.has_distortion
        assert view.image.shape == (96, 96, 3) and view.image.dtype == np.float32
        ideal = fs["ideals"][view.name]
        interior = np.s_[10:-10, 10:-10]
        # undistortion brings the image closer to the ideal pinhole image
        raw_error = np.abs(read_image(view.path)[interior] - ideal[interior]).mean()
        assert np.abs(view.image[interior] - ideal[interior]).mean() < IMAGE_ROUNDTRIP_RATIO_8BIT * raw_error
    np.testing.assert_array_equal(data.scan.V, fs["scan"][0])


def test_view_selection_and_unknown_view(facescape_root):
    data = load(facescape_root, views=["2", "0"])
    assert [v.name for v in data.views] == ["2", "0"]
    with pytest.raises(InputError, match="view '5' requested but not described"):
        load(facescape_root, views=["5"])


def test_rt_scale_brings_raw_data_to_mm(facescape_root, tmp_path):
    fs = facescape_root
    s, R, t = 2.5, Rotation.random(random_state=0).as_matrix(), np.array([3.0, -40.0, 12.0])
    # write a raw variant: scan and cameras in a frame with X_mm = R (s X_raw) + t
    V, F = fs["scan"]
    V_raw = ((V - t) @ R) / s
    write_ply(fs["scans"] / SUBJECT / f"{EXPRESSION}.ply", V_raw, F)
    params = {}
    for cam in fs["cameras"]:
        params.update(cam.transformed(1 / s, R.T, -(R.T @ t) / s).to_params())
    (fs["folder"] / "params.json").write_text(json.dumps(params))
    table = tmp_path / "Rt_scale_dict.json"
    table.write_text(json.dumps({SUBJECT: {"3": [s, np.concatenate([R, t[:, None]], 1).tolist()]}}))
    data = load(fs, rt_scale_path=table)
    np.testing.assert_allclose(data.scan.V, V, atol=1e-9)
    for view, cam in zip(data.views, fs["cameras"]):
        np.testing.assert_allclose(view.camera.Rt, cam.Rt, atol=1e-9)
    assert read_rt_scale(table, SUBJECT, EXPRESSION)[0] == s
    with pytest.raises(InputError, match="no valid \\[scale, Rt\\] entry for subject '8'"):
        read_rt_scale(table, "8", EXPRESSION)


def test_undistorted_images_are_cached(facescape_root, tmp_path):
    fs = facescape_root
    first = load(fs, cache_dir=tmp_path / "cache")
    cached = tmp_path / "cache" / SUBJECT / EXPRESSION / "0.png"
    assert cached.is_file()
    stamp = cached.stat().st_mtime_ns
    second = load(fs, cache_dir=tmp_path / "cache")
    assert cached.stat().st_mtime_ns == stamp  # reused, not recomputed
    uncached = load(fs)
    for a, b, c in zip(first.views, second.views, uncached.views):
        # Bitwise: whichever job fills the cache must see the colours every later job reads back.
        np.testing.assert_array_equal(a.image, b.image)
        np.testing.assert_array_equal(a.image, c.image)


def test_corrupt_cached_image_is_rebuilt(facescape_root, tmp_path, caplog):
    first = load(facescape_root, cache_dir=tmp_path / "cache")
    cached = tmp_path / "cache" / SUBJECT / EXPRESSION / "0.png"
    cached.write_bytes(cached.read_bytes()[:100])  # cut off mid-write
    with caplog.at_level("WARNING"):
        again = load(facescape_root, cache_dir=tmp_path / "cache")
    assert "0.png" in caplog.text and "undistorting" in caplog.text
    np.testing.assert_array_equal(first.views[0].image, again.views[0].image)
    assert load(facescape_root, cache_dir=tmp_path / "cache").views[0].image.shape == first.views[0].image.shape


def test_max_image_size_downsamples_with_intrinsics(facescape_root):
    data = load(facescape_root, max_image_size=48)
    view = data.views[0]
    assert view.image.shape == (48, 48, 3) and view.camera.width == 48
    full = load(facescape_root).views[0]
    np.testing.assert_allclose(view.camera.K[0, 0], full.camera.K[0, 0] / 2)


# --- bad input: one test per case, each must name the file and the problem -------------------

def test_missing_params(facescape_root):
    (facescape_root["folder"] / "params.json").unlink()
    with pytest.raises(InputError, match=r"params\.json: file not found"):
        load(facescape_root)


def test_corrupt_params(facescape_root):
    (facescape_root["folder"] / "params.json").write_text("{\"0_K\": [1, 2")
    with pytest.raises(InputError, match=r"params\.json: corrupt JSON"):
        load(facescape_root)


def test_view_key_missing(facescape_root):
    path = facescape_root["folder"] / "params.json"
    params = json.loads(path.read_text())
    del params["1_Rt"]
    path.write_text(json.dumps(params))
    with pytest.raises(InputError, match=r"params\.json: view '1': key '1_Rt' missing"):
        load(facescape_root)


def test_missing_image(facescape_root):
    (facescape_root["folder"] / "2.png").unlink()
    with pytest.raises(InputError, match=r"2\.jpg: image of view '2' not found"):
        load(facescape_root)


def test_corrupt_image(facescape_root):
    (facescape_root["folder"] / "1.png").write_bytes(b"\x89PNG\r\n\x1a\n broken")
    with pytest.raises(InputError, match=r"1\.png: corrupt or unreadable image"):
        load(facescape_root)


def test_image_size_differs_from_params(facescape_root):
    write_image(facescape_root["folder"] / "0.png", np.zeros((40, 50, 3)))
    with pytest.raises(InputError, match=r"0\.png: image is 50x40 but params\.json says 96x96"):
        load(facescape_root)


def test_nan_scan(facescape_root):
    V, F = facescape_root["scan"]
    V = V.copy()
    V[5] = np.nan
    write_ply(facescape_root["scans"] / SUBJECT / f"{EXPRESSION}.ply", V, F)
    with pytest.raises(InputError, match=r"3_mouth_stretch\.ply: 1 vertices have NaN"):
        load(facescape_root)


def test_empty_scan(facescape_root):
    (facescape_root["scans"] / SUBJECT / f"{EXPRESSION}.ply").write_bytes(b"")
    with pytest.raises(InputError, match=r"3_mouth_stretch\.ply: scan file is empty"):
        load(facescape_root)


def test_scan_in_wrong_units(facescape_root):
    V, F = facescape_root["scan"]
    write_ply(facescape_root["scans"] / SUBJECT / f"{EXPRESSION}.ply", V / 1000.0, F)  # metres
    with pytest.raises(InputError, match=r"3_mouth_stretch\.ply: bounding-box diagonal is 0\.3.*millimetres"):
        load(facescape_root)


def test_missing_scan(facescape_root):
    os.remove(facescape_root["scans"] / SUBJECT / f"{EXPRESSION}.ply")
    with pytest.raises(InputError, match="scan file not found"):
        load(facescape_root)


def test_expression_number():
    assert expression_number("13_lip_funneler") == 13
    with pytest.raises(InputError, match="naming"):
        expression_number("smile")


@pytest.mark.parametrize("key", ["K", "distortion", "width", "height", "valid"])
def test_a_described_view_missing_a_key_is_an_error_not_dropped(facescape_root, key):
    """Only ``{view}_valid: false`` may drop a view; a view missing ``{view}_K`` (or any key) names file and key."""
    from gpja.data.facescape import list_views, read_cameras

    path = facescape_root["folder"] / "params.json"
    params = json.loads(path.read_text())
    del params[f"1_{key}"]
    path.write_text(json.dumps(params))
    assert list_views(params) == ["0", "1", "2", "9"]
    with pytest.raises(InputError, match=rf"params\.json: view '1': key '1_{key}' missing"):
        read_cameras(path)
    with pytest.raises(InputError, match=rf"params\.json: view '1': key '1_{key}' missing"):
        load(facescape_root)


def test_a_view_marked_invalid_may_lack_its_other_keys(facescape_root):
    path = facescape_root["folder"] / "params.json"
    params = json.loads(path.read_text())
    for key in ("K", "Rt", "distortion", "width", "height"):
        del params[f"9_{key}"]  # only 9_valid: false is left
    path.write_text(json.dumps(params))
    assert [v.name for v in load(facescape_root).views] == ["0", "1", "2"]
