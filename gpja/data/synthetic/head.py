"""Procedural head identity and its rest-pose implicit surface (signed distance).

The rest head is a sequence of constructive-solid-geometry steps on
ellipsoids (smooth unions and subtractions, Inigo Quilez's polynomial smooth
minimum), evaluated by a small numba interpreter. Frame: the canonical head
frame, face towards +Z, top of the head towards +Y, X towards the subject's
left, millimetres, origin near the head centre.

The rest surface is genus 0: the mouth is a pocket (slit between the lips
opening into an oral cavity) and the eyes are spheres set into sockets.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numba
import numpy as np

#: Columns of one CSG step: op, k (blend radius, mm), centre (3), semi-axes (3),
#: rotation (9, row-major, world -> primitive frame).
_ROW = 17
OP_UNION, OP_SUBTRACT, OP_HARD_UNION = 0.0, 1.0, 2.0
EYE_RADIUS_MM = 12.0


@dataclass(frozen=True)
class HeadParams:
    """Identity parameters of one synthetic subject (all lengths in mm).

    Drawn by :func:`sample_head_params`; stored in ``subject.json``.
    """

    cranium_half_width: float = 74.0
    cranium_half_height: float = 92.0
    cranium_half_depth: float = 99.0
    face_length: float = 1.08       # vertical scale of the lower face
    jaw_half_width: float = 57.0
    chin_half_width: float = 20.0
    cheek_size: float = 1.0
    brow_prominence: float = 1.0
    nose_length: float = 1.0
    nose_width: float = 1.0
    eye_half_spacing: float = 32.0
    mouth_half_width: float = 24.0
    lip_thickness: float = 1.0
    ear_size: float = 1.0
    neck_half_width: float = 50.0
    skin_tone: float = 0.3          # 0 light .. 1 dark
    skin_hue: float = 0.0           # -1 yellowish .. 1 reddish
    iris_hue: float = 0.5           # 0 blue .. 1 brown
    hair_tone: float = 0.2          # 0 black .. 1 light brown
    freckle_density: float = 0.5
    albedo_seed: int = 0

    def to_dict(self) -> dict:
        return asdict(self)

    # --- derived landmarks of the construction (rest frame, mm) ---------------
    @property
    def mouth_y(self) -> float:
        """y of the mouth slit's centre line."""
        return -54.0 * self.face_length

    @property
    def lip_front_z(self) -> float:
        return 98.0

    def eye_center(self, side: int) -> np.ndarray:
        """(3,) centre of the eyeball; side -1 = subject's right (-X), +1 = left."""
        x = side * self.eye_half_spacing
        y = 12.0
        surf = self._cranium_front_z(x, y)
        return np.array([x, y, surf - EYE_RADIUS_MM - 3.0])

    def _cranium_front_z(self, x: float, y: float) -> float:
        cy, cz = 20.0, -5.0  # cranium centre (x = 0)
        q = 1.0 - (x / self.cranium_half_width) ** 2 - ((y - cy) / self.cranium_half_height) ** 2
        return cz + self.cranium_half_depth * math.sqrt(max(q, 0.0))


def sample_head_params(rng: np.random.Generator) -> HeadParams:
    """Draw one identity from ``rng`` (proportions, features, colours)."""
    u = lambda lo, hi: float(rng.uniform(lo, hi))  # noqa: E731
    return HeadParams(
        cranium_half_width=u(70.0, 78.0),
        cranium_half_height=u(88.0, 96.0),
        cranium_half_depth=u(95.0, 103.0),
        face_length=u(1.02, 1.14),
        jaw_half_width=u(52.0, 61.0),
        chin_half_width=u(16.0, 24.0),
        cheek_size=u(0.85, 1.15),
        brow_prominence=u(0.7, 1.3),
        nose_length=u(0.85, 1.15),
        nose_width=u(0.85, 1.2),
        eye_half_spacing=u(30.0, 34.0),
        mouth_half_width=u(22.0, 26.0),
        lip_thickness=u(0.8, 1.2),
        ear_size=u(0.9, 1.1),
        neck_half_width=u(46.0, 54.0),
        skin_tone=u(0.0, 1.0),
        skin_hue=u(-1.0, 1.0),
        iris_hue=u(0.0, 1.0),
        hair_tone=u(0.0, 1.0),
        freckle_density=u(0.2, 1.0),
        albedo_seed=int(rng.integers(0, 2**31 - 1)),
    )


