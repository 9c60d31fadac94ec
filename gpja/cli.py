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
from pathlib import Path

from gpja.errors import GpjaError, InputError


def _settings(text: str, option: str = "--settings") -> dict:
    """A JSON-object option (a config section, e.g. ``--settings``, read by a settings class's ``from_config``)."""
    try:
        value = json.loads(text)
    except json.JSONDecodeError as err:
        raise InputError(option, f"not valid JSON ({err})") from None
    if not isinstance(value, dict):
        raise InputError(option, f"expected a JSON object, got {text!r}")
    return value


def cmd_synth(args: argparse.Namespace) -> None:
    from gpja.data.synthetic import SynthConfig, subject_seed_index, synthesize_subject

    cfg = SynthConfig.from_config(_settings(args.settings), "--settings")
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


def cmd_check_data(args: argparse.Namespace) -> None:
    from gpja.data.source import DataSource
    from gpja.data.summary import summarize_expression
    from gpja.io import write_json

    data = DataSource.from_args(args).load(args.subject, args.expression)
    summary = summarize_expression(data)
    print(f"check-data: {args.subject}/{args.expression}: {len(data.views)} views, "
          f"scan {summary['scan']['n_vertices']} vertices, median edge {summary['scan']['median_edge_mm']} mm", flush=True)
    write_json(args.output, summary)


def cmd_scan_targets(args: argparse.Namespace) -> None:
    from gpja.data.source import DataSource
    from gpja.data.summary import check_one_image_size, targets_preview, warn_on_empty_targets
    from gpja.io import write_image
    from gpja.render import render_scan_targets, renderer, resolve_backend

    data = DataSource.from_args(args).load(args.subject, args.expression)
    check_one_image_size(data, args.images_root)
    backend = resolve_backend(args.backend)
    start = time.perf_counter()
    targets = render_scan_targets(data.scan.V, data.scan.F, data.cameras, cache_path=args.output,
                                  render=renderer(backend))
    covered = targets["coverage"][..., 0].numpy()
    print(f"scan-targets: {args.subject}/{args.expression}: {len(data.views)} views, backend {backend}, "
          f"{time.perf_counter() - start:.2f} s, scan covers {100 * covered.mean():.1f}% of the pixels", flush=True)
    warn_on_empty_targets([view.name for view in data.views], covered)
    if args.preview:
        write_image(args.preview, targets_preview([view.image for view in data.views], targets["normal"].numpy(),
                                                  targets["depth"][..., 0].numpy(), covered))


def _renderer(args: argparse.Namespace):
    """The ``render_views`` of ``--backend`` (``gpja.render.renderer``; an unknown or missing backend is an InputError)."""
    from gpja.render import renderer

    return renderer(args.backend)


def _load_for_registration(args, sh, render=None):
    """The expression's data and its registration targets (images, scan targets) under SH lighting ``sh`` (9, 3).

    Reads only the capture (images, cameras, scan): never the synthetic ground truth.
    """
    from gpja.data.source import DataSource
    from gpja.register.pipeline import expression_targets, warn_on_holes

    data = DataSource.from_args(args).load(args.subject, args.expression)
    warn_on_holes(data)
    return data, expression_targets(data, args.targets, sh, render=render)


def cmd_template(args: argparse.Namespace) -> None:
    from gpja.lighting import uniform_sh
    from gpja.register.pipeline import write_template
    from gpja.register.template import TemplateSettings, create_template

    settings = TemplateSettings.from_config(_settings(args.settings), "--settings")
    render = _renderer(args)
    # the depth-only fit does not shade; the texture's lighting is estimated from the images (or uniform)
    data, targets = _load_for_registration(args, uniform_sh(1.0), render)
    start = time.perf_counter()
    template = create_template(data.scan.V, targets, settings, progress=lambda m: print(m, flush=True), render=render,
                               lighting=args.lighting)
    write_template(template, args.output_dir)
    print(f"template: {args.subject} done in {time.perf_counter() - start:.1f} s "
          f"({len(template.mesh.V)} vertices) -> {args.output_dir}", flush=True)


