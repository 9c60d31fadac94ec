from pathlib import Path

import numpy as np
import pytest

from gpja.errors import InputError
from gpja.io import atomic_path, link_or_copy, read_image, read_json, read_npz, write_image, write_json, write_npz
from tests.tolerances import UINT8_STEP


def test_atomic_path_leaves_nothing_on_failure(tmp_path):
    target = tmp_path / "out" / "result.json"
    with pytest.raises(RuntimeError):
        with atomic_path(target) as tmp:
            tmp.write_text("half")
            raise RuntimeError("step failed")
    assert not target.exists()
    assert list((tmp_path / "out").iterdir()) == []


def test_atomic_path_keeps_previous_content_on_failure(tmp_path):
    target = tmp_path / "a.json"
    write_json(target, {"kept": True})
    with pytest.raises(RuntimeError):
        with atomic_path(target) as tmp:
            tmp.write_text("{")
            raise RuntimeError
    assert read_json(target) == {"kept": True}


def test_image_round_trip_and_corrupt_image(tmp_path):
    img = np.random.default_rng(0).random((9, 7, 3)).astype(np.float32)
    write_image(tmp_path / "a.png", img)
    assert np.abs(read_image(tmp_path / "a.png") - img).max() <= UINT8_STEP / 2 + 1e-6
    (tmp_path / "bad.jpg").write_bytes(b"\xff\xd8\xff\xe0 truncated")
    with pytest.raises(InputError, match="bad.jpg: corrupt or unreadable image"):
        read_image(tmp_path / "bad.jpg")
    with pytest.raises(InputError, match="image file not found"):
        read_image(tmp_path / "none.png")


def test_json_and_npz_errors(tmp_path):
    (tmp_path / "c.json").write_text("{not json")
    with pytest.raises(InputError, match="c.json: corrupt JSON"):
        read_json(tmp_path / "c.json")
    write_npz(tmp_path / "a.npz", x=np.arange(3))
    np.testing.assert_array_equal(read_npz(tmp_path / "a.npz")["x"], np.arange(3))
    (tmp_path / "b.npz").write_bytes(b"garbage")
    with pytest.raises(InputError, match="b.npz: corrupt npz"):
        read_npz(tmp_path / "b.npz")
    # cut off mid-write: numpy fails inside its zip / zlib readers, not with OSError
    write_npz(tmp_path / "big.npz", x=np.random.default_rng(0).random(4096))
    data = (tmp_path / "big.npz").read_bytes()
    for n in (len(data) // 2, len(data) - 30):
        (tmp_path / "cut.npz").write_bytes(data[:n])
        with pytest.raises(InputError, match="cut.npz: corrupt npz"):
            read_npz(tmp_path / "cut.npz")


def test_link_or_copy_replaces(tmp_path):
    (tmp_path / "src.txt").write_text("new")
    (tmp_path / "dst.txt").write_text("old")
    link_or_copy(tmp_path / "src.txt", tmp_path / "dst.txt")
    assert (tmp_path / "dst.txt").read_text() == "new"


def test_atomic_outputs_get_the_usual_file_mode(tmp_path):
    import os

    write_json(tmp_path / "m.json", {})
    umask = os.umask(0)
    os.umask(umask)
    assert (tmp_path / "m.json").stat().st_mode & 0o777 == 0o666 & ~umask


def test_path_patterns_fill_subject_and_expression_and_refuse_other_fields():
    from gpja.io import fill_path_pattern

    assert fill_path_pattern("a/{subject}/{expression}.obj", "S01", "1_neutral") == Path("a/S01/1_neutral.obj")
    assert fill_path_pattern("fixed.obj", "S01", "1_neutral") == Path("fixed.obj")
    with pytest.raises(InputError, match="only {subject} and {expression}"):
        fill_path_pattern("a/{subj}.obj", "S01", "1_neutral")


def test_npz_round_trip_keeps_every_dtype_and_shape_and_is_compressed(tmp_path):
    rng = np.random.default_rng(1)
    arrays = {"V": rng.random((50, 3)).astype(np.float32), "F": rng.integers(0, 50, (80, 3)).astype(np.int32),
              "flags": rng.random(7) < 0.5, "names": np.array(["1_neutral", "2_smile"]), "empty": np.zeros((0, 3)),
              "scalar": np.float64(2.5), "zeros": np.zeros(100_000)}
    write_npz(tmp_path / "r.npz", **arrays)
    back = read_npz(tmp_path / "r.npz")
    assert list(back) == list(arrays)
    for key, value in arrays.items():
        assert back[key].dtype == np.asarray(value).dtype and back[key].shape == np.shape(value)
        np.testing.assert_array_equal(back[key], value)
    with np.load(tmp_path / "r.npz") as plain:  # numpy's own reader
        np.testing.assert_array_equal(plain["F"], arrays["F"])
    assert (tmp_path / "r.npz").stat().st_size < 100_000  # 800 KB of zeros deflate to almost nothing
