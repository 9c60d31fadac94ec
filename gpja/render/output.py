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
from gpja.render.silhouettes import face_adjacency

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

    def __post_init__(self) -> None:
        self.faces = torch.as_tensor(np.asarray(self.faces), dtype=torch.int64)
        if self.uv_faces is not None:
            self.uv_faces = torch.as_tensor(np.asarray(self.uv_faces), dtype=torch.int64)
        if self.adjacency is None:
            self.adjacency = face_adjacency(self.faces.numpy())

    def incidence(self, n_vertices: int) -> tuple[np.ndarray, np.ndarray]:
        """``vertex_incidence`` of the faces for ``n_vertices`` vertices, built once."""
        if n_vertices not in self._incidence:
            self._incidence[n_vertices] = vertex_incidence(self.faces.numpy(), n_vertices)
        return self._incidence[n_vertices]


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
