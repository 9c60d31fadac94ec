"""A subject's expressions as one glTF 2.0 binary (``.glb``) with morph targets (blendshapes).

The base expression (e.g. the neutral face) is the mesh; every other expression on the same
triangulation is a morph target of it, so Blender (shape keys), three.js, Unity or any glTF viewer
can blend between them. The texture is embedded as a PNG.

pygltflib writes the file because it writes glTF 2.0 morph targets (``primitive.targets``,
``mesh.weights``); trimesh's glTF exporter does not export them.

Conventions of the file (and how they differ from :class:`gpja.mesh.TexturedMesh`):

- Units: glTF's unit is the metre, so positions are written in metres (mm / 1000) as float32. Axes
  are written as given (glTF: +Y up, the asset's front towards +Z).
- Seams: glTF has one index per corner for every attribute, so each distinct (vertex, uv) pair of the
  corners becomes one glTF vertex (:func:`split_at_seams`). Both copies of a seam vertex carry the same
  position, normal and deltas, so the seam neither opens nor shows a crease when targets are blended.
- Morph targets store float32 position deltas in metres. They are computed in float64 against the
  float32 base actually written (``target - float64(float32(base))``), so base + delta reconstructs each
  target to float32 rounding of the delta alone, whatever the head's distance from the origin; a
  coordinate a target leaves unchanged gets a delta of exactly 0 (it reads back as the float32 base).
- Texture coordinates: glTF's origin is top-left, OBJ's bottom-left: ``TEXCOORD_0 = (u, 1 - v)``.
- Target names go to ``mesh.extras["targetNames"]`` (what Blender's and three.js's importers read for
  shape-key / morph names), the base expression's name to ``mesh.extras["base"]``; ``mesh.weights``
  are all 0 (the file shows the base).
- Normals: area-weighted vertex normals of the welded base mesh, copied to every split copy so seams
  shade smoothly. Targets carry no normals (viewers reuse or recompute them).
- Texture: an 8-bit PNG in the binary buffer; material pbrMetallicRoughness with it as
  baseColorTexture, metallic 0, roughness 1; sampler linear magnification, trilinear minification
  (LINEAR_MIPMAP_LINEAR, what Blender writes for "Linear"), clamp to edge.
- Layout: one binary buffer; indices uint32 (ELEMENT_ARRAY_BUFFER), each attribute and target in its
  own tightly packed, 4-byte aligned bufferView (ARRAY_BUFFER); POSITION min / max on the base and
  on every target accessor.
"""
from __future__ import annotations

import io
from pathlib import Path

import numpy as np
import pygltflib
from PIL import Image

from gpja.errors import InputError
from gpja.io import atomic_path, to_uint8
from gpja.mesh import TexturedMesh
from gpja.surface import vertex_normals

#: glTF's unit is the metre; gpja's is the millimetre.
MM_PER_METRE = 1000.0

_FLOAT = pygltflib.FLOAT  # 5126
_UINT = pygltflib.UNSIGNED_INT  # 5125
_ARRAY_BUFFER = pygltflib.ARRAY_BUFFER  # 34962
_ELEMENT_ARRAY_BUFFER = pygltflib.ELEMENT_ARRAY_BUFFER  # 34963
_ALIGN = 4


