"""Time the two sparse Cholesky backends of ``gpja.cholesky`` side by side, on the systems the workflow factors.

- ``flow``: the flow stage's displacement system ``mu Ln^T Ln + W + eps I`` (``gpja.register.flow``; 2-ring
  sparsity) on icospheres of a registration's level sizes (the default's flow stages run at 16K and 40K
  vertices; 100K is its last level).
- ``nicp``: NICP's 4n x 4n optimal-step system (``gpja.baselines.nicp_solver``) on an icosphere of the
  template's size (16K vertices).

No workflow run is needed. Prints JSON: per system and backend the median seconds of a factorisation and of
one 3-column solve over ``--repeats`` alternating runs, their ratios (simplicial / supernodal), and the largest
difference between the backends' solutions relative to the solution's size.
Usage: python benchmarks/bench_cholesky.py [--repeats 3] [--threads 1]
"""
from __future__ import annotations

import argparse
import json
import statistics
import time

import numpy as np
import scipy.sparse as sp
import trimesh

from gpja.cholesky import BACKENDS, factorize


def icosphere_near(n_vertices: int) -> tuple[np.ndarray, np.ndarray]:
    """An icosphere (radius 100 mm) with about ``n_vertices`` vertices, cut down to that many by a plane
    (an open mesh like a bust, and the size asked for)."""
    subdivisions = int(np.ceil(np.log(max(n_vertices - 2, 10) / 10.0) / np.log(4.0)))
    sphere = trimesh.creation.icosphere(subdivisions=subdivisions, radius=100.0)
    V, F = np.asarray(sphere.vertices), np.asarray(sphere.faces)
    keep = np.argsort(V[:, 2])[:n_vertices]
    inside = np.zeros(len(V), bool)
    inside[keep] = True
    F = F[inside[F].all(1)]
    index = np.full(len(V), -1)
    index[keep] = np.arange(len(keep))
    return V[keep], index[F]


def flow_system(n_vertices: int) -> sp.csr_matrix:
    from gpja.register.flow import smoothness_system

    V, F = icosphere_near(n_vertices)
    w = np.random.default_rng(0).integers(0, 5, len(V)).astype(float)  # matches seen by 0-4 views
    return (smoothness_system(F, len(V), 30.0) + sp.diags(w)).tocsr()


def nicp_system(n_vertices: int) -> sp.csr_matrix:
    """NICP's normal equations at its first stiffness (``solve_affine``: ``alpha^2 K + D^T W D``), normalised units."""
    from gpja.baselines.nicp_solver import block_diagonal, stiffness_matrix
    from gpja.surface import vertex_areas

    V, F = icosphere_near(n_vertices)
    Vn = V / 100.0
    Vh = np.c_[Vn, np.ones(len(V))]
    return (50.0 ** 2 * stiffness_matrix(F, len(V), 1.0) + block_diagonal(Vh, vertex_areas(Vn, F))).tocsr()


def time_backends(H: sp.csr_matrix, repeats: int) -> dict:
    B = np.random.default_rng(1).normal(size=(H.shape[0], 3))
    factor_s = {b: [] for b in BACKENDS}
    solve_s = {b: [] for b in BACKENDS}
    solutions = {}
    for _ in range(repeats):
        for backend in BACKENDS:
            t = time.perf_counter()
            factor = factorize(H, backend)
            factor_s[backend].append(time.perf_counter() - t)
            t = time.perf_counter()
            solutions[backend] = factor.solve(B)
            solve_s[backend].append(time.perf_counter() - t)
    a, b = (solutions[k] for k in BACKENDS)
    out = {"size": H.shape[0], "nonzeros": int(H.nnz)}
    for backend in BACKENDS:
        out[backend] = {"factorize_s": round(statistics.median(factor_s[backend]), 4),
                        "solve_s": round(statistics.median(solve_s[backend]), 5)}
    out["factorize_ratio_simplicial_over_supernodal"] = round(out["simplicial"]["factorize_s"] / out["supernodal"]["factorize_s"], 2)
    out["solve_ratio_simplicial_over_supernodal"] = round(out["simplicial"]["solve_s"] / out["supernodal"]["solve_s"], 2)
    out["max_relative_difference"] = float(np.abs(a - b).max() / np.abs(b).max())
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args()
    from gpja.threads import limit_threads

    limit_threads(args.threads)
    systems = {f"flow_{n // 1000}K": flow_system(n) for n in (16002, 40005, 100013)}
    systems["nicp_16K"] = nicp_system(16002)
    result = {"benchmark": "cholesky", "repeats": args.repeats, "threads": args.threads,
              "systems": {name: time_backends(H, args.repeats) for name, H in systems.items()}}
    print(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()
