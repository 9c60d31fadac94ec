"""The paper's render passes: shaded colour F_S, depth F_D, normals F_N, mouth mask, coverage.

All passes of one call share one rasterisation and one antialiasing step, so
asking for several costs little more than asking for one.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

import numpy as np
import torch

from gpja.camera import Camera
from gpja.lighting import shade_lambertian
from gpja.render.silhouettes import blend_across_edges, edge_crossings, face_adjacency, find_edge_pairs
from gpja.render.fragments import Fragments, rasterize_fragments
from gpja.render.interpolate import interpolate_attribute, interpolate_rows
from gpja.render.normals import normalize_rows, vertex_incidence, vertex_normals
from gpja.render.project import project_to_screen
from gpja.render.texture import sample_texture

PASSES = ("color", "depth", "normal", "mask")
CHANNELS = {"color": 3, "depth": 1, "normal": 3, "mask": 1, "coverage": 1}


@dataclass
class Topology:
    """Connectivity shared by every render of a mesh level (built once per level).

    Attributes:
        faces: (m, 3) int64 vertex indices.
        uv_faces: (m, 3) int64 UV indices, or None.
        adjacency: (m, 3) int64 neighbouring face per edge (for antialiasing).
    """

    faces: torch.Tensor
    uv_faces: torch.Tensor | None = None
    adjacency: np.ndarray = field(default=None)  # type: ignore[assignment]
    _incidence: dict = field(default_factory=dict, init=False, repr=False)

    def __post_init__(self) -> None:
        self.faces = torch.as_tensor(np.asarray(self.faces), dtype=torch.int64)
        if self.uv_faces is not None:
            self.uv_faces = torch.as_tensor(np.asarray(self.uv_faces), dtype=torch.int64)
        if self.adjacency is None:
            self.adjacency = face_adjacency(self.faces.numpy())

    def incidence(self, n_vertices: int) -> tuple[np.ndarray, np.ndarray]:
        """``vertex_incidence`` of the faces for ``n_vertices`` vertices, built once."""
        if n_vertices not in self._incidence:
            self._incidence[n_vertices] = vertex_incidence(self.faces.numpy(), n_vertices)
        return self._incidence[n_vertices]


def check_render_input(V: torch.Tensor, faces: torch.Tensor, cameras: Sequence[Camera]) -> None:
    """Raise ``ValueError`` with a clear message for unusable render input."""
    if V.dim() != 2 or V.shape[1] != 3 or len(V) == 0:
        raise ValueError(f"vertices must be a non-empty (n, 3) tensor, got shape {tuple(V.shape)}")
    if len(faces) == 0:
        raise ValueError("the mesh has no faces")
    bad = ~torch.isfinite(V).all(dim=1)
    if bad.any():
        raise ValueError(f"{int(bad.sum())} of {len(V)} vertices are NaN or infinite (first: {int(bad.nonzero()[0])})")
    if int(faces.min()) < 0 or int(faces.max()) >= len(V):
        raise ValueError(f"face indices must lie in [0, {len(V)}), got [{int(faces.min())}, {int(faces.max())}]")
    if not cameras:
        raise ValueError("no camera given")
    for cam in cameras:
        if cam.width <= 0 or cam.height <= 0:
            raise ValueError(f"camera {cam.name!r} has a zero-size image ({cam.width}x{cam.height})")


@dataclass
class RenderOutput:
    """A batch of rendered views, stored sparsely.

    Only pixels that can differ from the background are kept: the covered
    pixels and the background pixels next to silhouettes that antialiasing
    blends into. Dense images are made on demand.

    Attributes:
        pixels: (R,) int64 flat pixel index ``(b * H + y) * W + x`` of each row.
        values: pass name -> (R, C) tensor (differentiable), incl. "coverage".
        backgrounds: pass name -> (C,) value of every pixel not in ``pixels``.
        shape: (B, H, W).
        fragments: the rasterisation (covered pixels are rows 0..P-1).
    """

    pixels: torch.Tensor
    values: dict[str, torch.Tensor]
    backgrounds: dict[str, torch.Tensor]
    shape: tuple[int, int, int]
    fragments: Fragments

    def dense(self, name: str) -> torch.Tensor:
        """(B, H, W, C) image of one pass (differentiable)."""
        n_views, height, width = self.shape
        vals = self.values[name]
        bg = self.backgrounds[name].to(vals.dtype)
        image = bg.repeat(n_views * height * width, 1).index_put((self.pixels,), vals)
        return image.reshape(n_views, height, width, vals.shape[1])

    def gather(self, image: torch.Tensor) -> torch.Tensor:
        """Rows of a dense (B, H, W, C) image (e.g. a target) at this render's pixels: (R, C)."""
        return image.reshape(-1, image.shape[-1])[self.pixels]


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
            normals), ``"mask"`` (the mouth-mask texture, [0, 1]). Coverage
            ((R, 1) in [0, 1]) is always computed.
        uv: (k, 2) texture coordinates (OBJ convention) indexed by ``topology.uv_faces``;
            needed by "color" and "mask".
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
    unknown = set(passes) - set(PASSES)
    if unknown:
        raise ValueError(f"unknown passes {sorted(unknown)}; choose from {PASSES}")
    if ("color" in passes or "mask" in passes) and (uv is None or topo.uv_faces is None):
        raise ValueError("the colour and mask passes need texture coordinates (uv and topology.uv_faces)")
    if "color" in passes and (texture is None or sh is None):
        raise ValueError("the colour pass needs a texture and SH lighting")
    if "mask" in passes and mask_texture is None:
        raise ValueError("the mask pass needs a mask texture")
    height, width = cameras[0].height, cameras[0].width
    faces = topo.faces.to(V.device)
    screen = project_to_screen(V, cameras)
    frags = rasterize_fragments(screen, faces, height, width, cull_backfaces)

    values: dict[str, torch.Tensor] = {}
    backgrounds: dict[str, torch.Tensor] = {}
    normals = None
    if "color" in passes or "normal" in passes:
        normals = normalize_rows(interpolate_rows(vertex_normals(V, faces, topo.incidence(len(V))), frags.bary,
                                                  frags.corners))
    uv_frag = interpolate_attribute(uv, topo.uv_faces, frags) if ("color" in passes or "mask" in passes) else None
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
        backgrounds.setdefault(name, torch.zeros(CHANNELS[name], dtype=V.dtype))
    values["coverage"] = torch.ones_like(frags.z)[:, None]
    backgrounds["coverage"] = torch.zeros(1, dtype=V.dtype)
    pixels = frags.pixel

    if antialias_edges:
        pairs = find_edge_pairs(frags, screen, faces, topo.adjacency)
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


