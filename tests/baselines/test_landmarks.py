"""Tests of gpja.baselines.landmarks: landmark file formats, bad files, attaching landmarks to the template."""
from __future__ import annotations

import json

import numpy as np
import pytest

from gpja.baselines.landmarks import read_landmarks, read_template_landmarks, template_landmark_points
from gpja.errors import InputError
from gpja.mesh import TexturedMesh
from tests.baselines.test_nicp import ellipsoid
from tests.tolerances import CLOSEST_POINT_F32_MM, EXACT_F64


def test_landmark_file_formats_agree(tmp_path):
    P = np.random.default_rng(0).normal(size=(68, 3)) * 40
    np.savez(tmp_path / "a.npz", landmarks=P)
    (tmp_path / "a.json").write_text(json.dumps(P.tolist()))
    (tmp_path / "b.json").write_text(json.dumps({"landmarks": P.tolist()}))
    np.savetxt(tmp_path / "a.txt", P, fmt="%.17g")
    np.savetxt(tmp_path / "a.csv", P, fmt="%.17g", delimiter=",")
    for name in ("a.npz", "a.json", "b.json", "a.txt", "a.csv"):
        assert np.array_equal(read_landmarks(tmp_path / name, count=68), P), name


def test_template_landmark_indices_from_a_one_column_file(tmp_path):
    (tmp_path / "tu.txt").write_text("3\n17\n42\n")
    idx = read_template_landmarks(tmp_path / "tu.txt")
    assert idx.dtype == np.int64 and idx.tolist() == [3, 17, 42]
    (tmp_path / "half.txt").write_text("3\n17.5\n42\n")
    with pytest.raises(InputError, match="half.txt: landmark indices must be whole numbers"):
        read_template_landmarks(tmp_path / "half.txt")


def test_landmark_points_attach_to_the_faces_of_their_closest_points():
    V, F = ellipsoid(3)
    mesh = TexturedMesh(V, F)
    faces = np.array([0, 50, 100, 150])
    P = V[F[faces]].mean(axis=1) + 0.01 * mesh.face_normals()[faces]  # just above each face's centroid
    attached = template_landmark_points(mesh, P, "landmarks")
    assert np.array_equal(attached.points, P) and np.array_equal(attached.faces, faces)
    np.testing.assert_allclose(attached.bary, 1.0 / 3.0, atol=CLOSEST_POINT_F32_MM)
    np.testing.assert_allclose(attached.bary.sum(axis=1), 1.0, atol=EXACT_F64)
    with pytest.raises(InputError, match="landmarks: template landmarks lie a median"):
        template_landmark_points(mesh, P * 1000.0, "landmarks")


@pytest.mark.parametrize("name, content, match", [
    ("lm.npz", b"PK\x03\x04 not really a zip", "corrupt or unreadable landmark file"),
    ("lm.txt", b"1 2 3\n4 5\n", "corrupt or unreadable landmark file"),
    ("lm.json", b'{"points": []}', "expected a list, or an object"),
    ("lm.txt", b"1 2\n3 4\n5 6\n", r"must be an \(L, 3\) array"),
])
def test_corrupt_landmark_files_are_named(tmp_path, name, content, match):
    path = tmp_path / name
    path.write_bytes(content)
    with pytest.raises(InputError, match=rf"{name}: .*{match}"):
        read_landmarks(path)
