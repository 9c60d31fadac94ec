"""Time the common triangulation's fit (``gpja.apply.remesh.fit_triangulation``) on a run's subject: each round's
chord errors recomputed only where the last split changed the triangulation (``incremental``, the default) against
every edge every round (the fit before it), side by side in one process, alternating.

Needs a finished run's template and GPJA meshes (``results/{dataset}/{subject}/``); the settings are the config's
``applications.remesh`` defaults (``gpja.apply.settings.RemeshSettings``).

Prints JSON: the median seconds of each over ``--repeats``, their ratio, the rounds and vertices, and whether both
gave the same triangulation (bit for bit).
Usage: python benchmarks/bench_triangulate.py [--subject-dir results/synthetic/S01] [--repeats 3]
"""
from __future__ import annotations

import argparse
import json
import statistics
import time
from pathlib import Path

import numpy as np

from gpja.apply.remesh import common_triangulation, fit_triangulation
from gpja.apply.settings import RemeshSettings
from gpja.mesh import read_obj


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--subject-dir", default="results/synthetic/S01", help="a run's results/{dataset}/{subject}")
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    subject = Path(args.subject_dir)
    template = read_obj(subject / "template" / "template.obj", load_texture=False)
    paths = sorted((subject / "gpja").glob("*.obj"))
    if not paths:
        raise SystemExit(f"no GPJA meshes under {subject / 'gpja'}: run the workflow first")
    meshes = {p.stem: read_obj(p, load_texture=False) for p in paths}
    s = RemeshSettings()
    start = common_triangulation(template, max(s.initial_vertices, len(template.V)))
    times: dict[str, list[float]] = {"incremental": [], "full": []}
    results, rounds = {}, {}
    for _ in range(max(args.repeats, 1)):
        for name in times:
            lines: list[str] = []
            t0 = time.perf_counter()
            results[name] = fit_triangulation(start, meshes, s.tolerance_mm, s.max_vertices, s.max_rounds,
                                              progress=lines.append, tangential_tolerance_mm=s.tangential_tolerance_mm,
                                              face_samples=s.face_samples, incremental=name == "incremental")
            times[name].append(time.perf_counter() - t0)
            rounds[name] = len(lines)
    a, b = results["incremental"], results["full"]
    same = all(np.array_equal(getattr(a, k), getattr(b, k)) for k in ("V", "F", "UV", "F_uv"))
    median = {k: statistics.median(v) for k, v in times.items()}
    print(json.dumps({"subject_dir": str(subject), "expressions": sorted(meshes), "repeats": args.repeats,
                      "median_s": {k: round(v, 2) for k, v in median.items()},
                      "seconds": {k: [round(t, 2) for t in v] for k, v in times.items()},
                      "ratio_incremental_to_full": round(median["incremental"] / median["full"], 3),
                      "rounds": rounds, "vertices": len(a.V), "identical": same}, indent=2))


if __name__ == "__main__":
    main()
