"""The applications' workflow steps on files: what ``gpja triangulate|remesh|export|animate`` do.

Each step reads the meshes a registration wrote (OBJ sharing the template's texture), checks them, calls the
array functions of :mod:`gpja.apply`, and writes its outputs atomically with a JSON log beside the main one.
"""
from __future__ import annotations

import os
import time
from pathlib import Path
from typing import Callable, Mapping

import numpy as np

from gpja.apply.settings import AnimationSettings, RemeshSettings, ReparamSettings
from gpja.errors import InputError
from gpja.io import write_json, write_npz
from gpja.mesh import TexturedMesh, read_obj, write_obj

#: Samples per surface of the deviation check between a remeshed expression and its source.
DEVIATION_SAMPLES = 200000
#: Side of the frontal render that compares a remeshed expression with its source (px).
CHECK_RENDER_SIZE = 512


def read_uv_mesh(path: str | Path) -> TexturedMesh:
    """A mesh with texture coordinates (the template's parametrisation), checked; no texture image."""
    mesh = read_obj(path, load_texture=False)
    mesh.validate(path)
    if not mesh.has_uv:
        raise InputError(path, "the mesh has no texture coordinates: the applications need the template's UVs")
    return mesh


def texture_ref(template_dir: str | Path, output: str | Path) -> str:
    """The shared texture's path relative to ``output``'s folder (what an MTL beside it names)."""
    return os.path.relpath(Path(template_dir) / "texture.png", Path(output).parent)


def triangulate(template_dir: str | Path, meshes: Mapping[str, str | Path], settings: RemeshSettings,
                output: str | Path, progress: Callable[[str], None] = print) -> dict:
    """The subject's common triangulation (``results/.../remeshed/common.obj``) fitted to its expressions.

    Args:
        template_dir: the subject's template folder (its ``template.obj`` is refined).
        meshes: expression -> registered mesh (OBJ with the template's UVs); the template's own expression may
            name ``template.obj``.
    Returns:
        The log written beside ``output`` (.json).
    """
    from gpja.apply.remesh import common_triangulation, fit_triangulation

    start = time.perf_counter()
    template = read_uv_mesh(Path(template_dir) / "template.obj")
    sources = {name: read_uv_mesh(path) for name, path in meshes.items()}
    common = common_triangulation(template, max(settings.initial_vertices, len(template.V)))
    progress(f"triangulate: template {len(template.V)} vertices refined to {len(common.V)}; fitting "
             f"{len(sources)} expressions to {settings.tolerance_mm:g} mm")
    rounds: list[str] = []

    def record(line: str) -> None:
        rounds.append(line)
        progress(f"triangulate: {line}")

    # the template itself needs no fitting: the common triangulation refines it, so its chords lie on it
    fitted = {str(meshes[k]): m for k, m in sources.items()
              if not (m.F.shape == template.F.shape and np.array_equal(m.F, template.F)
                      and np.array_equal(m.V, template.V))}
    common = fit_triangulation(common, fitted, settings.tolerance_mm, settings.max_vertices,
                               settings.max_rounds, progress=record,
                               tangential_tolerance_mm=settings.tangential_tolerance_mm,
                               face_samples=settings.face_samples)
    write_obj(output, common, texture_name=texture_ref(template_dir, output))
    log = {"template": str(Path(template_dir) / "template.obj"), "expressions": {k: str(v) for k, v in meshes.items()},
           "vertices": len(common.V), "faces": len(common.F), "texture_coordinates": len(common.UV),
           "settings": settings.__dict__, "rounds": rounds, "seconds": round(time.perf_counter() - start, 2)}
    write_json(Path(output).with_suffix(".json"), log)
    return log


def surface_deviation(a: TexturedMesh, b: TexturedMesh, samples: int = DEVIATION_SAMPLES, seed: int = 0) -> dict:
    """Distances (mm) from ``samples`` area-uniform points of each surface to the other: max (the two one-sided
    Hausdorff distances, as sampled), 99th percentile and mean."""
    from gpja.metrics.geometry import sample_surface
    from gpja.surface import prepare_surface

    out = {}
    for name, (p, q) in {"to_source": (a, b), "from_source": (b, a)}.items():
        points, _ = sample_surface(p.V, p.F, samples, seed)
        d = prepare_surface(q.V, q.F, find_boundary=False).closest(points).distance
        out[name] = {"max_mm": float(d.max()), "p99_mm": float(np.percentile(d, 99)), "mean_mm": float(d.mean())}
    return out


