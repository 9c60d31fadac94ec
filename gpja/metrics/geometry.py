"""Geometric scores of a registered mesh against its expression's raw scan, millimetres.

The paper (Experiments, "Metrics") scores geometric alignment against the raw
scan with the L1-Chamfer distance computed "via the point-mesh approach",
normal consistency, and F-scores at 0.5 mm and 1.0 mm. Here:

* scan -> mesh: every scan vertex to the registered mesh's *surface* (the
  paper's "point (of GT)-to-mesh" distance). Always all scan points: the scan
  is the ground truth, and a registration that misses part of it must pay.
* mesh -> scan: ``samples`` points drawn uniformly by area on the registered
  mesh (seeded) to the scan's surface, restricted by the coverage rule below.
  Sampling by area, not taking vertices, keeps the score independent of the
  mesh's vertex count and density (refinement adds vertices).
* L1-Chamfer = mean of the two directions' mean (unsquared) distances.
* Normal consistency (N.C.): mean ``|n . n'|`` at the closest points, per
  direction, then the mean of the two. A sample takes its triangle's normal,
  a scan vertex its area-weighted vertex normal; ``n'`` is the normal of the
  triangle hit on the other mesh. Points whose normal is undefined (isolated
  scan vertices, degenerate triangles hit) are left out of N.C. only.
* F-score at ``tau``: precision = fraction of (covered) mesh samples within
  ``tau`` of the scan, recall = fraction of scan points within ``tau`` of the
  mesh, F = 2PR / (P + R), 0 when both are 0.

Coverage rule (mesh -> scan only). The registered mesh is a closed bust; the
scan is a multiview-stereo surface with holes and a cropped neck, scalp and
back of head. A mesh point over a hole has its closest scan point on the
hole's rim, at whatever distance the hole's size dictates: counting it would
score the scan's missing data, not the registration. Rules:

* ``"boundary"`` (default): a sample counts only if its closest scan point is
  not on the scan's boundary (an open edge or a vertex on one) *and* it lies
  within ``max_distance_mm`` of the scan. The boundary test removes mesh
  regions over holes and beyond the crop, however far they reach; the cap
  removes mesh regions facing scan data that is not their counterpart (the
  closed bust's mouth cavity or the back of the ears facing the scan's lips
  or cheek from behind).
* ``"distance"``: only the cap. ``"none"``: every sample counts.

The cap's default, 5 mm, is 5-10x the F-score thresholds: errors up to it are
graded in full, and F@1.0 already counts everything above 1 mm as wrong, so a
larger cap would only let no-data regions dominate the mean. Errors beyond the
cap are not hidden: the scan -> mesh direction uses every scan point with no
cap, and the excluded fraction is reported so a method cannot gain by leaving
the scan.

Closest points and the scan's rim follow :mod:`gpja.surface` (Open3D's
float32 BVH about the scan's bounding-box centre, distances in float64; the
rim after welding coincident vertices), the convention every module shares.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from gpja.data.source import read_scan_mm
from gpja.data.units import check_head_units, check_units
from gpja.errors import InputError
from gpja.io import write_npz
from gpja.mesh import TexturedMesh, read_obj
from gpja.surface import ClosestPoints, bounding_box_centre, closest_points, prepare_surface, vertex_normals

#: Points sampled on the registered mesh for the mesh -> scan direction: at
#: 200K the sampling noise of a mean distance is ~0.2 % (well below the
#: differences the paper's tables resolve) and the query stays well inside the
#: 3 s budget (benchmarks/bench_metrics_geometry.py).
DEFAULT_SAMPLES = 200_000
DEFAULT_SEED = 0
#: F-score thresholds of the paper, mm.
DEFAULT_THRESHOLDS_MM = (0.5, 1.0)
#: Distance cap of the coverage rule, mm (see the module docstring).
DEFAULT_MAX_DISTANCE_MM = 5.0
COVERAGE_RULES = ("boundary", "distance", "none")


# --- sampling, coverage, scores -----------------------------------------------------------

def sample_surface(V: np.ndarray, F: np.ndarray, count: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Points uniformly distributed by area on a triangle mesh.

    Args:
        V: (n, 3) float64 mm; F: (m, 3) int64; count: number of points; seed: RNG seed.
    Returns:
        points: (count, 3) float64 mm; face: (count,) int64 triangle of each point.
    """
    rng = np.random.default_rng(seed)
    tri = V[F]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    cdf = np.cumsum(area)
    # side="right" never lands on a zero-area face (its cdf step is empty)
    face = np.minimum(np.searchsorted(cdf, rng.random(count) * cdf[-1], side="right"), len(F) - 1)
    r1, r2 = rng.random((2, count))
    s = np.sqrt(r1)  # the square root makes the density uniform over the triangle
    w = np.column_stack([1.0 - s, s * (1.0 - r2), s * r2])
    points = np.einsum("qk,qkc->qc", w, tri[face])
    return points, face


