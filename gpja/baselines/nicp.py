"""Optimal-step non-rigid ICP (Amberg, Romdhani & Vetter, CVPR 2007): the geometric baseline.

The subject's template (the same mesh GPJA starts from) is deformed onto each
expression scan. Every template vertex ``v_i`` carries its own affine map
``X_i`` (4x3: ``x_i = X_i^T [v_i; 1]``); each iteration minimises

    sum_i a_i w_i |X_i^T v~_i - u_i|^2                 (data: closest scan point u_i)
  + alpha^2 sum_(i,j) in edges |G (X_i - X_j)|^2       (stiffness, G = diag(1, 1, 1, gamma))
  + beta^2 (A / L) sum_l |x_l - u_l|^2                  (landmarks x_l, see TemplateLandmarks)

in closed form: in Amberg's notation the least-squares solution of
``[alpha M (x) G; W D; beta D_L] X = [0; W U; U_L]``. We solve its normal
equations (a 4n x 4n sparse SPD system with three right-hand sides) with a
sparse Cholesky factor (cholespy / CHOLMOD), reused as a CG preconditioner
while the system changes little (:class:`AffineSolver`). For each stiffness
``alpha`` of a decreasing schedule, correspondences and solves alternate until
the mean vertex move of an iteration drops below ``convergence_mm``.

Modules: this one holds the settings, the algorithm and the file driver
(:func:`run_baseline`, the workflow's entry point); the sparse system and its
solver are :mod:`gpja.baselines.nicp_solver`, landmark files and attaching
landmarks to the template :mod:`gpja.baselines.landmarks`, correspondences and
the rigid pre-alignment :mod:`gpja.baselines.alignment`; closest points, the
scan's rim and normals are the shared :mod:`gpja.surface`.

Scale invariance: positions are centred and divided by their RMS radius
before solving, so ``gamma = 1`` weighs translation and linear parts evenly;
data weights carry the vertex area ``a_i`` (normalised units), so a stiffness
means the same on a 2K- and a 16K-vertex template (the edge sum approximates a
Dirichlet energy, which does not depend on the resolution). ``A`` is the
template's area: ``beta = 1`` makes the landmarks weigh as much as the whole
dense data term. Roughly, a level of stiffness ``alpha`` follows deformations
whose length scale exceeds ``alpha`` head radii (~100 mm).

Correspondences are rejected (``w_i = 0``) when the closest scan point lies on
the scan's boundary (holes, the cropped neck and scalp: Amberg's rule, which
keeps the back of the head and the underside of the neck from being dragged
onto the scan's rim), when it is farther than ``max_distance_mm``, or when the
scan and template normals differ by more than ``max_normal_angle_deg`` (the
mouth interior, the far side of thin parts). Rejected vertices follow their
neighbours through the stiffness term. The boundary is :func:`gpja.surface.rim`'s,
the one the metrics use: coincident vertices are welded first, so a scan saved
with per-corner vertices is not all rim.

Schedule (:data:`DEFAULT_STEPS`: alpha 0.06 -> 0.0075 halving, beta 1 -> 0.1),
tuned on the synthetic subject S01 (template -> 1_neutral, 2_smile) against
scan-to-mesh distance and the correspondence error measured with the ground
truth's rest coordinates. The template is the subject's own head fitted to
``3_mouth_stretch``, and the rigid stage already aligns the parts an
expression leaves alone (forehead, scalp, nose) to ~0.1 mm, so there is no
identity difference for the usual stiff, near-global levels (alpha >= 0.25)
to absorb. Worse, at those levels the jaw landmarks (mouth open -> closed
moves the chin ~40 mm) bend the whole head, and point-to-point data does not
resist the resulting tangential sliding: starting at alpha = 3 (beta 10) slid
the forehead and scalp 5-8 mm and gave a mean correspondence error of 7.3 mm,
against 1.5 mm when starting at 0.06, at the same scan-to-mesh distance
(0.17 mm). Starting at 0.06 keeps the landmark pull local to the jaw and
lips. The landmark weight halves with each level but stays at 0.1, not 0:
released, the landmarks drift 2 mm for a 0.01 mm better scan-to-mesh
distance. Detected landmarks are noisy; with 2 mm of Gaussian noise the
scan-to-mesh distance did not change and the correspondence error grew to
2.0 mm. Below alpha = 0.0075 the fit gains little (0.116 -> 0.101 mm at
0.004 in an earlier variant) while folds grow. The remaining folds (~50-100
edges more than the template) are where the template's open mouth is
closed: lip interior and under the chin. For a template of another person,
prepend stiffer levels (e.g. alpha 3, 1, 0.5, 0.25 with beta 1).

Why not ``trimesh.registration.nricp_amberg``: profiled (cProfile) on the 16K-
vertex synthetic template against a 208K-vertex scan, one iteration took
~29 s: ~18 s in ``trimesh.proximity.closest_point`` (an R-tree plus per-triangle
numpy), ~9 s in SuperLU (``spsolve`` of the normal equations, factorised from
scratch each iteration) and ~1.5 s building a ``lil_matrix``. It also has no
boundary rejection, and its stiffness depends on the mesh resolution. Open3D's
BVH closest points (~60 ms per query of 16K points) and the reused Cholesky
factor (~0.2-0.5 s per solve) make an iteration ~50x cheaper: ~9 s for a whole
registration on S01 (~30 iterations), on a shared 2-core machine.
"""

