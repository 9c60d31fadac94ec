"""An artist's UV-unwrapped mesh of a subject carried onto every expression (the paper's "Applications").

Every expression mesh GPJA registers shares the template's texture parametrisation (its UV atlas); each has
its own triangulation (refinement split different edges), but a texture coordinate names one surface point in
every one of them. An artist's mesh of the subject, modelled in the template expression's frame with its own
triangulation and its own UV unwrap, is carried to expression b by the paper's map phi_b phi_a^-1:

1. each artist vertex goes to its closest point on the template, hence a template texture coordinate
   (:func:`artist_on_template`: phi_a^-1);
2. that texture coordinate is located in expression b's atlas and gives a point of its surface
   (:func:`carry_to_expression`: phi_b, with ``gpja.apply.remesh.locate_uv`` and ``positions_at_uv``).

The carried meshes keep the artist's faces and UVs, so the artist's texture (or the shared texture resampled
into the artist's layout, :func:`resample_texture`) goes with every expression. :func:`check_artist_mesh`
rejects meshes the map would silently ruin (no UVs, other units, another frame), and :func:`flipped_faces`
counts the triangles that turn over between two expressions.

Without an artist at hand, :func:`make_standin_artist_mesh` makes a stand-in: the template decimated to a
coarser triangulation and unwrapped again by xatlas.

Conventions (as the rest of gpja): positions in mm; UVs in OBJ's convention (origin bottom-left, v up); a
texture's row 0 is its top (v = 1). Texel (r, c) of a (T, T) texture has its centre at
u = (c + 0.5) / T, v = 1 - (r + 0.5) / T and a texture is sampled bilinearly with the border texel repeated:
``gpja.render.texture.sample_texture`` (grid_sample, align_corners=False, padding "border") and the nvdiffrast
backend (``dr.texture`` with v flipped, boundary "clamp") sample so, and ``gpja.render.uv_raster`` places texel
centres so.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from gpja.apply.remesh import locate_on_atlas, positions_at_uv
from gpja.errors import InputError
from gpja.folds import turned_faces
from gpja.mesh import TexturedMesh
from gpja.render.rasterize import BACKGROUND
from gpja.render.uv_raster import rasterize_uv
from gpja.surface import prepare_surface

#: The artist mesh's bounding-box diagonal over the template's must lie in this range; outside it the mesh is
#: in other units (metres, centimetres, inches) or is not of this subject.
UNITS_RATIO_RANGE = (0.5, 2.0)
#: The median distance from the artist mesh's vertices to the template surface may be at most this, mm: a mesh
#: modelled on the template sits on it; more means another frame (a shift, a rotation) or another subject.
ARTIST_MAX_MEDIAN_MM = 1.0
#: The 95th percentile of that distance may be at most this, mm (an artist may reshape a few parts: ears, hair).
ARTIST_MAX_P95_MM = 5.0
#: Side of the atlas xatlas packs the stand-in's charts into, texels (it picks the texel density to match).
STANDIN_ATLAS_RESOLUTION = 1024
#: Gap xatlas leaves around each chart of the stand-in, texels of that atlas: at a 256-texel texture still
#: about 2 texels, so bilinear lookups at a chart's border read its own (dilated) colour, never the next chart's.
STANDIN_ATLAS_PADDING = 8


# --- a stand-in artist mesh -----------------------------------------------------------------------------

def make_standin_artist_mesh(template: TexturedMesh, faces: int, seed: int = 0) -> TexturedMesh:
    """A different, coarser triangulation of the template's surface with its own UV unwrap.

    1. pymeshlab's quadric edge collapse decimates the template (positions and faces only, its UVs dropped)
       to about ``faces`` triangles, keeping its topology (no holes closed or opened, genus kept), its
       rim (``preserveboundary``) and its face orientation (``preservenormal``). Collapsed vertices take
       the quadric's optimal position, so the stand-in is off the template's surface by a fraction of its
       edge length, as an artist's mesh would be. ``gpja.register.template.decimate_with_texture`` is not
       used: it keeps the template's atlas, and the point here is a layout of the stand-in's own.
    2. xatlas (``xatlas==0.0.11``, the Python binding of Jonathan Young's xatlas: a well-kept library
       (Godot's lightmapper unwraps with it); writing a chart segmenter, parametriser and packer is out of
       scope) cuts the surface into charts, flattens and packs them into one atlas
       (:data:`STANDIN_ATLAS_RESOLUTION`, :data:`STANDIN_ATLAS_PADDING`). xatlas splits vertices at chart
       seams, returning per split vertex its source vertex (``vmapping``), split faces (``indices``) and UVs
       normalised to [0, 1]; the result is welded: ``V`` = the decimated positions, ``F = vmapping[indices]``,
       ``UV = uvs``, ``F_uv = indices``.

    UV orientation: with its default ``rotate_charts``, xatlas's packer leaves whole charts mirrored (measured
    on a sphere: 16% to 73% of the faces clockwise, one chart at a time, whatever ``fix_winding`` says; its
    quarter turns evidently swap u and v). It is switched off; ``rotate_charts_to_axis`` (aligning each chart's
    main axis with u or v) stays on and mirrors nothing. Then xatlas's u and v, read as OBJ's (origin
    bottom-left, v up), leave the faces counter-clockwise in UV as they are in 3-D seen from outside (measured:
    every face, on several seeds), so a texture painted on the layout is not shown mirrored; the tests check it.

    Deterministic: pymeshlab's collapse and xatlas give the same output for the same input (the tests call it
    twice). ``seed`` 0 decimates the template's faces in their order; another seed shuffles the face order
    first (``numpy.random.default_rng(seed)``), which changes the collapse order among equal costs and so gives
    another triangulation and another layout.

    Args:
        template: V (n, 3) float64 mm, F (m, 3); its UVs are not used.
        faces: the wanted face count (pymeshlab may stop a little above or below it); at least 4.
        seed: 0 = the template's face order; other values shuffle it.
    Returns:
        A mesh without texture: V (n', 3) float64 mm, F (m', 3) int64, UV (k', 2) float64 in [0, 1] (OBJ
        convention), F_uv (m', 3) int64.
    """
    import pymeshlab
    import xatlas

    template.validate("template")
    if faces < 4:
        raise ValueError(f"a stand-in needs at least 4 faces, got {faces}")
    F = template.F
    if seed != 0:
        F = F[np.random.default_rng(seed).permutation(len(F))]
    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=template.V, face_matrix=F.astype(np.int32)))
    if faces < len(F):
        ms.meshing_decimation_quadric_edge_collapse(targetfacenum=int(faces), preservetopology=True,
                                                    preserveboundary=True, preservenormal=True)
    ms.meshing_remove_unreferenced_vertices()
    decimated = ms.current_mesh()
    V = np.asarray(decimated.vertex_matrix(), dtype=np.float64)
    F = np.asarray(decimated.face_matrix(), dtype=np.int64)

    atlas = xatlas.Atlas()
    atlas.add_mesh(np.ascontiguousarray(V, dtype=np.float32), np.ascontiguousarray(F, dtype=np.uint32))
    pack = xatlas.PackOptions()
    pack.resolution = STANDIN_ATLAS_RESOLUTION
    pack.padding = STANDIN_ATLAS_PADDING
    pack.rotate_charts = False  # its quarter turns are transposes: mirrored charts
    pack.rotate_charts_to_axis = True
    atlas.generate(xatlas.ChartOptions(), pack)
    if atlas.atlas_count != 1:  # several atlases would overlap in [0, 1]
        raise RuntimeError(f"xatlas packed the stand-in into {atlas.atlas_count} atlases, expected one")
    vmapping, indices, uvs = atlas[0]
    F_uv = np.asarray(indices, dtype=np.int64)
    return TexturedMesh(V, np.asarray(vmapping, dtype=np.int64)[F_uv], np.asarray(uvs, dtype=np.float64), F_uv)


def uv_signed_areas(UV: np.ndarray, F_uv: np.ndarray) -> np.ndarray:
    """(m,) float64 twice the signed area of each UV triangle (UV units squared): > 0 counter-clockwise in
    OBJ's frame (u right, v up)."""
    a, b, c = UV[F_uv[:, 0]], UV[F_uv[:, 1]], UV[F_uv[:, 2]]
    return (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])