def coverage_mask(cp: ClosestPoints, rule: str, max_distance_mm: float) -> np.ndarray:
    """(q,) bool: which mesh points count in the mesh -> scan direction (module docstring)."""
    if rule == "none":
        return np.ones(len(cp.distance), dtype=bool)
    near = cp.distance <= max_distance_mm
    return near & ~cp.on_boundary if rule == "boundary" else near


def normal_agreement(n_query: np.ndarray, n_hit: np.ndarray) -> np.ndarray:
    """``|n . n'|`` of paired unit normals (q, 3); NaN where either is undefined (zero)."""
    dot = np.abs(np.einsum("qc,qc->q", n_query, n_hit))
    defined = (np.einsum("qc,qc->q", n_query, n_query) > 0.5) & (np.einsum("qc,qc->q", n_hit, n_hit) > 0.5)
    return np.where(defined, dot, np.nan)


def f_score(precision: float, recall: float) -> float:
    """Harmonic mean of precision and recall; 0 when both are 0."""
    return 0.0 if precision + recall == 0 else 2.0 * precision * recall / (precision + recall)


def threshold_key(tau: float) -> str:
    """JSON key of a threshold in mm: 0.5 -> "0.5", 1.0 -> "1"."""
    return f"{tau:g}"


# --- results ------------------------------------------------------------------------------

@dataclass
class VertexErrors:
    """Per-vertex distances for heatmap figures.

    Attributes:
        mesh_vertex_error_mm: (n,) float64 distance of each registered-mesh
            vertex to the scan surface, NaN where the coverage rule excludes it.
        mesh_vertex_covered: (n,) bool, the vertex passes the coverage rule.
        scan_vertex_error_mm: (n_scan,) float64 distance of each scan vertex to
            the registered mesh surface.
    """

    mesh_vertex_error_mm: np.ndarray
    mesh_vertex_covered: np.ndarray
    scan_vertex_error_mm: np.ndarray

    def save(self, path: str | Path) -> None:
        """Write the three arrays to a compressed ``.npz`` atomically."""
        write_npz(path, mesh_vertex_error_mm=self.mesh_vertex_error_mm,
                  mesh_vertex_covered=self.mesh_vertex_covered, scan_vertex_error_mm=self.scan_vertex_error_mm)


@dataclass
class GeometryMetrics:
    """Geometric scores of one registered mesh (module docstring for definitions).

    Attributes:
        chamfer_l1_mm: mean of ``mesh_to_scan_mm`` and ``scan_to_mesh_mm``.
        mesh_to_scan_mm: mean distance of covered mesh samples to the scan.
        scan_to_mesh_mm: mean distance of scan vertices to the mesh.
        normal_consistency: mean of the two directions' N.C. (1 = parallel).
        fscore, precision, recall: per threshold, keyed by ``threshold_key``.
        coverage: the rule used; max_distance_mm: its cap.
        excluded_fraction: fraction of mesh samples the rule left out.
        errors: per-vertex arrays (not part of the JSON).
        timings_s: seconds per stage (not part of the JSON: it is not reproducible).
    """

    chamfer_l1_mm: float
    mesh_to_scan_mm: float
    scan_to_mesh_mm: float
    normal_consistency: float
    normal_consistency_mesh_to_scan: float
    normal_consistency_scan_to_mesh: float
    fscore: dict[str, float]
    precision: dict[str, float]
    recall: dict[str, float]
    coverage: str
    max_distance_mm: float
    excluded_fraction: float
    samples: int
    samples_used: int
    seed: int
    scan_points: int
    mesh_vertices: int
    mesh_faces: int
    scan_faces: int
    errors: VertexErrors = field(repr=False)
    timings_s: dict[str, float] = field(default_factory=dict, repr=False)

    def to_json(self) -> dict:
        """The scores as a JSON-serialisable dict (Python floats and ints)."""
        out = {}
        for name in self.__dataclass_fields__:
            if name in ("errors", "timings_s"):
                continue
            value = getattr(self, name)
            out[name] = {k: float(v) for k, v in value.items()} if isinstance(value, dict) else value
        return out