import os
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from gpja.baselines.alignment import find_correspondences, rigid_align
from gpja.baselines.landmarks import (check_landmarks, check_landmarks_on_scan, read_landmarks,
                                      read_template_landmarks, template_landmark_points, transform_points)
from gpja.baselines.nicp_solver import AffineProblem, AffineSolver, apply_affine, prepare_problem, solve_affine
from gpja.cholesky import BACKENDS as CHOLESKY_BACKENDS
from gpja.cholesky import DEFAULT_BACKEND as DEFAULT_CHOLESKY
from gpja.data.source import DataSource
from gpja.data.units import check_units
from gpja.errors import InputError
from gpja.io import fill_path_pattern
from gpja.mesh import TexturedMesh
from gpja.results import read_template, write_registration
from gpja.settings import from_section
from gpja.surface import Surface, prepare_surface, vertex_normals


@dataclass(frozen=True)
class NicpStep:
    """One stiffness level of the schedule.

    Attributes:
        stiffness: alpha (normalised units; see the module docstring).
        landmark_weight: beta; 0 drops the landmark term.
        max_iterations: cap on correspondence/solve alternations at this level.
    """

    stiffness: float
    landmark_weight: float
    max_iterations: int

    def __post_init__(self) -> None:
        if not (self.stiffness > 0 and self.landmark_weight >= 0 and self.max_iterations >= 1):
            raise ValueError(f"stiffness must be > 0, landmark weight >= 0, iterations >= 1, got "
                             f"[{self.stiffness}, {self.landmark_weight}, {self.max_iterations}]")


#: Default schedule (see the module docstring, "Schedule").
DEFAULT_STEPS = (
    NicpStep(0.06, 1.0, 8),
    NicpStep(0.03, 0.5, 10),
    NicpStep(0.015, 0.2, 10),
    NicpStep(0.0075, 0.1, 10),
)