# --- checks ---------------------------------------------------------------------------------------------

def bounding_box_diagonal(V: np.ndarray) -> float:
    """Length of the axis-aligned bounding box's diagonal of ``V (n, 3)``, units of ``V``."""
    return float(np.linalg.norm(V.max(axis=0) - V.min(axis=0)))


def check_artist_mesh(artist: TexturedMesh, template: TexturedMesh, source: str | Path) -> None:
    """Raise :class:`InputError` naming ``source`` if the artist mesh cannot be carried by the template.

    Checks, in order: a usable mesh (``artist.validate``: not empty, finite positions, indices in range);
    texture coordinates; millimetres (the bounding-box diagonals' ratio in :data:`UNITS_RATIO_RANGE`); the
    template expression's frame (distances from the artist's vertices to the template surface: median at
    most :data:`ARTIST_MAX_MEDIAN_MM`, 95th percentile at most :data:`ARTIST_MAX_P95_MM`).

    Args:
        artist: V (n, 3) float64 mm, F, UV (k, 2), F_uv.
        template: the subject's template, V (n_t, 3) float64 mm, F (m_t, 3).
        source: the artist mesh's file (or name), for the message.
    """
    artist.validate(source)
    if not artist.has_uv:
        raise InputError(source, "the artist mesh has no texture coordinates ('vt'): it needs its own UV unwrap "
                                 "to be carried to the expressions")
    mine, theirs = bounding_box_diagonal(artist.V), bounding_box_diagonal(template.V)
    low, high = UNITS_RATIO_RANGE
    if not low * theirs <= mine <= high * theirs:
        raise InputError(source, f"the artist mesh looks like it is in different units (bounding box diagonal "
                                 f"{mine:.4g} mm against the template's {theirs:.4g} mm); the artist mesh must be "
                                 "in millimetres in the template expression's frame")
    surface = prepare_surface(template.V, template.F, find_boundary=False)
    distance = surface.closest(artist.V).distance
    median, p95 = float(np.median(distance)), float(np.percentile(distance, 95))
    if median > ARTIST_MAX_MEDIAN_MM or p95 > ARTIST_MAX_P95_MM:
        raise InputError(source, f"the artist mesh is too far from the template's surface: its vertices are "
                                 f"{median:.3g} mm from it (median) and {p95:.3g} mm (95th percentile), at most "
                                 f"{ARTIST_MAX_MEDIAN_MM:g} mm and {ARTIST_MAX_P95_MM:g} mm allowed; the artist mesh "
                                 "must be of this subject, in millimetres, in the template expression's frame")


