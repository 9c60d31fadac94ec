"""Dense correspondence error on synthetic data, where the ground truth is exact.

Geometric scores cannot see a registration that lies on the scan but slides
along it; the synthetic benchmark can. For every expression ``e`` it stores
``scan_rest_coords``: the rest-space (material) coordinate, mm, of every vertex
of that expression's scan (``{ground_truth_root}/{subject}/{e}.npz``).
Registered meshes keep the template's vertices first and in order (refinement
appends new ones), so vertex ``i < n_template`` of a registered mesh and
template vertex ``i`` are meant to be the same material point.

For each such ``i``:

* ``m_reg(i)``: project the registered vertex onto the expression's scan
  (closest point), interpolate that scan's rest coordinates there;
* ``m_tpl(i)``: the same for the template vertex and the scan of the
  template's expression (``3_mouth_stretch``, the one the template was fitted to);
* error ``|m_reg(i) - m_tpl(i)|``, mm in rest space.

A vertex counts only where both projections are meaningful: within
``max_distance_mm`` of the scan and with its closest point not on the scan's
boundary, in *both* expressions. Off the scan (scalp, back of the head, below
the neck cut, over holes) the closest point is the rim of the scan, whose
material coordinate has nothing to do with the vertex. The cap's default,
2 mm, is 2-4x the F-score thresholds the geometric scores grade, so vertices of
any acceptable registration are kept; beyond it, the foot point stops standing
for "the material point this vertex represents" (on a lip or a nostril, whose
radius of curvature is a few mm, the projection from farther away can land on
the other side). The fraction of vertices used is reported with the scores.

The score above looks from the registered mesh's side, so a vertex that left the scan is dropped, not
counted: a lower lip tucked 10 mm inside a closed mouth, behind a visible lip made of other vertices,
never shows in it. The **position error** looks from the ground truth's side. For each usable template
vertex (same cap as above), it takes the vertex's material ``m_tpl(i)``, finds that material on the
registered expression's scan (the closest point of ``m_tpl(i)`` on the scan's rest-space surface,
``rest_expr`` on the scan's faces), and measures the distance, mm in expression space, from the
registered vertex to the point where the expression put that material. Material that is more than
:data:`PRESENT_MM` from the expression's rest-space scan is not visible in that expression (the inside
of a closed mouth, an eyeball under a closed lid), so it is not scored. The registered side has no cap,
so a vertex is never dropped because it ended up far from the scan. The position error is reported as
``position`` with the same statistics and regions as the main score.

The **floor** is the lower bound of a registration's score. Vertex ``i``'s floor is the rest-space
distance from ``m_tpl(i)`` to the expression's rest-space scan: 0 for material the expression shows, and
for hidden material (an eyeball under a closed lid, the inner lips of a closed mouth) the distance to the
nearest material that is shown. Its registered error can never be smaller (``m_reg(i)`` lies on that
surface), wherever the vertex lands. The statistics ``floor`` are taken over the same vertices as the
score (and by the same regions), so none of the score's statistics can be below the floor's: what is
left above it is what the registration could still win. The floor differs between methods only by which
vertices each keeps on the scan: a method that leaves the hidden eyeball off the scan is not scored on it
(S01 ``18_eye_closed``: GPJA keeps 57 of the eye region's 72 usable vertices on the scan, 63% of them
hidden material, floor median 1.84 mm; NICP keeps 27, 22% hidden, floor median 0).

By region: where the ground truth has the rest landmarks (``landmarks_rest``), every used vertex
is labelled by the facial region of ``m_tpl(i)`` (:mod:`gpja.metrics.regions`: mouth, eyes, nose,
brows, the rest of the face, ears/scalp/neck), and the scores gain ``regions.{region}.{median_mm,
mean_mm, p95_mm, count}``. The labels are defined in rest space, so a vertex keeps its region in
every expression, and they come from where the template vertex *is* (on the template expression's
scan), not from where a method moved it.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from gpja.data.source import DataSource
from gpja.data.units import check_units
from gpja.errors import InputError
from gpja.io import read_npz, write_npz
from gpja.mesh import TexturedMesh, check_vertex_prefix, read_obj
from gpja.metrics.regions import REGIONS, UNLABELLED, check_landmarks, label_regions, region_statistics
from gpja.surface import Surface, interpolate, prepare_surface

#: The expression the synthetic subject's template was fitted to (DESIGN.md).
TEMPLATE_EXPRESSION = "3_mouth_stretch"
#: Distance cap of a usable projection onto the scan, mm (module docstring).
DEFAULT_MAX_DISTANCE_MM = 2.0
#: A template vertex's material counts as present in an expression when it lies within this of that expression's
#: scan in rest space, mm (the position error; module docstring): the scans' rest coordinates are exact, so this
#: only has to absorb the interpolation across a scan triangle.
PRESENT_MM = 0.5
#: The ground-truth array of rest coordinates in each expression's ``.npz``.
REST_COORDS_KEY = "scan_rest_coords"
#: The ground-truth array of the 68 rest-space landmarks (the same in every expression's ``.npz``).
LANDMARKS_REST_KEY = "landmarks_rest"


def check_rest_coords(rest: np.ndarray, n_scan_vertices: int, source: str | Path) -> np.ndarray:
    """Return ``rest`` as (n, 3) float64 after checking it matches its scan; raise :class:`InputError` if not."""
    rest = np.asarray(rest, dtype=np.float64)
    if rest.ndim != 2 or rest.shape[1] != 3 or len(rest) != n_scan_vertices:
        raise InputError(source, f"{REST_COORDS_KEY} has shape {rest.shape}, expected ({n_scan_vertices}, 3): "
                                 "one rest coordinate per scan vertex (ground truth of another scan?)")
    if not np.isfinite(rest).all():
        raise InputError(source, f"{REST_COORDS_KEY} contains NaN or infinite values")
    return rest


def check_finite(V: np.ndarray, source: str | Path) -> np.ndarray:
    """Return ``V`` as (n, 3) float64; raise :class:`InputError` on NaN or infinite rows."""
    V = np.asarray(V, dtype=np.float64).reshape(-1, 3)
    bad = ~np.isfinite(V).all(axis=1)
    if bad.any():
        raise InputError(source, f"{int(bad.sum())} vertices have NaN or infinite coordinates")
    return V


def material_coordinates(points: np.ndarray, scan: tuple[np.ndarray, np.ndarray] | Surface, rest: np.ndarray,
                         max_distance_mm: float) -> tuple[np.ndarray, np.ndarray]:
    """Rest-space coordinates of points projected onto a scan.

    Args:
        points: (q, 3) float64 positions in the scan's expression space, mm.
        scan: (V (n, 3) float64 mm, F (m, 3) int64) of the scan, or its :func:`gpja.surface.prepare_surface`.
        rest: (n, 3) float64 rest coordinate of every scan vertex, mm.
        max_distance_mm: projections farther than this are unusable.
    Returns:
        coords: (q, 3) float64 interpolated rest coordinates, mm.
        usable: (q,) bool, within the cap and not projected onto the scan's boundary.
    """
    surface = scan if isinstance(scan, Surface) else prepare_surface(*scan)  # about the scan's bounding-box centre
    cp = surface.closest(points)
    coords = interpolate(surface, cp, rest)
    return coords, (cp.distance <= max_distance_mm) & ~cp.on_boundary


@dataclass(frozen=True)
class CorrespondenceReference:
    """The side of the correspondence error that does not depend on the registered mesh: the template's material
    (``m_tpl``, where the expression puts it, the floor) and the expression's prepared scan. Made once by
    :func:`correspondence_reference`, it scores any number of meshes of that expression (``gpja stages`` scores
    every stage of a registration: building it once per stage was two thirds of the job).

    Attributes:
        V_template: (n_template, 3) float64 template positions, mm.
        scan_expr: the registered expression's scan, prepared (:func:`gpja.surface.prepare_surface`).
        rest_expr: (n_scan_expr, 3) float64 rest coordinates of its vertices, mm.
        m_tpl, usable_tpl: :func:`material_coordinates` of the template vertices on the template expression's scan.
        truth, present, hidden_mm: :func:`material_positions` of ``m_tpl`` on the registered expression's scan.
        labels: (n_template,) int8 region of each usable template vertex (``UNLABELLED`` elsewhere), or None
            without landmarks.
        max_distance_mm: projection cap (module docstring).
    """

    V_template: np.ndarray
    scan_expr: Surface
    rest_expr: np.ndarray
    m_tpl: np.ndarray
    usable_tpl: np.ndarray
    truth: np.ndarray
    present: np.ndarray
    hidden_mm: np.ndarray
    labels: np.ndarray | None
    max_distance_mm: float


def correspondence_reference(V_template: np.ndarray, scan_expr: tuple[np.ndarray, np.ndarray], rest_expr: np.ndarray,
                             scan_tpl: tuple[np.ndarray, np.ndarray], rest_tpl: np.ndarray, *,
                             max_distance_mm: float = DEFAULT_MAX_DISTANCE_MM,
                             landmarks_rest: np.ndarray | None = None) -> CorrespondenceReference:
    """The :class:`CorrespondenceReference` of one expression; arguments as :func:`correspondence_error`'s.

    Raises:
        InputError: a bad cap, NaN template positions, rest coordinates that do not match their scan.
    """
    if not np.isfinite(max_distance_mm) or max_distance_mm <= 0:
        raise InputError("config", f"metrics: max_distance_mm must be a positive number (got {max_distance_mm})")
    V_template = check_finite(V_template, "template")
    rest_expr = check_rest_coords(rest_expr, len(scan_expr[0]), "ground truth of the registered expression")
    rest_tpl = check_rest_coords(rest_tpl, len(scan_tpl[0]), "ground truth of the template expression")
    m_tpl, usable_tpl = material_coordinates(V_template, scan_tpl, rest_tpl, max_distance_mm)
    truth, present, hidden_mm = material_positions(m_tpl, scan_expr, rest_expr)
    labels = None
    if landmarks_rest is not None:
        labels = np.full(len(V_template), UNLABELLED, dtype=np.int8)
        labels[usable_tpl] = label_regions(m_tpl[usable_tpl], landmarks_rest)
    return CorrespondenceReference(V_template, prepare_surface(*scan_expr), rest_expr, m_tpl, usable_tpl, truth,
                                   present, hidden_mm, labels, float(max_distance_mm))


def correspondence_error(V_reg: np.ndarray, V_template: np.ndarray,
                         scan_expr: tuple[np.ndarray, np.ndarray], rest_expr: np.ndarray,
                         scan_tpl: tuple[np.ndarray, np.ndarray], rest_tpl: np.ndarray, *,
                         max_distance_mm: float = DEFAULT_MAX_DISTANCE_MM,
                         mesh_source: str | Path = "registered mesh",
                         landmarks_rest: np.ndarray | None = None) -> dict:
    """Rest-space distance between what registered and template vertices stand for.

    Args:
        V_reg: (n_reg, 3) float64 registered-mesh positions, mm; n_reg >= n_template.
        V_template: (n_template, 3) float64 template positions, mm.
        scan_expr: (V, F) of the registered expression's scan, mm / int64.
        rest_expr: (n_scan_expr, 3) float64 rest coordinates of its vertices, mm.
        scan_tpl, rest_tpl: the same for the template's expression.
        max_distance_mm: projection cap (module docstring).
        mesh_source: name of the registered mesh in error messages.
        landmarks_rest: (68, 3) float64 rest-space landmarks, mm, or None: the per-region scores.
    Returns:
        dict: ``mean_mm``, ``median_mm``, ``p95_mm``, ``max_mm`` over used
        vertices; ``n_used``, ``n_template_vertices``, ``fraction_used``,
        ``max_distance_mm``; ``vertex_error_mm`` (n_template,) float64, NaN
        where unused; ``vertex_used`` (n_template,) bool; with landmarks, ``regions``
        (:func:`gpja.metrics.regions.region_statistics`) and ``vertex_region`` (n_template,) int8
        (index into :data:`gpja.metrics.regions.REGIONS`, ``UNLABELLED`` where unused); ``position``, the
        position error (module docstring): ``mean_mm``, ``median_mm``, ``p95_mm``, ``max_mm``, ``n_used``,
        ``fraction_used``, ``present_mm`` and with landmarks ``regions``; ``vertex_position_error_mm``
        (n_template,) float64, NaN where the template vertex is unusable or its material is not present;
        ``floor``, the score's lower bound (module docstring): ``mean_mm``, ``median_mm``, ``p95_mm``, ``max_mm``,
        ``n_used``, ``fraction_used`` over the scored vertices and with landmarks ``regions`` (by the score's
        labels); ``vertex_floor_mm`` (n_template,) float64 for every usable template vertex (NaN elsewhere):
        every scored vertex's ``vertex_error_mm`` is at least its floor.
    Raises:
        InputError: fewer registered vertices than template vertices, NaN
        positions, rest coordinates that do not match their scan, or no vertex
        usable in both expressions.
    """
    reference = correspondence_reference(V_template, scan_expr, rest_expr, scan_tpl, rest_tpl,
                                         max_distance_mm=max_distance_mm, landmarks_rest=landmarks_rest)
    return score_correspondence(V_reg, reference, mesh_source)


def score_correspondence(V_reg: np.ndarray, reference: CorrespondenceReference,
                         mesh_source: str | Path = "registered mesh") -> dict:
    """:func:`correspondence_error` of ``V_reg`` (n_reg, 3) float64 mm against a prepared ``reference``."""
    r = reference
    V_reg = check_finite(V_reg, mesh_source)
    n_template = len(r.V_template)
    check_vertex_prefix(len(V_reg), n_template, mesh_source)
    m_reg, usable_reg = material_coordinates(V_reg[:n_template], r.scan_expr, r.rest_expr, r.max_distance_mm)
    used = usable_reg & r.usable_tpl
    if not used.any():
        raise InputError(mesh_source, f"no template vertex lies within {r.max_distance_mm:g} mm of both scans "
                                      "(away from their boundaries): is the mesh in the scan's frame?")
    error = np.where(used, np.linalg.norm(m_reg - r.m_tpl, axis=1), np.nan)
    out = summarise(error, used)
    out.update(n_template_vertices=n_template, max_distance_mm=r.max_distance_mm,
               vertex_error_mm=error, vertex_used=used)
    floor = np.where(r.usable_tpl, r.hidden_mm, np.nan)
    out["floor"] = summarise(floor, used)
    out["vertex_floor_mm"] = floor
    placed = r.usable_tpl & r.present
    position = np.where(placed, np.linalg.norm(V_reg[:n_template] - r.truth, axis=1), np.nan)
    out["position"] = {**summarise(position, placed), "present_mm": PRESENT_MM}
    out["vertex_position_error_mm"] = position
    if r.labels is not None:
        regions = np.where(used, r.labels, UNLABELLED).astype(np.int8)
        out.update(regions=region_statistics(error, regions), vertex_region=regions)
        out["position"]["regions"] = region_statistics(position, np.where(placed, r.labels, UNLABELLED))
        out["floor"]["regions"] = region_statistics(floor, regions)
    return out


def summarise(error: np.ndarray, used: np.ndarray) -> dict:
    """``mean_mm``, ``median_mm``, ``p95_mm``, ``max_mm`` of ``error[used]`` (None when nothing is used),
    ``n_used`` and ``fraction_used``."""
    e = error[used]
    stats = ((float(e.mean()), float(np.median(e)), float(np.percentile(e, 95)), float(e.max())) if e.size
             else (None,) * 4)
    return {**dict(zip(("mean_mm", "median_mm", "p95_mm", "max_mm"), stats)), "n_used": int(used.sum()),
            "fraction_used": float(used.mean())}


def material_positions(material: np.ndarray, scan: tuple[np.ndarray, np.ndarray], rest: np.ndarray,
                       present_mm: float = PRESENT_MM) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Where an expression's scan puts rest-space material points: the inverse of :func:`material_coordinates`.

    Args:
        material: (q, 3) float64 rest-space points, mm.
        scan: (V (n, 3) float64 mm, F (m, 3) int64) of the expression's scan.
        rest: (n, 3) float64 rest coordinate of every scan vertex, mm.
        present_mm: material farther than this from the scan's rest-space surface is not present (hidden).
    Returns:
        positions: (q, 3) float64 expression-space points, mm; present: (q,) bool, the material lies on the
        scan in rest space (within ``present_mm``, not at its boundary); hidden_mm: (q,) float64 the rest-space
        distance, mm, from each material point to the nearest material the scan shows (0 where it shows it).
    """
    rest_surface = prepare_surface(rest, scan[1])
    cp = rest_surface.closest(material)
    return (interpolate(rest_surface, cp, scan[0]), (cp.distance <= present_mm) & ~cp.on_boundary,
            np.asarray(cp.distance, dtype=np.float64))


