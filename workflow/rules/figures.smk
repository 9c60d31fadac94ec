# Stage 5, figures: the paper's figures per subject, PNG (in the report) and PDF, drawn by `gpja figure`.

FIGURES_DIR = f"{RESULTS}/figures"
PHOTOMETRIC = config["metrics"].get("photometric", True)
# the rule of each figure, what it shows, and the methods / expressions it draws (gpja/report/figures.py)
FIGURE_KINDS = {
    "template_stages": dict(methods=["gpja"], ablation=False),
    "geometric_errors": dict(methods=COMPARED, ablation=False),
    "photometric_errors": dict(methods=["gpja"], ablation=False),
    "closeups": dict(methods=["gpja"], ablation=False),
    "convergence": dict(methods=["gpja"], ablation=False),
    "ablation_normal": dict(methods=["gpja", "gpja-no_normal"], ablation=True),
    "ablation_mask": dict(methods=["gpja", "gpja-no_mask"], ablation=True),
}


def figure_kinds(subject):
    """The figures this configuration draws for one subject."""
    kinds = ["template_stages", "geometric_errors", "convergence"]
    kinds += ["photometric_errors", "closeups"] if PHOTOMETRIC else []
    if subject in ABLATION_SUBJECTS and any(e in EXPRESSIONS for e in ABLATION_EXPRESSIONS):
        kinds += ["ablation_normal"] if "gpja-no_normal" in ABLATION_VARIANTS else []
        kinds += ["ablation_mask"] if "gpja-no_mask" in ABLATION_VARIANTS and PHOTOMETRIC else []
    return kinds


def subject_figures(subject):
    return [f"{FIGURES_DIR}/{kind}_{subject}.{ext}" for kind in figure_kinds(subject) for ext in ("png", "pdf")]


def figure_expressions(kind):
    return [e for e in ABLATION_EXPRESSIONS if e in EXPRESSIONS] if FIGURE_KINDS[kind]["ablation"] else EXPRESSIONS


def figure_inputs(kind):
    """A figure's inputs: the subject's template and the metrics (or registration logs) it draws."""

    def inputs(wildcards):
        files = [f"{RESULTS}/{wildcards.subject}/template/template.obj",
                 f"{RESULTS}/{wildcards.subject}/template/texture.png"]
        if kind == "convergence":
            files += [f"{RESULTS}/{wildcards.subject}/gpja/{e}.json" for e in EXPRESSIONS]
        elif kind != "template_stages":
            files += [f"{RESULTS}/{wildcards.subject}/{m}/metrics/{e}.json" for m in FIGURE_KINDS[kind]["methods"]
                      for e in figure_expressions(kind)]
        return files

    return inputs


for _kind in FIGURE_KINDS:

    rule:
        name:
            f"plot_{_kind}"
        input:
            figure_inputs(_kind),
        output:
            png=report(
                f"{FIGURES_DIR}/{_kind}_{{subject}}.png",
                caption=f"../report/figure_{_kind}.rst",
                category="Figures",
                subcategory=_kind.replace("_", " "),
                labels={"figure": _kind.replace("_", " "), "subject": "{subject}"},
            ),
            pdf=f"{FIGURES_DIR}/{_kind}_{{subject}}.pdf",
        params:
            kind=_kind,
            methods=FIGURE_KINDS[_kind]["methods"],
            expressions=figure_expressions(_kind),
            data=data_args(),
            cache=f"{RESULTS}/undistorted",
            settings=json_arg(config.get("figures", {})),
            results=RESULTS,
        log:
            f"{LOGS}/{{subject}}/figures/{_kind}.log",
        benchmark:
            f"{BENCH}/{{subject}}/figures/{_kind}.tsv"
        threads: 1
        resources:
            mem_mb=3000,
            runtime=10,
        shell:
            "gpja --threads {threads} figure {params.kind} --subject {wildcards.subject} --methods {params.methods:q}"
            " --expressions {params.expressions:q} --results {params.results} {params.data} --cache-dir {params.cache}"
            " --settings {params.settings} --output {output.png} > {log} 2>&1"
