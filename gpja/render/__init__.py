"""Differentiable mesh rendering on the CPU (numba visibility + torch shading).

Public ops, nvdiffrast-style:
    project_to_screen       world vertices -> (B, n, 3) pixel x, y and depth
    rasterize               (numba) triangle id + depth per pixel for all views
    rasterize_fragments     the above + differentiable perspective-correct barycentrics
    interpolate_attribute   per-vertex / per-UV attributes at covered pixels
    sample_texture          bilinear texture lookup (gradients to UVs and texture)
    antialias               silhouette-edge blending with vertex gradients
    render_views            the paper's passes: color (F_S), depth (F_D), normal (F_N), mask
    image_l1                exact full-image L1 of a sparse render against a dense target
    render_scan_targets     a fixed scan's depth/normal images, rendered once and cached
    renderer(name)          the render_views of a backend: "auto" | "cpu" | "nvdiffrast" (experimental)

Modules, each importing only those above it: output (Topology, RenderOutput, PASSES), passes (the CPU
render_views), nvdiffrast_backend, backend (the choice), targets (the scan targets and their cache).
"""
from gpja.render.backend import BACKENDS, renderer, resolve_backend
from gpja.render.silhouettes import antialias, face_adjacency, find_edge_pairs
from gpja.render.fragments import Fragments, rasterize_fragments
from gpja.render.interpolate import interpolate_attribute, interpolate_rows, scatter_to_image
from gpja.render.normals import vertex_normals
from gpja.render.output import PASSES, RenderOutput, Topology
from gpja.render.passes import image_l1, render_views
from gpja.render.project import project_to_screen
from gpja.render.rasterize import rasterize
from gpja.render.targets import render_scan_targets
from gpja.render.texture import sample_texture

__all__ = [
    "BACKENDS", "renderer", "resolve_backend", "Fragments", "PASSES", "RenderOutput", "Topology", "image_l1", "antialias", "face_adjacency", "find_edge_pairs", "interpolate_attribute",
    "interpolate_rows", "project_to_screen", "rasterize", "rasterize_fragments", "render_scan_targets",
    "render_views", "sample_texture", "scatter_to_image", "vertex_normals",
]
