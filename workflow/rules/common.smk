# Paths and small helpers shared by the rules. Keep this file small: logic belongs in gpja.
# Method names and switches come from the registry (gpja/methods.py), every results/logs/benchmarks path
# from the layout (gpja/results.py), the figures from their registry (gpja/report/figures.py).
import json
import shlex

import gpja.methods as registry
from gpja.results import Layout
from gpja.settings import data_expressions, settings_section

DATASET = config["dataset"]
SUBJECTS = [str(s) for s in config["subjects"]]
EXPRESSIONS = list(config["expressions"])
DATA = config["data"]
SYNTH = config["synthetic"]
REG = config["registration"]
BACKEND = config["render"]["backend"]
TEMPLATE_EXPRESSION = REG["template_expression"]
# the template's expression is always read (and synthesised), even if not registered
DATA_EXPRESSIONS = data_expressions(config)
BASELINES = config.get("baselines", {})
# the registered baselines the config enables (baselines.<name>.enabled), in registry order
BASELINE_METHODS = [m for m in registry.names("baseline") if BASELINES.get(m, {}).get("enabled")]
# imported methods by name: {pattern, transform, texture}
EXTERNAL = {m["name"]: m for m in BASELINES.get("external", [])}
ABLATION = REG.get("ablations") or {"variants": []}
ABLATION_VARIANTS = list(ABLATION["variants"])
ABLATION_SUBJECTS = [str(s) for s in ABLATION.get("subjects") or SUBJECTS]
ABLATION_EXPRESSIONS = list(ABLATION.get("expressions") or EXPRESSIONS)
REGISTRATION_METHODS = registry.names("gpja") + ABLATION_VARIANTS
# the methods of the comparison (Tables 1-2): GPJA, the baselines, imported meshes; each runs on every
# (subject, expression)
COMPARED = registry.names("gpja") + BASELINE_METHODS + list(EXTERNAL)
METHODS = COMPARED + ABLATION_VARIANTS
LAYOUT = Layout.for_dataset(DATASET)
RESULTS = str(LAYOUT.root)
UNDISTORTED = str(LAYOUT.undistorted)


wildcard_constraints:
    subject="|".join(SUBJECTS),
    expression="|".join(DATA_EXPRESSIONS),
    method="|".join(METHODS),


def results_path(name, *parts):
    """A path of the results layout (``Layout.<name>(*parts)``) as a string; parts may be wildcard patterns."""
    return str(getattr(LAYOUT, name)(*parts))


def log_path(*parts):
    return str(LAYOUT.log(*parts))


def bench_path(*parts):
    return str(LAYOUT.benchmark(*parts))


def params_json(subject, expression):
    return f"{DATA['images_root']}/{subject}/{expression}/params.json"


def scan_ply(subject, expression):
    return f"{DATA['scans_root']}/{subject}/{expression}.ply"


def expression_inputs(wildcards):
    """The files one expression is read from (synthesised first when the dataset is)."""
    files = {
        "params": params_json(wildcards.subject, wildcards.expression),
        "scan": scan_ply(wildcards.subject, wildcards.expression),
    }
    if DATA.get("rt_scale"):
        files["rt_scale"] = DATA["rt_scale"]
    return files


def data_args():
    """Command-line options of `gpja` that say where the dataset is."""
    args = ["--images-root", DATA["images_root"], "--scans-root", DATA["scans_root"]]
    if DATA.get("rt_scale"):
        args += ["--rt-scale", DATA["rt_scale"]]
    if DATA.get("views"):
        args += ["--views", *map(str, DATA["views"])]
    if DATA.get("max_image_size"):
        args += ["--max-image-size", str(DATA["max_image_size"])]
    return shlex.join(args)


def synth_settings():
    """The synthetic generator's settings as one JSON argument (seed included)."""
    return shlex.quote(json.dumps(settings_section(config, "synthetic"), sort_keys=True))


def gt_args():
    """Ground truth (synthetic data only): for the metrics and figures, never the template or registrations."""
    return f"--ground-truth-root {DATA['ground_truth_root']}" if DATA.get("ground_truth_root") else ""


def json_arg(obj):
    return shlex.quote(json.dumps(obj, sort_keys=True))


def external_texture_arg(wildcards):
    """An imported mesh references the subject's template texture when configured to (texture: template)."""
    texture = EXTERNAL[wildcards.method].get("texture")
    if texture == "template":
        return f"--texture {results_path('template_file', wildcards.subject, 'texture.png')}"
    return f"--texture {shlex.quote(texture)}" if texture else ""


def without_args(wildcards):
    """The constraints an ablation variant switches off (gpja.methods), as `gpja register --without ...`."""
    off = registry.method(wildcards.method).without
    return "--without " + " ".join(off) if off else ""


def runs(subject=None):
    """Every (subject, method, expression) the configuration registers and scores: the compared methods on
    every subject and expression, the ablation variants on their subjects and expressions."""
    combos = [(s, m, e) for s in SUBJECTS for m in COMPARED for e in EXPRESSIONS]
    combos += [(s, m, e) for s in ABLATION_SUBJECTS for m in ABLATION_VARIANTS for e in ABLATION_EXPRESSIONS
               if s in SUBJECTS and e in EXPRESSIONS]
    return [c for c in combos if subject is None or c[0] == subject]


def metrics_files(subject=None):
    return [results_path("metrics", s, m, e) for s, m, e in runs(subject)]


def subject_targets(subject):
    """Everything one subject contributes: data checks, scan targets, template, every run's metrics, its figures."""
    targets = [results_path("data_summary", subject, e) for e in EXPRESSIONS]
    targets += [results_path("scan_targets", subject, e) for e in EXPRESSIONS]
    if SYNTH["enabled"]:
        targets.append(results_path("contact_sheet", subject))
    targets.append(results_path("template_file", subject, "template.obj"))
    targets += metrics_files(subject)
    targets += reference_targets(subject)  # synthetic: texture quality, oracle (workflow/rules/reference.smk)
    targets += application_targets(subject)  # workflow/rules/apply.smk
    targets += FIGURE_PLAN.outputs(subject)  # workflow/rules/figures.smk
    return targets


def all_targets(wildcards):
    """Every output: each subject's, then the tables and the HTML report built from all of them."""
    targets = [t for s in SUBJECTS for t in subject_targets(s)]
    targets += list(rules.make_tables.output)  # the tables (workflow/rules/report.smk)
    targets.append(str(LAYOUT.report))
    return targets
