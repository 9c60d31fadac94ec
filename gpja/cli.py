"""The ``gpja`` command: one subcommand per workflow step.

Every subcommand writes its outputs atomically and exits with status 2 and a
one-line ``error: <file>: <problem>`` on bad input, so a Snakemake log names
the culprit. ``check-regression`` exits with status 1 when a metric is worse
than its reference beyond tolerance.
"""
from __future__ import annotations

import argparse
import json
import logging
import sys
import time
import zlib
from pathlib import Path

import numpy as np

from gpja.errors import GpjaError, InputError


def subject_seed_index(subject: str) -> int:
    """A stable per-subject integer (independent of the subject list's order)."""
    return zlib.crc32(str(subject).encode("utf-8")) & 0x7FFFFFFF


def _add_data_args(p: argparse.ArgumentParser, required: bool = True) -> None:
    p.add_argument("--images-root", required=required, help="FaceScape multiview root: {root}/{subject}/{expression}/{view}.jpg|png")
    p.add_argument("--scans-root", required=required, help="raw scans: {root}/{subject}/{expression}.ply")
    p.add_argument("--rt-scale", default=None, help="FaceScape Rt_scale_dict.json (omit when data is in mm)")
    p.add_argument("--views", nargs="+", default=None, help="view names to use (default: all valid)")
    p.add_argument("--max-image-size", type=int, default=None, help="downsample images to this longer side")


def cmd_synth(args: argparse.Namespace) -> None:
    from gpja.data.synthetic import SynthConfig, synthesize_subject

    try:
        settings = json.loads(args.settings)
    except json.JSONDecodeError as err:
        raise InputError("--settings", f"not valid JSON ({err})") from None
    if "expressions" in settings:
        settings["expressions"] = tuple(settings["expressions"])
    try:
        cfg = SynthConfig(**settings)
    except TypeError as err:
        raise InputError("--settings", str(err)) from None
    start = time.perf_counter()
    summary = synthesize_subject(
        args.subject, subject_seed_index(args.subject), cfg,
        images_root=Path(args.images_root), scans_root=Path(args.scans_root),
        gt_root=Path(args.ground_truth_root), raw_root=Path(args.raw_root),
        contact_sheet_path=Path(args.contact_sheet),
        progress=lambda msg: print(msg, flush=True),
    )
    print(f"synth: subject {args.subject} done in {time.perf_counter() - start:.1f} s", flush=True)
    print(json.dumps(summary, indent=1, default=str), flush=True)


def summarize_expression(data) -> dict:
    """A JSON-able summary of a loaded expression, with consistency checks."""
    views = []
    for view in data.views:
        entry = {"name": view.name, "width": view.camera.width, "height": view.camera.height,
                 "image": str(view.path), "mean_rgb": view.image.reshape(-1, 3).mean(axis=0).round(4).tolist()}
        if data.scan is not None:
            uv, z = view.camera.project(data.scan.V)
            inside = (z > 0) & (uv[:, 0] >= -0.5) & (uv[:, 0] <= view.camera.width - 0.5) \
                & (uv[:, 1] >= -0.5) & (uv[:, 1] <= view.camera.height - 0.5)
            entry["scan_fraction_in_view"] = round(float(inside.mean()), 4)
            if inside.mean() < 0.05:
                logging.warning("view %s: only %.1f%% of the scan projects into the image; cameras and scan may be misaligned",
                                view.name, 100 * inside.mean())
        views.append(entry)
    summary = {"subject": data.subject, "expression": data.expression, "views": views,
               "rt_scale": None if data.R is None else {"scale": data.scale, "R": data.R.tolist(), "t": data.t.tolist()}}
    if data.scan is not None:
        from gpja.mesh import TexturedMesh

        V = data.scan.V
        edges = TexturedMesh(V, data.scan.F).edge_lengths()
        summary["scan"] = {"path": str(data.scan.path), "n_vertices": int(len(V)), "n_faces": int(len(data.scan.F)),
                           "bbox_min_mm": V.min(axis=0).round(3).tolist(), "bbox_max_mm": V.max(axis=0).round(3).tolist(),
                           "median_edge_mm": round(float(np.median(edges)), 4)}
    return summary


