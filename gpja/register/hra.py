"""Holistic Rendering Alignment: the paper's colour, depth and normal constraints.

L_color = sum_j |(F_S(x | Pi_j, S, C_T) - P_j) * F_S(x | Pi_j, B)|   (mouth-masked, shaded colour)
L_depth = sum_j |F_D(x | Pi_j) - F_D(scan | Pi_j)|
L_normal = sum_j |F_N(x | Pi_j) - F_N(scan | Pi_j)|

Choices beyond the paper's text, made deliberately:
- Depth and normal differences count only where the scan itself was rendered
  (its coverage): a multiview-stereo scan has holes (top and back of the skull,
  under the chin), and comparing against the empty background there would pull
  the template towards the camera.
- Silhouettes: antialiasing blends the template's depth with the 0 background,
  so a plain |d - d_scan| makes every outline pixel a ~600 mm error whose
  gradient, through the uniform Adam normalisation (one scale for all
  vertices), freezes the rest of the mesh. Since antialiasing blends depth and
  coverage c with the same weights (d = c * d_surface), we compare, weighted
  by the scan's coverage s, |d - c * D_scan| = c * |d_surface - D_scan| (with
  D_scan = d_scan / s, the scan's own un-blended value) and charge the
  coverage the template lacks, relu(s - c), a fixed ``SILHOUETTE_DEPTH_MM``
  (normals: ``SILHOUETTE_NORMAL``). Both terms vanish at a perfect fit, and
  outlines move at a rate comparable to the interior.
- Each constraint is an average over the pixels it counts, so the three have
  comparable scales in the logs (the uniform Adam step is scale-free anyway).
- Optionally (``Schedule.color_gradient: tangential``), the colour constraint moves vertices only along
  the surface (:func:`along_surface`): what a texture can tell is where on the surface a point is;
  how far off the scan it lies is the depth and normal constraints' to say.
"""
from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Sequence

import torch

from gpja.camera import Camera
from gpja.render import RenderOutput, Topology, render_views
from gpja.render.normals import tangential_part

CONSTRAINTS = ("color", "depth", "normal")
#: How the colour constraint's gradient reaches the vertices: all of it (the paper), or only its part in each
#: vertex's tangent plane (:func:`along_surface`).
COLOR_GRADIENTS = ("full", "tangential")
#: Cost of a scan pixel the template does not cover, in the depth constraint's units (mm).
SILHOUETTE_DEPTH_MM = 10.0
#: The same for the normal constraint (units of a normal difference, per channel).
SILHOUETTE_NORMAL = 1.0
#: A pixel's scan coverage above this counts as covered (the targets' antialiased blends leave tiny values
#: outside the scan's outline).
COVERED = 1e-3