def cmd_register(args: argparse.Namespace) -> None:
    import os

    from gpja.data.units import check_units
    from gpja.register.hra import Switches
    from gpja.register.multiscale import Schedule
    from gpja.register.pipeline import before_snap, chain_start, register
    from gpja.results import LIGHTING_FILE, read_template, read_template_lighting, write_registration

    schedule = Schedule.from_config(_settings(args.settings), "--settings")
    template, mask = read_template(args.template_dir)
    start_mesh = template
    if args.start_from:
        from gpja.mesh import read_obj
        from gpja.register.pipeline import start_from

        start_mesh = start_from(template, read_obj(args.start_from, load_texture=False), args.start_from)
    render = _renderer(args)
    # the lighting the template's texture was fused under (its albedo is relative to it)
    data, targets = _load_for_registration(args, read_template_lighting(args.template_dir), render)
    check_units(template, data.scan.V, data.scan.path)
    off = set(args.without or [])
    switches = Switches(color="color" not in off, depth="depth" not in off, normal="normal" not in off, mask="mask" not in off)
    start = time.perf_counter()
    on_stage = None
    if args.stages_dir:
        from gpja.results import stage_writer

        on_stage = stage_writer(args.stages_dir)
    on_stage, kept = before_snap(on_stage)
    from gpja.register.gain import UnlikelyGain

    try:
        mesh, log = register(start_mesh, mask, targets, schedule, switches, progress=lambda m: print(m, flush=True),
                             render=render, on_stage=on_stage, orientation=template.V, scan=(data.scan.V, data.scan.F))
    except UnlikelyGain as err:  # the registration knows no files: name the expression's images here
        raise InputError(Path(args.images_root) / args.subject / args.expression, str(err)) from err
    texture_ref = os.path.relpath(Path(args.template_dir) / "texture.png", Path(args.output).parent)
    summary = {"subject": args.subject, "expression": args.expression, "switches": switches.__dict__,
               "start": str(args.start_from) if args.start_from else "template",
               "lighting": str(Path(args.template_dir) / LIGHTING_FILE),
               "seconds": round(time.perf_counter() - start, 2), **log.to_json()}
    if args.start_output:  # written first: the registration's own files mark the step done
        from gpja.mesh import write_obj

        write_obj(args.start_output, chain_start(template, kept() or mesh), texture_name=None)
    write_registration(mesh, summary, args.output, texture_ref)
    print(f"register: {args.subject}/{args.expression} done in {summary['seconds']} s ({len(mesh.V)} vertices)", flush=True)


def cmd_order(args: argparse.Namespace) -> None:
    from gpja.data.source import DataSource
    from gpja.io import write_json
    from gpja.register.order import plan_order

    source = DataSource.from_args(args)
    names = list(dict.fromkeys([args.template_expression, *args.expressions]))
    scans = {e: source.scan(args.subject, e).V for e in names}
    plan = plan_order(scans, args.template_expression, samples=args.samples, seed=args.seed)
    plan["subject"] = args.subject
    write_json(args.output, plan)
    for e in plan["order"][1:]:
        print(f"order: {args.subject}/{e} starts from {plan['parent'][e]} "
              f"({plan['distances_mm'][e][plan['parent'][e]]:.2f} mm apart)", flush=True)


def cmd_baseline(args: argparse.Namespace) -> None:
    from gpja.data.source import DataSource
    from gpja.methods import method, names

    entry = method(args.method)
    if entry.kind != "baseline":
        raise InputError("--method", f"{args.method!r} is not a baseline; registered: {', '.join(names('baseline'))}")
    section = _settings(args.section, "--section")  # the config's baselines.<method>
    start = time.perf_counter()
    log = entry.run_function()(args.template_dir, DataSource.from_args(args), args.subject, args.expression,
                               args.output, section, args.template_expression, lambda m: print(m, flush=True))
    print(f"{args.method}: {args.subject}/{args.expression} done in {time.perf_counter() - start:.1f} s "
          f"({log.get('vertices', '?')} vertices)", flush=True)


def cmd_import(args: argparse.Namespace) -> None:
    from gpja.baselines.external import import_mesh
    from gpja.data.source import DataSource

    log = import_mesh(args.pattern, args.subject, args.expression, args.output, transform_pattern=args.transform,
                      texture=args.texture, source=DataSource.from_args(args), method=args.method)
    print(f"import: {args.method} {args.subject}/{args.expression} <- {log['source']} "
          f"({log['vertices']} vertices{'' if log['has_uv'] else ', no UVs'})", flush=True)


