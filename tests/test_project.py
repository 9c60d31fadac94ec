"""The project's own promises: README <-> CI agreement, pinned environment, config schema, DAG."""
from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

import jsonschema
import numpy as np
import pytest
import yaml

from tests.configs import CONFIGS, OVERLAYS, load_config
from tests.tolerances import SCAN_AGAINST_ITSELF_MM

ROOT = Path(__file__).resolve().parents[1]
SNAKEMAKE = [sys.executable, "-m", "snakemake"]
#: Metrics of a CI-configuration run, refreshed with
#: ``gpja check-regression --metrics results/synthetic-ci --reference tests/data/ci_reference_metrics.json --write-reference``
CI_REFERENCE = ROOT / "tests/data/ci_reference_metrics.json"


def readme_commands() -> list[str]:
    block = re.search(r"<!-- quick-start -->\s*```(?:bash|sh)?\n(.*?)```", (ROOT / "README.md").read_text(), re.S)
    assert block, "README.md has no quick-start block"
    return [line for line in block.group(1).splitlines() if line.strip() and not line.startswith("#")]


def heading_anchors(path: Path) -> set[str]:
    """The anchors GitHub gives a Markdown file's headings: lower case, punctuation but ``-`` and ``_`` dropped, spaces
    as hyphens, a repeated heading suffixed ``-1``, ``-2`` ...; headings inside code fences are none."""
    anchors, seen, fenced = set(), {}, False
    for line in path.read_text().splitlines():
        if line.startswith("```"):
            fenced = not fenced
            continue
        heading = None if fenced else re.match(r"^#{1,6} (.*)", line)
        if heading:
            slug = re.sub(r"[^\w\- ]", "", heading.group(1).strip().lower()).replace(" ", "-")
            count = seen.get(slug, 0)
            seen[slug] = count + 1
            anchors.add(slug if count == 0 else f"{slug}-{count}")
    return anchors


def test_heading_anchors_follow_githubs_rules(tmp_path):
    page = tmp_path / "page.md"
    page.write_text("# The 3 x 6 run (`config/extended.yaml`, issue 17)\n## A\n## A\n```\n# not a heading\n```\n")
    assert heading_anchors(page) == {"the-3-x-6-run-configextendedyaml-issue-17", "a", "a-1"}


def test_links_to_headings_in_the_docs_resolve():
    """Every ``[text](file.md#anchor)`` and ``[text](#anchor)`` in the README and docs/ names a heading that exists."""
    broken, anchors = [], {}  # each linked page's headings parsed once
    for page in [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]:
        for target, anchor in re.findall(r"\]\(([^)#\s]*)#([^)\s]+)\)", page.read_text()):
            linked = ((page.parent / target) if target else page).resolve()
            if linked.suffix != ".md" or not linked.exists():
                continue
            if linked not in anchors:
                anchors[linked] = heading_anchors(linked)
            if anchor not in anchors[linked]:
                broken.append(f"{page.relative_to(ROOT)} -> {target or page.name}#{anchor}")
    assert not broken, "links to headings that do not exist:\n" + "\n".join(broken)


def test_readme_has_exactly_two_commands_and_ci_runs_the_test_one():
    commands = readme_commands()
    assert len(commands) == 2
    main, tests = commands
    assert main.rstrip().endswith("snakemake --cores 2")
    assert "pytest" in tests
    ci = [line for line in (ROOT / ".ci/run").read_text().splitlines() if line and not line.startswith(("#", "set ", "cd "))]
    assert ci == [tests]


def test_conda_env_mirrors_pinned_pip_set():
    pins = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    declared = set(pins["dependencies"]) | set(pins["optional-dependencies"]["test"])
    assert all("==" in d for d in declared), "every dependency must be pinned exactly"
    assert "torch==2.13.0" in declared and not any(d.startswith("torchvision") for d in declared)
    env = yaml.safe_load((ROOT / "envs/gpja.yaml").read_text())
    pip = next(d["pip"] for d in env["dependencies"] if isinstance(d, dict))
    assert set(pip) == declared


@pytest.mark.parametrize("name", CONFIGS)
def test_configs_validate_against_schema(name):
    schema = yaml.safe_load((ROOT / "workflow/schemas/config.schema.yaml").read_text())
    jsonschema.validate(load_config(name), schema)


