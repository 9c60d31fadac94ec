# Stage 3, baselines: optimal-step NICP from the same template, and meshes imported from other tools.


rule nicp_expression:
    """Register the subject's template to one expression with optimal-step non-rigid ICP (Amberg et al. 2007)."""
    input:
        unpack(registration_inputs),
        template=rules.build_template.output.obj,
        texture=rules.build_template.output.texture,
    output:
        obj=f"{RESULTS}/{{subject}}/nicp/{{expression}}.obj",
        log_json=f"{RESULTS}/{{subject}}/nicp/{{expression}}.json",
    params:
        scans=f"--scans-root {DATA['scans_root']}" + (f" --rt-scale {DATA['rt_scale']}" if DATA.get("rt_scale") else ""),
        # functions, not strings: Snakemake would fill a string's {subject}/{expression} with this job's
        # wildcards, but gpja needs the pattern (it also reads the template expression's landmarks)
        landmarks=lambda wc: NICP.get("landmarks", ""),
        template_landmarks=lambda wc: (f"--template-landmarks {shlex.quote(NICP['template_landmarks'])}"
                                       if NICP.get("template_landmarks") else ""),
        settings=json_arg(NICP.get("settings", {})),
        template_dir=f"{RESULTS}/{{subject}}/template",
        template_expression=TEMPLATE_EXPRESSION,
    log:
        f"{LOGS}/{{subject}}/nicp/{{expression}}.log",
    benchmark:
        f"{BENCH}/{{subject}}/nicp/{{expression}}.tsv"
    threads: 2
    resources:
        mem_mb=4000,
        runtime=10,
    shell:
        "gpja --threads {threads} nicp --subject {wildcards.subject} --expression {wildcards.expression}"
        " {params.scans} --template-dir {params.template_dir} --template-expression {params.template_expression}"
        " --landmarks {params.landmarks:q} {params.template_landmarks} --settings {params.settings}"
        " --output {output.obj} > {log} 2>&1"


# only when the config names imported methods (baselines.external)
if EXTERNAL:

    rule import_expression:
        """Import another tool's mesh of one expression (e.g. FaceScape TU models, NPHM) to be scored identically."""
        input:
            unpack(expression_inputs),
        output:
            obj=f"{RESULTS}/{{subject}}/{{method}}/{{expression}}.obj",
            log_json=f"{RESULTS}/{{subject}}/{{method}}/{{expression}}.json",
        wildcard_constraints:
            method="|".join(EXTERNAL),
        params:
            pattern=lambda wc: EXTERNAL[wc.method]["pattern"],
            transform=lambda wc: (f"--transform {shlex.quote(EXTERNAL[wc.method]['transform'])}"
                                  if EXTERNAL[wc.method].get("transform") else ""),
            texture=lambda wc: external_texture_arg(wc),
            scans=f"--scans-root {DATA['scans_root']}" + (f" --rt-scale {DATA['rt_scale']}" if DATA.get("rt_scale") else ""),
        log:
            f"{LOGS}/{{subject}}/{{method}}/{{expression}}.log",
        benchmark:
            f"{BENCH}/{{subject}}/{{method}}/{{expression}}.tsv"
        threads: 1
        resources:
            mem_mb=2000,
            runtime=5,
        shell:
            "gpja --threads {threads} import --subject {wildcards.subject} --expression {wildcards.expression}"
            " --method {wildcards.method} --pattern {params.pattern:q} {params.transform} {params.texture}"
            " {params.scans} --output {output.obj} > {log} 2>&1"
