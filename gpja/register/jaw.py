"""The jaw stage (beyond the paper, ``Schedule.jaw_iterations``): a rigid motion of the lower face first.

Why (docs/experiments.md, "Issue 15"): from the mouth-open template, a closed-mouth expression
needs the chin to travel 16-24 mm. The paper's free deformation does it with steps smoothed by
``(I + lambda L)^-1``, which spread the chin's motion over many edges: the neck, which does not
move, is dragged 12-14 mm with it, and nothing in the colour, depth or normal constraints charges
an untextured cylinder for sliding along itself, so the drag stays (it was 80% of the mean
correspondence error). The smoothing prior lacks what every face rig has: a jaw that turns about
a hinge while the neck stays.

The stage optimises six numbers, a rotation ``r`` (axis-angle, radians) and a translation ``t``
(mm) of the jaw about a pivot ``p``, blended per vertex by a weight ``w`` in [0, 1]::

    x_i' = x_i + w_i (R(r) (x_i - p) + p + t - x_i)

with the warm-up's constraints (unmasked colour, and depth and normals where they are on) in the
usual rotation, one Adam state per constraint. The warm-up and the levels then start from the
posed mesh, with less left to do and so less to spread.

The weight comes from the template's own design, not from data: the bust's mouth socket is a
known UV region (the mouth mask), so its rim is the lips' inner edge. From it, in the canonical
head frame (+Y up, +Z forward, mm): the jaw is what lies below the mouth slit (a narrow split
between the lips, wider towards the cheeks), fading out towards the ears and down the neck, in
proportions of the head's own depth (:func:`jaw_weights`). The lower wall of the socket goes with
the jaw; its upper wall stays.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Callable

import numpy as np
import torch

from gpja.errors import InputError
from gpja.mesh import TexturedMesh

#: Proportions of the jaw region, as fractions of the head's depth ``L`` (front of the face to the
#: back of the skull, mm). Anatomical rules of thumb: the mandible's ramus stands in front of the
#: ear, about half the head's depth behind the face; the chin's underside ends about a quarter of
#: it below the mouth, and the soft tissue under it follows the jaw part of the way to the hyoid.
JAW_BACK_FADE = (0.65, 0.40)      # weight 0 at 0.65 L behind the face front, 1 at 0.40 L
JAW_NECK_FADE = (0.45, 0.25)      # weight 0 at 0.45 L below the mouth, 1 at 0.25 L
JAW_CHEEK_WIDEN = 0.15            # the slit's split widens over 0.15 L beyond the mouth corners
JAW_SPLIT_MM = (3.0, 15.0)        # width (mm) of the split between the lips, and its growth at the cheeks
JAW_PIVOT = (0.50, 0.10)          # hinge: 0.50 L behind the face front, 0.10 L above the mouth


def smoothstep(e0: float, e1: float, x: np.ndarray) -> np.ndarray:
    """Cubic Hermite step: 0 at ``e0``, 1 at ``e1`` (``e0 > e1`` gives a falling step)."""
    t = np.clip((x - e0) / (e1 - e0), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def socket_vertices(mesh: TexturedMesh, mask_texture: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The mouth socket's vertices and its rim (the lips' inner edge), from the mouth mask.

    Args:
        mesh: the template (or a registration on its topology) with UVs.
        mask_texture: (T, T) or (T, T, 1) mouth mask in UV space, 0 on the socket (row 0 = v = 1).
    Returns:
        socket: (n,) bool, vertices of faces whose UV centroid lies on the socket;
        rim: (k,) int64 indices of the vertices shared by socket and non-socket faces.
    Raises:
        InputError: the mask marks no face, or the socket has no rim (no mouth to hinge).
    """
    mask = np.asarray(mask_texture, dtype=np.float32).reshape(np.shape(mask_texture)[0], -1)
    T_h, T_w = mask.shape
    centre = mesh.UV[mesh.F_uv].mean(axis=1)
    col = np.clip((centre[:, 0] * T_w).astype(int), 0, T_w - 1)
    row = np.clip(((1.0 - centre[:, 1]) * T_h).astype(int), 0, T_h - 1)
    in_socket = mask[row, col] < 0.5
    if not in_socket.any() or in_socket.all():
        raise InputError("mouth mask", "marks no mouth socket on the template's faces: the jaw stage needs one")
    socket = np.zeros(len(mesh.V), dtype=bool)
    socket[mesh.F[in_socket].ravel()] = True
    outside = np.zeros(len(mesh.V), dtype=bool)
    outside[mesh.F[~in_socket].ravel()] = True
    rim = np.flatnonzero(socket & outside)
    if len(rim) < 4:
        raise InputError("mouth mask", f"the mouth socket's rim has {len(rim)} vertices: no lips to hinge")
    return socket, rim


