"""The photometric upper bound on synthetic data: the ground truth rendered by our renderer, scored like a method.

A method's PSNR, SSIM and LPIPS say little on their own: even a perfect registration with a perfect
texture cannot match the captured images exactly (our rasteriser is not the generator's ray caster,
the images were resampled once by undistortion and quantised to 8 bits). The *oracle* measures that
floor: it renders what the capture was made of, with our renderer at the reference cameras, and
scores it with the photometric code every method is scored with (:mod:`gpja.metrics.photometric`:
the same head mask, composite, PSNR, SSIM and LPIPS per view). A method's distance to the oracle is
the real gap.

What it renders (the image formation of ``gpja.data.synthetic.capture.render_view``):

* surface: the expression's true surface: the scan's vertices put back where the generator's
  expression map sends their rest points (``map_to_expression`` of ``scan_rest_coords``), so scan
  noise (``synthetic.scan_noise_mm``) does not shade the oracle (it equals the scan when the noise is
  0); the scan's triangles, smooth vertex normals (the renderer's ``normal`` pass);
* albedo: the generator's procedural albedo (``evaluate_albedo``, tables from ``subject.json``'s
  identity) at each pixel's rest-space point, which the renderer interpolates from the scan's
  ``scan_rest_coords`` (the ``uv`` pass, two coordinates per render), times the expression's
  ``skin_gain``. Per pixel rather than per vertex: the generator evaluates the albedo per ray, and
  per-vertex albedo interpolated over 0.8-1 mm triangles blurs the pores and freckles a pixel of the
  512 px default images resolves (0.7 mm);
* light: the ground truth's SH lighting, Lambertian (``gpja.lighting.shade_lambertian``), clipped
  to [0, 1] as the generator clips;
* antialiasing: ``supersample`` x ``supersample`` point samples per pixel averaged (the generator's
  box filter; default: the generator's own ``supersample`` from ``subject.json``), background 0 as
  in every method's render (the composite replaces it outside the head mask).

Measured on the CI data (S01, 128 px, 8 views; PSNR dB / SSIM / LPIPS, ``1_neutral``): the oracle
32.31 / 0.944 / 0.034; with one sample per pixel 28.58 / 0.875 / 0.084, three 32.61 / 0.939 / 0.026;
per-vertex albedo 32.00 / 0.935 / 0.033; the albedo slid by 1 mm 29.04; without the skin gain 31.44;
under the paper's uniform white light 20.50 / 0.808 / 0.151. What is left is at the scan's rims
(pixels the scan half covers, blended with the black background as every method's render is), the
lids' and lips' creases, and the reference images' resampling.

Geometry: the same true surface scored against the expression's scan with the geometric protocol of
every method (:func:`gpja.metrics.geometry.evaluate_geometry`, the run's ``metrics`` settings). On a
noise-free capture it is the scan itself (C.D. 0; N.C. 0.9997, the scan vertices' normals against its
faces'); with ``synthetic.scan_noise_mm`` it measures what the noise alone costs, which no registration
can win back: on a capture with 0.15 mm of noise (seed 47, S01 ``1_neutral``) the true surface scores
C.D. 0.097 mm and N.C. 0.937, against the N.C. bar of 0.99 that a smooth mesh can only meet on a smooth
scan (docs/experiments.md, "The ground truth's own geometric score").

Output: a metrics JSON with the photometric and geometric families (``correspondence`` is null), at
``results/{dataset}/{subject}/oracle/metrics/{expression}.json``; the per-view renders and error images
beside it, as for every method.
"""
from __future__ import annotations

import logging
from pathlib import Path
from typing import TYPE_CHECKING, Callable, Sequence

import numpy as np

from gpja.errors import InputError
from gpja.io import read_json, read_npz

if TYPE_CHECKING:  # workflow/rules/reference.smk imports this module's names while the Snakefile parses
    from gpja.camera import Camera
    from gpja.data.source import DataSource
    from gpja.metrics.evaluate import MetricSettings

log = logging.getLogger(__name__)

#: The method name of the oracle's results (``gpja.methods``: kind ``reference``).
ORACLE = "oracle"
#: The ground-truth file of a subject's identity and generator settings.
SUBJECT_FILE = "subject.json"