def _rot(yaw_deg: float = 0.0, pitch_deg: float = 0.0, roll_deg: float = 0.0) -> np.ndarray:
    """World -> primitive rotation (3, 3): inverse of R_y(yaw) R_x(pitch) R_z(roll)."""
    a, b, c = np.radians([yaw_deg, pitch_deg, roll_deg])
    Ry = np.array([[math.cos(a), 0, math.sin(a)], [0, 1, 0], [-math.sin(a), 0, math.cos(a)]])
    Rx = np.array([[1, 0, 0], [0, math.cos(b), -math.sin(b)], [0, math.sin(b), math.cos(b)]])
    Rz = np.array([[math.cos(c), -math.sin(c), 0], [math.sin(c), math.cos(c), 0], [0, 0, 1]])
    return (Ry @ Rx @ Rz).T


def _row(op, k, center, axes, rot=None) -> np.ndarray:
    r = np.zeros(_ROW)
    r[0], r[1] = op, k
    r[2:5] = center
    r[5:8] = axes
    r[8:17] = (np.eye(3) if rot is None else rot).ravel()
    return r


def build_head_program(p: HeadParams) -> dict[str, np.ndarray]:
    """The CSG program of the rest head.

    Returns:
        dict with ``"head"`` (k, 17) float64 — the full head — and ``"pocket"``
        (k', 17) — the mouth pocket alone (used by the albedo to darken the oral
        cavity); rows are (op, k, centre, semi-axes, rotation).
    """
    f = p.face_length
    my = p.mouth_y
    rows = []
    U, S = OP_UNION, OP_SUBTRACT
    rows.append(_row(U, 0, (0, 20, -5), (p.cranium_half_width, p.cranium_half_height, p.cranium_half_depth)))
    # lower face / jaw mass
    rows.append(_row(U, 22, (0, -38 * f, 18), (p.jaw_half_width, 55 * f, 72)))
    # neck
    rows.append(_row(U, 25, (0, -150, -12), (p.neck_half_width, 88, p.neck_half_width * 0.95)))
    # chin
    rows.append(_row(U, 12, (0, -86 * f, 70), (p.chin_half_width, 15 * f, 17)))
    # cheek bones
    cs = p.cheek_size
    for s in (-1, 1):
        rows.append(_row(U, 12, (s * 42, -18 * f, 62), (20 * cs, 15 * cs, 20 * cs)))
    # brow ridge
    rows.append(_row(U, 10, (0, 31, 80 + 2 * p.brow_prominence), (58, 10, 13 * p.brow_prominence)))
    # nose: bridge, tip lobe, alae
    nl, nw = p.nose_length, p.nose_width
    rows.append(_row(U, 6, (0, 8, 96), (7 * nw, 24 * nl, 9), _rot(pitch_deg=-25)))
    rows.append(_row(U, 4, (0, -14 * f, 101 + 6 * nl), (9 * nw, 8, 9)))
    rows.append(_row(U, 4, (0, -17 * f, 96), (5 * nw, 5, 10)))
    rows.append(_row(U, 6, (0, -10 * f, 90), (13 * nw, 12, 11)))
    for s in (-1, 1):
        rows.append(_row(U, 4, (s * 12 * nw, -18 * f, 95 + 3 * nl), (7 * nw, 6.5, 7)))
    # ears (flattened discs with a concha hollow)
    es = p.ear_size
    for s in (-1, 1):
        ex = s * (p.cranium_half_width + 1.0)
        rows.append(_row(U, 4, (ex, 0, -8), (7, 30 * es, 18 * es), _rot(yaw_deg=-s * 20)))
        rows.append(_row(S, 2, (ex + s * 7, -2, -6), (4, 13 * es, 9 * es), _rot(yaw_deg=-s * 20)))
    # lips
    lt = p.lip_thickness
    rows.append(_row(U, 3, (0, my + 6.0 * f, 90), (p.mouth_half_width + 1, 6.0 * lt, 8 * lt)))
    rows.append(_row(U, 3, (0, my - 6.5 * f, 88.5), (p.mouth_half_width - 2, 6.5 * lt, 8.5 * lt)))
    # eye sockets
    for s in (-1, 1):
        c = p.eye_center(s)
        rows.append(_row(S, 3, (c[0], c[1], c[2] + 15.0), (19, 7.5, 12)))
    # mouth pocket: slit between the lips + oral cavity behind
    pocket = [
        _row(U, 0, (0, my, 88), (p.mouth_half_width, 2.3, 22)),
        _row(U, 3, (0, my - 2, 56), (p.mouth_half_width - 1, 12, 17)),
    ]
    for r in pocket:
        rr = r.copy()
        rr[0], rr[1] = S, 1.5
        rows.append(rr)
    # eyeballs (smooth union makes a small lid fillet at the crease)
    for s in (-1, 1):
        rows.append(_row(OP_UNION, 1.2, p.eye_center(s), (EYE_RADIUS_MM,) * 3))
    return {"head": np.stack(rows), "pocket": np.stack(pocket)}


