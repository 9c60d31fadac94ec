"""The capture's colour gain per expression (beyond the paper, ``Schedule.color_gain``).

The shared texture is fused from the template expression's photographs under the lighting estimated from them
(``gpja.register.lighting_estimate``); every other expression is compared with it under that same lighting. A
real capture's expressions are photographed apart: exposure, white balance and the skin's flush differ by a few
per cent per channel (the synthetic data draws a gain in [0.97, 1.03] per channel and expression). The colour
constraint then sees the whole face a few per cent too bright or too dark, and moves the surface to shift
darker or brighter material under the pixels. Measured on a 3 x 6 capture whose template expression and lip
funneler differ by 5 % in red: PSNR 2.6 dB under the ground truth rendered with the same texture, where the
default capture (2 %) gave +0.6 (docs/experiments.md, "The capture's colour gain per expression").

The gain is one factor per channel: the reference's colour over the render's, the median over the pixels where
both show skin (the render's texel seen, not the mouth's inside, inside the scan's coverage and away from the
render's silhouette, neither too dark to divide by nor clipped). A median rather than a least-squares ratio: the
start is the parent expression's registration, whose mouth and lids can be millimetres off, and the median takes
no notice of the few per cent of pixels they cover. The lighting's colour scales the render exactly (the shading
is linear in the SH coefficients), so the gain multiplies the lighting's columns (:func:`with_gain`) and every
render of the registration (jaw and lid searches, flow stages, levels) sees it; the metrics keep the template's
lighting, as for every other method.
"""
from __future__ import annotations

import dataclasses

import numpy as np
import torch

from gpja.errors import GpjaError
from gpja.mesh import TexturedMesh
from gpja.register.hra import ExpressionTargets
from gpja.register.lighting_estimate import CLIP_LEVEL, MIN_COVERAGE

#: Darkest rendered colour (linear, any channel) a ratio is taken of: below it the ratio is mostly noise.
MIN_RENDER_COLOR = 0.05
#: Fewest pixels a gain is measured on; with fewer the gain is 1 (and the log says why).
MIN_PIXELS = 500
#: A measured gain outside this range is not a capture's exposure but a wrong start or wrong data: it is refused.
GAIN_RANGE = (0.5, 2.0)


class UnlikelyGain(GpjaError, ValueError):
    """The references differ from the start's render by more than a capture's exposure (:data:`GAIN_RANGE`)."""


def match_gain(rendered: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """The per-channel factor that takes rendered colours to reference colours: the median of their ratios.

    Args:
        rendered: (N, 3) float linear colours of the render at N pixels, all > 0.
        reference: (N, 3) float linear colours of the references at the same pixels.
    Returns:
        (3,) float64 gains, ``median(reference[:, c] / rendered[:, c])``.
    """
    rendered, reference = np.asarray(rendered, dtype=np.float64), np.asarray(reference, dtype=np.float64)
    if rendered.shape != reference.shape or rendered.ndim != 2 or rendered.shape[1] != 3 or len(rendered) == 0:
        raise ValueError(f"need two (N, 3) colour arrays with N > 0, got {rendered.shape} and {reference.shape}")
    if not (rendered > 0).all():
        raise ValueError("rendered colours must be positive to divide by")
    return np.median(reference / rendered, axis=0)


def with_gain(targets: ExpressionTargets, gain: np.ndarray) -> ExpressionTargets:
    """``targets`` whose lighting (9, 3) has each channel's column multiplied by ``gain`` (3,): every render under it
    is ``gain`` times as bright per channel. ``with_gain(t, g)`` then ``with_gain(., 1 / g)`` gives ``t``'s lighting."""
    factor = torch.as_tensor(np.asarray(gain, dtype=np.float64), dtype=targets.sh.dtype)
    if factor.shape != (3,) or not torch.isfinite(factor).all() or not (factor > 0).all():
        raise ValueError(f"gain must be three positive numbers, got {gain}")
    return dataclasses.replace(targets, sh=targets.sh * factor[None, :])


def measure_gain(mesh: TexturedMesh, targets: ExpressionTargets, texture: torch.Tensor, mask_texture: torch.Tensor,
                 render=None) -> tuple[np.ndarray, dict]:
    """The expression's colour gain against ``mesh`` rendered with the shared texture under ``targets.sh``.

    Args:
        mesh: the registration's start (mm, the template's atlas).
        targets: the expression's references, scan coverage and lighting.
        texture: (T, T, 3) shared albedo; mask_texture: (T', T', 1) the mouth mask (1 = skin, 0 = the mouth's inside).
        render: the backend's ``render_views``; None = the CPU renderer.
    Returns:
        gain (3,) float64 (ones when fewer than :data:`MIN_PIXELS` pixels qualify) and a log entry: ``gain``,
        ``pixels``, ``measured`` (False when too few pixels qualified).
    Raises:
        UnlikelyGain: the measured gain is outside :data:`GAIN_RANGE` (the start is not on this capture).
    """
    from gpja.render import Topology, render_views

    render = render or render_views
    topology = Topology(torch.from_numpy(mesh.F), torch.from_numpy(mesh.F_uv))
    V = torch.tensor(mesh.V, dtype=torch.float32)
    uv = torch.tensor(mesh.UV, dtype=torch.float32)
    with torch.no_grad():
        out = render(V, topology, targets.cameras, ("color", "mask"), uv=uv, texture=texture,
                     mask_texture=mask_texture, sh=targets.sh, cull_backfaces=True)
        rendered = out.values["color"].double().numpy()
        skin = (out.values["mask"][:, 0] > 0.5).numpy()
        inside = (out.values["coverage"][:, 0] >= 1.0).numpy()  # not blended across a silhouette
        scanned = (out.gather(targets.coverage)[:, 0] >= MIN_COVERAGE).numpy()
        reference = out.gather(targets.images).double().numpy()
    keep = (skin & inside & scanned & (rendered.min(axis=1) > MIN_RENDER_COLOR)
            & (reference.max(axis=1) < CLIP_LEVEL) & (reference.min(axis=1) > 0.0))
    pixels = int(keep.sum())
    if pixels < MIN_PIXELS:
        return np.ones(3), {"gain": [1.0, 1.0, 1.0], "pixels": pixels, "measured": False}
    gain = match_gain(rendered[keep], reference[keep])
    low, high = GAIN_RANGE
    if not ((gain >= low) & (gain <= high)).all():
        raise UnlikelyGain(f"the references are {np.round(gain, 3).tolist()} times as bright as the start's render "
                         f"(per channel; at most {low:g}-{high:g} is a capture's exposure): the start does not lie "
                         "on this capture, or the images are not this subject's")
    return gain, {"gain": [round(float(g), 5) for g in gain], "pixels": pixels, "measured": True}
