"""Time the CPU renderer's rasteriser and silhouette search on a registered mesh, visiting its faces in their own
order against the Z-order curve of ``Topology.visit_order`` (the default since it exists), alternating, one thread.

The mesh is a registration's result (default: the workflow's S01 ``1_neutral``, 100K vertices, 200K faces, whose
refined faces lie 80 mm apart in their own order), rendered into the first ``--views`` of its expression's
undistorted cameras with back faces culled, as a registration's last level renders it. Both orders must give the
same triangle ids, depths, facings and silhouette pairs (checked; the run stops otherwise).

Prints JSON: the median milliseconds of each kernel in each order, and their ratios.
Usage: python benchmarks/bench_visit_order.py [--subject S01] [--expression 1_neutral] [--views 4] [--repeats 25]
"""
from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", default="data/synthetic")
    parser.add_argument("--results", default="results/synthetic")
    parser.add_argument("--subject", default="S01")
    parser.add_argument("--expression", default="1_neutral")
    parser.add_argument("--mesh", help="a registered .obj (default: RESULTS/SUBJECT/gpja/EXPRESSION.obj)")
    parser.add_argument("--views", type=int, default=4)
    parser.add_argument("--repeats", type=int, default=25)
    args = parser.parse_args()

    from gpja.threads import limit_threads

    limit_threads(1)
    import numpy as np
    import torch

    from gpja.data.source import DataSource
    from gpja.mesh import read_obj
    from gpja.register.pipeline import expression_targets
    from gpja.render import Topology, project_to_screen
    from gpja.render.rasterize import rasterize_with_facing
    from gpja.render.silhouettes import find_edge_pairs
    from gpja.render.fragments import rasterize_fragments
    from gpja.results import read_template_lighting

    results = Path(args.results) / args.subject
    mesh_path = Path(args.mesh) if args.mesh else results / "gpja" / f"{args.expression}.obj"
    targets_path = results / "targets" / f"{args.expression}.npz"
    for needed in (mesh_path, targets_path, results / "template" / "lighting.json"):
        if not needed.exists():
            sys.exit(f"bench_visit_order: {needed} is missing; run the workflow first (snakemake --cores 2)")
    data = DataSource(images_root=Path(args.data) / "images", scans_root=Path(args.data) / "scans",
                      cache_dir=Path(args.results) / "undistorted").load(args.subject, args.expression)
    cameras = expression_targets(data, targets_path, read_template_lighting(results / "template")).cameras[: args.views]
    mesh = read_obj(mesh_path)
    V = torch.tensor(mesh.V, dtype=torch.float32)
    screen = project_to_screen(V, cameras)
    faces = torch.from_numpy(np.ascontiguousarray(mesh.F, dtype=np.int64))
    size = (cameras[0].height, cameras[0].width)
    topo = Topology(faces)
    topo.visit_order(mesh.V)
    start = time.perf_counter()
    ids, ordered, candidates = topo.visit_order(mesh.V)  # built at the second ask
    order_ms = 1000 * (time.perf_counter() - start)
    visits = {"own": (None, topo.silhouette_candidates()), "visit_order": ((ids, ordered), candidates)}

    def rasterise(name):
        return rasterize_with_facing(screen.numpy(), mesh.F, *size, cull_backfaces=True, visit=visits[name][0])

    frags = {name: rasterize_fragments(screen, faces, *size, True, visits[name][0]) for name in visits}

    def search(name):
        return find_edge_pairs(frags[name], screen, faces, topo.adjacency, visits[name][1])

    for a, b in zip(rasterise("own"), rasterise("visit_order")):
        if not np.array_equal(a, b):
            sys.exit("bench_visit_order: the two orders rasterise differently")
    for a, b in zip(vars(search("own")).values(), vars(search("visit_order")).values()):
        if not torch.equal(a, b):
            sys.exit("bench_visit_order: the two orders find different silhouette pairs")
    times = {(kernel, name): [] for kernel in ("rasterise", "silhouettes") for name in visits}
    for _ in range(args.repeats):
        for name in visits:
            for kernel, run in (("rasterise", rasterise), ("silhouettes", search)):
                t = time.perf_counter()
                run(name)
                times[kernel, name].append(time.perf_counter() - t)
    ms = {key: round(1000 * statistics.median(t), 2) for key, t in times.items()}
    print(json.dumps({
        "mesh": str(mesh_path), "vertices": int(len(mesh.V)), "faces": int(len(mesh.F)),
        "views": len(cameras), "image_size": list(size), "repeats": args.repeats, "threads": 1,
        "visit_order_build_ms": round(order_ms, 1), "same_output": True,
        **{kernel: {"own_order_ms": ms[kernel, "own"], "visit_order_ms": ms[kernel, "visit_order"],
                    "ratio": round(ms[kernel, "visit_order"] / ms[kernel, "own"], 3)}
           for kernel in ("rasterise", "silhouettes")}}, indent=1))


if __name__ == "__main__":
    main()
