# Stage 4b, references (synthetic data with its ground truth only): what the methods are measured against.
# - texture_quality: the template texture against the generator's albedo (observed / unobserved texels).
# - oracle_metrics: the ground truth (scan, albedo, SH light) rendered by our renderer and scored like a method:
#   the "oracle" row of Table 2; its true surface scored against the scan, the "oracle" row of Table 1.
# Only these steps and the metrics read the ground truth; the template and the registrations never do.
from gpja.metrics.oracle import ORACLE, SUBJECT_FILE
from gpja.metrics.texture_quality import ERROR_IMAGE_FILE, QUALITY_FILE

# the condition under which `gpja metrics` scores the correspondence: synthetic data in mm with its ground truth
GROUND_TRUTH = bool(DATA.get("ground_truth_root")) and not DATA.get("rt_scale")


def ground_truth_file(subject, name):
    """A file of the synthetic ground truth: ``{ground_truth_root}/{subject}/{name}``."""
    return f"{DATA['ground_truth_root']}/{subject}/{name}"


def reference_targets(subject):
    """The reference outputs of one subject: its texture quality and the oracle's metrics of every expression."""
    if not GROUND_TRUTH:
        return []
    targets = [results_path("template_file", subject, QUALITY_FILE)]
    return targets + [results_path("metrics", subject, ORACLE, e) for e in EXPRESSIONS]


if GROUND_TRUTH:

    rule texture_quality:
        """PSNR/SSIM of the template texture against the ground-truth albedo, and its per-texel error image."""
        input:
            template=results_path("template_file", "{subject}", "template.obj"),
            texture=results_path("template_file", "{subject}", "texture.png"),
            scan=scan_ply("{subject}", TEMPLATE_EXPRESSION),
            truth=ground_truth_file("{subject}", f"{TEMPLATE_EXPRESSION}.npz"),
            subject_info=ground_truth_file("{subject}", SUBJECT_FILE),
        output:
            json=results_path("template_file", "{subject}", QUALITY_FILE),
            image=results_path("template_file", "{subject}", ERROR_IMAGE_FILE),
        params:
            template_dir=results_path("template_dir", "{subject}"),
            scans_root=DATA["scans_root"],
            gt_root=DATA["ground_truth_root"],
            expression=TEMPLATE_EXPRESSION,
        log:
            log_path("{subject}", "texture_quality"),
        benchmark:
            bench_path("{subject}", "texture_quality")
        threads: 1
        resources:
            mem_mb=3000,
            runtime=10,
        shell:
            "gpja --threads {threads} texture-quality --subject {wildcards.subject} --template-dir {params.template_dir}"
            " --template-expression {params.expression} --scans-root {params.scans_root}"
            " --ground-truth-root {params.gt_root} --output {output.json} --error-image {output.image} > {log} 2>&1"

    rule oracle_metrics:
        """The ground-truth surface, albedo and lighting rendered at the reference cameras and scored photometrically;
        the true surface scored against the scan geometrically (what the scan's noise alone costs)."""
        input:
            unpack(registration_inputs),
            truth=ground_truth_file("{subject}", "{expression}.npz"),
            subject_info=ground_truth_file("{subject}", SUBJECT_FILE),
        output:
            json=results_path("metrics", "{subject}", ORACLE, "{expression}"),
            details=directory(results_path("metrics_details", "{subject}", ORACLE, "{expression}")),
        params:
            data=data_args(),
            cache=UNDISTORTED,
            gt_root=DATA["ground_truth_root"],
            settings=json_arg(config["metrics"]),
            backend=BACKEND,
        log:
            log_path("{subject}", ORACLE, "{expression}"),
        benchmark:
            bench_path("{subject}", ORACLE, "{expression}")
        threads: 1
        resources:
            mem_mb=4000,
            runtime=10,
        shell:
            "gpja --threads {threads} oracle --subject {wildcards.subject} --expression {wildcards.expression}"
            " {params.data} --cache-dir {params.cache} --ground-truth-root {params.gt_root} --targets {input.targets}"
            " --settings {params.settings} --backend {params.backend} --output {output.json}"
            " --output-dir {output.details} > {log} 2>&1"
