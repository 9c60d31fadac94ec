"""Where a reference photograph shows the mouth open: its dark openings.

The inside of an open mouth receives little light: in the gamma-encoded grey images the flow matches, it is 20-40
of 255 on the synthetic captures, the skin 140-170 and the lips 120-150. A closed mouth shows at most the thin dark
line where the lips meet. So an opening is a region darker than ``SOCKET_DARK_FRACTION`` of the skin's median grey
and at least ``OPENING_MIN_PX`` wide (a morphological opening removes the contact line), inside the head's
silhouette (the background beside a side view's lips is no opening; the flow stage's switch counts it, as measured).

Two consumers (both beyond the paper): the flow stage's ``socket_margin_px``, which asks whether a view shows the
mouth open beside the render's socket (:mod:`gpja.register.flow`), and the colour constraint's mouth mask with
``Schedule.mask_where_open``, which leaves the socket out only where the reference shows an opening
(:mod:`gpja.register.hra`).
"""
from __future__ import annotations

import numpy as np

#: a reference pixel is as dark as an open mouth when its grey level is below this fraction of the median grey of
#: the pixels the scan covers fully
SOCKET_DARK_FRACTION = 0.5
#: ... and an opening is a dark region at least this wide (px): the dark contact line of closed lips is not one
OPENING_MIN_PX = 5
#: a pixel the scan covers more than this is inside the head (the holes it leaves there are too)
SILHOUETTE_COVERAGE = 0.5
#: a pixel the scan covers more than this is skin, whose median grey sets the scale of "dark"
SKIN_COVERAGE = 0.999


def opened(region: np.ndarray, width_px: int) -> np.ndarray:
    """(H, W) bool ``region`` without its parts narrower than ``width_px`` (a morphological opening by a disc of that
    diameter, OpenCV's)."""
    import cv2

    disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (int(width_px), int(width_px)))
    return cv2.morphologyEx(region.astype(np.uint8), cv2.MORPH_OPEN, disc).astype(bool)


def inside_silhouette(covered: np.ndarray) -> np.ndarray:
    """(H, W) bool: the pixels of ``covered`` (H, W) bool and the holes it encloses (a scan's open mouth, which it
    does not cover), but not the background, which reaches the image's border (OpenCV's connected components)."""
    import cv2

    _, labels = cv2.connectedComponents((~covered).astype(np.uint8), connectivity=4)
    border = np.unique(np.concatenate([labels[0], labels[-1], labels[:, 0], labels[:, -1]]))
    return ~(np.isin(labels, border[border > 0]) & ~covered)


def dark_openings(grey: np.ndarray, coverage: np.ndarray, within_head: bool = True) -> np.ndarray:
    """(H, W) bool: the openings one reference shows (module docstring).

    Args:
        grey: (H, W) uint8 gamma-encoded grey reference (``gpja.register.flow.to_match_u8``).
        coverage: (H, W) float the scan's coverage of each pixel in [0, 1].
        within_head: True = only inside the head's silhouette (:func:`inside_silhouette`); False = a dark background
            counts as well (the flow stage's ``socket_margin_px`` as measured: there a side view whose background
            lies beside the socket keeps its matches).
    """
    skin = coverage > SKIN_COVERAGE
    level = np.median(grey[skin]) if skin.any() else np.median(grey)
    dark = grey < SOCKET_DARK_FRACTION * level
    if within_head:
        dark &= inside_silhouette(coverage > SILHOUETTE_COVERAGE)
    return opened(dark, OPENING_MIN_PX)
