"""Faces the re-parametrised artist mesh turns over between adjacent expressions, and, on synthetic data, how many
the generator's own deformation turns over.

Issue 16 asks that the artist mesh, carried onto every expression (``gpja reparametrize``), turns no face over
between adjacent expressions: the registration tree's hops (``registration_order.json``: each expression and the
one its registration started from). A face is turned over when its normal turns by more than 90 degrees
(``gpja.apply.reparam.flipped_faces``).

Some turning is right. A closing upper lid slides over the eyeball, and the continuous surface the template makes of
lid and eyeball (one skin, as a scan sees it) has to fold under the lid: the material between the lid's margin and
the eyeball's top faces backwards once the lid is closed. The synthetic benchmark knows the true motion of every
point: its expressions are maps of rest space (``gpja.data.synthetic.expressions.map_to_expression``). Carried
through them instead (:func:`carry_through_truth`: each artist vertex's rest point by Newton's method on the template
expression's map, then every expression's map of it), the artist mesh shows which turns the data asks for. The
metrics read the ground truth; the registration and the reparametrisation never do.

Written here rather than taken from a library: the maps are the generator's own functions, and the Newton step
needs only their finite-difference Jacobians (3x3 per point), which numpy solves in one batch.
"""
from __future__ import annotations

import time
from pathlib import Path
from typing import Callable, Mapping

import numpy as np

from gpja.errors import InputError

#: Newton steps inverting the template expression's map (the maps are smooth; 5-8 reach 1e-10 mm).
NEWTON_ITERATIONS = 30
#: A rest point counts as found when its image is this close to the artist vertex, mm.
NEWTON_TOLERANCE_MM = 1e-3
#: Central-difference step of the maps' Jacobians, mm.
JACOBIAN_STEP_MM = 1e-4
#: Halvings of a Newton step that would not shrink a point's residual.
BACKTRACKS = 12
#: Further starts (the next nearest scan vertices' rest points) for a vertex whose first start stalls.
RESTARTS = 16
#: A face GPJA turns counts as near the truth's when its centroid is this close to a face the truth turns, mm (about
#: two rings of the default stand-in artist mesh, whose edges are 2-3 mm).
NEAR_TRUTH_MM = 5.0


# --- the ground truth's motion -----------------------------------------------------------------------------------

def map_jacobians(space_map: Callable[[np.ndarray], np.ndarray], R: np.ndarray,
                  step: float = JACOBIAN_STEP_MM) -> np.ndarray:
    """(n, 3, 3) float64 Jacobians ``d map / d R`` of a map of space at ``R (n, 3)`` mm, by the generator's central
    differences (``gpja.data.synthetic.expressions.central_jacobians``) at this module's step."""
    from gpja.data.synthetic.expressions import central_jacobians

    return central_jacobians(space_map, R, step)


def invert_map(space_map: Callable[[np.ndarray], np.ndarray], X: np.ndarray, guess: np.ndarray,
               iterations: int = NEWTON_ITERATIONS) -> tuple[np.ndarray, np.ndarray]:
    """Points ``R`` with ``space_map(R) = X``, by Newton's method from ``guess``.

    Args:
        space_map: (n, 3) -> (n, 3) float64 mm, smooth and invertible near the answers.
        X: (n, 3) float64 targets, mm; guess: (n, 3) float64 starting points, mm.
        iterations: Newton steps (a point whose Jacobian is singular keeps its last position).
    Returns:
        R (n, 3) float64 mm and the residual ``|space_map(R) - X|`` (n,) float64 mm.
    """
    X = np.asarray(X, dtype=np.float64)
    R = np.array(guess, dtype=np.float64)
    residual = space_map(R) - X
    size = np.linalg.norm(residual, axis=1)
    for _ in range(iterations):
        if size.max(initial=0.0) < 1e-12:
            break
        J = map_jacobians(space_map, R)
        ok = np.abs(np.linalg.det(J)) > 1e-12
        step = np.zeros_like(R)
        step[ok] = np.linalg.solve(J[ok], residual[ok][:, :, None])[:, :, 0]
        # damped: halve a point's step until its residual shrinks (a full step can overshoot where the map is far
        # from linear over it, e.g. from a start across an open mouth)
        scale = np.ones(len(R))
        todo = ok & (size > 0)
        for _ in range(BACKTRACKS):
            if not todo.any():
                break
            trial = R[todo] - scale[todo, None] * step[todo]
            trial_residual = space_map(trial) - X[todo]
            trial_size = np.linalg.norm(trial_residual, axis=1)
            better = trial_size < size[todo]
            idx = np.flatnonzero(todo)[better]
            R[idx], residual[idx], size[idx] = trial[better], trial_residual[better], trial_size[better]
            todo[idx] = False
            scale[todo] *= 0.5
    return R, size


