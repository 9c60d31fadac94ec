"""``render_views`` on a CUDA GPU with nvdiffrast (experimental, not yet checked against the CPU backend).

Same inputs and ``RenderOutput`` as ``gpja.render.passes.render_views``; the
output holds every pixel (dense rows), so ``image_l1`` and ``dense`` work
unchanged. Inputs on the CPU (the registration keeps its parameters there) are
moved to the GPU and the output back to the vertices' device, differentiably,
so a caller switches backend by switching the function alone. Conventions
bridged here: OpenCV pixels (origin top-left, centres at integers, y down) to
OpenGL clip space (y up), and nvdiffrast's bottom-up image rows back to top-down.
"""
from __future__ import annotations

from typing import Sequence

import torch

from gpja.camera import Camera
from gpja.lighting import shade_lambertian
from gpja.render.normals import normalize_rows, vertex_normals
from gpja.render.output import CHANNELS, PASSES, RenderOutput, Topology, check_render_input
from gpja.render.project import project_to_screen

#: Clip-space depth range (mm); heads sit 300-1500 mm from the rig's cameras.
NEAR_MM, FAR_MM = 10.0, 10000.0
_CONTEXTS: dict = {}


def screen_to_clip(screen: torch.Tensor, width: int, height: int) -> torch.Tensor:
    """(B, n, 3) pixel x, y, depth -> (B, n, 4) OpenGL clip coordinates (w = depth)."""
    x, y, z = screen.unbind(-1)
    ndc_x = 2.0 * (x + 0.5) / width - 1.0
    ndc_y = 1.0 - 2.0 * (y + 0.5) / height
    ndc_z = (FAR_MM + NEAR_MM) / (FAR_MM - NEAR_MM) - 2.0 * FAR_MM * NEAR_MM / ((FAR_MM - NEAR_MM) * z)
    return torch.stack([ndc_x * z, ndc_y * z, ndc_z * z, z], dim=-1)


def front_facing(screen: torch.Tensor, faces: torch.Tensor) -> torch.Tensor:
    """(B, m) bool: face f looks towards camera b (negative signed area in y-down pixels, as the CPU rasteriser).

    Args:
        screen: (B, n, 3) pixel x, y and depth. faces: (m, 3) int vertex indices.
    """
    tri = screen[:, faces.long(), :2]  # (B, m, 3, 2)
    e1, e2 = tri[:, :, 1] - tri[:, :, 0], tri[:, :, 2] - tri[:, :, 0]
    return e1[..., 0] * e2[..., 1] - e1[..., 1] * e2[..., 0] < 0


def render_views_nvdiffrast(V: torch.Tensor, topology: Topology | torch.Tensor, cameras: Sequence[Camera],
                            passes: Sequence[str] = PASSES, *, uv=None, texture=None, mask_texture=None, sh=None,
                            background=0.0, antialias_edges: bool = True, cull_backfaces: bool = False) -> RenderOutput:
    """nvdiffrast implementation of ``render_views`` (see there for arguments and units).

    ``V`` (and the textures) may live on the CPU: they are rendered on the first CUDA device and the
    output is returned on ``V``'s device. ``cull_backfaces``: nvdiffrast rasterises both sides, so
    pixels whose nearest triangle faces away from the camera are left uncovered; for a closed surface
    (the template) that is the CPU backend's picture, whose nearest surface always faces the camera.
    """
    home = V.device
    if home.type == "cuda":
        return _render_cuda(V, topology, cameras, passes, uv, texture, mask_texture, sh, background,
                            antialias_edges, cull_backfaces)
    cuda = torch.device("cuda")
    moved = [None if t is None else t.to(cuda) for t in (uv, texture, mask_texture, sh)]
    bg = background.to(cuda) if torch.is_tensor(background) else background
    out = _render_cuda(V.to(cuda), topology, cameras, passes, *moved, bg, antialias_edges, cull_backfaces)
    return RenderOutput(out.pixels.to(home), {k: v.to(home) for k, v in out.values.items()},
                        {k: v.to(home) for k, v in out.backgrounds.items()}, out.shape, None)


def _render_cuda(V, topology, cameras, passes, uv, texture, mask_texture, sh, background, antialias_edges,
                 cull_backfaces) -> RenderOutput:
    """:func:`render_views_nvdiffrast` with every tensor on one CUDA device."""
    import nvdiffrast.torch as dr

    topo = topology if isinstance(topology, Topology) else Topology(topology)
    check_render_input(V, topo.faces, cameras)
    device = V.device
    height, width = cameras[0].height, cameras[0].width
    ctx = _CONTEXTS.setdefault(device, dr.RasterizeCudaContext(device=device))
    faces = topo.faces.to(device=device, dtype=torch.int32)
    screen = project_to_screen(V, cameras)
    clip = screen_to_clip(screen, width, height).float().contiguous()
    rast, _ = dr.rasterize(ctx, clip, faces, resolution=[height, width])
    covered = (rast[..., 3:4] > 0).float()
    if cull_backfaces:
        # rast's last channel is triangle id + 1 (0 = empty)
        tri = (rast[..., 3].long() - 1).clamp_min(0).reshape(len(cameras), -1)
        front = front_facing(screen.detach(), faces).gather(1, tri).reshape(covered.shape)
        covered = covered * front.float()
    images: dict[str, torch.Tensor] = {}
    backgrounds: dict[str, torch.Tensor] = {}
    normals = None
    if "color" in passes or "normal" in passes:
        vn = vertex_normals(V, topo.faces.to(device)).float().contiguous()
        normals = dr.interpolate(vn[None], rast, faces)[0]
        normals = normalize_rows(normals.reshape(-1, 3)).reshape(normals.shape)
    uv_obj = uv_img = None
    if "color" in passes or "mask" in passes or "uv" in passes:
        uv_obj = dr.interpolate(uv.float()[None].contiguous(), rast, topo.uv_faces.to(device=device, dtype=torch.int32))[0]
        uv_img = torch.stack([uv_obj[..., 0], 1.0 - uv_obj[..., 1]], dim=-1)  # nvdiffrast: v down the image rows
    for name in passes:
        if name == "color":
            albedo = dr.texture(texture.float()[None].contiguous(), uv_img, filter_mode="linear", boundary_mode="clamp")
            bg = torch.as_tensor(background, dtype=torch.float32, device=device).expand(3)
            images[name] = shade_lambertian(albedo, normals, sh.float().to(device)) * covered + bg * (1 - covered)
            backgrounds[name] = bg
        elif name == "depth":
            z = dr.interpolate(screen[..., 2:3].float().contiguous(), rast, faces)[0]
            images[name] = z * covered
        elif name == "normal":
            images[name] = normals * covered
        elif name == "mask":
            images[name] = dr.texture(mask_texture.float()[None].contiguous(), uv_img, filter_mode="linear",
                                      boundary_mode="clamp") * covered
        elif name == "uv":
            images[name] = uv_obj * covered
        backgrounds.setdefault(name, torch.zeros(CHANNELS[name], device=device))
    images["coverage"] = covered
    backgrounds["coverage"] = torch.zeros(1, device=device)
    values = {}
    for name, img in images.items():
        if antialias_edges:
            img = dr.antialias(img.contiguous(), rast, clip, faces)
        img = torch.flip(img, dims=[1])  # nvdiffrast row 0 is the bottom of the image
        values[name] = img.reshape(-1, img.shape[-1]).to(V.dtype)
    pixels = torch.arange(len(cameras) * height * width, device=device)
    return RenderOutput(pixels, values, backgrounds, (len(cameras), height, width), fragments=None)
