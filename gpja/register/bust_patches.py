"""The quad-grid patches of the bust (:mod:`gpja.register.bust`), sampled on its implicit surface.

``main`` (azimuth columns x elevation rows, the mouth slit left out), the
``top`` crown and ``bottom`` neck-cut caps, the mouth ``pocket`` tube and its
``pocket_end`` cap, collected by a :class:`PatchBuilder` in that order (the
order fixes the vertex numbering and the orientation pass).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np

from gpja.register.bust_grid import coons_grid, cumulative_length, grid_quads, resample, split_ab
from gpja.register.bust_shape import BustShape, cast_rays, relax_on_surface, surface_points


@dataclass
class Patch:
    """One quad-grid patch: its cells over the mesh's vertices and over its own chart's UVs.

    Attributes:
        name: one of :data:`CHARTS`.
        quads: (q, 4) int64 vertex indices. uv_quads: (q, 4) int64 indices into ``uv``.
        uv: (k, 2) float64 chart-local UVs in [0, 1]^2.
        size_mm: (width, height) of the patch on the surface, mm (for packing).
    """

    name: str
    quads: np.ndarray
    uv_quads: np.ndarray
    uv: np.ndarray
    size_mm: tuple


@dataclass
class MainGrid:
    """The main patch's vertex grid and the parametrisation it was sampled from.

    Attributes:
        V: (R, N, 3) float64 vertices, mm; row 0 the top ring, row R-1 the neck cut.
        theta: (N,) azimuths (theta[0] = -pi, the back seam; theta[n] = 0, the front), radians.
        alpha: (R,) elevations, radians. th_f, s_th: fine azimuths and their arc length (mm).
        al_f, s_al: fine elevations and their arc length (mm).
        n: index of the front column. j_up: upper lip row (j_up + 1 the lower one).
        m: half width of the mouth slit, in columns.
    """

    V: np.ndarray
    theta: np.ndarray
    alpha: np.ndarray
    th_f: np.ndarray
    s_th: np.ndarray
    al_f: np.ndarray
    s_al: np.ndarray
    n: int
    j_up: int
    m: int

    @property
    def ids(self) -> np.ndarray:
        """(R, N) int64 vertex index of every grid point (the grid's vertices come first in the mesh)."""
        return np.arange(self.V.shape[0] * self.V.shape[1]).reshape(self.V.shape[:2])


class PatchBuilder:
    """Collects vertices and patches while the bust is assembled."""

    def __init__(self, first: np.ndarray) -> None:
        self.verts = [first]
        self.n_verts = len(first)
        self.patches: list[Patch] = []

    def vertices(self) -> np.ndarray:
        """(n, 3) float64 all vertices so far."""
        return np.concatenate(self.verts)

    def add_verts(self, P: np.ndarray) -> np.ndarray:
        """Append points (..., 3); returns their (k,) int64 vertex indices."""
        P = P.reshape(-1, 3)
        self.verts.append(P)
        out = np.arange(self.n_verts, self.n_verts + len(P))
        self.n_verts += len(P)
        return out

    def cap_patch(self, name: str, ring_ids: np.ndarray, a: int, b: int, start: int,
                  interior_fn: Callable[[np.ndarray, int, int], np.ndarray]) -> None:
        """Grid cap (a x b cells) whose boundary is the closed loop ring_ids (2(a+b),) from ``start``.

        ``interior_fn(boundary (2(a+b), 3), a, b)`` gives the (a+1, b+1, 3) grid; its interior is added.
        """
        L = len(ring_ids)
        loop = np.asarray(ring_ids)[(start + np.arange(L)) % L]
        G = interior_fn(self.vertices()[loop], a, b)                  # (a+1, b+1, 3)
        gid = np.full((a + 1, b + 1), -1, dtype=np.int64)
        p = np.arange(a + 1)
        q = np.arange(b + 1)
        gid[p, b] = loop[p]
        gid[a, q] = loop[a + (b - q)]
        gid[p, 0] = loop[a + b + (a - p)]
        gid[0, q] = loop[(2 * a + b + q) % L]
        if a > 1 and b > 1:
            gid[1:-1, 1:-1] = self.add_verts(G[1:-1, 1:-1]).reshape(a - 1, b - 1)
        Vc = self.vertices()
        span_u = np.linalg.norm(np.diff(Vc[gid], axis=0), axis=-1).sum(0).mean()
        span_v = np.linalg.norm(np.diff(Vc[gid], axis=1), axis=-1).sum(1).mean()
        uvg = np.stack(np.meshgrid(p / a, q / b, indexing="ij"), -1)
        uid = np.arange((a + 1) * (b + 1)).reshape(a + 1, b + 1)
        self.patches.append(Patch(name, grid_quads(gid), grid_quads(uid), uvg.reshape(-1, 2), (span_u, span_v)))


def main_columns(sh: BustShape, c0: np.ndarray, h: float, a_top: float):
    """Azimuths uniform in arc length along a few rows, symmetric about theta = 0.

    Returns:
        th_f (721,), s_th (721,) mm, theta (2n,), n.
    """
    th_f = np.linspace(-np.pi, np.pi, 721)
    al_ref = np.array([0.9, 0.5, 0.0, -0.4, -0.9]) * a_top
    ring = surface_points(sh, c0, np.repeat(th_f[:, None], len(al_ref), 1),
                          np.repeat(al_ref[None], len(th_f), 0)).reshape(len(th_f), -1, 3)
    s_th = cumulative_length(ring)
    s_th = 0.5 * (s_th + (s_th[-1] - s_th[::-1]))  # exact symmetry
    n = max(4, int(round(s_th[-1] / h / 2)))
    theta = resample(th_f, s_th, 2 * n)[:-1]         # theta[0] = -pi (back), theta[n] = 0 (front)
    theta[n] = 0.0
    return th_f, s_th, theta, n


def main_rows(sh: BustShape, c0: np.ndarray, h: float, a_top: float, a_edge: float, mouth_open_mm: float):
    """Elevations uniform in arc length along four meridians, two rows forced at the lips.

    Returns:
        al_f (1201,), s_al (1201,) mm, alpha (R,), j_up (the upper lip row).
    """
    al_f = np.linspace(a_top, a_edge, 1201)
    mer_th = np.array([0.0, 0.5 * np.pi, np.pi, -0.5 * np.pi])
    mer = surface_points(sh, c0, np.repeat(mer_th[None], len(al_f), 0),
                         np.repeat(al_f[:, None], 4, 1)).reshape(len(al_f), 4, 3)
    s_al = cumulative_length(mer)
    front_y = mer[:, 0, 1]
    k_mid = np.argmin(np.abs(front_y - sh.mouth_y)) + 40
    a_up = np.interp(-(sh.mouth_y + 0.5 * mouth_open_mm), -front_y[:k_mid], al_f[:k_mid])
    a_lo = np.interp(-(sh.mouth_y - 0.5 * mouth_open_mm), -front_y[:k_mid], al_f[:k_mid])
    s_up, s_lo = np.interp(-a_up, -al_f, s_al), np.interp(-a_lo, -al_f, s_al)
    n1 = max(2, int(round(s_up / h)))
    n2 = max(2, int(round((s_al[-1] - s_lo) / h)))
    alpha = np.concatenate([np.interp(np.linspace(0, s_up, n1 + 1), s_al, al_f),
                            np.interp(np.linspace(s_lo, s_al[-1], n2 + 1), s_al, al_f)])
    alpha[0], alpha[-1] = a_top, a_edge
    return al_f, s_al, alpha, n1


def main_grid(sh: BustShape, c0: np.ndarray, h: float, a_top: float, a_edge: float,
               mouth_open_mm: float) -> MainGrid:
    """The main patch's (R, N) grid of surface points, its neck row flattened onto the cut."""
    th_f, s_th, theta, n = main_columns(sh, c0, h, a_top)
    al_f, s_al, alpha, j_up = main_rows(sh, c0, h, a_top, a_edge, mouth_open_mm)
    R, N = len(alpha), 2 * n
    TH, AL = np.meshgrid(theta, alpha, indexing="xy")   # (R, N)
    Vmain = surface_points(sh, c0, TH, AL).reshape(R, N, 3)
    Vmain[-1, :, 1] = sh.neck_cut_y
    xs = Vmain[j_up, :, 0]
    m = int(np.sum((xs[n + 1 :] < sh.mouth_half_width) & (theta[n + 1 :] < 0.5 * np.pi)))
    return MainGrid(Vmain, theta, alpha, th_f, s_th, al_f, s_al, n, j_up, max(m, 2))


def main_patch(g: MainGrid, face_uv_boost: float) -> Patch:
    """The main chart: local [0,1]^2 UVs, u with the face boost, the seam column duplicated; the slit left out."""
    R, N = g.V.shape[:2]
    n, j_up, m, ids = g.n, g.j_up, g.m, g.ids
    th_u = np.append(g.theta, np.pi)
    w_th = 1.0 + face_uv_boost * 0.5 * (1.0 + np.cos(0.5 * (th_u[:-1] + th_u[1:])))
    s_th_at = np.interp(th_u, g.th_f, g.s_th)
    seg = np.diff(s_th_at) * w_th
    u_main = np.concatenate([[0.0], np.cumsum(seg)]) / seg.sum()
    s_rows = np.interp(-g.alpha, -g.al_f, g.s_al)
    v_main = 1.0 - s_rows / s_rows[-1]
    main_mm = (s_th_at[-1], s_rows[-1])
    uv_ids_main = np.arange(R * (N + 1)).reshape(R, N + 1)
    UV_main = np.stack(np.meshgrid(u_main, v_main, indexing="xy"), -1).reshape(-1, 2)

    cells_i, cells_j = np.meshgrid(np.arange(N), np.arange(R - 1), indexing="xy")
    keep = ~((cells_j == j_up) & (cells_i >= n - m) & (cells_i < n + m))
    ci, cj = cells_i[keep], cells_j[keep]
    q_main = np.stack([ids[cj, ci], ids[cj + 1, ci], ids[cj + 1, (ci + 1) % N], ids[cj, (ci + 1) % N]], 1)
    quv_main = np.stack([uv_ids_main[cj, ci], uv_ids_main[cj + 1, ci], uv_ids_main[cj + 1, ci + 1],
                         uv_ids_main[cj, ci + 1]], 1)
    return Patch("main", q_main, quv_main, UV_main, main_mm)


def add_crown(builder: PatchBuilder, g: MainGrid, sh: BustShape, c0: np.ndarray, a_top: float) -> None:
    """The crown cap: a Coons patch in the (x, z) plane of the directions, uniform in polar angle, then cast."""
    psi_max = 0.5 * np.pi - a_top

    def crown(bd, a, b):
        dd = bd - c0  # boundary directions, in bd's order
        dd /= np.linalg.norm(dd, axis=1, keepdims=True)
        G2 = coons_grid(dd[:, [0, 2]], a, b)
        rho = np.linalg.norm(G2, axis=-1)
        rho_max = math.cos(a_top)
        psi = np.clip(rho / rho_max, 0, 1) * psi_max
        scale = np.divide(np.sin(psi), rho, out=np.zeros_like(rho), where=rho > 1e-12)
        D = np.stack([G2[..., 0] * scale, np.cos(psi), G2[..., 1] * scale], -1)
        t = cast_rays(sh, c0, D.reshape(-1, 3)).reshape(D.shape[:2])
        return c0 + t[..., None] * D

    ext = g.V[0].max(0) - g.V[0].min(0)
    a_t, b_t = split_ab(g.n, ext[0] / ext[2])
    builder.cap_patch("top", g.ids[0], a_t, b_t, g.n - a_t // 2, crown)


def add_neck_cut(builder: PatchBuilder, g: MainGrid, sh: BustShape) -> None:
    """The flat disk closing the neck at ``sh.neck_cut_y``."""
    def flat(bd, a, b):
        G = coons_grid(bd, a, b)
        G[..., 1] = sh.neck_cut_y
        return G

    a_b, b_b = split_ab(g.n, 1.0)
    builder.cap_patch("bottom", g.ids[-1], a_b, b_b, g.n - a_b // 2, flat)


def add_mouth_pocket(builder: PatchBuilder, g: MainGrid, sh: BustShape, h: float, mouth_open_mm: float,
                      pocket_depth_mm: float, pocket_height_mm: float) -> tuple[np.ndarray, np.ndarray]:
    """The mouth socket: a tube of rings from the lip loop into the head, closed by an end cap.

    Returns:
        lip (4m+2,) int64 vertex ids of the lip loop (upper row left->right, lower row right->left),
        rid (K+1, 4m+2) int64 vertex ids of the tube's rings (row 0 the lip loop).
    """
    n, j_up, m, ids = g.n, g.j_up, g.m, g.ids
    upper = ids[j_up, n - m : n + m + 1]
    lower = ids[j_up + 1, n - m : n + m + 1][::-1]
    lip = np.concatenate([upper, lower])
    L = len(lip)                                   # 4m + 2
    P0 = g.V.reshape(-1, 3)[lip]
    phi = np.pi - np.pi / L - np.arange(L) * (2 * np.pi / L)
    z_front = float(P0[:, 2].max())
    z_end = z_front - pocket_depth_mm
    w0 = float(np.abs(P0[:, 0]).max())
    loop_len = np.linalg.norm(np.diff(np.vstack([P0, P0[:1]]), axis=0), axis=1).sum()
    K = max(3, int(round(pocket_depth_mm * 1.15 / h)))
    rings = [lip]
    ring_pts = [P0]
    for k in range(1, K + 1):
        s = k / K
        b = np.clip(s / 0.45, 0.0, 1.0)
        b = b * b * (3 - 2 * b)
        half_h = 0.5 * mouth_open_mm + (0.5 * pocket_height_mm - 0.5 * mouth_open_mm) * math.sin(0.5 * np.pi * min(1.0, s / 0.6))
        half_w = w0 * (0.92 - 0.25 * s)
        E = np.stack([half_w * np.cos(phi), sh.mouth_y - 3.0 * s + half_h * np.sin(phi)], 1)
        xy = (1 - b) * P0[:, :2] + b * E
        z = (1 - s) * P0[:, 2] + s * z_end
        Pk = np.column_stack([xy, z])
        ring_pts.append(Pk)
        rings.append(builder.add_verts(Pk))
    rid = np.stack(rings, 0)                                   # (K+1, L)
    kk, ll = np.meshgrid(np.arange(K), np.arange(L), indexing="ij")
    q_tube = np.stack([rid[kk, ll], rid[kk + 1, ll], rid[kk + 1, (ll + 1) % L], rid[kk, (ll + 1) % L]], -1).reshape(-1, 4)
    uid_t = np.arange((K + 1) * (L + 1)).reshape(K + 1, L + 1)
    quv_tube = np.stack([uid_t[kk, ll], uid_t[kk + 1, ll], uid_t[kk + 1, ll + 1], uid_t[kk, ll + 1]], -1).reshape(-1, 4)
    depth_mm = cumulative_length(np.stack(ring_pts))
    UV_tube = np.stack(np.meshgrid(np.arange(L + 1) / L, 1.0 - depth_mm / depth_mm[-1], indexing="xy"), -1).reshape(-1, 2)
    builder.patches.append(Patch("pocket", q_tube, quv_tube, UV_tube, (loop_len, depth_mm[-1])))

    end_ratio = 2 * w0 * (0.92 - 0.25) / pocket_height_mm
    a_p, b_p = split_ab(L // 2, end_ratio)
    builder.cap_patch("pocket_end", rid[-1], a_p, b_p, m - a_p // 2, lambda bd, a, b: coons_grid(bd, a, b))
    return lip, rid


def relax_patches(builder: PatchBuilder, g: MainGrid, lip: np.ndarray, sh: BustShape, iterations: int) -> np.ndarray:
    """Even out the sampling on the implicit surface (rays from c0 crowd where the surface is oblique).

    The main grid and the crown move; the neck-cut crease and the lip edges stay. Returns (n, 3) float64.
    """
    V = builder.vertices()
    n_main = g.V.shape[0] * g.V.shape[1]
    free = np.zeros(len(V), bool)
    free[:n_main] = True
    free[g.ids[-1]] = False                    # neck-cut crease
    free[lip] = False                          # lip edges
    top_ids = np.concatenate([p.quads.ravel() for p in builder.patches if p.name == "top"])
    free[top_ids] = True
    all_q = np.concatenate([p.quads for p in builder.patches])
    return relax_on_surface(V, all_q, free, sh, iterations=iterations)
