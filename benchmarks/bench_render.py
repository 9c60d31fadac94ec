"""Time the CPU renderer: one forward + backward of the colour, depth and normal passes
(plus the mouth-mask pass the colour loss uses) over 8 views, on a synthetic head mesh
decimated to 16K / 64K / 250K triangles, at 256x256 and 512x512.

Side by side in the same run, the straightforward alternative: Open3D
``RaycastingScene`` rebuilt every iteration for visibility, then plain torch
(barycentrics, indexing interpolation, texture) for the same passes and losses.
It has no antialiasing pass, so the comparison favours it.

Prints JSON: per configuration the median milliseconds of each path and their ratio.
With ``--ops``: each fused numba op of the renderer (projection, vertex normals, SH
irradiance) against the torch expression it replaces, forward + backward.
With ``--face-order``: the same step with the faces shuffled and in spatial order (``Topology.in_spatial_order``).
Usage: python benchmarks/bench_render.py [--repeats N] [--faces 16000 64000 250000] [--sizes 256 512] [--cull] [--ops]
       [--face-order]
"""
from __future__ import annotations

import argparse
import json
import statistics
import time

import numpy as np
import open3d as o3d
import pymeshlab
import torch
from skimage.measure import marching_cubes

from gpja.data.synthetic import head as head_mod
from gpja.data.synthetic.capture import make_rig, make_sh
from gpja.render import Topology, image_l1, render_views
from gpja.lighting import LAMBERT_FACTORS, irradiance_over_pi, sh_basis
from gpja.render.normals import vertex_incidence, vertex_normals, vertex_normals_torch
from gpja.render.project import project_to_screen, project_to_screen_torch
from gpja.render.texture import sample_texture


def head_meshes(face_counts: list[int]) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """The synthetic head (seed 0) as marching cubes at 0.7 mm, decimated to each face count."""
    params = head_mod.sample_head_params(np.random.default_rng(0))
    program = head_mod.build_head_program(params)["head"]
    grid, origin = head_mod.sample_sdf_grid(program, 0.7, np.zeros(3))
    verts, faces, _, _ = marching_cubes(grid, 0.0, spacing=(0.7,) * 3)
    out = {}
    for target in face_counts:
        ms = pymeshlab.MeshSet()
        ms.add_mesh(pymeshlab.Mesh(origin + verts.astype(np.float64), faces.astype(np.int32)))
        if target < len(faces):
            ms.meshing_decimation_quadric_edge_collapse(targetfacenum=target, preservetopology=True)
        m = ms.current_mesh()
        out[target] = (m.vertex_matrix().astype(np.float64), m.face_matrix().astype(np.int64))
    return out


def cylindrical_uv(V: np.ndarray) -> np.ndarray:
    theta = np.arctan2(V[:, 0], V[:, 2])
    return np.stack([0.5 + theta / (2 * np.pi), (V[:, 1] - V[:, 1].min()) / np.ptp(V[:, 1])], axis=1)