@dataclass(frozen=True)
class NicpSettings:
    """Optimal-step NICP parameters.

    Attributes:
        steps: stiffness schedule, stiffest first.
        gamma: weight of the translation column in the stiffness term.
        max_distance_mm: reject correspondences farther than this.
        max_normal_angle_deg: reject correspondences whose normals differ by more.
        reject_boundary: reject closest points on the scan's boundary (holes, crops).
        convergence_mm: a level ends when the mean vertex move of an iteration drops below this.
        rigid_iterations: trimmed rigid ICP iterations after the landmark Procrustes.
        rigid_keep: fraction of the (valid) correspondences the rigid ICP keeps, closest first.
        similarity: let the pre-alignment scale the template (False: both are mm already).
        cholesky: the sparse Cholesky backend of the 4n x 4n solves (``gpja.cholesky``): ``simplicial``
            (cholespy) or ``supernodal`` (cvxopt's CHOLMOD; the same registration to rounding). The
            supernodal factor is built 8x faster but applied 2.7x slower, and a default-run NICP applies it
            ~190 times for 2 factorisations: 23.8-27.9 s against 22.9-24.0 s (docs/benchmarks.md).
    """

    steps: tuple[NicpStep, ...] = DEFAULT_STEPS
    gamma: float = 1.0
    max_distance_mm: float = 10.0
    max_normal_angle_deg: float = 60.0
    reject_boundary: bool = True
    convergence_mm: float = 0.02
    rigid_iterations: int = 10
    rigid_keep: float = 0.8
    similarity: bool = False
    cholesky: str = DEFAULT_CHOLESKY

    #: ``NicpSettings.from_config(section, source)``: from ``baselines.nicp.settings`` (gpja.settings);
    #: ``steps`` is a list of ``[stiffness, landmark_weight, max_iterations]`` or of mappings with those keys.
    from_config = classmethod(from_section)

    def __post_init__(self) -> None:
        if not self.steps:
            raise ValueError("NICP needs at least one step")
        if not (self.gamma >= 0 and self.max_distance_mm > 0 and 0 < self.max_normal_angle_deg <= 180
                and self.convergence_mm >= 0 and self.rigid_iterations >= 0 and 0 < self.rigid_keep <= 1):
            raise ValueError("need gamma >= 0, max_distance_mm > 0, max_normal_angle_deg in (0, 180], "
                             "convergence_mm >= 0, rigid_iterations >= 0, rigid_keep in (0, 1]")
        if self.cholesky not in CHOLESKY_BACKENDS:
            raise ValueError(f"cholesky must be one of {', '.join(CHOLESKY_BACKENDS)}, got {self.cholesky!r}")

    def to_dict(self) -> dict:
        return asdict(self)


# --- the registration ------------------------------------------------------------------------

def run_level(prob: AffineProblem, solver: AffineSolver, target: Surface, F: np.ndarray, step: NicpStep,
              settings: NicpSettings, X: np.ndarray, cur: np.ndarray, corr: tuple, timings: dict
              ) -> tuple[np.ndarray, np.ndarray, tuple, int, float]:
    """Alternate correspondences and solves at one stiffness until the vertices settle.

    Args:
        X: (4n, 3) current affine maps; cur: (n, 3) their positions, mm;
        corr: ``(U, valid, dist)`` correspondences of ``cur``.
    Returns:
        X, cur, the correspondences of the final ``cur``, iterations run, last mean move (mm).
    """
    its, moved = 0, float("nan")
    for its in range(1, step.max_iterations + 1):
        U, valid, _ = corr
        t = time.perf_counter()
        X = solve_affine(prob, solver, (U - prob.center) / prob.scale, prob.area * valid,
                         step.stiffness, step.landmark_weight, X)
        timings["solve"] += time.perf_counter() - t
        new = apply_affine(prob, X)
        moved = float(np.linalg.norm(new - cur, axis=1).mean())
        cur = new
        t = time.perf_counter()
        corr = find_correspondences(target, cur, vertex_normals(cur, F), settings)
        timings["closest_points"] += time.perf_counter() - t
        if moved < settings.convergence_mm:
            break
    return X, cur, corr, its, moved


