# Stage 2, GPJA: the subject's textured template, then every expression registered from it.


def registration_inputs(wildcards, expression=None):
    """An expression's data files and its cached scan targets: what a capture has (never the ground truth)."""
    expression = expression or wildcards.expression
    files = {"params": params_json(wildcards.subject, expression), "scan": scan_ply(wildcards.subject, expression),
             "targets": results_path("scan_targets", wildcards.subject, expression)}
    if DATA.get("rt_scale"):
        files["rt_scale"] = DATA["rt_scale"]
    return files


rule build_template:
    """Fit the genus-0 bust to the mouth-open scan (depth only), estimate the lighting, fuse the texture, decimate."""
    input:
        unpack(lambda wc: registration_inputs(wc, TEMPLATE_EXPRESSION)),
    output:
        obj=results_path("template_file", "{subject}", "template.obj"),
        mtl=results_path("template_file", "{subject}", "template.mtl"),
        texture=report(
            results_path("template_file", "{subject}", "texture.png"),
            caption="../report/template_texture.rst",
            category="Template",
            labels={"subject": "{subject}", "figure": "texture"},
        ),
        mask=results_path("template_file", "{subject}", "mouth_mask.png"),
        log_json=results_path("template_file", "{subject}", "template.json"),
        lighting=results_path("template_file", "{subject}", "lighting.json"),
        observed=results_path("template_file", "{subject}", "texture_observed.png"),
        stages=directory(results_path("template_file", "{subject}", "stages")),
    params:
        data=data_args(),
        cache=UNDISTORTED,
        settings=json_arg(REG["template"]),
        lighting=REG.get("lighting", "estimate"),
        expression=TEMPLATE_EXPRESSION,
        out_dir=results_path("template_dir", "{subject}"),
        backend=BACKEND,
    log:
        log_path("{subject}", "build_template"),
    benchmark:
        bench_path("{subject}", "build_template")
    threads: 2
    priority: 20  # every registration of the subject waits for it
    resources:
        mem_mb=6000,
        runtime=30,
    shell:
        "gpja --threads {threads} template --subject {wildcards.subject} --expression {params.expression} {params.data}"
        " --cache-dir {params.cache} --targets {input.targets} --settings {params.settings} --lighting {params.lighting}"
        " --backend {params.backend}"
        " --output-dir {params.out_dir} > {log} 2>&1"


rule register_expression:
    """Register the subject's template to one expression with GPJA (or an ablation variant)."""
    input:
        unpack(registration_inputs),
        template=rules.build_template.output.obj,
        texture=rules.build_template.output.texture,
        mask=rules.build_template.output.mask,
        lighting=rules.build_template.output.lighting,
    output:
        obj=results_path("registration", "{subject}", "{method}", "{expression}"),
        log_json=results_path("registration_log", "{subject}", "{method}", "{expression}"),
    wildcard_constraints:
        method="|".join(REGISTRATION_METHODS),
    params:
        data=data_args(),
        cache=UNDISTORTED,
        settings=json_arg(REG["gpja"]),
        without=without_args,
        template_dir=results_path("template_dir", "{subject}"),
        backend=BACKEND,
    log:
        log_path("{subject}", "{method}", "{expression}"),
    benchmark:
        bench_path("{subject}", "{method}", "{expression}")
    # one thread each: two registrations side by side on 2 cores finish 1.37x sooner than one after the other
    # on 2 threads (README "Runtime"); --set-threads register_expression=2 speeds up a single expression
    threads: 1
    priority: 10  # the longest jobs: start them as soon as they can run, let short ones fill the gaps
    resources:
        mem_mb=6000,
        runtime=30,
    shell:
        "gpja --threads {threads} register --subject {wildcards.subject} --expression {wildcards.expression} {params.data}"
        " --cache-dir {params.cache} --targets {input.targets} --settings {params.settings}"
        " --template-dir {params.template_dir} {params.without} --backend {params.backend} --output {output.obj} > {log} 2>&1"
