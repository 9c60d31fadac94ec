# Stage 5, figures: the paper's figures per subject, PNG (in the report) and PDF, drawn by `gpja figure`.
# One rule per entry of the figure registry (gpja/report/figures.py: what each figure draws, what it reads,
# when the config draws it); its caption is workflow/report/figure_{name}.rst.
from gpja.report.figures import FIGURES, FigurePlan

FIGURE_PLAN = FigurePlan(
    layout=LAYOUT,
    expressions=tuple(EXPRESSIONS),
    compared=tuple(COMPARED),
    ablation_variants=tuple(ABLATION_VARIANTS),
    ablation_subjects=tuple(ABLATION_SUBJECTS),
    ablation_expressions=tuple(ABLATION_EXPRESSIONS),
    photometric=config["metrics"].get("photometric", True),
    ground_truth=GROUND_TRUTH,  # workflow/rules/reference.smk
    applications=APPS_ON,  # workflow/rules/apply.smk
    application_expressions=tuple(APP_EXPRESSIONS),
)


def figure_inputs(figure):
    """The input function of a figure's rule: what it needs of one subject (FigurePlan.inputs)."""
    return lambda wildcards: FIGURE_PLAN.inputs(figure, wildcards.subject)


for _figure in FIGURES.values():

    rule:
        name:
            f"plot_{_figure.name}"
        input:
            figure_inputs(_figure),
        output:
            png=report(
                results_path("figure", _figure.name, "{subject}", "png"),
                caption=f"../report/{_figure.caption}",
                category="Figures",
                subcategory=_figure.name.replace("_", " "),
                labels={"figure": _figure.name.replace("_", " "), "subject": "{subject}"},
            ),
            pdf=results_path("figure", _figure.name, "{subject}", "pdf"),
        params:
            kind=_figure.name,
            methods=FIGURE_PLAN.methods(_figure),
            expressions=FIGURE_PLAN.expressions_of(_figure),
            data=data_args(),
            cache=UNDISTORTED,
            settings=json_arg(config.get("figures", {})),
            results=RESULTS,
            backend=BACKEND,
        log:
            log_path("{subject}", "figures", _figure.name),
        benchmark:
            bench_path("{subject}", "figures", _figure.name)
        threads: 1
        resources:
            mem_mb=3000,
            runtime=10,
        shell:
            "gpja --threads {threads} figure {params.kind} --subject {wildcards.subject} --methods {params.methods:q}"
            " --expressions {params.expressions:q} --results {params.results} {params.data} --cache-dir {params.cache}"
            " --settings {params.settings} --backend {params.backend} --output {output.png} > {log} 2>&1"