def carry_through_truth(V: np.ndarray, ground_truth_root: str | Path, scans_root: str | Path, subject: str,
                        source_expression: str, expressions) -> tuple[dict[str, np.ndarray], np.ndarray, np.ndarray]:
    """A mesh in the source expression's frame carried by the synthetic generator's true motion.

    Each vertex's rest point solves ``phi_source(r) = v`` (:func:`invert_map`), starting from the rest point of the
    source expression's nearest scan vertex moved by the inverse Jacobian there; its position in expression ``e``
    is ``phi_e(r)``. Vertices off the scan (the mouth's socket the template closes, the bust) go through the same
    maps: the generator's motion of that point of space.

    Args:
        V: (n, 3) float64 mm, e.g. the artist mesh on the template expression.
        ground_truth_root: ``{root}/{subject}/subject.json`` and ``{source_expression}.npz`` (its scan's rest points).
        scans_root: ``{root}/{subject}/{source_expression}.ply``.
        expressions: the expressions to carry it to.
    Returns:
        ``{expression: (n, 3) float64 mm}``, the (n,) bool of vertices whose rest point was found
        (:data:`NEWTON_TOLERANCE_MM`) and each vertex's (n,) float64 distance to the nearest scan vertex, mm (deep
        in an open mouth's socket the start is 13-18 mm away and the jaw's map stretches space twelvefold there:
        the damped steps of :func:`invert_map` still reach it).
    Raises:
        InputError: a ground-truth or scan file is missing or corrupt, or the rest points do not match the scan.
    """
    from scipy.spatial import cKDTree

    from gpja.data.synthetic.expressions import map_to_expression
    from gpja.io import read_npz
    from gpja.mesh import read_ply
    from gpja.metrics.oracle import subject_identity

    head = subject_identity(ground_truth_root, subject)
    truth_path = Path(ground_truth_root) / subject / f"{source_expression}.npz"
    arrays = read_npz(truth_path)
    if "scan_rest_coords" not in arrays:
        raise InputError(truth_path, "no 'scan_rest_coords' (not a synthetic expression's ground truth?)")
    rest = np.asarray(arrays["scan_rest_coords"], dtype=np.float64)
    scan_path = Path(scans_root) / subject / f"{source_expression}.ply"
    scan = np.asarray(read_ply(scan_path)[0], dtype=np.float64)
    if rest.shape != scan.shape:
        raise InputError(truth_path, f"{len(rest)} rest points for the {len(scan)} vertices of {scan_path}")

    def source_map(R):
        return map_to_expression(R, head, source_expression)

    V = np.asarray(V, dtype=np.float64)
    tree = cKDTree(scan)
    distance, nearest = tree.query(V)
    R, residual = invert_map(source_map, V, linear_guess(source_map, V, scan[nearest], rest[nearest]))
    found = residual < NEWTON_TOLERANCE_MM
    # where the map squeezes space (under a dropped jaw's chin) the nearest start can stall: then the vertex itself,
    # then the next nearest scan vertices' rest points
    # (column 0 of the neighbours is the nearest, already tried: its turn goes to the vertex itself)
    stalled = np.flatnonzero(~found)
    neighbours = tree.query(V[stalled], k=RESTARTS + 1)[1] if stalled.size else None
    for k in range(RESTARTS + 1 if stalled.size else 0):
        rows = np.flatnonzero(~found[stalled])
        if not rows.size:
            break
        lost, start = stalled[rows], neighbours[rows, k]
        guess = V[lost] if k == 0 else linear_guess(source_map, V[lost], scan[start], rest[start])
        retry, size = invert_map(source_map, V[lost], guess)
        won = size < NEWTON_TOLERANCE_MM
        R[lost[won]], found[lost[won]] = retry[won], True
    return {e: map_to_expression(R, head, e) for e in expressions}, found, distance


