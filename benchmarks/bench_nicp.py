"""Time the NICP baseline at the paper's sizes: a ~16K-vertex closed template onto a
~250K-face open scan (an ellipsoid with a jaw-like opening, bumps and a rigid offset,
its back cropped; 68 landmarks on the front).
Prints JSON: wall time per registration (median over --repeats), the per-stage and
per-stiffness-level breakdown, the solver's factorisation/CG counts, and the
scan-to-mesh mean distance before and after.

The sparse Cholesky backends (``NicpSettings.cholesky``, ``gpja.cholesky``) run side by side, alternating:
each backend gets its own timings, and ``max_vertex_difference_mm`` says how far their results are apart.

Usage: python benchmarks/bench_nicp.py [--repeats N] [--seed S] [--backends supernodal simplicial]
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time

import numpy as np
import open3d as o3d
import trimesh

from gpja.baselines.nicp import NicpSettings, nicp
from gpja.cholesky import BACKENDS as CHOLESKY_BACKENDS
from gpja.mesh import TexturedMesh
from gpja.surface import prepare_surface

AXES_MM = np.array([80.0, 100.0, 90.0])


def open_jaw(V: np.ndarray, angle_deg: float = 15.0) -> np.ndarray:
    """Rotate the lower part (y < -30 mm, smoothly blended) about a hinge axis along X,
    like a jaw opening: the chin moves ~25 mm."""
    w = 1.0 / (1.0 + np.exp(-(-V[:, 1] - 30.0) / 8.0))
    a = np.radians(angle_deg) * w
    pivot = np.array([0.0, -10.0, -20.0])
    y, z = V[:, 1] - pivot[1], V[:, 2] - pivot[2]
    return np.c_[V[:, 0], pivot[1] + np.cos(a) * y - np.sin(a) * z, pivot[2] + np.sin(a) * y + np.cos(a) * z]


def deform(V: np.ndarray, seed: int) -> np.ndarray:
    """An expression-sized change, mm: a jaw opening, smooth radial bumps at two scales
    (4 mm / 25 mm wide and 1.5 mm / 8 mm wide) on the front, a 4-degree turn and a 4 mm shift."""
    rng = np.random.default_rng(seed)
    d = V / np.linalg.norm(V, axis=1, keepdims=True)
    height = np.zeros(len(V))
    for count, amp, width in ((12, 4.0, 25.0), (30, 1.5, 8.0)):
        dirs = rng.normal(size=(count, 3)) * [0.6, 0.6, 0.3] + [0, 0, 1.0]
        centres = AXES_MM * dirs / np.linalg.norm(dirs, axis=1, keepdims=True)
        for c, s in zip(centres, rng.choice([-1.0, 1.0], count)):
            height += s * amp * np.exp(-((V - c) ** 2).sum(1) / (2 * width ** 2))
    th = np.radians(4.0)
    R = np.array([[np.cos(th), 0, np.sin(th)], [0, 1, 0], [-np.sin(th), 0, np.cos(th)]])
    return open_jaw(V + height[:, None] * d) @ R.T + [3.0, -2.0, 2.0]


def make_case(seed: int) -> dict:
    """Template (~16K vertices, spherical UVs) and scan (~250K faces, open), both mm."""
    ico = trimesh.creation.icosphere(subdivisions=6)
    m = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(np.asarray(ico.vertices) * AXES_MM),
                                  o3d.utility.Vector3iVector(np.asarray(ico.faces)))
    m = m.simplify_quadric_decimation(target_number_of_triangles=32000)
    V, F = np.asarray(m.vertices), np.asarray(m.triangles).astype(np.int64)
    d = V / np.linalg.norm(V, axis=1, keepdims=True)
    UV = np.c_[0.5 + np.arctan2(d[:, 0], d[:, 2]) / (2 * np.pi), 0.5 + np.arcsin(d[:, 1]) / np.pi]
    template = TexturedMesh(V, F, UV, F.copy())

    fine = trimesh.creation.icosphere(subdivisions=7)
    Vs, Fs = deform(np.asarray(fine.vertices) * AXES_MM, seed), np.asarray(fine.faces)
    Fs = Fs[(fine.vertices[Fs][:, :, 2] > -0.5).all(axis=1)]  # crop the back: an open face scan with a rim
    used = np.unique(Fs)
    remap = np.full(len(Vs), -1)
    remap[used] = np.arange(len(used))
    Vs, Fs = Vs[used], remap[Fs]

    rng = np.random.default_rng(seed + 1)
    lm = rng.choice(np.flatnonzero(V[:, 2] > 0.5 * AXES_MM[2]), 68, replace=False)
    return {"template": template, "V_scan": Vs, "F_scan": Fs, "lm_template": lm, "lm_scan": deform(V, seed)[lm]}


def scan_to_mesh_mean(V_scan: np.ndarray, V: np.ndarray, F: np.ndarray) -> float:
    return float(prepare_surface(V, F, find_boundary=False).closest(V_scan).distance.mean())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--backends", nargs="+", default=list(CHOLESKY_BACKENDS), choices=CHOLESKY_BACKENDS)
    args = ap.parse_args()
    case = make_case(args.seed)
    runs_by_backend = {backend: [] for backend in args.backends}
    for _ in range(max(1, args.repeats)):
        for backend in args.backends:
            t = time.perf_counter()
            mesh, log = nicp(case["template"], case["V_scan"], case["F_scan"], case["lm_template"], case["lm_scan"],
                             NicpSettings(cholesky=backend), progress=lambda line: print(line, file=sys.stderr))
            runs_by_backend[backend].append({"wall_s": time.perf_counter() - t, "log": log, "V": mesh.V})
    out = {
        "benchmark": "nicp",
        "template_vertices": len(case["template"].V),
        "scan_vertices": len(case["V_scan"]),
        "scan_faces": len(case["F_scan"]),
        "landmarks": len(case["lm_template"]),
        "cpu_count": os.cpu_count(),
        "load_average_1min": round(os.getloadavg()[0], 2),
        "backends": {backend: summarise(runs, case) for backend, runs in runs_by_backend.items()},
    }
    if len(args.backends) == 2:
        a, b = (runs_by_backend[k][0]["V"] for k in args.backends)
        out["max_vertex_difference_mm"] = float(np.abs(a - b).max())
        out["wall_ratio"] = round(out["backends"][args.backends[1]]["wall_s_median"]
                                  / out["backends"][args.backends[0]]["wall_s_median"], 3)
    print(json.dumps(out, indent=1))


def summarise(runs: list[dict], case: dict) -> dict:
    """One backend's runs: median times, per-step breakdown, solver counts, distances, determinism."""
    first = runs[0]["log"]
    return {
        "repeats": len(runs),
        "wall_s_median": round(statistics.median(r["wall_s"] for r in runs), 3),
        "wall_s_runs": [round(r["wall_s"], 3) for r in runs],
        "stages_s_median": {k: round(statistics.median(r["log"]["seconds"][k] for r in runs), 3)
                            for k in first["seconds"]},
        "steps": [{"stiffness": s["stiffness"], "landmark_weight": s["landmark_weight"], "iterations": s["iterations"],
                   "seconds_median": round(statistics.median(r["log"]["steps"][i]["seconds"] for r in runs), 3),
                   "mean_distance_mm": round(s["mean_distance_mm"], 4)} for i, s in enumerate(first["steps"])],
        "solver": {k: v for k, v in first["solver"].items() if k != "per_solve"},
        "scan_to_mesh_mean_mm": {
            "before": round(scan_to_mesh_mean(case["V_scan"], case["template"].V, case["template"].F), 4),
            "after": round(scan_to_mesh_mean(case["V_scan"], runs[0]["V"], case["template"].F), 4)},
        "deterministic": all(np.array_equal(r["V"], runs[0]["V"]) for r in runs),
    }


if __name__ == "__main__":
    main()