# --- evaluation ---------------------------------------------------------------------------

def check_options(samples: int, thresholds, coverage: str, max_distance_mm: float) -> None:
    """Raise :class:`InputError` (source ``config``) on unusable metric settings."""
    if int(samples) < 1:
        raise InputError("config", f"metrics: samples must be at least 1 (got {samples})")
    if len(thresholds) == 0 or any(not np.isfinite(t) or t <= 0 for t in thresholds):
        raise InputError("config", f"metrics: F-score thresholds must be positive mm values (got {list(thresholds)})")
    if coverage not in COVERAGE_RULES:
        raise InputError("config", f"metrics: coverage must be one of {', '.join(COVERAGE_RULES)} (got {coverage!r})")
    if not np.isfinite(max_distance_mm) or max_distance_mm <= 0:
        raise InputError("config", f"metrics: max_distance_mm must be a positive number (got {max_distance_mm})")


def evaluate_geometry(V: np.ndarray, F: np.ndarray, V_scan: np.ndarray, F_scan: np.ndarray, *,
                      samples: int = DEFAULT_SAMPLES, seed: int = DEFAULT_SEED,
                      thresholds: tuple[float, ...] = DEFAULT_THRESHOLDS_MM, coverage: str = "boundary",
                      max_distance_mm: float = DEFAULT_MAX_DISTANCE_MM,
                      mesh_source: str | Path = "registered mesh", scan_source: str | Path = "scan") -> GeometryMetrics:
    """Score a registered mesh against a scan (both in the same frame, mm).

    Args:
        V: (n, 3) float64 registered-mesh positions, mm; F: (m, 3) int64 faces.
        V_scan: (n_scan, 3) float64 scan positions, mm; F_scan: (m_scan, 3) int64.
        samples: points sampled on the registered mesh; seed: their RNG seed.
        thresholds: F-score thresholds, mm.
        coverage: ``"boundary"``, ``"distance"`` or ``"none"`` (module docstring).
        max_distance_mm: the coverage rule's distance cap, mm.
        mesh_source, scan_source: names used in error messages (the files).
    Raises:
        InputError: empty meshes, NaN/inf positions, bad face indices, sizes
        that differ by more than the unit check allows, a mesh with no area or
        with no point where the scan has data, or bad options.
    """
    check_options(samples, thresholds, coverage, max_distance_mm)
    mesh = TexturedMesh(V, F).validate(mesh_source)
    scan = TexturedMesh(V_scan, F_scan).validate(scan_source)
    check_units(mesh, scan.V, scan_source)
    timings = {}

    t = time.perf_counter()
    origin = bounding_box_centre(scan.V)  # one origin for both: the float32 queries share one frame
    scan_surface = prepare_surface(scan.V, scan.F, origin)
    mesh_surface = prepare_surface(mesh.V, mesh.F, origin, find_boundary=False)  # only the scan's rim matters
    timings["scene_build"] = time.perf_counter() - t

    t = time.perf_counter()
    if not np.any(mesh_surface.face_normals.any(axis=1)):
        raise InputError(mesh_source, "the mesh has zero surface area (every triangle is degenerate)")
    points, sample_face = sample_surface(mesh.V, mesh.F, int(samples), seed)
    timings["sampling"] = time.perf_counter() - t

    t = time.perf_counter()
    # samples and vertices in one query: one pass over the BVH instead of two
    to_scan = closest_points(scan_surface, np.concatenate([points, mesh.V]))
    timings["mesh_to_scan"] = time.perf_counter() - t
    t = time.perf_counter()
    to_mesh = closest_points(mesh_surface, scan.V)
    timings["scan_to_mesh"] = time.perf_counter() - t

    t = time.perf_counter()
    covered_all = coverage_mask(to_scan, coverage, max_distance_mm)
    covered, vertex_covered = covered_all[: len(points)], covered_all[len(points):]
    if not covered.any():
        raise InputError(mesh_source, f"no point of the mesh lies where the scan has data (coverage rule {coverage!r}, "
                                      f"cap {max_distance_mm:g} mm): is it in the scan's frame?")
    d_mesh = to_scan.distance[: len(points)][covered]
    d_scan = to_mesh.distance
    nc_mesh = normal_agreement(mesh_surface.face_normals[sample_face[covered]],
                               scan_surface.face_normals[to_scan.face[: len(points)][covered]])
    nc_scan = normal_agreement(vertex_normals(scan.V, scan.F), mesh_surface.face_normals[to_mesh.face])
    precision = {threshold_key(tau): float(np.mean(d_mesh <= tau)) for tau in thresholds}
    recall = {threshold_key(tau): float(np.mean(d_scan <= tau)) for tau in thresholds}
    errors = VertexErrors(np.where(vertex_covered, to_scan.distance[len(points):], np.nan), vertex_covered, d_scan)
    timings["scores"] = time.perf_counter() - t
    mesh_to_scan, scan_to_mesh = float(d_mesh.mean()), float(d_scan.mean())
    nc_mesh_mean, nc_scan_mean = float(np.nanmean(nc_mesh)), float(np.nanmean(nc_scan))
    return GeometryMetrics(
        chamfer_l1_mm=0.5 * (mesh_to_scan + scan_to_mesh), mesh_to_scan_mm=mesh_to_scan, scan_to_mesh_mm=scan_to_mesh,
        normal_consistency=0.5 * (nc_mesh_mean + nc_scan_mean),
        normal_consistency_mesh_to_scan=nc_mesh_mean, normal_consistency_scan_to_mesh=nc_scan_mean,
        fscore={k: f_score(precision[k], recall[k]) for k in precision}, precision=precision, recall=recall,
        coverage=coverage, max_distance_mm=float(max_distance_mm), excluded_fraction=float(1.0 - covered.mean()),
        samples=int(samples), samples_used=int(covered.sum()), seed=int(seed), scan_points=len(scan.V),
        mesh_vertices=len(mesh.V), mesh_faces=len(mesh.F), scan_faces=len(scan.F),
        errors=errors, timings_s=timings)


