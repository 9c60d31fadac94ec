# Stage 4, metrics: every method's mesh of every expression scored identically (one JSON each).


rule compute_metrics:
    """Geometry (Chamfer, N.C., F-scores), photometry (PSNR, SSIM, LPIPS) and correspondence of one mesh."""
    input:
        unpack(registration_inputs),
        mesh=f"{RESULTS}/{{subject}}/{{method}}/{{expression}}.obj",
        template=f"{RESULTS}/{{subject}}/template/template.obj",
        texture=f"{RESULTS}/{{subject}}/template/texture.png",
    output:
        json=f"{RESULTS}/{{subject}}/{{method}}/metrics/{{expression}}.json",
        details=directory(f"{RESULTS}/{{subject}}/{{method}}/metrics/{{expression}}"),
    params:
        data=data_args(),
        gt=gt_args(),
        cache=f"{RESULTS}/undistorted",
        settings=json_arg(config["metrics"]),
        template_dir=f"{RESULTS}/{{subject}}/template",
        template_expression=TEMPLATE_EXPRESSION,
    log:
        f"{LOGS}/{{subject}}/{{method}}/metrics/{{expression}}.log",
    benchmark:
        f"{BENCH}/{{subject}}/{{method}}/metrics/{{expression}}.tsv"
    threads: 1
    resources:
        mem_mb=4000,
        runtime=10,
    shell:
        "gpja --threads {threads} metrics --subject {wildcards.subject} --expression {wildcards.expression} --method {wildcards.method}"
        " --mesh {input.mesh} --template-dir {params.template_dir} --template-expression {params.template_expression}"
        " {params.data} {params.gt} --cache-dir {params.cache} --targets {input.targets}"
        " --settings {params.settings} --output {output.json} --output-dir {output.details} > {log} 2>&1"
