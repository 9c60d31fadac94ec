import numpy as np
import trimesh

from gpja.camera import Camera
from gpja.data.synthetic.scan import edge_lengths, visible_face_counts


def test_sphere_visibility_two_cameras():
    s = trimesh.creation.icosphere(subdivisions=3, radius=10.0)
    V, F = np.asarray(s.vertices), np.asarray(s.faces)
    K = np.array([[100.0, 0, 31.5], [0, 100.0, 31.5], [0, 0, 1]])
    cams = [Camera.look_at((0, 0, 200.0), (0, 0, 0), (0, 1, 0), K, 64, 64, name="0"),
            Camera.look_at((0, 0, -200.0), (0, 0, 0), (0, 1, 0), K, 64, 64, name="1")]
    n = visible_face_counts(V, F, cams)
    cz = V[F].mean(1)[:, 2]
    assert np.all(n[cz > 5.0] == 1) and np.all(n[cz < -5.0] == 1)
    assert np.all(n <= 1)  # no triangle faces both cameras


def test_edge_lengths_of_a_unit_triangle():
    V = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]])
    e = np.sort(edge_lengths(V, np.array([[0, 1, 2]])))
    assert np.allclose(e, [1, 1, np.sqrt(2)])
