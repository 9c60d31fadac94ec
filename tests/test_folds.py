"""Folds of a mesh on a surface and their untangling (gpja/folds.py): a flat grid with one vertex pushed past its
neighbour, on a plane."""
import numpy as np

from gpja.apply.reparam import flipped_faces
from gpja.folds import folded_faces, turned_faces, untangle_on_surface
from gpja.render.silhouettes import face_adjacency
from gpja.surface import prepare_surface
from tests.tolerances import CLOSEST_POINT_F32_MM


def flat_grid(n: int = 8) -> tuple[np.ndarray, np.ndarray]:
    """An n x n grid of 1 mm squares in z = 0, two counter-clockwise triangles each (normals +z)."""
    x, y = np.meshgrid(np.arange(float(n)), np.arange(float(n)))
    V = np.column_stack([x.ravel(), y.ravel(), np.zeros(n * n)])
    F = np.array([[i * n + j, i * n + j + 1, i * n + j + n + 1] for i in range(n - 1) for j in range(n - 1)]
                 + [[i * n + j, i * n + j + n + 1, i * n + j + n] for i in range(n - 1) for j in range(n - 1)])
    return V, F


def pushed(V: np.ndarray) -> np.ndarray:
    """The 8 x 8 grid with vertex (3, 3) pushed past its right neighbour (4, 3), in the plane: a fold."""
    moved = V.copy()
    moved[3 * 8 + 3, 0] = 4.6
    return moved


def test_folded_faces_analytic_on_a_flat_grid():
    """Flat: nothing folded. One interior vertex pushed past its right neighbour (in the plane): exactly the
    faces whose orientation reversed are folded, and they are the ones ``flipped_faces`` counts against the
    flat grid."""
    V, F = flat_grid()
    adjacency = face_adjacency(F)
    assert not folded_faces(V, F, adjacency).any()
    moved = pushed(V)
    reversed_ = np.cross(moved[F[:, 1]] - moved[F[:, 0]], moved[F[:, 2]] - moved[F[:, 0]])[:, 2] < 0
    assert reversed_.sum() > 0
    np.testing.assert_array_equal(folded_faces(moved, F, adjacency), reversed_)
    assert flipped_faces(V, moved, F) == reversed_.sum()
    assert not folded_faces(V * np.array([1.0, -1.0, -1.0]), F, adjacency).any()  # turned over as a whole: no fold


def test_untangle_unfolds_a_grid_and_stays_on_its_plane():
    """The pushed vertex is pulled back among its neighbours: no fold left, every vertex still on the plane,
    the rim where it was, vertices away from the fold untouched (rings = 1)."""
    V, F = flat_grid()
    moved = pushed(V)
    plane = prepare_surface(np.array([[-5.0, -5, 0], [15, -5, 0], [15, 15, 0], [-5, 15, 0]]),
                            np.array([[0, 1, 2], [0, 2, 3]]), find_boundary=False)
    out, log = untangle_on_surface(moved, F, plane, iterations=50, rings=1)
    assert log["folded_before"] > 0 and log["folded_after"] == 0 and 1 <= log["rounds"] <= 50
    assert not folded_faces(out, F, face_adjacency(F)).any()
    assert np.abs(out[:, 2]).max() < CLOSEST_POINT_F32_MM
    rim = (V[:, 0] == 0) | (V[:, 0] == 7) | (V[:, 1] == 0) | (V[:, 1] == 7)
    np.testing.assert_array_equal(out[rim], moved[rim])
    far = np.abs(V[:, :2] - [3.0, 3.0]).max(axis=1) >= 4  # beyond the folded fan and one ring
    np.testing.assert_array_equal(out[far], moved[far])
    assert log["moved_vertices"] < len(V) and log["max_move_mm"] > 0.5


def rolled_rim(V: np.ndarray) -> np.ndarray:
    """The 8 x 8 grid with its last column (x = 7) laid back to x = 5.5, past the column x = 6, in the plane: the
    strip between them is turned over, and at the rim no face points against its neighbours' sum."""
    moved = V.copy()
    moved[V[:, 0] == 7, 0] = 5.5
    return moved


def test_turned_faces_analytic_on_a_flat_grid():
    V, F = flat_grid()
    adjacency = face_adjacency(F)
    assert not turned_faces(V, V, F).any()
    moved = pushed(V)
    np.testing.assert_array_equal(turned_faces(moved, V, F), folded_faces(moved, F, adjacency))
    assert turned_faces(V * np.array([1.0, -1.0, -1.0]), V, F).all()  # turned as a whole, folded nowhere
    rolled = rolled_rim(V)
    strip = V[F][:, :, 0].max(axis=1) == 7
    np.testing.assert_array_equal(turned_faces(rolled, V, F), strip)
    assert not folded_faces(rolled, F, adjacency).any()  # what the fold test misses


def test_untangle_with_a_reference_lays_back_what_the_fold_test_misses():
    """The rolled rim: folds alone see nothing and move nothing; with the flat grid as the reference the turned
    strip is smoothed back (its inner column pulled behind the rim's), on the plane, but for its two end faces,
    whose only movable vertex is the one the rim's rows hold (rim vertices stay)."""
    V, F = flat_grid()
    rolled = rolled_rim(V)
    plane = prepare_surface(np.array([[-5.0, -5, 0], [15, -5, 0], [15, 15, 0], [-5, 15, 0]]),
                            np.array([[0, 1, 2], [0, 2, 3]]), find_boundary=False)
    same, log = untangle_on_surface(rolled, F, plane, iterations=50, rings=1)
    np.testing.assert_array_equal(same, rolled)
    assert log["folded_before"] == 0 and "turned_before" not in log
    out, log = untangle_on_surface(rolled, F, plane, iterations=50, rings=1, reference=V)
    assert log["turned_before"] == 2 * 7 and log["turned_after"] == 2
    left = turned_faces(out, V, F)
    assert set(np.round(V[F[left]][:, :, 1].min(axis=1))) | set(np.round(V[F[left]][:, :, 1].max(axis=1))) <= {0, 1, 6, 7}
    assert (np.isin(V[F[left]][:, :, 1], [0.0, 7.0])).any(axis=1).all()  # each touches a rim row
    assert np.abs(out[:, 2]).max() < CLOSEST_POINT_F32_MM