# --- the map through texture space ------------------------------------------------------------------------

def template_uv_of_points(template: TexturedMesh, P: np.ndarray) -> np.ndarray:
    """The template texture coordinate of the closest template point of each of ``P (q, 3)`` float64 mm.

    The closest point (``gpja.surface``: Open3D, float32 BVH) is a face and barycentrics; the barycentrics are
    clipped to [0, 1] and renormalised (float32 can leave them a hair negative) and interpolate the face's UV
    corners. A point whose closest point is on a seam gets the texture coordinate of one of its charts: both
    name the same surface point.

    Returns:
        (q, 2) float64 texture coordinates of the template's atlas (OBJ convention).
    """
    if not template.has_uv:
        raise ValueError("the template has no texture coordinates")
    surface = prepare_surface(template.V, template.F, find_boundary=False)
    hit = surface.closest(np.asarray(P, dtype=np.float64))
    bary = np.clip(hit.barycentric, 0.0, 1.0)
    bary /= bary.sum(axis=1, keepdims=True)
    return np.einsum("qk,qkc->qc", bary, template.UV[template.F_uv[hit.face]])


def artist_on_template(artist: TexturedMesh, template: TexturedMesh) -> np.ndarray:
    """The template texture coordinate of every artist vertex (phi_a^-1: via its closest template point).

    Args:
        artist: V (n, 3) float64 mm in the template expression's frame.
        template: V (n_t, 3) float64 mm, F, UV (k_t, 2), F_uv.
    Returns:
        (n, 2) float64 template texture coordinates (OBJ convention), one per artist vertex.
    """
    return template_uv_of_points(template, artist.V)