def render_scan_targets(V_scan: np.ndarray, F_scan: np.ndarray, cameras: Sequence[Camera],
                        cache_path: str | Path | None = None, backend: str = "cpu") -> dict[str, torch.Tensor]:
    """Depth, normal and coverage images of a fixed scan, rendered once per view set.

    The scan never moves, so its targets are computed once (no gradient) and,
    with ``cache_path``, stored as ``.npz`` and reused while the views match.

    Args:
        V_scan: (n, 3) float positions, mm. F_scan: (m, 3) int faces.
        cameras: the undistorted views.
        cache_path: ``.npz`` to reuse (when its views match) or create.
        backend: "auto" | "cpu" | "nvdiffrast" (see ``gpja.render.backend``).
    Returns:
        ``"depth"`` (B, H, W, 1) mm, ``"normal"`` (B, H, W, 3), ``"coverage"``
        (B, H, W, 1), float32 tensors.
    """
    from gpja.io import write_npz
    from gpja.render.backend import renderer

    key = np.frombuffer(b"".join(c.cache_key() + c.Rt.tobytes() for c in cameras), dtype=np.uint8)
    if cache_path is not None and Path(cache_path).is_file():
        with np.load(cache_path) as cached:
            if np.array_equal(cached["views_key"], key) and cached["n_vertices"] == len(V_scan):
                return {k: torch.from_numpy(cached[k]) for k in ("depth", "normal", "coverage")}
    render = renderer(backend)
    device = torch.device("cuda") if render is not render_views else torch.device("cpu")
    with torch.no_grad():
        out = render(torch.as_tensor(np.asarray(V_scan), dtype=torch.float32, device=device),
                     torch.as_tensor(np.asarray(F_scan)), cameras, passes=("depth", "normal"))
        targets = {k: out.dense(k).contiguous().cpu() for k in ("depth", "normal", "coverage")}
    if cache_path is not None:
        write_npz(cache_path, views_key=key, n_vertices=np.int64(len(V_scan)),
                  **{k: v.numpy() for k, v in targets.items()})
    return targets
