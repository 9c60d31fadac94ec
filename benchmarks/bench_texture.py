"""Time the template's texture step (render, size choice, fusion, lighting fit, fill) on a fitted mesh.

Takes the dense fitted mesh a template build kept (``template/stages/fitted.obj``) and the
template expression's images and scan targets, runs ``gpja.register.template.build_texture``
with the template settings of a config (default ``config/config.yaml``; ``--settings`` JSON
overrides keys of ``registration.template``), and prints JSON: seconds per stage, the texture
size and median texel footprint, the observed fraction, the colour L1 / PSNR of the fitted mesh
rendered with the new texture under the estimated light against the images (over the pixels the
scan covers), the colour L1 of the texture shaded by the scan's normals instead (what a mesh with
the scan's normals, as registrations fit them, renders), and, with ``--ground-truth``, the lighting's error against the synthetic truth
(``gpja.metrics.lighting``; read by this benchmark only, never by the method).

Usage:
  python benchmarks/bench_texture.py [--data data/synthetic] [--results results/synthetic] [--subject S01]
        [--expression 3_mouth_stretch] [--config config/config.yaml] [--settings JSON] [--ground-truth]
        [--write DIR]
Run the workflow's build_template step first, so the fitted mesh and the scan targets exist.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np
import yaml

REPO = Path(__file__).resolve().parents[1]


def scan_shaded_l1(mesh, texture: np.ndarray, sh: np.ndarray, targets) -> float:
    """Mean |texture(uv) * shading(scan normal) - image| over the pixels the scan fully covers."""
    import torch

    from gpja.lighting import irradiance_over_pi
    from gpja.render import Topology, render_views, sample_texture

    out = render_views(torch.tensor(mesh.V, dtype=torch.float32), Topology(torch.from_numpy(mesh.F), torch.from_numpy(mesh.F_uv)),
                       targets.cameras, ("uv",), uv=torch.tensor(mesh.UV, dtype=torch.float32), antialias_edges=False)
    keep = targets.coverage.reshape(-1)[out.pixels] > 0.999
    normals = targets.normal.reshape(-1, 3)[out.pixels][keep].double()
    shading = irradiance_over_pi(normals / normals.norm(dim=1, keepdim=True), torch.tensor(sh)).float()
    albedo = sample_texture(torch.tensor(texture), out.values["uv"][keep])
    return float((albedo * shading - targets.images.reshape(-1, 3)[out.pixels][keep]).abs().mean())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", default="data/synthetic")
    parser.add_argument("--results", default="results/synthetic")
    parser.add_argument("--subject", default="S01")
    parser.add_argument("--expression", default="3_mouth_stretch", help="the template expression")
    parser.add_argument("--config", default=str(REPO / "config" / "config.yaml"))
    parser.add_argument("--settings", default="{}", help="JSON overriding keys of registration.template")
    parser.add_argument("--lighting", choices=["estimate", "uniform"], default="estimate")
    parser.add_argument("--ground-truth", action="store_true", help="report the lighting's error (synthetic data)")
    parser.add_argument("--write", default=None, help="folder to write texture.png and texture_observed.png to")
    args = parser.parse_args()

    import torch

    from gpja.data.source import DataSource
    from gpja.io import write_image
    from gpja.lighting import uniform_sh
    from gpja.mesh import read_obj
    from gpja.metrics.photometric import head_mask, masked_psnr, render_with_texture
    from gpja.register.pipeline import expression_targets
    from gpja.register.template import TemplateSettings, build_texture

    section = yaml.safe_load(Path(args.config).read_text())["registration"]["template"]
    settings = TemplateSettings.from_config({**section, **json.loads(args.settings)}, "--settings")
    data_root, results = Path(args.data), Path(args.results) / args.subject
    fitted_path = results / "template" / "stages" / "fitted.obj"
    targets_path = results / "targets" / f"{args.expression}.npz"
    for needed in (fitted_path, targets_path):
        if not needed.exists():
            sys.exit(f"bench_texture: {needed} is missing; run the workflow's build_template step first")
    data = DataSource(images_root=data_root / "images", scans_root=data_root / "scans",
                      cache_dir=Path(args.results) / "undistorted").load(args.subject, args.expression)
    targets = expression_targets(data, targets_path, uniform_sh(1.0))
    fitted = read_obj(fitted_path, load_texture=False)

    start = time.perf_counter()
    texture, observed, sh, log = build_texture(fitted, targets, settings, args.lighting,
                                               progress=lambda m: print(m, file=sys.stderr), scan_V=data.scan.V)
    seconds = time.perf_counter() - start

    renders = render_with_texture(fitted, texture, targets.cameras, torch.tensor(sh, dtype=torch.float32))
    images = targets.images.numpy()
    masks = head_mask(targets.coverage.numpy())
    l1 = float(np.mean([np.abs(r - i)[m].mean() for r, i, m in zip(renders, images, masks) if m.any()]))
    psnr = float(np.mean([masked_psnr(r, i, m) for r, i, m in zip(renders, images, masks) if m.any()]))
    l1_scan = scan_shaded_l1(fitted, texture, sh, targets)
    report = {
        "benchmark": "texture", "subject": args.subject, "expression": args.expression,
        "settings": {k: v for k, v in {**section, **json.loads(args.settings)}.items()
                     if k.startswith(("texture", "fusion", "lighting"))},
        "views": len(data.views), "image_size": [data.views[0].camera.width, data.views[0].camera.height],
        "mesh_vertices": int(len(fitted.V)),
        "machine": {"cpus": os.cpu_count(), "threads": torch.get_num_threads(), "python": platform.python_version()},
        "seconds": round(seconds, 3), "seconds_by_stage": {k: round(v, 3) for k, v in log["seconds"].items()},
        "texture_size": log["size"], "median_footprint_px": log["median_footprint_px"],
        "observed_fraction": round(log["observed_fraction"], 4), "albedo_scale": log["albedo_scale"],
        "render_l1": round(l1, 5), "render_psnr_db": round(psnr, 3), "scan_shaded_l1": round(l1_scan, 5),
    }
    if args.ground_truth:
        from gpja.data.ground_truth import lighting_for
        from gpja.metrics.lighting import lighting_scores

        truth = lighting_for(args.subject, args.expression, data_root / "ground_truth")
        report["lighting"] = {k: v for k, v in lighting_scores(sh, truth).items() if k != "definition"}
    if args.write:
        out = Path(args.write)
        write_image(out / "texture.png", texture)
        write_image(out / "texture_observed.png", np.where(observed, 255, 0).astype(np.uint8))
    print(json.dumps(report, indent=1))


if __name__ == "__main__":
    main()