def linear_guess(space_map: Callable[[np.ndarray], np.ndarray], X: np.ndarray, anchors: np.ndarray,
                 anchor_rest: np.ndarray) -> np.ndarray:
    """(n, 3) rest points near ``X (n, 3)`` mm: each anchor's rest point moved by the map's inverse Jacobian there
    (``anchors`` (n, 3) mm, images of ``anchor_rest`` (n, 3) mm)."""
    guess = np.array(anchor_rest, dtype=np.float64)
    J = map_jacobians(space_map, guess)
    ok = np.abs(np.linalg.det(J)) > 1e-12
    guess[ok] += np.linalg.solve(J[ok], (X - anchors)[ok][:, :, None])[:, :, 0]
    return guess


# --- the counts ----------------------------------------------------------------------------------------------------

def tree_hops(order: Mapping) -> list[tuple[str, str]]:
    """``(parent, expression)`` of every hop of a registration tree (``registration_order.json``), in its order."""
    parent = order.get("parent") if isinstance(order, Mapping) else None
    sequence = order.get("order") if isinstance(order, Mapping) else None
    if not isinstance(parent, Mapping) or not isinstance(sequence, list):
        raise ValueError("a registration order needs 'order' (a list) and 'parent' (an object)")
    return [(parent[e], e) for e in sequence if parent.get(e) is not None]


def hop_turns(carried: Mapping[str, np.ndarray], F: np.ndarray, hops, observed: np.ndarray,
              truth: Mapping[str, np.ndarray] | None = None, truth_found: np.ndarray | None = None) -> list[dict]:
    """Faces turned over along each hop, by the carried meshes and (optionally) by the ground truth's motion.

    Args:
        carried: ``{expression: (n, 3) float64 mm}``, one topology ``F (m, 3)``.
        hops: ``(parent, expression)`` pairs (:func:`tree_hops`).
        observed: (m,) bool faces on material a camera saw (``gpja.apply.steps.observed_faces``).
        truth: the same meshes carried by the true motion (:func:`carry_through_truth`), or None.
        truth_found: (n,) bool vertices the true motion places; a face counts in the truth's columns only when its
            three vertices are placed (None = all).
    Returns:
        One dict a hop: ``parent``, ``expression``, ``turned``, ``turned_observed``, ``turned_faces`` (their
        indices); with ``truth`` also ``truth_turned``, ``truth_turned_observed``, ``both`` (turned by both),
        ``near_truth`` (GPJA's turned faces within :data:`NEAR_TRUTH_MM` of one the truth turns, centroid to
        centroid at the parent's true positions: the same fold a ring or two off counts), ``faces_compared`` and
        ``truth_turned_faces``.
    """
    from scipy.spatial import cKDTree

    from gpja.folds import turned_faces

    F = np.asarray(F, dtype=np.int64)
    observed = np.asarray(observed, dtype=bool)
    compared = np.ones(len(F), dtype=bool) if truth_found is None else np.asarray(truth_found, bool)[F].all(axis=1)
    rows = []
    for parent, expression in hops:
        ours = turned_faces(carried[expression], carried[parent], F)
        row = {"parent": parent, "expression": expression, "turned": int(ours.sum()),
               "turned_observed": int((ours & observed).sum())}
        if truth is not None:
            true = turned_faces(truth[expression], truth[parent], F) & compared
            near = 0
            if true.any() and ours.any():
                centroids = np.asarray(truth[parent], dtype=np.float64)[F].mean(axis=1)
                gap, _ = cKDTree(centroids[true]).query(centroids[ours])
                near = int((gap <= NEAR_TRUTH_MM).sum())
            row.update(truth_turned=int(true.sum()), truth_turned_observed=int((true & observed).sum()),
                       both=int((true & ours).sum()), near_truth=near, faces_compared=int(compared.sum()),
                       truth_turned_faces=np.flatnonzero(true).tolist())
        row["turned_faces"] = np.flatnonzero(ours).tolist()
        rows.append(row)
    return rows