def test_schema_rejects_bad_config():
    schema = yaml.safe_load((ROOT / "workflow/schemas/config.schema.yaml").read_text())
    cfg = yaml.safe_load((ROOT / "config/config.yaml").read_text())
    cfg["synthetic"]["image_size"] = 8
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.validate(cfg, schema)


def workflow_env() -> dict:
    """The environment for a workflow subprocess: this interpreter's bin first, so rules find ``gpja``."""
    return {**os.environ, "PATH": str(Path(sys.executable).parent) + ":" + os.environ["PATH"]}


def copy_workflow(dst: Path) -> Path:
    for item in ("Snakefile", "workflow", "config"):
        src = ROOT / item
        (shutil.copytree if src.is_dir() else shutil.copy)(src, dst / item)
    return dst


@pytest.mark.parametrize("name", ["config.yaml", *OVERLAYS])
def test_dry_run_schedules_synthesis_and_checks(tmp_path, name):
    """The default run's DAG, and an overlay's (``--configfile``, merged over the default), job by job."""
    work = copy_workflow(tmp_path)
    extra = [] if name == "config.yaml" else ["--configfile", f"config/{name}"]
    out = subprocess.run([*SNAKEMAKE, "-n", "--cores", "2", "--quiet", "rules", *extra], cwd=work,
                         capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    counts = dict(re.findall(r"^(\w+)\s+(\d+)\s*$", out.stdout, re.M))
    cfg = load_config(name)
    n_subjects, n_expressions = len(cfg["subjects"]), len(cfg["expressions"])
    assert int(counts["synthesize_subject"]) == n_subjects
    assert int(counts["check_expression"]) == n_subjects * n_expressions
    with_template = n_expressions + (cfg["registration"]["template_expression"] not in cfg["expressions"])
    assert int(counts["render_scan_targets"]) == n_subjects * with_template
    assert int(counts["build_template"]) == n_subjects
    assert int(counts["registration_order"]) == n_subjects * (cfg["registration"]["start"] == "tree")
    assert int(counts["score_stages"]) == n_subjects * n_expressions  # GPJA's stages (figure registration_stages)
    ablations = cfg["registration"]["ablations"]
    n_ablation = (len(ablations["variants"]) * len(ablations["subjects"] or cfg["subjects"])
                  * len(ablations["expressions"] or cfg["expressions"]))
    assert n_ablation > 0  # the default run shows the ablations (Table 3, the ablation figures)
    assert int(counts["register_expression"]) == n_subjects * n_expressions + n_ablation
    baselines = cfg["baselines"]
    n_nicp = n_subjects * n_expressions if baselines["nicp"]["enabled"] else 0
    assert int(counts.get("baseline_expression", 0)) == n_nicp
    compared = 1 + baselines["nicp"]["enabled"] + len(baselines["external"])
    assert int(counts["compute_metrics"]) == n_subjects * n_expressions * compared + n_ablation
    for kind in ("template_stages", "geometric_errors", "photometric_errors", "closeups", "convergence"):
        assert int(counts[f"plot_{kind}"]) == n_subjects, kind
    assert int(counts["plot_ablation_normal"]) == int(counts["plot_ablation_mask"]) == len(ablations["subjects"])
    assert int(counts["make_tables"]) == int(counts["make_report"]) == 1


def test_extended_config_is_the_bigger_run():
    """config/extended.yaml: at least 3 subjects x 6 expressions with a jaw-sideways and a cheek-blowing one, the
    default's method (no registration setting of its own), its own dataset so the default run's results stay."""
    extended, default = load_config("extended.yaml"), load_config("config.yaml")
    assert len(extended["subjects"]) >= 3 and len(extended["expressions"]) >= 6
    assert {"5_jaw_left", "17_cheek_blowing"} <= set(extended["expressions"])
    assert extended["registration"] == default["registration"]
    assert extended["dataset"] != default["dataset"]
    roots = [extended["data"][k] for k in ("images_root", "scans_root", "ground_truth_root")]
    roots += [extended["synthetic"]["raw_root"], extended["baselines"]["nicp"]["landmarks"]]
    assert all(root.startswith(f"data/{extended['dataset']}/") for root in roots), roots


def test_every_job_of_the_default_dag_but_the_template_runs_on_one_thread(tmp_path):
    """With ``--cores 2`` a 2-thread job only starts when both cores are free at once; while one subject's
    1-thread jobs keep a core busy, the other subject's 2-thread synthesis waited 25 minutes (the clean-clone run
    at e663e18). Every rule but the template's claims one thread (the template waits only for short jobs: every
    long one needs it)."""
    work = copy_workflow(tmp_path)
    out = subprocess.run([*SNAKEMAKE, "-n", "-p", "--cores", "2"], cwd=work, capture_output=True, text=True,
                         timeout=300)
    assert out.returncode == 0, out.stderr[-3000:]
    threads = re.findall(r"gpja --threads (\d+) (\w[\w-]*)", out.stdout)
    commands = {command for _, command in threads}
    assert {"synth", "scan-targets", "template", "baseline"} <= commands, commands
    assert {(n, c) for n, c in threads if n != "1"} == {("2", "template")}


def dry_run_jobs(work: Path, *targets: str) -> list[dict]:
    """The jobs a dry run schedules for ``targets``: rule name and wildcards of each."""
    out = subprocess.run([*SNAKEMAKE, "-n", "--cores", "2", "--", *targets], cwd=work, capture_output=True,
                         text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-3000:]
    jobs = []
    for block in re.split(r"\n(?=(?:local)?(?:rule|checkpoint) \w+:)", out.stdout):
        head = re.match(r"(?:local)?(?:rule|checkpoint) (\w+):", block.strip())
        if head:
            wildcards = re.search(r"wildcards: (.*)", block)
            pairs = dict(p.split("=", 1) for p in wildcards.group(1).split(", ")) if wildcards else {}
            jobs.append({"rule": head.group(1), **pairs})
    return jobs


def test_subject_target_schedules_only_that_subject(tmp_path):
    """README "Per-subject targets": results/{dataset}/{subject}/all.done builds one subject and nothing else."""
    work = copy_workflow(tmp_path)
    cfg = yaml.safe_load((ROOT / "config/config.yaml").read_text())
    subject, others = cfg["subjects"][-1], cfg["subjects"][:-1]
    jobs = dry_run_jobs(work, f"results/{cfg['dataset']}/{subject}/all.done")
    rules = {j["rule"] for j in jobs}
    assert {"synthesize_subject", "build_template", "register_expression", "compute_metrics",
            "plot_geometric_errors", "subject_all"} <= rules
    assert not rules & {"make_tables", "make_report"}  # tables and the report need every subject
    assert all(j.get("subject") in (None, subject) for j in jobs), [j for j in jobs if j.get("subject") != subject]
    assert sum(j["rule"] == "register_expression" for j in jobs) == len(cfg["expressions"])  # no ablations on it
    assert others and not any(j.get("subject") in others for j in jobs)
    # the ablation subject gets its variants too
    ablated = cfg["registration"]["ablations"]["subjects"][0]
    methods = {j.get("method") for j in dry_run_jobs(work, f"results/{cfg['dataset']}/{ablated}/all.done")}
    assert set(cfg["registration"]["ablations"]["variants"]) <= methods


def test_the_paper_schedule_variant_runs_from_the_template_with_its_own_settings(tmp_path):
    """gpja-paper goes through the DAG with the config's registration.paper section and never starts from
    another expression; GPJA itself waits for the registration tree (registration.start: tree)."""
    work = copy_workflow(tmp_path)
    cfg = yaml.safe_load((ROOT / "config/config.yaml").read_text())
    ablations = cfg["registration"]["ablations"]
    assert "gpja-paper" in ablations["variants"]
    subject, expression = (ablations["subjects"] or cfg["subjects"])[0], (ablations["expressions"] or cfg["expressions"])[0]
    target = f"results/{cfg['dataset']}/{subject}/gpja-paper/metrics/{expression}.json"
    out = subprocess.run([*SNAKEMAKE, "-n", "-p", "--cores", "2", "--", target], cwd=work, capture_output=True,
                         text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-3000:]
    command = next(line for line in out.stdout.splitlines() if " register --subject" in line)
    settings = json.loads(re.search(r"--settings '([^']*)'", command).group(1))
    assert settings == cfg["registration"]["paper"]
    assert settings["warmup_iterations"] == 0 and settings["optimizer_state"] == "shared"
    assert "--start-from" not in command and "registration_order" not in out.stdout
    jobs = dry_run_jobs(work, f"results/{cfg['dataset']}/{subject}/gpja/metrics/{expression}.json")
    assert any(j["rule"] == "registration_order" and j["subject"] == subject for j in jobs)


def test_reference_steps_and_their_outputs_are_in_the_ci_dag(tmp_path):
    """Synthetic data: the texture quality, the oracle of every expression, the correspondence figure and the
    tables that read them are scheduled; the oracle is one more method of the tables' step."""
    work = copy_workflow(tmp_path)
    cfg = yaml.safe_load((ROOT / "config/ci.yaml").read_text())
    out = subprocess.run([*SNAKEMAKE, "-n", "--cores", "2", "--configfile", "config/ci.yaml", "--printshellcmds"],
                         cwd=work, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-3000:]
    counts = dict(re.findall(r"^(\w+)\s+(\d+)\s*$", out.stdout, re.M))
    n_subjects, n_expressions = len(cfg["subjects"]), len(cfg["expressions"])
    assert int(counts["texture_quality"]) == int(counts["plot_correspondence_errors"]) == n_subjects
    assert int(counts["oracle_metrics"]) == n_subjects * n_expressions
    oracle = re.search(r"gpja --threads 1 oracle .*", out.stdout).group(0)  # scored with the methods' protocol
    assert json.loads(re.search(r"--settings '([^']*)'", oracle).group(1)) == load_config("ci.yaml")["metrics"]
    tables = re.search(r"gpja --threads 1 tables .*", out.stdout).group(0)
    assert ("--tables geometry photometric ablation correspondence correspondence_regions position_regions texture turns"
            " timing") in tables
    assert int(counts["count_turns"]) == n_subjects
    turns = re.search(r"gpja --threads 1 turns .*", out.stdout).group(0)
    assert "--ground-truth-root" in turns and "--order results/" in turns
    methods = ["gpja", "nicp", *cfg["registration"]["ablations"]["variants"], "oracle"]
    assert re.search(rf"--methods {' '.join(methods)}\b", tables)
    # the template figure waits for the texture's error image
    assert re.search(r"figure template_stages .*", out.stdout)
    report = re.search(r"rule plot_template_stages:\n(.*?)\n\n", out.stdout, re.S).group(1)
    assert "texture_error.png" in report


def test_invalid_config_stops_before_any_rule(tmp_path):
    work = copy_workflow(tmp_path)
    out = subprocess.run([*SNAKEMAKE, "-n", "--cores", "1", "--config", "dataset=bad/name"], cwd=work,
                         capture_output=True, text=True, timeout=300)
    assert out.returncode != 0
    assert "dataset" in out.stderr + out.stdout


@pytest.mark.slow
def test_ci_workflow_runs_end_to_end(tmp_path):
    """The real DAG on the CI configuration: synthesis, then every expression through the reader."""
    work = copy_workflow(tmp_path)
    out = subprocess.run([*SNAKEMAKE, "--cores", "2", "--configfile", "config/ci.yaml"], cwd=work,
                         capture_output=True, text=True, timeout=900, env=workflow_env())
    assert out.returncode == 0, out.stderr[-3000:]
    cfg = yaml.safe_load((ROOT / "config/ci.yaml").read_text())
    for expression in cfg["expressions"]:
        summary = yaml.safe_load((work / f"results/{cfg['dataset']}/S01/data/{expression}.json").read_text())
        assert len(summary["views"]) == cfg["synthetic"]["n_views"]
        assert all(v["scan_fraction_in_view"] > 0.5 for v in summary["views"])
        assert 0.3 < summary["scan"]["median_edge_mm"] < 1.2
    assert (work / f"results/{cfg['dataset']}/S01/contact_sheet.png").is_file()
    template_dir = work / f"results/{cfg['dataset']}/S01/template"
    for name in ("template.obj", "template.mtl", "texture.png", "mouth_mask.png", "template.json",
                 "stages/bust.obj", "stages/fitted.obj"):
        assert (template_dir / name).is_file(), name
    from gpja.mesh import read_obj

    template = read_obj(template_dir / "template.obj")
    for expression in cfg["expressions"]:
        registered = read_obj(work / f"results/{cfg['dataset']}/S01/gpja/{expression}.obj")
        assert registered.texture is not None  # the shared template texture, by reference
        assert len(registered.F) > len(template.F)  # refined between levels
        log = json.loads((work / f"results/{cfg['dataset']}/S01/gpja/{expression}.json").read_text())
        levels = [lvl for lvl in log["levels"] if lvl.get("stage", "level") == "level"]
        assert [lvl["lambda"] for lvl in levels] == cfg["registration"]["gpja"]["lambdas"]
        metrics = json.loads((work / f"results/{cfg['dataset']}/S01/gpja/metrics/{expression}.json").read_text())
        assert metrics["method"] == "gpja" and metrics["expression"] == expression
        assert 0.0 < metrics["geometry"]["chamfer_l1_mm"] < 2.0
        assert 0.9 < metrics["geometry"]["normal_consistency"] <= 1.0
        assert metrics["photometric"]["psnr"] > 15.0
        assert metrics["correspondence"]["fraction_used"] > 0.3
        # the floor: over the score's own vertices, so none of the score's statistics is below it
        floor = metrics["correspondence"]["floor"]
        assert floor["n_used"] == metrics["correspondence"]["n_used"]
        assert all(floor[k] <= metrics["correspondence"][k] for k in ("mean_mm", "median_mm", "p95_mm"))
        nicp = json.loads((work / f"results/{cfg['dataset']}/S01/nicp/metrics/{expression}.json").read_text())
        assert nicp["method"] == "nicp" and nicp["photometric"]["psnr"] > 15.0  # NICP keeps the template's UVs
        details = work / f"results/{cfg['dataset']}/S01/gpja/metrics/{expression}"
        assert (details / "geometry_errors.npz").is_file() and (details / "render" / "0.png").is_file()
        # by facial region, and the oracle above every method (nothing can beat the ground truth)
        assert set(metrics["correspondence"]["regions"]) == {"mouth", "eyes", "nose", "brows", "face", "outer"}
        oracle = json.loads((work / f"results/{cfg['dataset']}/S01/oracle/metrics/{expression}.json").read_text())
        assert oracle["photometric"]["psnr"] > max(metrics["photometric"]["psnr"], nicp["photometric"]["psnr"])
        # its true surface against a noise-free scan (config/ci.yaml): the scan itself
        assert cfg["synthetic"]["scan_noise_mm"] == 0.0
        assert oracle["geometry"]["chamfer_l1_mm"] < SCAN_AGAINST_ITSELF_MM < metrics["geometry"]["chamfer_l1_mm"]
        assert oracle["geometry"]["normal_consistency"] > 0.999
    # the closed-mouth expression is registered through the tree (scans alone), gpja-paper from the template
    closed = cfg["registration"]["ablations"]["expressions"][0]
    order = json.loads((work / f"results/{cfg['dataset']}/S01/registration_order.json").read_text())
    assert order["parent"][closed] != cfg["registration"]["template_expression"]  # a chain, not the template
    assert json.loads((work / f"results/{cfg['dataset']}/S01/gpja/{closed}.json").read_text())["start"] != "template"
    assert json.loads((work / f"results/{cfg['dataset']}/S01/gpja-paper/{closed}.json").read_text())["start"] == "template"
    # ... from its parent's registration before the snap: the snap finishes each output, the tree carries the levels'
    parent = order["parent"][closed]
    handed = f"results/{cfg['dataset']}/S01/gpja/starts/{parent}.obj"
    assert json.loads((work / f"results/{cfg['dataset']}/S01/gpja/{closed}.json").read_text())["start"] == handed
    from gpja.results import read_stages

    parent_stages = [mesh for name, mesh in read_stages(work / f"results/{cfg['dataset']}/S01/gpja/stages/{parent}")
                     if name != "snap"]
    handed_V = read_obj(work / handed, load_texture=False).V
    np.testing.assert_allclose(handed_V, parent_stages[-1].V[: len(handed_V)], atol=1e-3)  # stages: float32
    stages = json.loads((work / f"results/{cfg['dataset']}/S01/gpja/stages/{closed}.json").read_text())["stages"]
    gpja_cfg = cfg["registration"]["gpja"]
    flow_levels = gpja_cfg.get("flow_levels", 1) if gpja_cfg.get("flow_rounds") else 0
    # snakemake merges ci.yaml's sections over the default's: the jaw and lid searches, the untangling and the snap are the
    # default's unless ci.yaml sets them
    default_gpja = yaml.safe_load((ROOT / "config/config.yaml").read_text())["registration"]["gpja"]
    merged = {**default_gpja, **gpja_cfg}
    expected = (["start"] + ["jaw"] * (merged.get("jaw_search_deg") is not None)
                + ["lids"] * (merged.get("lid_search_deg") is not None) + ["flow"] * (flow_levels > 0)
                + ["spread"] * bool(flow_levels > 0 and merged.get("lip_spread"))
                + ["warmup"] * bool(gpja_cfg.get("warmup_iterations")))
    for k in range(len(gpja_cfg["lambdas"])):
        expected += [f"flow{k + 1}"] * (0 < k < flow_levels) + [f"level{k + 1}"]
    expected += ["untangle"] * (merged.get("untangle_iterations", 0) > 0) + ["snap"] * (merged.get("snap_mm", 0) > 0)
    assert [r["stage"] for r in stages] == expected
    assert all(r["position"]["median_mm"] >= 0.0 and set(r["floor_regions"]) == set(r["regions"]) for r in stages)
    quality = json.loads((template_dir / "texture_quality.json").read_text())
    assert quality["observed"]["psnr"] > 15.0 and (template_dir / "texture_error.png").is_file()
    for expression in cfg["expressions"]:
        with np.load(work / f"results/{cfg['dataset']}/S01/targets/{expression}.npz") as targets:
            size = cfg["synthetic"]["image_size"]
            assert targets["depth"].shape == (cfg["synthetic"]["n_views"], size, size, 1)
            assert 0.05 < targets["coverage"].mean() < 0.9  # the head, not empty, not everything
            assert 400 < np.median(targets["depth"][targets["coverage"][..., 0] > 0.99]) < 800  # rig ~600 mm away
    tables = work / f"results/{cfg['dataset']}/tables"
    for name in ("geometry", "photometric", "ablation", "correspondence", "correspondence_regions", "position_regions",
                 "texture", "turns", "timing"):
        for suffix in ("csv", "md", "tex"):
            assert (tables / f"{name}.{suffix}").is_file(), f"{name}.{suffix}"
    assert "Oracle (ground truth)" in (tables / "photometric.md").read_text()
    assert "GPJA floor" in (tables / "correspondence.md").read_text()
    figures = work / f"results/{cfg['dataset']}/figures"
    for kind in ("template_stages", "geometric_errors", "correspondence_errors", "photometric_errors", "closeups",
                 "convergence", "ablation_mask", "registration_stages"):
        for suffix in ("png", "pdf"):
            assert (figures / f"{kind}_S01.{suffix}").stat().st_size > 10_000, f"{kind}.{suffix}"
    # the applications: one triangulation for every expression, on its source; a glTF; a video; the artist mesh
    from gpja.apply.steps import read_remeshed

    subject_dir = work / f"results/{cfg['dataset']}/S01"
    apps = cfg["applications"]
    remeshed = read_remeshed({e: subject_dir / "remeshed" / f"{e}.obj" for e in cfg["expressions"]})  # shared F/UV
    assert len(next(iter(remeshed.values())).V) > len(template.V)
    for expression in cfg["expressions"]:
        log = json.loads((subject_dir / "remeshed" / f"{expression}.json").read_text())
        assert max(log["deviation"]["to_source"]["max_mm"], log["deviation"]["from_source"]["max_mm"]) <= 0.1
        assert log["render"]["identical"] or log["render"]["psnr_db"] >= 35.0
        carried = json.loads((subject_dir / "reparam" / f"{expression}.json").read_text())
        assert carried["distance_to_source_mm"]["max"] <= 1e-3
    # every hop of the tree counted, by the carried meshes and by the true motion, which places every vertex (the
    # socket's too, 13-18 mm inside the open mouth, where the jaw's map stretches space twelvefold)
    turns = json.loads((subject_dir / "reparam" / "turns.json").read_text())
    assert [(h["parent"], h["expression"]) for h in turns["hops"]] == [
        (order["parent"][e], e) for e in order["order"] if order["parent"][e]]
    truth = turns["truth"]
    assert truth["vertices_placed"] == truth["vertices"] and truth["unplaced_nearest_scan_mm"] is None
    assert all(0 <= h["both"] <= min(h["turned"], h["truth_turned"]) for h in turns["hops"])
    assert (subject_dir / "S01.glb").stat().st_size > 100_000
    assert (subject_dir / "animation.mp4").stat().st_size > 1_000
    frames = np.load(subject_dir / "animation_frames.npz")
    assert len(frames["frames"]) == apps["animation"]["strip_frames"]
    assert int(frames["count"]) == (len(apps["animation"]["sequence"]) - 1) * apps["animation"]["frames_per_transition"] + 1
    for kind in ("animation", "reparam", "turns"):
        assert (figures / f"{kind}_S01.png").stat().st_size > 10_000, kind
    report = (work / f"results/{cfg['dataset']}/report.html").read_text(errors="replace")
    assert "closeups_S01.png" in report and "geometry.md" in report  # figures and tables in the HTML report
    # the maintainers' regression gate: every metric within tolerance of the committed reference
    check = subprocess.run([str(Path(sys.executable).parent / "gpja"), "check-regression", "--metrics",
                            str(work / f"results/{cfg['dataset']}"), "--reference", str(CI_REFERENCE)],
                           capture_output=True, text=True, timeout=300)
    assert check.returncode == 0, check.stdout[-3000:] + check.stderr[-2000:]
    assert (work / f"logs/{cfg['dataset']}/S01/synthesize_subject.log").is_file()
    assert (work / f"benchmarks/{cfg['dataset']}/S01/synthesize_subject.tsv").is_file()


def test_baseline_rule_passes_the_config_section_with_its_patterns_unfilled(tmp_path):
    """A params string would have its {subject}/{expression} filled by Snakemake; NICP needs the landmark
    pattern (it reads the template expression's landmarks through it too). The generic baseline rule passes
    the config's baselines.nicp section as it is, and writes where the NICP rule always wrote."""
    work = copy_workflow(tmp_path)
    target = "results/synthetic/S01/nicp/2_smile.obj"
    out = subprocess.run([*SNAKEMAKE, "-n", "-p", "--cores", "1", "--", target], cwd=work,
                         capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    cfg = yaml.safe_load((ROOT / "config/config.yaml").read_text())
    section = cfg["baselines"]["nicp"]
    assert "{subject}" in section["landmarks"]
    shell = next(line for line in out.stdout.splitlines() if " baseline --method nicp " in line)
    passed = re.search(r"--section '([^']*)'", shell)
    assert passed and json.loads(passed.group(1)) == section, shell
    assert "--output results/synthetic/S01/nicp/2_smile.obj > logs/synthetic/S01/nicp/2_smile.log" in shell


def test_config_method_names_are_checked_when_the_config_loads(tmp_path):
    """An imported method may not take a registered method's name: `snakemake -n` stops with one line."""
    work = copy_workflow(tmp_path)
    cfg = yaml.safe_load((ROOT / "config/ci.yaml").read_text())
    cfg["baselines"]["external"] = [{"name": "nicp", "pattern": "elsewhere/{subject}/{expression}.obj"}]
    (work / "bad.yaml").write_text(yaml.safe_dump(cfg))
    out = subprocess.run([*SNAKEMAKE, "-n", "--cores", "1", "--configfile", "bad.yaml"], cwd=work,
                         capture_output=True, text=True, timeout=300)
    assert out.returncode != 0
    assert "baselines.external: imported method name 'nicp' is taken" in out.stderr + out.stdout


def test_schema_lists_exactly_the_registered_ablation_variants():
    """The schema may restate the registry's ablation names for its error message, but never disagree with it."""
    from gpja.methods import names

    schema = yaml.safe_load((ROOT / "workflow/schemas/config.schema.yaml").read_text())
    variants = schema["properties"]["registration"]["properties"]["ablations"]["properties"]["variants"]
    enum = variants["items"].get("enum")
    assert enum is None or enum == names("ablation")


def test_every_table_and_figure_has_its_caption():
    from gpja.report.figures import FIGURES
    from gpja.report.tables import TABLE_NAMES

    captions = {p.name for p in (ROOT / "workflow/report").glob("*.rst")}
    assert {FIGURES[name].caption for name in FIGURES} <= captions
    assert {f"table_{name}.rst" for name in TABLE_NAMES} <= captions
