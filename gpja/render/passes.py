"""The CPU renderer: the paper's passes (shaded colour F_S, depth F_D, normals F_N, mouth mask, coverage).

All passes of one call share one rasterisation and one antialiasing step, so
asking for several costs little more than asking for one. The output types are
in ``gpja.render.output``; ``gpja.render.backend`` picks this renderer or nvdiffrast.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np
import torch

from gpja.camera import Camera
from gpja.lighting import shade_lambertian
from gpja.render.fragments import rasterize_fragments
from gpja.render.interpolate import interpolate_attribute, interpolate_rows
from gpja.render.normals import normalize_rows, vertex_normals
from gpja.render.output import ALL_PASSES, CHANNELS, PASSES, RenderOutput, Topology, check_render_input
from gpja.render.project import project_to_screen
from gpja.render.silhouettes import blend_across_edges, edge_crossings, find_edge_pairs
from gpja.render.texture import sample_texture


def render_views(
    V: torch.Tensor,
    topology: Topology | torch.Tensor,
    cameras: Sequence[Camera],
    passes: Sequence[str] = PASSES,
    *,
    uv: torch.Tensor | None = None,
    texture: torch.Tensor | None = None,
    mask_texture: torch.Tensor | None = None,
    sh: torch.Tensor | None = None,
    background: torch.Tensor | float = 0.0,
    antialias_edges: bool = True,
    cull_backfaces: bool = False,
) -> RenderOutput:
    """Render a mesh into a batch of views.

    Args:
        V: (n, 3) float32/float64 vertex positions, world frame, mm.
        topology: a ``Topology`` (or an (m, 3) int64 face tensor).
        cameras: B undistorted cameras sharing one image size (H, W).
        passes: any of ``"color"`` (F_S: texture x Lambertian SH shading, linear
            RGB), ``"depth"`` (F_D: camera z, mm), ``"normal"`` (F_N: world unit
            normals), ``"mask"`` (the mouth-mask texture, [0, 1]), and on request ``"uv"``
            (the interpolated texture coordinates). Coverage ((R, 1) in [0, 1]) is always computed.
        uv: (k, 2) texture coordinates (OBJ convention) indexed by ``topology.uv_faces``;
            needed by "color", "mask" and "uv".
        texture: (T, T, 3) albedo in [0, 1]. mask_texture: (T', T', 1) in [0, 1].
        sh: (9, 3) radiance SH coefficients (``gpja.lighting``).
        background: value of empty pixels in "color" (scalar or (3,)); other passes use 0.
        antialias_edges: blend across silhouette edges (gives silhouette gradients).
        cull_backfaces: skip triangles facing away from the camera.
    Returns:
        A ``RenderOutput``; ``out.dense("depth")`` is a (B, H, W, 1) image.
    """
    topo = topology if isinstance(topology, Topology) else Topology(topology)
    check_render_input(V, topo.faces, cameras)
    unknown = set(passes) - set(ALL_PASSES)
    if unknown:
        raise ValueError(f"unknown passes {sorted(unknown)}; choose from {ALL_PASSES}")
    textured = "color" in passes or "mask" in passes or "uv" in passes
    if textured and (uv is None or topo.uv_faces is None):
        raise ValueError("the colour, mask and uv passes need texture coordinates (uv and topology.uv_faces)")
    if "color" in passes and (texture is None or sh is None):
        raise ValueError("the colour pass needs a texture and SH lighting")
    if "mask" in passes and mask_texture is None:
        raise ValueError("the mask pass needs a mask texture")
    height, width = cameras[0].height, cameras[0].width
    faces = topo.faces.to(V.device)
    screen = project_to_screen(V, cameras)
    visit = topo.visit_order(V.detach().numpy()) if V.device.type == "cpu" else None
    frags = rasterize_fragments(screen, faces, height, width, cull_backfaces, None if visit is None else visit[:2])

    values: dict[str, torch.Tensor] = {}
    backgrounds: dict[str, torch.Tensor] = {}
    normals = None
    if "color" in passes or "normal" in passes:
        normals = normalize_rows(interpolate_rows(vertex_normals(V, faces, topo.incidence(len(V))), frags.bary,
                                                  frags.corners))
    uv_frag = interpolate_attribute(uv, topo.uv_faces, frags) if textured else None
    for name in passes:
        if name == "color":
            values[name] = shade_lambertian(sample_texture(texture, uv_frag), normals, sh.to(V.dtype))
            backgrounds[name] = torch.as_tensor(background, dtype=V.dtype).expand(3)
        elif name == "depth":
            values[name] = frags.z[:, None]
        elif name == "normal":
            values[name] = normals
        elif name == "mask":
            values[name] = sample_texture(mask_texture, uv_frag)
        elif name == "uv":
            values[name] = uv_frag
        backgrounds.setdefault(name, torch.zeros(CHANNELS[name], dtype=V.dtype))
    values["coverage"] = torch.ones_like(frags.z)[:, None]
    backgrounds["coverage"] = torch.zeros(1, dtype=V.dtype)
    pixels = frags.pixel

    if antialias_edges:
        pairs = find_edge_pairs(frags, screen, faces, topo.adjacency,
                                topo.silhouette_candidates() if visit is None else visit[2])
        if len(pairs.occluder):
            # rows for background pixels that silhouettes blend into, after the covered ones;
            # covered pixels are listed in increasing flat index, so a binary search finds their rows
            covered = pixels.numpy()
            touched = np.concatenate([pairs.occluder.numpy(), pairs.other.numpy()])
            pos = np.searchsorted(covered, touched)
            hit = pos < len(covered)
            hit[hit] = covered[pos[hit]] == touched[hit]
            extra = np.unique(touched[~hit])
            rows = np.where(hit, pos, len(covered) + np.searchsorted(extra, touched))
            pixels = torch.cat([pixels, torch.from_numpy(extra)])
            occ_row = torch.from_numpy(rows[: len(pairs.occluder)])
            oth_row = torch.from_numpy(rows[len(pairs.occluder):])
            t = edge_crossings(screen, pairs, width, height)
            for name, vals in values.items():
                padded = torch.cat([vals, backgrounds[name].expand(len(extra), -1)], dim=0)
                values[name] = blend_across_edges(padded, t, occ_row, oth_row)
    out_values, out_bg = values, backgrounds
    return RenderOutput(pixels, out_values, out_bg, frags.shape, frags)


def image_l1(out: RenderOutput, name: str, target: torch.Tensor, weight: torch.Tensor | None = None,
             target_background_l1: torch.Tensor | None = None) -> torch.Tensor:
    """Sum over all pixels of ``weight * |render - target|``, from the sparse render.

    Pixels outside ``out.pixels`` hold the background value b, so their total
    is the constant ``sum |b - target|`` over those pixels: computed here from
    ``target_background_l1`` (the sum of |b - target| over the *whole* image,
    which a caller caches per target) minus the part inside ``out.pixels``.
    With ``weight`` (R, 1) (e.g. the rendered mouth mask, 0 on background),
    pixels outside the render are taken to have weight 0.

    Args:
        target: (B, H, W, C) dense target image.
    Returns:
        scalar tensor (differentiable in the render).
    """
    pred = out.values[name]
    tgt = out.gather(target)
    if weight is not None:
        return ((pred - tgt).abs() * weight).sum()
    bg = out.backgrounds[name].to(pred.dtype)
    if target_background_l1 is None:
        target_background_l1 = (target - bg).abs().sum()
    outside = target_background_l1 - (tgt - bg).abs().sum()
    return (pred - tgt).abs().sum() + outside.detach()
