"""Facial regions of rest-space surface points, from the 68 ground-truth landmarks (synthetic data).

The correspondence error is one number per expression unless it is broken down by where it is
(:mod:`gpja.metrics.correspondence`). A point is labelled from its rest-space (material) position
``X`` and the subject's rest landmarks ``L`` (``landmarks_rest`` in the ground truth, iBUG-68 order:
jaw 0-16, brows 17-26, nose 27-35, eyes 36-47, outer lip 48-59, inner lip 60-67). Frame: face
towards +Z, top of the head towards +Y (DESIGN.md), mm.

Regions, in :data:`REGIONS` order (the label is the index):

* **feature regions** ``mouth`` (lips and the mouth's inside), ``eyes`` (eyeballs and lids),
  ``nose``, ``brows``: a point belongs to the feature group ``g`` whose landmarks are nearest in
  units of the group's radius :data:`RADII_MM` (3-D distance to the nearest landmark of ``g``,
  divided by its radius), when that ratio is below 1. A group also takes every point in front of
  the face plane (below) whose frontal (x, y) projection lies inside one of its contours
  :data:`CONTOURS`: ``mouth`` the outer-lip polygon (48-59), ``eyes`` either eye's polygon (36-41,
  42-47), ``nose`` the polygon of the bridge's top and the nostrils (27, 35-31): the oral cavity and
  the eyeballs lie deeper, and the nose's sides farther, than the radii reach from the landmarks.
  ``mouth`` also takes the oral cavity behind the lips: points between the mouth corners (x of 48
  and 54), within :data:`CAVITY_MM` above or below the outer lip's extent, and deeper than the
  outer lip's rearmost landmark by :data:`CAVITY_DEPTH_MM` (but in front of the face plane).
* ``face``, the rest of the face: not a feature point, in front of the face plane, and inside the
  frontal polygon of the jaw line (0-16) closed by the brows (26 -> 17) raised by
  :data:`FOREHEAD_MM`, so the forehead belongs to the face.
* ``outer``: everything else: the ears, the scalp, the neck, the back of the head.

The face plane: ``z >= min(L[0].z, L[16].z) - FACE_PLANE_MARGIN_MM``; the jaw line's ends lie in
front of the ears, so the sides and the back of the head stay ``outer`` even where their frontal
projection falls inside the face polygon.

Radii (mm): mouth 8 (about a lip's height around the lip contour), eyes 6 (the lids around the
eye contour), nose 8 (the alae beyond the nostrils 31/35, the tip and the bridge's sides), brows 7
(the brow hair around its centre line). The cavity box: 15 mm above and below the outer lip, from
22 mm behind its rearmost landmark (the mouth corners): deeper than the chin's and the cheeks'
surface beside the lips, so those stay ``face``. The synthetic head's features are 20-50 mm apart,
so the regions of different groups barely touch; where they do, the nearer (relative to the radius)
wins. Checked by eye on the default identity (frontal and sagittal scatter plots of a 1.5 mm rest
mesh): lips and oral cavity, eyeballs and lids, the nose with its alae, the brows, the face up to
20 mm above the brows; ears, scalp and neck outside.
"""
from __future__ import annotations

import numpy as np

from gpja.errors import InputError

#: Region names, in label order.
REGIONS = ("mouth", "eyes", "nose", "brows", "face", "outer")
#: Display names of the regions (tables, figures).
REGION_LABELS = {"mouth": "mouth/lips", "eyes": "eyes/lids", "nose": "nose", "brows": "brows",
                 "face": "rest of face", "outer": "ears/scalp/neck"}
#: iBUG-68 landmark indices of each feature group.
LANDMARK_GROUPS = {"mouth": tuple(range(48, 68)), "eyes": tuple(range(36, 48)), "nose": tuple(range(27, 36)),
                   "brows": tuple(range(17, 27))}
#: Radius of each feature group around its landmarks, mm (module docstring).
RADII_MM = {"mouth": 8.0, "eyes": 6.0, "nose": 8.0, "brows": 7.0}
#: How far the oral cavity reaches above and below the outer lip's landmarks, mm; and how far behind them it starts.
CAVITY_MM = 15.0
CAVITY_DEPTH_MM = 22.0
#: Height of the forehead above the brows that still counts as face, mm.
FOREHEAD_MM = 20.0
#: How far behind the jaw line's ends (landmarks 0 and 16) the face plane lies, mm.
FACE_PLANE_MARGIN_MM = 5.0
N_LANDMARKS = 68
JAW = tuple(range(0, 17))
#: Frontal (x, y) polygons of landmarks that belong to a feature group wholly (module docstring).
CONTOURS = {"mouth": (tuple(range(48, 60)),), "eyes": (tuple(range(36, 42)), tuple(range(42, 48))),
            "nose": ((27, 35, 34, 33, 32, 31),)}
#: The label of points without a region (not labelled: e.g. vertices the correspondence does not use).
UNLABELLED = -1