# --- the ground truth ------------------------------------------------------------------------------------------

def subject_identity(ground_truth_root: str | Path, subject: str):
    """The generator's ``HeadParams`` of a subject, from the identity in ``{ground_truth_root}/{subject}/subject.json``.

    Raises:
        InputError: the file is missing or corrupt, or its identity is not the generator's.
    """
    from gpja.data.synthetic.head import HeadParams

    path = Path(ground_truth_root) / str(subject) / SUBJECT_FILE
    meta = read_json(path)
    identity = meta.get("identity") if isinstance(meta, dict) else None
    if not isinstance(identity, dict):
        raise InputError(path, "no 'identity' object (not a synthetic subject's ground truth?)")
    try:
        return HeadParams(**identity)
    except TypeError as err:
        raise InputError(path, f"identity does not match the generator's parameters ({err})") from None


def subject_albedo(ground_truth_root: str | Path, subject: str) -> dict[str, np.ndarray]:
    """The generator's albedo tables of a subject (``gpja.data.synthetic.albedo.albedo_tables``), rebuilt from
    its identity (:func:`subject_identity`)."""
    from gpja.data.synthetic.albedo import albedo_tables

    return albedo_tables(subject_identity(ground_truth_root, subject))


def true_surface_vertices(ground_truth_root: str | Path, subject: str, expression: str, rest: np.ndarray) -> np.ndarray:
    """(n, 3) float64 the expression's true positions (mm) of the scan vertices whose rest points are ``rest``:
    the generator's expression map of them, without the scan's noise."""
    from gpja.data.synthetic.expressions import map_to_expression

    return map_to_expression(rest, subject_identity(ground_truth_root, subject), expression)


def generator_supersample(ground_truth_root: str | Path, subject: str) -> int:
    """The generator's rays per pixel along each axis (``subject.json`` config), 1 when it is not recorded."""
    meta = read_json(Path(ground_truth_root) / str(subject) / SUBJECT_FILE)
    value = ((meta or {}).get("config") or {}).get("supersample", 1)
    return max(int(value), 1)


def expression_truth(ground_truth_root: str | Path, subject: str, expression: str,
                     n_scan_vertices: int) -> dict[str, np.ndarray]:
    """The ground truth of one expression the oracle renders with.

    Returns:
        ``rest`` (n_scan_vertices, 3) float64 rest coordinates of the scan's vertices (mm), ``sh`` (9, 3)
        float64 SH lighting, ``gain`` (3,) float64 per-expression skin gain (1 where not recorded).
    Raises:
        InputError: a missing or corrupt file, or arrays of the wrong shape.
    """
    from gpja.metrics.correspondence import check_rest_coords, ground_truth_path

    path = ground_truth_path(ground_truth_root, subject, expression)
    arrays = read_npz(path)
    for key in ("scan_rest_coords", "sh"):
        if key not in arrays:
            raise InputError(path, f"no {key!r} array (has: {', '.join(sorted(arrays)) or 'nothing'})")
    sh = np.asarray(arrays["sh"], dtype=np.float64)
    gain = np.asarray(arrays.get("skin_gain", np.ones(3)), dtype=np.float64).ravel()
    if sh.shape != (9, 3) or gain.shape != (3,) or not (np.isfinite(sh).all() and np.isfinite(gain).all()):
        raise InputError(path, f"sh must be 9 x 3 and skin_gain 3 finite values, got {sh.shape} and {gain.shape}")
    return {"rest": check_rest_coords(arrays["scan_rest_coords"], n_scan_vertices, path), "sh": sh, "gain": gain}


# --- rendering -------------------------------------------------------------------------------------------------

