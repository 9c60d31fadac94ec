"""Optical-flow correspondences (beyond the paper, ``Schedule.flow_rounds``): image matching before the descent.

Why (docs/experiments.md, "Issue 15"): GPJA's colour constraint is a per-pixel L1 descended by a
first-order optimiser, so its basin is about as wide as the texture's features (a few pixels, ~1 mm
a pixel at 512^2). The jaw of the mouth-open template is 15-25 mm from a closed mouth's, far
outside it, and the free-form descent slides what no constraint pins (nose, neck) while it chases
the lips. Dense image matching has the wide basin the descent lacks: a coarse-to-fine optical flow
(OpenCV's DIS, Kroeger et al. 2016) between the start mesh rendered with the shared texture and
each reference photograph says, for every visible pixel, where that surface point went, tens of
pixels away.

One round:

1. Render the mesh with the shared texture and the capture's lighting in every view (the colour
   the colour constraint compares), and its depth (visibility). With ``scan_shading_px`` (beyond the stage
   as first written) the render is shaded by the scan's normals where it lies on the scan, as the texture's
   fusion divided the photographs by them (:func:`shade_by_scan`), except in the first ``own_shading_rounds``.
2. Flow render -> reference and reference -> render per view, on gamma-encoded grey images.
3. Each vertex visible in a view (its depth matches the rendered depth, it faces the camera, it is
   not in the mouth socket) moves to ``p' = p + flow(p)`` in that view. The match is kept when the
   backward flow returns it (``|flow(p) + back(p')|`` below a pixel tolerance) and the scan covers
   ``p'``; its 3D target is the scan's point seen at ``p'`` (the cached scan depth, unprojected).
4. A vertex's targets from several views are combined by their median; views further than
   ``spread`` mm from it are dropped. With ``still_mm`` > 0 (beyond the stage as first written), a
   combined target closer than that to its vertex becomes the vertex itself: a match that says "hardly
   moved" is read as "did not move" (below, ``match_round``).
5. The mesh moves by the smooth displacement ``d`` minimising
   ``sum_i w_i |x_i + d_i - t_i|^2 + mu |L d|^2`` (``L`` the graph Laplacian normalised by the
   degree, so ``mu`` does not depend on the resolution), re-weighted twice by the residual
   (``w_i / (1 + (r_i / spread)^2)``) so that a few bad matches do not pull a neighbourhood.
   Vertices without a target (socket, back of the head, hidden neck) follow their neighbours; a weak
   pull towards no motion (``STAY_WEIGHT``) keeps those far from any match in place.

The rounds repeat with the moved mesh (each flow then only corrects what is left). The result is a
start whose features already sit where the reference's are; the paper's levels then refine it.
No ground truth is read: only the reference images, the scan's depth and the shared texture.
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Callable

import numpy as np
import scipy.sparse as sp
import torch

from gpja.camera import Camera
from gpja.cholesky import DEFAULT_BACKEND
from gpja.mesh import TexturedMesh
from gpja.register.hra import ExpressionTargets
from gpja.register.openings import dark_openings

#: gamma applied to linear colours before matching (flow works on perceptual contrast)
MATCH_GAMMA = 1.0 / 2.2
#: a vertex is visible in a view when its depth is within this of the rendered depth (mm)
VISIBLE_DEPTH_MM = 1.0
#: and when the cosine between its normal and the direction to the camera is at least this
MIN_FACING = 0.3
#: residual re-weighting passes of the smooth solve
REWEIGHT_PASSES = 2
#: a view's reference shows the mouth open when the opening's pixels beside the render's socket are at least this
#: fraction of the socket's (measured: 0.19-0.45 for the lip funnelers' references, 0 for every closed mouth's)
OPENING_MIN_FRACTION = 0.1
#: weight of the pull of every vertex towards no motion, relative to a match's (1)
STAY_WEIGHT = 1e-3
#: relative residual at which the preconditioned solves of the re-weighted systems stop, and their most
#: iterations before a refactorisation (S01 13_lip_funneler at 100K vertices: 25 and 41 iterations,
#: 1e-4 mm from factorising every pass; a factor shared between rounds needed refactorising: the
#: matches change too much)
SOLVE_RTOL = 1e-6
SOLVE_MAX_CG = 100
#: The pyramid level OpenCV's DIS medium preset stops at (half size): the flow stages as first written.
PRESET_FINEST_SCALE = 1
#: ``FlowSettings.scan_shading_px``: a pixel the scan covers fully (``lighting_estimate.MIN_COVERAGE``, the lighting
#: estimate's test) is shaded by the scan's normal where the render's depth lies within these (mm) of the scan's: wholly up to the first, not from the second
#: on, linear between. A part the expression moves by more (an open jaw over a closed one) keeps its own shading,
#: whose shadows and highlights move with it and guide the flow over tens of pixels.
SCAN_SHADING_NEAR_MM = (0.5, 1.5)


@dataclass(frozen=True)
class FlowSettings:
    """One flow stage's parameters.

    Attributes:
        rounds: render -> flow -> move rounds (0 = off).
        smoothness: ``mu`` of the displacement's smoothness (dimensionless; larger = stiffer).
        fb_tolerance_px: forward-backward flow disagreement (px) above which a match is dropped.
        spread_mm: views whose target is further than this from the vertex's median target are
            dropped, and the residual re-weighting's scale (mm).
        still_mm: a target closer than this to its vertex is replaced by the vertex (0 = off, the stage as
            first written; ``match_round``).
        chroma: weight of the red-green chroma in the matched channel (0 = luminance alone, the stage as
            first written; :func:`to_match_u8`).
        finest_scale: the finest pyramid level DIS flow computes its field at (0 = the full image; 1 = half size and
            upsampled, OpenCV's medium preset and the stage as first written; :func:`dense_flow`).
        scan_shading_px: None = the render is shaded by the mesh's own normals (the stage as first written); a
            number = by the scan's normal images blurred by this Gaussian sigma (px) where the scan covers the
            pixel and the render lies on it (:func:`shade_by_scan`); the texture fusion's ``fusion_normal_blur_px``
            is the consistent value.
        socket_margin_px: beyond the stage as first written (0 = off): in a view whose reference shows the mouth
            closed (no dark opening, :func:`gpja.register.openings.dark_openings`, beside the render's socket:
            ``OPENING_MIN_FRACTION``), a vertex whose pixel in the render lies within this many pixels of the
            mouth's socket (the rendered mouth mask) does not match. DIS's patches there straddle a dark socket the
            reference does not show: from the lip funneler's start, the flow slid the middle of S01 ``1_neutral``'s
            lower lip 4-5 mm sideways (docs/experiments.md, "Flow matches beside the socket"; measured, not the
            default).
        own_shading_rounds: with ``scan_shading_px``, the first this many rounds still shade by the mesh's own
            normals: a first stage's first round follows motions of tens of pixels (a closing jaw), whose shadows
            move with the surface; the later rounds only correct what is left.
        cholesky: the backend of the displacement solve's factor (:mod:`gpja.cholesky`): ``"simplicial"``
            (cholespy, the stage as first written, the default) or ``"supernodal"``, which factors the
            40K-vertex level's system 8x faster (the two flow stages 15.7 -> 11.8 s). The displacements
            agree to rounding, but a registration amplifies last bits: in the clean-clone run at ``c19c2fb``
            that rounding sent S01 ``1_neutral`` to C.D. 0.176 mm (0.030 before; docs/experiments.md).
    """

    rounds: int = 3
    smoothness: float = 30.0
    fb_tolerance_px: float = 1.0
    spread_mm: float = 2.0
    still_mm: float = 0.0
    chroma: float = 0.0
    finest_scale: int = PRESET_FINEST_SCALE
    cholesky: str = DEFAULT_BACKEND
    scan_shading_px: float | None = None
    own_shading_rounds: int = 0
    socket_margin_px: float = 0.0


def to_grey_u8(image: np.ndarray) -> np.ndarray:
    """(H, W, 3) linear colours in [0, 1] -> (H, W) uint8 gamma-encoded luminance (``to_match_u8`` without chroma)."""
    return to_match_u8(image, 0.0)


def red_green_chroma(image: np.ndarray) -> np.ndarray:
    """(H, W, 3) linear colours -> (H, W) float64 ``(R - G) / (R + G + B)``, in [-1, 1] (0 where black)."""
    total = image.sum(-1)
    return (image[..., 0] - image[..., 1]) / np.maximum(total, 1e-3)


def to_match_u8(image: np.ndarray, chroma: float) -> np.ndarray:
    """(H, W, 3) linear colours in [0, 1] -> (H, W) uint8 channel the optical flow matches.

    ``(Y + chroma * C) / (1 + chroma)`` with ``Y`` the gamma-encoded luminance and ``C`` the clipped
    red-green chroma (:func:`red_green_chroma`, in [0, 1]). DIS flow takes one 8-bit channel, and
    luminance alone cannot see the lips: on the synthetic references the vermilion and the skin around
    it differ by 0.01 in gamma luminance (skin texture: 0.02-0.05) but by 0.2 in this chroma (skin:
    0.005-0.02), so the lip's outline, the one feature that says where a closed lip's material went,
    is flat in the grey image (docs/experiments.md, "The lips are invisible to the flow"). The same
    linear map is applied to the render and the reference.
    """
    grey = np.clip(image @ np.array([0.299, 0.587, 0.114]), 0.0, 1.0) ** MATCH_GAMMA
    if chroma > 0:
        grey = (grey + chroma * np.clip(red_green_chroma(image), 0.0, 1.0)) / (1.0 + chroma)
    return np.clip(255.0 * grey + 0.5, 0, 255).astype(np.uint8)


def dense_flow(source: np.ndarray, target: np.ndarray, finest_scale: int = PRESET_FINEST_SCALE) -> np.ndarray:
    """(H, W, 2) float32 flow (px) taking ``source`` pixels to ``target`` (uint8 (H, W) images).

    OpenCV's DIS flow (coarse-to-fine patch search with variational refinement): it reaches
    displacements of tens of pixels, which is why it is used rather than a local descent. Its medium
    preset, with ``finest_scale`` the pyramid level it stops at: the preset's 1 computes the field at half
    size and upsamples it; 0 computes it on the full image (about 4x the time: 15 -> 59 ms at 512^2 on one
    thread), which on the first hops' starts lowers the matches' error on the skin, brows and nose by a
    fifth to a third (docs/experiments.md, "The optical flow on the full image").
    """
    import cv2

    dis = cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_MEDIUM)
    dis.setFinestScale(int(finest_scale))
    return dis.calc(source, target, None)


def within(region: np.ndarray, margin_px: float) -> np.ndarray:
    """(H, W) bool: pixels closer than ``margin_px`` to a pixel of ``region`` (H, W) bool (OpenCV's exact
    Euclidean distance transform)."""
    import cv2

    if not region.any():
        return np.zeros(region.shape, dtype=bool)
    distance = cv2.distanceTransform((~region).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    return distance < float(margin_px)


def bilinear(image: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """``image`` (H, W, C) float64 sampled at pixel positions ``xy`` (n, 2) (centres at integers, clamped).

    Written here rather than ``cv2.remap``: remap quantises the sub-pixel weights to 1/32 px and
    works in float32, and the flow's sub-pixel positions are what the matches are made of.
    """
    h, w = image.shape[:2]
    x = np.clip(xy[:, 0], 0.0, w - 1.0)
    y = np.clip(xy[:, 1], 0.0, h - 1.0)
    x0 = np.minimum(np.floor(x).astype(np.int64), w - 2)
    y0 = np.minimum(np.floor(y).astype(np.int64), h - 2)
    fx = (x - x0)[:, None]
    fy = (y - y0)[:, None]
    return ((1 - fx) * (1 - fy) * image[y0, x0] + fx * (1 - fy) * image[y0, x0 + 1]
            + (1 - fx) * fy * image[y0 + 1, x0] + fx * fy * image[y0 + 1, x0 + 1])


def unproject(camera: Camera, xy: np.ndarray, depth: np.ndarray) -> np.ndarray:
    """World points (n, 3) mm at pixels ``xy`` (n, 2) of an undistorted camera and camera depths (n,) mm."""
    xn = camera.pixels_to_normalized(xy)
    Xc = np.concatenate([xn * depth[:, None], depth[:, None]], axis=1)
    return (Xc - camera.t) @ camera.R


def view_matches(camera: Camera, V: np.ndarray, normals: np.ndarray, use: np.ndarray, render_grey: np.ndarray,
                 render_depth: np.ndarray, reference_grey: np.ndarray, scan_depth: np.ndarray,
                 scan_coverage: np.ndarray, fb_tolerance_px: float, finest_scale: int = PRESET_FINEST_SCALE,
                 socket: np.ndarray | None = None, socket_margin_px: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """The matched scan points of the vertices in one view.

    Args:
        V, normals: (n, 3) float64 vertex positions (mm) and unit normals.
        use: (n,) bool vertices allowed to match (not in the mouth socket).
        render_grey, reference_grey: (H, W) uint8 (``to_match_u8``).
        render_depth: (H, W) float64 the mesh's camera depth, mm (0 = empty).
        scan_depth, scan_coverage: (H, W) float64 the scan's depth (mm) and coverage in [0, 1].
        finest_scale: :func:`dense_flow`'s.
        socket, socket_margin_px: (H, W) bool the render's socket pixels and ``FlowSettings.socket_margin_px``:
            where the reference shows no opening beside the socket, the vertices within the margin of it do not
            match (None or 0 = every match is kept).
    Returns:
        targets: (n, 3) float64 scan points, mm (NaN where no match); facing: (n,) the cosine weight.
    """
    n = len(V)
    xy, z = camera.project(V)
    h, w = render_grey.shape
    inside = (xy[:, 0] >= 0) & (xy[:, 0] <= w - 1) & (xy[:, 1] >= 0) & (xy[:, 1] <= h - 1) & (z > 0)
    pix = np.clip(np.rint(xy).astype(np.int64), 0, [w - 1, h - 1])
    seen = render_depth[pix[:, 1], pix[:, 0]]
    to_camera = camera.center[None, :] - V
    facing = (normals * to_camera).sum(1) / np.linalg.norm(to_camera, axis=1)
    ok = use & inside & (seen > 0) & (np.abs(seen - z) < VISIBLE_DEPTH_MM) & (facing >= MIN_FACING)
    targets = np.full((n, 3), np.nan)
    if not ok.any():
        return targets, facing
    forward = dense_flow(render_grey, reference_grey, finest_scale)
    backward = dense_flow(reference_grey, render_grey, finest_scale)
    p = xy[ok]
    f = bilinear(forward, p)
    q = p + f
    back = bilinear(backward, q)
    qi = np.clip(np.rint(q).astype(np.int64), 0, [w - 1, h - 1])
    good = ((np.linalg.norm(f + back, axis=1) < fb_tolerance_px)
            & (q[:, 0] >= 0) & (q[:, 0] <= w - 1) & (q[:, 1] >= 0) & (q[:, 1] <= h - 1)
            & (scan_coverage[qi[:, 1], qi[:, 0]] > 0.999))
    if socket is not None and socket_margin_px > 0 and socket.any():
        dark = dark_openings(reference_grey, scan_coverage, within_head=False)
        beside = within(socket, socket_margin_px)
        if (dark & beside).sum() < OPENING_MIN_FRACTION * socket.sum():  # the reference's mouth is closed
            good &= ~beside[pix[ok, 1], pix[ok, 0]]
    cov = bilinear(scan_coverage[..., None], q[good])[:, 0]
    dep = bilinear(scan_depth[..., None], q[good])[:, 0] / np.maximum(cov, 1e-6)
    idx = np.flatnonzero(ok)[good]
    targets[idx] = unproject(camera, q[good], dep)
    return targets, facing


def combine_views(per_view: np.ndarray, spread_mm: float) -> tuple[np.ndarray, np.ndarray]:
    """Per-vertex target from its views' targets.

    Args:
        per_view: (B, n, 3) float64 targets, NaN where a view has none.
    Returns:
        target: (n, 3) float64 (NaN where none); count: (n,) int views that agree within ``spread_mm``
        of the per-vertex median.
    """
    seen = np.isfinite(per_view).all(2).any(0)
    median = np.full(per_view.shape[1:], np.nan)
    median[seen] = np.nanmedian(per_view[:, seen], axis=0)
    with np.errstate(invalid="ignore"):
        close = np.linalg.norm(per_view - median[None], axis=2) <= spread_mm
    count = close.sum(0)
    summed = np.where(close[..., None], per_view, 0.0).sum(0)
    target = np.where(count[:, None] > 0, summed / np.maximum(count, 1)[:, None], np.nan)
    return target, count


def smoothness_matrix(F: np.ndarray, n: int) -> sp.csr_matrix:
    """(n, n) ``Ln^T Ln`` with ``Ln = I - D^-1 A`` the degree-normalised graph Laplacian."""
    from gpja.register.laplacian import uniform_laplacian

    L = uniform_laplacian(np.zeros((n, 3)), F)
    degree = np.asarray(L.diagonal()).clip(1.0)
    Ln = sp.diags(1.0 / degree) @ L
    return (Ln.T @ Ln).tocsr()


def smoothness_system(F: np.ndarray, n: int, smoothness: float) -> sp.csr_matrix:
    """(n, n) ``mu Ln^T Ln + STAY_WEIGHT I``: the part of the displacement's normal equations that the matches
    do not change (one per stage: building it costs ~1 s at 100K vertices)."""
    return (smoothness * smoothness_matrix(F, n) + sp.identity(n) * STAY_WEIGHT).tocsr()


def solve_displacement(V: np.ndarray, F: np.ndarray, target: np.ndarray, weight: np.ndarray, smoothness: float,
                       spread_mm: float, system: sp.spmatrix | None = None, backend: str = DEFAULT_BACKEND) -> np.ndarray:
    """The smooth displacement (n, 3) mm that takes weighted vertices towards their targets (module docstring).

    The first pass's system is factorised; the re-weighted passes change only the weights of the matches,
    so conjugate gradients preconditioned by that factor and started from the previous pass's
    displacement solve them (``AffineSolver``; it refactorises when CG does not converge): a pass takes
    15-40 preconditioned iterations. At 40K vertices the ``"supernodal"`` factor takes 0.44 s to build and
    0.045 s to apply, the ``"simplicial"`` one 3.7 s and 0.019 s (``benchmarks/bench_cholesky.py``).
    Factorising every pass with the supernodal factor instead would save another 3 s a registration,
    but its exact solves differ from the preconditioned ones by 1e-5 mm, and that moved a whole
    registration's correspondence median by 0.035 mm (docs/benchmarks.md, "Sparse Cholesky").

    ``system``: :func:`smoothness_system` of ``F``, when the caller has it. ``backend``: the factor's
    :mod:`gpja.cholesky` backend (``FlowSettings.cholesky``).
    """
    from gpja.baselines.nicp_solver import AffineSolver

    n = len(V)
    has = np.isfinite(target).all(1) & (weight > 0)
    residual = np.where(has[:, None], target - V, 0.0)
    # the small pull to no motion keeps vertices far from every match (the back of the head, a refined
    # mesh's socket) where they are; the smoothness alone would extrapolate the matches' motion linearly
    S = smoothness_system(F, n, smoothness) if system is None else system
    solver = AffineSolver(rtol=SOLVE_RTOL, max_cg=SOLVE_MAX_CG, backend=backend)
    w = np.where(has, weight, 0.0)
    d = np.zeros_like(V)
    for _ in range(REWEIGHT_PASSES + 1):
        d = solver.solve((S + sp.diags(w)).tocsr(), w[:, None] * residual, d, smoothness)
        r = np.linalg.norm(d - residual, axis=1)
        w = np.where(has, weight / (1.0 + (r / spread_mm) ** 2), 0.0)
    return d


def socket_vertices(mesh: TexturedMesh, mask_texture: torch.Tensor) -> np.ndarray:
    """(n,) bool: the vertices of ``mesh`` whose texture the mouth mask leaves out (the socket, the mouth's
    interior). ``mask_texture``: (T, T, 1) float mouth mask in [0, 1] (0 = socket). A vertex on a UV seam has
    several texture coordinates; any one of them tells socket from skin (the last written is sampled)."""
    from gpja.render import sample_texture

    uv_of_vertex = np.zeros((len(mesh.V), 2))
    uv_of_vertex[mesh.F.ravel()] = mesh.UV[mesh.F_uv.ravel()]
    inside = sample_texture(mask_texture.float(), torch.tensor(uv_of_vertex, dtype=torch.float32))[:, 0].numpy()
    return inside <= 0.5


def shade_by_scan(albedo: np.ndarray, render_depth: np.ndarray, own_colour: np.ndarray, scan_normal: np.ndarray,
                  scan_depth: np.ndarray, scan_coverage: np.ndarray, sh: torch.Tensor, blur_px: float) -> np.ndarray:
    """One view's render, shaded by the scan's normals where the rendered surface lies on the scan.

    Why (``FlowSettings.scan_shading_px``; docs/experiments.md, "The flow's render shaded by the scan"): the shared
    texture is the photographs divided by the shading of the scan's blurred normals (``fusion_scan_normals``), and
    the template is a decimation of the dense fit those texels were read on. On the nose its interpolated normals
    differ from the scan's, and so does its shading: the template rendered against its own expression's references
    gives a flow of 0.9-1.3 px on the nose in the side views, 0.1 px on the rest of the face. The flow reads that
    as motion and slides the nose along the surface. Shaded by the scan's normals, the same render gives 0.1-0.4 px.
    Only where the render's depth is within :data:`SCAN_SHADING_NEAR_MM` of the scan's (a ramp between the two):
    elsewhere the pixel shows another part of the surface than the scan does (the chin of an open jaw over a
    closed one's neck), and the shading of its own shape is what lets the flow follow it.

    Args:
        albedo: (H, W, 3) float64 the render's texture colour (linear). render_depth: (H, W) float64 camera depth
            of the render, mm (0 = empty). own_colour: (H, W, 3) float64 the render shaded by the mesh's normals.
        scan_normal: (H, W, 3) float world unit normals of the scan; scan_depth: (H, W) float its camera depth,
            mm; scan_coverage: (H, W) float in [0, 1].
        sh: (9, 3) the capture's SH lighting. blur_px: Gaussian sigma (px) of the normals' blur (0 = none).
    Returns:
        (H, W, 3) float64 linear colour.
    """
    from gpja.lighting import shade_lambertian
    from gpja.register.lighting_estimate import MIN_COVERAGE, blurred_normals

    normal = np.asarray(scan_normal, dtype=np.float64)
    if blur_px > 0:
        normal = blurred_normals(normal, scan_coverage, float(blur_px)).astype(np.float64)
    near, far = SCAN_SHADING_NEAR_MM
    gap = np.abs(np.asarray(render_depth) - np.asarray(scan_depth))
    weight = np.clip((far - gap) / (far - near), 0.0, 1.0)
    use = (np.asarray(render_depth) > 0) & (np.asarray(scan_coverage) >= MIN_COVERAGE) & (weight > 0)
    out = np.array(own_colour, dtype=np.float64)
    shaded = shade_lambertian(torch.from_numpy(albedo[use]), torch.from_numpy(normal[use]), sh.double()).numpy()
    w = weight[use][:, None]
    out[use] = w * shaded + (1.0 - w) * out[use]
    return out


def match_round(mesh: TexturedMesh, targets: ExpressionTargets, texture: torch.Tensor, mask_texture: torch.Tensor,
                settings: FlowSettings, render: Callable | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The flow targets of ``mesh``'s vertices: target (n, 3) mm (NaN = none) and weight (n,).

    ``settings.still_mm``: why a small match is taken as no motion. Below a pixel (about 1 mm at 512^2) the
    flow's answer is its bias, not the surface's motion: on the nose, where nothing moves between two
    expressions, every flow stage of the default schedule slid the vertices 0.2-0.3 mm down the slopes
    (docs/experiments.md, "The nose slides"). Read as "stays", such a match holds its vertex where the
    descent left it, and the descent, whose basin is a few pixels, aligns what is left. Large motions (a
    closing jaw, 5-20 mm) are kept as they are. ``settings.scan_shading_px``: :func:`shade_by_scan`.
    """
    from gpja.render import Topology, render_views, sample_texture, vertex_normals

    render = render or render_views
    V = torch.tensor(mesh.V, dtype=torch.float32)
    topo = Topology(torch.from_numpy(mesh.F), torch.from_numpy(mesh.F_uv))
    by_scan = settings.scan_shading_px is not None
    passes = ("color", "depth", "mask", "uv") if by_scan else ("color", "depth", "mask")
    scan_depth = targets.depth.double().numpy()[..., 0]
    scan_cov = targets.coverage.double().numpy()[..., 0]
    with torch.no_grad():
        out = render(V, topo, targets.cameras, passes, uv=torch.tensor(mesh.UV, dtype=torch.float32),
                     texture=texture, mask_texture=mask_texture, sh=targets.sh, antialias_edges=False,
                     cull_backfaces=True)
        colour = out.dense("color").double().numpy()
        depth = out.dense("depth").double().numpy()[..., 0]
        # the socket's pixels (rendered mouth mask 0), only where the margin needs them
        socket = ((out.dense("mask")[..., 0] < 0.5).numpy() & (depth > 0) if settings.socket_margin_px > 0
                  else [None] * len(targets.cameras))
        normals = vertex_normals(torch.from_numpy(mesh.V), torch.from_numpy(mesh.F)).numpy()
        if by_scan:
            uv = out.dense("uv")
            albedo = sample_texture(texture.float(), uv.reshape(-1, 2).float()).double().numpy().reshape(colour.shape)
            scan_normals = targets.normal.double().numpy()
            colour = np.stack([shade_by_scan(albedo[b], depth[b], colour[b], scan_normals[b], scan_depth[b],
                                             scan_cov[b], targets.sh, float(settings.scan_shading_px))
                               for b in range(len(targets.cameras))])
    # the socket: vertices whose texture is masked out (mouth interior) do not match
    use = ~socket_vertices(mesh, mask_texture)
    images = targets.images.double().numpy()
    per_view = np.full((len(targets.cameras), len(mesh.V), 3), np.nan)
    for b, camera in enumerate(targets.cameras):
        per_view[b], _ = view_matches(
            camera, mesh.V, normals, use, to_match_u8(colour[b], settings.chroma), depth[b],
            to_match_u8(images[b], settings.chroma), scan_depth[b],
            scan_cov[b], settings.fb_tolerance_px, settings.finest_scale,
            socket[b], settings.socket_margin_px)
    target, count = combine_views(per_view, settings.spread_mm)
    if settings.still_mm > 0:
        still = np.isfinite(target).all(1) & (np.linalg.norm(target - mesh.V, axis=1) < settings.still_mm)
        target[still] = mesh.V[still]
    return target, count.astype(np.float64)


def align_by_flow(mesh: TexturedMesh, targets: ExpressionTargets, texture: torch.Tensor, mask_texture: torch.Tensor,
                  settings: FlowSettings, render: Callable | None = None,
                  progress: Callable[[str], None] = print) -> tuple[TexturedMesh, dict]:
    """Move ``mesh`` by ``settings.rounds`` rounds of flow matching (module docstring).

    Args:
        mesh: the start (mm) with UVs; its topology is kept.
        texture: (T, T, 3) shared albedo; mask_texture: (T', T', 1) mouth mask (0 = socket).
    Returns:
        the moved mesh and a log entry (per round: matched fraction, median and 95th percentile move, mm).
    """
    import time

    start = time.perf_counter()
    rounds = []
    base = mesh
    system = smoothness_system(base.F, len(base.V), settings.smoothness)  # the same every round
    for k in range(int(settings.rounds)):
        shading = settings if k >= settings.own_shading_rounds else replace(settings, scan_shading_px=None)
        target, weight = match_round(mesh, targets, texture, mask_texture, shading, render)
        matched = np.isfinite(target).all(1)
        # the whole displacement from the start is re-solved each round, so the matches' noise does not add up
        d = solve_displacement(base.V, base.F, target, weight, settings.smoothness, settings.spread_mm, system,
                               settings.cholesky)
        move = np.linalg.norm(base.V + d - mesh.V, axis=1)
        mesh = base.with_vertices(base.V + d)
        entry = {"matched_fraction": round(float(matched.mean()), 4), "median_move_mm": round(float(np.median(move)), 4),
                 "p95_move_mm": round(float(np.percentile(move, 95)), 4), "max_move_mm": round(float(move.max()), 3)}
        rounds.append(entry)
        progress(f"flow round {k + 1}/{settings.rounds}: {100 * entry['matched_fraction']:.0f}% of the vertices "
                 f"matched, moved median {entry['median_move_mm']:.2f} mm, p95 {entry['p95_move_mm']:.2f} mm")
    return mesh, {"stage": "flow", "rounds": rounds, "vertices": int(len(mesh.V)),
                  "seconds": round(time.perf_counter() - start, 3)}
