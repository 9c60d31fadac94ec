"""gpja.register.spread: the lips' material spread between the mouth's corners as the template spreads it."""
import numpy as np
import pytest
import torch

from gpja.register.flow import socket_vertices
from gpja.register.jaw import socket_rim
from gpja.register.multiscale import RegistrationLog, Schedule, spread_stage
from gpja.register.spread import (ANCHOR_VERTICES, MAX_MEDIAN_SHIFT_MM, REACH_MM, corner_anchors, spread_along_x,
                                  spread_lips)
from gpja.surface import prepare_surface

#: float64 identities, mm.
EXACT = 1e-9
#: a vertex put back on the surface lies on it to this (mm; the closest-point query's float32 rounding at 100 mm)
ON_SURFACE_MM = 1e-4
#: the bust's pressed lips spread again: the band's x error falls to at most this fraction of the pressing's (medians;
#: the shift itself is exact (the analytic test), and the way back onto the pressed surface, whose 8 mm faces the
#: pressing bent, costs the rest: 0.52 of 1.67 mm when written)
RESTORED_FRACTION = 0.4


def grid_mouth():
    """A plane z = 0, 1 mm grid over x in [-30, 30], y in [-20, 20]: a "socket" |x| < 20, |y| < 2 (its rim the
    outermost socket vertices), the rest skin."""
    xs, ys = np.meshgrid(np.arange(-30.0, 30.5, 1.0), np.arange(-20.0, 20.5, 1.0))
    T = np.stack([xs.ravel(), ys.ravel(), np.zeros(xs.size)], axis=1)
    socket = (np.abs(T[:, 0]) < 20) & (np.abs(T[:, 1]) < 2)
    rim = np.flatnonzero(socket & ((np.abs(T[:, 0]) == 19) | (np.abs(T[:, 1]) == 1)))
    return T, socket, rim


def test_corner_anchors_are_the_skin_beyond_the_rims_ends():
    T, socket, rim = grid_mouth()
    left, right = corner_anchors(T, socket, rim)
    assert len(left) == len(right) == ANCHOR_VERTICES
    assert (T[left, 0] < -19).all() and (T[right, 0] > 19).all() and not socket[left].any()
    assert T[left, 0].max() <= -20 and np.abs(T[left, 1]).max() <= 2  # the nearest skin, not a far one


def test_the_template_itself_is_not_moved():
    """Identity: a mesh spread like the template (here, the template) gets no shift."""
    T, socket, rim = grid_mouth()
    shift, weight = spread_along_x(T, T, rim, *corner_anchors(T, socket, rim))
    assert (weight > 0).sum() > 100 and np.abs(shift).max() < EXACT


def test_pressed_lips_get_the_templates_shares_back():
    """Analytic: the band |x| < 19 pressed to 60 % towards the middle, the corners' skin where it was: every vertex of
    full weight gets back its template x exactly; outside the band nothing moves; a uniform shift of the whole mouth
    (corners included) is kept."""
    T, socket, rim = grid_mouth()
    left, right = corner_anchors(T, socket, rim)
    V = T.copy()
    pressed = np.abs(T[:, 0]) < 19
    V[pressed, 0] *= 0.6
    shift, weight = spread_along_x(V, T, rim, left, right)
    full = weight == 1.0
    assert full.sum() > 50
    np.testing.assert_allclose(V[full, 0] + shift[full], T[full, 0], atol=EXACT)
    assert (shift[weight == 0] == 0).all()
    moved = T + np.array([3.0, 0.0, 0.0])
    assert np.abs(spread_along_x(moved, T, rim, left, right)[0]).max() < EXACT
    # the band is what lies within REACH_MM of the rim on the template, between the corners
    far = np.linalg.norm(T[:, None, :] - T[rim][None], axis=2).min(1) >= REACH_MM
    assert (weight[far] == 0).all()


@pytest.fixture(scope="module")
def bust_mouth(small_bust):
    mesh = small_bust.mesh
    mask = torch.tensor(small_bust.mouth_mask(256))[..., None]
    return mesh, mask


