"""Where a dataset is, said once: the roots and options every step reads an expression with.

The workflow passes the same options (``--images-root``, ``--scans-root``, ``--rt-scale``,
``--views``, ``--max-image-size``, ``--cache-dir``) to every step; :class:`DataSource` holds them
so that loading an expression, or reading its scan in millimetres, is one call everywhere.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from gpja.data.facescape import ExpressionData, Scan, load_expression, read_rt_scale, read_scan, scan_path
from gpja.errors import InputError


@dataclass(frozen=True)
class DataSource:
    """A dataset in FaceScape layout.

    Attributes:
        images_root: ``{root}/{subject}/{expression}/{view}.jpg|png`` + ``params.json``; None when only scans
            are needed.
        scans_root: ``{root}/{subject}/{expression}.ply``; None when only images are needed.
        rt_scale: FaceScape's ``Rt_scale_dict.json`` (raw data into the aligned mm frame); None = already in mm.
        views: the view names to use; None = every valid view.
        cache_dir: where undistorted images are cached.
        max_image_size: downsample images (and intrinsics) to this longer side.
    """

    images_root: Path | None = None
    scans_root: Path | None = None
    rt_scale: Path | None = None
    views: tuple[str, ...] | None = None
    cache_dir: Path | None = None
    max_image_size: int | None = None

    def __post_init__(self):
        for name in ("images_root", "scans_root", "rt_scale", "cache_dir"):
            value = getattr(self, name)
            if value is not None and not isinstance(value, Path):
                object.__setattr__(self, name, Path(value))
        if self.views is not None:
            object.__setattr__(self, "views", tuple(str(v) for v in self.views))

    @classmethod
    def from_args(cls, args) -> "DataSource":
        """From parsed ``gpja`` options (absent attributes count as not given)."""
        return cls(images_root=getattr(args, "images_root", None), scans_root=getattr(args, "scans_root", None),
                   rt_scale=getattr(args, "rt_scale", None), views=getattr(args, "views", None),
                   cache_dir=getattr(args, "cache_dir", None), max_image_size=getattr(args, "max_image_size", None))

    def load(self, subject: str, expression: str, with_scan: bool = True) -> ExpressionData:
        """The undistorted views (and, with ``with_scan`` and a scans root, the scan) of one expression."""
        if self.images_root is None:
            raise InputError("--images-root", f"needed to load {subject}/{expression}'s images")
        return load_expression(self.images_root, subject, expression, views=self.views,
                               scans_root=self.scans_root if with_scan else None, rt_scale_path=self.rt_scale,
                               cache_dir=self.cache_dir, max_image_size=self.max_image_size)

    def scan_file(self, subject: str, expression: str) -> Path:
        if self.scans_root is None:
            raise InputError("--scans-root", f"needed to read the scan of {subject}/{expression}")
        return scan_path(self.scans_root, subject, expression)

    def scan(self, subject: str, expression: str) -> Scan:
        """The scan of one expression in the aligned millimetre frame (``X' = R (s X) + t`` with ``rt_scale``)."""
        return read_scan_mm(self.scan_file(subject, expression), subject, expression, self.rt_scale)

    def transform(self, subject: str, expression: str) -> tuple[float, np.ndarray | None, np.ndarray | None]:
        """The raw-to-aligned transform of one expression (:func:`aligned_transform`), e.g. for its landmarks."""
        return aligned_transform(self.rt_scale, subject, expression)


def aligned_transform(rt_scale: str | Path | None, subject: str, expression: str
                      ) -> tuple[float, np.ndarray | None, np.ndarray | None]:
    """``(s, R (3, 3), t (3,) mm)`` with ``X' = R (s X) + t`` from FaceScape's ``Rt_scale_dict.json``;
    ``(1.0, None, None)`` (the identity: data already in mm) when ``rt_scale`` is None."""
    return read_rt_scale(rt_scale, subject, expression) if rt_scale is not None else (1.0, None, None)


def read_scan_mm(path: str | Path, subject: str, expression: str, rt_scale: str | Path | None = None) -> Scan:
    """Read a scan PLY into the aligned millimetre frame, applying FaceScape's ``Rt_scale_dict`` when given.

    Raises:
        InputError: naming the file, for a missing/corrupt/empty scan, NaN vertices, a missing transform
        entry, or an extent that is not a head in millimetres.
    """
    return read_scan(path, *aligned_transform(rt_scale, subject, expression))
