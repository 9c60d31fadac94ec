# Stage 6, the paper's applications (config `applications`): every expression of a subject on one triangulation,
# an animation through them, the artist mesh carried onto each, one glTF with every expression as a blendshape.
# The template's own expression is the template mesh (the registration's starting point).
from gpja.apply.settings import AnimationSettings

APPS = config.get("applications") or {}
APPS_ON = bool(APPS.get("enabled", False))
APP_EXPRESSIONS = EXPRESSIONS + ([TEMPLATE_EXPRESSION] if TEMPLATE_EXPRESSION not in EXPRESSIONS else [])


def source_mesh(subject, expression):
    """The mesh an application reads for one expression: GPJA's registration, or the template for its own."""
    if expression == TEMPLATE_EXPRESSION and expression not in EXPRESSIONS:
        return results_path("template_file", subject, "template.obj")
    return results_path("registration", subject, "gpja", expression)


def named_meshes(paths):
    """`NAME=PATH ...` arguments of `gpja triangulate|export|animate`."""
    return " ".join(shlex.quote(f"{name}={path}") for name, path in paths.items())


def application_targets(subject):
    """Every output of the applications for one subject (none when `applications.enabled` is off)."""
    if not APPS_ON:
        return []
    targets = [results_path("remeshed", subject, e) for e in APP_EXPRESSIONS]
    targets += [results_path("reparametrized", subject, e) for e in APP_EXPRESSIONS]
    targets += [results_path("reparam_turns", subject)]
    targets += [results_path("blendshapes", subject), results_path("animation", subject)]
    return targets


rule triangulate_subject:
    """The triangulation, in the template's texture space, that every remeshed expression of the subject shares."""
    input:
        template=rules.build_template.output.obj,
        meshes=lambda wc: [source_mesh(wc.subject, e) for e in APP_EXPRESSIONS],
    output:
        obj=results_path("common_triangulation", "{subject}"),
        log_json=str(LAYOUT.common_triangulation("{subject}").with_suffix(".json")),
    params:
        meshes=lambda wc: named_meshes({e: source_mesh(wc.subject, e) for e in APP_EXPRESSIONS}),
        template_dir=results_path("template_dir", "{subject}"),
        settings=json_arg(APPS.get("remesh") or {}),
    log:
        log_path("{subject}", "applications", "triangulate"),
    benchmark:
        bench_path("{subject}", "applications", "triangulate")
    threads: 1
    priority: 10  # on the run's last chain (every GPJA registration of the subject -> this -> remesh -> export)
    resources:
        mem_mb=6000,
        runtime=20,
    shell:
        "gpja --threads {threads} triangulate --subject {wildcards.subject} --template-dir {params.template_dir}"
        " --meshes {params.meshes} --settings {params.settings} --output {output.obj} > {log} 2>&1"


rule remesh_expression:
    """One expression on the subject's common triangulation, with its deviation and render checks."""
    input:
        common=rules.triangulate_subject.output.obj,
        mesh=lambda wc: source_mesh(wc.subject, wc.expression),
        lighting=rules.build_template.output.lighting,
    output:
        obj=results_path("remeshed", "{subject}", "{expression}"),
        log_json=str(LAYOUT.remeshed("{subject}", "{expression}").with_suffix(".json")),
    params:
        template_dir=results_path("template_dir", "{subject}"),
    log:
        log_path("{subject}", "applications", "remesh_{expression}"),
    benchmark:
        bench_path("{subject}", "applications", "remesh_{expression}")
    threads: 1
    resources:
        mem_mb=3000,
        runtime=10,
    shell:
        "gpja --threads {threads} remesh --subject {wildcards.subject} --expression {wildcards.expression}"
        " --common {input.common} --mesh {input.mesh} --template-dir {params.template_dir} --output {output.obj}"
        " > {log} 2>&1"


rule export_subject:
    """The remeshed expressions as one glTF binary: the base expression, every other a morph target."""
    input:
        meshes=lambda wc: [results_path("remeshed", wc.subject, e) for e in APP_EXPRESSIONS],
        texture=rules.build_template.output.texture,
    output:
        report(
            results_path("blendshapes", "{subject}"),
            caption="../report/blendshapes.rst",
            category="Applications",
            labels={"subject": "{subject}", "output": "glTF blendshapes"},
        ),
    params:
        meshes=lambda wc: named_meshes({e: results_path("remeshed", wc.subject, e) for e in APP_EXPRESSIONS}),
        template_dir=results_path("template_dir", "{subject}"),
        settings=json_arg(APPS.get("export") or {}),
    log:
        log_path("{subject}", "applications", "export"),
    benchmark:
        bench_path("{subject}", "applications", "export")
    threads: 1
    resources:
        mem_mb=3000,
        runtime=10,
    shell:
        "gpja --threads {threads} export --subject {wildcards.subject} --meshes {params.meshes}"
        " --template-dir {params.template_dir} --settings {params.settings} --output {output} > {log} 2>&1"


def animation_expressions():
    return list(dict.fromkeys((APPS.get("animation") or {}).get("sequence") or AnimationSettings().sequence))