@numba.njit(cache=True, fastmath=False, inline="always")
def _ellipsoid(px, py, pz, row):
    qx = px - row[2]
    qy = py - row[3]
    qz = pz - row[4]
    lx = row[8] * qx + row[9] * qy + row[10] * qz
    ly = row[11] * qx + row[12] * qy + row[13] * qz
    lz = row[14] * qx + row[15] * qy + row[16] * qz
    ax, ay, az = row[5], row[6], row[7]
    k0 = math.sqrt((lx / ax) ** 2 + (ly / ay) ** 2 + (lz / az) ** 2)
    k1 = math.sqrt((lx / (ax * ax)) ** 2 + (ly / (ay * ay)) ** 2 + (lz / (az * az)) ** 2)
    if k1 < 1e-12:
        return -min(ax, min(ay, az))
    return k0 * (k0 - 1.0) / k1


@numba.njit(cache=True, inline="always")
def _smin(a, b, k):
    if k <= 0.0:
        return min(a, b)
    h = max(k - abs(a - b), 0.0) / k
    return min(a, b) - h * h * k * 0.25


@numba.njit(cache=True)
def _sdf_point(px, py, pz, prog):
    d = 1e9
    for i in range(prog.shape[0]):
        row = prog[i]
        e = _ellipsoid(px, py, pz, row)
        op = row[0]
        if op == 0.0:
            d = _smin(d, e, row[1])
        elif op == 1.0:
            d = -_smin(-d, e, row[1])
        else:
            d = min(d, e)
    return d


@numba.njit(cache=True, parallel=True)
def _sdf_points(P, prog, out):
    for i in numba.prange(P.shape[0]):
        out[i] = _sdf_point(P[i, 0], P[i, 1], P[i, 2], prog)


def evaluate_sdf(points: np.ndarray, program: np.ndarray) -> np.ndarray:
    """Signed distance (approximate, exact sign) of a CSG program.

    Args:
        points: (n, 3) float64 rest-space points, mm.
        program: (k, 17) float64 from :func:`build_head_program`.
    Returns:
        (n,) float64, negative inside, mm (a close bound near the surface).
    """
    P = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
    out = np.empty(len(P))
    _sdf_points(P, np.ascontiguousarray(program, dtype=np.float64), out)
    return out