def render_ground_truth(V: np.ndarray, F: np.ndarray, rest: np.ndarray, albedo: Callable[[np.ndarray], np.ndarray],
                        sh: np.ndarray, gain: np.ndarray, cameras: Sequence["Camera"], supersample: int = 1,
                        render: Callable | None = None) -> np.ndarray:
    """Render a surface with a rest-space albedo function under SH light (module docstring), view by view.

    Args:
        V: (n, 3) float64 surface vertices, mm. F: (m, 3) int64 faces.
        rest: (n, 3) float64 rest-space coordinate of every vertex, mm.
        albedo: rest points (k, 3) float64 mm -> (k, 3) float64 linear RGB albedo in [0, 1].
        sh: (9, 3) SH radiance coefficients; gain: (3,) colour gain applied to the albedo.
        cameras: B undistorted cameras of one image size (H, W).
        supersample: point samples per pixel along each axis, box-averaged.
        render: a backend's ``render_views`` (``gpja.render.renderer``); None = the CPU renderer.
    Returns:
        (B, H, W, 3) float32 linear RGB in [0, 1], 0 where the surface covers nothing.
    """
    import torch

    from gpja.lighting import shade_lambertian
    from gpja.render import Topology, render_views

    render = render or render_views
    S = int(supersample)
    if S < 1:
        raise ValueError(f"supersample must be >= 1, got {supersample}")
    rest = np.asarray(rest, dtype=np.float64)
    topology = Topology(np.asarray(F, dtype=np.int64), np.asarray(F, dtype=np.int64))
    Vt = torch.as_tensor(np.asarray(V), dtype=torch.float32)
    # the uv pass interpolates two values per render: rest x, y first, then z
    attributes = [torch.as_tensor(rest[:, :2], dtype=torch.float32),
                  torch.as_tensor(np.column_stack([rest[:, 2], np.zeros(len(rest))]), dtype=torch.float32)]
    images = []
    for camera in cameras:
        fine = camera.resized(camera.width * S, camera.height * S) if S > 1 else camera
        with torch.no_grad():
            first = render(Vt, topology, [fine], passes=("uv", "normal"), uv=attributes[0], antialias_edges=False)
            second = render(Vt, topology, [fine], passes=("uv",), uv=attributes[1], antialias_edges=False)
            covered = first.dense("coverage")[0, ..., 0].cpu().numpy() > 0.5
            xy = first.dense("uv")[0].cpu().numpy()[covered].astype(np.float64)
            z = second.dense("uv")[0, ..., :1].cpu().numpy()[covered].astype(np.float64)
            normals = first.dense("normal")[0].cpu().numpy()[covered].astype(np.float64)
        normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-12)
        colour = np.zeros((*covered.shape, 3))
        colour[covered] = np.clip(shade_lambertian(albedo(np.hstack([xy, z])) * gain[None, :], normals, sh), 0.0, 1.0)
        images.append(colour.reshape(camera.height, S, camera.width, S, 3).mean(axis=(1, 3)).astype(np.float32))
    return np.stack(images)


# --- scoring ---------------------------------------------------------------------------------------------------

def score_renders(renders: np.ndarray, images: np.ndarray, coverage: np.ndarray, names: Sequence[str],
                  out_dir: str | Path | None = None, source: str | Path = ORACLE) -> dict:
    """PSNR, SSIM and LPIPS of ready-made renders with the photometric protocol of every method.

    The head mask of :func:`gpja.metrics.photometric.head_mask`, then
    :func:`gpja.metrics.photometric.score_renders`, the one scoring function of every method.

    Args:
        renders, images: (B, H, W, 3) float32 in [0, 1]. coverage: (B, H, W, 1) scan coverage in [0, 1].
        names: B view names. out_dir: where ``render/{view}.png`` and ``l1/{view}.png`` go (None: not written).
    Returns:
        ``psnr`` (dB), ``ssim``, ``lpips``, ``views``, ``image_size``, ``per_view``, ``mask_definition``, ...
    """
    from gpja.metrics import photometric

    masks = photometric.head_mask(coverage)
    if not masks.any():
        raise InputError("coverage", f"the head mask ({photometric.MASK_DEFINITION}) is empty in every view")
    return photometric.score_renders(renders, images, masks, names, out_dir, source)