def nicp(template: TexturedMesh, V_scan: np.ndarray, F_scan: np.ndarray, template_landmarks: np.ndarray,
         scan_landmarks: np.ndarray, settings: NicpSettings = NicpSettings(),
         progress: Callable[[str], None] = print, source: str | Path = "scan",
         landmark_source: str | Path = "scan landmarks") -> tuple[TexturedMesh, dict]:
    """Register ``template`` to a scan with landmark-guided optimal-step NICP.

    Args:
        template: the subject template (its F, UV, F_uv are kept exactly), positions mm.
        V_scan: (k, 3) float64 scan positions, mm, roughly in the template's frame.
        F_scan: (f, 3) int64 scan faces (open surfaces and holes are fine).
        template_landmarks: (L,) int vertex indices, or (L, 3) float64 positions
            in the template's frame, mm (see :func:`template_landmark_points`).
        scan_landmarks: (L, 3) float64 the same landmarks on the scan, mm.
        settings: schedule and rejection parameters.
        progress: called with one line for the rigid stage and one per stiffness level.
        source, landmark_source: name the scan and its landmarks in errors.
    Returns:
        The registered mesh (the template with new ``V``) and a JSON-able log.
    Raises:
        InputError: empty scan, NaN, a landmark count mismatch, landmarks off the scan.
    """
    t_start = time.perf_counter()
    V_scan = np.asarray(V_scan, dtype=np.float64)
    F_scan = np.asarray(F_scan, dtype=np.int64)
    TexturedMesh(V_scan, F_scan).validate(source)
    scan_landmarks = check_landmarks(scan_landmarks, None, landmark_source)
    landmarks = template_landmark_points(template, template_landmarks, "template landmarks")
    if len(landmarks) != len(scan_landmarks):
        raise InputError(landmark_source, f"{len(scan_landmarks)} landmarks, but the template has {len(landmarks)}")

    timings = {"closest_points": 0.0, "solve": 0.0}
    t = time.perf_counter()
    target = prepare_surface(V_scan, F_scan, find_boundary=settings.reject_boundary)
    check_landmarks_on_scan(target, scan_landmarks, landmark_source)
    timings["build_target"] = time.perf_counter() - t

    t = time.perf_counter()
    F = template.F
    cur, P, rigid = rigid_align(template.V, F, target, landmarks, scan_landmarks, settings)
    timings["rigid"] = time.perf_counter() - t
    icp_last = rigid["icp_mean_distance_mm"][-1] if rigid["icp_mean_distance_mm"] else float("nan")
    progress(f"nicp rigid: landmark error {rigid['landmark_error_mm']:.2f} mm, trimmed ICP mean distance "
             f"{icp_last:.2f} mm ({timings['rigid']:.1f} s)")

    prob = prepare_problem(cur, F, landmarks, P, scan_landmarks, settings.gamma)
    X = np.tile(np.eye(4, 3), (len(cur), 1))  # identity affine per vertex: x_i = v_i
    solver = AffineSolver(backend=settings.cholesky)
    corr = find_correspondences(target, cur, vertex_normals(cur, F), settings)
    steps_log = []
    for k, step in enumerate(settings.steps):
        t = time.perf_counter()
        X, cur, corr, its, moved = run_level(prob, solver, target, F, step, settings, X, cur, corr, timings)
        _, valid, dist = corr
        lm_err = np.linalg.norm((prob.DL @ X) * prob.scale + prob.center - scan_landmarks, axis=1)
        entry = {"stiffness": step.stiffness, "landmark_weight": step.landmark_weight, "iterations": its,
                 "last_move_mm": moved,
                 "mean_distance_mm": float(dist[valid].mean()) if valid.any() else float("nan"),
                 "matched_fraction": float(valid.mean()), "landmark_error_mm": float(lm_err.mean()),
                 "seconds": time.perf_counter() - t}
        steps_log.append(entry)
        progress(f"nicp step {k + 1}/{len(settings.steps)}: stiffness {step.stiffness:g}, landmark weight "
                 f"{step.landmark_weight:g}: {its} it, mean distance {entry['mean_distance_mm']:.3f} mm "
                 f"({100 * entry['matched_fraction']:.0f}% matched), landmark error "
                 f"{entry['landmark_error_mm']:.2f} mm, {entry['seconds']:.1f} s")
    timings["total"] = time.perf_counter() - t_start
    log_ = {"method": "nicp", "settings": settings.to_dict(), "vertices": len(cur), "scan_vertices": len(V_scan),
            "scan_faces": len(F_scan), "landmarks": len(landmarks), "rigid": rigid, "steps": steps_log,
            "solver": solver.stats, "seconds": timings}
    return template.with_vertices(cur), log_  # shares F, UV, F_uv (and the texture) with the template


# --- files -----------------------------------------------------------------------------------

#: The keys of the config's ``baselines.nicp`` section (:func:`run_baseline`).
SECTION_KEYS = ("enabled", "landmarks", "template_landmarks", "settings")