def test_the_bust_pressed_lips_spread_again_on_the_surface(bust_mouth):
    """Regression on the CI bust: its lips' band pressed 20 % towards the mouth's middle in x (the corners' skin
    stays); spread_lips takes the band back to the template's x, puts every moved vertex on the pressed mesh's
    surface, and leaves every vertex outside the band bit for bit."""
    mesh, mask = bust_mouth
    socket = socket_vertices(mesh, mask)
    rim = socket_rim(mesh.F, socket)
    left, right = corner_anchors(mesh.V, socket, rim)
    _, weight = spread_along_x(mesh.V, mesh.V, rim, left, right)
    centre = 0.5 * (mesh.V[left, 0].mean() + mesh.V[right, 0].mean())
    press = weight.copy()
    press[np.concatenate([left, right])] = 0.0  # the flow placed the corners' skin
    V = mesh.V.copy()
    V[:, 0] -= 0.2 * press * (V[:, 0] - centre)
    pressed = mesh.with_vertices(V)
    messages = []
    out, entry = spread_lips(pressed, mesh.V, mask, messages.append)
    band = weight > 0
    assert entry["stage"] == "spread" and entry["moved"] == int(band.sum()) > 20 and "spread:" in messages[0]
    pressed_by = np.median(np.abs(V[band, 0] - mesh.V[band, 0]))
    assert pressed_by > 1.0  # mm: the pressing was real
    assert np.median(np.abs(out.V[band, 0] - mesh.V[band, 0])) < RESTORED_FRACTION * pressed_by
    assert (out.V[~band] == V[~band]).all()
    surface = prepare_surface(V, mesh.F, find_boundary=False)
    assert surface.closest(out.V[band]).distance.max() < ON_SURFACE_MM
    assert out.F is pressed.F or (out.F == pressed.F).all()


def test_a_lower_face_carried_sideways_is_left_alone(bust_mouth):
    """A jaw turned sideways: the lips' band carried 2 x MAX_MEDIAN_SHIFT_MM along x past the corners, which stay;
    spreading it back would undo a real motion, so nothing moves and the log says why."""
    mesh, mask = bust_mouth
    socket = socket_vertices(mesh, mask)
    rim = socket_rim(mesh.F, socket)
    left, right = corner_anchors(mesh.V, socket, rim)
    _, weight = spread_along_x(mesh.V, mesh.V, rim, left, right)
    carried = (weight > 0).astype(np.float64)
    carried[np.concatenate([left, right])] = 0.0
    V = mesh.V.copy()
    V[:, 0] += 2.0 * MAX_MEDIAN_SHIFT_MM * carried
    messages = []
    out, entry = spread_lips(mesh.with_vertices(V), mesh.V, mask, messages.append)
    assert (out.V == V).all() and entry["moved"] == 0 and "left out" in messages[0]
    assert entry["skipped_median_shift_mm"] > MAX_MEDIAN_SHIFT_MM


def test_a_mask_without_a_mouth_moves_nothing(bust_mouth):
    mesh, _ = bust_mouth
    messages = []
    out, entry = spread_lips(mesh, mesh.V, torch.ones(64, 64, 1), messages.append)
    assert entry["moved"] == 0 and (out.V == mesh.V).all() and "nothing moved" in messages[0]
    with pytest.raises(ValueError, match="shape"):
        spread_lips(mesh, mesh.V[:-1], torch.ones(64, 64, 1))


def test_spread_stage_logs_and_saves_the_stage(bust_mouth):
    mesh, mask = bust_mouth
    log, saved = RegistrationLog(), []
    out = spread_stage(mesh, mesh.V, mask, lambda m: None, log, lambda name, m: saved.append(name))
    assert saved == ["spread"] and log.levels[-1]["stage"] == "spread" and out.V.shape == mesh.V.shape


def test_schedule_refuses_a_lip_spread_that_is_not_a_boolean():
    assert Schedule().lip_spread is False
    with pytest.raises(ValueError, match="lip_spread"):
        Schedule(lip_spread=1)