def score_true_geometry(V_true: np.ndarray, scan_V: np.ndarray, scan_F: np.ndarray, settings: "MetricSettings",
                        scan_source: str | Path = "scan") -> dict:
    """The true surface's geometric scores against its (noisy) scan, as a method's (module docstring).

    Args:
        V_true: (n, 3) float64 the scan's vertices at their true positions, mm (:func:`true_surface_vertices`).
        scan_V: (n, 3) float64 the scan's vertices as captured, mm. scan_F: (m, 3) int64 the scan's faces,
            which the true surface shares.
        settings: the run's scoring protocol (:class:`gpja.metrics.evaluate.MetricSettings`).
    Returns:
        ``GeometryMetrics.to_json()`` plus ``mesh`` (what was scored) and ``scan``.
    """
    from gpja.metrics.geometry import evaluate_geometry

    s = settings
    scores = evaluate_geometry(V_true, scan_F, scan_V, scan_F, samples=s.samples, seed=s.seed,
                               thresholds=s.thresholds_mm, coverage=s.coverage, max_distance_mm=s.max_distance_mm,
                               mesh_source=f"{scan_source} at its true positions", scan_source=scan_source)
    return {"mesh": f"{scan_source} at its true positions", "scan": str(scan_source), **scores.to_json()}


def evaluate_oracle(source: "DataSource", ground_truth_root: str | Path, subject: str, expression: str,
                    targets_path: str | Path | None = None, out_dir: str | Path | None = None,
                    supersample: int | None = None, render: Callable | None = None,
                    settings: "MetricSettings | None" = None) -> dict:
    """The oracle's metrics JSON of one expression (module docstring).

    Args:
        source: the synthetic dataset (images, scans in mm).
        ground_truth_root: its ground truth (``{root}/{subject}/{expression}.npz``, ``subject.json``).
        targets_path: the expression's scan-targets cache (.npz; the head mask), reused or written.
        out_dir: the folder of per-view renders and error images (None: not written).
        supersample: samples per pixel along each axis; None = the generator's.
        render: a backend's ``render_views``; None = the CPU renderer.
        settings: the scoring protocol of the geometric scores (None: the defaults of ``MetricSettings``).
    Returns:
        JSON-able ``{"subject", "expression", "method": "oracle", "geometry": {...}, "photometric": {...},
        "correspondence": None, "oracle": {what was rendered}}``.
    Raises:
        InputError: real data (an ``Rt_scale_dict``), missing or corrupt files, views of different sizes.
    """
    from gpja.data.synthetic.albedo import evaluate_albedo
    from gpja.metrics.evaluate import MetricSettings
    from gpja.render import render_scan_targets

    if source.rt_scale is not None:
        raise InputError("--rt-scale", "the oracle needs synthetic data in mm (no Rt_scale_dict)")
    data = source.load(subject, expression)
    if len({(c.width, c.height) for c in data.cameras}) != 1:
        raise InputError(source.images_root or "images", "views differ in size; set max_image_size so they share one")
    truth = expression_truth(ground_truth_root, subject, expression, len(data.scan.V))
    tables = subject_albedo(ground_truth_root, subject)
    S = generator_supersample(ground_truth_root, subject) if supersample is None else int(supersample)
    V_true = true_surface_vertices(ground_truth_root, subject, expression, truth["rest"])
    renders = render_ground_truth(V_true, data.scan.F, truth["rest"], lambda X: evaluate_albedo(X, tables),
                                  truth["sh"], truth["gain"], data.cameras, S, render)
    targets = render_scan_targets(data.scan.V, data.scan.F, data.cameras, cache_path=targets_path, render=render)
    scores = score_renders(renders, np.stack(data.images), targets["coverage"].numpy(),
                           [v.name for v in data.views], out_dir, source=data.scan.path)
    geometry = score_true_geometry(V_true, data.scan.V, data.scan.F, settings or MetricSettings(), data.scan.path)
    return {"subject": str(subject), "expression": expression, "method": ORACLE, "mesh": str(data.scan.path),
            "geometry": geometry, "photometric": scores, "correspondence": None,
            "oracle": {"surface": f"{data.scan.path} vertices at their true positions (the generator's expression "
                       "map of scan_rest_coords)", "albedo": "generator albedo per pixel at the interpolated "
                       "scan_rest_coords, times skin_gain", "lighting": "ground-truth SH", "supersample": S,
                       "skin_gain": truth["gain"].tolist()}}
