"""Import meshes registered by other tools (FaceScape TU models, NPHM, anything) for scoring.

A method that runs elsewhere leaves one mesh per subject and expression,
found through a path pattern with ``{subject}`` and ``{expression}``
placeholders, e.g. ``/data/facescape_tu/{subject}/models_reg/{expression}.obj``.
Each mesh is brought into the canonical millimetre frame by an optional
per-mesh transform, checked, and written to the method's output location
(``results/{dataset}/{subject}/{method}/{expression}.obj`` + ``.json`` log) so
the metrics treat it like GPJA's and NICP's meshes.

Transforms (a JSON file, path pattern with the same placeholders), applied as
``X' = s R X + t``:
    {"matrix": [[...4 numbers...] x 4]}   or a bare 4x4 (or 3x4) list
    {"scale": s, "R": [[3x3]], "t": [3]}
    FaceScape's Rt_scale_dict.json        ([subject][expression number] = [s, Rt],
                                           read by :func:`gpja.data.facescape.read_rt_scale`)
The linear part must be a positive scale times a proper rotation: a shear,
a non-uniform scale or a mirror would change the surface being scored.

OBJ files keep their texture coordinates (and texture image, if their MTL
names one); PLY files are read as positions and faces only. A mesh without
texture coordinates is written without them and its log says so: the
photometric metrics refuse such a mesh.
"""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from gpja.data.facescape import read_rt_scale
from gpja.data.source import DataSource
from gpja.data.units import check_head_units, check_units
from gpja.errors import InputError
from gpja.io import fill_path_pattern, read_image, read_json, write_json
from gpja.mesh import TexturedMesh, read_obj, read_ply, write_obj
from gpja.surface import prepare_surface

MESH_SUFFIXES = (".obj", ".ply")
#: Rotation check: |R^T R - I| (after dividing out the scale) must stay below this.
ROTATION_ATOL = 1e-4
#: The imported mesh must come this close to the scan (median scan-to-mesh distance, mm);
#: farther means a missing or wrong transform.
MAX_MEDIAN_GAP_MM = 20.0


def read_mesh(path: Path, pattern: str | Path) -> TexturedMesh:
    """Read an OBJ (with UVs and texture when present) or a PLY (positions and faces)."""
    if not path.is_file():
        raise InputError(path, f"mesh file not found (from pattern {str(pattern)!r})")
    suffix = path.suffix.lower()
    if suffix == ".obj":
        return read_obj(path)
    if suffix == ".ply":
        V, F = read_ply(path)
        return TexturedMesh(V, F)
    raise InputError(path, f"unsupported mesh format {suffix!r} (use {' or '.join(MESH_SUFFIXES)})")


def similarity_from_matrix(M: np.ndarray, source: str | Path) -> tuple[float, np.ndarray, np.ndarray]:
    """Split a 4x4 or 3x4 matrix into ``(s, R (3, 3), t (3,))``; raise if it is not a similarity."""
    M = np.asarray(M, dtype=np.float64)
    if M.shape == (4, 4):
        if not np.allclose(M[3], [0.0, 0.0, 0.0, 1.0], atol=1e-9):
            raise InputError(source, f"the matrix's last row is {M[3].tolist()}, expected [0, 0, 0, 1] (no projective part)")
        M = M[:3]
    if M.shape != (3, 4):
        raise InputError(source, f"expected a 4x4 or 3x4 matrix, got shape {M.shape}")
    A = M[:, :3]
    det = np.linalg.det(A)
    if det <= 0:
        raise InputError(source, f"the linear part has determinant {det:.4g}: a mirror or a collapse, not a rotation")
    s = float(np.cbrt(det))
    return s, A / s, M[:, 3]


def check_similarity(s: float, R: np.ndarray, t: np.ndarray, source: str | Path) -> tuple[float, np.ndarray, np.ndarray]:
    """Validate ``(s, R, t)``: finite, ``s > 0``, ``R`` a proper rotation; raise naming ``source``."""
    R = np.asarray(R, dtype=np.float64)
    t = np.asarray(t, dtype=np.float64).reshape(-1)
    if R.shape != (3, 3) or t.shape != (3,):
        raise InputError(source, f"R must be 3x3 and t 3 numbers, got shapes {R.shape} and {t.shape}")
    if not (np.isfinite(s) and np.isfinite(R).all() and np.isfinite(t).all()):
        raise InputError(source, "the transform contains NaN or infinite values")
    if s <= 0:
        raise InputError(source, f"scale must be positive, got {s:g}")
    err = float(np.abs(R.T @ R - np.eye(3)).max())
    if err > ROTATION_ATOL or np.linalg.det(R) < 0:
        raise InputError(source, f"not a rigid/similarity transform: the linear part is not a scaled rotation "
                                 f"(|R^T R - I| = {err:.3g}, det R = {np.linalg.det(R):.3g})")
    return float(s), R, t


