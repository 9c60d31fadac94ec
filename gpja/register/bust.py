"""The genus-0 bust that template creation starts from, and its placement on a scan.

The paper (Sec. 4, "Textured Template Mesh Creation") starts from "a coarse
genus-0 mesh with pre-designed texture parametrization, resembling a bust
sculpture" that "approximately overlaps the scan" of the mouth-open
expression. :func:`make_bust` builds that mesh procedurally:

* Shape: a smooth implicit bust (cranium, jaw, chin, cheek bones, brow, nose,
  lips, a vertical neck cut flat at the bottom), sampled by rays from a centre
  ``c0`` on the neck axis (the surface is star-shaped from ``c0``).
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

:func:`place_bust` scales and translates the bust onto a scan in the
canonical head frame (face +Z, top +Y, X to the subject's left, mm): an
initial guess from robust scan percentiles and the nose tip, refined by a
trimmed scale+translation ICP of the scan points onto the bust surface.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from gpja.errors import InputError
from gpja.mesh import TexturedMesh

#: Chart names, in the order of their integer label in :attr:`Bust.face_chart`.
CHARTS = ("main", "top", "bottom", "pocket", "pocket_end")
#: Charts that make up the mouth socket (mask 0).
POCKET_CHARTS = ("pocket", "pocket_end")
#: Gutter around every UV chart, in UV units.
UV_MARGIN = 0.008
#: Scan extents (robust, mm) accepted as a head in millimetres.
SCAN_EXTENT_RANGE_MM = (80.0, 1500.0)


# --- the implicit bust ----------------------------------------------------------------------

@dataclass(frozen=True)
class BustShape:
    """Proportions of the bust, mm, canonical head frame (origin near the head centre)."""

    cranium_center: tuple = (0.0, 20.0, -5.0)
    cranium_axes: tuple = (74.0, 92.0, 99.0)
    neck_radius: float = 52.0
    neck_axis_z: float = -10.0
    neck_cut_y: float = -210.0
    mouth_y: float = -58.0
    mouth_half_width: float = 24.0
    centre_y: float = -60.0  # y of the ray centre c0 (on the neck axis)

    def primitives(self) -> list[tuple[float, tuple, tuple]]:
        """(blend radius k, centre, semi-axes) of the ellipsoids, smooth-unioned in order."""
        my = self.mouth_y
        w = self.mouth_half_width
        prims = [
            (0.0, self.cranium_center, self.cranium_axes),
            (22.0, (0.0, -41.0, 18.0), (57.0, 59.0, 72.0)),          # jaw / lower face
            (12.0, (0.0, -93.0, 70.0), (20.0, 16.0, 17.0)),          # chin
            (12.0, (-42.0, -19.0, 62.0), (20.0, 15.0, 20.0)),        # cheek bones
            (12.0, (42.0, -19.0, 62.0), (20.0, 15.0, 20.0)),
            (10.0, (0.0, 31.0, 82.0), (58.0, 10.0, 13.0)),           # brow ridge
            (6.0, (0.0, 2.0, 95.0), (7.0, 22.0, 9.0)),               # nose bridge
            (4.0, (0.0, -15.0, 107.0), (9.0, 8.0, 9.0)),             # nose tip
            (6.0, (0.0, -11.0, 90.0), (13.0, 12.0, 11.0)),           # nose base
            (4.0, (-12.0, -19.0, 98.0), (7.0, 6.5, 7.0)),            # alae
            (4.0, (12.0, -19.0, 98.0), (7.0, 6.5, 7.0)),
            (3.0, (0.0, my + 6.0, 90.0), (w + 1.0, 6.0, 8.0)),       # upper lip
            (3.0, (0.0, my - 7.0, 88.5), (w - 2.0, 6.5, 8.5)),       # lower lip
        ]
        return prims


def _ellipsoid_sdf(P: np.ndarray, c, a) -> np.ndarray:
    """Approximate signed distance to an axis-aligned ellipsoid (Quilez's bound), mm."""
    q = (P - np.asarray(c)) / np.asarray(a)
    k0 = np.linalg.norm(q, axis=-1)
    k1 = np.linalg.norm(q / np.asarray(a), axis=-1)
    return k0 * (k0 - 1.0) / np.maximum(k1, 1e-12)


def _smin(a: np.ndarray, b: np.ndarray, k: float) -> np.ndarray:
    if k <= 0:
        return np.minimum(a, b)
    h = np.clip(0.5 + 0.5 * (b - a) / k, 0.0, 1.0)
    return b + (a - b) * h - k * h * (1.0 - h)


def bust_sdf(P: np.ndarray, shape: BustShape) -> np.ndarray:
    """Signed distance (negative inside, approximate away from the surface) of the bust.

    Args:
        P: (..., 3) float64 points, mm.
    Returns:
        (...,) float64.
    """
    d = None
    for k, c, a in shape.primitives():
        e = _ellipsoid_sdf(P, c, a)
        d = e if d is None else _smin(d, e, k)
    # neck: vertical cylinder from y = -20 down, smooth-unioned, then cut flat
    radial = np.hypot(P[..., 0], P[..., 2] - shape.neck_axis_z) - shape.neck_radius
    neck = np.maximum(radial, P[..., 1] + 20.0)
    d = _smin(d, neck, 25.0)
    return np.maximum(d, shape.neck_cut_y - P[..., 1])


def _cast(shape: BustShape, c0: np.ndarray, dirs: np.ndarray, step: float = 2.5, t_max: float = 280.0) -> np.ndarray:
    """Distance along each ray from ``c0`` to the outermost surface crossing.

    Args:
        c0: (3,) ray origin inside the bust, mm; dirs: (n, 3) unit directions.
    Returns:
        (n,) float64 distances, mm.
    """
    dirs = np.asarray(dirs, dtype=np.float64).reshape(-1, 3)
    ts = np.arange(step, t_max + step, step)
    out = np.empty(len(dirs))
    for s in range(0, len(dirs), 4096):
        D = dirs[s : s + 4096]
        inside = bust_sdf(c0 + ts[None, :, None] * D[:, None, :], shape) < 0
        last = len(ts) - 1 - np.argmax(inside[:, ::-1], axis=1)  # outermost inside sample
        lo, hi = ts[last], ts[last] + step
        for _ in range(22):
            mid = 0.5 * (lo + hi)
            ins = bust_sdf(c0 + mid[:, None] * D, shape) < 0
            lo, hi = np.where(ins, mid, lo), np.where(ins, hi, mid)
        out[s : s + 4096] = 0.5 * (lo + hi)
    return out


def _dirs(theta: np.ndarray, alpha: np.ndarray) -> np.ndarray:
    """Unit directions (..., 3) for azimuth theta (0 = +Z, +pi/2 = +X) and elevation alpha."""
    ca = np.cos(alpha)
    return np.stack([ca * np.sin(theta), np.sin(alpha), ca * np.cos(theta)], axis=-1)


# --- grid helpers ---------------------------------------------------------------------------

def _quads_to_tris(V: np.ndarray, quads: np.ndarray) -> np.ndarray:
    """Split quads (q, 4) (a, b, c, d in cyclic order) along the diagonal giving the larger minimum angle.

    Returns (2q, 3) local-order triangles; the pairs are (a,b,c),(a,c,d) or (a,b,d),(b,c,d).
    """
    def min_angle(t):
        P = V[t]
        ang = []
        for i in range(3):
            u = P[:, (i + 1) % 3] - P[:, i]
            w = P[:, (i + 2) % 3] - P[:, i]
            cos = (u * w).sum(1) / np.maximum(np.linalg.norm(u, axis=1) * np.linalg.norm(w, axis=1), 1e-12)
            ang.append(np.arccos(np.clip(cos, -1, 1)))
        return np.min(ang, axis=0)

    a, b, c, d = quads.T
    s1 = np.minimum(min_angle(np.stack([a, b, c], 1)), min_angle(np.stack([a, c, d], 1)))
    s2 = np.minimum(min_angle(np.stack([a, b, d], 1)), min_angle(np.stack([b, c, d], 1)))
    use1 = s1 >= s2
    t1 = np.where(use1[:, None], np.stack([a, b, c], 1), np.stack([a, b, d], 1))
    t2 = np.where(use1[:, None], np.stack([a, c, d], 1), np.stack([b, c, d], 1))
    return np.concatenate([t1, t2])


def _coons(bd: np.ndarray, a: int, b: int, smooth_iters: int = 60) -> np.ndarray:
    """Fill an (a+1, b+1) grid from its boundary loop (Coons patch + Laplacian smoothing).

    Args:
        bd: (2(a+b), d) boundary points in loop order starting at grid corner
            (0, b): top row p = 0..a, right column q = b..0, bottom row
            p = a..0, left column q = 0..b.
    Returns:
        (a+1, b+1, d) grid, G[p, q], boundary equal to ``bd``.
    """
    L = 2 * (a + b)
    assert len(bd) == L
    p = np.arange(a + 1)
    q = np.arange(b + 1)
    T = bd[p]                                   # q = b
    R = bd[a + (b - q)]                         # p = a
    B = bd[a + b + (a - p)]                     # q = 0
    Lf = bd[(2 * a + b + q) % L]                # p = 0
    u = (p / a)[:, None, None]
    v = (q / b)[None, :, None]
    G = ((1 - v) * B[:, None] + v * T[:, None] + (1 - u) * Lf[None, :] + u * R[None, :]
         - ((1 - u) * (1 - v) * B[0] + u * (1 - v) * B[a] + (1 - u) * v * T[0] + u * v * T[a]))
    for _ in range(smooth_iters):  # Tutte-like relaxation of the interior (convex boundary: no flips)
        G[1:-1, 1:-1] = 0.25 * (G[:-2, 1:-1] + G[2:, 1:-1] + G[1:-1, :-2] + G[1:-1, 2:])
    return G


def _sdf_normal(P: np.ndarray, shape: BustShape, eps: float = 0.05) -> np.ndarray:
    """(n, 3) gradient of :func:`bust_sdf` by central differences (not normalised)."""
    g = np.empty_like(P)
    for i in range(3):
        d = np.zeros(3)
        d[i] = eps
        g[:, i] = (bust_sdf(P + d, shape) - bust_sdf(P - d, shape)) / (2 * eps)
    return g


def _project(P: np.ndarray, shape: BustShape, steps: int = 4) -> np.ndarray:
    """Newton steps taking points near the surface onto it."""
    for _ in range(steps):
        g = _sdf_normal(P, shape)
        f = bust_sdf(P, shape)
        P = P - (f / np.maximum((g * g).sum(1), 1e-12))[:, None] * g
    return P


def _relax_on_surface(V: np.ndarray, quads: np.ndarray, free: np.ndarray, shape: BustShape,
                      iterations: int = 40, step: float = 0.5) -> np.ndarray:
    """Tangential umbrella smoothing of the ``free`` vertices, re-projected onto the implicit surface."""
    import scipy.sparse as sp

    if iterations <= 0 or not free.any():
        return V
    e = np.concatenate([quads[:, [0, 1]], quads[:, [1, 2]], quads[:, [2, 3]], quads[:, [3, 0]]])
    e = np.unique(np.sort(e, axis=1), axis=0)
    n = len(V)
    A = sp.coo_matrix((np.ones(2 * len(e)), (np.r_[e[:, 0], e[:, 1]], np.r_[e[:, 1], e[:, 0]])), shape=(n, n)).tocsr()
    A.data[:] = 1.0
    deg = np.asarray(A.sum(1)).ravel()
    idx = np.flatnonzero(free)
    V = V.copy()
    for _ in range(iterations):
        avg = (A[idx] @ V) / deg[idx, None]
        d = avg - V[idx]
        nrm = _sdf_normal(V[idx], shape)
        nrm /= np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-12)
        d -= (d * nrm).sum(1, keepdims=True) * nrm
        V[idx] = _project(V[idx] + step * d, shape, steps=2)
    V[idx] = _project(V[idx], shape, steps=4)
    return V


