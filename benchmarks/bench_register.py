"""Time one GPJA registration, level by level, at the default or the paper's settings.

Registers a subject's template to one expression of a finished workflow run
(default: the default config's ``data/synthetic`` and ``results/synthetic``,
subject S01, expression 1_neutral) and prints JSON: total seconds, and per
level the vertex count, iterations, iterations per second and where the time
went (forward solve, render + loss, backward incl. the adjoint solve), plus
the scan-to-mesh distance of the result (mean / median / 95th percentile, mm;
every scan vertex to the registered surface, Open3D closest points).

Presets:
  default  the settings of ``config/config.yaml`` (registration.gpja).
  paper    4 levels 16K -> ~250K vertices (refine factor 2.5), lambda
           200/120/80/50, 1500 iterations in all (375 per level), 8 views at
           the data's resolution (512 x 512 for the default synthetic data).
  paper-fast  the paper's settings with issue 17's speed levers (``PAPER_FAST``); side by side with the
           paper's: ``--preset paper-fast --compare-settings '{"views_per_iteration": null,
           "image_factor": null, "face_order": "mesh", "average_iterations": 0}'``.
  --settings '{...}' overrides either (same keys as the config section).

Side by side (issue 15: a registration started from another expression's result must cost no more
than one from the template): ``--compare-start results/synthetic/S01/gpja/13_lip_funneler.obj``
runs, alternating ``--repeats`` times, the registration from the template (as before) and from that
mesh with its stage meshes saved (as the workflow now runs it), and prints both and the ratio of
their median times.

The flow stage against the warm-up it replaced (issue 15: a default registration must cost no more
than before): ``--compare-settings '{"flow_rounds": 0, "warmup_iterations": 200}'`` runs, alternating
``--repeats`` times, the preset and the preset with those overrides (both from the template, or both
from ``--start``), and prints both and the ratio of their median times.

Usage:
  python benchmarks/bench_register.py [--preset default|paper] [--subject S01] [--expression 1_neutral]
        [--data data/synthetic] [--results results/synthetic] [--settings JSON]
Run the workflow first (``snakemake --cores 2``) so the data, targets and template exist.
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
PAPER = {"lambdas": [200, 120, 80, 50], "iterations": [375, 375, 375, 375], "refine_factor": 2.5, "lr_fraction": 0.1}
#: Issue 17's speed levers on the paper's settings (``--preset paper-fast``): half the views per iteration, the
#: first level at half the resolution, the faces rendered in spatial order, and the mean of each level's last 30
#: iterates, which takes out the noise that a random half of the views puts into the last steps.
PAPER_FAST = {**PAPER, "views_per_iteration": [4, 4, 4, 4], "image_factor": [2, 1, 1, 1], "face_order": "spatial",
              "average_iterations": 30}
PRESETS = {"paper": PAPER, "paper-fast": PAPER_FAST}


def scan_to_mesh_mm(scan_V: np.ndarray, V: np.ndarray, F: np.ndarray) -> dict:
    from gpja.surface import closest_points, prepare_surface

    surface = prepare_surface(V, F, scan_V.mean(axis=0), find_boundary=False)
    d = closest_points(surface, scan_V).distance
    return {"mean": round(float(d.mean()), 4), "median": round(float(np.median(d)), 4),
            "p95": round(float(np.percentile(d, 95)), 4)}


def shared_texture_psnr(mesh, texture: np.ndarray, targets) -> float:
    """Mean over views of the PSNR (dB) of the mesh rendered with the template texture, over the head mask."""
    from gpja.metrics.photometric import head_mask, masked_psnr, render_with_texture

    renders = render_with_texture(mesh, texture, targets.cameras, targets.sh)
    masks = head_mask(targets.coverage.numpy())
    return float(np.mean([masked_psnr(r, i, m) for r, i, m in zip(renders, targets.images.numpy(), masks) if m.any()]))


def accuracy_scorer(args, template_dir: Path):
    """A function scoring a registered mesh against the synthetic ground truth (None without one): C.D.
    (the metrics' L1 Chamfer, mm) and the dense correspondence (median, mean, p95, the mouth's median and every region's,
    mm). A benchmark may read the ground truth; the registration it times never does."""
    import tempfile

    gt_root = Path(args.data) / "ground_truth"
    if not (gt_root / args.subject / f"{args.expression}.npz").exists():
        return None
    from gpja.mesh import read_ply, write_obj
    from gpja.metrics.correspondence import correspondence_error_files
    from gpja.metrics.geometry import evaluate_geometry

    scans_root = Path(args.data) / "scans"
    scan_V, scan_F = read_ply(scans_root / args.subject / f"{args.expression}.ply")

    def score(mesh) -> dict:
        geometry = evaluate_geometry(mesh.V, mesh.F, scan_V, scan_F)
        with tempfile.TemporaryDirectory() as tmp:
            path = Path(tmp) / "registered.obj"
            write_obj(path, mesh, texture_name=None)
            corr = correspondence_error_files(path, template_dir / "template.obj", scans_root, gt_root,
                                              args.subject, args.expression)
        regions = corr.get("regions") or {}
        medians = {name: None if (r or {}).get("median_mm") is None else round(r["median_mm"], 3)
                   for name, r in regions.items()}
        return {"chamfer_l1_mm": round(geometry.chamfer_l1_mm, 4),
                "correspondence_mm": {k: round(corr[k], 3) for k in ("median_mm", "mean_mm", "p95_mm")},
                "mouth_median_mm": medians.get("mouth"), "region_medians_mm": medians}

    return score


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--preset", choices=["default", *PRESETS], default="default")
    parser.add_argument("--settings", default="{}", help="JSON overriding the preset")
    parser.add_argument("--subject", default="S01")
    parser.add_argument("--expression", default="1_neutral")
    parser.add_argument("--data", default="data/synthetic")
    parser.add_argument("--results", default="results/synthetic")
    parser.add_argument("--compare-start", default=None,
                        help="a registered .obj of another expression: time the template start against it")
    parser.add_argument("--compare-settings", default=None,
                        help="JSON overriding the preset for a second schedule, timed alternating with the first")
    parser.add_argument("--start", default=None, help="a registered .obj of another expression to start from")
    parser.add_argument("--repeats", type=int, default=1,
                        help="alternating runs of each (--compare-start, --compare-settings)")
    parser.add_argument("--threads", type=int, default=None, help="threads (as gpja --threads); default: torch's")
    args = parser.parse_args()

    from gpja.data.source import DataSource
    from gpja.register.hra import Switches

    if args.threads:
        from gpja.threads import limit_threads

        limit_threads(args.threads)
    from gpja.register.multiscale import Schedule
    from gpja.register.pipeline import expression_targets, register
    from gpja.results import read_template, read_template_lighting

    default = yaml.safe_load((REPO / "config" / "config.yaml").read_text())["registration"]["gpja"]
    settings = {**PRESETS.get(args.preset, default), **json.loads(args.settings)}
    schedule = Schedule.from_config(settings, "--settings")
    data_root, results = Path(args.data), Path(args.results) / args.subject
    template_dir = results / "template"
    targets_path = results / "targets" / f"{args.expression}.npz"
    for needed in (template_dir / "template.obj", template_dir / "lighting.json", targets_path):
        if not needed.exists():
            sys.exit(f"bench_register: {needed} is missing; run the workflow first (snakemake --cores 2)")

    data = DataSource(images_root=data_root / "images", scans_root=data_root / "scans",
                      cache_dir=Path(args.results) / "undistorted").load(args.subject, args.expression)
    # the lighting the template's texture was fused under (lighting.json), as `gpja register` reads it
    targets = expression_targets(data, targets_path, read_template_lighting(template_dir))
    template, mask = read_template(template_dir)
    orientation = template.V  # the template's orientation for the untangling's turned faces, as `gpja register`
    if args.compare_start:
        compare_starts(args, template, mask, targets, schedule, data)
        return
    if args.start:
        from gpja.mesh import read_obj
        from gpja.register.pipeline import start_from

        template = start_from(template, read_obj(args.start, load_texture=False), args.start)
    if args.compare_settings:
        other = Schedule.from_config({**settings, **json.loads(args.compare_settings)}, "--compare-settings")
        compare_schedules(args, template, mask, targets, {"preset": schedule, "compared": other}, data, orientation)
        return
    start = time.perf_counter()
    mesh, log = register(template, mask, targets, schedule, Switches(), progress=lambda m: print(m, file=sys.stderr),
                         orientation=orientation, scan=(data.scan.V, data.scan.F))
    seconds = time.perf_counter() - start
    levels = [level_entry(lv) for lv in log.levels]
    score = accuracy_scorer(args, template_dir)
    print(json.dumps({
        "benchmark": "register", "preset": args.preset, "settings": settings, "subject": args.subject,
        "expression": args.expression, "views": len(data.views),
        "image_size": [data.views[0].camera.width, data.views[0].camera.height],
        "machine": machine(),
        "seconds": round(seconds, 2), "levels": levels,
        "scan_to_mesh_mm": scan_to_mesh_mm(data.scan.V, mesh.V, mesh.F),
        "psnr_db": round(shared_texture_psnr(mesh, template.texture, targets), 2),
        "accuracy": None if score is None else score(mesh),
    }, indent=1))


def level_entry(lv: dict) -> dict:
    """One registration log entry in the JSON: a flow stage or the untangling (seconds, rounds) or a level / the
    warm-up."""
    if "iterations" not in lv:  # a stage without descent iterations
        rounds = lv.get("rounds") or 0  # the flow logs each round, the untangling counts them
        return {"level": lv["stage"], "vertices": lv.get("vertices"), "seconds": lv["seconds"],
                "rounds": rounds if isinstance(rounds, int) else len(rounds)}
    return {"level": lv["level"] + 1 if lv.get("stage") != "warmup" else "warm-up", "vertices": lv["vertices"],
            "iterations": lv["iterations"], "seconds": lv["seconds"], "setup_seconds": lv["setup_seconds"],
            "iterations_per_second": round(lv["iterations"] / max(lv["seconds"] - lv["setup_seconds"], 1e-9), 2),
            "seconds_by_stage": lv["seconds_by_stage"]}


def time_alternately(cases: dict, repeats: int, data, score=None) -> tuple[dict, dict]:
    """Run each case (name -> callable returning ``(mesh, log)``) in turn, ``repeats`` times round.

    Returns per-case runs (seconds; per flow stage and level its time and, for a level, where it went:
    solve, render, backward; scan-to-mesh; with ``score`` (:func:`accuracy_scorer`) its accuracy) and
    median seconds.
    """
    import statistics

    runs = {name: [] for name in cases}
    for _ in range(max(repeats, 1)):
        for name, run in cases.items():
            t0 = time.perf_counter()
            mesh, log = run()
            entry = {"seconds": round(time.perf_counter() - t0, 2),
                     "levels": [{k: e[k] for k in ("level", "vertices", "seconds", "seconds_by_stage") if k in e}
                                for e in map(level_entry, log.levels)],
                     "scan_to_mesh_mm": scan_to_mesh_mm(data.scan.V, mesh.V, mesh.F)}
            if score is not None:
                entry["accuracy"] = score(mesh)
            runs[name].append(entry)
    return runs, {k: statistics.median(r["seconds"] for r in v) for k, v in runs.items()}


def machine() -> dict:
    return {"cpus": os.cpu_count(), "python": platform.python_version()}


def compare_schedules(args, start_mesh, mask, targets, schedules: dict, data, orientation=None) -> None:
    """Alternate registrations with each of ``schedules`` (name -> Schedule) from one start; print JSON.
    ``orientation``: the template's positions (``register``'s), when ``start_mesh`` is another start."""
    from gpja.register.hra import Switches
    from gpja.register.pipeline import register

    def case(schedule):
        return lambda: register(start_mesh, mask, targets, schedule, Switches(),
                                progress=lambda m: print(m, file=sys.stderr), orientation=orientation,
                                scan=(data.scan.V, data.scan.F))

    runs, medians = time_alternately({name: case(s) for name, s in schedules.items()}, args.repeats, data,
                                     accuracy_scorer(args, Path(args.results) / args.subject / "template"))
    print(json.dumps({"benchmark": "register_settings", "subject": args.subject, "expression": args.expression,
                      "start": args.start or "template", "compared_settings": json.loads(args.compare_settings),
                      "threads": args.threads, "repeats": args.repeats, "runs": runs, "median_seconds": medians,
                      "ratio_preset_to_compared": round(medians["preset"] / medians["compared"], 3),
                      "machine": machine()}, indent=1))


def compare_starts(args, template, mask, targets, schedule, data) -> None:
    """Alternate the registration from the template and from ``--compare-start`` (stages saved); print JSON."""
    import tempfile

    from gpja.mesh import read_obj
    from gpja.register.hra import Switches
    from gpja.register.pipeline import register, start_from
    from gpja.results import stage_writer

    parent = start_from(template, read_obj(args.compare_start, load_texture=False), args.compare_start)

    def case(mesh0, save_stages):
        def run():
            with tempfile.TemporaryDirectory() as tmp:
                return register(mesh0, mask, targets, schedule, Switches(),
                                on_stage=stage_writer(tmp) if save_stages else None,
                                progress=lambda m: print(m, file=sys.stderr), orientation=template.V,
                                scan=(data.scan.V, data.scan.F))
        return run

    runs, medians = time_alternately({"template": case(template, False), "tree": case(parent, True)}, args.repeats,
                                     data)
    print(json.dumps({"benchmark": "register_start", "subject": args.subject, "expression": args.expression,
                      "start_from": args.compare_start, "repeats": args.repeats, "runs": runs,
                      "median_seconds": medians, "ratio_tree_to_template": round(medians["tree"] / medians["template"], 3),
                      "machine": machine()}, indent=1))

if __name__ == "__main__":
    main()
