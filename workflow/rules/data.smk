# Stage 1, data: synthesise the default benchmark (FaceScape layout) and check/undistort every expression.

if SYNTH["enabled"]:

    rule synthesize_subject:
        """Procedural head, expressions, scans, multiview images and ground truth of one subject."""
        output:
            params=[params_json("{subject}", e) for e in DATA_EXPRESSIONS],
            scans=[scan_ply("{subject}", e) for e in DATA_EXPRESSIONS],
            ground_truth=[f"{DATA['ground_truth_root']}/{{subject}}/{e}.npz" for e in DATA_EXPRESSIONS],
            subject_info=f"{DATA['ground_truth_root']}/{{subject}}/subject.json",
            contact_sheet=report(
                results_path("contact_sheet", "{subject}"),
                caption="../report/contact_sheet.rst",
                category="Data",
                labels={"subject": "{subject}", "figure": "contact sheet"},
            ),
        params:
            settings=synth_settings(),
            images_root=DATA["images_root"],
            scans_root=DATA["scans_root"],
            gt_root=DATA["ground_truth_root"],
            raw_root=SYNTH.get("raw_root", f"data/{DATASET}/raw"),
        log:
            log_path("{subject}", "synthesize_subject"),
        benchmark:
            bench_path("{subject}", "synthesize_subject")
        # 1 thread, as every rule but the template: a 2-thread job waits for two free cores at once
        # (docs/benchmarks.md "Threads"); its outputs are the same on 1 and 2 threads
        threads: 1
        resources:
            mem_mb=4000,
            runtime=10,
        shell:
            "gpja --threads {threads} synth --subject {wildcards.subject} --settings {params.settings}"
            " --images-root {params.images_root} --scans-root {params.scans_root}"
            " --ground-truth-root {params.gt_root} --raw-root {params.raw_root}"
            " --contact-sheet {output.contact_sheet} > {log} 2>&1"


rule check_expression:
    """Load one expression through the FaceScape reader, undistort its views once, summarise it."""
    input:
        unpack(expression_inputs),
    output:
        results_path("data_summary", "{subject}", "{expression}"),
    params:
        data=data_args(),
        cache=UNDISTORTED,
    log:
        log_path("{subject}", "check_expression", "{expression}"),
    benchmark:
        bench_path("{subject}", "check_expression", "{expression}")
    threads: 1
    resources:
        mem_mb=2000,
        runtime=5,
    shell:
        "gpja --threads {threads} check-data --subject {wildcards.subject} --expression {wildcards.expression}"
        " {params.data} --cache-dir {params.cache} --output {output} > {log} 2>&1"


rule render_scan_targets:
    """Render one expression's scan into its views once: the depth/normal targets of registration."""
    input:
        unpack(expression_inputs),
    output:
        targets=results_path("scan_targets", "{subject}", "{expression}"),
        # a diagnostic preview, left out of the HTML report (1.7 MB each would dominate it)
        preview=results_path("scan_targets_preview", "{subject}", "{expression}"),
    params:
        data=data_args(),
        cache=UNDISTORTED,
        backend=BACKEND,
    log:
        log_path("{subject}", "render_scan_targets", "{expression}"),
    benchmark:
        bench_path("{subject}", "render_scan_targets", "{expression}")
    # 1 thread, as every rule but the template: a 2-thread job waits for two free cores at once
    # (docs/benchmarks.md "Threads"); its outputs are the same on 1 and 2 threads
    threads: 1
    resources:
        mem_mb=3000,
        runtime=5,
    shell:
        "gpja --threads {threads} scan-targets --subject {wildcards.subject} --expression {wildcards.expression}"
        " {params.data} --cache-dir {params.cache} --backend {params.backend}"
        " --output {output.targets} --preview {output.preview} > {log} 2>&1"
