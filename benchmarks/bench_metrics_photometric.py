"""Time the photometric metrics (PSNR, SSIM, LPIPS of a textured render) for 8 views at 512x512.

Scene: the synthetic head (seed 0, as in bench_render.py) decimated to 64K triangles
with cylindrical UVs and a smooth random 1024^2 texture. The "scan" is the head
itself (its coverage gives the head mask); the reference images are renders of
the head displaced by a smooth 0.5 mm field plus 2% pixel noise, so every metric
has something to measure.

Prints JSON: median seconds of the whole ``evaluate_photometric`` call and of its
parts (render / PSNR + SSIM / LPIPS), and the metric values.
Usage: python benchmarks/bench_metrics_photometric.py [--repeats N] [--size 512] [--views 8] [--faces 64000] [--threads T]
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import time

import numpy as np
import torch
from scipy.ndimage import gaussian_filter

from bench_render import cylindrical_uv, head_meshes  # same folder: the same synthetic head
from gpja.data.synthetic.capture import make_rig, make_sh
from gpja.mesh import TexturedMesh
from gpja.metrics.lpips import lpips_distance, shared_lpips
from gpja.metrics.photometric import (
    comparison_crop, evaluate_photometric, head_mask, masked_psnr, masked_ssim, render_with_texture,
)
from gpja.render import render_scan_targets


def median_s(fn, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def scene(n_faces: int, size: int, n_views: int):
    """(mesh, texture, cameras, reference images, coverage, sh) of the benchmark."""
    V, F = head_meshes([n_faces])[n_faces]
    rng = np.random.default_rng(0)
    texture = gaussian_filter(rng.random((1024, 1024, 3)), sigma=(6, 6, 0)).astype(np.float32)
    texture = np.clip(0.5 + 4.0 * (texture - 0.5), 0.0, 1.0)  # restore contrast lost to the blur
    mesh = TexturedMesh(V, F, cylindrical_uv(V), F)
    cameras = [c.undistorted() for c in make_rig(np.random.default_rng(1), n_views, size, 600.0, False)]
    sh = make_sh(rng)
    shift = 0.5 * np.sin(V / 20.0)  # smooth 0.5 mm displacement
    displaced = render_with_texture(mesh.with_vertices(V + shift), texture, cameras, sh)
    images = np.clip(displaced + rng.normal(0.0, 0.02, displaced.shape), 0.0, 1.0).astype(np.float32)
    coverage = render_scan_targets(V, F, cameras)["coverage"]
    return mesh, texture, cameras, images, coverage, sh


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--size", type=int, default=512)
    ap.add_argument("--views", type=int, default=8)
    ap.add_argument("--faces", type=int, default=64000)
    ap.add_argument("--threads", type=int, default=None,
                    help="torch intra-op threads (default: torch's choice); on a machine shared with other jobs, "
                         "1 avoids the stalls of threads waiting for descheduled siblings")
    args = ap.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    mesh, texture, cameras, images, coverage, sh = scene(args.faces, args.size, args.views)
    masks = head_mask(coverage)
    shared_lpips()  # weights are read once per process; not part of a call's cost
    result = evaluate_photometric(mesh, texture, cameras, images, coverage, sh)  # warm-up (numba JIT)

    renders = render_with_texture(mesh, texture, cameras, sh)
    crops = [comparison_crop(r, i, m) for r, i, m in zip(renders, images, masks)]

    def psnr_ssim():
        for render, reference, mask in zip(renders, images, masks):
            masked_psnr(render, reference, mask)
            masked_ssim(*comparison_crop(render, reference, mask))

    timings = {
        "total_s": median_s(lambda: evaluate_photometric(mesh, texture, cameras, images, coverage, sh), args.repeats),
        "render_s": median_s(lambda: render_with_texture(mesh, texture, cameras, sh), args.repeats),
        "psnr_ssim_s": median_s(psnr_ssim, args.repeats),
        "lpips_s": median_s(lambda: [lpips_distance(*c) for c in crops], args.repeats),
    }
    print(json.dumps({
        "benchmark": "metrics_photometric", "views": args.views, "image": args.size, "faces": int(len(mesh.F)),
        "torch_threads": torch.get_num_threads(), "cpus": os.cpu_count(), "load_average_1min": round(os.getloadavg()[0], 2),
        "repeats": args.repeats,
        "head_mask_fraction": round(float(masks.mean()), 3),
        "lpips_crop_fraction": round(float(np.mean([c[2].size for c in crops]) / args.size ** 2), 3),
        **{k: round(v, 3) for k, v in timings.items()},
        "psnr": round(result["psnr"], 3), "ssim": round(result["ssim"], 4), "lpips": round(result["lpips"], 4),
    }, indent=1))


if __name__ == "__main__":
    main()