def cmd_metrics(args: argparse.Namespace) -> None:
    from gpja.data.source import DataSource
    from gpja.io import write_json
    from gpja.metrics.evaluate import MetricSettings, evaluate_expression, summary_line

    settings = MetricSettings.from_config(_settings(args.settings), "--settings")
    start = time.perf_counter()
    result = evaluate_expression(
        mesh_path=args.mesh, subject=args.subject, expression=args.expression, method=args.method,
        template_dir=args.template_dir, source=DataSource.from_args(args), targets_path=args.targets,
        out_dir=args.output_dir, ground_truth_root=args.ground_truth_root,
        template_expression=args.template_expression, settings=settings, render=_renderer(args))
    write_json(args.output, result)
    print(f"metrics: {args.subject}/{args.method}/{args.expression}: {summary_line(result)} "
          f"({time.perf_counter() - start:.1f} s)", flush=True)


def cmd_stages(args: argparse.Namespace) -> None:
    from gpja.data.source import DataSource
    from gpja.metrics.stages import score_stages

    out = score_stages(args.stages_dir, args.template_dir, DataSource.from_args(args), args.ground_truth_root,
                       args.subject, args.expression, args.targets, args.output,
                       template_expression=args.template_expression, render=_renderer(args))
    for row in out["stages"]:
        print(f"stages: {args.subject}/{args.expression} {row['stage']}: correspondence median {row['median_mm']:.2f} "
              f"mean {row['mean_mm']:.2f} mm, PSNR {row['psnr']:.2f} dB (view {out['view']})", flush=True)


def cmd_oracle(args: argparse.Namespace) -> None:
    from gpja.data.source import DataSource
    from gpja.io import write_json
    from gpja.metrics.evaluate import MetricSettings
    from gpja.metrics.oracle import evaluate_oracle

    settings = MetricSettings.from_config(_settings(args.settings), "--settings")
    start = time.perf_counter()
    result = evaluate_oracle(DataSource.from_args(args), args.ground_truth_root, args.subject, args.expression,
                             targets_path=args.targets, out_dir=args.output_dir, supersample=args.supersample,
                             render=_renderer(args), settings=settings)
    write_json(args.output, result)
    p, g = result["photometric"], result["geometry"]
    print(f"oracle: {args.subject}/{args.expression}: PSNR {p['psnr']:.2f} dB, SSIM {p['ssim']:.4f}, "
          f"LPIPS {p['lpips']:.4f}; the true surface against the scan: C.D. {g['chamfer_l1_mm']:.4f} mm, "
          f"N.C. {g['normal_consistency']:.4f} ({time.perf_counter() - start:.1f} s)", flush=True)


def cmd_texture_quality(args: argparse.Namespace) -> None:
    from gpja.metrics.texture_quality import texture_quality_files

    start = time.perf_counter()
    out = texture_quality_files(args.template_dir, args.scans_root, args.ground_truth_root, args.subject,
                                args.template_expression, args.output, args.error_image)
    parts = ", ".join(f"{k} PSNR {out[k]['psnr']:.2f} dB SSIM {out[k]['ssim']:.4f} ({out[k]['texels']} texels)"
                      for k in ("observed", "unobserved") if out[k]["psnr"] is not None)
    print(f"texture-quality: {args.subject}: {parts}; gain {', '.join(f'{g:.3f}' for g in out['gain'])} "
          f"({time.perf_counter() - start:.1f} s)", flush=True)


def cmd_tables(args: argparse.Namespace) -> None:
    from gpja.report.formats import write_table
    from gpja.report.tables import build_tables

    tables = build_tables(args.results, args.benchmarks, args.subjects, args.methods, args.expressions,
                          names=args.tables, published=args.published, ablation_subjects=args.ablation_subjects,
                          ablation_expressions=args.ablation_expressions)
    for table in tables:
        paths = write_table(table, args.output_dir)
        print(f"tables: {table.name}: {len(table.csv_rows)} rows -> {', '.join(str(p) for p in paths)}", flush=True)


def cmd_figure(args: argparse.Namespace) -> None:
    from gpja.data.source import DataSource
    from gpja.report.figures import FigureRequest, FigureSettings, RunFiles, make_figure
    from gpja.results import Layout

    # the backend is resolved when a figure renders (FigureRequest.render): figures drawn from saved files alone
    # then never import torch
    request = FigureRequest(RunFiles(Layout(args.results), DataSource.from_args(args)), args.subject,
                            tuple(args.methods), tuple(args.expressions),
                            FigureSettings.from_config(_settings(args.settings), "--settings"),
                            backend=args.backend)
    start = time.perf_counter()
    png, pdf = make_figure(args.kind, request, args.output)
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


