"""Time the CPU LargeSteps machinery on meshes of ~16K, ~64K and ~250K vertices.

For each size: building ``M = I + lambda L`` (cotangent Laplacian, scipy),
factorising it (cholespy float32 Cholesky, CPU), one solve of an (n, 3)
float32 right-hand side, and one optimisation iteration's LargeSteps overhead
(``x = M^-1 u`` forward plus ``dL/du = M^-1 dL/dx`` backward, i.e. two solves,
plus the UniformAdam update). The issue's budget: ~120 ms per solve at 250K
vertices on the 2-core CPU machine.

Meshes: N x N triangulated tori (closed, genus 1, every vertex of valence 6)
with a deterministic bump so cotangent weights vary, N = 128, 256, 500
(16,384 / 65,536 / 250,000 vertices), radii 100 mm and 40 mm.

Thread interplay: torch's OpenMP workers spin-wait after each parallel op
(libgomp's default ``OMP_WAIT_POLICY``) and then compete for the two cores with
cholespy's solve, so torch ops and solves interleaved in one iteration cost far
more than either alone. ``OMP_WAIT_POLICY`` is read when the OpenMP runtime
loads, so the benchmark measures each setting in its own child process:
``default`` (the variable as inherited) and ``passive``.

Prints JSON: per wait policy and size, the median milliseconds of each stage.
Usage: python benchmarks/bench_largesteps.py [--repeats N] [--sides 128 256 500] [--lam 20]
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
import time

import numpy as np
import torch

from gpja.register.laplacian import system_matrix
from gpja.register.largesteps import SmoothingSolver, UniformAdam, from_differential


def torus(side: int, R: float = 100.0, r: float = 40.0) -> tuple[np.ndarray, np.ndarray]:
    """(side^2, 3) float64 vertices in mm and (2 side^2, 3) int64 faces of a bumpy torus."""
    a, b = np.meshgrid(np.arange(side), np.arange(side), indexing="ij")
    th, ph = 2 * np.pi * a / side, 2 * np.pi * b / side
    rr = r * (1.0 + 0.1 * np.sin(5 * th) * np.cos(7 * ph))
    V = np.stack([(R + rr * np.cos(ph)) * np.cos(th), (R + rr * np.cos(ph)) * np.sin(th), rr * np.sin(ph)], -1)
    idx = (a * side + b)
    i00, i10 = idx, ((a + 1) % side) * side + b
    i01, i11 = a * side + (b + 1) % side, ((a + 1) % side) * side + (b + 1) % side
    F = np.concatenate([np.stack([i00, i10, i11], -1).reshape(-1, 3), np.stack([i00, i11, i01], -1).reshape(-1, 3)])
    return V.reshape(-1, 3), F.astype(np.int64)


def median_ms(fn, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(1e3 * (time.perf_counter() - t0))
    return statistics.median(times)


def bench(side: int, lam: float, repeats: int) -> dict:
    V, F = torus(side)
    M = system_matrix(V, F, lam)
    build = median_ms(lambda: system_matrix(V, F, lam), max(3, repeats // 3))
    factor = median_ms(lambda: SmoothingSolver(M), max(3, repeats // 3))
    solver = SmoothingSolver(M)
    b = torch.from_numpy(M @ V).float()
    solver.solve(b)  # warm-up
    solve = median_ms(lambda: solver.solve(b), repeats)
    err = float((solver.solve(b).double() - torch.from_numpy(V)).abs().max() / np.abs(V).max())

    u = b.clone().requires_grad_(True)
    opt = UniformAdam([u], lr=0.1)
    g = torch.randn(len(V), 3, generator=torch.Generator().manual_seed(0))

    def iteration():
        opt.zero_grad()
        (from_differential(u, solver) * g).sum().backward()
        opt.step()

    iteration()
    it = median_ms(iteration, repeats)
    return {
        "vertices": len(V), "faces": len(F), "nnz_M": int(M.nnz), "lam": lam,
        "build_matrix_ms": round(build, 2), "factorise_ms": round(factor, 2),
        "solve_n3_ms": round(solve, 2), "iteration_overhead_ms": round(it, 2),
        "solve_rel_error": err,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=9)
    ap.add_argument("--sides", type=int, nargs="+", default=[128, 256, 500])
    ap.add_argument("--lam", type=float, default=20.0)
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        print(json.dumps([bench(s, args.lam, args.repeats) for s in args.sides]))
        return
    runs = {}
    for name, policy in [("default", os.environ.get("OMP_WAIT_POLICY")), ("passive", "PASSIVE")]:
        env = dict(os.environ)
        if policy is None:
            env.pop("OMP_WAIT_POLICY", None)
        else:
            env["OMP_WAIT_POLICY"] = policy
        cmd = [sys.executable, __file__, "--child", "--repeats", str(args.repeats), "--lam", str(args.lam),
               "--sides", *map(str, args.sides)]
        res = subprocess.run(cmd, env=env, check=True, capture_output=True, text=True)
        runs[name] = {"OMP_WAIT_POLICY": policy, "results": json.loads(res.stdout.strip().splitlines()[-1])}
    out = {
        "machine": {"cpus": os.cpu_count(), "torch_threads": torch.get_num_threads(),
                    "platform": platform.platform()},
        "budget_solve_ms_at_250k": 120.0,
        "runs": runs,
    }
    print(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()
