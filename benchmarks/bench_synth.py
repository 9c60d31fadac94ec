"""Time the synthetic benchmark: one subject, default settings (10 expressions,
8 views, 512x512). Prints JSON: wall time per run (median over --repeats) and
the per-stage breakdown (sdf, marching cubes, per-expression scan, render, write).

Usage: python benchmarks/bench_synth.py [--repeats N] [--image-size PX]
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

from gpja.data.synthetic import SynthConfig, synthesize_subject


def run_once(cfg: SynthConfig) -> dict:
    with tempfile.TemporaryDirectory(prefix="bench_synth_") as tmp:
        root = Path(tmp)
        t = time.perf_counter()
        s = synthesize_subject("1", 0, cfg, root / "images", root / "scans", root / "gt", root / "raw",
                               root / "sheet.png", progress=lambda line: print(line, file=sys.stderr))
        s["wall_s"] = time.perf_counter() - t
    return s


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--repeats", type=int, default=1)
    ap.add_argument("--image-size", type=int, default=512)
    args = ap.parse_args()
    # warm-up: JIT compilation (cached on disk by numba) is not part of the measurement
    t = time.perf_counter()
    run_once(SynthConfig(image_size=16, n_views=2, scan_voxel_mm=3.0, render_voxel_mm=3.0,
                         expressions=("1_neutral",)))
    warmup = time.perf_counter() - t
    cfg = SynthConfig(image_size=args.image_size)
    runs = [run_once(cfg) for _ in range(max(1, args.repeats))]
    stages = runs[0]["timings_s"].keys()
    out = {
        "benchmark": "synthesize_subject",
        "config": {"image_size": cfg.image_size, "n_views": cfg.n_views, "expressions": len(cfg.expressions),
                   "scan_voxel_mm": cfg.scan_voxel_mm, "render_voxel_mm": cfg.render_voxel_mm,
                   "supersample": cfg.supersample, "raw_variant": cfg.raw_variant},
        "cpu_count": os.cpu_count(),
        "repeats": len(runs),
        "warmup_s": round(warmup, 3),
        "wall_s_median": round(statistics.median(r["wall_s"] for r in runs), 3),
        "wall_s_runs": [round(r["wall_s"], 3) for r in runs],
        "stages_s_median": {k: round(statistics.median(r["timings_s"][k] for r in runs), 3) for k in stages},
        "per_expression_s_median": {
            k: round(statistics.median(r["timings_s"][k] for r in runs) / len(cfg.expressions), 3)
            for k in ("scan", "render", "write")},
        "scan_vertices": {e: c["scan_vertices"] for e, c in runs[0]["counts"].items()},
        "render_mesh_vertices": runs[0]["render_mesh_vertices"],
    }
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