def _named_paths(items: list[str], option: str) -> dict[str, str]:
    """``NAME=PATH`` arguments as an ordered mapping."""
    out = {}
    for item in items:
        name, sep, path = item.partition("=")
        if not sep or not name or not path:
            raise InputError(option, f"expected NAME=PATH, got {item!r}")
        if name in out:
            raise InputError(option, f"{name!r} is given twice ({out[name]} and {path})")
        out[name] = path
    return out


def cmd_triangulate(args: argparse.Namespace) -> None:
    from gpja.apply.settings import RemeshSettings
    from gpja.apply.steps import triangulate

    settings = RemeshSettings.from_config(_settings(args.settings), "--settings")
    log = triangulate(args.template_dir, _named_paths(args.meshes, "--meshes"), settings, args.output,
                      progress=lambda m: print(m, flush=True))
    print(f"triangulate: {args.subject}: {log['vertices']} vertices in {log['seconds']} s -> {args.output}", flush=True)


def cmd_remesh(args: argparse.Namespace) -> None:
    from gpja.apply.steps import remesh

    remesh(args.common, args.mesh, args.template_dir, args.expression, args.output,
           progress=lambda m: print(m, flush=True))


def cmd_export(args: argparse.Namespace) -> None:
    from gpja.apply.settings import ExportSettings
    from gpja.apply.steps import export

    settings = ExportSettings.from_config(_settings(args.settings), "--settings")
    path = export(_named_paths(args.meshes, "--meshes"), settings.base, args.template_dir, args.output, args.subject)
    print(f"export: {args.subject}: base {settings.base}, {len(args.meshes) - 1} morph targets -> {path}", flush=True)


def cmd_animate(args: argparse.Namespace) -> None:
    from gpja.apply.settings import AnimationSettings
    from gpja.apply.steps import animate

    settings = AnimationSettings.from_config(_settings(args.settings), "--settings")
    start = time.perf_counter()
    path = animate(_named_paths(args.meshes, "--meshes"), settings, args.template_dir, args.output,
                   args.frames_output)
    print(f"animate: {args.subject}: {' -> '.join(settings.sequence)} in {time.perf_counter() - start:.1f} s "
          f"-> {path}", flush=True)


def cmd_artist(args: argparse.Namespace) -> None:
    from gpja.apply.settings import ReparamSettings
    from gpja.apply.steps import artist_mesh

    settings = ReparamSettings.from_config(_settings(args.settings), "--settings")
    log = artist_mesh(args.template_dir, settings, args.subject, args.output, progress=lambda m: print(m, flush=True))
    print(f"artist: {args.subject}: {log['faces']} faces in {log['seconds']} s -> {args.output}", flush=True)


def cmd_reparametrize(args: argparse.Namespace) -> None:
    from gpja.apply.settings import ReparamSettings
    from gpja.apply.steps import reparametrize

    settings = ReparamSettings.from_config(_settings(args.settings), "--settings")
    reparametrize(args.artist, args.mesh, args.template_dir, args.expression, args.output, settings,
                  progress=lambda m: print(m, flush=True))


def cmd_turns(args: argparse.Namespace) -> None:
    from gpja.metrics.turns import count_turns

    count_turns(args.artist, _named_paths(args.meshes, "--meshes"), args.order, args.template_dir, args.subject,
                args.output, args.ground_truth_root, args.scans_root, args.template_expression,
                progress=lambda m: print(m, flush=True))


def _add_expression_args(p: argparse.ArgumentParser, method: str | None = None) -> None:
    """``--subject`` and ``--expression`` (and ``--method``, with this help, for a scored method's mesh)."""
    p.add_argument("--subject", required=True)
    p.add_argument("--expression", required=True)
    if method:
        p.add_argument("--method", required=True, help=method)


def _add_scan_args(p: argparse.ArgumentParser, help: str = "raw scans: {root}/{subject}/{expression}.ply") -> None:
    """Where the scans are: ``--scans-root`` and ``--rt-scale``."""
    p.add_argument("--scans-root", required=True, help=help)
    p.add_argument("--rt-scale", default=None, help="FaceScape Rt_scale_dict.json (omit when data is in mm)")


