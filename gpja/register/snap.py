"""The registration's last step onto the scan: every vertex moved along its normal to the scan's surface.

Beyond the paper (``Schedule.snap_mm``, 0 = off). The levels end where a tug of war between the constraints
leaves them: each constraint steps by up to the learning rate whatever its units (one normalised Adam each),
so where the colour prefers another shape than the scan's, the depth constraint does not win outright, and
the mean of the last iterates sits a little off the scan. Usually a few hundredths of a millimetre; after an
unlucky draw the whole last level can end 0.1-0.8 mm off (docs/experiments.md, "Snapping onto the scan":
C.D. 0.176 mm against 0.030 from a last-bit change in a factorisation).

The snap reads the scan itself, the registration's own input. From each vertex it casts a ray along its
normal both ways and takes the nearer hit within ``max_mm`` on a scan face that faces the same way (cosine
above :data:`MIN_FACING`), so a surface inside the head (the mouth's socket behind closed lips) never snaps
onto the lips' outside. Vertices without such a hit (holes of the scan, hidden parts) follow their
neighbours: the offsets ``t`` solve ``(W + mu L) d = W t``, with ``W`` 1 where a ray hit and ``L`` the
uniform Laplacian, so the moved surface has no steps at the edges of what the scan covers. Motion is along
the normals only: the texture's alignment along the surface stays as the levels left it.

Written here rather than taken from a library: Open3D's and trimesh's closest-point projections move
vertices sideways as well (onto the nearest point, not along the normal) and know no facing test.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from gpja.cholesky import factorize
from gpja.mesh import TexturedMesh
from gpja.register.laplacian import uniform_laplacian
from gpja.surface import bounding_box_centre, load_open3d, raycasting_scene, vertex_normals

#: A hit counts only on a scan face whose normal is within about 60 degrees of the vertex's normal.
MIN_FACING = 0.5
#: The diagonal's floor where no ray hit: keeps the system positive definite on parts with no hit at all.
FREE_WEIGHT = 1e-6


def normal_offsets(V: np.ndarray, normals: np.ndarray, scan_V: np.ndarray, scan_F: np.ndarray,
                   max_mm: float) -> tuple[np.ndarray, np.ndarray]:
    """Signed distance along each vertex's normal to the scan, within ``max_mm``.

    Args:
        V: (n, 3) float64 positions, mm; normals: (n, 3) float64 unit vertex normals.
        scan_V: (k, 3) float64 scan positions, mm; scan_F: (l, 3) int scan faces.
        max_mm: the farthest hit that counts, mm.
    Returns:
        offsets: (n,) float64, mm, ``V + offsets * normals`` is on the scan (0 where no hit);
        hit: (n,) bool, a facing scan face lies within ``max_mm`` along the normal (either way).
    """
    o3d = load_open3d()

    origin = bounding_box_centre(scan_V)
    scene = raycasting_scene(np.asarray(scan_V, dtype=np.float64) - origin, scan_F)
    scan_normals = TexturedMesh(np.asarray(scan_V, dtype=np.float64), scan_F).face_normals()
    nearest = np.full(len(V), np.inf)
    offsets = np.zeros(len(V))
    for sign in (1.0, -1.0):
        rays = np.concatenate([V - origin, sign * normals], axis=1).astype(np.float32)
        answer = scene.cast_rays(o3d.core.Tensor(rays))
        t = answer["t_hit"].numpy().astype(np.float64)
        ok = np.isfinite(t) & (t <= max_mm)
        face = answer["primitive_ids"].numpy()[ok].astype(np.int64)
        ok[ok] = (scan_normals[face] * normals[ok]).sum(axis=1) > MIN_FACING
        nearer = ok & (t < nearest)
        nearest[nearer] = t[nearer]
        offsets[nearer] = sign * t[nearer]
    return offsets, np.isfinite(nearest)


def snap_to_scan(V: np.ndarray, F: np.ndarray, scan_V: np.ndarray, scan_F: np.ndarray, max_mm: float,
                 smoothness: float = 1.0) -> tuple[np.ndarray, dict]:
    """Move a registered mesh along its normals onto the scan (module docstring).

    Args:
        V: (n, 3) float64 registered positions, mm; F: (m, 3) int faces.
        scan_V: (k, 3) float64 scan positions, mm; scan_F: (l, 3) int scan faces.
        max_mm: the farthest a ray looks for the scan, mm (> 0).
        smoothness: ``mu``, how strongly the offsets follow their neighbours (> 0; dimensionless).
    Returns:
        (n, 3) float64 moved positions, and a log entry: ``hit_fraction`` (vertices whose ray hit),
        ``gap_median_mm`` and ``gap_p95_mm`` (|offset| where hit, before), ``moved_median_mm``, ``moved_max_mm``.
    """
    if not max_mm > 0 or not smoothness > 0:
        raise ValueError(f"max_mm and smoothness must be > 0, got {max_mm} and {smoothness}")
    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    normals = vertex_normals(V, F)
    offsets, hit = normal_offsets(V, normals, np.asarray(scan_V, dtype=np.float64), np.asarray(scan_F, dtype=np.int64),
                                  float(max_mm))
    weight = hit.astype(np.float64) + FREE_WEIGHT
    system = (sp.diags(weight) + float(smoothness) * uniform_laplacian(V, F)).tocsc()
    d = factorize(system).solve((weight * offsets)[:, None])[:, 0]
    gaps = np.abs(offsets[hit])
    entry = {"hit_fraction": float(hit.mean()),
             "gap_median_mm": float(np.median(gaps)) if gaps.size else 0.0,
             "gap_p95_mm": float(np.percentile(gaps, 95)) if gaps.size else 0.0,
             "moved_median_mm": float(np.median(np.abs(d))), "moved_max_mm": float(np.abs(d).max())}
    return V + d[:, None] * normals, entry