def check_landmarks(landmarks: np.ndarray, source="landmarks_rest") -> np.ndarray:
    """Return ``landmarks`` as (68, 3) float64; raise :class:`InputError` naming ``source`` otherwise."""
    L = np.asarray(landmarks, dtype=np.float64)
    if L.shape != (N_LANDMARKS, 3) or not np.isfinite(L).all():
        raise InputError(source, f"landmarks_rest must be {N_LANDMARKS} finite 3-D points (iBUG-68), "
                                 f"got shape {L.shape}")
    return L


def face_polygon(landmarks: np.ndarray) -> np.ndarray:
    """(27, 2) float64 frontal (x, y) polygon of the face: jaw line 0-16, then brows 26 -> 17 raised by
    :data:`FOREHEAD_MM`, mm."""
    L = check_landmarks(landmarks)
    brows = L[list(range(26, 16, -1)), :2] + np.array([0.0, FOREHEAD_MM])
    return np.concatenate([L[list(JAW), :2], brows])


def inside_polygon(points_xy: np.ndarray, polygon: np.ndarray) -> np.ndarray:
    """(q,) bool: the points (q, 2) lie inside the closed polygon (k, 2) (scikit-image's even-odd test)."""
    from skimage.measure import points_in_poly

    if len(points_xy) == 0:
        return np.zeros(0, dtype=bool)
    return points_in_poly(np.asarray(points_xy, dtype=np.float64), np.asarray(polygon, dtype=np.float64))


def in_cavity(points: np.ndarray, landmarks: np.ndarray) -> np.ndarray:
    """(q,) bool: the rest points (q, 3) lie in the oral cavity's box behind the lips (module docstring)."""
    lips = landmarks[list(CONTOURS["mouth"][0])]
    x, y, z = points[:, 0], points[:, 1], points[:, 2]
    return ((x >= landmarks[48, 0]) & (x <= landmarks[54, 0]) & (y >= lips[:, 1].min() - CAVITY_MM)
            & (y <= lips[:, 1].max() + CAVITY_MM) & (z <= lips[:, 2].min() - CAVITY_DEPTH_MM))


def label_regions(points: np.ndarray, landmarks: np.ndarray) -> np.ndarray:
    """The region of each rest-space point (module docstring).

    Args:
        points: (q, 3) float64 rest-space positions, mm; rows with NaN get :data:`UNLABELLED`.
        landmarks: (68, 3) float64 rest-space iBUG-68 landmarks, mm.
    Returns:
        (q,) int8 index into :data:`REGIONS`, or :data:`UNLABELLED`.
    """
    from scipy.spatial.distance import cdist

    L = check_landmarks(landmarks)
    X = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    finite = np.isfinite(X).all(axis=1)
    labels = np.full(len(X), UNLABELLED, dtype=np.int8)
    P = X[finite]
    front = P[:, 2] >= min(L[0, 2], L[16, 2]) - FACE_PLANE_MARGIN_MM
    # distance to each feature group in units of its radius; 0 inside the mouth and eye polygons
    ratio = np.stack([cdist(P, L[list(LANDMARK_GROUPS[g])]).min(axis=1) / RADII_MM[g] for g in LANDMARK_GROUPS], 1)
    groups = list(LANDMARK_GROUPS)
    for group, contours in CONTOURS.items():
        for contour in contours:
            ratio[front & inside_polygon(P[:, :2], L[list(contour), :2]), groups.index(group)] = 0.0
    ratio[front & in_cavity(P, L), groups.index("mouth")] = 0.0
    nearest = ratio.argmin(axis=1)
    feature = ratio[np.arange(len(P)), nearest] < 1.0
    face = front & inside_polygon(P[:, :2], face_polygon(L))
    region_of_group = np.array([REGIONS.index(g) for g in groups])
    labels[finite] = np.where(feature, region_of_group[nearest],
                              np.where(face, REGIONS.index("face"), REGIONS.index("outer")))
    return labels


def region_statistics(errors: np.ndarray, labels: np.ndarray) -> dict[str, dict]:
    """Median, mean, 95th percentile and count of the finite errors of each region.

    Args:
        errors: (n,) float64 per-point errors, mm; NaN where not scored.
        labels: (n,) int region labels (:func:`label_regions`).
    Returns:
        ``{region: {"median_mm", "mean_mm", "p95_mm", "count"}}`` for every region of :data:`REGIONS`;
        the statistics are None for a region without a scored point (count 0).
    """
    errors = np.asarray(errors, dtype=np.float64)
    labels = np.asarray(labels)
    if errors.shape != labels.shape:
        raise ValueError(f"errors {errors.shape} and labels {labels.shape} differ in shape")
    out = {}
    for k, name in enumerate(REGIONS):
        e = errors[(labels == k) & np.isfinite(errors)]
        stats = (float(np.median(e)), float(e.mean()), float(np.percentile(e, 95))) if e.size else (None,) * 3
        out[name] = {"median_mm": stats[0], "mean_mm": stats[1], "p95_mm": stats[2], "count": int(e.size)}
    return out
