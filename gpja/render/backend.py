"""Choice of rasterisation backend: the CPU renderer, or nvdiffrast on a CUDA GPU.

``render.backend`` in the config (``--backend`` of the ``gpja`` commands):
``auto`` picks nvdiffrast when it imports and CUDA is available, else the CPU
renderer; ``cpu`` always uses the CPU renderer; ``nvdiffrast`` requires it and
fails clearly otherwise. Both backends take the same arguments and return the
same ``RenderOutput`` type, so losses and callers do not change: every step
that renders (scan targets, template fit and texture, registration,
photometric metrics, figures) takes the ``render`` function :func:`renderer`
returns. The nvdiffrast path has NOT been run against the CPU backend yet (no
GPU was available when it was written): treat it as experimental.
"""
from __future__ import annotations

import importlib.util
from typing import Callable

from gpja.errors import InputError
from gpja.render.passes import render_views

BACKENDS = ("auto", "cpu", "nvdiffrast")


def nvdiffrast_available() -> bool:
    """True when nvdiffrast imports and torch sees a CUDA device."""
    if importlib.util.find_spec("nvdiffrast") is None:
        return False
    import torch

    return bool(torch.cuda.is_available())


def resolve_backend(name: str = "auto") -> str:
    """The concrete backend ("cpu" or "nvdiffrast") for a configured name.

    Raises:
        InputError: an unknown name, or "nvdiffrast" where it does not import or no CUDA device is visible.
    """
    if name not in BACKENDS:
        raise InputError("render.backend", f"must be one of {', '.join(BACKENDS)}, got {name!r}")
    if name == "auto":
        return "nvdiffrast" if nvdiffrast_available() else "cpu"
    if name == "nvdiffrast" and not nvdiffrast_available():
        raise InputError("render.backend", "'nvdiffrast' is not installed or no CUDA device is visible; "
                                           "use 'auto' or 'cpu'")
    return name


def renderer(name: str = "auto") -> Callable:
    """The ``render_views`` function of a backend (same signature and output for both).

    ``"cpu"`` (and ``"auto"`` without a GPU) gives ``gpja.render.passes.render_views`` itself.
    """
    if resolve_backend(name) == "nvdiffrast":
        from gpja.render.nvdiffrast_backend import render_views_nvdiffrast

        return render_views_nvdiffrast
    return render_views