def evaluate_geometry_files(mesh_path: str | Path, scan_path: str | Path, *, rt_scale: str | Path | None = None,
                            subject: str | None = None, expression: str | None = None,
                            errors_path: str | Path | None = None, **options) -> dict:
    """Score a registered mesh file against a scan file; optionally save per-vertex errors.

    Args:
        mesh_path: registered mesh OBJ (mm, aligned frame).
        scan_path: scan PLY; with ``rt_scale`` (FaceScape's ``Rt_scale_dict.json``)
            it is brought into the aligned mm frame by the entry of
            ``subject``/``expression``, which are then required.
        errors_path: where to write :class:`VertexErrors` (``.npz``), or None.
        options: keyword options of :func:`evaluate_geometry`.
    Returns:
        ``GeometryMetrics.to_json()`` plus the file names, subject and expression.
    Raises:
        InputError: missing/corrupt files, NaN or empty meshes, units that are
        not mm, and everything :func:`evaluate_geometry` rejects.
    """
    mesh = read_obj(mesh_path, load_texture=False)
    check_head_units(mesh.V, mesh_path)
    if rt_scale is not None and (subject is None or expression is None):
        raise InputError(rt_scale, "subject and expression are needed to look up the scan's Rt_scale entry")
    scan = read_scan_mm(scan_path, subject, expression, rt_scale)
    metrics = evaluate_geometry(mesh.V, mesh.F, scan.V, scan.F, mesh_source=mesh_path, scan_source=scan_path, **options)
    if errors_path is not None:
        metrics.errors.save(errors_path)
    out = {"mesh": str(mesh_path), "scan": str(scan_path), "subject": subject, "expression": expression}
    out.update(metrics.to_json())
    out["errors"] = None if errors_path is None else str(errors_path)
    return out