def carry_to_expression(artist: TexturedMesh, template_uv: np.ndarray, expression_mesh: TexturedMesh,
                        source: str | Path) -> TexturedMesh:
    """The artist mesh on an expression: its vertices at their template texture coordinates there (phi_b).

    Args:
        artist: F (m, 3), UV, F_uv (and texture) kept; its positions are not used.
        template_uv: (n, 2) float64, :func:`artist_on_template` of the artist's n vertices.
        expression_mesh: a registered expression, V (n_e, 3) float64 mm, F, and an atlas that refines the
            template's (UV (k_e, 2), F_uv).
        source: the expression's file (or name), for messages.
    Returns:
        The artist's topology (same F, UV, F_uv, texture) with V (n, 3) float64 mm on the expression's surface.
    Raises:
        InputError: the expression mesh (named ``source``) is unusable, has no UVs, or its atlas misses a
            texture coordinate by more than ``gpja.apply.remesh.UV_OFF_ATLAS`` (it does not share the
            template's parametrisation: its atlas refines the template's exactly, so the distance is ~0).
    """
    template_uv = np.asarray(template_uv, dtype=np.float64)
    if template_uv.shape != (len(artist.V), 2):
        raise ValueError(f"template_uv has shape {template_uv.shape}, expected ({len(artist.V)}, 2)")
    location = locate_on_atlas(expression_mesh, template_uv, source, "of an artist vertex")
    return TexturedMesh(positions_at_uv(expression_mesh, location), artist.F, artist.UV, artist.F_uv, artist.texture)


# --- the shared texture in the artist's layout ----------------------------------------------------------

