"""Which expression each registration starts from: a tree over a subject's scans (beyond the paper).

The paper registers every expression from the template. The template is built from the mouth-open
expression, and for a closed mouth the lips must travel ~20 mm, farther than the colour constraint's
basin: the depth and normal constraints close the socket's walls over the lower lip while the
texture stays open (docs/method.md, "Registration order"). Starting a closed-mouth expression from
an already registered expression whose mouth is nearer to it shortens that way.

The tree is the minimum spanning tree of the scans' distances, rooted at the template expression:
each expression is registered from its parent (the template's own expression from the template), so
the steps between consecutive registrations are as small as the captures allow. The distance is the
symmetric mean closest-point distance between two scans, mm: the scans are what a capture has; no
registration, landmark or ground truth is read.
"""
from __future__ import annotations

from typing import Mapping, Sequence

import numpy as np

from gpja.errors import InputError

def sample_points(V: np.ndarray, n: int, seed: int) -> np.ndarray:
    """Up to ``n`` of the scan's vertices, chosen with a seeded generator (all when it has fewer)."""
    if len(V) <= n:
        return V
    return V[np.random.default_rng(seed).choice(len(V), n, replace=False)]


def scan_distances(scans: Sequence[np.ndarray], samples: int = 20000, seed: int = 0) -> np.ndarray:
    """Symmetric mean closest-point distance between every pair of scans.

    Args:
        scans: k arrays (n_i, 3) float64 of scan vertices, mm, in one frame.
        samples: vertices drawn from each scan for the means (the trees use every vertex).
        seed: the sampling's seed.
    Returns:
        (k, k) float64, mm: ``D[i, j] = (mean_p d(p, scan_j) + mean_q d(q, scan_i)) / 2`` over the samples
        p of scan i and q of scan j, zero on the diagonal. ``d`` is the distance to the nearest *vertex*
        (scans are dense: MVS or 0.8 mm voxels), so differences below half a vertex spacing do not show.
    """
    from scipy.spatial import cKDTree

    trees = [cKDTree(V) for V in scans]
    points = [sample_points(V, samples, seed) for V in scans]
    k = len(scans)
    D = np.zeros((k, k))
    for i in range(k):
        for j in range(i + 1, k):
            forward = trees[j].query(points[i])[0].mean()
            backward = trees[i].query(points[j])[0].mean()
            D[i, j] = D[j, i] = 0.5 * (forward + backward)
    return D


def registration_tree(names: Sequence[str], distances: np.ndarray, root: str) -> dict:
    """The minimum spanning tree of ``distances`` rooted at ``root``, as parents and an order.

    Args:
        names: k expression names, ``root`` among them.
        distances: (k, k) symmetric, mm (:func:`scan_distances`).
        root: the template's expression.
    Returns:
        ``{"root": root, "parent": {name: parent name, root: None}, "order": [names, each after its
        parent], "depth": {name: edges from the root}}``.
    """
    from scipy.sparse.csgraph import breadth_first_order, minimum_spanning_tree

    names = list(names)
    if root not in names:
        raise ValueError(f"the root {root!r} is not among the expressions {names}")
    D = np.asarray(distances, dtype=np.float64)
    # csgraph reads zero (and tiny) weights as "no edge", so identical scans would fall out of the tree;
    # every spanning tree has k - 1 edges, so one constant added to every edge leaves the minimum unchanged
    lifted = np.where(np.eye(len(D), dtype=bool), 0.0, D + 1.0 + np.abs(D).max())
    tree = minimum_spanning_tree(lifted)
    order, predecessors = breadth_first_order(tree, names.index(root), directed=False)
    parent = {root: None}
    depth = {root: 0}
    for i in order[1:]:
        parent[names[i]] = names[predecessors[i]]
        depth[names[i]] = depth[parent[names[i]]] + 1
    return {"root": root, "parent": parent, "order": [names[i] for i in order], "depth": depth}


def plan_order(scans: Mapping[str, np.ndarray], root: str, samples: int = 20000, seed: int = 0) -> dict:
    """The registration tree of one subject from its scans (:func:`registration_tree`) plus the distances.

    Args:
        scans: expression name -> (n, 3) float64 scan vertices, mm; the template's expression among them.
        root: the template's expression.
    Returns:
        the tree's dict with ``"distances_mm": {a: {b: mm}}`` added.
    Raises:
        InputError: the template's expression has no scan.
    """
    names = list(scans)
    if root not in scans:
        raise InputError("scans", f"the template expression {root!r} has no scan; have {', '.join(names)}")
    D = scan_distances([scans[n] for n in names], samples, seed)
    plan = registration_tree(names, D, root)
    plan["distances_mm"] = {a: {b: round(float(D[i, j]), 4) for j, b in enumerate(names)} for i, a in enumerate(names)}
    return plan


def parents_in_tree(plan: Mapping, expression: str) -> Mapping:
    """The plan's ``parent`` map, after checking that ``expression`` is in the tree (InputError if not)."""
    parent = plan["parent"]
    if expression not in parent:
        raise InputError("registration order", f"{expression!r} is not in the registration tree "
                                               f"({', '.join(parent)})")
    return parent


def chain(plan: Mapping, expression: str) -> list[str]:
    """The expressions from the root to ``expression`` (both included) in the plan's tree."""
    parent = parents_in_tree(plan, expression)
    path = [expression]
    while parent[path[-1]] is not None:
        path.append(parent[path[-1]])
    return path[::-1]


def start_expression(plan: Mapping, expression: str) -> str | None:
    """The expression whose GPJA registration ``expression`` starts from; None = the template itself.

    The root is the template's own expression, so it and its children start from the template (a
    registration of the template to its own expression would only add that registration's drift).

    Raises:
        InputError: ``expression`` is not in the plan's tree.
    """
    start = parents_in_tree(plan, expression)[expression]
    return None if start is None or start == plan["root"] else start
