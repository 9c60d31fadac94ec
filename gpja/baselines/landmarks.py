"""Landmarks for NICP: reading landmark files, and attaching landmarks to the template.

Scan landmarks are (L, 3) points in the scan file's frame (the synthetic ground
truth's ``.npz``, or 68x3 JSON/TXT files of detected landmarks); template
landmarks are vertex indices (e.g. FaceScape's TU-model indices) or points in
the template's frame. Each template landmark is carried by the affine maps of
the corners of one template face (:class:`TemplateLandmarks`).
"""
from __future__ import annotations

import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from gpja.errors import InputError
from gpja.io import read_json
from gpja.mesh import TexturedMesh
from gpja.surface import Surface, prepare_surface

#: iBUG-68 points that an expression barely moves (nose bridge, nostrils, eye
#: corners): the rigid pre-alignment uses only these when 68 landmarks are given,
#: so an open-mouth template is not tilted towards a closed-mouth scan.
IBUG_STABLE = (27, 28, 29, 30, 31, 32, 33, 34, 35, 36, 39, 42, 45)
#: A landmark farther than this from the scan surface means landmarks and scan are
#: in different frames or units (GT and detected landmarks lie on the scan), mm.
LANDMARK_TO_SCAN_MAX_MM = 10.0


@dataclass
class TemplateLandmarks:
    """Landmarks on the template, each carried by the affine maps of one template face.

    Attributes:
        faces: (L,) int64 the face each landmark belongs to.
        bary: (L, 3) float64 barycentric weights of the face's corners (those of
            the closest surface point).
        points: (L, 3) float64 the landmark positions, mm, template frame. They
            may lie off the surface where the template does not follow the scan
            it was fitted to (deep eye corners, the open mouth): the landmark is
            then the point ``p`` itself, moved by ``sum_k b_k X_k^T [p; 1]``,
            so its offset from the surface is kept rather than snapped away.
    """

    faces: np.ndarray
    bary: np.ndarray
    points: np.ndarray

    def __len__(self) -> int:
        return len(self.faces)


def check_landmarks(points: np.ndarray, count: int | None, source: str | Path) -> np.ndarray:
    """(L, 3) float64 landmarks, or :class:`InputError` naming ``source`` (wrong shape or count, NaN)."""
    P = np.asarray(points, dtype=np.float64)
    if P.ndim != 2 or P.shape[1] != 3:
        raise InputError(source, f"landmarks must be an (L, 3) array, got shape {P.shape}")
    if count is not None and len(P) != count:
        raise InputError(source, f"expected {count} landmarks, got {len(P)}")
    if len(P) < 3:
        raise InputError(source, f"at least 3 landmarks are needed for the rigid pre-alignment, got {len(P)}")
    if not np.isfinite(P).all():
        bad = int(np.argmax(~np.isfinite(P).all(axis=1)))
        raise InputError(source, f"landmarks contain NaN or infinite coordinates (first: landmark {bad})")
    return P


def vertex_landmarks(template: TexturedMesh, indices: np.ndarray, source: str | Path) -> TemplateLandmarks:
    """Landmarks at template vertices ``indices (L,)`` (e.g. FaceScape's TU-model landmark indices)."""
    lm = np.asarray(indices, dtype=np.int64)
    if len(lm) < 3:
        raise InputError(source, f"at least 3 landmarks are needed, got {len(lm)}")
    if lm.min() < 0 or lm.max() >= len(template.V):
        raise InputError(source, f"landmark vertex indices out of range [0, {len(template.V)}) "
                                 f"(min {lm.min()}, max {lm.max()})")
    face_of = np.full(len(template.V), -1)
    face_of[template.F.ravel()] = np.repeat(np.arange(len(template.F)), 3)  # any face of the vertex
    faces = face_of[lm]
    if (faces < 0).any():
        raise InputError(source, f"landmark vertex {int(lm[np.argmax(faces < 0)])} belongs to no face")
    bary = (template.F[faces] == lm[:, None]).astype(np.float64)
    return TemplateLandmarks(faces, bary, template.V[lm].copy())


