# Stage 4, metrics: every method's mesh of every expression scored identically (one JSON each).
# The synthetic ground truth is read here (and by the figures), never by the template or the registrations.


def ground_truth_inputs(wildcards):
    """The ground truth a score reads (synthetic data): the expression's and the template expression's
    (correspondence is measured through the template's rest coordinates)."""
    if not DATA.get("ground_truth_root"):
        return {}
    root = f"{DATA['ground_truth_root']}/{wildcards.subject}"
    return {"ground_truth": f"{root}/{wildcards.expression}.npz",
            "ground_truth_template": f"{root}/{TEMPLATE_EXPRESSION}.npz"}


rule compute_metrics:
    """Geometry (Chamfer, N.C., F-scores), photometry (PSNR, SSIM, LPIPS) and correspondence of one mesh."""
    input:
        unpack(registration_inputs),
        unpack(ground_truth_inputs),
        mesh=results_path("registration", "{subject}", "{method}", "{expression}"),
        template=results_path("template_file", "{subject}", "template.obj"),
        texture=results_path("template_file", "{subject}", "texture.png"),
        lighting=results_path("template_file", "{subject}", "lighting.json"),
    output:
        json=results_path("metrics", "{subject}", "{method}", "{expression}"),
        details=directory(results_path("metrics_details", "{subject}", "{method}", "{expression}")),
    params:
        data=data_args(),
        gt=gt_args(),
        cache=UNDISTORTED,
        settings=json_arg(config["metrics"]),
        template_dir=results_path("template_dir", "{subject}"),
        template_expression=TEMPLATE_EXPRESSION,
        backend=BACKEND,
    log:
        log_path("{subject}", "{method}", "metrics", "{expression}"),
    benchmark:
        bench_path("{subject}", "{method}", "metrics", "{expression}")
    threads: 1
    resources:
        mem_mb=4000,
        runtime=10,
    shell:
        "gpja --threads {threads} metrics --subject {wildcards.subject} --expression {wildcards.expression} --method {wildcards.method}"
        " --mesh {input.mesh} --template-dir {params.template_dir} --template-expression {params.template_expression}"
        " {params.data} {params.gt} --cache-dir {params.cache} --targets {input.targets} --backend {params.backend}"
        " --settings {params.settings} --output {output.json} --output-dir {output.details} > {log} 2>&1"


rule score_stages:
    """Synthetic data: correspondence and the frontal view's L1 after each stage of one registration."""
    input:
        unpack(registration_inputs),
        unpack(ground_truth_inputs),
        stages=results_path("registration_stages", "{subject}", "{method}", "{expression}"),
        template=results_path("template_file", "{subject}", "template.obj"),
        texture=results_path("template_file", "{subject}", "texture.png"),
        lighting=results_path("template_file", "{subject}", "lighting.json"),
    output:
        json=results_path("stage_scores", "{subject}", "{method}", "{expression}"),
        npz=results_path("stage_arrays", "{subject}", "{method}", "{expression}"),
    wildcard_constraints:
        method="|".join(REGISTRATION_METHODS),
    params:
        data=data_args(),
        cache=UNDISTORTED,
        gt=DATA.get("ground_truth_root"),
        template_dir=results_path("template_dir", "{subject}"),
        template_expression=TEMPLATE_EXPRESSION,
        backend=BACKEND,
    log:
        log_path("{subject}", "{method}", "stages", "{expression}"),
    benchmark:
        bench_path("{subject}", "{method}", "stages", "{expression}")
    threads: 1
    resources:
        mem_mb=4000,
        runtime=10,
    shell:
        "gpja --threads {threads} stages --subject {wildcards.subject} --expression {wildcards.expression}"
        " --stages-dir {input.stages} --template-dir {params.template_dir} --template-expression {params.template_expression}"
        " {params.data} --cache-dir {params.cache} --targets {input.targets} --ground-truth-root {params.gt}"
        " --backend {params.backend} --output {output.json} > {log} 2>&1"