def split_at_seams(F: np.ndarray, F_uv: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One glTF vertex per distinct (position, texture coordinate) pair of the corners.

    Args:
        F: (m, 3) int corner indices into the welded positions V (n, 3).
        F_uv: (m, 3) int corner indices into the texture coordinates UV (k, 2).
    Returns:
        vertex_of: (s,) int64 index into V of every glTF vertex.
        uv_of: (s,) int64 index into UV of every glTF vertex.
        faces: (m, 3) int64 corner indices into the glTF vertices (same triangles, same winding).
        glTF vertices are numbered by first occurrence in corner order (face by face, corner by
        corner), so the result is deterministic; positions no face references get no glTF vertex.
    """
    F = np.asarray(F)
    F_uv = np.asarray(F_uv)
    if F.ndim != 2 or F.shape[1] != 3 or F.shape != F_uv.shape:
        raise ValueError(f"F {F.shape} and F_uv {F_uv.shape} must both be (m, 3)")
    vc = F.astype(np.int64).ravel()
    tc = F_uv.astype(np.int64).ravel()
    if vc.size == 0:
        empty = np.zeros(0, dtype=np.int64)
        return empty, empty.copy(), np.zeros((0, 3), dtype=np.int64)
    if vc.min() < 0 or tc.min() < 0:
        raise ValueError("negative corner indices")
    key = vc * (int(tc.max()) + 1) + tc  # one int64 per (vertex, uv) pair
    _, first, inverse = np.unique(key, return_index=True, return_inverse=True)
    order = np.argsort(first, kind="stable")  # unique pairs by first occurrence
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    corner = first[order]
    return vc[corner], tc[corner], rank[inverse.ravel()].reshape(-1, 3).astype(np.int64)


def write_blendshapes_glb(path: str | Path, base: TexturedMesh, targets: dict[str, np.ndarray],
                          texture: np.ndarray, base_name: str, mesh_name: str = "head") -> Path:
    """Write the base expression with the others as morph targets, textured, to one ``.glb``, atomically.

    Args:
        path: the ``.glb`` to write (parent folders are created; a failed write leaves no file).
        base: the base expression: V (n, 3) float64 positions in mm, F (m, 3) int64, UV (k, 2) float64
            texture coordinates in [0, 1] with origin bottom-left (OBJ), F_uv (m, 3) int64. Must have UVs.
        targets: expression name -> (n, 3) float64 positions in mm on base's F / UV / F_uv. The insertion
            order is the morph-target order. May be empty.
        texture: (H, W, 3) RGB, float in [0, 1] (clipped) or uint8; embedded as a lossless PNG (8 bit).
        base_name: the base expression's name (``mesh.extras["base"]``).
        mesh_name: the name of the glTF node and mesh.
    Returns:
        The path written.
    Raises:
        InputError (with ``path``): base without UVs, an empty mesh, NaN / inf positions, a target of
        another shape than ``base.V``, a texture that is not (H, W, 3) uint8 / finite float; the
        message names the expression.
    """
    path = Path(path)
    names = _check_inputs(path, base, targets, texture, base_name)

    vertex_of, uv_of, faces = split_at_seams(base.F, base.F_uv)
    # float64 in metres first; each float32 array written is rounded once from float64
    base_m = base.V[vertex_of] / MM_PER_METRE
    position = base_m.astype(np.float32)
    normal = vertex_normals(base.V, base.F)
    normal[np.linalg.norm(normal, axis=1) < 0.5] = (0.0, 0.0, 1.0)  # no face of non-zero area: glTF needs unit normals
    normal = normal[vertex_of].astype(np.float32)
    uv = base.UV[uv_of]
    texcoord = np.column_stack([uv[:, 0], 1.0 - uv[:, 1]]).astype(np.float32)
    written_base = position.astype(np.float64)
    deltas = []
    for name in names:
        V_t = np.asarray(targets[name], dtype=np.float64)[vertex_of]
        delta = np.where(V_t == base.V[vertex_of], 0.0, V_t / MM_PER_METRE - written_base)
        deltas.append(delta.astype(np.float32))

    builder = _GlbBuilder()
    i_indices = builder.accessor(faces.astype(np.uint32).ravel(), "SCALAR", _ELEMENT_ARRAY_BUFFER)
    i_position = builder.accessor(position, "VEC3", _ARRAY_BUFFER, bounds=True)
    i_normal = builder.accessor(normal, "VEC3", _ARRAY_BUFFER)
    i_texcoord = builder.accessor(texcoord, "VEC2", _ARRAY_BUFFER)
    i_targets = [builder.accessor(d, "VEC3", _ARRAY_BUFFER, bounds=True, name=n) for n, d in zip(names, deltas)]
    i_png = builder.view(_png_bytes(texture))

    gltf = pygltflib.GLTF2(
        asset=pygltflib.Asset(generator="gpja (pygltflib)", version="2.0"),
        scene=0,
        scenes=[pygltflib.Scene(nodes=[0])],
        nodes=[pygltflib.Node(name=mesh_name, mesh=0)],
        meshes=[pygltflib.Mesh(
            name=mesh_name,
            primitives=[pygltflib.Primitive(
                attributes=pygltflib.Attributes(POSITION=i_position, NORMAL=i_normal, TEXCOORD_0=i_texcoord),
                indices=i_indices, material=0, mode=pygltflib.TRIANGLES,
                targets=[pygltflib.Attributes(POSITION=i) for i in i_targets])],
            weights=[0.0] * len(names),
            extras={"targetNames": list(names), "base": base_name})],
        materials=[pygltflib.Material(
            name=f"{mesh_name}_texture",
            pbrMetallicRoughness=pygltflib.PbrMetallicRoughness(
                baseColorFactor=[1.0, 1.0, 1.0, 1.0], baseColorTexture=pygltflib.TextureInfo(index=0),
                metallicFactor=0.0, roughnessFactor=1.0))],
        textures=[pygltflib.Texture(sampler=0, source=0)],
        samplers=[pygltflib.Sampler(magFilter=pygltflib.LINEAR, minFilter=pygltflib.LINEAR_MIPMAP_LINEAR,
                                    wrapS=pygltflib.CLAMP_TO_EDGE, wrapT=pygltflib.CLAMP_TO_EDGE)],
        images=[pygltflib.Image(bufferView=i_png, mimeType="image/png", name="texture")],
        accessors=builder.accessors,
        bufferViews=builder.views,
        buffers=[pygltflib.Buffer(byteLength=len(builder.blob))],
    )
    gltf.set_binary_blob(bytes(builder.blob))
    data = b"".join(gltf.save_to_bytes())  # the whole file in memory: nothing is written if this fails
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)
    return path


def _check_inputs(path: Path, base: TexturedMesh, targets: dict[str, np.ndarray], texture: np.ndarray,
                  base_name: str) -> list[str]:
    """Raise :class:`InputError` naming the expression for unusable inputs; the target names, in order."""
    if not base.has_uv:
        raise InputError(path, f"base expression {base_name!r} has no texture coordinates (UV, F_uv)")
    if len(base.V) == 0 or len(base.F) == 0:
        raise InputError(path, f"base expression {base_name!r} is an empty mesh "
                               f"({len(base.V)} vertices, {len(base.F)} faces)")
    bad = ~np.isfinite(base.V).all(axis=1)
    if bad.any():
        raise InputError(path, f"base expression {base_name!r}: {int(bad.sum())} vertices have NaN or infinite "
                               f"coordinates (first: vertex {int(np.argmax(bad))})")
    try:  # index ranges, UV faces one to one, finite UVs
        base.validate(path)
    except InputError as err:
        raise InputError(path, f"base expression {base_name!r}: {err.problem}") from None
    names = list(targets)
    for name in names:
        if not isinstance(name, str) or not name:
            raise InputError(path, f"morph target name {name!r} is not a non-empty string")
        V_t = np.asarray(targets[name])
        if V_t.shape != base.V.shape:
            raise InputError(path, f"expression {name!r} has vertices of shape {V_t.shape}, "
                                   f"the base {base_name!r} has {base.V.shape}")
        if not np.issubdtype(V_t.dtype, np.number):
            raise InputError(path, f"expression {name!r}: vertices are {V_t.dtype}, not numbers")
        bad = ~np.isfinite(V_t).all(axis=1)
        if bad.any():
            raise InputError(path, f"expression {name!r}: {int(bad.sum())} vertices have NaN or infinite "
                                   f"coordinates (first: vertex {int(np.argmax(bad))})")
    tex = np.asarray(texture)
    if tex.ndim != 3 or tex.shape[2] != 3 or tex.shape[0] == 0 or tex.shape[1] == 0:
        raise InputError(path, f"texture has shape {tex.shape}, expected (H, W, 3) RGB")
    if tex.dtype != np.uint8:
        if not np.issubdtype(tex.dtype, np.floating):
            raise InputError(path, f"texture dtype {tex.dtype}: expected uint8 or float in [0, 1]")
        if not np.isfinite(tex).all():
            raise InputError(path, "texture contains NaN or infinite values")
    return names


def _png_bytes(texture: np.ndarray) -> bytes:
    """(H, W, 3) float [0, 1] or uint8 RGB as PNG file bytes (8 bit, lossless)."""
    out = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(to_uint8(texture))).save(out, format="PNG")
    return out.getvalue()


class _GlbBuilder:
    """One little-endian binary buffer, its bufferViews (each 4-byte aligned) and accessors."""

    def __init__(self) -> None:
        self.blob = bytearray()
        self.views: list[pygltflib.BufferView] = []
        self.accessors: list[pygltflib.Accessor] = []

    def view(self, data: bytes, target: int | None = None) -> int:
        """Append ``data`` as a new bufferView; its index."""
        self.blob += b"\0" * (-len(self.blob) % _ALIGN)
        self.views.append(pygltflib.BufferView(buffer=0, byteOffset=len(self.blob), byteLength=len(data),
                                               target=target))
        self.blob += data
        self.blob += b"\0" * (-len(self.blob) % _ALIGN)
        return len(self.views) - 1

    def accessor(self, array: np.ndarray, kind: str, target: int, bounds: bool = False,
                 name: str | None = None) -> int:
        """Append a float32 (VEC2 / VEC3) or uint32 (SCALAR) array as a tightly packed accessor; its index."""
        little = array.astype(array.dtype.newbyteorder("<"), copy=False)
        component = {np.dtype(np.float32): _FLOAT, np.dtype(np.uint32): _UINT}[array.dtype]
        acc = pygltflib.Accessor(bufferView=self.view(np.ascontiguousarray(little).tobytes(), target),
                                 byteOffset=0, componentType=component, count=int(len(array)), type=kind,
                                 name=name)
        if bounds:  # the exact float32 extremes, as the spec's validator checks them
            acc.min = [float(x) for x in array.min(axis=0)]
            acc.max = [float(x) for x in array.max(axis=0)]
        self.accessors.append(acc)
        return len(self.accessors) - 1
