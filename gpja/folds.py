"""Folds of a triangle mesh that lies on a surface, and smoothing them out along it.

A registration that crumples its texture parametrisation (parts no camera sees, under the jaw, the lids of a
closing eye) leaves vertices on the right surface in the wrong order: their triangles fold over, a pleat of
three layers where the surface has one. :func:`folded_faces` finds them; :func:`untangle_on_surface` moves the
vertices around them back into order without leaving the surface. Two users: the registration's last stage
(``registration.gpja.untangle_iterations``, ``gpja.register.multiscale``) and the artist mesh carried onto an
expression (``applications.reparam.untangle_iterations``, ``gpja.apply.steps.reparametrize``).

Written here rather than taken from a library: pymeshlab's and Open3D's smoothing filters move every vertex
and know no target surface to stay on; this moves only the folds' neighbourhoods and projects them back with
the closest-point queries of ``gpja.surface``.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from gpja.surface import Surface, rim


def folded_faces(V: np.ndarray, F: np.ndarray, adjacency: np.ndarray) -> np.ndarray:
    """Which faces lie folded over within one mesh: the normal points against its neighbours'.

    Args:
        V: (n, 3) float64 positions, mm; F: (m, 3) int faces.
        adjacency: (m, 3) int64 neighbour across each edge, -1 on the rim (``gpja.render.silhouettes.face_adjacency``).
    Returns:
        (m,) bool: ``n_f . sum(n_g over neighbours g) < 0`` with unit face normals (a degenerate face has a zero
        normal and is not folded). A smooth surface has none; a pleat (the triangles' order along the surface
        reversed) has a strip of them.
    """
    V, F = np.asarray(V, dtype=np.float64), np.asarray(F, dtype=np.int64)
    return folded_among(unit_normals(V, F), adjacency, np.arange(len(F)))


def unit_normals(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """(m, 3) float64 unit normals of faces ``F (m, 3)`` (zero for a degenerate face)."""
    n = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)


def folded_among(normals: np.ndarray, adjacency: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """:func:`folded_faces` of the faces with indices ``faces (k,)``, from every face's unit normal (m, 3)."""
    near = adjacency[faces]
    around = np.where((near >= 0)[:, :, None], normals[np.maximum(near, 0)], 0.0).sum(axis=1)
    return (normals[faces] * around).sum(axis=1) < 0.0


def turned_faces(V: np.ndarray, reference: np.ndarray, F: np.ndarray) -> np.ndarray:
    """(m,) bool: faces ``F`` whose normal at ``V`` (n, 3) points against its normal at ``reference`` (n, 3), mm (the
    same mesh before a deformation). A pleat whose creases are rounded has no folded face (each face agrees with
    its neighbours) but its middle layer is turned over against where it came from."""
    return opposed(unit_normals(V, F), unit_normals(reference, F))


def opposed(normals: np.ndarray, reference_normals: np.ndarray) -> np.ndarray:
    """(k,) bool: rows of two (k, 3) normal arrays that point against each other (a zero normal opposes none)."""
    return np.einsum("kc,kc->k", normals, reference_normals) < 0.0


def untangle_on_surface(V: np.ndarray, F: np.ndarray, surface: Surface, iterations: int, rings: int,
                        reference: np.ndarray | None = None) -> tuple[np.ndarray, dict]:
    """Smooth the folds out of a mesh that lies on ``surface`` without leaving it.

    Each round takes the vertices of the folded faces (:func:`folded_faces`; with ``reference``, also the faces
    turned over against it, :func:`turned_faces`) and ``rings`` rings around them, moves each to the mean of
    its neighbours (uniform Laplacian) and back onto ``surface`` at the closest point; rim vertices stay. Stops
    when nothing is folded or after ``iterations`` rounds. Vertices away from the folds do not move.

    Args:
        V: (n, 3) float64 mm on ``surface``; F: (m, 3) int faces.
        surface: the expression's surface (``gpja.surface.prepare_surface``).
        iterations: most rounds (0 = none: ``V`` returned unchanged).
        rings: neighbourhood around the folded faces' vertices that moves with them.
        reference: (n, 3) float64 mm, the mesh's positions before the deformation that folded it, or None.
    Returns:
        The untangled (n, 3) float64 positions (on ``surface``) and a log: ``folded_before``, ``folded_after``
        (faces folded or, with ``reference``, turned), ``rounds``, ``moved_vertices`` (ever moved),
        ``max_move_mm``; with ``reference`` also ``turned_before`` and ``turned_after``.
    """
    from gpja.register.laplacian import uniform_laplacian
    from gpja.render.silhouettes import face_adjacency

    V = np.array(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    adjacency = face_adjacency(F)
    normals = unit_normals(V, F)
    creased = folded_among(normals, adjacency, np.arange(len(F)))
    reference_normals = None if reference is None else unit_normals(np.asarray(reference, dtype=np.float64), F)
    turned = np.zeros(len(F), dtype=bool) if reference_normals is None else opposed(normals, reference_normals)
    folded = creased | turned
    log = {"folded_before": int(folded.sum()), "folded_after": int(folded.sum()), "rounds": 0,
           "moved_vertices": 0, "max_move_mm": 0.0}
    if reference_normals is not None:
        log.update(turned_before=int(turned.sum()), turned_after=int(turned.sum()))
    if iterations <= 0 or not folded.any():
        return V, log
    L = uniform_laplacian(V, F)
    degree = np.maximum(L.diagonal(), 1.0)
    neighbours = (sp.diags(L.diagonal()) - L).tocsr()  # the 0/1 vertex adjacency
    fixed = rim(V, F)[1]
    start = V.copy()
    ever = np.zeros(len(V), dtype=bool)
    for round_ in range(1, int(iterations) + 1):
        move = np.zeros(len(V), dtype=bool)
        move[F[folded].ravel()] = True
        for _ in range(int(rings)):
            move |= (neighbours @ move.astype(np.float64)) > 0
        move &= ~fixed
        if not move.any():
            break
        mean = (neighbours[move] @ V) / degree[move, None]  # the moving rows only
        V[move] = surface.closest(mean).point
        ever |= move
        # only the faces at moved vertices change their normal, only they and their neighbours their fold
        touched = np.flatnonzero(move[F].any(axis=1))
        normals[touched] = unit_normals(V, F[touched])
        near = adjacency[touched].ravel()
        check = np.union1d(touched, near[near >= 0])
        folded[check] = folded_among(normals, adjacency, check)
        if reference_normals is not None:
            turned[touched] = opposed(normals[touched], reference_normals[touched])
            folded[check] |= turned[check]
        log["rounds"] = round_
        if not folded.any():
            break
    if reference_normals is not None:
        log["turned_after"] = int(turned.sum())
    log.update(folded_after=int(folded.sum()), moved_vertices=int(ever.sum()),
               max_move_mm=float(np.linalg.norm(V - start, axis=1).max()))
    return V, log