def run_baseline(template_dir: str | Path, source: DataSource, subject: str, expression: str, output: str | Path,
                 section: dict, template_expression: str = "3_mouth_stretch",
                 progress: Callable[[str], None] = print) -> dict:
    """The workflow's baseline entry point: register the subject's template to one expression scan with NICP.

    Every baseline of :data:`gpja.methods.METHODS` has this signature.

    Args:
        template_dir: the subject's template folder (template.obj, texture.png, ...).
        source: the dataset; its scans root (and ``Rt_scale_dict.json``) locate the expression's scan.
        output: the registered mesh's OBJ; its log goes next to it as ``.json``.
        section: the config's ``baselines.nicp`` mapping: ``landmarks`` (pattern of the scan landmark
            files), ``template_landmarks`` (pattern, or None), ``settings`` (:class:`NicpSettings`
            fields), ``enabled`` (not read here). See :func:`register_files`.
        template_expression: the expression the template was fitted to.
    Returns:
        The log written next to the OBJ.
    Raises:
        InputError: an unknown section key, a missing landmark pattern, bad settings, and
        everything :func:`register_files` rejects.
    """
    unknown = sorted(set(section) - set(SECTION_KEYS))
    if unknown:
        raise InputError("baselines.nicp", f"unknown key(s) {', '.join(unknown)}; known: {', '.join(SECTION_KEYS)}")
    if not section.get("landmarks"):
        raise InputError("baselines.nicp.landmarks", "NICP needs the pattern of the scan landmark files")
    settings = NicpSettings.from_config(section.get("settings"), "baselines.nicp.settings")
    return register_files(template_dir, source, subject, expression, output, section["landmarks"],
                          section.get("template_landmarks"), template_expression, settings, progress)


def register_files(template_dir: str | Path, source: DataSource, subject: str, expression: str,
                   out_obj: str | Path, landmarks: str | Path, template_landmarks: str | Path | None = None,
                   template_expression: str = "3_mouth_stretch", settings: NicpSettings = NicpSettings(),
                   progress: Callable[[str], None] = print) -> dict:
    """Register a subject's template to one expression scan with NICP; write OBJ + JSON log.

    Args:
        template_dir: the subject's template folder (template.obj, texture.png, ...).
        source: ``source.scan(subject, expression)`` is the scan in mm; ``source.transform`` moves the
            landmarks with it.
        out_obj: the registered mesh's OBJ; its log goes next to it as ``.json``.
        landmarks: pattern of the scan landmark files, with ``{subject}`` and
            ``{expression}`` placeholders (e.g. the synthetic ground truth
            ``.../ground_truth/{subject}/{expression}.npz``, or 68x3 JSON/TXT
            files of detected landmarks). Points are in the scan file's frame:
            the ``Rt_scale`` transform moves them with the scan.
        template_landmarks: pattern (``{subject}``) of a file of template landmark
            vertex indices or positions in the template's frame; None takes the
            ``landmarks`` file of ``template_expression`` (the expression the
            template was fitted to) and snaps it onto the template.
    Returns:
        The log written next to the OBJ.
    """
    subject = str(subject)
    template_dir = Path(template_dir)
    template, _ = read_template(template_dir)
    scan = source.scan(subject, expression)
    check_units(template, scan.V, scan.path)
    lm_path = fill_path_pattern(landmarks, subject, expression)
    scan_lm = transform_points(read_landmarks(lm_path), *source.transform(subject, expression))
    if template_landmarks is None:
        tl_path = fill_path_pattern(landmarks, subject, template_expression)
        tmpl_lm = transform_points(read_landmarks(tl_path), *source.transform(subject, template_expression))
    else:
        tl_path = fill_path_pattern(template_landmarks, subject, template_expression)
        tmpl_lm = read_template_landmarks(tl_path)
    if len(tmpl_lm) != len(scan_lm):
        raise InputError(lm_path, f"{len(scan_lm)} landmarks, but the template's landmark file {tl_path} has {len(tmpl_lm)}")
    try:
        mesh, log_ = nicp(template, scan.V, scan.F, tmpl_lm, scan_lm, settings, progress=progress,
                          source=scan.path, landmark_source=lm_path)
    except InputError as err:
        if err.path == "template landmarks":
            raise InputError(tl_path, err.problem) from None
        raise
    log_.update(subject=subject, expression=expression, template=str(template_dir / "template.obj"),
                scan=str(scan.path), landmarks_file=str(lm_path), template_landmarks_file=str(tl_path),
                rt_scale=None if source.rt_scale is None else str(source.rt_scale))
    texture_ref = os.path.relpath(template_dir / "texture.png", Path(out_obj).parent)
    write_registration(mesh, log_, out_obj, texture_ref)
    return log_