def count_turns(artist_path: str | Path, meshes: Mapping[str, str | Path], order_path: str | Path,
                template_dir: str | Path, subject: str, output: str | Path,
                ground_truth_root: str | Path | None = None, scans_root: str | Path | None = None,
                template_expression: str | None = None, progress: Callable[[str], None] = print) -> dict:
    """``gpja turns``: the artist mesh's turned faces along every hop of the registration tree, and with synthetic
    ground truth the true motion's, written as JSON.

    Args:
        artist_path: the artist mesh (``reparam/artist.obj``, in the template expression's frame).
        meshes: ``{expression: reparam/{expression}.obj}`` for every expression of the tree, its root included.
        order_path: ``registration_order.json``.
        template_dir: the subject's template (``texture_observed.png`` marks the faces on observed material).
        ground_truth_root, scans_root: synthetic ground truth and scans (both or neither).
        template_expression: the artist mesh's expression (default: the tree's root).
    Raises:
        InputError: a file is missing or corrupt, a mesh has another topology than the artist mesh, or an
            expression of the tree has no mesh.
    """
    from gpja.apply.steps import observed_faces, read_uv_mesh
    from gpja.io import read_json, write_json
    from gpja.mesh import read_obj

    start = time.perf_counter()
    if (ground_truth_root is None) != (scans_root is None):
        raise InputError("--ground-truth-root", "give the ground truth and the scans together, or neither")
    order = read_json(order_path)
    try:
        hops = tree_hops(order)
    except (ValueError, KeyError) as err:
        raise InputError(order_path, f"not a registration order ({err})") from None
    artist = read_obj(artist_path, load_texture=False)
    artist.validate(artist_path)
    carried = {}
    for expression in dict.fromkeys(e for hop in hops for e in hop):
        if expression not in meshes:
            raise InputError(order_path, f"expression {expression!r} of the tree has no re-parametrised mesh "
                                         f"(given: {', '.join(meshes)})")
        mesh = read_obj(meshes[expression], load_texture=False)
        mesh.validate(meshes[expression])
        if mesh.V.shape != artist.V.shape or not np.array_equal(mesh.F, artist.F):
            raise InputError(meshes[expression], f"not in the artist mesh's topology ({len(mesh.V)} vertices and "
                                                 f"{len(mesh.F)} faces against {len(artist.V)} and {len(artist.F)})")
        carried[expression] = mesh.V
    template = read_uv_mesh(Path(template_dir) / "template.obj")
    observed = observed_faces(template_dir, template, artist.V[artist.F].mean(axis=1))
    truth = found = None
    if ground_truth_root is not None:
        source = template_expression or order.get("root")
        truth, found, distance = carry_through_truth(artist.V, ground_truth_root, scans_root, subject, source,
                                                     list(carried))
    rows = hop_turns(carried, artist.F, hops, observed, truth, found)
    log = {"subject": subject, "artist_mesh": str(artist_path), "faces": int(len(artist.F)),
           "observed_faces": int(observed.sum()), "hops": rows,
           "truth": None if truth is None else {
               "vertices_placed": int(found.sum()), "vertices": int(len(found)),
               # how close to the scan an unplaced vertex comes (None: all placed)
               "unplaced_nearest_scan_mm": float(distance[~found].min()) if (~found).any() else None},
           "seconds": round(time.perf_counter() - start, 2)}
    write_json(output, log)
    for row in rows:
        line = (f"turns: {subject} {row['parent']} -> {row['expression']}: {row['turned']} of {len(artist.F)} faces "
                f"turned over ({row['turned_observed']} on observed material)")
        if truth is not None:
            line += (f"; the true motion turns {row['truth_turned']} ({row['truth_turned_observed']} observed), "
                     f"{row['both']} of them also turned here; {row['near_truth']} of these {row['turned']} within "
                     f"{NEAR_TRUTH_MM:g} mm of one the truth turns")
        progress(line)
    return log