def read_transform(path: Path, subject: str, expression: str) -> tuple[float, np.ndarray, np.ndarray]:
    """``(s, R, t)`` of one mesh from a transform JSON (any of the module's three forms)."""
    obj = read_json(path)
    if isinstance(obj, dict) and str(subject) in obj and isinstance(obj[str(subject)], dict):
        return read_rt_scale(path, subject, expression)  # FaceScape's Rt_scale_dict.json
    try:
        if isinstance(obj, dict) and "matrix" in obj:
            s, R, t = similarity_from_matrix(obj["matrix"], path)
        elif isinstance(obj, dict) and {"R", "t"} <= set(obj):
            s, R, t = float(obj.get("scale", 1.0)), obj["R"], obj["t"]
        elif isinstance(obj, list):
            s, R, t = similarity_from_matrix(obj, path)
        else:
            raise InputError(path, "expected {'matrix': 4x4}, {'scale', 'R', 't'}, a bare 4x4 list, "
                                   f"or FaceScape's Rt_scale_dict.json with subject {subject!r}")
        return check_similarity(s, R, t, path)
    except InputError:
        raise
    except (TypeError, ValueError) as err:  # ragged lists, strings where numbers belong
        raise InputError(path, f"malformed transform ({type(err).__name__}: {err})") from None


def apply_similarity(V: np.ndarray, s: float, R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """``s R V + t`` for ``V (n, 3)`` float64, mm out."""
    return s * V @ np.asarray(R).T + np.asarray(t)


def check_against_scan(V: np.ndarray, F: np.ndarray, scan_V: np.ndarray, source: str | Path) -> float:
    """Raise if a mesh ``(V, F)`` and a scan ``scan_V (k, 3)`` (both mm) differ in size or place.

    Returns:
        the median scan-to-mesh distance, mm.
    """
    check_units(TexturedMesh(V, F), scan_V, source)
    gap = float(np.median(prepare_surface(V, F, find_boundary=False).closest(scan_V).distance))
    if gap > MAX_MEDIAN_GAP_MM:
        raise InputError(source, f"the mesh lies a median {gap:.3g} mm from the scan (> {MAX_MEDIAN_GAP_MM:g} mm): "
                                 "missing or wrong transform?")
    return gap


def import_mesh(pattern: str | Path, subject: str, expression: str, out_obj: str | Path,
                transform_pattern: str | Path | None = None, texture: str | Path | None = None,
                source: DataSource | None = None, method: str = "external") -> dict:
    """Bring one externally registered mesh into the method's output location.

    Args:
        pattern: path pattern of the meshes (``{subject}``, ``{expression}``), OBJ or PLY.
        out_obj: where to write the OBJ; the log goes next to it as ``.json``.
        transform_pattern: path pattern of the transform JSON, or None (already mm, canonical frame).
        texture: an image the output's MTL should reference instead of the mesh's
            own texture (e.g. a shared texture); None keeps the mesh's own texture,
            copied next to the output as ``{stem}.png``, if it has one.
        source: the dataset whose scan of the expression (in mm) the mesh's size and placement
            are checked against; None skips the check.
        method: the imported method's name, recorded in the log.
    Returns:
        The log (also written next to the OBJ).
    Raises:
        InputError: missing or corrupt mesh, NaN vertices, a malformed or
        non-similarity transform, wrong units, a mesh far from the scan.
    """
    subject = str(subject)
    out_obj = Path(out_obj)
    path = fill_path_pattern(pattern, subject, expression)
    mesh = read_mesh(path, pattern)
    log = {"method": method, "subject": subject, "expression": expression, "source": str(path),
           "pattern": str(pattern), "vertices": len(mesh.V), "faces": len(mesh.F), "transform": None}
    if transform_pattern is not None:
        tpath = fill_path_pattern(transform_pattern, subject, expression)
        if not tpath.is_file():
            raise InputError(tpath, f"transform file not found (from pattern {str(transform_pattern)!r})")
        s, R, t = read_transform(tpath, subject, expression)
        mesh = mesh.with_vertices(apply_similarity(mesh.V, s, R, t))
        log["transform"] = {"file": str(tpath), "scale": s, "R": R.tolist(), "t": t.tolist()}
    check_head_units(mesh.V, path)
    if source is not None:
        scan = source.scan(subject, expression)
        log["scan"] = str(scan.path)
        log["median_scan_gap_mm"] = check_against_scan(mesh.V, mesh.F, scan.V, path)

    log["has_uv"] = mesh.has_uv
    if not mesh.has_uv:
        log["note"] = "the mesh has no texture coordinates: written without; photometric metrics will refuse it"
        write_obj(out_obj, TexturedMesh(mesh.V, mesh.F), texture_name=None)
        log["texture"] = None
    elif texture is not None:
        texture = Path(texture)
        read_image(texture)  # fail now, not at scoring time, if it is missing or corrupt
        ref = os.path.relpath(texture, out_obj.parent)
        write_obj(out_obj, TexturedMesh(mesh.V, mesh.F, mesh.UV, mesh.F_uv), texture_name=ref)
        log["texture"] = str(texture)
    elif mesh.texture is not None:
        write_obj(out_obj, mesh, texture_name=f"{out_obj.stem}.png")
        log["texture"] = str(out_obj.with_suffix(".png"))
    else:
        log["note"] = "the mesh has texture coordinates but no texture image"
        write_obj(out_obj, mesh, texture_name=None)
        log["texture"] = None
    write_json(out_obj.with_suffix(".json"), log)
    return log
