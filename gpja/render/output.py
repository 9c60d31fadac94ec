"""What every render backend returns and shares: the passes, a mesh's topology, the sparse output.

``gpja.render.passes`` (the CPU renderer) and ``gpja.render.nvdiffrast_backend``
both take a :class:`Topology` and return a :class:`RenderOutput`, so losses and
callers do not depend on the backend.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence

import numpy as np
import torch

from gpja.camera import Camera
from gpja.render.fragments import Fragments
from gpja.render.normals import vertex_incidence
from gpja.render.silhouettes import edge_candidates, face_adjacency

#: The paper's render passes: shaded colour F_S, depth F_D, normals F_N, and the mouth mask (the default).
PASSES = ("color", "depth", "normal", "mask")
#: Every pass a backend renders on request: the paper's, and the interpolated texture coordinates
#: (``"uv"``, OBJ convention; the texture reconstruction samples its texture there).
ALL_PASSES = PASSES + ("uv",)
#: Channels of each pass's values (``coverage`` is always rendered).
CHANNELS = {"color": 3, "depth": 1, "normal": 3, "mask": 1, "uv": 2, "coverage": 1}


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
    _candidates: np.ndarray | None = field(default=None, init=False, repr=False)
    _visit: tuple | None = field(default=None, init=False, repr=False)
    _visits_asked: int = field(default=0, init=False, repr=False)

    def __post_init__(self) -> None:
        self.faces = torch.as_tensor(np.asarray(self.faces), dtype=torch.int64)
        if self.uv_faces is not None:
            self.uv_faces = torch.as_tensor(np.asarray(self.uv_faces), dtype=torch.int64)
        if self.adjacency is None:
            self.adjacency = face_adjacency(self.faces.numpy())

    @classmethod
    def in_spatial_order(cls, V: np.ndarray, faces: np.ndarray, uv_faces: np.ndarray | None = None) -> "Topology":
        """The topology with its faces (and UV faces alike) permuted by :func:`spatial_face_order` of ``V``.

        Its renders are the unpermuted topology's (see there); face ids in them (``Fragments.tri_id``) index the
        permuted buffers, so use it where only the rendered values count (the registration's losses).
        """
        order = spatial_face_order(V, faces)
        return cls(np.asarray(faces)[order], None if uv_faces is None else np.asarray(uv_faces)[order])

    def silhouette_candidates(self) -> np.ndarray:
        """``edge_candidates`` of the adjacency (the edges the antialiasing searches), built once."""
        if self._candidates is None:
            self._candidates = edge_candidates(self.adjacency)
        return self._candidates

    def visit_order(self, V: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """The order in which the CPU renderer's rasteriser and silhouette search visit the faces and edges,
        or None for their own order. Neither output depends on it (``gpja.render.rasterize``,
        ``find_edge_pairs``); along a Z-order curve of the face centroids (:func:`spatial_face_order`)
        consecutive faces are neighbours on the screen as well, so the depth buffer and the walks' vertices
        stay in cache: at 100K vertices, 4 views at 512x512, the rasteriser takes a fifth less time and the
        silhouette search a tenth (docs/benchmarks.md, "The rasteriser's visiting order").

        Built from ``V`` (n, 3) (the positions of the render that asks) the second time a render asks: a
        topology rendered once (a flow stage's, a metric's) does not pay for the sort (~60 ms at 100K vertices),
        one rendered every iteration of a level does, once.

        Returns:
            ``(ids (m,) int64, faces[ids] (m, 3) int64, candidates (c, 4) int64)``: the faces in visiting order,
            and :meth:`silhouette_candidates` sorted (stably) by their face's place in ``ids``.
        """
        self._visits_asked += 1
        if self._visit is None and self._visits_asked >= 2:
            faces = self.faces.numpy()
            ids = spatial_face_order(V, faces)
            place = np.empty(len(ids), dtype=np.int64)
            place[ids] = np.arange(len(ids))
            candidates = self.silhouette_candidates()
            by_place = np.argsort(place[candidates[:, 0]], kind="stable")
            self._visit = (ids, np.ascontiguousarray(faces[ids]), np.ascontiguousarray(candidates[by_place]))
        return self._visit

    def incidence(self, n_vertices: int) -> tuple[np.ndarray, np.ndarray]:
        """``vertex_incidence`` of the faces for ``n_vertices`` vertices, built once."""
        if n_vertices not in self._incidence:
            self._incidence[n_vertices] = vertex_incidence(self.faces.numpy(), n_vertices)
        return self._incidence[n_vertices]


#: Bits per axis of :func:`spatial_face_order`'s Z-order curve: a 1024^3 grid over the mesh's bounding box
#: (0.3 mm cells on a head), finer than the faces of any registration level.
ORDER_BITS = 10


def spatial_face_order(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """A permutation of the faces along a Z-order (Morton) curve of their centroids.

    Rendering the permuted faces gives the same images (up to which of two faces at exactly the same depth wins
    a pixel, and the float rounding of per-vertex sums): the rasteriser and the scatter/gather kernels visit the
    faces in this order, and consecutive faces along the curve are neighbours on the surface and on the screen,
    so their pixels and vertices stay in cache. A refined registration mesh lists its faces grouped by how they
    were split, consecutive faces 80 mm apart on a head; along the curve they are 1 mm apart, and a render and
    its backward pass at 100K vertices take a fifth less time (docs/benchmarks.md). Written here because none of
    the dependencies sorts by a space-filling curve (meshoptimizer's reordering is not among them).

    Args:
        V: (n, 3) float vertex positions (any unit). F: (m, 3) int vertex indices.
    Returns:
        (m,) int64 permutation: ``F[order]`` lists the faces along the curve (ties keep the input order).
    """
    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    if len(F) == 0:
        return np.zeros(0, dtype=np.int64)
    centroids = V[F].mean(axis=1)
    low, extent = centroids.min(axis=0), np.ptp(centroids, axis=0).max()
    cells = (1 << ORDER_BITS) - 1
    q = np.zeros_like(centroids, dtype=np.uint64) if not extent > 0 else \
        np.clip(np.floor((centroids - low) / extent * cells), 0, cells).astype(np.uint64)
    code = np.zeros(len(F), dtype=np.uint64)
    for bit in range(ORDER_BITS):
        for axis in range(3):
            code |= ((q[:, axis] >> np.uint64(bit)) & np.uint64(1)) << np.uint64(3 * bit + axis)
    return np.argsort(code, kind="stable")


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
        fragments: the rasterisation (covered pixels are rows 0..P-1); None from the nvdiffrast
            backend, whose rows are every pixel.
    """

    pixels: torch.Tensor
    values: dict[str, torch.Tensor]
    backgrounds: dict[str, torch.Tensor]
    shape: tuple[int, int, int]
    fragments: Fragments | None

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