def ground_truth_path(ground_truth_root: str | Path, subject: str, expression: str) -> Path:
    """``{ground_truth_root}/{subject}/{expression}.npz``."""
    return Path(ground_truth_root) / str(subject) / f"{expression}.npz"


def read_rest_coords(ground_truth_root: str | Path, subject: str, expression: str, n_scan_vertices: int) -> np.ndarray:
    """(n_scan_vertices, 3) float64 rest coordinates of an expression's scan vertices, mm."""
    path = ground_truth_path(ground_truth_root, subject, expression)
    arrays = read_npz(path)
    if REST_COORDS_KEY not in arrays:
        raise InputError(path, f"no {REST_COORDS_KEY!r} array (has: {', '.join(sorted(arrays)) or 'nothing'})")
    return check_rest_coords(arrays[REST_COORDS_KEY], n_scan_vertices, path)


def read_landmarks_rest(ground_truth_root: str | Path, subject: str, expression: str) -> np.ndarray | None:
    """(68, 3) float64 rest-space landmarks of an expression's ground truth, mm; None when it has none."""
    path = ground_truth_path(ground_truth_root, subject, expression)
    arrays = read_npz(path)
    return check_landmarks(arrays[LANDMARKS_REST_KEY], path) if LANDMARKS_REST_KEY in arrays else None


