"""Time reading a registered-size OBJ: numpy's one-call parser (``gpja.mesh.read_obj``'s fast path) against the
line-by-line parser it falls back to, side by side in one process.

A GPJA registration writes 100K vertices and 200K triangles with texture coordinates; every metrics, stage
score, remesh, re-parametrisation, export and animation job reads such files (a metrics job five times).
The mesh here is an icosphere of about that size with a UV per vertex, so no workflow run is needed.

Prints JSON: the median seconds of each parser over ``--repeats`` alternating reads, their ratio, and whether
both read the same arrays.
Usage: python benchmarks/bench_io.py [--subdivisions 7] [--repeats 5]
"""
from __future__ import annotations

import argparse
import json
import statistics
import tempfile
import time
from pathlib import Path
from unittest import mock

import numpy as np
import trimesh

import gpja.mesh as M


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--subdivisions", type=int, default=7, help="icosphere subdivisions (7: 164K vertices)")
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    sphere = trimesh.creation.icosphere(subdivisions=args.subdivisions, radius=100.0)
    V = np.asarray(sphere.vertices, dtype=np.float64)
    F = np.asarray(sphere.faces, dtype=np.int64)
    UV = 0.5 + 0.5 * V[:, :2] / 100.0
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "mesh.obj"
        M.write_obj(path, M.TexturedMesh(V, F, UV, F), texture_name=None)

        def line_by_line():
            with mock.patch.object(M, "_parse_numbers", lambda *a, **k: None), \
                    mock.patch.object(M, "_parse_triangles", lambda *a, **k: None):
                return M.read_obj(path, load_texture=False)

        def fast():
            return M.read_obj(path, load_texture=False)

        times = {"numpy": [], "line_by_line": []}
        meshes = {}
        for _ in range(max(args.repeats, 1)):
            for name, read in (("numpy", fast), ("line_by_line", line_by_line)):
                t0 = time.perf_counter()
                meshes[name] = read()
                times[name].append(time.perf_counter() - t0)
        a, b = meshes["numpy"], meshes["line_by_line"]
        same = all(np.array_equal(getattr(a, k), getattr(b, k)) for k in ("V", "F", "UV", "F_uv"))
        medians = {k: round(statistics.median(v), 3) for k, v in times.items()}
        print(json.dumps({"benchmark": "read_obj", "vertices": len(V), "faces": len(F),
                          "file_mb": round(path.stat().st_size / 1e6, 1), "repeats": args.repeats,
                          "median_seconds": medians, "ratio_numpy_to_line_by_line":
                              round(medians["numpy"] / medians["line_by_line"], 3), "identical": same}, indent=1))


if __name__ == "__main__":
    main()