def render_agreement(a: TexturedMesh, b: TexturedMesh, texture: np.ndarray, sh: np.ndarray) -> dict:
    """PSNR (dB) over the head between frontal renders of two meshes with one texture and lighting."""
    from gpja.camera import framing_camera
    from gpja.metrics.photometric import masked_psnr, render_with_texture

    camera = framing_camera(b.V, CHECK_RENDER_SIZE)
    images = [render_with_texture(m, texture, [camera], sh)[0] for m in (a, b)]
    head = (images[0].sum(-1) > 0) | (images[1].sum(-1) > 0)
    psnr = float(masked_psnr(images[0], images[1], head))
    # identical renders: +inf dB, which JSON cannot hold
    return {"psnr_db": round(psnr, 3) if np.isfinite(psnr) else None, "identical": not np.isfinite(psnr),
            "pixels": int(head.sum()),
            "size_px": CHECK_RENDER_SIZE}


def remesh(common_path: str | Path, mesh_path: str | Path, template_dir: str | Path, expression: str,
           output: str | Path, progress: Callable[[str], None] = print) -> dict:
    """One expression on the common triangulation (OBJ naming the shared texture), with its checks in the log:
    the seam agreement, the deviation from the source surface both ways, and the PSNR of the two renders."""
    from gpja.apply.remesh import remesh_onto
    from gpja.io import read_image
    from gpja.results import read_template_lighting

    start = time.perf_counter()
    common = read_uv_mesh(common_path)
    source = read_uv_mesh(mesh_path)
    result = remesh_onto(common, source, mesh_path)
    texture = read_image(Path(template_dir) / "texture.png")
    deviation = surface_deviation(result.mesh, source)
    agreement = render_agreement(result.mesh, source, texture, read_template_lighting(template_dir))
    write_obj(output, result.mesh, texture_name=texture_ref(template_dir, output))
    log = {"expression": expression, "source": str(mesh_path), "common": str(common_path),
           "vertices": len(result.mesh.V), "source_vertices": len(source.V),
           "seam_disagreement_mm": result.seam_disagreement_mm, "off_atlas_uv": result.off_atlas_uv,
           "deviation": deviation, "render": agreement, "seconds": round(time.perf_counter() - start, 2)}
    write_json(Path(output).with_suffix(".json"), log)
    progress(f"remesh: {expression}: {len(source.V)} -> {len(result.mesh.V)} vertices; deviation max "
             f"{deviation['to_source']['max_mm']:.3f} / {deviation['from_source']['max_mm']:.3f} mm (to / from the "
             f"source), p99 {deviation['to_source']['p99_mm']:.4f} mm; render PSNR "
             f"{'identical' if agreement['identical'] else format(agreement['psnr_db'], '.1f') + ' dB'}")
    return log


def read_remeshed(paths: Mapping[str, str | Path]) -> dict[str, TexturedMesh]:
    """Remeshed expressions by name; they must share F, UV and F_uv bit for bit (one common triangulation)."""
    meshes = {name: read_uv_mesh(path) for name, path in paths.items()}
    if not meshes:
        raise InputError("remeshed", "no remeshed expressions given")
    first_name, first = next(iter(meshes.items()))
    for name, mesh in meshes.items():
        same = (mesh.F.shape == first.F.shape and np.array_equal(mesh.F, first.F) and mesh.UV.shape == first.UV.shape
                and np.array_equal(mesh.UV, first.UV) and np.array_equal(mesh.F_uv, first.F_uv))
        if not same:
            raise InputError(paths[name], f"not on the same triangulation as {paths[first_name]} (F, UV or F_uv "
                                          "differ): remesh both onto one common triangulation")
    return meshes


def export(paths: Mapping[str, str | Path], base: str, template_dir: str | Path, output: str | Path,
           subject: str) -> Path:
    """The remeshed expressions as one glTF binary: ``base`` is the mesh, the others its morph targets."""
    from gpja.apply.export import write_blendshapes_glb
    from gpja.io import read_image

    if base not in paths:
        raise InputError("applications.export.base", f"the base expression {base!r} is not among the remeshed "
                                                     f"expressions ({', '.join(paths)})")
    meshes = read_remeshed(paths)
    texture = read_image(Path(template_dir) / "texture.png")
    targets = {name: mesh.V for name, mesh in meshes.items() if name != base}
    return write_blendshapes_glb(output, meshes[base], targets, texture, base_name=base, mesh_name=subject)


