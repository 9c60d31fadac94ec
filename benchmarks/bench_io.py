"""Time reading a registered-size OBJ: ``gpja.mesh.read_obj`` (numpy over the file's bytes, ``_scan_obj``) against
the reader before it (a Python loop over the lines, then numpy's one-call parsers) and the line-by-line parsers both
fall back to, side by side in one process.

A GPJA registration writes 100K vertices and 200K triangles with texture coordinates; every metrics, stage
score, remesh, re-parametrisation, export and animation job reads such files (a metrics job five times).
The mesh here is an icosphere of about that size with a UV per vertex, so no workflow run is needed.

Prints JSON: the median seconds of each reader over ``--repeats`` alternating reads, their ratios, and whether
all read the same arrays (bit for bit).
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

        def scan():
            return M.read_obj(path, load_texture=False)

        def numpy():  # the text path: the reader before the byte scan
            with mock.patch.object(M, "_scan_obj", lambda *a, **k: None):
                return M.read_obj(path, load_texture=False)

        def line_by_line():
            with mock.patch.object(M, "_scan_obj", lambda *a, **k: None), \
                    mock.patch.object(M, "_parse_numbers", lambda *a, **k: None), \
                    mock.patch.object(M, "_parse_triangles", lambda *a, **k: None):
                return M.read_obj(path, load_texture=False)

        readers = {"scan": scan, "numpy": numpy, "line_by_line": line_by_line}
        times = {name: [] for name in readers}
        meshes = {}
        for _ in range(max(args.repeats, 1)):
            for name, read in readers.items():
                t0 = time.perf_counter()
                meshes[name] = read()
                times[name].append(time.perf_counter() - t0)
        a = meshes["scan"]
        same = all(getattr(a, k).tobytes() == getattr(b, k).tobytes()
                   for b in meshes.values() for k in ("V", "F", "UV", "F_uv"))
        medians = {k: round(statistics.median(v), 3) for k, v in times.items()}
        print(json.dumps({"benchmark": "read_obj", "vertices": len(V), "faces": len(F),
                          "file_mb": round(path.stat().st_size / 1e6, 1), "repeats": args.repeats,
                          "median_seconds": medians,
                          "ratio_numpy_to_line_by_line": round(medians["numpy"] / medians["line_by_line"], 3),
                          "ratio_scan_to_numpy": round(medians["scan"] / medians["numpy"], 3),
                          "identical": same}, indent=1))


if __name__ == "__main__":
    main()