def _grid_quads(idx: np.ndarray) -> np.ndarray:
    """(P-1)(Q-1) quads of an index grid idx (P, Q): (i,j),(i+1,j),(i+1,j+1),(i,j+1)."""
    return np.stack([idx[:-1, :-1], idx[1:, :-1], idx[1:, 1:], idx[:-1, 1:]], -1).reshape(-1, 4)


def _cumulative(points: np.ndarray) -> np.ndarray:
    """(n,) cumulative polyline length along axis 0 of (n, ..., 3), averaged over the trailing curves."""
    seg = np.linalg.norm(np.diff(points, axis=0), axis=-1)
    if seg.ndim > 1:
        seg = seg.mean(axis=tuple(range(1, seg.ndim)))
    return np.concatenate([[0.0], np.cumsum(seg)])


def _resample(param: np.ndarray, s: np.ndarray, n: int) -> np.ndarray:
    """n+1 values of ``param`` at uniform steps of the monotone length ``s``."""
    return np.interp(np.linspace(s[0], s[-1], n + 1), s, param)


# --- the Bust -------------------------------------------------------------------------------

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
    c0 = np.array([0.0, sh.centre_y, sh.neck_axis_z])
    a_top = math.radians(top_elevation_deg)
    a_edge = -math.atan2(sh.centre_y - sh.neck_cut_y, sh.neck_radius)
    cast = lambda th, al: c0 + _cast(sh, c0, _dirs(th, al).reshape(-1, 3))[:, None] * _dirs(th, al).reshape(-1, 3)  # noqa: E731

    # columns: azimuths uniform in arc length along a few rows, symmetric about theta = 0
    th_f = np.linspace(-np.pi, np.pi, 721)
    al_ref = np.array([0.9, 0.5, 0.0, -0.4, -0.9]) * a_top
    ring = cast(np.repeat(th_f[:, None], len(al_ref), 1), np.repeat(al_ref[None], len(th_f), 0)).reshape(len(th_f), -1, 3)
    s_th = _cumulative(ring)
    s_th = 0.5 * (s_th + (s_th[-1] - s_th[::-1]))  # exact symmetry
    n = max(4, int(round(s_th[-1] / h / 2)))
    N = 2 * n
    theta = _resample(th_f, s_th, N)[:-1]         # theta[0] = -pi (back), theta[n] = 0 (front)
    theta[n] = 0.0

    # rows: elevations uniform in arc length along four meridians, two rows forced at the lips
    al_f = np.linspace(a_top, a_edge, 1201)
    mer_th = np.array([0.0, 0.5 * np.pi, np.pi, -0.5 * np.pi])
    mer = cast(np.repeat(mer_th[None], len(al_f), 0), np.repeat(al_f[:, None], 4, 1)).reshape(len(al_f), 4, 3)
    s_al = _cumulative(mer)
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
    j_up = n1                                      # upper lip row; j_up + 1 is the lower lip row
    R = len(alpha)

    TH, AL = np.meshgrid(theta, alpha, indexing="xy")   # (R, N)
    Vmain = cast(TH, AL).reshape(R, N, 3)
    Vmain[-1, :, 1] = sh.neck_cut_y
    xs = Vmain[j_up, :, 0]
    m = int(np.sum((xs[n + 1 :] < sh.mouth_half_width) & (theta[n + 1 :] < 0.5 * np.pi)))
    m = max(m, 2)
    ids = np.arange(R * N).reshape(R, N)
    verts = [Vmain.reshape(-1, 3)]
    n_verts = R * N

    # main chart UVs (local [0,1]^2, u with face boost, seam column duplicated)
    th_u = np.append(theta, np.pi)
    w_th = 1.0 + face_uv_boost * 0.5 * (1.0 + np.cos(0.5 * (th_u[:-1] + th_u[1:])))
    seg = np.diff(s_th_at := np.interp(th_u, th_f, s_th)) * w_th
    u_main = np.concatenate([[0.0], np.cumsum(seg)]) / seg.sum()
    s_rows = np.interp(-alpha, -al_f, s_al)
    v_main = 1.0 - s_rows / s_rows[-1]
    main_mm = (s_th_at[-1], s_rows[-1])
    uv_ids_main = np.arange(R * (N + 1)).reshape(R, N + 1)
    UV_main = np.stack(np.meshgrid(u_main, v_main, indexing="xy"), -1).reshape(-1, 2)

    cells_i, cells_j = np.meshgrid(np.arange(N), np.arange(R - 1), indexing="xy")
    keep = ~((cells_j == j_up) & (cells_i >= n - m) & (cells_i < n + m))
    ci, cj = cells_i[keep], cells_j[keep]
    q_main = np.stack([ids[cj, ci], ids[cj + 1, ci], ids[cj + 1, (ci + 1) % N], ids[cj, (ci + 1) % N]], 1)
    quv_main = np.stack([uv_ids_main[cj, ci], uv_ids_main[cj + 1, ci], uv_ids_main[cj + 1, ci + 1], uv_ids_main[cj, ci + 1]], 1)

    patches = []  # (name, quads (q,4) vertex ids, quads uv ids local, UV local (k,2), size_mm (w,h))
    patches.append(("main", q_main, quv_main, UV_main, main_mm))

    def add_verts(P):
        nonlocal n_verts
        P = P.reshape(-1, 3)
        verts.append(P)
        out = np.arange(n_verts, n_verts + len(P))
        n_verts += len(P)
        return out

    def cap_patch(name, ring_ids, a, b, start, interior_fn):
        """Grid cap (a x b cells) whose boundary is the closed loop ring_ids (2(a+b),) from ``start``."""
        L = len(ring_ids)
        loop = np.asarray(ring_ids)[(start + np.arange(L)) % L]
        V_all = np.concatenate(verts)
        G = interior_fn(V_all[loop], a, b)                  # (a+1, b+1, 3)
        gid = np.full((a + 1, b + 1), -1, dtype=np.int64)
        p = np.arange(a + 1)
        q = np.arange(b + 1)
        gid[p, b] = loop[p]
        gid[a, q] = loop[a + (b - q)]
        gid[p, 0] = loop[a + b + (a - p)]
        gid[0, q] = loop[(2 * a + b + q) % L]
        if a > 1 and b > 1:
            gid[1:-1, 1:-1] = add_verts(G[1:-1, 1:-1]).reshape(a - 1, b - 1)
        Vc = np.concatenate(verts)
        span_u = np.linalg.norm(np.diff(Vc[gid], axis=0), axis=-1).sum(0).mean()
        span_v = np.linalg.norm(np.diff(Vc[gid], axis=1), axis=-1).sum(1).mean()
        uvg = np.stack(np.meshgrid(p / a, q / b, indexing="ij"), -1)
        uid = np.arange((a + 1) * (b + 1)).reshape(a + 1, b + 1)
        patches.append((name, _grid_quads(gid), _grid_quads(uid), uvg.reshape(-1, 2), (span_u, span_v)))

    def split_ab(L2, ratio):
        """a + b = L2 with a even, a / b ~ ratio."""
        a = int(round(L2 * ratio / (1 + ratio) / 2)) * 2
        a = min(max(a, 2), L2 - 1 - ((L2 - 1) % 1))
        return a, L2 - a

    # crown: Coons patch in the (x, z) plane of the directions, uniform in polar angle, then cast
    psi_max = 0.5 * np.pi - a_top

    def crown(bd, a, b):
        dd = bd - c0  # boundary directions, in bd's order
        dd /= np.linalg.norm(dd, axis=1, keepdims=True)
        G2 = _coons(dd[:, [0, 2]], a, b)
        rho = np.linalg.norm(G2, axis=-1)
        rho_max = math.cos(a_top)
        psi = np.clip(rho / rho_max, 0, 1) * psi_max
        scale = np.divide(np.sin(psi), rho, out=np.zeros_like(rho), where=rho > 1e-12)
        D = np.stack([G2[..., 0] * scale, np.cos(psi), G2[..., 1] * scale], -1)
        t = _cast(sh, c0, D.reshape(-1, 3)).reshape(D.shape[:2])
        return c0 + t[..., None] * D

    top_ring = ids[0]
    ext = Vmain[0].max(0) - Vmain[0].min(0)
    a_t, b_t = split_ab(n, ext[0] / ext[2])
    cap_patch("top", top_ring, a_t, b_t, n - a_t // 2, crown)

    def flat(bd, a, b):
        G = _coons(bd, a, b)
        G[..., 1] = sh.neck_cut_y
        return G

    bot_ring = ids[-1]
    a_b, b_b = split_ab(n, 1.0)
    cap_patch("bottom", bot_ring, a_b, b_b, n - a_b // 2, flat)

    # mouth pocket: lip loop (upper lip row left->right, lower lip row right->left)
    upper = ids[j_up, n - m : n + m + 1]
    lower = ids[j_up + 1, n - m : n + m + 1][::-1]
    lip = np.concatenate([upper, lower])
    L = len(lip)                                   # 4m + 2
    P0 = Vmain.reshape(-1, 3)[lip]
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
        rings.append(add_verts(Pk))
    rid = np.stack(rings, 0)                                   # (K+1, L)
    kk, ll = np.meshgrid(np.arange(K), np.arange(L), indexing="ij")
    q_tube = np.stack([rid[kk, ll], rid[kk + 1, ll], rid[kk + 1, (ll + 1) % L], rid[kk, (ll + 1) % L]], -1).reshape(-1, 4)
    uid_t = np.arange((K + 1) * (L + 1)).reshape(K + 1, L + 1)
    quv_tube = np.stack([uid_t[kk, ll], uid_t[kk + 1, ll], uid_t[kk + 1, ll + 1], uid_t[kk, ll + 1]], -1).reshape(-1, 4)
    ring_pts = np.stack(ring_pts)
    depth_mm = _cumulative(ring_pts)
    UV_tube = np.stack(np.meshgrid(np.arange(L + 1) / L, 1.0 - depth_mm / depth_mm[-1], indexing="xy"), -1).reshape(-1, 2)
    patches.append(("pocket", q_tube, quv_tube, UV_tube, (loop_len, depth_mm[-1])))

    end_ratio = 2 * w0 * (0.92 - 0.25) / pocket_height_mm
    a_p, b_p = split_ab(L // 2, end_ratio)
    cap_patch("pocket_end", rid[-1], a_p, b_p, m - a_p // 2, lambda bd, a, b: _coons(bd, a, b))

    V = np.concatenate(verts)
    # even out the sampling on the implicit surface (rays from c0 crowd where the surface is oblique)
    free = np.zeros(len(V), bool)
    free[: R * N] = True
    free[ids[-1]] = False                      # neck-cut crease
    free[lip] = False                          # lip edges
    top_ids = np.concatenate([p[1].ravel() for p in patches if p[0] == "top"])
    free[top_ids] = True
    all_q = np.concatenate([p[1] for p in patches])
    V = _relax_on_surface(V, all_q, free, sh, iterations=relax_iterations)
    Vmain = V[: R * N].reshape(R, N, 3)
    return _assemble(V, patches, sh, Vmain, n, j_up, m, rid)


def _assemble(V, patches, sh, Vmain, n, j_up, m, rid) -> Bust:
    """Triangulate, orient, pack the UV charts and collect landmarks."""
    # orient: each patch consistent with those accepted before (shared directed edges must be opposite)
    tris, tuv, labels = [], [], []
    seen = set()
    for name, q, quv, UV, _ in patches:
        order = _quads_to_tris(V, q)
        nq = len(q)
        # same local split for the UV quads: recover which diagonal was used per quad
        t_v = order
        split1 = (t_v[:nq, 2] == q[:, 2])
        a, b, c, d = quv.T
        t1 = np.where(split1[:, None], np.stack([a, b, c], 1), np.stack([a, b, d], 1))
        t2 = np.where(split1[:, None], np.stack([a, c, d], 1), np.stack([b, c, d], 1))
        t_uv = np.concatenate([t1, t2])
        # make the local UV triangles counter-clockwise
        P = UV[t_uv]
        e1, e2 = P[:, 1] - P[:, 0], P[:, 2] - P[:, 0]
        area = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
        if np.median(area) < 0:
            t_v, t_uv = t_v[:, ::-1], t_uv[:, ::-1]
        edges = {(int(x), int(y)) for tri in t_v for x, y in ((tri[0], tri[1]), (tri[1], tri[2]), (tri[2], tri[0]))}
        if edges & seen:  # same directed edge as an accepted patch: reverse faces, mirror the chart
            t_v, t_uv = t_v[:, ::-1], t_uv[:, ::-1]
            UV = UV.copy()
            UV[:, 0] = 1.0 - UV[:, 0]
            edges = {(y, x) for x, y in edges}
        seen |= edges
        tris.append(t_v)
        tuv.append(t_uv)
        labels.append(np.full(len(t_v), CHARTS.index(name)))
        patches[[p[0] for p in patches].index(name)] = (name, q, quv, UV, _)
    F = np.concatenate(tris).astype(np.int64)
    face_chart = np.concatenate(labels).astype(np.int64)

    # pack: main chart on top (full width), the others in a row below, scaled to fit
    sizes = {p[0]: p[4] for p in patches}
    mg = UV_MARGIN
    W, H = sizes["main"]
    main_h = min(0.7, (1 - 2 * mg) * H / W)
    rects = {"main": (mg, 1 - mg - main_h, 1 - mg, 1 - mg)}
    rest = [p[0] for p in patches if p[0] != "main"]
    strip_h = 1 - main_h - 4 * mg
    widths = np.array([sizes[r][0] for r in rest])
    heights = np.array([sizes[r][1] for r in rest])
    sigma = min(strip_h / heights.max(), (1 - 2 * mg * len(rest)) / widths.sum())
    x = mg
    for r, w, hh in zip(rest, widths, heights):
        rects[r] = (x, mg, x + w * sigma, mg + hh * sigma)
        x += w * sigma + 2 * mg
    UV_all, F_uv, off = [], [], 0
    for (name, _, _, UV, _), t_uv in zip(patches, tuv):
        u0, v0, u1, v1 = rects[name]
        UV_all.append(np.column_stack([u0 + UV[:, 0] * (u1 - u0), v0 + UV[:, 1] * (v1 - v0)]))
        F_uv.append(t_uv + off)
        off += len(UV)
    UV_all = np.concatenate(UV_all)
    F_uv = np.concatenate(F_uv).astype(np.int64)

    mesh = TexturedMesh(V, F, UV_all, F_uv)
    vol = np.einsum("ij,ij->i", V[F[:, 0]], np.cross(V[F[:, 1]], V[F[:, 2]])).sum() / 6.0
    if vol < 0:  # should not happen: the main grid is built outward
        raise RuntimeError("bust construction produced an inward-oriented surface")
    pocket_faces = np.flatnonzero(np.isin(face_chart, [CHARTS.index(c) for c in POCKET_CHARTS])).astype(np.int64)

    front = Vmain[:, n]
    below = front[:, 1] < sh.mouth_y - 20
    chin = front[below][np.argmax(front[below][:, 2])]
    lm = {
        "mouth": 0.5 * (Vmain[j_up, n] + Vmain[j_up + 1, n]),
        "mouth_right": 0.5 * (Vmain[j_up, n - m] + Vmain[j_up + 1, n - m]),
        "mouth_left": 0.5 * (Vmain[j_up, n + m] + Vmain[j_up + 1, n + m]),
        "nose_tip": Vmain.reshape(-1, 3)[np.argmax(Vmain.reshape(-1, 3)[:, 2])].copy(),
        "chin": chin.copy(),
        "head_top": V[np.argmax(V[:, 1])].copy(),
        "neck_cut": np.array([0.0, sh.neck_cut_y, sh.neck_axis_z]),
        "pocket_end": V[rid[-1]].mean(0),
    }
    return Bust(mesh=mesh, pocket_faces=pocket_faces, face_chart=face_chart, charts=rects, landmarks=lm)


# --- placement --------------------------------------------------------------------------------

def _scan_points(scan_V) -> np.ndarray:
    P = np.asarray(scan_V, dtype=np.float64)
    if P.ndim != 2 or P.shape[1] != 3 or len(P) == 0:
        raise InputError("scan", f"expected a non-empty (n, 3) array of scan vertices, got shape {P.shape}")
    P = P[np.isfinite(P).all(1)]
    if len(P) < 100:
        raise InputError("scan", f"only {len(P)} finite scan vertices; too few to place the bust")
    lo, hi = np.percentile(P, [1, 99], axis=0)
    ext = float((hi - lo).max())
    if not SCAN_EXTENT_RANGE_MM[0] <= ext <= SCAN_EXTENT_RANGE_MM[1]:
        raise InputError("scan", f"robust extent {ext:.4g} is outside [{SCAN_EXTENT_RANGE_MM[0]:g}, "
                                 f"{SCAN_EXTENT_RANGE_MM[1]:g}]: the scan does not look like a head in millimetres")
    return P


def fit_placement(bust: Bust, scan_V, iterations: int = 80, trim: float = 0.8, max_points: int = 20000,
                  seed: int = 0) -> tuple[float, np.ndarray]:
    """Scale and translation taking ``bust`` onto a scan in the canonical frame.

    Initial guess: the scale of the robust head width (X, percentiles 2-98 of
    the points above the mouth level) and the nose tip (the front-most
    points); refined by a trimmed ICP with uniform scale + translation only (no
    rotation: the frame is canonical) matching scan points to their nearest
    bust surface samples, so the scan's holes (back/top of skull) do not bias it.

    Args:
        scan_V: (n, 3) float64 scan vertices, mm.
        trim: fraction of closest correspondences kept per iteration.
    Returns:
        (scale, translation (3,)) such that ``bust.transformed(scale, translation)`` overlaps the scan.
    Raises:
        InputError: empty scan, or not in millimetres (robust extent outside 80-1500 mm).
    """
    from scipy.spatial import cKDTree

    P = _scan_points(scan_V)
    rng = np.random.default_rng(seed)
    if len(P) > max_points:
        P = P[rng.choice(len(P), max_points, replace=False)]
    B = _surface_samples(bust.mesh, spacing_mm=2.0)
    # initial guess
    zq = np.percentile(P[:, 2], 99.5)
    tip_s = P[P[:, 2] >= zq].mean(0)
    tip_b = bust.landmarks["nose_tip"]
    yb_mouth = bust.landmarks["mouth"][1]
    up_b = B[(B[:, 1] > yb_mouth) & (B[:, 1] < bust.landmarks["head_top"][1])]
    wb = np.subtract(*np.percentile(up_b[:, 0], [98, 2]))
    band = P[P[:, 1] > tip_s[1] - 0.5 * (tip_b[1] - yb_mouth)]
    ws = np.subtract(*np.percentile((band if len(band) > 50 else P)[:, 0], [98, 2]))
    s = float(np.clip(ws / wb, 0.6, 1.6))
    t = tip_s - s * tip_b
    t[0] = 0.5 * np.sum(np.percentile(P[:, 0], [2, 98])) - s * 0.0
    tree = cKDTree(B)
    for _ in range(iterations):
        # nearest bust sample for each scan point, in bust coordinates
        d, idx = tree.query((P - t) / s)
        keep = d <= np.quantile(d, trim)
        q, b = P[keep], B[idx[keep]]
        qm, bm = q.mean(0), b.mean(0)
        bc, qc = b - bm, q - qm
        s_new = float((bc * qc).sum() / max((bc * bc).sum(), 1e-12))
        s_new = float(np.clip(s_new, 0.5 * s, 2.0 * s))
        t_new = qm - s_new * bm
        done = abs(s_new - s) < 1e-5 and np.linalg.norm(t_new - t) < 1e-3
        s, t = s_new, t_new
        if done:
            break
    return s, t


def place_bust(bust: Bust, scan_V, **kwargs) -> Bust:
    """The bust scaled and translated to approximately overlap a scan (see :func:`fit_placement`).

    Args:
        scan_V: (n, 3) float64 scan vertices in the canonical head frame, mm.
    Raises:
        InputError: empty scan, or not in millimetres.
    """
    s, t = fit_placement(bust, scan_V, **kwargs)
    return bust.transformed(s, t)


def _surface_samples(mesh: TexturedMesh, spacing_mm: float = 2.0) -> np.ndarray:
    """(k, 3) points on the surface: vertices, face centroids and edge midpoints (deterministic)."""
    V, F = mesh.V, mesh.F
    tri = V[F]
    pts = [V, tri.mean(1)]
    e = np.unique(np.sort(F[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1), axis=0)
    pts.append(0.5 * (V[e[:, 0]] + V[e[:, 1]]))
    return np.concatenate(pts)