rule animate_subject:
    """Interpolate the remeshed expressions along the configured sequence, render two views, encode a video."""
    input:
        meshes=lambda wc: [results_path("remeshed", wc.subject, e) for e in animation_expressions()],
        texture=rules.build_template.output.texture,
        lighting=rules.build_template.output.lighting,
    output:
        video=report(
            results_path("animation", "{subject}"),
            caption="../report/animation.rst",
            category="Applications",
            labels={"subject": "{subject}", "output": "animation"},
        ),
        frames=results_path("animation_frames", "{subject}"),
    params:
        meshes=lambda wc: named_meshes({e: results_path("remeshed", wc.subject, e) for e in animation_expressions()}),
        template_dir=results_path("template_dir", "{subject}"),
        settings=json_arg(APPS.get("animation") or {}),
    log:
        log_path("{subject}", "applications", "animate"),
    benchmark:
        bench_path("{subject}", "applications", "animate")
    threads: 1
    resources:
        mem_mb=6000,
        runtime=20,
    shell:
        "gpja --threads {threads} animate --subject {wildcards.subject} --meshes {params.meshes}"
        " --template-dir {params.template_dir} --settings {params.settings} --output {output.video}"
        " --frames-output {output.frames} > {log} 2>&1"


rule artist_mesh:
    """The artist mesh carried onto every expression (applications.reparam.artist_mesh, or a stand-in), with the
    shared texture resampled into its UV layout."""
    input:
        template=rules.build_template.output.obj,
        texture=rules.build_template.output.texture,
        artist=lambda wc: ([(APPS.get("reparam") or {})["artist_mesh"].replace("{subject}", wc.subject)]
                           if (APPS.get("reparam") or {}).get("artist_mesh") else []),
    output:
        obj=results_path("artist_mesh", "{subject}"),
        mtl=str(LAYOUT.artist_mesh("{subject}").with_suffix(".mtl")),
        texture=str(LAYOUT.reparam_dir("{subject}") / "texture.png"),
        log_json=str(LAYOUT.artist_mesh("{subject}").with_suffix(".json")),
    params:
        template_dir=results_path("template_dir", "{subject}"),
        # the untangling is the carrying's, not the artist mesh's: changing it does not remake the artist mesh
        settings=json_arg({k: v for k, v in (APPS.get("reparam") or {}).items() if not k.startswith("untangle_")}),
    log:
        log_path("{subject}", "applications", "artist_mesh"),
    benchmark:
        bench_path("{subject}", "applications", "artist_mesh")
    threads: 1
    resources:
        mem_mb=3000,
        runtime=10,
    shell:
        "gpja --threads {threads} artist --subject {wildcards.subject} --template-dir {params.template_dir}"
        " --settings {params.settings} --output {output.obj} > {log} 2>&1"


rule reparametrize_expression:
    """The artist mesh on one expression: the paper's phi_b phi_a^-1 through the template's texture space."""
    input:
        artist=rules.artist_mesh.output.obj,
        mesh=lambda wc: source_mesh(wc.subject, wc.expression),
        lighting=rules.build_template.output.lighting,
    output:
        obj=results_path("reparametrized", "{subject}", "{expression}"),
        log_json=str(LAYOUT.reparametrized("{subject}", "{expression}").with_suffix(".json")),
    params:
        template_dir=results_path("template_dir", "{subject}"),
        settings=json_arg(APPS.get("reparam") or {}),
    log:
        log_path("{subject}", "applications", "reparametrize_{expression}"),
    benchmark:
        bench_path("{subject}", "applications", "reparametrize_{expression}")
    threads: 1
    resources:
        mem_mb=3000,
        runtime=10,
    shell:
        "gpja --threads {threads} reparametrize --subject {wildcards.subject} --expression {wildcards.expression}"
        " --artist {input.artist} --mesh {input.mesh} --template-dir {params.template_dir}"
        " --settings {params.settings} --output {output.obj}"
        " > {log} 2>&1"


def truth_of_turns(wildcards):
    """The ground truth `gpja turns` carries the artist mesh through (synthetic data only)."""
    if not GROUND_TRUTH:
        return {}
    return {"truth": ground_truth_file(wildcards.subject, f"{TEMPLATE_EXPRESSION}.npz"),
            "subject_info": ground_truth_file(wildcards.subject, SUBJECT_FILE),
            "scan": scan_ply(wildcards.subject, TEMPLATE_EXPRESSION)}


rule count_turns:
    """The artist mesh's faces turned over along each hop of the registration tree, and, on synthetic data, the
    faces the generator's own motion turns over (a closing eye folds the lid's skin under)."""
    input:
        unpack(truth_of_turns),
        artist=rules.artist_mesh.output.obj,
        meshes=lambda wc: [results_path("reparametrized", wc.subject, e) for e in APP_EXPRESSIONS],
        order=results_path("registration_order", "{subject}"),
        template=rules.build_template.output.obj,
        observed=rules.build_template.output.observed,
    output:
        results_path("reparam_turns", "{subject}"),
    params:
        meshes=lambda wc: named_meshes({e: results_path("reparametrized", wc.subject, e) for e in APP_EXPRESSIONS}),
        template_dir=results_path("template_dir", "{subject}"),
        truth=(f"--ground-truth-root {DATA['ground_truth_root']} --scans-root {DATA['scans_root']}"
               if GROUND_TRUTH else ""),
        expression=TEMPLATE_EXPRESSION,
    log:
        log_path("{subject}", "applications", "turns"),
    benchmark:
        bench_path("{subject}", "applications", "turns")
    threads: 1
    resources:
        mem_mb=2000,
        runtime=5,
    shell:
        "gpja --threads {threads} turns --subject {wildcards.subject} --artist {input.artist} --meshes {params.meshes}"
        " --order {input.order} --template-dir {params.template_dir} --template-expression {params.expression}"
        " {params.truth} --output {output} > {log} 2>&1"