def plain_step(V, F, cams, uv, tex, mask, sh, targets):
    """Open3D visibility rebuilt from the current vertices + plain torch shading/interpolation."""
    H, W = cams[0].height, cams[0].width
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(V.detach().numpy().astype(np.float32)), o3d.core.Tensor(F.numpy().astype(np.uint32)))
    v, u = np.mgrid[0:H, 0:W]
    pix = np.stack([u.ravel(), v.ravel()], 1).astype(np.float64)
    rays = np.concatenate([np.concatenate(c.pixel_rays(pix), 1) for c in cams]).astype(np.float32)
    ids = scene.cast_rays(o3d.core.Tensor(rays), nthreads=0)["primitive_ids"].numpy().astype(np.int64)
    hit = np.flatnonzero(ids != o3d.t.geometry.RaycastingScene.INVALID_ID)
    view = torch.from_numpy(hit // (H * W))
    px = torch.from_numpy((hit % W).astype(np.float32))
    py = torch.from_numpy(((hit // W) % H).astype(np.float32))
    face = torch.from_numpy(ids[hit])
    screen = project_to_screen_torch(V, cams)
    s = screen[view[:, None], F[face]]  # (P, 3, 3)
    dx, dy = s[..., 0] - px[:, None], s[..., 1] - py[:, None]
    e = torch.stack([dx[:, 1] * dy[:, 2] - dy[:, 1] * dx[:, 2], dx[:, 2] * dy[:, 0] - dy[:, 2] * dx[:, 0],
                     dx[:, 0] * dy[:, 1] - dy[:, 0] * dx[:, 1]], 1)
    w = e / s[..., 2]
    bary = w / w.sum(1, keepdim=True)
    z = e.sum(1) / w.sum(1)
    tri = F[face]
    vn = torch.zeros_like(V).index_add_(0, F.reshape(-1), torch.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]], dim=1).repeat_interleave(3, 0))
    vn = vn / vn.norm(dim=1, keepdim=True)
    normal = (bary[..., None] * vn[tri]).sum(1)
    normal = normal / normal.norm(dim=1, keepdim=True)
    uvp = (bary[..., None] * uv[tri]).sum(1)
    color = sample_texture(tex, uvp) * plain_irradiance(normal, sh)
    m = sample_texture(mask, uvp)
    flat = torch.from_numpy(hit)
    loss = ((color - targets["color"].reshape(-1, 3)[flat]).abs() * m).sum()
    loss = loss + (z[:, None] - targets["depth"].reshape(-1, 1)[flat]).abs().sum()
    loss = loss + (normal - targets["normal"].reshape(-1, 3)[flat]).abs().sum()
    loss.backward()


def plain_irradiance(normals, sh):
    """E(n)/pi as torch expressions (what ``irradiance_over_pi`` does on other devices)."""
    return sh_basis(normals) @ (sh * torch.as_tensor(LAMBERT_FACTORS / np.pi, dtype=sh.dtype)[:, None])


def fused_op_rows(meshes, cams, repeats: int) -> list[dict]:
    """Each numba op against the torch expression it replaces, forward + backward, side by side."""
    rows = []
    gen = torch.Generator().manual_seed(1)
    for n_faces, (V0, F0) in meshes.items():
        V = torch.tensor(V0, dtype=torch.float32, requires_grad=True)
        F = torch.from_numpy(F0)
        incidence = vertex_incidence(F0, len(V0))
        g_screen = torch.randn(len(cams), len(V0), 3, generator=gen)
        g_normals = torch.randn(len(V0), 3, generator=gen)
        ops = {
            "project_to_screen": (lambda: project_to_screen(V, cams).backward(g_screen),
                                  lambda: project_to_screen_torch(V, cams).backward(g_screen)),
            "vertex_normals": (lambda: vertex_normals(V, F, incidence).backward(g_normals),
                               lambda: vertex_normals_torch(V, F).backward(g_normals)),
        }
        for name, (fused, plain) in ops.items():
            row = {"op": name, "faces": int(len(F0)), "vertices": int(len(V0)), "views": len(cams),
                   "fused_ms": round(median_ms(fused, repeats), 2), "torch_ms": round(median_ms(plain, repeats), 2)}
            row["speedup"] = round(row["torch_ms"] / row["fused_ms"], 2)
            rows.append(row)
            print(json.dumps(row), flush=True)
    # shading runs per covered pixel: ~620K of them in 8 views at 512 x 512 of the head
    n = torch.nn.functional.normalize(torch.randn(620_000, 3, generator=gen), dim=1).requires_grad_(True)
    sh = torch.randn(9, 3, generator=gen)
    g = torch.randn(620_000, 3, generator=gen)
    row = {"op": "irradiance_over_pi", "pixels": 620_000,
           "fused_ms": round(median_ms(lambda: irradiance_over_pi(n, sh).backward(g), repeats), 2),
           "torch_ms": round(median_ms(lambda: plain_irradiance(n, sh).backward(g), repeats), 2)}
    row["speedup"] = round(row["torch_ms"] / row["fused_ms"], 2)
    rows.append(row)
    print(json.dumps(row), flush=True)
    return rows


def our_step(V, topo, cams, uv, tex, mask, sh, targets, bg_l1, cull=False):
    out = render_views(V, topo, cams, ("color", "depth", "normal", "mask"), uv=uv, texture=tex, mask_texture=mask, sh=sh,
                       cull_backfaces=cull)
    loss = image_l1(out, "color", targets["color"], weight=out.values["mask"])
    loss = loss + image_l1(out, "depth", targets["depth"], target_background_l1=bg_l1["depth"])
    loss = loss + image_l1(out, "normal", targets["normal"], target_background_l1=bg_l1["normal"])
    loss.backward()


def median_ms(fn, repeats: int) -> float:
    fn()  # warm-up (numba compilation, allocator)
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return 1000.0 * statistics.median(times)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--faces", type=int, nargs="+", default=[16000, 64000, 250000])
    ap.add_argument("--sizes", type=int, nargs="+", default=[256, 512])
    ap.add_argument("--no-baseline", action="store_true")
    ap.add_argument("--ops", action="store_true",
                    help="instead: each fused numba op (projection, vertex normals, SH irradiance) against the torch "
                         "expression it replaces, 8 views at 512 x 512")
    ap.add_argument("--cull", action="store_true",
                    help="back-face culling, as registration renders its closed template (the ray-cast baseline "
                         "only hits front faces of a closed mesh either way)")
    ap.add_argument("--face-order", action="store_true",
                    help="also time the same mesh with its faces shuffled (as a refined registration mesh lists "
                         "them) and in spatial order (Schedule.face_order: spatial)")
    args = ap.parse_args()
    meshes = head_meshes(args.faces)
    if args.ops:
        cams = [c.undistorted() for c in make_rig(np.random.default_rng(1), 8, 512, 600.0, False)]
        print(json.dumps({"benchmark": "fused_ops_forward_backward", "torch_threads": torch.get_num_threads(),
                          "repeats": args.repeats, "results": fused_op_rows(meshes, cams, args.repeats)}, indent=1))
        return
    rng = np.random.default_rng(0)
    sh = torch.tensor(make_sh(rng), dtype=torch.float32)
    gen = torch.Generator().manual_seed(0)
    tex = torch.rand(1024, 1024, 3, generator=gen)
    mask = torch.ones(256, 256, 1)
    results = []
    for size in args.sizes:
        cams = [c.undistorted() for c in make_rig(np.random.default_rng(1), 8, size, 600.0, False)]
        targets = {"color": torch.rand(8, size, size, 3, generator=gen), "depth": 600 * torch.rand(8, size, size, 1, generator=gen),
                   "normal": torch.rand(8, size, size, 3, generator=gen)}
        bg_l1 = {k: v.abs().sum() for k, v in targets.items()}
        for n_faces, (V0, F0) in meshes.items():
            topo = Topology(torch.from_numpy(F0), torch.from_numpy(F0))
            uv = torch.tensor(cylindrical_uv(V0), dtype=torch.float32)
            V = torch.tensor(V0, dtype=torch.float32, requires_grad=True)
            row = {"faces": int(len(F0)), "vertices": int(len(V0)), "image": size, "views": 8, "cull_backfaces": args.cull}
            row["gpja_ms"] = round(median_ms(lambda: our_step(V, topo, cams, uv, tex, mask, sh, targets, bg_l1, args.cull),
                                             args.repeats), 1)
            if args.face_order:
                shuffled = F0[np.random.default_rng(2).permutation(len(F0))]
                for name, order_topo in (("shuffled", Topology(torch.from_numpy(shuffled), torch.from_numpy(shuffled))),
                                         ("spatial", Topology.in_spatial_order(V0, shuffled, shuffled))):
                    row[f"gpja_{name}_ms"] = round(median_ms(
                        lambda: our_step(V, order_topo, cams, uv, tex, mask, sh, targets, bg_l1, args.cull), args.repeats), 1)
            if not args.no_baseline:
                F = torch.from_numpy(F0)
                row["open3d_plain_torch_ms"] = round(median_ms(lambda: plain_step(V, F, cams, uv, tex, mask, sh, targets), args.repeats), 1)
                row["speedup"] = round(row["open3d_plain_torch_ms"] / row["gpja_ms"], 2)
            results.append(row)
            print(json.dumps(row), flush=True)
    print(json.dumps({"benchmark": "render_forward_backward", "torch_threads": torch.get_num_threads(),
                      "repeats": args.repeats, "results": results}, indent=1))


if __name__ == "__main__":
    main()
