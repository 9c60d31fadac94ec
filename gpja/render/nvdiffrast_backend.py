"""``render_views`` on a CUDA GPU with nvdiffrast (experimental, not yet checked against the CPU backend).

Same inputs and ``RenderOutput`` as ``gpja.render.passes.render_views``; the
output holds every pixel (dense rows), so ``image_l1`` and ``dense`` work
unchanged. Conventions bridged here: OpenCV pixels (origin top-left, centres at
integers, y down) to OpenGL clip space (y up), and nvdiffrast's bottom-up image
rows back to top-down.
"""
from __future__ import annotations

from typing import Sequence

import torch

from gpja.camera import Camera
from gpja.lighting import shade_lambertian
from gpja.render.normals import normalize_rows, vertex_normals
from gpja.render.passes import CHANNELS, PASSES, RenderOutput, Topology, check_render_input
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


def render_views_nvdiffrast(V: torch.Tensor, topology: Topology | torch.Tensor, cameras: Sequence[Camera],
                            passes: Sequence[str] = PASSES, *, uv=None, texture=None, mask_texture=None, sh=None,
                            background=0.0, antialias_edges: bool = True, cull_backfaces: bool = False) -> RenderOutput:
    """nvdiffrast implementation of ``render_views`` (see there for arguments and units)."""
    import nvdiffrast.torch as dr

    if cull_backfaces:
        raise ValueError("cull_backfaces is not supported by the nvdiffrast backend (it rasterises both sides)")
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
    images: dict[str, torch.Tensor] = {}
    backgrounds: dict[str, torch.Tensor] = {}
    normals = None
    if "color" in passes or "normal" in passes:
        vn = vertex_normals(V, topo.faces.to(device)).float().contiguous()
        normals = dr.interpolate(vn[None], rast, faces)[0]
        normals = normalize_rows(normals.reshape(-1, 3)).reshape(normals.shape)
    uv_img = None
    if "color" in passes or "mask" in passes:
        uv_img = dr.interpolate(uv.float()[None].contiguous(), rast, topo.uv_faces.to(device=device, dtype=torch.int32))[0]
        uv_img = torch.stack([uv_img[..., 0], 1.0 - uv_img[..., 1]], dim=-1)  # nvdiffrast: v down the image rows
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
    return RenderOutput(pixels, values, backgrounds, (len(cameras), height, width), fragments=None)  # type: ignore[arg-type]