def sample_texture_np(texture: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Bilinear samples of ``texture`` (T, T, C) at ``uv`` (q, 2) (OBJ convention): (q, C) float32.

    The renderer's convention (``gpja.render.texture.sample_texture``; ``gpja.render.uv_raster.uv_to_texel``):
    texel (r, c) centred at u = (c + 0.5) / T, v = 1 - (r + 0.5) / T, the border texel repeated outside. The lookup is
    ``gpja.register.texture_fill.sample_bilinear`` (OpenCV ``remap``: positions rounded to 1/32 texel).
    """
    from gpja.register.texture_fill import sample_bilinear
    from gpja.render.uv_raster import uv_to_texel

    if texture.shape[0] != texture.shape[1]:
        raise ValueError(f"texture must be square, got {texture.shape[:2]}")
    return sample_bilinear(np.ascontiguousarray(texture, dtype=np.float32), uv_to_texel(uv, texture.shape[0]))


def dilate(values: np.ndarray, known: np.ndarray, rounds: int) -> np.ndarray:
    """Grow ``values`` (T, T, C) out of the ``known`` (T, T) bool texels by ``rounds`` rings.

    Each round, every unknown texel with a known 8-neighbour takes the mean of its known 8-neighbours and
    becomes known. Known texels keep their values; texels left unknown are 0. Returns (T, T, C) float32.
    """
    import cv2

    out = np.where(known[..., None], values, 0.0).astype(np.float32)
    known = known.copy()
    kernel = np.ones((3, 3), np.float32)
    for _ in range(rounds):
        weight = cv2.filter2D(known.astype(np.float32), -1, kernel, borderType=cv2.BORDER_CONSTANT)
        grown = (~known) & (weight > 0.5)
        if not grown.any():
            break
        total = cv2.filter2D(out, -1, kernel, borderType=cv2.BORDER_CONSTANT).reshape(out.shape)
        out[grown] = total[grown] / weight[grown][:, None]
        known |= grown
    return out


def resample_texture(artist: TexturedMesh, template: TexturedMesh, texture: np.ndarray, size: int,
                     padding: int = 4) -> tuple[np.ndarray, np.ndarray]:
    """The shared texture (the template's atlas) resampled into the artist's UV layout.

    For every texel centre of a (size, size) image (row 0 at the top) inside one of the artist's UV triangles
    (``gpja.render.uv_raster.rasterize_uv``, the texture fusion's texel rasteriser): its 3-D point on the artist mesh,
    that point's closest template point and its template texture coordinate (:func:`template_uv_of_points`),
    where ``texture`` is sampled bilinearly (:func:`sample_texture_np`: the renderer's convention, so the artist
    mesh rendered with the result shows what the template rendered with ``texture`` shows). Texels outside every
    chart are filled by ``padding`` rounds of dilation from the covered ones (:func:`dilate`), so bilinear
    lookups at a chart's border read no background; the rest stays 0.

    The texture is resampled once through the artist mesh as given, so in every expression a texel shows the
    template point it shows here: the carried meshes move the artist's vertices, not its texture.

    Args:
        artist: V (n, 3) float64 mm, F, UV (k, 2), F_uv: the layout to fill.
        template: V (n_t, 3) float64 mm, F, UV (k_t, 2), F_uv: the atlas ``texture`` belongs to.
        texture: (T, T, 3) float in [0, 1], row 0 at the top (the shared texture).
        size: side of the result, texels.
        padding: rings of gutter texels filled around the charts.
    Returns:
        texture: (size, size, 3) float32 in [0, 1].
        covered: (size, size) bool, the texel centre is inside one of the artist's UV triangles.
    """
    if not artist.has_uv:
        raise ValueError("the artist mesh has no texture coordinates")
    texture = np.asarray(texture, dtype=np.float32)
    if texture.ndim != 3 or texture.shape[2] != 3:
        raise ValueError(f"texture must be (T, T, 3), got {texture.shape}")
    if size < 1 or padding < 0:
        raise ValueError(f"size must be positive and padding non-negative, got {size} and {padding}")
    texels = rasterize_uv(artist.UV, artist.F_uv, size)  # every texel centre inside an artist UV triangle
    points = texels.surface(artist.V, artist.F)  # (N, 3) mm on the artist mesh
    values = texels.scatter(sample_texture_np(texture, template_uv_of_points(template, points)), fill=0.0)
    covered = texels.face_image != BACKGROUND
    return dilate(values, covered, padding), covered


# --- quality --------------------------------------------------------------------------------------------

def flipped_faces(V_a: np.ndarray, V_b: np.ndarray, F: np.ndarray) -> int:
    """The number of faces whose normal turns by more than 90 degrees from one mesh to another.

    Args:
        V_a, V_b: (n, 3) float64 positions (mm) of two meshes of one topology (e.g. adjacent expressions).
        F: (m, 3) int faces, shared.
    Returns:
        Faces with ``n_a . n_b < 0`` (``gpja.folds.turned_faces``); a face degenerate in either mesh counts as not
        flipped.
    """
    V_a, V_b = np.asarray(V_a, dtype=np.float64), np.asarray(V_b, dtype=np.float64)
    if V_a.shape != V_b.shape:
        raise ValueError(f"the meshes have {V_a.shape} and {V_b.shape} vertices")
    return int(turned_faces(V_b, V_a, np.asarray(F, dtype=np.int64)).sum())