def correspondence_error_files(mesh_path: str | Path, template_path: str | Path, scans_root: str | Path,
                               ground_truth_root: str | Path, subject: str, expression: str,
                               template_expression: str = TEMPLATE_EXPRESSION,
                               errors_path: str | Path | None = None, *,
                               max_distance_mm: float = DEFAULT_MAX_DISTANCE_MM) -> dict:
    """Correspondence error of a registered mesh file against the synthetic ground truth.

    Args:
        mesh_path: registered mesh OBJ of ``subject``/``expression`` (mm).
        template_path: the subject's template OBJ (fitted to ``template_expression``).
        scans_root: ``{scans_root}/{subject}/{expression}.ply`` (synthetic: already mm).
        ground_truth_root: ``{ground_truth_root}/{subject}/{expression}.npz``.
        errors_path: where to write ``vertex_error_mm``, ``vertex_used``, ``vertex_position_error_mm`` and
            ``vertex_floor_mm`` (``.npz``; with the template expression's ``landmarks_rest`` also ``vertex_region`` and
            ``region_names``), or None.
        max_distance_mm: projection cap (module docstring).
    Returns:
        the scores of :func:`correspondence_error` without its arrays (``regions`` when the
        template expression's ground truth has ``landmarks_rest``), plus the file names, subject and
        expressions (JSON-serialisable).
    Raises:
        InputError: missing or corrupt files, a ground truth whose row count is
        not its scan's vertex count, a mesh with fewer vertices than the template.
    """
    mesh = read_obj(mesh_path, load_texture=False)
    template = read_obj(template_path, load_texture=False)
    check_vertex_prefix(len(mesh.V), len(template.V), mesh_path)
    scans = DataSource(scans_root=scans_root)  # synthetic scans are in mm already: no Rt_scale
    scan_e = scans.scan(subject, expression)
    scan_t = scan_e if template_expression == expression else scans.scan(subject, template_expression)
    check_units(template, scan_t.V, scan_t.path)
    check_units(TexturedMesh(mesh.V, mesh.F), scan_e.V, scan_e.path)
    rest_e = read_rest_coords(ground_truth_root, subject, expression, len(scan_e.V))
    rest_t = read_rest_coords(ground_truth_root, subject, template_expression, len(scan_t.V))
    landmarks = read_landmarks_rest(ground_truth_root, subject, template_expression)
    result = correspondence_error(mesh.V, template.V, (scan_e.V, scan_e.F), rest_e, (scan_t.V, scan_t.F), rest_t,
                                  max_distance_mm=max_distance_mm, mesh_source=mesh_path, landmarks_rest=landmarks)
    if errors_path is not None:
        labels = {} if landmarks is None else {"vertex_region": result["vertex_region"],
                                               "region_names": np.array(REGIONS)}
        write_npz(errors_path, vertex_error_mm=result["vertex_error_mm"], vertex_used=result["vertex_used"],
                  vertex_position_error_mm=result["vertex_position_error_mm"],
                  vertex_floor_mm=result["vertex_floor_mm"], **labels)
    out = {"mesh": str(mesh_path), "template": str(template_path), "subject": str(subject),
           "expression": expression, "template_expression": template_expression}
    out.update({k: v for k, v in result.items() if not isinstance(v, np.ndarray)})
    out["errors"] = None if errors_path is None else str(errors_path)
    return out
