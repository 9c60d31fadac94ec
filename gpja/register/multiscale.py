"""The multiscale regularised optimisation of GPJA (paper, "Multiscale Regularized Optimization").

Per level: LargeSteps re-parameterisation ``u = (I + lambda L) x`` with the
cotangent Laplacian, uniform Adam on ``u``, one HRA constraint back-propagated
per iteration in rotation (colour -> depth -> normal). Between levels the mesh
is refined by selective edge splitting (texture parametrisation kept exactly)
and the system matrix is rebuilt with the next, smaller ``lambda``.

Learning rate: the paper sets eta to "one-tenth of the face length". We read
"face length" as the mean edge length of the current level's triangles (mm),
so each uniform-Adam step moves the differential coordinates by at most about
a tenth of an edge, and the step shrinks as the mesh is refined. The paper
runs 1500 iterations; a shorter schedule (the default config's 3 x 150) takes
proportionally larger steps (``lr_fraction``) that decay within each level
(``lr_decay``), see README "Registration settings".

Flow stage (beyond the paper, ``Schedule.flow_rounds``, the default): before the descent of each of
the first ``flow_levels`` levels, the mesh is rendered with the shared texture and matched to every
reference photograph by optical flow; the matches, lifted onto the scan, move the mesh by one smooth
displacement (``gpja.register.flow``). Flow reaches the 15-25 mm of a closing jaw, which the colour
constraint's per-pixel descent does not, and it pins what the descent would slide (docs/experiments.md,
"Issue 15: optical-flow matching"). With it, the warm-up below is not needed (the default runs none).

Correspondence warm-up (beyond the paper, ``Schedule.warmup_iterations``):
the template is built from the mouth-open expression, and for a closed mouth
the depth and normal constraints are satisfied as soon as the mouth socket's
walls are pulled forward onto the scan's lower lip. They are blind to that
tangential sliding, and the masked colour constraint charges nothing for
socket pixels, so the mouth stays open in texture while the geometry
matches. A short phase of the unmasked colour constraint alone, at the first
level's resolution and lambda, first moves the lips onto the reference's
lips; the paper's levels then run unchanged. Colour alone has directions it
does not see or even rewards: it averages over the pixels the template covers,
so pulling a badly matching part (a chin, a closed eye's lid) out of view lowers
it, and with the clean fused texture it caved chins and lids in (S01
``18_eye_closed``: Chamfer 0.9 mm). ``Schedule.warmup_geometry`` keeps depth and
normals in the warm-up's rotation, each with its own optimiser state (below), so
the surface stays on the scan while the unmasked colour moves the lips.

One optimiser state per constraint (beyond the paper, ``Schedule.optimizer_state``):
the uniform Adam normalises each step by the largest second moment of the
gradients it has seen. Shared by the rotation, those moments are the depth
constraint's (mm, silhouette charges of 10 mm a pixel), and the colour
constraint's steps shrink to about its gradients' ratio to depth's (on the
default data the colour loss hardly moves once depth joins). With one state
per constraint, each step is normalised by its own constraint's gradients, so
each constraint moves the surface by up to the learning rate whatever its
units; the rotation then balances them as the paper intends.

Tangential hold (beyond the paper, ``Schedule.hold_tangential``): during the
levels, the vertices the warm-up (without one, the first flow stage) did not
move far are pulled back, by a small fraction per iteration, towards their
starting positions along the surface (not along the normal), so untextured
parts (nose, neck) stop sliding after the jaw (``gpja.register.hold``); with ``hold_gap_mm`` what
starts off the target's scan is not held.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace
from typing import Callable

import numpy as np
import torch

from gpja.cholesky import BACKENDS as CHOLESKY_BACKENDS
from gpja.errors import GpjaError
from gpja.mesh import TexturedMesh
from gpja.register.flow import FlowSettings
from gpja.register.hold import TangentialHold, mouth_factor, scan_gap
from gpja.register.hra import COLOR_GRADIENTS, ExpressionTargets, Switches, along_surface, render_constraint
from gpja.register.largesteps import LargeStepsParametrization
from gpja.register.remesh import refine_by_factor, refine_carrying
from gpja.render import Topology
from gpja.settings import from_section


class RegistrationDiverged(GpjaError):
    """The optimisation produced NaN or infinite values."""


#: ``Schedule.image_factor`` never takes a level's images below this many pixels on their shorter side: at 256 px
#: (about 2 mm a pixel on the default's heads) a half-size first level no longer closed the CI-sized open mouth
#: (tests/test_open_to_closed.py: lower lip 5.3 mm against 3.5 mm at full size).
MIN_IMAGE_SIDE_PX = 256
#: ``Schedule.face_order``: the mesh's own face order (as first written) or a spatial one, for speed.
FACE_ORDERS = ("mesh", "spatial")

#: ``Schedule.optimizer_state``: one Adam for the whole rotation, or one per constraint.
OPTIMIZER_STATES = ("shared", "per_constraint")


@dataclass(frozen=True)
class Schedule:
    """Levels of the multiscale optimisation.

    Attributes:
        lambdas: regularisation weight per level (paper: 200, 120, 80, 50).
        iterations: iterations per level (one constraint each).
        refine_factor: vertex-count growth between levels (paper: 16K -> 250K over 4 levels ~ 2.5x).
        lr_fraction: learning rate as a fraction of the level's mean edge length (paper: 0.1).
        lr_decay: ratio of a level's last learning rate to its first, decayed geometrically over the
            level's iterations (1 = constant, the paper). Uniform Adam with a constant step keeps
            oscillating by about a step; short schedules take large steps and need the decay to settle.
        color_pool: per level, the box (px) colours are averaged over before the colour constraint
            compares them (1 = per pixel, the paper; None = 1 at every level).
        warmup_iterations: iterations of the unmasked colour constraint alone before the first level,
            at its resolution and lambda (0 = none, the paper; module docstring). Only runs when the
            colour constraint is on.
        warmup_geometry: the warm-up also runs the depth and normal constraints (those switched on),
            so the unmasked colour slides the lips while the surface stays on the scan; false = colour
            alone.
        optimizer_state: "shared" = one uniform Adam for every constraint (the paper's text names one
            optimiser); "per_constraint" = each constraint of the rotation steps with its own moments
            (beyond the paper; module docstring).
        hold_tangential: per level iteration, the fraction of a held vertex's tangential offset from its
            starting position that is removed (0 = off, the paper; beyond the paper, ``gpja.register.hold``).
            Needs a warm-up or a flow stage: the first of them tells what moves.
        hold_moved_mm: (held, free): a vertex the warm-up (without one, the first flow stage) moved at most
            ``held`` mm is held fully, one it moved ``free`` mm or more not at all (linear between, then
            smoothed).
        hold_gap_mm: (held, free) or None (off): the weights are also multiplied by a ramp on the starting
            surface's gap to the target's scan (``gpja.register.hold.scan_gap``): kept at or below ``held`` mm,
            0 at or beyond ``free`` mm, so what lies off the scan (a part the expression moves) is free even
            where the first phase hardly moved it.
        hold_mouth_mm: (free, held) or None (off, the hold as first written): the weights are also multiplied by
            a ramp on the distance (mm, on the start) to the nearest vertex of the mouth's socket (the template's
            mouth mask, ``gpja.register.hold.mouth_factor``): 0 within ``free`` mm, 1 from ``held`` mm on. The
            lips' surroundings (chin, mouth corners, the band between lip and chin) move with every expression
            of the mouth, even where the first flow stage moved them less than ``hold_moved_mm``.
        hold_mouth_at_flow_mm: (held, free) or None (off, the hold's start is the registration's): after the last
            flow stage, the hold is anchored where that stage put the vertices within ``free`` mm of the mouth's
            socket (the template's mouth mask), and those within ``held`` mm are held fully (linear between; the
            weights only rise, ``TangentialHold.reanchored``). Stage by stage, the mouths were best right after a
            flow stage and the descent of the fine levels gave 0.1-0.9 mm back, rolling a funneler's lower lip
            inwards where the lips' uniform colour says nothing.
        hold_moved_at_flow: False (off, the hold as first written) or True: after the last flow stage, the
            vertices the hold leaves mostly free (weight below 0.5: what the first flow stage moved, what lay off
            the scan) are anchored where that stage put them, with weight ``1 - weight``
            (``TangentialHold.reanchored``: the weights only rise). Stage by stage, the fine levels' descent slid
            the jaw, the neck and the lips along the scan, where the skin's uniform colour says nothing, away from
            where the last flow stage put them.
        mouth_stiffness: (factor, near, far) or None (off, the paper's one lambda everywhere): each level's
            lambda is multiplied by ``factor`` on the triangles within ``near`` mm of the mouth's socket (the
            template's mouth mask) and by 1 from ``far`` mm on, linear between (:func:`mouth_face_weight`). The
            descent of the fine levels, at small lambdas, rolled the lips of the lip funnelers inwards while it
            aligned the rest of the face; a stiffer mouth keeps the flow stages' lips.
        spring_rate: per level iteration, the fraction of each edge's length change from the registration's
            start that is given back, along the surface (0 = off, the paper; beyond the paper,
            ``gpja.register.hold.edge_spring_step``): inside a lip of uniform colour it keeps the material's
            spacing, which nothing else decides. Needs a warm-up or a flow stage, as the hold does.
        flow_rounds: rounds of optical-flow matching (``gpja.register.flow``) before a level's descent
            (0 = none, the paper; beyond the paper). Only runs when the colour constraint is on.
        flow_levels: how many levels, from the first, start with those rounds.
        flow_final_rounds: rounds of one more flow stage after the last level's descent (0 = none, the schedule
            as first written; beyond the paper). The descents of the fine levels fit the scan's detail and the
            photographs' shading, and slide material that no colour edge pins; this stage puts it back where the
            photographs say, before the untangling and the snap. Measured, it lowers the correspondence mean and p95
            but raises its median and C.D. (docs/experiments.md, "The optical flow on the full image"): off.
        jaw_search_deg: (lo, hi) or None (off, the paper): before the first flow stage, the lower face is
            turned about a hinge to the pitch angle in [lo, hi] degrees (0 = the start's pose, negative closes)
            whose render best matches the references (beyond the paper, ``gpja.register.jaw``). When it turns,
            the hold keeps the turned jaw and releases the rig's blend between jaw and skull. Only runs when the
            colour constraint is on.
        jaw_lips_mm: (lo, hi) or None (off): after a turn, the lower and then the upper lip are also moved up or
            down by the lift in [lo, hi] mm that matches the references best (``gpja.register.jaw.lip_weights``).
        jaw_shift_mm: (lo, hi) or None (the pitch alone): the jaw's forward shift (mm, lo <= 0 <= hi) is searched
            with its pitch (``gpja.register.jaw.search_grid_2d``).
        jaw_window_mm: None (the whole images) or a distance (mm): the jaw search scores the render in the box
            around the start's vertices within that distance of the mouth's socket (``gpja.register.jaw.colour_score``).
        jaw_reach_mm: None (the rig's weights) or (near, far) mm: the jaw's pose fades out between these distances
            from the socket's rim (``gpja.register.jaw.limit_reach``).
        lid_search_deg: the largest angle (degrees) or None (off, the paper): after the jaw search and before the
            first flow stage, the upper lids are turned down over the eyeballs by the angle in [0, this] whose
            render best matches the references (beyond the paper, ``gpja.register.lids``; the rig comes from the
            whites of the eyes in the shared texture). Only runs when the colour constraint is on.
        flow_smoothness: the smoothness ``mu`` of the flow stage's displacement (dimensionless).
        flow_still_mm: a flow match that moves its vertex less than this is taken as "stays" (0 = off, the
            stage as first written; ``gpja.register.flow.match_round``).
        flow_socket_margin_px: beyond the stage as first written (0 = off): in the flow stages, in a view whose
            reference shows the mouth closed, a vertex whose pixel in the render lies within this many pixels of the
            mouth's socket does not match (``gpja.register.flow``, ``FlowSettings.socket_margin_px``).
        flow_chroma: weight of the red-green chroma beside the luminance in the image the flow matches (0 =
            luminance alone, the stage as first written; ``gpja.register.flow.to_match_u8``): the lips'
            outline is a chroma edge.
        flow_finest_scale: the pyramid level the flow's field is computed at (1 = half size, OpenCV's medium
            preset and the stage as first written; 0 = the full image; ``gpja.register.flow.dense_flow``).
        flow_scan_shading_px: None = the flow stages compare the mesh's render shaded by its own normals (the stage
            as first written); a number = shaded by the scan's normal images blurred by this sigma (px) where the
            render lies on the scan, from the first stage's second round on (beyond the paper; ``gpja.register.flow.shade_by_scan``: the shared texture is the
            photographs divided by that shading, and the coarse levels' normals differ from it on the nose).
        flow_cholesky: the sparse Cholesky backend of the flow stage's displacement solve (``gpja.cholesky``):
            ``simplicial`` (cholespy, the stage as first written) or ``supernodal`` (CHOLMOD's supernodal factor
            through cvxopt: faster to factor, the same displacements to rounding; ``FlowSettings.cholesky``).
        color_gradient: "full" = the colour constraint's whole gradient moves the vertices (the paper);
            "tangential" = only its part along the surface (``gpja.register.hra.along_surface``, beyond the
            paper): on the template's nose the colour's normal push, undone by depth along the view rays,
            slid the surface 0.5 mm.
        average_iterations: a level ends with the mean of the vertex positions after its last this many
            steps instead of the last one (0 = the last, the paper; beyond the paper). Uniform Adam keeps
            every vertex moving by about a step to the end of a level, so the last iterate lies a random
            fraction of a step from where the iterates settle; their mean does not.
        views_per_iteration: per level, how many of the views each iteration renders (0 = all, the paper;
            None = all at every level; beyond the paper, for speed). Each constraint cycles through the
            views in random order (:class:`ViewCycle`, seeded by ``seed``), so over a level every view
            counts equally often for every constraint.
        image_factor: per level, the references and scan targets are box-averaged by this factor and the
            cameras resized (1 = the data's resolution, the paper; None = 1 at every level; beyond the
            paper, for speed): a coarse level's edges span several pixels, so it loses little at half the
            resolution and renders a quarter of the pixels (``ExpressionTargets.downsampled``). Never below
            :data:`MIN_IMAGE_SIDE_PX` on the shorter side (:meth:`factor`).
        seed: seeds the view order of ``views_per_iteration`` (the config's; same seed, same numbers).
        face_order: the order in which a level's renders visit the faces: "mesh" (the mesh's own, as first
            written) or "spatial" (beyond the paper, for speed: along a Z-order curve of the level's start,
            ``gpja.render.output.spatial_face_order``): the same renders up to rounding and depth ties, a
            fifth faster at 100K vertices, because a refined mesh lists its faces scattered over the head.
        untangle_iterations: beyond the paper (0 = off, the paper): after the last level, at most this many
            rounds that smooth the mesh's folded triangles out along its own surface (``gpja.folds``); the
            surface stays, the texture coordinates of the crumpled parts move back into order.
        untangle_rings: vertex rings around a fold that move with it.
        untangle_turned: beyond the paper (False = folds alone): the untangling also smooths the faces turned over
            against the template (``gpja.folds.turned_faces``; ``optimise``'s ``orientation``): pleats with rounded
            creases, which a fold's test misses (the neck's cap, under the jaw).
        snap_mm: beyond the paper (0 = off, the paper): the last step moves every vertex along its normal onto
            the expression's scan, looking this far (mm) both ways (``gpja.register.snap``): the levels' tug of
            war between the constraints leaves the surface a little off the scan, after an unlucky draw by
            tenths of a millimetre. Needs the scan (``optimise``'s ``scan``).
        snap_smoothness: how strongly the snap's offsets follow their neighbours where no ray hit the scan.
        color_gain: beyond the paper (False = the template's lighting as it is, the paper): before anything
            else, the expression's colour gain per channel is measured against the start's render and multiplies
            the lighting of every render of the registration (``gpja.register.gain``): a capture's expressions
            differ in exposure and white balance by a few per cent. Needs the colour constraint.
        color_scan_px: beyond the paper (None = the colour counts wherever the template renders, the paper): the
            colour constraint counts only within this many pixels of the scan's coverage in each compared image
            (``ExpressionTargets.color_weight``). The template is a model of what the scan covers; beyond it (the
            neck below the scan's cut, shoulders, clothes) the photographs show what the template's extension
            does not model, and matching its colours there crumpled the neck and turned its cap over.
        mask_where_open: beyond the paper (False = the mouth mask leaves the socket out of the colour constraint
            wherever the render shows it, the paper): the socket is left out only where the reference shows an
            opening (``ExpressionTargets.mask_where_open``, :mod:`gpja.register.openings`). Over a closed mouth the
            socket's dark texture is then compared with the lips the reference shows, so socket material left on the
            lips' front costs; the paper's mask lets it stay there for nothing.
        lip_spread: beyond the paper (False = off): after the first flow stage, the lips' material is spread along x
            between the mouth's corners as the template spreads it (:mod:`gpja.register.spread`): a pursed parent
            hands down lips pressed towards the middle, and their one colour shows neither the flow nor the descent
            where their material lies. Needs the flow stage (it places the corners).
    """

    lambdas: tuple[float, ...] = (200.0, 120.0, 80.0, 50.0)
    iterations: tuple[int, ...] = (375, 375, 375, 375)
    refine_factor: float = 2.5
    lr_fraction: float = 0.1
    lr_decay: float = 1.0
    color_pool: tuple[int, ...] | None = None
    warmup_iterations: int = 0
    warmup_geometry: bool = False
    optimizer_state: str = "shared"
    hold_tangential: float = 0.0
    hold_moved_mm: tuple[float, float] = (0.75, 2.5)
    hold_gap_mm: tuple[float, float] | None = None
    hold_mouth_mm: tuple[float, float] | None = None
    mouth_stiffness: tuple[float, float, float] | None = None
    hold_mouth_at_flow_mm: tuple[float, float] | None = None
    hold_moved_at_flow: bool = False
    spring_rate: float = 0.0
    flow_rounds: int = 0
    flow_levels: int = 1
    flow_final_rounds: int = 0
    jaw_search_deg: tuple[float, float] | None = None
    jaw_lips_mm: tuple[float, float] | None = None
    jaw_shift_mm: tuple[float, float] | None = None
    jaw_window_mm: float | None = None
    jaw_reach_mm: tuple[float, float] | None = None
    lid_search_deg: float | None = None
    lip_seal: float | None = None
    flow_smoothness: float = FlowSettings.smoothness
    flow_still_mm: float = FlowSettings.still_mm
    flow_socket_margin_px: float = FlowSettings.socket_margin_px
    flow_chroma: float = FlowSettings.chroma
    flow_finest_scale: int = FlowSettings.finest_scale
    flow_scan_shading_px: float | None = FlowSettings.scan_shading_px
    flow_cholesky: str = FlowSettings.cholesky
    color_gradient: str = "full"
    average_iterations: int = 0
    views_per_iteration: tuple[int, ...] | None = None
    image_factor: tuple[int, ...] | None = None
    seed: int = 0
    face_order: str = "mesh"
    untangle_iterations: int = 0
    untangle_rings: int = 1
    untangle_turned: bool = False
    snap_mm: float = 0.0
    snap_smoothness: float = 1.0
    color_gain: bool = False
    color_scan_px: int | None = None
    mask_where_open: bool = False
    lip_spread: bool = False

    #: ``Schedule.from_config(section, source)``: from a config section (``registration.gpja``), see gpja.settings.
    from_config = classmethod(from_section)

    def __post_init__(self) -> None:
        if len(self.lambdas) != len(self.iterations) or not self.lambdas:
            raise ValueError(f"lambdas ({len(self.lambdas)}) and iterations ({len(self.iterations)}) need one entry "
                             "per level, at least one level")
        if any(int(n) < 1 for n in self.iterations):
            raise ValueError(f"iterations must be >= 1 at every level, got {list(self.iterations)}")
        if any(float(lam) < 0 for lam in self.lambdas):
            raise ValueError(f"lambdas must be >= 0, got {list(self.lambdas)}")
        if self.color_scan_px is not None and not (isinstance(self.color_scan_px, int) and self.color_scan_px >= 0):
            raise ValueError(f"color_scan_px must be null or a whole number of pixels >= 0, got {self.color_scan_px!r}")
        for name in ("mask_where_open", "lip_spread"):
            if not isinstance(getattr(self, name), (bool, np.bool_)):
                raise ValueError(f"{name} must be true or false, got {getattr(self, name)!r}")
        if self.color_pool is not None and (len(self.color_pool) != len(self.lambdas)
                                            or any(int(p) < 1 for p in self.color_pool)):
            raise ValueError(f"color_pool needs one entry >= 1 per level ({len(self.lambdas)}), "
                             f"got {list(self.color_pool)}")
        if self.views_per_iteration is not None and (len(self.views_per_iteration) != len(self.lambdas)
                                                     or any(int(v) < 0 for v in self.views_per_iteration)):
            raise ValueError(f"views_per_iteration needs one entry >= 0 per level ({len(self.lambdas)}; 0 = all "
                             f"views), got {list(self.views_per_iteration)}")
        if self.image_factor is not None and (len(self.image_factor) != len(self.lambdas)
                                              or any(int(f) < 1 for f in self.image_factor)):
            raise ValueError(f"image_factor needs one entry >= 1 per level ({len(self.lambdas)}), "
                             f"got {list(self.image_factor)}")
        if int(self.untangle_iterations) < 0 or int(self.untangle_rings) < 0:
            raise ValueError(f"untangle_iterations and untangle_rings must be >= 0, got {self.untangle_iterations} "
                             f"and {self.untangle_rings}")
        if not float(self.snap_mm) >= 0.0 or not float(self.snap_smoothness) > 0.0:
            raise ValueError(f"snap_mm must be >= 0 and snap_smoothness > 0, got {self.snap_mm} and {self.snap_smoothness}")
        if int(self.warmup_iterations) < 0:
            raise ValueError(f"warmup_iterations must be >= 0, got {self.warmup_iterations}")
        if self.optimizer_state not in OPTIMIZER_STATES:
            raise ValueError(f"optimizer_state must be one of {', '.join(OPTIMIZER_STATES)}, "
                             f"got {self.optimizer_state!r}")
        if not float(self.refine_factor) > 1.0:
            raise ValueError(f"refine_factor must be > 1, got {self.refine_factor}")
        if not float(self.lr_fraction) > 0.0:
            raise ValueError(f"lr_fraction must be > 0, got {self.lr_fraction}")
        if not 0.0 < self.lr_decay <= 1.0:
            raise ValueError(f"lr_decay must be in (0, 1], got {self.lr_decay}")
        if int(self.flow_rounds) < 0 or int(self.flow_levels) < 0:
            raise ValueError(f"flow_rounds and flow_levels must be >= 0, got {self.flow_rounds}, {self.flow_levels}")
        if int(self.flow_final_rounds) < 0:
            raise ValueError(f"flow_final_rounds must be >= 0, got {self.flow_final_rounds}")
        if int(self.average_iterations) < 0:
            raise ValueError(f"average_iterations must be >= 0, got {self.average_iterations}")
        if not float(self.flow_smoothness) > 0.0:
            raise ValueError(f"flow_smoothness must be > 0, got {self.flow_smoothness}")
        if not float(self.flow_still_mm) >= 0.0:
            raise ValueError(f"flow_still_mm must be >= 0, got {self.flow_still_mm}")
        if not float(self.flow_socket_margin_px) >= 0.0:
            raise ValueError(f"flow_socket_margin_px must be >= 0, got {self.flow_socket_margin_px}")
        if not float(self.flow_chroma) >= 0.0:
            raise ValueError(f"flow_chroma must be >= 0, got {self.flow_chroma}")
        if int(self.flow_finest_scale) not in (0, 1, 2):
            raise ValueError(f"flow_finest_scale must be 0, 1 or 2, got {self.flow_finest_scale}")
        if self.flow_scan_shading_px is not None and not float(self.flow_scan_shading_px) >= 0.0:
            raise ValueError(f"flow_scan_shading_px must be null or >= 0, got {self.flow_scan_shading_px}")
        if self.flow_cholesky not in CHOLESKY_BACKENDS:
            raise ValueError(f"flow_cholesky must be one of {', '.join(CHOLESKY_BACKENDS)}, got {self.flow_cholesky!r}")
        if self.face_order not in FACE_ORDERS:
            raise ValueError(f"face_order must be one of {', '.join(FACE_ORDERS)}, got {self.face_order!r}")
        if self.color_gradient not in COLOR_GRADIENTS:
            raise ValueError(f"color_gradient must be one of {', '.join(COLOR_GRADIENTS)}, got {self.color_gradient!r}")
        if not 0.0 <= float(self.hold_tangential) < 1.0:
            raise ValueError(f"hold_tangential must be in [0, 1), got {self.hold_tangential}")
        if not 0.0 <= float(self.spring_rate) <= 1.0:
            raise ValueError(f"spring_rate must be in [0, 1], got {self.spring_rate}")
        if len(self.hold_moved_mm) != 2 or not 0.0 <= float(self.hold_moved_mm[0]) < float(self.hold_moved_mm[1]):
            raise ValueError(f"hold_moved_mm must be two distances 0 <= held < free (mm), got {list(self.hold_moved_mm)}")
        if self.hold_gap_mm is not None and (len(self.hold_gap_mm) != 2
                                             or not 0.0 <= float(self.hold_gap_mm[0]) < float(self.hold_gap_mm[1])):
            raise ValueError(f"hold_gap_mm must be null or two distances 0 <= held < free (mm), got {self.hold_gap_mm}")
        if self.hold_mouth_mm is not None and (len(self.hold_mouth_mm) != 2
                                               or not 0.0 <= float(self.hold_mouth_mm[0]) < float(self.hold_mouth_mm[1])):
            raise ValueError(f"hold_mouth_mm must be null or two distances 0 <= free < held (mm), got "
                             f"{self.hold_mouth_mm}")
        if self.mouth_stiffness is not None and (len(self.mouth_stiffness) != 3
                                                 or not float(self.mouth_stiffness[0]) >= 1.0
                                                 or not 0.0 <= float(self.mouth_stiffness[1])
                                                 < float(self.mouth_stiffness[2])):
            raise ValueError(f"mouth_stiffness must be null or [factor >= 1, near, far] with 0 <= near < far (mm), got "
                             f"{self.mouth_stiffness}")
        if self.jaw_search_deg is not None and (len(self.jaw_search_deg) != 2
                                                or not -90.0 <= float(self.jaw_search_deg[0]) <= 0.0
                                                <= float(self.jaw_search_deg[1]) <= 90.0):
            raise ValueError(f"jaw_search_deg must be null or two angles -90 <= lo <= 0 <= hi <= 90 (degrees), got "
                             f"{self.jaw_search_deg}")
        if self.jaw_shift_mm is not None and (len(self.jaw_shift_mm) != 2
                                              or not -30.0 <= float(self.jaw_shift_mm[0]) <= 0.0
                                              <= float(self.jaw_shift_mm[1]) <= 30.0):
            raise ValueError(f"jaw_shift_mm must be null or two shifts -30 <= lo <= 0 <= hi <= 30 (mm), got "
                             f"{self.jaw_shift_mm}")
        if self.jaw_reach_mm is not None and (len(self.jaw_reach_mm) != 2
                                              or not 0.0 <= float(self.jaw_reach_mm[0]) < float(self.jaw_reach_mm[1])):
            raise ValueError(f"jaw_reach_mm must be null or two distances 0 <= near < far (mm), got {self.jaw_reach_mm}")
        if self.jaw_window_mm is not None and not 0.0 < float(self.jaw_window_mm) <= 200.0:
            raise ValueError(f"jaw_window_mm must be null or a distance in (0, 200] mm, got {self.jaw_window_mm}")
        if self.lid_search_deg is not None and not 0.0 < float(self.lid_search_deg) <= 120.0:
            raise ValueError(f"lid_search_deg must be null or an angle in (0, 120] degrees, got {self.lid_search_deg}")
        if self.lip_seal is not None and not 0.0 < float(self.lip_seal) <= 1.0:
            raise ValueError(f"lip_seal must be null or a fraction in (0, 1], got {self.lip_seal}")
        if self.hold_mouth_at_flow_mm is not None and (
                len(self.hold_mouth_at_flow_mm) != 2
                or not 0.0 <= float(self.hold_mouth_at_flow_mm[0]) < float(self.hold_mouth_at_flow_mm[1])):
            raise ValueError(f"hold_mouth_at_flow_mm must be null or two distances 0 <= held < free (mm), got "
                             f"{self.hold_mouth_at_flow_mm}")
        if not isinstance(self.hold_moved_at_flow, (bool, np.bool_)):
            raise ValueError(f"hold_moved_at_flow must be true or false, got {self.hold_moved_at_flow!r}")
        if self.jaw_lips_mm is not None and (len(self.jaw_lips_mm) != 2
                                             or not -30.0 <= float(self.jaw_lips_mm[0]) <= 0.0
                                             <= float(self.jaw_lips_mm[1]) <= 30.0):
            raise ValueError(f"jaw_lips_mm must be null or two lifts -30 <= lo <= 0 <= hi <= 30 (mm), got "
                             f"{self.jaw_lips_mm}")

    @property
    def holds(self) -> bool:
        """Whether the start pulls on the registration: the tangential hold or the edge springs."""
        return self.hold_tangential > 0 or self.spring_rate > 0

    def pool(self, level: int) -> int:
        """The colour constraint's pooling box (px) at ``level``."""
        return 1 if self.color_pool is None else int(self.color_pool[level])

    def views(self, level: int) -> int:
        """How many views an iteration of ``level`` renders (0 = all)."""
        return 0 if self.views_per_iteration is None else int(self.views_per_iteration[level])

    def factor(self, level: int, height: int | None = None, width: int | None = None) -> int:
        """The image downsampling factor of ``level`` (1 = the data's resolution); with the images' size, the
        largest factor up to it that divides both sides and keeps the shorter one at least
        :data:`MIN_IMAGE_SIDE_PX` (or at its size, if smaller)."""
        factor = 1 if self.image_factor is None else int(self.image_factor[level])
        if height is None or width is None:
            return factor
        while factor > 1 and (height % factor or width % factor or min(height, width) // factor < MIN_IMAGE_SIDE_PX):
            factor -= 1
        return factor

    def learning_rate(self, base: float, iteration: int, n_iterations: int) -> float:
        """The step of ``iteration`` of a level whose first step is ``base`` (geometric decay)."""
        return base * self.lr_decay ** (iteration / max(n_iterations - 1, 1))


@dataclass
class RegistrationLog:
    """What a registration did: losses per iteration, time and size per level."""

    levels: list[dict] = field(default_factory=list)

    def to_json(self) -> dict:
        return {"levels": self.levels}


class ViewCycle:
    """Which views each iteration renders, when it renders ``per_iteration`` of ``n_views``.

    Every constraint draws its views from its own queue of seeded random permutations of all the
    views, ``per_iteration`` at a time and never one twice in a draw, so over ``n_views`` draws of
    a constraint each view is used ``per_iteration`` times: a stochastic gradient over the views
    whose every view counts equally (paired with ``Schedule.average_iterations``, which averages out
    the last steps' noise).
    """

    def __init__(self, n_views: int, per_iteration: int, seed: int, level: int) -> None:
        self.n_views = int(n_views)
        self.per_iteration = min(int(per_iteration), self.n_views) if per_iteration else self.n_views
        self.rng = np.random.default_rng([int(seed), int(level)])
        self.queues: dict[str, list[int]] = {}

    @property
    def all_views(self) -> bool:
        return self.per_iteration >= self.n_views

    def draw(self, constraint: str) -> list[int]:
        """The next ``per_iteration`` distinct view indices for ``constraint``, sorted."""
        if self.all_views:
            return list(range(self.n_views))
        queue = self.queues.setdefault(constraint, [])
        if len(queue) < self.per_iteration:
            queue.extend(int(i) for i in self.rng.permutation(self.n_views))
        chosen: list[int] = []
        k = 0
        while len(chosen) < self.per_iteration:
            if queue[k] in chosen:  # a view left from the last permutation comes again in the new one
                k += 1
                continue
            chosen.append(queue.pop(k))
        return sorted(chosen)


def mean_edge_length(mesh: TexturedMesh) -> float:
    return float(mesh.edge_lengths().mean())


def warmup_switches(switches: Switches, schedule: Schedule) -> Switches:
    """The warm-up's constraints: colour with the mouth socket not masked, alone or (``warmup_geometry``)
    with the depth and normal constraints that ``switches`` has on (module docstring)."""
    keep = bool(schedule.warmup_geometry)
    return Switches(color=True, depth=keep and switches.depth, normal=keep and switches.normal, mask=False)


def optimise(mesh: TexturedMesh, targets: ExpressionTargets, switches: Switches, schedule: Schedule, *,
             texture: torch.Tensor, mask_texture: torch.Tensor, render=None, cull_backfaces: bool = True,
             progress: Callable[[str], None] = print, progress_every: int = 50,
             on_stage: Callable[[str, TexturedMesh], None] | None = None,
             orientation: np.ndarray | None = None,
             scan: tuple[np.ndarray, np.ndarray] | None = None) -> tuple[TexturedMesh, RegistrationLog]:
    """Deform ``mesh`` towards one expression, level by level.

    Args:
        mesh: the starting mesh (mm) with UVs; refined between levels.
        orientation: (n, 3) float64 mm, positions on ``mesh``'s topology whose faces' orientation the
            untangling keeps (``untangle_turned``): the template's, in the workflow; None = ``mesh``'s own.
        targets: reference images, scan targets, cameras and lighting.
        switches: which constraints (and the mouth mask) to use.
        texture: (T, T, 3) albedo; mask_texture: (T', T', 1) mouth mask (1 = use, 0 = mouth interior).
        render: the backend's ``render_views`` (``gpja.render.renderer``) for every iteration's render;
            None = the CPU renderer (``gpja.render.render_views``).
        cull_backfaces: skip back faces (the template is closed: they are never visible).
        on_stage: called with ``("warmup", mesh)`` after the warm-up and ``("level{k}", mesh)`` after level k
            (1-based), for diagnostics (``gpja register --stages-dir``).
        scan: the expression's scan (V (k, 3) float64 mm, F (l, 3) int) for ``schedule.snap_mm``; None = no snap.
    Returns:
        The registered mesh (last level's topology, same UV parametrisation) and its log: one entry
        per level, preceded by the warm-up's (``"stage": "warmup"``) when there is one.
    Raises:
        RegistrationDiverged: a loss or the vertices became NaN/inf (names level and iteration).
    """
    switches.rotation()  # fails early when every constraint is off
    log = RegistrationLog()
    if schedule.color_scan_px is not None:  # every colour comparison below: only near what the scan covers
        targets = replace(targets, color_scan_px=int(schedule.color_scan_px))
    if schedule.mask_where_open:  # the socket left out of the colour only where the reference shows an opening
        targets = replace(targets, mask_where_open=True)
    if schedule.color_gain and switches.color:
        targets = gain_stage(mesh, targets, texture, mask_texture, render, progress, log)
    # the template's positions on the start's topology (the workflow's orientation, else the start's own): the lips'
    # spread reads them (lip_spread), the untangling keeps their faces' orientation (untangle_turned)
    untangle_turned = schedule.untangle_turned and schedule.untangle_iterations > 0
    template_V = None
    if schedule.lip_spread or untangle_turned:
        template_V = np.array(mesh.V if orientation is None else orientation, dtype=np.float64)
        if template_V.shape != mesh.V.shape:
            raise ValueError(f"orientation has shape {template_V.shape}, the mesh's vertices {mesh.V.shape}")
    # the orientation the untangling keeps, carried through the refinements
    reference = template_V if untangle_turned else None
    common = dict(targets=targets, texture=texture, mask_texture=mask_texture, render=render,
                  cull_backfaces=cull_backfaces, progress=progress, progress_every=progress_every)
    hold = None
    # the flow stage matches the render's colours: without the colour constraint there is none
    flow_levels = int(schedule.flow_levels) if schedule.flow_rounds and switches.color else 0
    warmup = bool(schedule.warmup_iterations and switches.color)
    release = None  # the hold's release where the jaw search's rig blends jaw and skull
    if schedule.jaw_search_deg is not None and switches.color:
        mesh, release = jaw_stage(mesh, targets, schedule, texture, mask_texture, render, progress, log, on_stage)
    if schedule.lid_search_deg is not None and switches.color:
        mesh = lids_stage(mesh, targets, schedule, texture, mask_texture, render, progress, log, on_stage)
    if flow_levels:
        before_flow = mesh
        mesh = flow_stage(mesh, targets, schedule, texture, mask_texture, render, progress, log, on_stage, "flow",
                          last=flow_levels == 1)
        if schedule.lip_spread:  # before the hold: what the spread moves is what the hold leaves free
            mesh = spread_stage(mesh, template_V, mask_texture, progress, log, on_stage)
        if schedule.holds and not warmup:  # the first flow stage tells what moves
            hold = start_hold(before_flow, mesh, schedule, targets, progress, "the flow stage", mask_texture, release)
            if flow_levels == 1:
                hold = anchor_hold_at_flow(hold, mesh, schedule, mask_texture, progress, "flow")
    if warmup:
        start_mesh = mesh
        mesh, entry = optimise_level(mesh, "warm-up", schedule.lambdas[0], int(schedule.warmup_iterations),
                                     warmup_switches(switches, schedule), schedule, 1, level=-1, **common)
        log.levels.append({"stage": "warmup", **entry})
        if on_stage is not None:
            on_stage("warmup", mesh)
        if schedule.holds:
            hold = start_hold(start_mesh, mesh, schedule, targets, progress, "the warm-up", mask_texture, release)
    elif schedule.holds and hold is None:
        progress("hold and springs: off (no warm-up or flow stage ran to tell moving parts from still ones)")
    for level, (lam, n_iter) in enumerate(zip(schedule.lambdas, schedule.iterations)):
        start = time.perf_counter()
        if level > 0:
            # the start's positions on this level's topology (the same splits: refinement picks edges by the mesh)
            if reference is not None:
                reference = refine_carrying(mesh, schedule.refine_factor, reference)[1]
            if hold is None:
                mesh = refine_by_factor(mesh, schedule.refine_factor)
            else:
                mesh, hold = hold.refine(mesh, schedule.refine_factor)
        refine_s = time.perf_counter() - start
        if 0 < level < flow_levels:
            # the hold stays: the next level's springs pull back what this stage slides in the held parts
            mesh = flow_stage(mesh, targets, schedule, texture, mask_texture, render, progress, log, on_stage,
                              f"flow{level + 1}", last=level == flow_levels - 1)
            if hold is not None and level == flow_levels - 1:
                hold = anchor_hold_at_flow(hold, mesh, schedule, mask_texture, progress, f"flow{level + 1}")
        mesh, entry = optimise_level(mesh, f"level {level + 1}/{len(schedule.lambdas)}", lam, n_iter, switches,
                                     schedule, schedule.pool(level), hold=hold, level=level, **common)
        entry["seconds"] = round(entry["seconds"] + refine_s, 3)
        entry["setup_seconds"] = round(entry["setup_seconds"] + refine_s, 3)
        log.levels.append({"stage": "level", "level": level, **entry})
        if on_stage is not None:
            on_stage(f"level{level + 1}", mesh)
    if int(schedule.flow_final_rounds) > 0 and switches.color:
        mesh = flow_stage(mesh, targets, schedule, texture, mask_texture, render, progress, log, on_stage,
                          "flow_final", rounds=int(schedule.flow_final_rounds))
    if schedule.untangle_iterations > 0:
        if reference is not None and reference.shape != mesh.V.shape:  # it must follow every refinement
            raise RuntimeError(f"the template's positions ({reference.shape}) do not match the mesh ({mesh.V.shape})")
        mesh = untangle_stage(mesh, schedule, progress, log, on_stage, reference)
    if schedule.snap_mm > 0:
        if scan is None:
            raise ValueError("snap_mm > 0 needs the expression's scan (optimise's scan)")
        mesh = snap_stage(mesh, scan, schedule, progress, log, on_stage)
    return mesh, log


def gain_stage(mesh: TexturedMesh, targets: ExpressionTargets, texture: torch.Tensor, mask_texture: torch.Tensor,
               render, progress: Callable[[str], None], log: RegistrationLog) -> ExpressionTargets:
    """The expression's colour gain measured against ``mesh`` (``gpja.register.gain``), logged as stage
    ``color_gain``; returns ``targets`` with the gain in its lighting (the mesh does not move)."""
    from gpja.register.gain import MIN_PIXELS, measure_gain, with_gain

    start = time.perf_counter()
    gain, entry = measure_gain(mesh, targets, texture, mask_texture, render)
    entry["seconds"] = round(time.perf_counter() - start, 3)
    log.levels.append({"stage": "color_gain", **entry})
    if entry["measured"]:
        progress(f"colour gain: the references are {' / '.join(f'{g:.3f}' for g in gain)} times the start's render "
                 f"(R / G / B, median over {entry['pixels']} skin pixels), {entry['seconds']:.1f} s")
    else:
        progress(f"colour gain: {entry['pixels']} skin pixels, fewer than {MIN_PIXELS}: the template's lighting as it is")
    return with_gain(targets, gain)


def snap_stage(mesh: TexturedMesh, scan: tuple[np.ndarray, np.ndarray], schedule: Schedule,
               progress: Callable[[str], None], log: RegistrationLog,
               on_stage: Callable[[str, TexturedMesh], None] | None) -> TexturedMesh:
    """The registered mesh moved along its normals onto ``scan`` (``gpja.register.snap``), logged and saved as
    stage ``snap``; returns the mesh (same topology and texture coordinates)."""
    from gpja.register.snap import snap_to_scan

    start = time.perf_counter()
    V, entry = snap_to_scan(mesh.V, mesh.F, scan[0], scan[1], float(schedule.snap_mm), float(schedule.snap_smoothness))
    mesh = mesh.with_vertices(V)
    entry["seconds"] = round(time.perf_counter() - start, 3)
    log.levels.append({"stage": "snap", **entry})
    progress(f"snap: {entry['hit_fraction']:.0%} of the vertices see the scan within {schedule.snap_mm:g} mm along "
             f"their normals (gap median {entry['gap_median_mm']:.3f}, p95 {entry['gap_p95_mm']:.3f} mm); moved median "
             f"{entry['moved_median_mm']:.3f}, at most {entry['moved_max_mm']:.2f} mm, {entry['seconds']:.1f} s")
    if on_stage is not None:
        on_stage("snap", mesh)
    return mesh


def spread_stage(mesh: TexturedMesh, template_V: np.ndarray, mask_texture: torch.Tensor,
                 progress: Callable[[str], None], log: RegistrationLog,
                 on_stage: Callable[[str, TexturedMesh], None] | None) -> TexturedMesh:
    """The lips' material spread between the mouth's corners (``gpja.register.spread``), logged and saved as stage
    ``spread``; returns the mesh (same topology and texture coordinates)."""
    from gpja.register.spread import spread_lips

    mesh, entry = spread_lips(mesh, template_V, mask_texture, progress)
    log.levels.append(entry)
    if on_stage is not None:
        on_stage("spread", mesh)
    return mesh


def untangle_stage(mesh: TexturedMesh, schedule: Schedule, progress: Callable[[str], None], log: RegistrationLog,
                   on_stage: Callable[[str, TexturedMesh], None] | None,
                   reference: np.ndarray | None = None) -> TexturedMesh:
    """The folds of the registered mesh smoothed out along its own surface (``gpja.folds``), logged and saved as
    stage ``untangle``; returns the mesh (same topology and texture coordinates, folds' vertices moved).
    ``reference``: (n, 3) the template's positions on this topology; faces turned against it count as folds."""
    from gpja.folds import untangle_on_surface
    from gpja.surface import prepare_surface

    start = time.perf_counter()
    V, entry = untangle_on_surface(mesh.V, mesh.F, prepare_surface(mesh.V, mesh.F, find_boundary=False),
                                   int(schedule.untangle_iterations), int(schedule.untangle_rings), reference)
    mesh = mesh.with_vertices(V)
    entry["seconds"] = round(time.perf_counter() - start, 3)
    log.levels.append({"stage": "untangle", **entry})
    turned = (f" (of them turned over against the template: {entry['turned_before']} -> {entry['turned_after']})"
              if "turned_before" in entry else "")
    progress(f"untangle: {entry['folded_before']} -> {entry['folded_after']} folded faces{turned} in {entry['rounds']} "
             f"rounds, {entry['moved_vertices']} vertices moved (at most {entry['max_move_mm']:.2f} mm along the "
             f"surface), {entry['seconds']:.1f} s")
    if on_stage is not None:
        on_stage("untangle", mesh)
    return mesh


def start_hold(start: TexturedMesh, moved: TexturedMesh, schedule: Schedule, targets: ExpressionTargets,
               progress: Callable[[str], None], what: str, mask_texture: torch.Tensor | None = None,
               release: np.ndarray | None = None) -> TangentialHold:
    """The tangential hold (``gpja.register.hold``) of a registration that started at ``start`` and was at
    ``moved`` after its first phase (``what``: the warm-up, or without one the first flow stage); with
    ``schedule.hold_gap_mm``, gated by ``start``'s gap to the scan of ``targets``; with ``schedule.hold_mouth_mm``,
    released around the socket of ``mask_texture`` ((T, T, 1) mouth mask, 0 = socket); ``release``: (n,) factor
    in [0, 1] the weights are also multiplied by (the jaw search's, :func:`gpja.register.jaw.blend_release`)."""
    gap_mm = None if schedule.hold_gap_mm is None else tuple(schedule.hold_gap_mm)
    gap = None if gap_mm is None else scan_gap(start.V, start.F, targets)
    mouth = None
    if schedule.hold_mouth_mm is not None:
        if mask_texture is None:
            raise ValueError("hold_mouth_mm needs the template's mouth mask (start_hold's mask_texture)")
        from gpja.register.flow import socket_vertices

        mouth = mouth_factor(start.V, socket_vertices(start, mask_texture), tuple(schedule.hold_mouth_mm))
    freed_at_mouth = None if mouth is None else float(np.mean(mouth == 0))
    if release is not None:
        mouth = release if mouth is None else mouth * release
    hold = TangentialHold.after_first_phase(start, moved, schedule.lambdas[0], schedule.hold_tangential,
                                            tuple(schedule.hold_moved_mm), gap, gap_mm, schedule.spring_rate, mouth)
    gated = "" if gap is None else (f"; free beyond {gap_mm[1]:g} mm off the scan: {np.mean(gap > gap_mm[1]):.0%} "
                                    "of the vertices")
    if freed_at_mouth is not None:
        gated += (f"; free within {schedule.hold_mouth_mm[0]:g} mm of the mouth's socket: {freed_at_mouth:.0%} "
                  "of the vertices")
    if release is not None:
        gated += f"; free where the jaw's turn is blended: {np.mean(release == 0):.0%} of the vertices"
    if schedule.hold_tangential > 0:
        progress(f"hold: {hold.held_fraction:.0%} of the vertices held tangentially "
                 f"(moved < {schedule.hold_moved_mm[0]:g}-{schedule.hold_moved_mm[1]:g} mm in {what}{gated})")
    if schedule.spring_rate > 0:
        progress(f"springs: {len(hold.edges)} edges kept at the start's lengths, rate {schedule.spring_rate:g}")
    return hold


def anchor_hold_at_flow(hold: TangentialHold, mesh: TexturedMesh, schedule: Schedule, mask_texture: torch.Tensor,
                        progress: Callable[[str], None], stage: str) -> TangentialHold:
    """``hold`` anchored where the last flow stage (``stage``) put ``mesh``: around the mouth
    (``schedule.hold_mouth_at_flow_mm``) and, with ``schedule.hold_moved_at_flow``, wherever the hold left the
    vertices free (weight ``1 - hold.weight``); the hold unchanged when neither is set."""
    near = np.zeros(len(mesh.V))
    if schedule.hold_mouth_at_flow_mm is not None:
        from gpja.register.flow import socket_vertices

        near = 1.0 - mouth_factor(mesh.V, socket_vertices(mesh, mask_texture), tuple(schedule.hold_mouth_at_flow_mm))
        progress(f"hold: {np.mean(near > 0):.0%} of the vertices anchored where {stage} put the mouth "
                 f"({np.mean(near >= 1):.0%} held fully)")
    if schedule.hold_moved_at_flow:
        free = 1.0 - np.asarray(hold.weight, dtype=np.float64)
        free = np.where(free > 0.5, free, 0.0)  # the held majority keeps its anchor at the registration's start
        progress(f"hold: {np.mean(free > 0):.0%} of the vertices it left free anchored where {stage} put them")
        near = np.maximum(near, free)
    if not np.any(near > 0):
        return hold
    return hold.reanchored(mesh.V, mesh.F, near)


def jaw_stage(mesh: TexturedMesh, targets: ExpressionTargets, schedule: Schedule, texture: torch.Tensor,
              mask_texture: torch.Tensor, render, progress: Callable[[str], None], log: RegistrationLog,
              on_stage: Callable[[str, TexturedMesh], None] | None) -> tuple[TexturedMesh, np.ndarray | None]:
    """The jaw search (``gpja.register.jaw``), logged and saved as stage ``jaw``; returns the turned mesh and, when
    it turned, the hold's release (:func:`gpja.register.jaw.blend_release`; None when the jaw stayed)."""
    from gpja.register.jaw import blend_release, search_jaw

    lips = None if schedule.jaw_lips_mm is None else tuple(schedule.jaw_lips_mm)
    shift = None if schedule.jaw_shift_mm is None else tuple(schedule.jaw_shift_mm)
    mesh, entry, rig = search_jaw(mesh, targets, texture, mask_texture, tuple(schedule.jaw_search_deg), render, progress,
                                  lips_mm=lips, shift_mm=shift, window_mm=schedule.jaw_window_mm,
                                  reach_mm=None if schedule.jaw_reach_mm is None else tuple(schedule.jaw_reach_mm))
    log.levels.append(entry)
    if on_stage is not None:
        on_stage("jaw", mesh)
    moved = entry["pitch_deg"] != 0.0 or entry.get("shift_mm", 0.0) != 0.0
    return mesh, (blend_release(rig.weight) if moved else None)


def lids_stage(mesh: TexturedMesh, targets: ExpressionTargets, schedule: Schedule, texture: torch.Tensor,
               mask_texture: torch.Tensor, render, progress: Callable[[str], None], log: RegistrationLog,
               on_stage: Callable[[str, TexturedMesh], None] | None) -> TexturedMesh:
    """The lid search (``gpja.register.lids``), logged and saved as stage ``lids``; returns the posed mesh (the
    hold, started after the flow stage, then keeps the lids where the search closed them)."""
    from gpja.register.lids import search_lids

    mesh, entry = search_lids(mesh, targets, texture, mask_texture, float(schedule.lid_search_deg), render, progress)
    log.levels.append(entry)
    if on_stage is not None:
        on_stage("lids", mesh)
    return mesh


def flow_stage(mesh: TexturedMesh, targets: ExpressionTargets, schedule: Schedule, texture: torch.Tensor,
               mask_texture: torch.Tensor, render, progress: Callable[[str], None], log: RegistrationLog,
               on_stage: Callable[[str, TexturedMesh], None] | None, name: str, last: bool = False,
               rounds: int | None = None) -> TexturedMesh:
    """``rounds`` (None: ``schedule.flow_rounds``) rounds of optical-flow matching (``gpja.register.flow``), logged
    and saved as stage ``name``; returns the moved mesh (same topology). After the ``last`` flow stage, the lips are
    sealed where the references show them closed (``schedule.lip_seal``, :mod:`gpja.register.seal`)."""
    from gpja.register.flow import align_by_flow

    rounds = int(schedule.flow_rounds) if rounds is None else int(rounds)
    settings = FlowSettings(rounds=rounds, smoothness=float(schedule.flow_smoothness),
                            still_mm=float(schedule.flow_still_mm), chroma=float(schedule.flow_chroma),
                            socket_margin_px=float(schedule.flow_socket_margin_px),
                            finest_scale=int(schedule.flow_finest_scale), cholesky=schedule.flow_cholesky,
                            scan_shading_px=(None if schedule.flow_scan_shading_px is None
                                             else float(schedule.flow_scan_shading_px)),
                            own_shading_rounds=1 if name == "flow" else 0)
    mesh, entry = align_by_flow(mesh, targets, texture, mask_texture, settings, render=render, progress=progress)
    log.levels.append({**entry, "stage": name})
    if schedule.lip_seal is not None and last:
        from gpja.register.seal import seal_lips

        mesh, sealed = seal_lips(mesh, targets, mask_texture, float(schedule.lip_seal), settings.smoothness, progress)
        log.levels.append({**sealed, "after": name})
    if on_stage is not None:
        on_stage(name, mesh)
    return mesh


def constraint_optimizers(param: LargeStepsParametrization, rotation: tuple[str, ...], lr: float,
                          state: str) -> dict:
    """The uniform Adam each constraint of ``rotation`` steps with: one shared, or one each.

    Shared, the moments mix the constraints' gradients, so the one with the largest gradients (depth,
    in mm) sets the normaliser and the others' steps shrink by their gradients' ratio to it. One each,
    every constraint's step is normalised by its own gradients: each moves the surface by up to the
    learning rate, whatever its units.
    """
    if state == "shared":
        shared = param.optimizer(lr)
        return {c: shared for c in rotation}
    return {c: param.optimizer(lr) for c in rotation}


def mouth_face_weight(mesh: TexturedMesh, mask_texture: torch.Tensor,
                      stiffness: tuple[float, float, float]) -> np.ndarray:
    """(m,) float64 factor on a level's lambda for each face of ``mesh`` (``Schedule.mouth_stiffness``).

    ``stiffness`` = (factor, near, far): a vertex within ``near`` mm (straight line, on ``mesh``) of the nearest
    socket vertex (:func:`gpja.register.flow.socket_vertices` of ``mask_texture``, (T, T, 1), 0 = socket) gets
    ``factor``, one from ``far`` mm on 1, linear between (:func:`gpja.register.hold.mouth_factor`); a face gets
    the mean of its corners'. All ones when the mask marks no socket.
    """
    from gpja.register.flow import socket_vertices

    factor, near, far = (float(v) for v in stiffness)
    away = mouth_factor(mesh.V, socket_vertices(mesh, mask_texture), (near, far))  # 0 near, 1 far
    vertex = factor + (1.0 - factor) * away
    return vertex[mesh.F].mean(axis=1)


def optimise_level(mesh: TexturedMesh, name: str, lam: float, n_iter: int, switches: Switches,
                   schedule: Schedule, pool: int, *, targets: ExpressionTargets, texture: torch.Tensor,
                   mask_texture: torch.Tensor, render, cull_backfaces: bool, progress: Callable[[str], None],
                   progress_every: int, hold: TangentialHold | None = None, level: int = 0) -> tuple[TexturedMesh, dict]:
    """``n_iter`` LargeSteps iterations on one fixed topology; returns the mesh and the level's log entry.

    ``name`` labels progress lines and errors ("level 2/3", "warm-up"). The first step is
    ``schedule.lr_fraction`` x this mesh's mean edge length (mm), decaying as the schedule says.
    ``render``: as in :func:`optimise` (None = the CPU renderer). ``hold``: the tangential hold on
    this mesh's vertices, applied before every iteration's render (None = none, the paper). ``level``: the
    schedule's level (0-based; -1 = the warm-up, which runs at the first level's images and views) for
    ``Schedule.image_factor`` and ``views_per_iteration``.
    """
    start = time.perf_counter()
    rotation = switches.rotation()
    settings_level = max(level, 0)
    factor = schedule.factor(settings_level, *targets.images.shape[1:3])
    targets = targets.downsampled(factor)
    cycle = ViewCycle(len(targets.cameras), schedule.views(settings_level), schedule.seed, level + 1)
    lr = schedule.lr_fraction * mean_edge_length(mesh)
    face_weight = None
    if schedule.mouth_stiffness is not None:
        face_weight = mouth_face_weight(mesh, mask_texture, tuple(schedule.mouth_stiffness))
    param = LargeStepsParametrization(mesh.V, mesh.F, lam, face_weight=face_weight)
    optimizers = constraint_optimizers(param, rotation, lr, schedule.optimizer_state)
    topo = Topology.in_spatial_order(mesh.V, mesh.F, mesh.F_uv) if schedule.face_order == "spatial" else \
        Topology(torch.from_numpy(mesh.F), torch.from_numpy(mesh.F_uv))
    uv = torch.tensor(mesh.UV, dtype=torch.float32)
    losses: dict[str, list[float]] = {c: [] for c in rotation}
    # where the time goes, s: the solve (I + lambda L)^-1 u in both directions, the render +
    # loss forward, and the render's backward pass
    timings = {"solve": 0.0, "render": 0.0, "backward": 0.0}
    setup_s = time.perf_counter() - start
    # the mean of the positions after the last `averaged` steps: the renders of the iterations after the first
    # of them (each renders the previous step's result), plus the result of the last step
    averaged = min(int(schedule.average_iterations), n_iter)
    position_sum = None
    for it in range(n_iter):
        constraint = rotation[it % len(rotation)]
        opt = optimizers[constraint]
        for group in opt.param_groups:
            group["lr"] = schedule.learning_rate(lr, it, n_iter)
        t0 = time.perf_counter()
        x = param.vertices()
        if hold is not None:
            dx = hold.correction(x)
            param.shift(dx)
            x = x + dx  # what vertices() now returns, without a second solve
        t1 = time.perf_counter()
        if averaged > 1 and it > n_iter - averaged:
            position_sum = x.detach().double() + (0.0 if position_sum is None else position_sum)
        if constraint == "color" and schedule.color_gradient == "tangential":
            x = along_surface(x, topo.faces)
        seen = targets if cycle.all_views else targets.views(cycle.draw(constraint))
        loss, _ = render_constraint(constraint, x, topo, seen, switches, uv, texture, mask_texture,
                                    render=render, cull_backfaces=cull_backfaces, color_pool=pool)
        value = loss.detach().item()
        if not math.isfinite(value):
            raise RegistrationDiverged(f"{name}, iteration {it}: the {constraint} loss is {value}")
        t2 = time.perf_counter()
        opt.zero_grad()
        loss.backward()
        opt.step()
        t3 = time.perf_counter()
        timings["solve"] += t1 - t0
        timings["render"] += t2 - t1
        timings["backward"] += t3 - t2  # includes the adjoint solve of the parametrisation
        if not torch.isfinite(param.u).all():
            raise RegistrationDiverged(f"{name}, iteration {it}: vertices became NaN/inf after the {constraint} step")
        losses[constraint].append(value)
        if progress_every and (it + 1) % progress_every == 0:
            rate = (it + 1) / (time.perf_counter() - start)
            recent = ", ".join(f"{c} {np.mean(v[-progress_every // len(rotation):]):.4g}" for c, v in losses.items() if v)
            progress(f"{name} iter {it + 1}/{n_iter}: {recent} ({rate:.1f} it/s)")
    with torch.no_grad():
        last = param.vertices().double()
        final = last if position_sum is None else (position_sum + last) / averaged
        mesh = mesh.with_vertices(final.numpy())
    return mesh, {"lambda": lam, "iterations": n_iter, "learning_rate_mm": lr, "color_pool": pool,
                  "image_factor": factor, "image_size": list(targets.images.shape[1:3]),
                  "views_per_iteration": cycle.per_iteration, "face_order": schedule.face_order,
                  "averaged_iterations": max(averaged, 1),
                  "vertices": int(len(mesh.V)), "faces": int(len(mesh.F)),
                  "seconds": round(time.perf_counter() - start, 3), "setup_seconds": round(setup_s, 3),
                  "seconds_by_stage": {k: round(v, 3) for k, v in timings.items()}, "losses": losses,
                  "hold": None if hold is None else {"rate": hold.rate, "held_fraction": round(hold.held_fraction, 4),
                                                     "spring_rate": hold.spring_rate}}
