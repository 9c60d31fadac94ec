# Stage 5, report: the paper's tables (geometry, photometry, ablations, correspondence, timing) from every metrics JSON.

# tables this configuration can fill: ablations only with ablation variants, correspondence only with synthetic
# ground truth (the condition under which `gpja metrics` scores it)
TABLES = ["geometry", "photometric"]
TABLES += ["ablation"] if any(m in ABLATIONS and m != "gpja" for m in METHODS) else []
TABLES += ["correspondence"] if DATA.get("ground_truth_root") and not DATA.get("rt_scale") else []
TABLES += ["timing"]
TABLES_DIR = f"{RESULTS}/tables"


def table_outputs():
    """Named outputs {table}_{csv|md|tex}: Markdown and CSV shown in the Snakemake report."""
    outputs = {}
    for table in TABLES:
        for ext in ("md", "csv"):
            outputs[f"{table}_{ext}"] = report(f"{TABLES_DIR}/{table}.{ext}", caption=f"../report/table_{table}.rst",
                                               category="Tables", labels={"table": table, "format": ext})
        outputs[f"{table}_tex"] = f"{TABLES_DIR}/{table}.tex"
    return outputs


def table_inputs(wildcards):
    """Every metrics JSON, and the registration logs the timing table reads."""
    combos = dict(subject=SUBJECTS, method=METHODS, expression=EXPRESSIONS)
    return {"metrics": expand(f"{RESULTS}/{{subject}}/{{method}}/metrics/{{expression}}.json", **combos),
            "logs": expand(f"{RESULTS}/{{subject}}/{{method}}/{{expression}}.json", **combos)}


rule make_tables:
    """The paper's Tables 1-3, correspondence and timing as CSV, Markdown and LaTeX (FaceScape: beside the paper's)."""
    input:
        unpack(table_inputs),
    output:
        **table_outputs(),
    params:
        results=RESULTS,
        benchmarks=BENCH,
        subjects=SUBJECTS,
        expressions=EXPRESSIONS,
        methods=METHODS,
        tables=TABLES,
        published="--published facescape" if DATASET == "facescape" else "",
        out_dir=TABLES_DIR,
    log:
        f"{LOGS}/make_tables.log",
    benchmark:
        f"{BENCH}/make_tables.tsv"
    threads: 1
    resources:
        mem_mb=1000,
        runtime=5,
    shell:
        "gpja --threads {threads} tables --results {params.results} --benchmarks {params.benchmarks}"
        " --subjects {params.subjects:q} --expressions {params.expressions:q} --methods {params.methods:q}"
        " --tables {params.tables} {params.published} --output-dir {params.out_dir} > {log} 2>&1"
