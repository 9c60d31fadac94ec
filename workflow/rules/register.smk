# Stage 2, GPJA: the subject's textured template, then every expression registered from it.
from gpja.register.order import start_expression


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
    # the one rule on 2 threads: its template depends on the thread count at some image sizes (the 256 px
    # open-to-closed test's decimates differently on 1 thread), so it keeps the thread count its results were
    # made with; while it waits for two free cores only short jobs run (docs/benchmarks.md "Threads")
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


checkpoint registration_order:
    """Which expression each registration starts from: the minimum spanning tree of the scans' distances."""
    input:
        scans=lambda wc: [scan_ply(wc.subject, e) for e in DATA_EXPRESSIONS],
    output:
        results_path("registration_order", "{subject}"),
    params:
        data=data_args(),
        expressions=" ".join(EXPRESSIONS),
        root=TEMPLATE_EXPRESSION,
    log:
        log_path("{subject}", "registration_order"),
    benchmark:
        bench_path("{subject}", "registration_order")
    threads: 1
    resources:
        mem_mb=2000,
        runtime=5,
    shell:
        "gpja --threads {threads} order --subject {wildcards.subject} --expressions {params.expressions}"
        " --template-expression {params.root} {params.data} --output {output} > {log} 2>&1"


def start_inputs(wildcards):
    """The mesh a registration starts from when it is not the template (``registration.start: tree``): the
    GPJA registration of the expression's parent in the subject's registration tree, before its snap (the
    parent's ``--start-output``, ``starts/{parent}.obj``). Variants that change
    one constraint (or drop the flow stage) start from the same mesh as GPJA; ``gpja-paper`` always starts
    from the template."""
    if REG.get("start", "template") != "tree" or not registry.method(wildcards.method).follows_start:
        return {}
    with open(checkpoints.registration_order.get(subject=wildcards.subject).output[0]) as fh:
        parent = start_expression(json.load(fh), wildcards.expression)
    return {"start": results_path("registration_start", wildcards.subject, "gpja", parent)} if parent else {}


def start_arg(wildcards, input):
    return f"--start-from {shlex.quote(input.start)}" if "start" in input.keys() else ""


rule register_expression:
    """Register the subject's template to one expression with GPJA (or an ablation variant)."""
    input:
        unpack(registration_inputs),
        unpack(start_inputs),
        template=rules.build_template.output.obj,
        texture=rules.build_template.output.texture,
        mask=rules.build_template.output.mask,
        lighting=rules.build_template.output.lighting,
    output:
        obj=results_path("registration", "{subject}", "{method}", "{expression}"),
        log_json=results_path("registration_log", "{subject}", "{method}", "{expression}"),
        stages=directory(results_path("registration_stages", "{subject}", "{method}", "{expression}")),
        start=results_path("registration_start", "{subject}", "{method}", "{expression}"),
    wildcard_constraints:
        method="|".join(REGISTRATION_METHODS),
    params:
        data=data_args(),
        cache=UNDISTORTED,
        settings=lambda wc: json_arg(registry.method(wc.method).schedule_settings(REG)),
        without=without_args,
        start=start_arg,
        template_dir=results_path("template_dir", "{subject}"),
        backend=BACKEND,
    log:
        log_path("{subject}", "{method}", "{expression}"),
    benchmark:
        bench_path("{subject}", "{method}", "{expression}")
    # one thread each: two registrations side by side on 2 cores finish 1.37x sooner than one after the other
    # on 2 threads (README "Runtime"); --set-threads register_expression=2 speeds up a single expression
    threads: 1
    # the longest jobs: start them as soon as they can run, let short ones fill the gaps; GPJA's own before the
    # ablation variants, since the subject's applications wait for every GPJA expression (the run's last chain)
    priority: lambda wc: 10 if wc.method == "gpja" else 5
    resources:
        mem_mb=6000,
        runtime=30,
    shell:
        "gpja --threads {threads} register --subject {wildcards.subject} --expression {wildcards.expression} {params.data}"
        " --cache-dir {params.cache} --targets {input.targets} --settings {params.settings}"
        " --template-dir {params.template_dir} {params.without} {params.start} --backend {params.backend} --output {output.obj} --stages-dir {output.stages}"
        " --start-output {output.start} > {log} 2>&1"