@dataclass(frozen=True)
class JawRig:
    """Where the jaw is on one mesh: per-vertex weights and a hinge.

    Attributes:
        weight: (n,) float64 in [0, 1], 1 on the lower lip, chin and jaw.
        pivot: (3,) float64 hinge point, mm.
    """

    weight: np.ndarray
    pivot: np.ndarray


def jaw_weights(V: np.ndarray, socket: np.ndarray, rim: np.ndarray) -> JawRig:
    """The jaw's per-vertex weight and hinge on a head in the canonical frame (module docstring).

    Args:
        V: (n, 3) float64 positions, mm, +Y up, +Z forward.
        socket: (n,) bool mouth-socket vertices; rim: (k,) int64 its rim (:func:`socket_vertices`).
    Returns:
        :class:`JawRig`.
    """
    V = np.asarray(V, dtype=np.float64)
    lips = V[rim]
    mouth = lips.mean(axis=0)
    half_width = float(np.percentile(np.abs(lips[:, 0] - mouth[0]), 98))
    front = float(V[:, 2].max())
    upper = V[(V[:, 1] > mouth[1]) & ~socket]
    depth = front - float(np.percentile(upper[:, 2] if len(upper) else V[:, 2], 1))
    if not depth > 0:
        raise InputError("template", "has no depth behind the mouth: not a head in the canonical frame")
    x, y, z = V[:, 0] - mouth[0], V[:, 1], V[:, 2]
    width = JAW_SPLIT_MM[0] + JAW_SPLIT_MM[1] * smoothstep(half_width, half_width + JAW_CHEEK_WIDEN * depth, np.abs(x))
    below = smoothstep(-0.5, 0.5, (mouth[1] - y) / width)
    back = smoothstep(front - JAW_BACK_FADE[0] * depth, front - JAW_BACK_FADE[1] * depth, z)
    neck = smoothstep(mouth[1] - JAW_NECK_FADE[0] * depth, mouth[1] - JAW_NECK_FADE[1] * depth, y)
    # the socket's walls have no neck or back to fade to: their lower wall follows the jaw whole
    weight = np.where(socket, below, below * back * neck)
    pivot = np.array([mouth[0], mouth[1] + JAW_PIVOT[1] * depth, front - JAW_PIVOT[0] * depth])
    return JawRig(weight, pivot)


def rotation_matrix(r: torch.Tensor) -> torch.Tensor:
    """Rodrigues: (3,) axis-angle (radians) -> (3, 3) rotation, differentiable, exact at r = 0."""
    theta2 = (r * r).sum()
    K = torch.zeros(3, 3, dtype=r.dtype)
    K = K.index_put((torch.tensor([0, 0, 1, 1, 2, 2]), torch.tensor([1, 2, 0, 2, 0, 1])),
                    torch.stack([-r[2], r[1], r[2], -r[0], -r[1], r[0]]))
    # sin(t)/t and (1 - cos t)/t^2 by their series near 0, so the gradient at r = 0 is finite
    small = theta2 < 1e-8
    theta = torch.sqrt(torch.where(small, torch.ones_like(theta2), theta2))
    a = torch.where(small, 1.0 - theta2 / 6.0, torch.sin(theta) / theta)
    b = torch.where(small, 0.5 - theta2 / 24.0, (1.0 - torch.cos(theta)) / (theta * theta))
    return torch.eye(3, dtype=r.dtype) + a * K + b * (K @ K)


def pose_jaw(V: torch.Tensor, weight: torch.Tensor, pivot: torch.Tensor, r: torch.Tensor,
             t: torch.Tensor) -> torch.Tensor:
    """Blend a rigid jaw motion into the vertices.

    Args:
        V: (n, 3) positions, mm. weight: (n,) in [0, 1]. pivot: (3,) hinge, mm.
        r: (3,) axis-angle rotation, radians. t: (3,) translation, mm. All of one float dtype.
    Returns:
        (n, 3) ``V + weight * (R (V - pivot) + pivot + t - V)``, differentiable in ``r`` and ``t``.
    """
    R = rotation_matrix(r)
    moved = (V - pivot) @ R.T + pivot + t
    return V + weight[:, None] * (moved - V)


