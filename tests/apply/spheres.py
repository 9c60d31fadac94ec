"""The UV-mapped test surface of the applications' tests: a lat-long sphere with a seam, written once."""
from __future__ import annotations

import numpy as np

from gpja.mesh import TexturedMesh


def latlong_sphere(n_lat: int, n_lon: int, radius: float, centre=(0.0, 0.0, 0.0)) -> TexturedMesh:
    """A lat-long sphere (y up), outward counter-clockwise faces, ``n_lat`` rings between the poles and ``n_lon``
    segments around: ``n_lat * n_lon + 2`` welded positions, ``2 * n_lat * n_lon`` faces.

    UVs: u = longitude / 2 pi (the column u = 1 repeats the positions of u = 0: a seam), v = 1 - polar
    angle / pi; each pole has one UV per segment (u at the segment's middle), so every pole spoke is a seam
    too: ``n_lat * (n_lon + 1) + 2 * n_lon`` texture coordinates.
    """
    theta = np.pi * np.arange(1, n_lat + 1) / (n_lat + 1)  # from the north pole (+y)
    phi = 2 * np.pi * np.arange(n_lon) / n_lon
    ring = np.stack([np.sin(theta)[:, None] * np.cos(phi)[None], np.cos(theta)[:, None] * np.ones(n_lon),
                     -np.sin(theta)[:, None] * np.sin(phi)[None]], axis=-1).reshape(-1, 3)
    V = np.asarray(centre, dtype=np.float64) + radius * np.vstack([[0, 1, 0], ring, [0, -1, 0]])
    north, south = 0, 1 + n_lat * n_lon

    def pos(i, j):  # ring i, column j (mod n_lon)
        return 1 + i * n_lon + j % n_lon

    def tex(i, j):  # ring UVs first: (n_lat, n_lon + 1), then the poles' per-segment UVs
        return i * (n_lon + 1) + j

    top_uv, bottom_uv = n_lat * (n_lon + 1), n_lat * (n_lon + 1) + n_lon
    uv_ring = np.stack(np.meshgrid(np.arange(n_lon + 1) / n_lon, 1 - np.arange(1, n_lat + 1) / (n_lat + 1)),
                       axis=-1).reshape(-1, 2)
    seg = (np.arange(n_lon) + 0.5) / n_lon
    UV = np.vstack([uv_ring, np.column_stack([seg, np.ones(n_lon)]), np.column_stack([seg, np.zeros(n_lon)])])
    F, F_uv = [], []
    for j in range(n_lon):
        F.append([north, pos(0, j), pos(0, j + 1)])
        F_uv.append([top_uv + j, tex(0, j), tex(0, j + 1)])
        for i in range(n_lat - 1):
            a, b, c, d = pos(i, j), pos(i + 1, j), pos(i + 1, j + 1), pos(i, j + 1)
            ta, tb, tc, td = tex(i, j), tex(i + 1, j), tex(i + 1, j + 1), tex(i, j + 1)
            F += [[a, b, c], [a, c, d]]
            F_uv += [[ta, tb, tc], [ta, tc, td]]
        F.append([south, pos(n_lat - 1, j + 1), pos(n_lat - 1, j)])
        F_uv.append([bottom_uv + j, tex(n_lat - 1, j + 1), tex(n_lat - 1, j)])
    return TexturedMesh(V, np.array(F), UV, np.array(F_uv))
