# Stage 5, report: the paper's tables (geometry, photometry, ablations, correspondence, timing) from every metrics JSON,
# and the HTML report of every table and figure.

# tables this configuration can fill: ablations only with ablation variants; correspondence (overall and by region),
# the position error and the texture's quality only with synthetic ground truth (GROUND_TRUTH, workflow/rules/reference.smk)
TABLES = ["geometry", "photometric"]
TABLES += ["ablation"] if ABLATION_VARIANTS else []
TABLES += ["correspondence", "correspondence_regions", "position_regions", "texture"] if GROUND_TRUTH else []
TABLES += ["turns"] if APPS_ON else []
TABLES += ["timing"]
TABLES_DIR = str(LAYOUT.tables_dir)
# the methods the tables read: every method, then the references (the oracle's row of Table 2)
TABLE_METHODS = METHODS + ([ORACLE] if GROUND_TRUTH else [])


def table_outputs():
    """Named outputs {table}_{csv|md|tex}: Markdown and CSV shown in the Snakemake report."""
    outputs = {}
    for table in TABLES:
        for ext in ("md", "csv"):
            outputs[f"{table}_{ext}"] = report(results_path("table", table, ext), caption=f"../report/table_{table}.rst",
                                               category="Tables", labels={"table": table, "format": ext})
        outputs[f"{table}_tex"] = results_path("table", table, "tex")
    return outputs


def table_inputs(wildcards):
    """Every metrics JSON, the registration logs the timing table reads and the references (synthetic data)."""
    return {"metrics": metrics_files(), "logs": [results_path("registration_log", s, m, e) for s, m, e in runs()],
            "references": [t for s in SUBJECTS for t in reference_targets(s)],
            "turns": [results_path("reparam_turns", s) for s in SUBJECTS] if APPS_ON else []}


rule make_tables:
    """The paper's Tables 1-3, correspondence and timing as CSV, Markdown and LaTeX (FaceScape: beside the paper's)."""
    input:
        unpack(table_inputs),
    output:
        **table_outputs(),
    params:
        results=RESULTS,
        benchmarks=str(LAYOUT.benchmarks_root),
        subjects=SUBJECTS,
        expressions=EXPRESSIONS,
        methods=TABLE_METHODS,
        tables=TABLES,
        published="--published facescape" if DATASET == "facescape" else "",
        ablation=(f"--ablation-subjects {shlex.join(ABLATION_SUBJECTS)} --ablation-expressions "
                  f"{shlex.join(ABLATION_EXPRESSIONS)}" if ABLATION_VARIANTS else ""),
        out_dir=TABLES_DIR,
    log:
        log_path("make_tables"),
    benchmark:
        bench_path("make_tables")
    threads: 1
    resources:
        mem_mb=1000,
        runtime=5,
    shell:
        "gpja --threads {threads} tables --results {params.results} --benchmarks {params.benchmarks}"
        " --subjects {params.subjects:q} --expressions {params.expressions:q} --methods {params.methods:q}"
        " --tables {params.tables} {params.published} {params.ablation} --output-dir {params.out_dir} > {log} 2>&1"


rule make_report:
    """The Snakemake HTML report of every table and figure (the same as `snakemake --report`), written last."""
    input:
        [t for s in SUBJECTS for t in subject_targets(s)],
        rules.make_tables.output,
    output:
        str(LAYOUT.report),
    params:
        snakefile=workflow.main_snakefile,
        # the run's own configuration (after --configfile/--config), so the report shows this run's files
        config=lambda wc: json.dumps(config, sort_keys=True),
    log:
        log_path("make_report"),
    benchmark:
        bench_path("make_report")
    threads: 1
    resources:
        mem_mb=2000,
        runtime=10,
    shell:
        # Snakemake reads the provenance of the finished jobs from .snakemake/ (no lock needed: read only)
        # (the shell runs under `set -e`: keep the status so the temporary config goes either way)
        "printf '%s' {params.config:q} > {output}.config.json; status=0"
        "; snakemake --snakefile {params.snakefile} {input:q} --nolock --configfile {output}.config.json"
        " --report {output} > {log} 2>&1 || status=$?; rm -f {output}.config.json; exit $status"


rule subject_all:
    """Everything of one subject (data checks, template, every registration and its metrics, its figures):
    `snakemake --cores 2 results/{dataset}/{subject}/all.done` rebuilds that subject only."""
    input:
        lambda wc: subject_targets(wc.subject),
    output:
        touch(results_path("subject_done", "{subject}")),
    log:
        log_path("{subject}", "subject_all"),
    benchmark:
        bench_path("{subject}", "subject_all")
    threads: 1
    resources:
        mem_mb=100,
        runtime=1,
    shell:
        "echo 'subject {wildcards.subject}: {input}' > {log}"