def cmd_check_data(args: argparse.Namespace) -> None:
    from gpja.data.facescape import load_expression
    from gpja.io import write_json

    data = load_expression(args.images_root, args.subject, args.expression, views=args.views,
                           scans_root=args.scans_root, rt_scale_path=args.rt_scale,
                           cache_dir=args.cache_dir, max_image_size=args.max_image_size)
    summary = summarize_expression(data)
    print(f"check-data: {args.subject}/{args.expression}: {len(data.views)} views, "
          f"scan {summary['scan']['n_vertices']} vertices, median edge {summary['scan']['median_edge_mm']} mm", flush=True)
    write_json(args.output, summary)


def cmd_scan_targets(args: argparse.Namespace) -> None:
    from gpja.data.facescape import load_expression
    from gpja.io import write_image
    from gpja.render import render_scan_targets, resolve_backend

    data = load_expression(args.images_root, args.subject, args.expression, views=args.views,
                           scans_root=args.scans_root, rt_scale_path=args.rt_scale,
                           cache_dir=args.cache_dir, max_image_size=args.max_image_size)
    sizes = {(v.camera.width, v.camera.height) for v in data.views}
    if len(sizes) != 1:
        raise InputError(args.images_root, f"{args.subject}/{args.expression}: views differ in size {sorted(sizes)}; "
                                           "set data.max_image_size so they share one")
    backend = resolve_backend(args.backend)
    start = time.perf_counter()
    targets = render_scan_targets(data.scan.V, data.scan.F, data.cameras, cache_path=args.output, backend=backend)
    covered = targets["coverage"][..., 0].numpy()
    print(f"scan-targets: {args.subject}/{args.expression}: {len(data.views)} views, backend {backend}, "
          f"{time.perf_counter() - start:.2f} s, scan covers {100 * covered.mean():.1f}% of the pixels", flush=True)
    for view, cov in zip(data.views, covered):
        if cov.sum() == 0:
            logging.warning("view %s: the scan covers no pixel of this view", view.name)
    if args.preview:
        # one row per view set: reference image | scan normals | scan depth (near = bright)
        normal = (0.5 + 0.5 * targets["normal"].numpy()) * covered[..., None]
        rows = []
        for view, n, d, cov in zip(data.views, normal, targets["depth"][..., 0].numpy(), covered):
            full = cov > 0.99  # silhouette pixels blend depth with the 0 background
            lo, hi = np.percentile(d[full], [1, 99]) if full.any() else (0.0, 1.0)  # per view: near = bright
            shade = np.clip(0.15 + 0.85 * (hi - d) / max(hi - lo, 1e-6), 0, 1) * cov
            rows.append(np.concatenate([view.image, n, np.repeat(shade[..., None], 3, -1)], axis=1))
        write_image(args.preview, np.concatenate(rows, axis=0))


def _load_for_registration(args):
    from gpja.data.facescape import load_expression
    from gpja.register.pipeline import expression_targets, lighting_for, warn_on_holes

    data = load_expression(args.images_root, args.subject, args.expression, views=args.views,
                           scans_root=args.scans_root, rt_scale_path=args.rt_scale,
                           cache_dir=args.cache_dir, max_image_size=args.max_image_size)
    warn_on_holes(data)
    sh = lighting_for(args.subject, args.expression, args.ground_truth_root)
    return data, expression_targets(data, args.targets, sh)


def _settings(text: str) -> dict:
    try:
        return json.loads(text)
    except json.JSONDecodeError as err:
        raise InputError("--settings", f"not valid JSON ({err})") from None


def _schedule(cfg: dict):
    from gpja.register.multiscale import Schedule

    return Schedule(lambdas=tuple(float(x) for x in cfg["lambdas"]), iterations=tuple(int(x) for x in cfg["iterations"]),
                    refine_factor=float(cfg.get("refine_factor", 2.5)), lr_fraction=float(cfg.get("lr_fraction", 0.1)),
                    lr_decay=float(cfg.get("lr_decay", 1.0)),
                    color_pool=tuple(int(p) for p in cfg["color_pool"]) if cfg.get("color_pool") else None,
                    warmup_iterations=int(cfg.get("warmup_iterations", 0)))


