"""Synthesise one subject and write it in FaceScape's on-disk layout.

Layout written by :func:`synthesize_subject`::

    {images_root}/{subject}/{expression}/{view}.png, params.json
    {scans_root}/{subject}/{expression}.ply
    {gt_root}/{subject}/{expression}.npz, subject.json
    {raw_root}/images/{subject}/{expression}/{view}.png (hard links), params.json (raw-frame cameras)
    {raw_root}/scans/{subject}/{expression}.ply
    {raw_root}/Rt_scale_dict/{subject}.json   # {subject: {exp_num: [scale, Rt 3x4]}}, X_mm = R (s X_raw) + t
    contact sheet PNG (rows = expressions, columns = views)

Every file goes through :mod:`gpja.io`'s atomic writers.
"""
from __future__ import annotations

import time
import zlib
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from gpja.data.synthetic.albedo import albedo_tables, evaluate_albedo
from gpja.data.synthetic.capture import RayBundle, build_scene, make_rig, make_sh, render_view, vertex_normals
from gpja.data.synthetic.expressions import DEFAULT_EXPRESSIONS, EXPRESSIONS, expression_number, map_to_expression
from gpja.data.synthetic.head import build_head_program, sample_head_params
from gpja.data.synthetic.landmarks import rest_landmarks
from gpja.data.synthetic.scan import cut_scan
from gpja.io import link_or_copy, write_image, write_json, write_npz
from gpja.mesh import write_ply
from gpja.settings import from_section

GENERATOR_VERSION = "1"
#: Views shown in the contact sheet (those that exist).
CONTACT_VIEWS = ("2", "0", "1", "5")
CONTACT_TILE_PX = 160


@dataclass(frozen=True)
class SynthConfig:
    """Settings of the synthetic benchmark (one subject = one call).

    Attributes:
        seed: dataset seed; subject i uses ``numpy.random.default_rng((seed, i))``.
        image_size: width = height of every image, pixels.
        n_views: number of cameras.
        camera_distance_mm: camera distance from the rig target.
        scan_voxel_mm: marching-cubes voxel of the scan (edges ~0.5-1 voxel).
        scan_noise_mm: sigma of Gaussian noise along the scan normals (0 = none).
        distortion: give the cameras lens distortion (applied to the images).
        supersample: rays per pixel along each axis (antialiasing).
        raw_variant: also write the raw-frame variant + Rt_scale_dict.
        expressions: FaceScape names to synthesise.
        render_voxel_mm: marching-cubes voxel of the render mesh (its grid is
            offset by half a voxel from the scan's, so the triangulations differ).
    """

    seed: int = 0
    image_size: int = 512
    n_views: int = 8
    camera_distance_mm: float = 600.0
    scan_voxel_mm: float = 0.8
    scan_noise_mm: float = 0.0
    distortion: bool = True
    supersample: int = 2
    raw_variant: bool = True
    expressions: tuple[str, ...] = DEFAULT_EXPRESSIONS
    render_voxel_mm: float = 0.8

    #: ``SynthConfig.from_config(section, source)``: from the ``synthetic`` section (gpja.settings).
    from_config = classmethod(from_section)

    def __post_init__(self) -> None:
        bad = [e for e in self.expressions if e not in EXPRESSIONS]
        if bad:
            raise ValueError(f"unknown synthetic expressions {bad}; known: {list(EXPRESSIONS)}")
        if len(set(self.expressions)) != len(self.expressions) or not self.expressions:
            raise ValueError("synthetic expressions must be a non-empty list without repeats")
        for name in ("image_size", "n_views", "supersample"):
            if int(getattr(self, name)) < 1:
                raise ValueError(f"{name} must be >= 1, got {getattr(self, name)}")
        for name in ("scan_voxel_mm", "render_voxel_mm", "camera_distance_mm"):
            if not float(getattr(self, name)) > 0:
                raise ValueError(f"{name} must be > 0, got {getattr(self, name)}")
        if self.scan_noise_mm < 0:
            raise ValueError(f"scan_noise_mm must be >= 0, got {self.scan_noise_mm}")


def subject_seed_index(subject: str) -> int:
    """A stable per-subject integer (independent of the subject list's order): the ``subject_index``
    of :func:`synthesize_subject`, CRC-32 of the name's UTF-8 bytes, 31 bits."""
    return zlib.crc32(str(subject).encode("utf-8")) & 0x7FFFFFFF