@numba.njit(cache=True, parallel=True)
def _fill_blocks(blocks, origin, h, B, prog, grid):
    nx, ny, nz = grid.shape
    for bi in numba.prange(blocks.shape[0]):
        i0, j0, k0 = blocks[bi, 0] * B, blocks[bi, 1] * B, blocks[bi, 2] * B
        for i in range(i0, min(i0 + B + 1, nx)):
            x = origin[0] + i * h
            for j in range(j0, min(j0 + B + 1, ny)):
                y = origin[1] + j * h
                for k in range(k0, min(k0 + B + 1, nz)):
                    grid[i, j, k] = _sdf_point(x, y, origin[2] + k * h, prog)


#: Rest-space bounding box of every head this module builds (mm).
HEAD_BOUNDS_MM = np.array([[-100.0, -245.0, -112.0], [100.0, 118.0, 132.0]])


def sample_sdf_grid(program: np.ndarray, voxel_mm: float, offset: np.ndarray | None = None,
                    block: int = 6) -> tuple[np.ndarray, np.ndarray]:
    """Sample the SDF on a regular grid, exactly only in a band around the surface.

    Blocks of ``block`` voxels whose corner value shows they are far from the
    surface are filled with a constant of the right sign (marching cubes only
    needs the sign there).

    Args:
        program: (k, 17) CSG program.
        voxel_mm: grid spacing h, mm.
        offset: (3,) sub-voxel shift of the grid origin, mm (default 0).
    Returns:
        grid: (nx, ny, nz) float32 signed distances, mm.
        origin: (3,) float64 position of grid[0, 0, 0], mm.
    """
    h = float(voxel_mm)
    origin = HEAD_BOUNDS_MM[0] + (np.zeros(3) if offset is None else np.asarray(offset, float))
    n = np.ceil((HEAD_BOUNDS_MM[1] - origin) / h).astype(int) + 1
    B = int(block)
    nb = (n - 1 + B - 1) // B
    # coarse values at block centres decide which blocks straddle the surface
    idx = np.stack(np.meshgrid(*[np.arange(m) for m in nb], indexing="ij"), -1).reshape(-1, 3)
    centres = origin + (idx + 0.5) * B * h
    dc = evaluate_sdf(centres, program)
    half_diag = 0.5 * B * h * math.sqrt(3.0)
    # the ellipsoid bound under-estimates distance by up to ~2x far from the surface
    near = np.abs(dc) < 2.0 * half_diag + 2.0 * h
    grid = np.empty(tuple(n), dtype=np.float32)
    sign = np.where(dc < 0, -1.0, 1.0).reshape(tuple(nb)).astype(np.float32)
    fill = np.repeat(np.repeat(np.repeat(sign, B, 0), B, 1), B, 2)
    padded = np.pad(fill, [(0, max(0, n[a] - fill.shape[a])) for a in range(3)], mode="edge")
    grid[...] = padded[: n[0], : n[1], : n[2]] * (B * h)
    _fill_blocks(idx[near].astype(np.int64), origin, h, B, program, grid)
    return grid, origin


def extract_rest_mesh(program: np.ndarray, voxel_mm: float, offset=None) -> tuple[np.ndarray, np.ndarray]:
    """Marching-cubes triangulation of the rest surface.

    Returns:
        V: (n, 3) float64 rest positions, mm.
        F: (m, 3) int64 faces, outward (counter-clockwise seen from outside).
    """
    from skimage.measure import marching_cubes

    grid, origin = sample_sdf_grid(program, voxel_mm, offset)
    verts, faces, _, _ = marching_cubes(grid, level=0.0, spacing=(voxel_mm,) * 3,
                                        allow_degenerate=False, method="lewiner")
    V = origin + verts.astype(np.float64)
    F = faces.astype(np.int64)
    return V, F