def cmd_template(args: argparse.Namespace) -> None:
    from gpja.register.pipeline import write_template
    from gpja.register.template import TemplateSettings, create_template

    cfg = _settings(args.settings)
    data, targets = _load_for_registration(args)
    settings = TemplateSettings(bust_edge_mm=float(cfg.get("bust_edge_mm", 6.0)), schedule=_schedule(cfg),
                                texture_size=int(cfg.get("texture_size", 1024)),
                                texture_iterations=int(cfg.get("texture_iterations", 200)),
                                texture_lr=float(cfg.get("texture_lr", 0.05)), template_faces=int(cfg.get("faces", 32000)))
    start = time.perf_counter()
    template = create_template(data.scan.V, targets, settings, progress=lambda m: print(m, flush=True))
    write_template(template, args.output_dir)
    print(f"template: {args.subject} done in {time.perf_counter() - start:.1f} s "
          f"({len(template.mesh.V)} vertices) -> {args.output_dir}", flush=True)


def cmd_register(args: argparse.Namespace) -> None:
    import os

    from gpja.register.hra import Switches
    from gpja.register.pipeline import check_units, read_template, register, write_registration

    cfg = _settings(args.settings)
    template, mask = read_template(args.template_dir)
    data, targets = _load_for_registration(args)
    check_units(template, data.scan.V, data.scan.path)
    off = set(args.without or [])
    switches = Switches(color="color" not in off, depth="depth" not in off, normal="normal" not in off, mask="mask" not in off)
    start = time.perf_counter()
    mesh, log = register(template, mask, targets, _schedule(cfg), switches, progress=lambda m: print(m, flush=True))
    texture_ref = os.path.relpath(Path(args.template_dir) / "texture.png", Path(args.output).parent)
    summary = {"subject": args.subject, "expression": args.expression, "switches": switches.__dict__,
               "seconds": round(time.perf_counter() - start, 2), **log.to_json()}
    write_registration(mesh, summary, args.output, texture_ref)
    print(f"register: {args.subject}/{args.expression} done in {summary['seconds']} s ({len(mesh.V)} vertices)", flush=True)


def cmd_nicp(args: argparse.Namespace) -> None:
    from gpja.baselines.nicp import run_nicp_files, settings_from_config

    settings = settings_from_config(_settings(args.settings), "--settings")
    start = time.perf_counter()
    log = run_nicp_files(args.template_dir, args.scans_root, args.subject, args.expression, args.output,
                         landmarks=args.landmarks, template_landmarks=args.template_landmarks,
                         template_expression=args.template_expression, rt_scale=args.rt_scale, settings=settings,
                         progress=lambda m: print(m, flush=True))
    print(f"nicp: {args.subject}/{args.expression} done in {time.perf_counter() - start:.1f} s "
          f"({log.get('vertices', '?')} vertices)", flush=True)


def cmd_import(args: argparse.Namespace) -> None:
    from gpja.baselines.external import import_mesh
    from gpja.data.facescape import scan_path

    log = import_mesh(args.pattern, args.subject, args.expression, args.output, transform_pattern=args.transform,
                      texture=args.texture, scan=scan_path(args.scans_root, args.subject, args.expression),
                      rt_scale=args.rt_scale, method=args.method)
    print(f"import: {args.method} {args.subject}/{args.expression} <- {log['source']} "
          f"({log['vertices']} vertices{'' if log['has_uv'] else ', no UVs'})", flush=True)


def cmd_metrics(args: argparse.Namespace) -> None:
    from gpja.io import write_json
    from gpja.metrics.evaluate import MetricSettings, evaluate_expression, summary_line

    try:
        settings = MetricSettings.from_config(_settings(args.settings))
    except TypeError as err:
        raise InputError("--settings", str(err)) from None
    start = time.perf_counter()
    result = evaluate_expression(
        mesh_path=args.mesh, subject=args.subject, expression=args.expression, method=args.method,
        template_dir=args.template_dir, images_root=args.images_root, scans_root=args.scans_root,
        targets_path=args.targets, out_dir=args.output_dir, ground_truth_root=args.ground_truth_root,
        rt_scale=args.rt_scale, views=args.views, cache_dir=args.cache_dir, max_image_size=args.max_image_size,
        template_expression=args.template_expression, settings=settings)
    write_json(args.output, result)
    print(f"metrics: {args.subject}/{args.method}/{args.expression}: {summary_line(result)} "
          f"({time.perf_counter() - start:.1f} s)", flush=True)