def random_rotation(rng: np.random.Generator) -> np.ndarray:
    """A uniformly random rotation (3, 3) float64."""
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    w, x, y, z = q
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def to_raw(X: np.ndarray, scale: float, R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Invert ``X_mm = R (s X_raw) + t``: (n, 3) mm -> (n, 3) raw units."""
    return ((X - t) @ R) / scale


def write_contact_sheet(path: Path, rows: list[tuple[str, dict[str, np.ndarray]]]) -> None:
    """A grid of downscaled views (rows = expressions) with labels, PNG."""
    import cv2

    tile = CONTACT_TILE_PX
    label_w = 150
    views = [v for v in CONTACT_VIEWS if all(v in imgs for _, imgs in rows)] or sorted(rows[0][1])[:4]
    sheet = np.full((tile * len(rows), label_w + tile * len(views), 3), 255, np.uint8)
    for r, (name, imgs) in enumerate(rows):
        cv2.putText(sheet, name, (4, r * tile + tile // 2), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 1, cv2.LINE_AA)
        for c, v in enumerate(views):
            im = (np.clip(imgs[v], 0, 1) * 255 + 0.5).astype(np.uint8)
            sheet[r * tile:(r + 1) * tile, label_w + c * tile:label_w + (c + 1) * tile] = cv2.resize(
                im, (tile, tile), interpolation=cv2.INTER_AREA)
    write_image(path, sheet)


def synthesize_subject(subject: str, subject_index: int, cfg: SynthConfig, images_root, scans_root, gt_root,
                       raw_root, contact_sheet_path, progress=print) -> dict:
    """Synthesise and write one subject (all expressions, images, scans, ground truth).

    Args:
        subject: folder name of the subject (e.g. "1").
        subject_index: index seeding the subject's generator with ``(cfg.seed, subject_index)``.
        cfg: settings.
        images_root, scans_root, gt_root, raw_root: output roots (see module docstring);
            ``raw_root`` is ignored when ``cfg.raw_variant`` is false.
        contact_sheet_path: PNG path of the contact sheet.
        progress: called with one line per expression.
    Returns:
        summary dict: timings per stage (s), vertex counts, paths.
    """
    T = {"sdf": 0.0, "marching_cubes": 0.0, "scan": 0.0, "render": 0.0, "write": 0.0, "setup": 0.0}
    t0 = time.perf_counter()
    images_root, scans_root, gt_root = Path(images_root), Path(scans_root), Path(gt_root)
    raw_root = Path(raw_root) if raw_root is not None else None
    rng = np.random.default_rng((int(cfg.seed), int(subject_index)))
    head = sample_head_params(rng)
    cams = make_rig(rng, cfg.n_views, cfg.image_size, cfg.camera_distance_mm, cfg.distortion)
    sh = make_sh(rng)
    gains = {e: 1.0 + rng.uniform(-0.03, 0.03, 3) for e in cfg.expressions}
    raw_tf = {}
    for e in cfg.expressions:
        s = float(rng.uniform(0.8, 1.2))
        raw_tf[e] = (s, random_rotation(rng), rng.uniform(-300.0, 300.0, 3))
    noise_rng = np.random.default_rng((int(cfg.seed), int(subject_index), 1))
    program = build_head_program(head)["head"]
    tables = albedo_tables(head)
    L_rest = rest_landmarks(head)
    T["setup"] += time.perf_counter() - t0

    # two independent triangulations of the rest surface
    from gpja.data.synthetic import head as head_mod
    from skimage.measure import marching_cubes

    meshes = {}
    for key, vox, off in (("scan", cfg.scan_voxel_mm, 0.0), ("render", cfg.render_voxel_mm, 0.5)):
        t = time.perf_counter()
        grid, origin = head_mod.sample_sdf_grid(program, vox, np.full(3, off * vox))
        T["sdf"] += time.perf_counter() - t
        t = time.perf_counter()
        verts, faces, _, _ = marching_cubes(grid, level=0.0, spacing=(vox,) * 3, allow_degenerate=False)
        meshes[key] = (origin + verts.astype(np.float64), faces.astype(np.int64))
        T["marching_cubes"] += time.perf_counter() - t
    Vs_rest, Fs = meshes["scan"]
    Vr_rest, Fr = meshes["render"]

    t = time.perf_counter()
    bundles = [RayBundle(c, cfg.supersample) for c in cams]
    T["render"] += time.perf_counter() - t

    def albedo_fn(X):
        return evaluate_albedo(X, tables)

    sheet_rows = []
    rt_dict: dict[str, list] = {}
    counts = {}
    for e in cfg.expressions:
        te = time.perf_counter()
        # --- scan
        t = time.perf_counter()
        Vs_expr = map_to_expression(Vs_rest, head, e)
        V_scan, F_scan, rest_scan = cut_scan(Vs_rest, Vs_expr, Fs, cams)
        if cfg.scan_noise_mm > 0:
            n = vertex_normals(V_scan, F_scan)
            V_scan = V_scan + noise_rng.normal(0.0, cfg.scan_noise_mm, (len(V_scan), 1)) * n
        T["scan"] += time.perf_counter() - t
        # --- render
        t = time.perf_counter()
        Vr_expr = map_to_expression(Vr_rest, head, e)
        N_expr = vertex_normals(Vr_expr, Fr)
        scene = build_scene(Vr_expr, Fr)
        images = {c.name: render_view(scene, b, Vr_rest, N_expr, Fr, albedo_fn, sh, gains[e])
                  for c, b in zip(cams, bundles)}
        del scene
        T["render"] += time.perf_counter() - t
        # --- write
        t = time.perf_counter()
        img_dir = images_root / subject / e
        params = {}
        for c in cams:
            write_image(img_dir / f"{c.name}.png", images[c.name])
            params.update(c.to_params(c.name))
        write_json(img_dir / "params.json", params)
        write_ply(scans_root / subject / f"{e}.ply", V_scan, F_scan)
        write_npz(gt_root / subject / f"{e}.npz", scan_rest_coords=rest_scan.astype(np.float64),
                  landmarks=map_to_expression(L_rest, head, e), landmarks_rest=L_rest,
                  sh=sh.astype(np.float64), skin_gain=gains[e].astype(np.float64))
        if cfg.raw_variant:
            s, R, tt = raw_tf[e]
            raw_img = raw_root / "images" / subject / e
            raw_params = {}
            for c in cams:
                link_or_copy(img_dir / f"{c.name}.png", raw_img / f"{c.name}.png")
                raw_params.update(c.transformed(1.0 / s, R.T, -(R.T @ tt) / s).to_params(c.name))
            write_json(raw_img / "params.json", raw_params)
            write_ply(raw_root / "scans" / subject / f"{e}.ply", to_raw(V_scan, s, R, tt), F_scan)
            rt_dict[str(expression_number(e))] = [s, np.concatenate([R, tt[:, None]], 1).tolist()]
        T["write"] += time.perf_counter() - t
        sheet_rows.append((e, images))
        counts[e] = {"scan_vertices": int(len(V_scan)), "scan_faces": int(len(F_scan))}
        progress(f"synthetic subject {subject}: {e} done in {time.perf_counter() - te:.1f} s "
                 f"(scan {len(V_scan)} vertices, {len(cams)} views {cfg.image_size}px)")

    t = time.perf_counter()
    if cfg.raw_variant:
        write_json(raw_root / "Rt_scale_dict" / f"{subject}.json", {subject: rt_dict})
    write_json(gt_root / subject / "subject.json", {
        "subject": subject, "subject_index": int(subject_index), "seed": int(cfg.seed),
        "generator_version": GENERATOR_VERSION, "expressions": list(cfg.expressions),
        "identity": head.to_dict(), "config": {k: (list(v) if isinstance(v, tuple) else v) for k, v in asdict(cfg).items()},
        "skin_gain": {e: gains[e].tolist() for e in cfg.expressions}, "sh": sh.tolist(),
        "units": "mm", "frame": "face +Z, up +Y, subject's left +X"})
    write_contact_sheet(Path(contact_sheet_path), sheet_rows)
    T["write"] += time.perf_counter() - t
    T["total"] = time.perf_counter() - t0
    return {"subject": subject, "timings_s": T, "counts": counts,
            "render_mesh_vertices": int(len(Vr_rest)), "scan_mesh_vertices_full": int(len(Vs_rest))}