@dataclass
class ExpressionTargets:
    """What one expression is registered to (fixed during the optimisation).

    Attributes:
        cameras: B undistorted cameras of one image size.
        images: (B, H, W, 3) float32 reference colours in [0, 1] (linear).
        depth: (B, H, W, 1) scan depth, mm (0 where the scan is absent).
        normal: (B, H, W, 3) scan world normals.
        coverage: (B, H, W, 1) scan coverage in [0, 1].
        sh: (9, 3) SH lighting of the capture (``gpja.lighting`` convention).
        color_scan_px: None = the colour constraint counts wherever the template renders (the paper); else only
            within this many pixels of the scan's coverage (:attr:`color_weight`; ``Schedule.color_scan_px``).
        mask_where_open: False = the mouth mask leaves the socket's pixels out of the colour constraint wherever the
            render shows them (the paper); True = only where the reference shows an opening there
            (:attr:`opening`, :func:`mouth_mask_weight`; ``Schedule.mask_where_open``).
    """

    cameras: Sequence[Camera]
    images: torch.Tensor
    depth: torch.Tensor
    normal: torch.Tensor
    coverage: torch.Tensor
    sh: torch.Tensor
    color_scan_px: int | None = None
    mask_where_open: bool = False

    @functools.cached_property
    def color_weight(self) -> torch.Tensor | None:
        """(B, H, W, 1) float32, 1 within :attr:`color_scan_px` pixels (a square) of a pixel the scan covers at
        all (coverage > :data:`COVERED`), else 0; None without ``color_scan_px``. Made at this resolution: a
        downsampled level counts its own pixels."""
        import torch.nn.functional as F

        if self.color_scan_px is None:
            return None
        k = int(self.color_scan_px)
        covered = (self.coverage.clamp(0.0, 1.0) > COVERED).to(torch.float32).permute(0, 3, 1, 2)
        return F.max_pool2d(covered, 2 * k + 1, stride=1, padding=k).permute(0, 2, 3, 1).contiguous()

    @functools.cached_property
    def opening(self) -> torch.Tensor:
        """(B, H, W, 1) float32, 1 where the reference shows the mouth open (a dark opening,
        :func:`gpja.register.openings.dark_openings`), else 0. Made at this resolution."""
        import numpy as np

        from gpja.register.flow import to_match_u8
        from gpja.register.openings import dark_openings

        images = self.images.double().numpy()
        coverage = self.coverage.double().numpy()[..., 0]
        found = [dark_openings(to_match_u8(images[b], 0.0), coverage[b]) for b in range(len(images))]
        return torch.from_numpy(np.stack(found)[..., None].astype(np.float32))

    def views(self, index: Sequence[int]) -> "ViewSubset":
        """The targets of the views ``index`` (B' view indices, in this order): a random subset per
        iteration (``Schedule.views_per_iteration``). Every loss is a mean over the pixels it counts, so
        its scale does not depend on how many views are rendered. Nothing is copied until a consumer
        reads a whole image (:class:`ViewSubset`)."""
        return ViewSubset(self, torch.as_tensor(list(index), dtype=torch.long))

    def rows(self, name: str, out: RenderOutput) -> torch.Tensor:
        """Rows (R, C) of target ``name`` ("images", "depth", "normal", "coverage") at ``out``'s pixels."""
        return out.gather(getattr(self, name))

    def coverage_total(self) -> torch.Tensor:
        """The scan's clamped coverage summed over every pixel of these views (scalar)."""
        return self.coverage.clamp(0.0, 1.0).sum()

    def downsampled(self, factor: int) -> "ExpressionTargets":
        """The targets at ``1 / factor`` of the resolution (``Schedule.image_factor``): every image
        box-averaged over ``factor x factor`` pixels and each camera resized to match.

        The scan targets are antialiased blends with the background (depth = coverage x the surface's
        depth, module docstring), so their box averages are the blends a ``factor``-times coarser
        render makes: ``depth / coverage`` stays the covered pixels' mean depth.

        Args:
            factor: integer >= 1 dividing the image's width and height (1 = these targets).
        Returns:
            targets of (B, H / factor, W / factor, C) each, cameras ``Camera.resized`` to that size.
        """
        import torch.nn.functional as F

        factor = int(factor)
        if factor == 1:
            return self
        height, width = self.images.shape[1:3]
        if factor < 1 or height % factor or width % factor:
            raise ValueError(f"image factor {factor} must be >= 1 and divide the image size {width} x {height}")

        def pool(t: torch.Tensor) -> torch.Tensor:
            return F.avg_pool2d(t.permute(0, 3, 1, 2), factor).permute(0, 2, 3, 1).contiguous()

        cameras = [c.resized(width // factor, height // factor) for c in self.cameras]
        return ExpressionTargets(cameras, pool(self.images), pool(self.depth), pool(self.normal),
                                 pool(self.coverage), self.sh, self.color_scan_px, self.mask_where_open)


class ViewSubset:
    """Some views of an :class:`ExpressionTargets`, read from its tensors without copying them.

    ``rows`` gathers a render's pixels straight from the full (B, H, W, C) tensors (a render of the subset
    numbers its views 0..B'-1; row ``(b H + y) W + x`` is row ``(index[b] H + y) W + x`` of the whole), so an
    iteration's losses copy no image: the subset of a 4-of-8-view draw was 33 MB of copies an iteration at
    512 px. The whole-image attributes (``images``, ``depth``, ``normal``, ``coverage``) are the same
    tensors :meth:`ExpressionTargets.views` used to build, made on first use, for any consumer that reads
    them whole. Gathered rows and sums are the same numbers as from those copies, to the bit.
    """

    def __init__(self, parent: ExpressionTargets, index: torch.Tensor):
        self.parent, self.index = parent, index
        self.cameras = [parent.cameras[int(i)] for i in index]
        self.sh = parent.sh
        self.mask_where_open = parent.mask_where_open
        self._dense: dict[str, torch.Tensor] = {}
        self._rows: tuple[torch.Tensor, torch.Tensor] | None = None  # (a render's pixels, their rows in the parent)

    def _subset(self, name: str) -> torch.Tensor:
        if name not in self._dense:
            self._dense[name] = getattr(self.parent, name)[self.index]
        return self._dense[name]

    images = property(lambda self: self._subset("images"))
    depth = property(lambda self: self._subset("depth"))
    normal = property(lambda self: self._subset("normal"))
    coverage = property(lambda self: self._subset("coverage"))
    color_weight = property(lambda self: None if self.parent.color_weight is None else self._subset("color_weight"))
    opening = property(lambda self: self._subset("opening"))

    def rows(self, name: str, out: RenderOutput) -> torch.Tensor:
        """Rows (R, C) of target ``name`` at ``out``'s pixels, read from the parent's tensor."""
        full = getattr(self.parent, name)
        pixels = out.pixels
        if self._rows is None or self._rows[0] is not pixels:  # once per render, whichever targets it reads
            per_view = full.shape[1] * full.shape[2]
            self._rows = (pixels, self.index[pixels // per_view] * per_view + pixels % per_view)
        return full.reshape(-1, full.shape[-1])[self._rows[1]]

    coverage_total = ExpressionTargets.coverage_total


@dataclass(frozen=True)
class Switches:
    """Which constraints (and the mouth mask) are used; the ablations turn them off."""

    color: bool = True
    depth: bool = True
    normal: bool = True
    mask: bool = True

    def rotation(self) -> tuple[str, ...]:
        """The constraints back-propagated in turn, one per iteration (paper: colour -> depth -> normal)."""
        active = tuple(c for c in CONSTRAINTS if getattr(self, c))
        if not active:
            raise ValueError("every constraint is switched off: nothing to optimise")
        return active


def passes_for(constraint: str, switches: Switches) -> tuple[str, ...]:
    """Render passes one constraint needs."""
    if constraint == "color":
        return ("color", "mask") if switches.mask else ("color",)
    return (constraint,)


def mouth_mask_weight(mask: torch.Tensor, coverage: torch.Tensor, opening: torch.Tensor | None) -> torch.Tensor:
    """The colour constraint's per-pixel weight from the render's mouth-mask pass.

    Args:
        mask, coverage: (..., 1) the render's mask pass (0 on the mouth's socket and the background, 1 on the rest of
            the head) and its coverage, at the same pixels.
        opening: (..., 1) the reference's openings there (``ExpressionTargets.opening``), or None (the paper).
    Returns:
        ``mask`` (the paper: the socket never counts), or with ``opening`` ``mask + (coverage - mask)+ (1 - opening)``:
        the socket counts where the reference shows no opening. There the socket's own dark texture is compared
        with the lips or skin the reference shows, so socket material left over a closed mouth's lips costs
        (docs/experiments.md, "The mouth mask only where the reference shows the mouth open").
    """
    if opening is None:
        return mask
    return mask + (coverage - mask).clamp_min(0.0) * (1.0 - opening)


def pooled_color_l1(out: RenderOutput, targets: ExpressionTargets | ViewSubset, weight_pass: str, pool: int) -> torch.Tensor:
    """Mean L1 of the weighted colour after ``pool x pool`` box averaging of render and reference.

    The comparison at a coarser image scale (beyond the paper, off by default): a feature that is many
    pixels from its place in the reference (a lip left at the template's open position) still overlaps
    it after pooling, so the colour gradient reaches it.

    Args:
        out: a render with the "color" pass and ``weight_pass`` ("mask" or "coverage").
        pool: box size in pixels (> 1).
    Returns:
        scalar tensor: sum |pool(w * render) - pool(w * reference)| / (3 * sum pool(w)).
    """
    import torch.nn.functional as F

    weight = out.dense(weight_pass)  # (B, H, W, 1)
    if weight_pass == "mask" and targets.mask_where_open:
        weight = mouth_mask_weight(weight, out.dense("coverage"), targets.opening.to(weight.dtype))
    if targets.color_weight is not None:
        weight = weight * targets.color_weight
    render = (out.dense("color") * weight).permute(0, 3, 1, 2)
    reference = (targets.images.to(render.dtype) * weight).permute(0, 3, 1, 2)
    diff = F.avg_pool2d(render, pool, ceil_mode=True) - F.avg_pool2d(reference, pool, ceil_mode=True)
    total = F.avg_pool2d(weight.detach().permute(0, 3, 1, 2), pool, ceil_mode=True).sum()
    return diff.abs().sum() / total.clamp_min(1e-6) / 3.0


def constraint_loss(constraint: str, out: RenderOutput, targets: ExpressionTargets | ViewSubset, switches: Switches,
                    color_pool: int = 1) -> torch.Tensor:
    """Mean absolute difference of one constraint over the pixels it counts.

    Args:
        constraint: "color", "depth" or "normal".
        out: a render with the passes from ``passes_for``.
        color_pool: compare colours after box-averaging this many pixels (1 = per pixel, the paper).
    Returns:
        scalar tensor (differentiable in the render).
    """
    if constraint == "color":
        # the mask pass is 0 on the mouth interior and on the background, 1 on the rest of the head
        weight_pass = "mask" if switches.mask else "coverage"
        if color_pool > 1:
            return pooled_color_l1(out, targets, weight_pass, color_pool)
        weight = out.values[weight_pass]
        if weight_pass == "mask" and targets.mask_where_open:
            weight = mouth_mask_weight(weight, out.values["coverage"], targets.rows("opening", out).to(weight.dtype))
        if targets.color_weight is not None:  # only near what the scan covers (Schedule.color_scan_px)
            weight = weight * targets.rows("color_weight", out)
        # image_l1's weighted sum, with the reference's rows gathered by the targets (no subset copied)
        loss = ((out.values["color"] - targets.rows("images", out)).abs() * weight).sum()
        return loss / weight.detach().sum().clamp_min(1.0) / 3.0
    target = "depth" if constraint == "depth" else "normal"
    kappa = SILHOUETTE_DEPTH_MM if constraint == "depth" else SILHOUETTE_NORMAL
    # Antialiased values are blends with the 0 background; on thin features a pixel can give
    # weight to several neighbours, so blended coverage may leave [0, 1] (depth follows it
    # consistently, d = c * D). Un-blend where the coverage is clearly non-zero, weight by the
    # clamped coverage.
    raw_scan = targets.rows("coverage", out)  # (R, 1)
    scan = raw_scan.clamp(0.0, 1.0)
    valid = raw_scan.abs() > COVERED
    target_rows = targets.rows(target, out)
    scan_value = torch.where(valid, target_rows / torch.where(valid, raw_scan, torch.ones_like(raw_scan)),
                             torch.zeros_like(raw_scan))
    cover = out.values["coverage"]
    inside = (scan * (out.values[constraint] - cover * scan_value).abs()).sum() / target_rows.shape[-1]
    missing = torch.relu(scan - cover.clamp(0.0, 1.0)).sum()
    # scan pixels outside the render's rows are wholly uncovered: a constant for the gradient
    total = targets.coverage_total()
    outside = total - scan.sum()
    return (inside + kappa * (missing + outside.detach())) / total.clamp_min(1.0)


def render_constraint(constraint: str, V: torch.Tensor, topology: Topology, targets: ExpressionTargets | ViewSubset,
                      switches: Switches, uv: torch.Tensor, texture: torch.Tensor, mask_texture: torch.Tensor,
                      render=None, cull_backfaces: bool = True, color_pool: int = 1) -> tuple[torch.Tensor, RenderOutput]:
    """Render what one constraint needs and return its loss and the render.

    ``render``: the backend's ``render_views`` (``gpja.render.renderer``); None = the CPU renderer.
    ``cull_backfaces``: the template is a closed surface, so back faces are never
    visible and skipping them halves the rasterisation (the CPU backend).
    """
    render = render or render_views
    out = render(V, topology, targets.cameras, passes_for(constraint, switches), uv=uv, texture=texture,
                 mask_texture=mask_texture, sh=targets.sh, cull_backfaces=cull_backfaces)
    return constraint_loss(constraint, out, targets, switches, color_pool), out


class _AlongSurface(torch.autograd.Function):
    """Identity forward; backward keeps each vertex's gradient in the plane orthogonal to its normal."""

    @staticmethod
    def forward(ctx, V: torch.Tensor, normals: torch.Tensor) -> torch.Tensor:
        ctx.save_for_backward(normals)
        return V.view_as(V)

    @staticmethod
    def backward(ctx, grad: torch.Tensor):
        (n,) = ctx.saved_tensors
        return tangential_part(grad, n), None


def along_surface(V: torch.Tensor, faces: torch.Tensor) -> torch.Tensor:
    """``V`` unchanged, whose gradient reaches the vertices only along the surface.

    Why (docs/experiments.md, "The nose slides"): with the estimated lighting the
    colour loss also has a gradient along the normals (on the template's nose it is along the normal at every
    vertex: the colour "wants" the nose smaller), which the depth constraint undoes along the view rays;
    the two steps do not cancel on a slope, and their sum slides the surface. Dropping the normal part
    leaves colour the tangential alignment that only it can see.

    Args:
        V: (n, 3) float32/float64 vertex positions, mm, part of the autograd graph.
        faces: (m, 3) int64 triangles (counter-clockwise from outside).
    Returns:
        (n, 3) the same values; backward: ``g - (g . n) n`` per vertex, ``n`` the area-weighted unit normal
        of the (detached) current positions.
    """
    from gpja.render import vertex_normals

    normals = vertex_normals(V.detach(), faces).to(V.dtype)
    return _AlongSurface.apply(V, normals)
