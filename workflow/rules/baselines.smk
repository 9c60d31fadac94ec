# Stage 3, baselines: every enabled baseline of the registry (gpja/methods.py; NICP) from the same template,
# and meshes imported from other tools.



def baseline_landmark_inputs(wildcards):
    """The landmark files a baseline's section names (NICP: ``landmarks`` of the expression and of the template
    expression, or ``template_landmarks``); on synthetic data they are ground-truth files the synthesis writes."""
    section = BASELINES.get(wildcards.method, {})
    if not section.get("landmarks"):
        return {}
    names = {"subject": wildcards.subject, "expression": wildcards.expression}
    template = section.get("template_landmarks") or section["landmarks"]
    return {"landmarks": section["landmarks"].format(**names),
            "template_landmarks": template.format(**{**names, "expression": TEMPLATE_EXPRESSION})}


# only when the config enables a baseline (baselines.<name>.enabled)
if BASELINE_METHODS:

    rule baseline_expression:
        """Register the subject's template to one expression with a baseline method, e.g. optimal-step non-rigid
        ICP (Amberg et al. 2007): `gpja baseline --method {method}` with the config's baselines.{method}."""
        input:
            unpack(registration_inputs),
            unpack(baseline_landmark_inputs),
            template=rules.build_template.output.obj,
            texture=rules.build_template.output.texture,
        output:
            obj=results_path("registration", "{subject}", "{method}", "{expression}"),
            log_json=results_path("registration_log", "{subject}", "{method}", "{expression}"),
        wildcard_constraints:
            method="|".join(BASELINE_METHODS),
        params:
            data=data_args(),
            cache=UNDISTORTED,
            # a function, not a string: Snakemake would fill a string's {subject}/{expression} with this job's
            # wildcards, but a baseline may need the pattern (NICP reads the template expression's landmarks)
            section=lambda wc: json_arg(BASELINES[wc.method]),
            template_dir=results_path("template_dir", "{subject}"),
            template_expression=TEMPLATE_EXPRESSION,
        log:
            log_path("{subject}", "{method}", "{expression}"),
        benchmark:
            bench_path("{subject}", "{method}", "{expression}")
        # 1 thread, as every rule but the template: a 2-thread job waits for two free cores at once
        # (docs/benchmarks.md "Threads"); its outputs are the same on 1 and 2 threads
        threads: 1
        resources:
            mem_mb=4000,
            runtime=10,
        shell:
            "gpja --threads {threads} baseline --method {wildcards.method} --subject {wildcards.subject}"
            " --expression {wildcards.expression} {params.data} --cache-dir {params.cache}"
            " --template-dir {params.template_dir} --template-expression {params.template_expression}"
            " --section {params.section} --output {output.obj} > {log} 2>&1"


# only when the config names imported methods (baselines.external)
if EXTERNAL:

    rule import_expression:
        """Import another tool's mesh of one expression (e.g. FaceScape TU models, NPHM) to be scored identically."""
        input:
            unpack(expression_inputs),
        output:
            obj=results_path("registration", "{subject}", "{method}", "{expression}"),
            log_json=results_path("registration_log", "{subject}", "{method}", "{expression}"),
        wildcard_constraints:
            method="|".join(EXTERNAL),
        params:
            pattern=lambda wc: EXTERNAL[wc.method]["pattern"],
            transform=lambda wc: (f"--transform {shlex.quote(EXTERNAL[wc.method]['transform'])}"
                                  if EXTERNAL[wc.method].get("transform") else ""),
            texture=lambda wc: external_texture_arg(wc),
            scans=f"--scans-root {DATA['scans_root']}" + (f" --rt-scale {DATA['rt_scale']}" if DATA.get("rt_scale") else ""),
        log:
            log_path("{subject}", "{method}", "{expression}"),
        benchmark:
            bench_path("{subject}", "{method}", "{expression}")
        threads: 1
        resources:
            mem_mb=2000,
            runtime=5,
        shell:
            "gpja --threads {threads} import --subject {wildcards.subject} --expression {wildcards.expression}"
            " --method {wildcards.method} --pattern {params.pattern:q} {params.transform} {params.texture}"
            " {params.scans} --output {output.obj} > {log} 2>&1"
