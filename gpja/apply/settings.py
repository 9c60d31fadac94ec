"""The settings of the applications (config ``applications.remesh|animation|export|reparam``).

Each is a frozen dataclass read by :func:`gpja.settings.from_section`; the defaults are written once, here.
"""
from __future__ import annotations

from dataclasses import dataclass

from gpja.settings import from_section


@dataclass(frozen=True)
class RemeshSettings:
    """The common triangulation (``gpja.apply.remesh``).

    Attributes:
        initial_vertices: the template refined uniformly (by edge length) to this many vertices first.
        tolerance_mm: then, round after round, every edge whose chord misses an expression's surface by more
            than this at its midpoint is split there (:func:`gpja.apply.remesh.fit_triangulation`). Inside a face
            the deviation can reach about 4/3 of it (a quadratic surface: 1/4 of the face's sag at an edge's
            midpoint, 1/3 at its centroid); the remesh logs record the deviation measured.
        tangential_tolerance_mm: None: the whole offset of an edge's midpoint from where its texture coordinate
            lands counts against ``tolerance_mm``. A number: only the offset along the surface's normal does
            (checked at face centres too), and the offset along the surface, which slides the texture without
            moving the surface, counts against this (docs/experiments.md, "The common triangulation's
            tangential tolerance").
        max_vertices: the common triangulation never grows beyond this.
        max_rounds: at most this many splitting rounds.
        face_samples: with ``tangential_tolerance_mm``, where inside each face the offset along the normal is
            checked too: 1 = the face's centre, 4 = also halfway from it to each corner (a fold inside one
            face that the centre misses).
    """

    initial_vertices: int = 40000
    tolerance_mm: float = 0.02
    tangential_tolerance_mm: float | None = 0.1
    max_vertices: int = 200000
    max_rounds: int = 16
    face_samples: int = 1

    from_config = classmethod(from_section)

    def __post_init__(self):
        if self.initial_vertices < 1 or self.max_vertices < self.initial_vertices:
            raise ValueError(f"need 1 <= initial_vertices <= max_vertices, got {self.initial_vertices} and "
                             f"{self.max_vertices}")
        if not self.tolerance_mm > 0:
            raise ValueError(f"tolerance_mm must be positive, got {self.tolerance_mm}")
        if self.tangential_tolerance_mm is not None and not self.tangential_tolerance_mm > 0:
            raise ValueError(f"tangential_tolerance_mm must be positive or null, got {self.tangential_tolerance_mm}")
        if self.max_rounds < 0:
            raise ValueError(f"max_rounds must be >= 0, got {self.max_rounds}")
        if self.face_samples not in (1, 4):
            raise ValueError(f"face_samples must be 1 or 4, got {self.face_samples}")


@dataclass(frozen=True)
class AnimationSettings:
    """The animation of the remeshed expressions (``gpja.apply.animate``).

    Attributes:
        sequence: the expressions visited in order (each must be registered, or the template's expression).
        frames_per_transition: frames from one expression to the next (the next's keyframe starts the next).
        fps: frames per second of the video.
        size: side of each view's frame (px); the video shows the views side by side.
        yaw_deg: the cameras' turns about the vertical axis (0 = frontal; +35 = three-quarter from the
            subject's left).
        strip_frames: frames shown in the film-strip figure (evenly spaced, keyframes included where they fall).
    """

    sequence: tuple[str, ...] = ("1_neutral", "2_smile", "3_mouth_stretch", "1_neutral")
    frames_per_transition: int = 24
    fps: int = 24
    size: int = 384
    yaw_deg: tuple[float, ...] = (0.0, 35.0)
    strip_frames: int = 8

    from_config = classmethod(from_section)

    def __post_init__(self):
        if len(self.sequence) < 2:
            raise ValueError(f"the sequence needs at least two expressions, got {list(self.sequence)}")
        if self.frames_per_transition < 1 or self.fps < 1 or self.size < 16 or self.strip_frames < 2:
            raise ValueError("need frames_per_transition >= 1, fps >= 1, size >= 16 and strip_frames >= 2")
        if not self.yaw_deg:
            raise ValueError("yaw_deg needs at least one camera")


@dataclass(frozen=True)
class ExportSettings:
    """The glTF blendshape export (``gpja.apply.export``).

    Attributes:
        base: the expression that is the mesh; every other is a morph target of it.
    """

    base: str = "1_neutral"

    from_config = classmethod(from_section)


@dataclass(frozen=True)
class ReparamSettings:
    """Re-parametrisation onto an artist mesh (``gpja.apply.reparam``).

    Attributes:
        artist_mesh: an OBJ with its own UVs, in mm, in the template expression's frame; ``{subject}`` in the
            path is replaced by the subject. None = a stand-in: the template decimated to ``standin_faces``
            faces and unwrapped by xatlas.
        standin_faces: faces of the stand-in (30000: its render with the resampled texture is 36 dB from the
            registered mesh's on S01 ``1_neutral``, 8000: 33 dB; a coarser surface shades differently).
        texture_size: side of the artist texture resampled from the shared one (px).
        untangle_iterations: beyond the paper: at most this many rounds that smooth the carried mesh's folded
            triangles back out along the expression's surface (``gpja.folds.untangle_on_surface``);
            0 (the default) = the paper's map phi_b phi_a^-1 alone, folds included. 100 takes S01's folds from
            229-347 to 7-23 per expression and costs 3-4 dB of the render check (docs/experiments.md).
        untangle_rings: vertex rings around a fold that move with it.
    """

    artist_mesh: str | None = None
    standin_faces: int = 30000
    texture_size: int = 1024
    untangle_iterations: int = 0
    untangle_rings: int = 1

    from_config = classmethod(from_section)

    def __post_init__(self):
        if self.standin_faces < 100 or self.texture_size < 16:
            raise ValueError("need standin_faces >= 100 and texture_size >= 16")
        if self.untangle_iterations < 0 or self.untangle_rings < 0:
            raise ValueError(f"need untangle_iterations >= 0 and untangle_rings >= 0, got "
                             f"{self.untangle_iterations} and {self.untangle_rings}")