def cmd_tables(args: argparse.Namespace) -> None:
    from gpja.report.tables import build_tables, write_table

    tables = build_tables(args.results, args.benchmarks, args.subjects, args.methods, args.expressions,
                          names=args.tables, published=args.published, ablation_subjects=args.ablation_subjects,
                          ablation_expressions=args.ablation_expressions)
    for table in tables:
        paths = write_table(table, args.output_dir)
        print(f"tables: {table.name}: {len(table.csv_rows)} rows -> {', '.join(str(p) for p in paths)}", flush=True)


def cmd_figure(args: argparse.Namespace) -> None:
    from gpja.report.figures import FigureSettings, RunFiles, make_figure

    settings = FigureSettings.from_config(_settings(args.settings))
    files = RunFiles(results=Path(args.results), images_root=args.images_root and Path(args.images_root),
                     scans_root=args.scans_root and Path(args.scans_root),
                     rt_scale=args.rt_scale and Path(args.rt_scale), views=args.views,
                     cache_dir=args.cache_dir and Path(args.cache_dir), max_image_size=args.max_image_size)
    start = time.perf_counter()
    png, pdf = make_figure(args.kind, files, args.subject, args.methods, args.expressions, settings, args.output)
    print(f"figure: {args.kind} of subject {args.subject} -> {png}, {pdf} ({time.perf_counter() - start:.1f} s)",
          flush=True)


def cmd_check_regression(args: argparse.Namespace) -> int:
    from gpja.report.regression import check_regression, load_tolerances, tolerance_lines, write_reference

    if args.write_reference:
        n = write_reference(args.metrics, args.reference, args.subjects, args.methods, args.expressions)
        print(f"check-regression: wrote {n} (subject, method, expression) entries from {args.metrics} "
              f"to {args.reference}", flush=True)
        return 0
    tolerances = load_tolerances(args.tolerances)
    failures, compared = check_regression(args.metrics, args.reference, tolerances)
    print("check-regression: tolerances (worse than the reference by more than this fails):", flush=True)
    print("\n".join(tolerance_lines(tolerances)), flush=True)
    for failure in failures:
        print(failure.line(), flush=True)
    verdict = f"{len(failures)} failure(s)" if failures else "all within tolerance"
    print(f"check-regression: {compared} metrics compared against {args.reference}: {verdict}", flush=True)
    return 1 if failures else 0