def animate(paths: Mapping[str, str | Path], settings: AnimationSettings, template_dir: str | Path,
            output: str | Path, frames_output: str | Path, progress: bool = True) -> Path:
    """Render the interpolation through ``settings.sequence`` from each of ``settings.yaw_deg``'s cameras, views
    side by side, as a video (``output``; a GIF beside it when no ffmpeg is found), and keep
    ``settings.strip_frames`` evenly spaced frames with their labels in ``frames_output`` (.npz) for the
    film-strip figure."""
    from gpja.apply.animate import render_frames, sequence_positions, tile_views, write_video
    from gpja.camera import framing_camera
    from gpja.io import read_image
    from gpja.results import read_template_lighting

    if Path(output).suffix.lower() != ".mp4":
        raise InputError(output, "a video is written as MP4: the file name must end in .mp4")
    missing = [name for name in dict.fromkeys(settings.sequence) if name not in paths]
    if missing:
        raise InputError("applications.animation.sequence", f"expression(s) {', '.join(missing)} of the sequence have "
                                                            f"no remeshed mesh (given: {', '.join(paths) or 'none'})")
    meshes = read_remeshed({name: paths[name] for name in dict.fromkeys(settings.sequence)})
    frames, labels = sequence_positions({k: m.V for k, m in meshes.items()}, settings.sequence,
                                        settings.frames_per_transition, "applications.animation.sequence")
    first = next(iter(meshes.values()))
    extent = np.concatenate([m.V for m in meshes.values()])
    cameras = [framing_camera(extent, settings.size, yaw_deg=yaw, name=f"yaw{yaw:g}") for yaw in settings.yaw_deg]
    texture = read_image(Path(template_dir) / "texture.png")
    views = render_frames(frames, first.F, first.UV, first.F_uv, texture, cameras,
                          read_template_lighting(template_dir), progress=progress)
    tiled = tile_views(views)
    keep = np.unique(np.round(np.linspace(0, len(tiled) - 1, settings.strip_frames)).astype(int))
    written = write_video(tiled, output, fps=settings.fps)
    write_npz(frames_output, frames=(np.clip(tiled[keep], 0, 1) * 255 + 0.5).astype(np.uint8), index=keep,
              labels=np.array([f"{labels[i][0]} -> {labels[i][1]}, t = {labels[i][2]:.2f}" for i in keep]),
              fps=np.array(settings.fps), count=np.array(len(tiled)))
    return written


def artist_mesh(template_dir: str | Path, settings: ReparamSettings, subject: str, output: str | Path,
                progress: Callable[[str], None] = print) -> dict:
    """The artist mesh of a subject (``settings.artist_mesh`` with ``{subject}`` filled, checked; or the stand-in)
    in ``output`` (.obj), with the shared texture resampled into its UV layout as ``texture.png`` beside it."""
    from gpja.apply.reparam import check_artist_mesh, make_standin_artist_mesh, resample_texture
    from gpja.io import read_image

    start = time.perf_counter()
    template = read_uv_mesh(Path(template_dir) / "template.obj")
    if settings.artist_mesh:
        source = Path(settings.artist_mesh.replace("{subject}", subject))
        artist = read_obj(source, load_texture=False)
        check_artist_mesh(artist, template, source)
        origin = str(source)
    else:
        artist = make_standin_artist_mesh(template, settings.standin_faces)
        origin = f"stand-in: the template decimated to {settings.standin_faces} faces, unwrapped by xatlas"
    progress(f"reparam: artist mesh {len(artist.V)} vertices, {len(artist.F)} faces ({origin}); resampling the "
             f"shared texture at {settings.texture_size} px")
    texture, covered = resample_texture(artist, template, read_image(Path(template_dir) / "texture.png"),
                                        settings.texture_size)
    write_obj(output, TexturedMesh(artist.V, artist.F, artist.UV, artist.F_uv, texture), texture_name="texture.png")
    log = {"artist_mesh": origin, "vertices": len(artist.V), "faces": len(artist.F),
           "texture_size": settings.texture_size, "covered_texels": round(float(covered.mean()), 4),
           "seconds": round(time.perf_counter() - start, 2)}
    write_json(Path(output).with_suffix(".json"), log)
    return log


def observed_faces(template_dir: str | Path, template: TexturedMesh, points: np.ndarray) -> np.ndarray:
    """(q,) bool: whether the template texel at each point's closest template point was seen by some camera of
    the template expression (``texture_observed.png``). ``points``: (q, 3) float64 mm, e.g. face centroids of a
    mesh in the template expression's frame (a centroid, not its vertices' texture coordinates averaged: a face
    may straddle a seam)."""
    from gpja.apply.reparam import template_uv_of_points
    from gpja.io import read_image
    from gpja.results import OBSERVED_TEXELS_FILE

    mask = read_image(Path(template_dir) / OBSERVED_TEXELS_FILE, mode="L") > 0.5
    height, width = mask.shape
    uv = template_uv_of_points(template, points)
    col = np.clip((uv[:, 0] * width).astype(int), 0, width - 1)
    row = np.clip(((1.0 - uv[:, 1]) * height).astype(int), 0, height - 1)
    return mask[row, col]