def _add_data_args(p: argparse.ArgumentParser, required: bool = True) -> None:
    """Where a dataset is (the options of :meth:`gpja.data.source.DataSource.from_args`)."""
    p.add_argument("--images-root", required=required, help="FaceScape multiview root: {root}/{subject}/{expression}/{view}.jpg|png")
    p.add_argument("--scans-root", required=required, help="raw scans: {root}/{subject}/{expression}.ply")
    p.add_argument("--rt-scale", default=None, help="FaceScape Rt_scale_dict.json (omit when data is in mm)")
    p.add_argument("--views", nargs="+", default=None, help="view names to use (default: all valid)")
    p.add_argument("--max-image-size", type=int, default=None, help="downsample images to this longer side")
    p.add_argument("--cache-dir", default=None, help="where undistorted images are cached")


def _add_registration_args(p: argparse.ArgumentParser) -> None:
    """The options of the steps that fit a mesh to one expression's images and scan (template, register).

    They read the capture only: no option names a ground truth (tests/test_no_oracle.py)."""
    _add_expression_args(p)
    _add_data_args(p)
    p.add_argument("--targets", required=True, help="the expression's scan targets .npz (rendered if missing)")
    p.add_argument("--settings", required=True, help="JSON: lambdas, iterations, refine_factor, lr_fraction, ...")
    _add_backend_arg(p)


def _add_backend_arg(p: argparse.ArgumentParser) -> None:
    """``--backend``: checked when the command runs (gpja.render.BACKENDS; importing it here would load torch
    for every command)."""
    p.add_argument("--backend", default="auto", help="render backend of every render of the step: auto | cpu | "
                                                     "nvdiffrast (auto: nvdiffrast when it imports and CUDA is visible)")


