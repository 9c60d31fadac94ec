# Paths and small helpers shared by the rules. Keep this file small: logic belongs in gpja.
import json
import shlex

DATASET = config["dataset"]
SUBJECTS = [str(s) for s in config["subjects"]]
EXPRESSIONS = list(config["expressions"])
DATA = config["data"]
SYNTH = config["synthetic"]
REG = config["registration"]
TEMPLATE_EXPRESSION = REG["template_expression"]
# the template's expression is always read (and synthesised), even if not registered
DATA_EXPRESSIONS = EXPRESSIONS + [e for e in [TEMPLATE_EXPRESSION] if e not in EXPRESSIONS]
BASELINES = config.get("baselines", {})
NICP = BASELINES.get("nicp", {"enabled": False})
# imported methods by name: {pattern, transform, texture}
EXTERNAL = {m["name"]: m for m in BASELINES.get("external", [])}
ABLATION = REG.get("ablations") or {"variants": []}
ABLATION_VARIANTS = list(ABLATION["variants"])
ABLATION_SUBJECTS = [str(s) for s in ABLATION.get("subjects") or SUBJECTS]
ABLATION_EXPRESSIONS = list(ABLATION.get("expressions") or EXPRESSIONS)
REGISTRATION_METHODS = ["gpja"] + ABLATION_VARIANTS
# the methods of the comparison (Tables 1-2): GPJA, NICP, imported meshes; each runs on every (subject, expression)
COMPARED = ["gpja"] + (["nicp"] if NICP.get("enabled") else []) + list(EXTERNAL)
METHODS = COMPARED + ABLATION_VARIANTS
RESULTS = f"results/{DATASET}"
REPORT_HTML = f"{RESULTS}/report.html"
LOGS = f"logs/{DATASET}"
BENCH = f"benchmarks/{DATASET}"


wildcard_constraints:
    subject="|".join(SUBJECTS),
    expression="|".join(DATA_EXPRESSIONS),
    method="|".join(METHODS),


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
    keys = ["seed", "image_size", "n_views", "camera_distance_mm", "scan_voxel_mm",
            "scan_noise_mm", "distortion", "supersample", "raw_variant"]
    settings = {k: SYNTH[k] for k in keys if k in SYNTH}
    settings["expressions"] = DATA_EXPRESSIONS
    return shlex.quote(json.dumps(settings, sort_keys=True))


def gt_args():
    """Ground truth (synthetic data only): the capture's SH lighting comes from it."""
    return f"--ground-truth-root {DATA['ground_truth_root']}" if DATA.get("ground_truth_root") else ""


def json_arg(obj):
    return shlex.quote(json.dumps(obj, sort_keys=True))


def external_texture_arg(wildcards):
    """An imported mesh references the subject's template texture when configured to (texture: template)."""
    texture = EXTERNAL[wildcards.method].get("texture")
    if texture == "template":
        return f"--texture {RESULTS}/{wildcards.subject}/template/texture.png"
    return f"--texture {shlex.quote(texture)}" if texture else ""


ABLATIONS = {"gpja": [], "gpja-no_normal": ["normal"], "gpja-no_depth": ["depth"],
             "gpja-no_color": ["color"], "gpja-no_mask": ["mask"]}


def without_args(wildcards):
    off = ABLATIONS[wildcards.method]
    return "--without " + " ".join(off) if off else ""


def runs(subject=None):
    """Every (subject, method, expression) the configuration registers and scores: the compared methods on
    every subject and expression, the ablation variants on their subjects and expressions."""
    combos = [(s, m, e) for s in SUBJECTS for m in COMPARED for e in EXPRESSIONS]
    combos += [(s, m, e) for s in ABLATION_SUBJECTS for m in ABLATION_VARIANTS for e in ABLATION_EXPRESSIONS
               if s in SUBJECTS and e in EXPRESSIONS]
    return [c for c in combos if subject is None or c[0] == subject]


def metrics_files(subject=None):
    return [f"{RESULTS}/{s}/{m}/metrics/{e}.json" for s, m, e in runs(subject)]


def subject_targets(subject):
    """Everything one subject contributes: data checks, scan targets, template, every run's metrics, its figures."""
    targets = [f"{RESULTS}/{subject}/data/{e}.json" for e in EXPRESSIONS]
    targets += [f"{RESULTS}/{subject}/targets/{e}.npz" for e in EXPRESSIONS]
    if SYNTH["enabled"]:
        targets.append(f"{RESULTS}/{subject}/contact_sheet.png")
    targets.append(f"{RESULTS}/{subject}/template/template.obj")
    targets += metrics_files(subject)
    targets += subject_figures(subject)  # workflow/rules/figures.smk
    return targets


def all_targets(wildcards):
    """Every output: each subject's, then the tables and the HTML report built from all of them."""
    targets = [t for s in SUBJECTS for t in subject_targets(s)]
    targets += list(rules.make_tables.output)  # the tables (workflow/rules/report.smk)
    targets.append(REPORT_HTML)
    return targets