def template_landmark_points(template: TexturedMesh, template_landmarks: np.ndarray, source: str | Path
                             ) -> TemplateLandmarks:
    """Attach landmarks to the template.

    Args:
        template_landmarks: (L,) integer vertex indices, or (L, 3) float
            positions, mm, in the template's frame (e.g. the landmarks of the
            expression the template was fitted to); each position is attached
            to the face of its closest surface point.
    Raises:
        InputError: indices out of range, NaN, or positions a median of more
        than ``LANDMARK_TO_SCAN_MAX_MM`` off the template (another frame or units).
    """
    lm = np.asarray(template_landmarks)
    if lm.ndim == 1 and np.issubdtype(lm.dtype, np.integer):
        return vertex_landmarks(template, lm, source)
    P = check_landmarks(lm, None, source)
    hit = prepare_surface(template.V, template.F, find_boundary=False).closest(P)
    gap = hit.distance
    if np.median(gap) > LANDMARK_TO_SCAN_MAX_MM:
        raise InputError(source, f"template landmarks lie a median {np.median(gap):.3g} mm off the template "
                                 f"(> {LANDMARK_TO_SCAN_MAX_MM:g} mm): not in the template's frame or units?")
    return TemplateLandmarks(hit.face, hit.barycentric, P)


def check_landmarks_on_scan(target: Surface, landmarks: np.ndarray, source: str | Path) -> None:
    """Raise if landmarks ``(L, 3)`` mm lie far from the scan: another frame, or other units."""
    gap = target.closest(landmarks).distance
    if np.median(gap) > LANDMARK_TO_SCAN_MAX_MM:
        raise InputError(source, f"landmarks lie a median {np.median(gap):.3g} mm off the scan surface "
                                 f"(> {LANDMARK_TO_SCAN_MAX_MM:g} mm): not in the scan's frame or units?")


# --- files -----------------------------------------------------------------------------------

def read_landmark_array(path: str | Path) -> np.ndarray:
    """The array stored in a landmark file, unchecked.

    Formats: ``.npz`` (key ``landmarks``), ``.npy``, ``.json`` (a list, or an
    object with a ``landmarks`` or ``indices`` list), anything else as text
    (one landmark per line; whitespace or commas).
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(path, "landmark file not found")
    suffix = path.suffix.lower()
    try:
        if suffix == ".npz":
            with np.load(path) as data:
                if "landmarks" not in data.files:
                    raise InputError(path, f"no 'landmarks' array (keys: {', '.join(data.files) or 'none'})")
                return np.asarray(data["landmarks"])
        if suffix == ".npy":
            return np.load(path)
        if suffix == ".json":
            obj = read_json(path)
            if isinstance(obj, dict):
                key = next((k for k in ("landmarks", "indices") if k in obj), None)
                if key is None:
                    raise InputError(path, "expected a list, or an object with a 'landmarks' or 'indices' list")
                obj = obj[key]
            return np.asarray(obj)
        text = path.read_text(encoding="utf-8").replace(",", " ")
        rows = [line.split() for line in text.splitlines() if line.strip() and not line.lstrip().startswith("#")]
        return np.asarray(rows, dtype=np.float64)
    except InputError:
        raise
    except (ValueError, TypeError, OSError, EOFError, UnicodeDecodeError, zipfile.BadZipFile) as err:
        raise InputError(path, f"corrupt or unreadable landmark file ({type(err).__name__}: {err})") from None


def read_landmarks(path: str | Path, count: int | None = None) -> np.ndarray:
    """(L, 3) float64 landmark positions from a file (see :func:`read_landmark_array`), checked."""
    return check_landmarks(read_landmark_array(path), count, path)


def read_template_landmarks(path: str | Path) -> np.ndarray:
    """Template landmarks from a file: (L,) int64 vertex indices or (L, 3) float64 positions, mm.

    A 1-D list of whole numbers (or a one-column text file) is read as vertex
    indices, e.g. FaceScape's 68 TU-model landmark indices.
    """
    arr = read_landmark_array(path)
    flat = arr.reshape(-1) if arr.ndim == 2 and arr.shape[1] == 1 else arr
    if flat.ndim == 1:
        try:
            idx = flat.astype(np.float64)
        except (TypeError, ValueError):
            raise InputError(path, "landmark indices must be numbers") from None
        if not np.isfinite(idx).all() or (idx != np.round(idx)).any():
            raise InputError(path, "landmark indices must be whole numbers")
        return idx.astype(np.int64)
    return check_landmarks(arr, None, path)


def transform_points(P: np.ndarray, scale: float, R: np.ndarray | None, t: np.ndarray | None) -> np.ndarray:
    """``R (s P) + t`` for ``P (L, 3)`` (FaceScape's raw-to-aligned transform; R None = identity)."""
    P = scale * np.asarray(P, dtype=np.float64)
    return P if R is None else P @ np.asarray(R).T + np.asarray(t)