def _add_selection_args(p: argparse.ArgumentParser, required: bool, note: str | None = None,
                        methods: str | None = None) -> None:
    """``--subjects``, ``--expressions`` and ``--methods``: the part of a run a report step reads.

    ``note`` starts each option's help (``"<note> subjects"``); ``methods`` is the help of ``--methods``.
    """
    helps = {name: f"{note} {name}" if note else None for name in ("subjects", "expressions", "methods")}
    helps["methods"] = methods or helps["methods"]
    for name, text in helps.items():
        p.add_argument(f"--{name}", nargs="+", required=required, default=None, help=text)


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
    _add_expression_args(p)
    _add_data_args(p)
    p.add_argument("--output", required=True, help="summary JSON")
    p.set_defaults(func=cmd_check_data)

    p = sub.add_parser("scan-targets", help="render an expression's scan depth/normal/coverage targets once per view set")
    _add_expression_args(p)
    _add_data_args(p)
    _add_backend_arg(p)
    p.add_argument("--output", required=True, help="targets .npz")
    p.add_argument("--preview", default=None, help="PNG: reference | scan normals | scan depth, one row per view")
    p.set_defaults(func=cmd_scan_targets)

    p = sub.add_parser("template", help="build a subject's textured template from its mouth-open expression")
    _add_registration_args(p)
    p.add_argument("--lighting", choices=["estimate", "uniform"], default="estimate",
                   help="the texture's SH lighting: estimate = fitted to the images (gpja.register.lighting_estimate), "
                        "uniform = white light of radiance 1 (the paper's FaceScape assumption); written to "
                        "lighting.json, which every registration and photometric score uses")
    p.add_argument("--output-dir", required=True)
    p.set_defaults(func=cmd_template)

    p = sub.add_parser("register", help="register the subject's template to one expression (GPJA or an ablation)")
    _add_registration_args(p)
    p.add_argument("--template-dir", required=True)
    p.add_argument("--without", nargs="*", choices=["color", "depth", "normal", "mask"], help="ablation: constraints to switch off")
    p.add_argument("--start-from", default=None,
                   help="another expression's registered .obj to start from (its template vertices' positions, on "
                        "the template's topology; registration.start: tree); default: the template")
    p.add_argument("--stages-dir", default=None,
                   help="folder for the mesh of each stage (start, warm-up, every level) as .npz, for diagnostics")
    p.add_argument("--output", required=True, help="registered mesh .obj (a .json log is written beside it)")
    p.add_argument("--start-output", default=None,
                   help="also write the .obj the registration tree's children start from (--start-from): the "
                        "template's vertices where the registration put them before the snap (snap_mm)")
    p.set_defaults(func=cmd_register)

    p = sub.add_parser("order", help="which expression each registration starts from: the minimum spanning tree of "
                                     "the subject's scan-to-scan distances, rooted at the template's expression")
    p.add_argument("--subject", required=True)
    p.add_argument("--expressions", nargs="+", required=True, help="the expressions to register")
    p.add_argument("--template-expression", default="3_mouth_stretch")
    _add_data_args(p, required=False)
    p.add_argument("--samples", type=int, default=20000, help="scan vertices per mean distance")
    p.add_argument("--seed", type=int, default=0, help="seed of the vertex sampling")
    p.add_argument("--output", required=True, help="order JSON: parent, order, depth and distances_mm")
    p.set_defaults(func=cmd_order)

    p = sub.add_parser("baseline", help="register the subject's template to one expression with a baseline "
                                        "(a `baseline` method of gpja.methods, e.g. nicp)")
    _add_expression_args(p, method="the baseline's name in gpja.methods.METHODS (e.g. nicp)")
    _add_data_args(p, required=False)  # each baseline reads what it needs (NICP: the scans)
    p.add_argument("--template-dir", required=True)
    p.add_argument("--template-expression", default="3_mouth_stretch")
    p.add_argument("--section", default="{}", help="JSON: the config's baselines.<method> section")
    p.add_argument("--output", required=True, help="registered mesh .obj (a .json log is written beside it)")
    p.set_defaults(func=cmd_baseline)

    p = sub.add_parser("import", help="bring a mesh made by another tool into the workflow (scored like the others)")
    _add_expression_args(p, method="the imported method's name")
    p.add_argument("--pattern", required=True, help="mesh path pattern with {subject} and {expression} (OBJ or PLY)")
    p.add_argument("--transform", default=None, help="transform JSON pattern (4x4, {scale, R, t} or Rt_scale_dict)")
    p.add_argument("--texture", default=None, help="texture the imported OBJ should reference (e.g. the template's)")
    _add_scan_args(p, help="to check the mesh's units and placement against the scan")
    p.add_argument("--output", required=True, help="the imported mesh .obj (a .json log beside it)")
    p.set_defaults(func=cmd_import)

    p = sub.add_parser("metrics", help="score one method's mesh of one expression: geometry, photometry, correspondence")
    _add_expression_args(p, method="the method's name (recorded in the JSON)")
    _add_data_args(p)
    p.add_argument("--ground-truth-root", default=None,
                   help="synthetic ground truth (correspondence, the estimated lighting's error); the renders use the "
                        "template's lighting.json")
    p.add_argument("--targets", default=None, help="the expression's scan targets .npz")
    p.add_argument("--mesh", required=True, help="the method's mesh .obj (template UVs for photometric metrics)")
    p.add_argument("--template-dir", required=True, help="the subject's template folder (shared texture)")
    p.add_argument("--template-expression", default="3_mouth_stretch")
    p.add_argument("--settings", default="{}", help="JSON: the config's metrics section")
    _add_backend_arg(p)
    p.add_argument("--output", required=True, help="metrics JSON")
    p.add_argument("--output-dir", required=True, help="per-vertex errors, renders and error images")
    p.set_defaults(func=cmd_metrics)

    p = sub.add_parser("stages", help="synthetic data: score the mesh after every stage of a registration "
                                      "(correspondence, the frontal view's PSNR and L1 image)")
    _add_expression_args(p)
    _add_data_args(p)
    _add_backend_arg(p)
    p.add_argument("--stages-dir", required=True, help="the registration's --stages-dir")
    p.add_argument("--template-dir", required=True)
    p.add_argument("--template-expression", default="3_mouth_stretch")
    p.add_argument("--targets", required=True, help="the expression's scan targets .npz")
    p.add_argument("--ground-truth-root", required=True, help="synthetic ground truth: {root}/{subject}/...")
    p.add_argument("--output", required=True, help="scores .json (the arrays go to the .npz beside it)")
    p.set_defaults(func=cmd_stages)

    p = sub.add_parser("oracle", help="synthetic data: render the ground truth (scan, albedo, lighting) at the "
                                      "reference cameras and score it like a method (Table 2's upper bound)")
    _add_expression_args(p)
    _add_data_args(p)
    p.add_argument("--ground-truth-root", required=True, help="synthetic ground truth: {root}/{subject}/...")
    p.add_argument("--targets", default=None, help="the expression's scan targets .npz (the head mask)")
    p.add_argument("--supersample", type=int, default=None,
                   help="samples per pixel along each axis (default: the generator's, from subject.json)")
    p.add_argument("--settings", default="{}", help="JSON: the config's metrics section (the geometric scores' "
                                                   "protocol)")
    _add_backend_arg(p)
    p.add_argument("--output", required=True, help="metrics JSON (photometric and geometric parts)")
    p.add_argument("--output-dir", required=True, help="per-view renders and error images")
    p.set_defaults(func=cmd_oracle)

    p = sub.add_parser("texture-quality", help="synthetic data: the template texture's PSNR/SSIM against the "
                                               "ground-truth albedo (observed and unobserved texels)")
    p.add_argument("--subject", required=True)
    p.add_argument("--template-dir", required=True, help="template.obj, texture.png (texture_observed.png)")
    p.add_argument("--template-expression", default="3_mouth_stretch")
    p.add_argument("--scans-root", required=True, help="synthetic scans (mm): {root}/{subject}/{expression}.ply")
    p.add_argument("--ground-truth-root", required=True, help="synthetic ground truth: {root}/{subject}/...")
    p.add_argument("--output", required=True, help="texture_quality.json")
    p.add_argument("--error-image", required=True, help="PNG of the per-texel error")
    p.set_defaults(func=cmd_texture_quality)

    from gpja.report.published import PUBLISHED_CHOICES
    from gpja.report.tables import TABLE_NAMES

    p = sub.add_parser("tables", help="the paper's tables (geometry, photometry, ablations, timing, correspondence) "
                                      "as CSV, Markdown and LaTeX")
    p.add_argument("--results", required=True, help="results/{dataset}: the metrics JSONs and registration logs")
    p.add_argument("--benchmarks", required=True, help="benchmarks/{dataset}: Snakemake's benchmark TSVs")
    _add_selection_args(p, required=True, methods="in table order, e.g. gpja nicp gpja-no_normal")
    p.add_argument("--tables", nargs="+", default=None,
                   help=f"{' '.join(TABLE_NAMES)} (default: those the run supports)")
    p.add_argument("--published", choices=PUBLISHED_CHOICES, default=None,
                   help="print the paper's published FaceScape numbers beside the reproduced ones")
    p.add_argument("--ablation-subjects", nargs="+", default=None,
                   help="the subjects the ablation variants ran on (default: --subjects)")
    p.add_argument("--ablation-expressions", nargs="+", default=None,
                   help="the expressions the ablation variants ran on (default: --expressions)")
    p.add_argument("--output-dir", required=True, help="results/{dataset}/tables: {table}.csv|md|tex")
    p.set_defaults(func=cmd_tables)

    p = sub.add_parser("triangulate", help="applications: the triangulation, in the template's texture space, that "
                                           "every remeshed expression of a subject shares")
    p.add_argument("--subject", required=True)
    p.add_argument("--template-dir", required=True, help="the subject's template folder")
    p.add_argument("--meshes", nargs="+", required=True, help="EXPRESSION=OBJ of every expression it must fit")
    p.add_argument("--settings", default="{}", help="JSON: the config's applications.remesh section")
    p.add_argument("--output", required=True, help="the .obj (a .json log beside it)")
    p.set_defaults(func=cmd_triangulate)

    p = sub.add_parser("remesh", help="applications: one expression on the subject's common triangulation")
    _add_expression_args(p)
    p.add_argument("--common", required=True, help="the common triangulation (gpja triangulate)")
    p.add_argument("--mesh", required=True, help="the expression's registered mesh (template UVs)")
    p.add_argument("--template-dir", required=True, help="the subject's template folder (texture, lighting)")
    p.add_argument("--output", required=True, help="the .obj (a .json log of its checks beside it)")
    p.set_defaults(func=cmd_remesh)

    p = sub.add_parser("export", help="applications: the remeshed expressions as one glTF binary with morph "
                                      "targets (blendshapes, Blender shape keys)")
    p.add_argument("--subject", required=True)
    p.add_argument("--meshes", nargs="+", required=True, help="EXPRESSION=OBJ of every remeshed expression")
    p.add_argument("--template-dir", required=True, help="the subject's template folder (its texture is embedded)")
    p.add_argument("--settings", default="{}", help="JSON: the config's applications.export section")
    p.add_argument("--output", required=True, help="the .glb")
    p.set_defaults(func=cmd_export)

    p = sub.add_parser("animate", help="applications: interpolate the remeshed expressions along a sequence, "
                                       "render, encode a video")
    p.add_argument("--subject", required=True)
    p.add_argument("--meshes", nargs="+", required=True, help="EXPRESSION=OBJ of the remeshed expressions")
    p.add_argument("--template-dir", required=True, help="the subject's template folder (texture, lighting)")
    p.add_argument("--settings", default="{}", help="JSON: the config's applications.animation section")
    p.add_argument("--output", required=True, help="the .mp4 (a .gif beside it when no ffmpeg is found)")
    p.add_argument("--frames-output", required=True, help="the film strip's frames (.npz)")
    p.set_defaults(func=cmd_animate)

    p = sub.add_parser("artist", help="applications: the artist mesh carried onto every expression (the configured "
                                      "one, or a stand-in), with the shared texture resampled into its UVs")
    p.add_argument("--subject", required=True)
    p.add_argument("--template-dir", required=True, help="the subject's template folder")
    p.add_argument("--settings", default="{}", help="JSON: the config's applications.reparam section")
    p.add_argument("--output", required=True, help="the .obj (texture.png and a .json log beside it)")
    p.set_defaults(func=cmd_artist)

    p = sub.add_parser("reparametrize", help="applications: the artist mesh on one expression (the paper's "
                                             "phi_b phi_a^-1 through the template's texture space)")
    _add_expression_args(p)
    p.add_argument("--artist", required=True, help="the artist mesh (gpja artist)")
    p.add_argument("--mesh", required=True, help="the expression's registered mesh (template UVs)")
    p.add_argument("--template-dir", required=True, help="the subject's template folder")
    p.add_argument("--settings", default="{}", help="JSON: the config's applications.reparam section")
    p.add_argument("--output", required=True, help="the .obj (a .json log of its checks beside it)")
    p.set_defaults(func=cmd_reparametrize)

    p = sub.add_parser("turns", help="applications: the artist mesh's faces turned over between adjacent "
                                     "expressions of the registration tree (and the ground truth's, synthetic data)")
    p.add_argument("--subject", required=True)
    p.add_argument("--artist", required=True, help="the artist mesh (gpja artist)")
    p.add_argument("--meshes", nargs="+", required=True,
                   help="EXPRESSION=PATH of every re-parametrised expression of the tree (gpja reparametrize)")
    p.add_argument("--order", required=True, help="registration_order.json (gpja order)")
    p.add_argument("--template-dir", required=True, help="the subject's template folder (texture_observed.png)")
    p.add_argument("--template-expression", default=None, help="the artist mesh's expression (default: the root)")
    p.add_argument("--ground-truth-root", default=None, help="synthetic ground truth: {root}/{subject}/... (optional)")
    p.add_argument("--scans-root", default=None, help="synthetic scans, with --ground-truth-root")
    p.add_argument("--output", required=True, help="the counts, JSON (reparam/turns.json)")
    p.set_defaults(func=cmd_turns)

    from gpja.report.figures import FIGURES

    p = sub.add_parser("figure", help="one of the paper's figures for one subject, as PNG and PDF")
    p.add_argument("kind", choices=list(FIGURES), help="a figure of gpja.report.figures.FIGURES")
    p.add_argument("--subject", required=True)
    p.add_argument("--methods", nargs="+", default=["gpja"], help="columns (geometric_errors); else the first is drawn")
    p.add_argument("--expressions", nargs="+", required=True)
    p.add_argument("--results", required=True, help="results/{dataset}")
    _add_data_args(p, required=False)  # images for the photometric figures, scans for the geometric ones
    p.add_argument("--settings", default="{}", help="JSON: the config's figures section")
    _add_backend_arg(p)
    p.add_argument("--output", required=True, help="the .png; the .pdf is written beside it")
    p.set_defaults(func=cmd_figure)

    p = sub.add_parser("check-regression", help="compare a run's metrics with reference values (exit 1 when worse "
                                                "beyond tolerance)")
    p.add_argument("--metrics", required=True, help="results/{dataset} of the run")
    p.add_argument("--reference", required=True, help="reference JSON, e.g. tests/data/ci_reference_metrics.json")
    p.add_argument("--tolerances", default=None, help="JSON overriding allowances: {metric: {absolute, relative}}")
    p.add_argument("--write-reference", action="store_true",
                   help="write --reference from the run's metrics instead of checking")
    _add_selection_args(p, required=False, note="with --write-reference: only these")
    p.set_defaults(func=cmd_check_regression)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.INFO,
                        format="%(levelname)s %(name)s: %(message)s", stream=sys.stderr)
    if args.threads:
        from gpja.threads import limit_threads

        limit_threads(args.threads)
    try:
        status = args.func(args)
    except GpjaError as err:
        print(f"error: {err}", file=sys.stderr, flush=True)
        return 2
    return status or 0


if __name__ == "__main__":
    sys.exit(main())
