"""The genus-0 bust that template creation starts from (placed on a scan by ``bust_placement``).

The paper (Sec. 4, "Textured Template Mesh Creation") starts from "a coarse
genus-0 mesh with pre-designed texture parametrization, resembling a bust
sculpture" that "approximately overlaps the scan" of the mouth-open
expression. :func:`make_bust` builds that mesh procedurally:

* Shape: the smooth implicit bust of :mod:`gpja.register.bust_shape`, sampled
  by rays from a centre ``c0`` on the neck axis (the surface is star-shaped
  from ``c0``).
* Topology: a closed, oriented, genus-0 triangle mesh made of five quad-grid
  patches, each triangulated along its better diagonal:

  - ``main``: columns of azimuth ``theta`` (seam at the back of the head) x
    rows of elevation ``alpha`` from the forehead down to the neck cut;
  - ``top``: the crown, a rectangular grid whose boundary is the main grid's
    top row (a "cube-sphere" cap);
  - ``bottom``: the flat neck cut, likewise;
  - ``pocket``: the mouth socket, a tube of rings going ``pocket_depth_mm``
    into the head from a slit between the lips (the cells of the main grid
    between the two lip rows are left out), and
  - ``pocket_end``: the rectangular grid closing the tube.

  Removing one disk (the slit) and gluing a disk (tube + end) keeps genus 0.
* UV layout: one chart per patch, packed in [0, 1]^2 without overlap. The
  main chart (face, sides, back, neck front) takes the top ~2/3 of the atlas
  with extra texel density towards the face; the pocket charts are small and
  separate, so the mouth interior is a known UV region (:meth:`Bust.mouth_mask`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from gpja.mesh import TexturedMesh
from gpja.register.bust_grid import quads_to_tris, split_like
from gpja.register.bust_patches import (MainGrid, Patch, PatchBuilder, add_crown, add_mouth_pocket, add_neck_cut, main_grid,
                                        main_patch, relax_patches)
from gpja.register.bust_shape import BustShape

#: Chart names, in the order of their integer label in :attr:`Bust.face_chart`.
CHARTS = ("main", "top", "bottom", "pocket", "pocket_end")
#: Charts that make up the mouth socket (mask 0).
POCKET_CHARTS = ("pocket", "pocket_end")
#: Gutter around every UV chart, in UV units.
UV_MARGIN = 0.008


@dataclass(eq=False)
class Bust:
    """A textured genus-0 bust.

    Attributes:
        mesh: the bust (welded positions, seams split UVs only, no texture).
        pocket_faces: (k,) int64 indices of the mouth-socket faces (tube + end).
        face_chart: (m,) int64 chart label of every face, an index into :data:`CHARTS`.
        charts: chart name -> (u0, v0, u1, v1) UV rectangle it lies in.
        landmarks: name -> (3,) float64 point, mm: ``mouth`` (slit centre),
            ``mouth_left``/``mouth_right`` (slit corners, +X/-X), ``nose_tip``,
            ``chin``, ``head_top``, ``neck_cut`` (centre of the cut disk),
            ``pocket_end`` (centre of the socket's end).
    """

    mesh: TexturedMesh
    pocket_faces: np.ndarray
    face_chart: np.ndarray
    charts: dict = field(default_factory=dict)
    landmarks: dict = field(default_factory=dict)

    def mouth_mask(self, size: int) -> np.ndarray:
        """(size, size) float32 mask in UV space: 0 on the mouth-socket charts, 1 elsewhere.

        Row 0 is the top of the image (v = 1); pixel (r, c) has its centre at
        u = (c + 0.5) / size, v = 1 - (r + 0.5) / size. The 0-region is each
        pocket chart's rectangle grown by half the gutter, so texture lookups
        on the socket never blend in ones.
        """
        size = int(size)
        if size < 1:
            raise ValueError(f"mask size must be positive, got {size}")
        c = (np.arange(size) + 0.5) / size
        u = c[None, :]
        v = 1.0 - c[:, None]
        mask = np.ones((size, size), dtype=np.float32)
        g = 0.5 * UV_MARGIN
        for name in POCKET_CHARTS:
            u0, v0, u1, v1 = self.charts[name]
            mask[(u >= u0 - g) & (u <= u1 + g) & (v >= v0 - g) & (v <= v1 + g)] = 0.0
        return mask

    def transformed(self, scale: float, translation) -> "Bust":
        """The bust scaled by ``scale`` about the origin, then translated by ``translation`` (3,) mm."""
        t = np.asarray(translation, dtype=np.float64).reshape(3)
        s = float(scale)
        return replace(self, mesh=self.mesh.with_vertices(self.mesh.V * s + t),
                       landmarks={k: np.asarray(p) * s + t for k, p in self.landmarks.items()})


# --- assembly -------------------------------------------------------------------------------

def _triangulate(V: np.ndarray, patches: list[Patch]) -> tuple[np.ndarray, list[np.ndarray], np.ndarray]:
    """Triangulate every patch and orient it consistently with those accepted before it.

    Shared directed edges must be opposite; a patch that repeats one is reversed and its chart mirrored
    (``patch.uv`` is replaced). Returns F (m, 3) int64, the per-patch local UV triangles, and the
    (m,) int64 chart label of every face.
    """
    tris, tuv, labels = [], [], []
    seen = set()
    for patch in patches:
        t_v = quads_to_tris(V, patch.quads)
        t_uv = split_like(patch.quads, t_v, patch.uv_quads)  # the same local split for the UV quads
        # make the local UV triangles counter-clockwise
        P = patch.uv[t_uv]
        e1, e2 = P[:, 1] - P[:, 0], P[:, 2] - P[:, 0]
        area = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
        if np.median(area) < 0:
            t_v, t_uv = t_v[:, ::-1], t_uv[:, ::-1]
        edges = {(int(x), int(y)) for tri in t_v for x, y in ((tri[0], tri[1]), (tri[1], tri[2]), (tri[2], tri[0]))}
        if edges & seen:  # same directed edge as an accepted patch: reverse faces, mirror the chart
            t_v, t_uv = t_v[:, ::-1], t_uv[:, ::-1]
            patch.uv = patch.uv.copy()
            patch.uv[:, 0] = 1.0 - patch.uv[:, 0]
            edges = {(y, x) for x, y in edges}
        seen |= edges
        tris.append(t_v)
        tuv.append(t_uv)
        labels.append(np.full(len(t_v), CHARTS.index(patch.name)))
    return np.concatenate(tris).astype(np.int64), tuv, np.concatenate(labels).astype(np.int64)


def _pack_charts(patches: list[Patch]) -> dict:
    """Chart name -> (u0, v0, u1, v1): the main chart on top (full width), the others in a row below."""
    sizes = {p.name: p.size_mm for p in patches}
    mg = UV_MARGIN
    W, H = sizes["main"]
    main_h = min(0.7, (1 - 2 * mg) * H / W)
    rects = {"main": (mg, 1 - mg - main_h, 1 - mg, 1 - mg)}
    rest = [p.name for p in patches if p.name != "main"]
    strip_h = 1 - main_h - 4 * mg
    widths = np.array([sizes[r][0] for r in rest])
    heights = np.array([sizes[r][1] for r in rest])
    sigma = min(strip_h / heights.max(), (1 - 2 * mg * len(rest)) / widths.sum())
    x = mg
    for r, w, hh in zip(rest, widths, heights):
        rects[r] = (x, mg, x + w * sigma, mg + hh * sigma)
        x += w * sigma + 2 * mg
    return rects


def _atlas(patches: list[Patch], tuv: list[np.ndarray], rects: dict) -> tuple[np.ndarray, np.ndarray]:
    """Chart-local UVs mapped into their rectangles: UV (k, 2) float64 and F_uv (m, 3) int64."""
    UV_all, F_uv, off = [], [], 0
    for patch, t_uv in zip(patches, tuv):
        u0, v0, u1, v1 = rects[patch.name]
        UV = patch.uv
        UV_all.append(np.column_stack([u0 + UV[:, 0] * (u1 - u0), v0 + UV[:, 1] * (v1 - v0)]))
        F_uv.append(t_uv + off)
        off += len(UV)
    return np.concatenate(UV_all), np.concatenate(F_uv).astype(np.int64)


def _landmarks(V: np.ndarray, Vmain: np.ndarray, g: MainGrid, rid: np.ndarray, sh: BustShape) -> dict:
    """The named points of :attr:`Bust.landmarks` from the relaxed vertices, mm."""
    n, j_up, m = g.n, g.j_up, g.m
    front = Vmain[:, n]
    below = front[:, 1] < sh.mouth_y - 20
    chin = front[below][np.argmax(front[below][:, 2])]
    return {
        "mouth": 0.5 * (Vmain[j_up, n] + Vmain[j_up + 1, n]),
        "mouth_right": 0.5 * (Vmain[j_up, n - m] + Vmain[j_up + 1, n - m]),
        "mouth_left": 0.5 * (Vmain[j_up, n + m] + Vmain[j_up + 1, n + m]),
        "nose_tip": Vmain.reshape(-1, 3)[np.argmax(Vmain.reshape(-1, 3)[:, 2])].copy(),
        "chin": chin.copy(),
        "head_top": V[np.argmax(V[:, 1])].copy(),
        "neck_cut": np.array([0.0, sh.neck_cut_y, sh.neck_axis_z]),
        "pocket_end": V[rid[-1]].mean(0),
    }


def make_bust(target_edge_mm: float = 4.0, shape: BustShape | None = None, mouth_open_mm: float = 4.0,
              pocket_depth_mm: float = 32.0, pocket_height_mm: float = 20.0, top_elevation_deg: float = 55.0,
              face_uv_boost: float = 1.0, relax_iterations: int = 30) -> Bust:
    """Build the textured genus-0 bust in the canonical head frame (mm).

    Args:
        target_edge_mm: typical edge length; 4 mm gives ~8K vertices, 3 mm ~14K.
        shape: proportions (default :class:`BustShape`, an adult head).
        mouth_open_mm: rest opening of the mouth slit at its centre.
        pocket_depth_mm: how deep the mouth socket goes behind the lips.
        pocket_height_mm: height of the socket's cavity behind the lips.
        top_elevation_deg: elevation (from the ray centre) where the main
            chart ends and the crown cap begins.
        face_uv_boost: extra texel density at the face relative to the back of
            the head in the main chart (density ~ 1 + boost * (1 + cos theta) / 2).
        relax_iterations: tangential smoothing steps evening out the triangles
            on the implicit surface (0: raw ray-cast sampling).
    Returns:
        :class:`Bust`.
    """
    if not target_edge_mm > 0.5:
        raise ValueError(f"target_edge_mm must be > 0.5 mm, got {target_edge_mm}")
    sh = shape or BustShape()
    h = float(target_edge_mm)
    c0 = sh.ray_centre()
    a_top = math.radians(top_elevation_deg)
    a_edge = -math.atan2(sh.centre_y - sh.neck_cut_y, sh.neck_radius)
    grid = main_grid(sh, c0, h, a_top, a_edge, mouth_open_mm)
    builder = PatchBuilder(grid.V.reshape(-1, 3))
    builder.patches.append(main_patch(grid, face_uv_boost))
    add_crown(builder, grid, sh, c0, a_top)
    add_neck_cut(builder, grid, sh)
    lip, rid = add_mouth_pocket(builder, grid, sh, h, mouth_open_mm, pocket_depth_mm, pocket_height_mm)
    V = relax_patches(builder, grid, lip, sh, relax_iterations)

    F, tuv, face_chart = _triangulate(V, builder.patches)
    rects = _pack_charts(builder.patches)
    UV, F_uv = _atlas(builder.patches, tuv, rects)
    vol = np.einsum("ij,ij->i", V[F[:, 0]], np.cross(V[F[:, 1]], V[F[:, 2]])).sum() / 6.0
    if vol < 0:  # should not happen: the main grid is built outward
        raise RuntimeError("bust construction produced an inward-oriented surface")
    pocket_faces = np.flatnonzero(np.isin(face_chart, [CHARTS.index(c) for c in POCKET_CHARTS])).astype(np.int64)
    Vmain = V[: grid.V.shape[0] * grid.V.shape[1]].reshape(grid.V.shape)
    return Bust(mesh=TexturedMesh(V, F, UV, F_uv), pocket_faces=pocket_faces, face_chart=face_chart, charts=rects,
                landmarks=_landmarks(V, Vmain, grid, rid, sh))