def _add_registration_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--subject", required=True)
    p.add_argument("--expression", required=True)
    _add_data_args(p)
    p.add_argument("--ground-truth-root", default=None, help="synthetic ground truth (for the SH lighting)")
    p.add_argument("--cache-dir", default=None, help="where undistorted images are cached")
    p.add_argument("--targets", required=True, help="the expression's scan targets .npz (rendered if missing)")
    p.add_argument("--settings", required=True, help="JSON: lambdas, iterations, refine_factor, lr_fraction, ...")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="gpja", description=__doc__.splitlines()[0])
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    parser.add_argument("--threads", type=int, default=None,
                        help="CPU threads for torch and numba (workflow rules pass their `threads`); default: all")
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("synth", help="synthesise one subject of the benchmark in FaceScape layout")
    p.add_argument("--subject", required=True)
    p.add_argument("--settings", default="{}", help="generator settings as JSON (see gpja.data.synthetic.SynthConfig)")
    p.add_argument("--images-root", required=True)
    p.add_argument("--scans-root", required=True)
    p.add_argument("--ground-truth-root", required=True)
    p.add_argument("--raw-root", required=True)
    p.add_argument("--contact-sheet", required=True, help="PNG overview of the subject")
    p.set_defaults(func=cmd_synth)

    p = sub.add_parser("check-data", help="load one expression through the FaceScape reader and summarise it")
    p.add_argument("--subject", required=True)
    p.add_argument("--expression", required=True)
    _add_data_args(p)
    p.add_argument("--cache-dir", default=None, help="where undistorted images are cached")
    p.add_argument("--output", required=True, help="summary JSON")
    p.set_defaults(func=cmd_check_data)

    p = sub.add_parser("scan-targets", help="render an expression's scan depth/normal/coverage targets once per view set")
    p.add_argument("--subject", required=True)
    p.add_argument("--expression", required=True)
    _add_data_args(p)
    p.add_argument("--cache-dir", default=None, help="where undistorted images are cached")
    p.add_argument("--backend", default="auto", help="render backend: auto | cpu | nvdiffrast")
    p.add_argument("--output", required=True, help="targets .npz")
    p.add_argument("--preview", default=None, help="PNG: reference | scan normals | scan depth, one row per view")
    p.set_defaults(func=cmd_scan_targets)

    p = sub.add_parser("template", help="build a subject's textured template from its mouth-open expression")
    _add_registration_args(p)
    p.add_argument("--output-dir", required=True)
    p.set_defaults(func=cmd_template)

    p = sub.add_parser("register", help="register the subject's template to one expression (GPJA or an ablation)")
    _add_registration_args(p)
    p.add_argument("--template-dir", required=True)
    p.add_argument("--without", nargs="*", choices=["color", "depth", "normal", "mask"], help="ablation: constraints to switch off")
    p.add_argument("--output", required=True, help="registered mesh .obj (a .json log is written beside it)")
    p.set_defaults(func=cmd_register)

    p = sub.add_parser("nicp", help="register the subject's template to one expression with optimal-step NICP")
    p.add_argument("--subject", required=True)
    p.add_argument("--expression", required=True)
    p.add_argument("--scans-root", required=True)
    p.add_argument("--rt-scale", default=None, help="FaceScape Rt_scale_dict.json (omit when data is in mm)")
    p.add_argument("--template-dir", required=True)
    p.add_argument("--template-expression", default="3_mouth_stretch")
    p.add_argument("--landmarks", required=True,
                   help="pattern ({subject}, {expression}) of the scan landmark files (68x3 JSON/TXT, or ground-truth .npz)")
    p.add_argument("--template-landmarks", default=None,
                   help="pattern ({subject}) of template landmark vertex indices or points; default: the template "
                        "expression's landmark file")
    p.add_argument("--settings", default="{}", help="JSON: NICP settings (steps, max_distance_mm, ...)")
    p.add_argument("--output", required=True, help="registered mesh .obj (a .json log is written beside it)")
    p.set_defaults(func=cmd_nicp)

    p = sub.add_parser("import", help="bring a mesh made by another tool into the workflow (scored like the others)")
    p.add_argument("--subject", required=True)
    p.add_argument("--expression", required=True)
    p.add_argument("--method", required=True, help="the imported method's name")
    p.add_argument("--pattern", required=True, help="mesh path pattern with {subject} and {expression} (OBJ or PLY)")
    p.add_argument("--transform", default=None, help="transform JSON pattern (4x4, {scale, R, t} or Rt_scale_dict)")
    p.add_argument("--texture", default=None, help="texture the imported OBJ should reference (e.g. the template's)")
    p.add_argument("--scans-root", required=True, help="to check the mesh's units and placement against the scan")
    p.add_argument("--rt-scale", default=None)
    p.add_argument("--output", required=True, help="the imported mesh .obj (a .json log beside it)")
    p.set_defaults(func=cmd_import)

    p = sub.add_parser("metrics", help="score one method's mesh of one expression: geometry, photometry, correspondence")
    p.add_argument("--subject", required=True)
    p.add_argument("--expression", required=True)
    p.add_argument("--method", required=True, help="the method's name (recorded in the JSON)")
    p.add_argument("--mesh", required=True, help="the method's mesh .obj (template UVs for photometric metrics)")
    p.add_argument("--template-dir", required=True, help="the subject's template folder (shared texture)")
    p.add_argument("--template-expression", default="3_mouth_stretch")
    _add_data_args(p)
    p.add_argument("--ground-truth-root", default=None, help="synthetic ground truth (lighting, correspondence)")
    p.add_argument("--cache-dir", default=None, help="where undistorted images are cached")
    p.add_argument("--targets", default=None, help="the expression's scan targets .npz")
    p.add_argument("--settings", default="{}", help="JSON: the config's metrics section")
    p.add_argument("--output", required=True, help="metrics JSON")
    p.add_argument("--output-dir", required=True, help="per-vertex errors, renders and error images")
    p.set_defaults(func=cmd_metrics)

    p = sub.add_parser("tables", help="the paper's tables (geometry, photometry, ablations, timing, correspondence) "
                                      "as CSV, Markdown and LaTeX")
    p.add_argument("--results", required=True, help="results/{dataset}: the metrics JSONs and registration logs")
    p.add_argument("--benchmarks", required=True, help="benchmarks/{dataset}: Snakemake's benchmark TSVs")
    p.add_argument("--subjects", nargs="+", required=True)
    p.add_argument("--expressions", nargs="+", required=True)
    p.add_argument("--methods", nargs="+", required=True, help="in table order, e.g. gpja nicp gpja-no_normal")
    p.add_argument("--tables", nargs="+", default=None,
                   help="geometry photometric ablation correspondence timing (default: those the run supports)")
    p.add_argument("--published", choices=["facescape"], default=None,
                   help="print the paper's published FaceScape numbers beside the reproduced ones")
    p.add_argument("--ablation-subjects", nargs="+", default=None,
                   help="the subjects the ablation variants ran on (default: --subjects)")
    p.add_argument("--ablation-expressions", nargs="+", default=None,
                   help="the expressions the ablation variants ran on (default: --expressions)")
    p.add_argument("--output-dir", required=True, help="results/{dataset}/tables: {table}.csv|md|tex")
    p.set_defaults(func=cmd_tables)

    from gpja.report.figures import FIGURES

    p = sub.add_parser("figure", help="one of the paper's figures for one subject, as PNG and PDF")
    p.add_argument("kind", choices=FIGURES)
    p.add_argument("--subject", required=True)
    p.add_argument("--methods", nargs="+", default=["gpja"], help="columns (geometric_errors); else the first is drawn")
    p.add_argument("--expressions", nargs="+", required=True)
    p.add_argument("--results", required=True, help="results/{dataset}")
    _add_data_args(p, required=False)  # images for the photometric figures, scans for the geometric ones
    p.add_argument("--cache-dir", default=None, help="where undistorted images are cached")
    p.add_argument("--settings", default="{}", help="JSON: the config's figures section")
    p.add_argument("--output", required=True, help="the .png; the .pdf is written beside it")
    p.set_defaults(func=cmd_figure)

    p = sub.add_parser("check-regression", help="compare a run's metrics with reference values (exit 1 when worse "
                                                "beyond tolerance)")
    p.add_argument("--metrics", required=True, help="results/{dataset} of the run")
    p.add_argument("--reference", required=True, help="reference JSON, e.g. tests/data/ci_reference_metrics.json")
    p.add_argument("--tolerances", default=None, help="JSON overriding allowances: {metric: {absolute, relative}}")
    p.add_argument("--write-reference", action="store_true",
                   help="write --reference from the run's metrics instead of checking")
    p.add_argument("--subjects", nargs="+", default=None, help="with --write-reference: only these subjects")
    p.add_argument("--methods", nargs="+", default=None, help="with --write-reference: only these methods")
    p.add_argument("--expressions", nargs="+", default=None, help="with --write-reference: only these expressions")
    p.set_defaults(func=cmd_check_regression)
    return parser


def limit_threads(n: int) -> None:
    """Use at most ``n`` threads: jobs sharing a machine otherwise oversubscribe it (torch's
    OpenMP workers spin while waiting, so two jobs of 2 threads on 2 cores run several times slower)."""
    import numba
    import torch

    torch.set_num_threads(n)
    numba.set_num_threads(min(n, numba.config.NUMBA_NUM_THREADS))


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.INFO,
                        format="%(levelname)s %(name)s: %(message)s", stream=sys.stderr)
    if args.threads:
        limit_threads(args.threads)
    try:
        status = args.func(args)
    except GpjaError as err:
        print(f"error: {err}", file=sys.stderr, flush=True)
        return 2
    return status or 0


if __name__ == "__main__":
    sys.exit(main())