def reparametrize(artist_path: str | Path, mesh_path: str | Path, template_dir: str | Path, expression: str,
                  output: str | Path, settings: ReparamSettings | None = None,
                  progress: Callable[[str], None] = print) -> dict:
    """The artist mesh carried onto one expression's registered mesh (its faces, UVs and texture kept), with its
    checks in the log: distance to the expression's surface, triangles flipped against the artist mesh as
    modelled, and the PSNR of its render (artist texture) against the registered mesh's (shared texture), under
    white light (the texture's check) and under the estimated lighting. ``settings``: ``untangle_iterations`` and
    ``untangle_rings`` (None = the defaults): the folds the map leaves are smoothed out along the surface
    (``gpja.folds.untangle_on_surface``), and the log has the counts before and after."""
    from gpja.apply.reparam import artist_on_template, carry_to_expression, flipped_faces
    from gpja.camera import framing_camera
    from gpja.folds import untangle_on_surface
    from gpja.io import read_image
    from gpja.lighting import uniform_sh
    from gpja.metrics.photometric import masked_psnr, render_with_texture
    from gpja.results import read_template_lighting
    from gpja.surface import prepare_surface

    start = time.perf_counter()
    template = read_uv_mesh(Path(template_dir) / "template.obj")
    artist = read_obj(artist_path)
    if not artist.has_uv or artist.texture is None:
        raise InputError(artist_path, "the artist mesh needs texture coordinates and its texture (gpja reparam)")
    source = read_uv_mesh(mesh_path)
    template_uv = artist_on_template(artist, template)
    settings = ReparamSettings() if settings is None else settings
    carried = carry_to_expression(artist, template_uv, source, mesh_path)
    surface = prepare_surface(source.V, source.F, find_boundary=False)
    flipped_mapped = flipped_faces(artist.V, carried.V, artist.F)
    V, untangle = untangle_on_surface(carried.V, carried.F, surface, settings.untangle_iterations,
                                      settings.untangle_rings)
    carried = carried.with_vertices(V)
    distance = surface.closest(carried.V).distance
    flipped = flipped_faces(artist.V, carried.V, artist.F)
    # the same count over the faces whose template texel some camera saw (not the socket, not under the chin)
    observed = observed_faces(template_dir, template, artist.V[artist.F].mean(axis=1))
    flipped_observed = flipped_faces(artist.V, carried.V, artist.F[observed])
    shared = read_image(Path(template_dir) / "texture.png")
    camera = framing_camera(source.V, CHECK_RENDER_SIZE)
    # the texture's check under uniform white light (the albedo as rendered), and the same under the estimated
    # lighting, where the coarser artist surface also shades differently
    psnr = {}
    for name, sh in (("psnr_db", uniform_sh(1.0)), ("lit_psnr_db", read_template_lighting(template_dir))):
        ours = render_with_texture(carried, artist.texture, [camera], sh)[0]
        theirs = render_with_texture(source, shared, [camera], sh)[0]
        head = (ours.sum(-1) > 0) & (theirs.sum(-1) > 0)
        psnr[name] = round(float(masked_psnr(ours, theirs, head)), 3)
    write_obj(output, TexturedMesh(carried.V, carried.F, carried.UV, carried.F_uv),
              texture_name=os.path.relpath(Path(artist_path).parent / "texture.png", Path(output).parent))
    log = {"expression": expression, "source": str(mesh_path), "artist_mesh": str(artist_path),
           "vertices": len(carried.V), "distance_to_source_mm": {"max": float(distance.max()),
                                                                 "median": float(np.median(distance))},
           "flipped_faces_against_artist": int(flipped), "flipped_observed_faces": int(flipped_observed),
           "flipped_faces_before_untangle": int(flipped_mapped), "untangle": untangle,
           "observed_faces": int(observed.sum()),
           "render": {**psnr, "pixels": int(head.sum()), "size_px": CHECK_RENDER_SIZE},
           "seconds": round(time.perf_counter() - start, 2)}
    write_json(Path(output).with_suffix(".json"), log)
    progress(f"reparametrize: {expression}: {len(carried.V)} vertices, max {distance.max():.2e} mm off the "
             f"registered surface, {flipped} faces flipped against the artist mesh ({flipped_observed} of "
             f"the {int(observed.sum())} on observed texels; {flipped_mapped} before untangling, folds "
             f"{untangle['folded_before']} -> {untangle['folded_after']} in {untangle['rounds']} rounds), "
             f"render PSNR {psnr['psnr_db']:.1f} dB (texture, white light), {psnr['lit_psnr_db']:.1f} dB "
             "(estimated lighting)")
    return log