def unpose_jaw(V: torch.Tensor, weight: torch.Tensor, pivot: torch.Tensor, r: torch.Tensor,
               t: torch.Tensor) -> torch.Tensor:
    """The inverse of :func:`pose_jaw` where ``weight`` is 0 or 1 (exact there; a blend is not invertible
    in closed form elsewhere, and none is needed by the registration: used by tests)."""
    R = rotation_matrix(r)
    back = (V - pivot - t) @ R + pivot
    return V + weight[:, None] * (back - V)


def fit_jaw(mesh: TexturedMesh, mask_texture: torch.Tensor, n_iter: int, lr_deg: float, lr_mm: float,
            lr_decay: float, loss: Callable[[str, torch.Tensor], torch.Tensor], rotation: tuple[str, ...],
            progress: Callable[[str], None] = print, progress_every: int = 20) -> tuple[TexturedMesh, dict]:
    """Optimise the jaw's rotation and translation; returns the posed mesh and the stage's log entry.

    Args:
        mesh: the starting mesh (template topology), mm.
        mask_texture: (T, T, 1) mouth mask (0 = socket), for the rig.
        n_iter: iterations, one constraint each, in ``rotation``'s order.
        lr_deg, lr_mm: first step of the rotation (degrees) and the translation (mm); both decay
            geometrically to ``lr_decay`` of it over the stage.
        loss: ``loss(constraint, V)`` -> scalar, differentiable in ``V`` ((n, 3) float32, mm).
    Raises:
        InputError: the mask marks no socket (:func:`socket_vertices`).
    """
    start = time.perf_counter()
    socket, rim = socket_vertices(mesh, mask_texture.detach().numpy())
    rig = jaw_weights(mesh.V, socket, rim)
    V0 = torch.tensor(mesh.V, dtype=torch.float32)
    weight = torch.tensor(rig.weight, dtype=torch.float32)
    pivot = torch.tensor(rig.pivot, dtype=torch.float32)
    r = torch.zeros(3, dtype=torch.float32, requires_grad=True)
    t = torch.zeros(3, dtype=torch.float32, requires_grad=True)
    # one Adam per constraint (as the levels' per_constraint state): each constraint's step is
    # normalised by its own gradients, whatever their units
    optimizers = {c: torch.optim.Adam([{"params": [r], "lr": math.radians(lr_deg)}, {"params": [t], "lr": lr_mm}])
                  for c in rotation}
    losses: dict[str, list[float]] = {c: [] for c in rotation}
    for it in range(n_iter):
        constraint = rotation[it % len(rotation)]
        opt = optimizers[constraint]
        scale = lr_decay ** (it / max(n_iter - 1, 1))
        opt.param_groups[0]["lr"] = math.radians(lr_deg) * scale
        opt.param_groups[1]["lr"] = lr_mm * scale
        value = loss(constraint, pose_jaw(V0, weight, pivot, r, t))
        if not math.isfinite(value.item()):
            from gpja.register.multiscale import RegistrationDiverged
            raise RegistrationDiverged(f"jaw, iteration {it}: the {constraint} loss is {value.item()}")
        opt.zero_grad()
        value.backward()
        opt.step()
        losses[constraint].append(value.item())
        if progress_every and (it + 1) % progress_every == 0:
            progress(f"jaw iter {it + 1}/{n_iter}: rotation {np.degrees(r.detach().numpy()).round(2).tolist()} deg, "
                     f"translation {t.detach().numpy().round(2).tolist()} mm")
    with torch.no_grad():
        V = pose_jaw(torch.from_numpy(mesh.V), torch.from_numpy(rig.weight), torch.from_numpy(rig.pivot),
                     r.detach().double(), t.detach().double())
    posed = mesh.with_vertices(V.numpy())
    entry = {"iterations": int(n_iter), "vertices": int(len(mesh.V)), "faces": int(len(mesh.F)),
             "rotation_deg": np.degrees(r.detach().numpy()).round(4).tolist(),
             "translation_mm": t.detach().numpy().round(4).tolist(), "pivot_mm": rig.pivot.round(3).tolist(),
             "jaw_fraction": round(float(np.mean(rig.weight > 0.5)), 4),
             "seconds": round(time.perf_counter() - start, 3), "losses": losses}
    return posed, entry
