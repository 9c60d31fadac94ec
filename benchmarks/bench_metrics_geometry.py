"""Time the geometric metrics (gpja.metrics.geometry.evaluate_geometry): a ~250K-face
registered mesh against a ~300K-face scan, both from the synthetic head (seed 0).

The "registered mesh" is the closed head surface (marching cubes) pushed 0-0.4 mm
along its normals by a smooth field, like a registration with sub-millimetre
error; the "scan" is an independent, finer marching-cubes triangulation of the
same head with the back of the skull and the neck cut away, so it has open
boundaries and the coverage rule has work to do. Target (issue): <= 3 s.

Prints JSON: median wall time over --repeats runs (after one warm-up run that
absorbs Open3D's one-time initialisation, also reported), the per-stage
breakdown (scene build = boundary edges + BVH of both meshes, sampling, closest
points in each direction, scores), and the scores themselves.
Usage: python benchmarks/bench_metrics_geometry.py [--repeats N] [--mesh-faces N] [--scan-faces N] [--samples N]
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import time

import numpy as np
from skimage.measure import marching_cubes

from gpja.data.synthetic import head as head_mod
from gpja.data.synthetic.capture import vertex_normals
from gpja.metrics.geometry import DEFAULT_SAMPLES, evaluate_geometry

#: Voxel used to count faces per voxel^-2 once, mm (coarse: fast).
CALIBRATION_VOXEL_MM = 2.0
#: The scan keeps the front of the head: z above this (mm, face towards +Z) and y above the neck cut.
SCAN_CUT_Z_MM = -30.0
SCAN_CUT_Y_MM = -150.0


def head_surface(program: np.ndarray, voxel_mm: float, offset: float) -> tuple[np.ndarray, np.ndarray]:
    """Marching cubes of the head SDF: V (n, 3) float64 mm, F (m, 3) int64."""
    grid, origin = head_mod.sample_sdf_grid(program, voxel_mm, np.full(3, offset * voxel_mm))
    verts, faces, _, _ = marching_cubes(grid, level=0.0, spacing=(voxel_mm,) * 3, allow_degenerate=False)
    return origin + verts.astype(np.float64), faces.astype(np.int64)


def voxel_for(program: np.ndarray, faces: float) -> float:
    """Voxel size whose marching-cubes mesh has about ``faces`` triangles (faces ~ 1 / voxel^2)."""
    _, F = head_surface(program, CALIBRATION_VOXEL_MM, 0.0)
    return CALIBRATION_VOXEL_MM * float(np.sqrt(len(F) / faces))


def cut_scan(V: np.ndarray, F: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Keep the faces in front of SCAN_CUT_Z_MM and above SCAN_CUT_Y_MM; drop unused vertices."""
    c = V[F].mean(axis=1)
    F = F[(c[:, 2] > SCAN_CUT_Z_MM) & (c[:, 1] > SCAN_CUT_Y_MM)]
    used, F = np.unique(F, return_inverse=True)
    return V[used], F.reshape(-1, 3)


def build_inputs(mesh_faces: int, scan_faces: int) -> dict:
    params = head_mod.sample_head_params(np.random.default_rng(0))
    program = head_mod.build_head_program(params)["head"]
    V, F = head_surface(program, voxel_for(program, mesh_faces), 0.0)
    bump = 0.2 + 0.2 * np.sin(V[:, 0] / 9.0) * np.cos(V[:, 1] / 11.0)  # smooth 0-0.4 mm "registration error"
    V = V + bump[:, None] * vertex_normals(V, F)
    full = head_surface(program, 1.0, 0.0)  # fraction of the surface the cut keeps, from a 1 mm mesh
    keep = len(cut_scan(*full)[1]) / len(full[1])
    Vs, Fs = cut_scan(*head_surface(program, voxel_for(program, scan_faces / keep), 0.37))
    return {"V": V, "F": F, "V_scan": Vs, "F_scan": Fs}


def run_once(inputs: dict, samples: int) -> tuple[float, object]:
    t = time.perf_counter()
    m = evaluate_geometry(inputs["V"], inputs["F"], inputs["V_scan"], inputs["F_scan"], samples=samples)
    return time.perf_counter() - t, m


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--mesh-faces", type=int, default=250_000)
    ap.add_argument("--scan-faces", type=int, default=300_000)
    ap.add_argument("--samples", type=int, default=DEFAULT_SAMPLES)
    args = ap.parse_args()
    t = time.perf_counter()
    inputs = build_inputs(args.mesh_faces, args.scan_faces)
    setup = time.perf_counter() - t
    warmup, _ = run_once(inputs, args.samples)
    runs = [run_once(inputs, args.samples) for _ in range(max(3, args.repeats))]
    walls = [w for w, _ in runs]
    metrics = runs[0][1]
    out = {
        "benchmark": "evaluate_geometry",
        "mesh": {"vertices": len(inputs["V"]), "faces": len(inputs["F"])},
        "scan": {"vertices": len(inputs["V_scan"]), "faces": len(inputs["F_scan"])},
        "samples": args.samples,
        "cpu_count": os.cpu_count(),
        "load_average_1min": round(os.getloadavg()[0], 2),
        "setup_s": round(setup, 3),
        "warmup_s": round(warmup, 3),
        "repeats": len(runs),
        "wall_s_median": round(statistics.median(walls), 3),
        "wall_s_runs": [round(w, 3) for w in walls],
        "stages_s_median": {k: round(statistics.median(m.timings_s[k] for _, m in runs), 3) for k in metrics.timings_s},
        "target_s": 3.0,
        "scores": {k: v for k, v in metrics.to_json().items()
                   if k in ("chamfer_l1_mm", "mesh_to_scan_mm", "scan_to_mesh_mm", "normal_consistency",
                            "fscore", "excluded_fraction")},
    }
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
