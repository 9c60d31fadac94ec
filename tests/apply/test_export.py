"""glTF 2.0 blendshape export (gpja/apply/export.py), read back by a reader written here.

The reader below parses the GLB with struct + json + numpy only (no pygltflib), so the file is checked
against the spec's layout rather than against the library that wrote it; trimesh is a second reader.
"""
import io
import json
import struct
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from gpja.apply.export import split_at_seams, write_blendshapes_glb
from gpja.errors import InputError
from gpja.io import to_uint8
from gpja.mesh import TexturedMesh
from tests.apply.spheres import latlong_sphere
from tests.tolerances import EXACT_F64, UINT8_STEP

#: Expressions recovered from the file (float32 metres: base + delta in float64, times 1000), mm: the deltas
#: are taken against the float32 base written, so only the float32 rounding of a delta (<= ~4e-6 mm for
#: deltas under 0.13 m) is left.
GLB_ROUNDTRIP_MM = 1e-5
#: The base of a head 0.9 m from the origin: float32 metres there have a half-ulp of 6e-5 mm.
FAR_BASE_F32_MM = 1e-4
#: float32 texture coordinates in [0, 1] (half an ulp below 1 is 3e-8), UV units.
UV_F32 = 1e-7
#: float32 unit normals: |n| - 1 and the area-weighted normal of a fine-ish sphere vs its radius (1 - cos).
NORMAL_UNIT_F32 = 1e-6
SPHERE_NORMAL_VS_RADIAL = 0.02
#: trimesh's bounds of the base vs ours, metres (float32 of ~1 m coordinates: ulp 6e-8 m).
TRIMESH_BOUNDS_M = 1e-6

CENTRE = np.array([10.0, 20.0, 30.0])  # mm: every coordinate under 0.25 m, where float32 metres keep 1e-5 mm
FAR_CENTRE = np.array([30.0, -250.0, 900.0])  # mm: where float32 metres keep only ~6e-5 mm
RADIUS = 100.0
N_LAT, N_LON = 6, 8  # rings between the poles, segments around


def seamed_sphere(centre: np.ndarray = CENTRE) -> TexturedMesh:
    """A lat-long sphere (y up) of radius 100 mm: 50 welded positions, 96 faces, 70 UVs.

    Its UV atlas has a seam: the column u = 1 repeats the positions of u = 0, and each pole has one UV
    per segment (u at the segment's middle), so the split has exactly N_LAT * (N_LON + 1) + 2 * N_LON = 70
    glTF vertices.
    """
    return latlong_sphere(N_LAT, N_LON, RADIUS, centre)


def expressions(base: TexturedMesh, centre: np.ndarray = CENTRE) -> dict[str, np.ndarray]:
    """Known maps of the base as morph targets, in a non-sorted order ("2_" sorts after "13_")."""
    upper = base.V[:, 1] > centre[1]
    raised = base.V.copy()
    raised[upper, 1] += 7.25  # only the upper half moves: the rest keeps delta 0 exactly
    return {
        "2_smile": centre + (base.V - centre) * np.array([1.1, 0.9, 1.05]),  # anisotropic scaling
        "13_lip_funneler": base.V + np.array([5.0, -3.0, 12.0]),  # translation
        "4_anger": raised,
    }


def texture_u8(size: int = 16) -> np.ndarray:
    return np.random.default_rng(0).integers(0, 256, size=(size, size, 3), dtype=np.uint8)


# --- an independent GLB reader (struct + json + numpy) ---------------------------------------------------

_COMPONENT = {5120: "i1", 5121: "u1", 5122: "<i2", 5123: "<u2", 5125: "<u4", 5126: "<f4"}
_WIDTH = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4}


def read_glb(path: Path) -> tuple[dict, bytes]:
    """The JSON document and the BIN chunk of a GLB, with the container's layout checked."""
    data = path.read_bytes()
    magic, version, length = struct.unpack_from("<4sII", data, 0)
    assert (magic, version, length) == (b"glTF", 2, len(data))
    json_len, json_type = struct.unpack_from("<I4s", data, 12)
    assert json_type == b"JSON" and json_len % 4 == 0
    doc = json.loads(data[20 : 20 + json_len].decode("utf-8"))
    offset = 20 + json_len
    bin_len, bin_type = struct.unpack_from("<I4s", data, offset)
    assert bin_type == b"BIN\0" and bin_len % 4 == 0 and offset + 8 + bin_len == len(data)
    assert len(doc["buffers"]) == 1 and "uri" not in doc["buffers"][0]
    assert doc["buffers"][0]["byteLength"] <= bin_len
    return doc, data[offset + 8 : offset + 8 + bin_len]


def read_view(doc: dict, blob: bytes, index: int) -> bytes:
    view = doc["bufferViews"][index]
    start = view.get("byteOffset", 0)
    assert view["buffer"] == 0 and start + view["byteLength"] <= doc["buffers"][0]["byteLength"]
    return blob[start : start + view["byteLength"]]


def read_accessor(doc: dict, blob: bytes, index: int) -> np.ndarray:
    """An accessor as a (count, width) array (count,) for SCALAR, honouring byteOffset and byteStride."""
    acc = doc["accessors"][index]
    view = doc["bufferViews"][acc["bufferView"]]
    dtype = np.dtype(_COMPONENT[acc["componentType"]])
    width = _WIDTH[acc["type"]]
    element = dtype.itemsize * width
    stride = view.get("byteStride", element)
    start = view.get("byteOffset", 0) + acc.get("byteOffset", 0)
    assert start % dtype.itemsize == 0 and stride % dtype.itemsize == 0  # the spec's alignment rules
    count = acc["count"]
    assert acc.get("byteOffset", 0) + stride * (count - 1) + element <= view["byteLength"]
    out = np.ndarray((count, width), dtype=dtype, buffer=blob, offset=start, strides=(stride, dtype.itemsize))
    out = out.astype(dtype.newbyteorder("="))
    return out[:, 0] if acc["type"] == "SCALAR" else out


def decode(path: Path) -> dict:
    """Everything the tests check, from the file alone, in gpja's units (mm, OBJ UVs)."""
    doc, blob = read_glb(path)
    (mesh,) = doc["meshes"]
    (prim,) = mesh["primitives"]
    assert prim.get("mode", 4) == 4  # triangles
    attrs = prim["attributes"]
    position = read_accessor(doc, blob, attrs["POSITION"])
    assert position.dtype == np.float32
    base_m = position.astype(np.float64)
    texcoord = read_accessor(doc, blob, attrs["TEXCOORD_0"]).astype(np.float64)
    targets = {}
    names = mesh.get("extras", {}).get("targetNames", [])  # absent (as an empty list would be) without targets
    for name, target in zip(names, prim.get("targets", []), strict=True):
        delta = read_accessor(doc, blob, target["POSITION"])
        assert delta.dtype == np.float32
        targets[name] = (base_m + delta.astype(np.float64)) * 1000.0
    image = doc["images"][doc["textures"][0]["source"]]
    assert image["mimeType"] == "image/png"
    png = read_view(doc, blob, image["bufferView"])
    return {
        "doc": doc,
        "blob": blob,
        "faces": read_accessor(doc, blob, prim["indices"]).reshape(-1, 3),
        "V": base_m * 1000.0,
        "normal": read_accessor(doc, blob, attrs["NORMAL"]).astype(np.float64),
        "UV": np.column_stack([texcoord[:, 0], 1.0 - texcoord[:, 1]]),
        "targets": targets,
        "texture": np.asarray(Image.open(io.BytesIO(png)).convert("RGB")),
    }


@pytest.fixture
def written(tmp_path):
    base = seamed_sphere()
    targets = expressions(base)
    tex = texture_u8()
    path = write_blendshapes_glb(tmp_path / "out" / "7" / "blendshapes.glb", base, targets, tex, "1_neutral")
    return path, base, targets, tex


# --- split_at_seams ---------------------------------------------------------------------------------------

def test_split_at_seams_two_triangles():
    F = np.array([[0, 1, 2], [2, 1, 3]])
    # shared UVs: no split, the faces are F itself
    vertex_of, uv_of, faces = split_at_seams(F, np.array([[0, 1, 2], [2, 1, 3]]))
    np.testing.assert_array_equal(vertex_of, [0, 1, 2, 3])
    np.testing.assert_array_equal(uv_of, [0, 1, 2, 3])
    np.testing.assert_array_equal(faces, F)
    # a seam along the shared edge 1-2: both of its ends split, numbered by first occurrence
    vertex_of, uv_of, faces = split_at_seams(F, np.array([[0, 1, 2], [3, 4, 5]]))
    np.testing.assert_array_equal(vertex_of, [0, 1, 2, 2, 1, 3])
    np.testing.assert_array_equal(uv_of, [0, 1, 2, 3, 4, 5])
    np.testing.assert_array_equal(faces, [[0, 1, 2], [3, 4, 5]])
    assert faces.dtype == vertex_of.dtype == uv_of.dtype == np.int64


def test_split_at_seams_sphere_counts_and_round_trip():
    mesh = seamed_sphere()
    n, m = len(mesh.V), len(mesh.F)
    vertex_of, uv_of, faces = split_at_seams(mesh.F, mesh.F_uv)
    assert n < len(vertex_of) < 3 * m
    assert len(vertex_of) == N_LAT * (N_LON + 1) + 2 * N_LON == len(mesh.UV)
    np.testing.assert_array_equal(vertex_of[faces], mesh.F)  # same triangles, same winding
    np.testing.assert_array_equal(uv_of[faces], mesh.F_uv)
    assert len({(v, t) for v, t in zip(vertex_of, uv_of)}) == len(vertex_of)  # each pair once
    np.testing.assert_array_equal(np.sort(np.unique(faces)), np.arange(len(vertex_of)))  # every one used
    # first occurrence in corner order: a vertex's first corner is never after a later vertex's
    first_corner = np.array([np.flatnonzero(faces.ravel() == s)[0] for s in range(len(vertex_of))])
    assert (np.diff(first_corner) > 0).all()
    again = split_at_seams(mesh.F.copy(), mesh.F_uv.copy())
    for a, b in zip(again, (vertex_of, uv_of, faces)):
        np.testing.assert_array_equal(a, b)


def test_sphere_is_outward_and_seamed():
    """The test mesh itself: counter-clockwise outward faces, a real seam."""
    mesh = seamed_sphere()
    centroids = mesh.V[mesh.F].mean(axis=1)
    assert ((mesh.face_normals() * (centroids - CENTRE)).sum(axis=1) > 0).all()
    assert len(mesh.V) == 2 + N_LAT * N_LON and len(mesh.F) == 2 * N_LON * N_LAT
    assert len(mesh.UV) > len(mesh.V)


# --- the file, read back independently --------------------------------------------------------------------

def test_every_expression_round_trips_through_the_file(written):
    path, base, targets, tex = written
    got = decode(path)
    vertex_of, uv_of, faces = split_at_seams(base.F, base.F_uv)
    np.testing.assert_array_equal(got["faces"], faces)
    np.testing.assert_array_equal(vertex_of[got["faces"]], base.F)
    assert list(got["targets"]) == list(targets) == ["2_smile", "13_lip_funneler", "4_anger"]
    assert np.abs(got["V"] - base.V[vertex_of]).max() <= GLB_ROUNDTRIP_MM
    for name, V in targets.items():
        moved = V[vertex_of] != base.V[vertex_of]  # per coordinate
        assert np.abs(got["targets"][name] - V[vertex_of])[moved].max() <= GLB_ROUNDTRIP_MM, name
        # a coordinate the target keeps has delta 0: it is the base as written
        np.testing.assert_array_equal(got["targets"][name][~moved], got["V"][~moved])
    assert np.abs(got["UV"] - base.UV[uv_of]).max() <= UV_F32
    np.testing.assert_array_equal(got["texture"], tex)  # PNG: lossless, uint8-exact


def test_seam_copies_share_position_normal_and_deltas(written):
    path, base, targets, _ = written
    got = decode(path)
    vertex_of, uv_of, _ = split_at_seams(base.F, base.F_uv)
    assert len(base.V) < len(vertex_of) < 3 * len(base.F)
    seam = 0
    for v in range(len(base.V)):
        copies = np.flatnonzero(vertex_of == v)
        seam += len(copies) > 1
        for arr in (got["V"], got["normal"], *got["targets"].values()):
            assert (arr[copies] == arr[copies[0]]).all()  # bit-identical: the seam never opens
        assert len(np.unique(uv_of[copies])) == len(copies)  # but their texture coordinates differ
    assert seam == N_LAT + 2  # one seam column plus both poles
    # the column u = 0 and u = 1 of ring 3: same positions, UVs 1 apart
    ring3 = [np.flatnonzero((uv_of == 3 * (N_LON + 1) + j))[0] for j in (0, N_LON)]
    np.testing.assert_array_equal(got["V"][ring3[0]], got["V"][ring3[1]])
    np.testing.assert_allclose(got["UV"][ring3[1], 0] - got["UV"][ring3[0], 0], 1.0, atol=UV_F32)


def test_normals_are_unit_area_weighted_and_radial(written):
    path, base, _, _ = written
    got = decode(path)
    n = got["normal"]
    assert np.abs(np.linalg.norm(n, axis=1) - 1).max() <= NORMAL_UNIT_F32
    radial = got["V"] - CENTRE
    radial /= np.linalg.norm(radial, axis=1, keepdims=True)
    assert (1 - (n * radial).sum(axis=1)).max() <= SPHERE_NORMAL_VS_RADIAL  # outward, smooth
    # the poles: by symmetry their area-weighted normal is exactly the axis
    vertex_of, _, _ = split_at_seams(base.F, base.F_uv)
    np.testing.assert_allclose(n[vertex_of == 0], np.tile([0, 1, 0], ((vertex_of == 0).sum(), 1)), atol=NORMAL_UNIT_F32)


def test_a_coordinate_a_target_keeps_has_delta_zero(written):
    path, base, _, _ = written
    doc, blob = read_glb(path)
    prim = doc["meshes"][0]["primitives"][0]
    vertex_of, _, _ = split_at_seams(base.F, base.F_uv)
    delta = read_accessor(doc, blob, prim["targets"][2]["POSITION"])  # "4_anger": upper half up 7.25 mm
    upper = base.V[vertex_of, 1] > CENTRE[1]
    assert (delta[~upper] == 0).all() and (delta[upper][:, [0, 2]] == 0).all()
    np.testing.assert_allclose(delta[upper][:, 1], 7.25e-3, rtol=1e-6)


def test_document_structure(written):
    path, base, targets, _ = written
    doc, blob = read_glb(path)
    assert doc["asset"]["version"] == "2.0"
    (node,) = doc["nodes"]
    (mesh,) = doc["meshes"]
    assert (node["name"], node["mesh"]) == ("head", 0)
    assert doc["scenes"][doc["scene"]]["nodes"] == [0]
    assert mesh["name"] == "head"
    assert mesh["extras"] == {"targetNames": list(targets), "base": "1_neutral"}
    assert mesh["weights"] == [0.0] * len(targets)
    prim = mesh["primitives"][0]
    assert set(prim["attributes"]) == {"POSITION", "NORMAL", "TEXCOORD_0"}
    assert [set(t) for t in prim["targets"]] == [{"POSITION"}] * len(targets)
    # accessor types, bufferView targets, alignment, exact min / max
    idx = doc["accessors"][prim["indices"]]
    assert (idx["componentType"], idx["type"]) == (5125, "SCALAR")
    assert doc["bufferViews"][idx["bufferView"]]["target"] == 34963
    for i in [*prim["attributes"].values(), *(t["POSITION"] for t in prim["targets"])]:
        acc = doc["accessors"][i]
        assert acc["componentType"] == 5126
        assert doc["bufferViews"][acc["bufferView"]]["target"] == 34962
    for i in [prim["attributes"]["POSITION"], *(t["POSITION"] for t in prim["targets"])]:
        acc, data = doc["accessors"][i], read_accessor(doc, blob, i)
        assert acc["min"] == data.min(axis=0).tolist() and acc["max"] == data.max(axis=0).tolist()
    assert all(v.get("byteOffset", 0) % 4 == 0 for v in doc["bufferViews"])
    image_view = doc["bufferViews"][doc["images"][0]["bufferView"]]
    assert "target" not in image_view and "byteStride" not in image_view
    # material and sampler
    (material,) = doc["materials"]
    pbr = material["pbrMetallicRoughness"]
    assert pbr["baseColorTexture"]["index"] == 0 and pbr["baseColorTexture"].get("texCoord", 0) == 0
    assert (pbr["metallicFactor"], pbr["roughnessFactor"]) == (0, 1)
    assert prim["material"] == 0
    sampler = doc["samplers"][doc["textures"][0]["sampler"]]
    assert sampler["magFilter"] == 9729 and sampler["minFilter"] in (9729, 9987)  # linear (trilinear)
    assert sampler["wrapS"] == sampler["wrapT"] == 33071  # clamp to edge


def test_float_texture_is_embedded_as_its_uint8_rounding(tmp_path):
    base = seamed_sphere()
    tex = np.random.default_rng(1).random((8, 8, 3)).astype(np.float32)
    path = write_blendshapes_glb(tmp_path / "b.glb", base, {}, tex, "1_neutral", mesh_name="subject_7")
    got = decode(path)
    np.testing.assert_array_equal(got["texture"], to_uint8(tex))
    assert np.abs(got["texture"] / 255.0 - tex).max() <= UINT8_STEP
    assert got["targets"] == {}
    doc = got["doc"]
    assert doc["nodes"][0]["name"] == doc["meshes"][0]["name"] == "subject_7"
    assert "targets" not in doc["meshes"][0]["primitives"][0]


def test_trimesh_reads_the_base(written):
    import trimesh

    path, base, _, _ = written
    scene = trimesh.load(path)
    (geom,) = scene.geometry.values()
    vertex_of, _, _ = split_at_seams(base.F, base.F_uv)
    assert len(geom.vertices) == len(vertex_of) and len(geom.faces) == len(base.F)
    expected = np.stack([base.V.min(axis=0), base.V.max(axis=0)]) / 1000.0  # metres
    np.testing.assert_allclose(geom.bounds, expected, atol=TRIMESH_BOUNDS_M)
    np.testing.assert_allclose(scene.bounds, expected, atol=TRIMESH_BOUNDS_M)
    assert geom.metadata.get("targetNames") == ["2_smile", "13_lip_funneler", "4_anger"]


# --- bad inputs ------------------------------------------------------------------------------------------

def _bad_cases():
    base = seamed_sphere()
    good = expressions(base)
    nan_base = TexturedMesh(base.V.copy(), base.F, base.UV, base.F_uv)
    nan_base.V[5, 1] = np.nan
    inf_target = dict(good, **{"13_lip_funneler": good["13_lip_funneler"].copy()})
    inf_target["13_lip_funneler"][9, 2] = np.inf
    empty = TexturedMesh(np.zeros((0, 3)), np.zeros((0, 3), dtype=int), np.zeros((0, 2)), np.zeros((0, 3), dtype=int))
    tex = texture_u8()
    return [
        ("no uv", TexturedMesh(base.V, base.F), good, tex, "'1_neutral' has no texture coordinates"),
        ("shape", base, dict(good, **{"2_smile": good["2_smile"][:-1]}), tex, r"'2_smile' has vertices of shape \(49, 3\)"),
        ("nan base", nan_base, good, tex, "'1_neutral': 1 vertices have NaN or infinite coordinates.*vertex 5"),
        ("inf target", base, inf_target, tex, "'13_lip_funneler': 1 vertices have NaN or infinite.*vertex 9"),
        ("empty", empty, {}, tex, "'1_neutral' is an empty mesh"),
        ("grey texture", base, good, tex[..., 0], r"texture has shape \(16, 16\)"),
        ("rgba texture", base, good, np.zeros((4, 4, 4)), r"texture has shape \(4, 4, 4\)"),
        ("nan texture", base, good, np.full((4, 4, 3), np.nan), "texture contains NaN"),
    ]


@pytest.mark.parametrize("case", _bad_cases(), ids=lambda c: c[0])
def test_bad_input_raises_naming_the_problem_and_writes_nothing(tmp_path, case):
    _, base, targets, tex, problem = case
    path = tmp_path / "out" / "blendshapes.glb"
    with pytest.raises(InputError, match=problem) as err:
        write_blendshapes_glb(path, base, targets, tex, "1_neutral")
    assert err.value.path == str(path)
    assert not path.exists()
    assert not any(tmp_path.rglob("*.glb*"))  # no temporary sibling either


def test_failed_write_leaves_no_file_and_keeps_the_old_one(tmp_path, monkeypatch):
    base = seamed_sphere()
    path = tmp_path / "blendshapes.glb"
    real_write_bytes = Path.write_bytes

    def disk_full(self, data):
        real_write_bytes(self, data[: len(data) // 2])
        raise OSError(28, "No space left on device")

    with monkeypatch.context() as m:
        m.setattr(Path, "write_bytes", disk_full)
        with pytest.raises(OSError, match="No space"):
            write_blendshapes_glb(path, base, expressions(base), texture_u8(), "1_neutral")
    assert list(tmp_path.iterdir()) == []  # neither the file nor a partial sibling
    write_blendshapes_glb(path, base, expressions(base), texture_u8(), "1_neutral")
    before = path.read_bytes()
    with monkeypatch.context() as m:
        m.setattr(Path, "write_bytes", disk_full)
        with pytest.raises(OSError):
            write_blendshapes_glb(path, base, {}, texture_u8(), "1_neutral")
    assert path.read_bytes() == before and list(tmp_path.iterdir()) == [path]


def test_output_is_deterministic(tmp_path):
    base = seamed_sphere()
    a = write_blendshapes_glb(tmp_path / "a.glb", base, expressions(base), texture_u8(), "1_neutral")
    b = write_blendshapes_glb(tmp_path / "b.glb", base, expressions(base), texture_u8(), "1_neutral")
    assert a.read_bytes() == b.read_bytes()
    assert np.abs(decode(a)["V"] - base.V[split_at_seams(base.F, base.F_uv)[0]]).max() > EXACT_F64  # float32 in file


def test_targets_far_from_the_origin_keep_their_precision(tmp_path):
    """Deltas are taken against the float32 base written, so a target is as exact as its delta's rounding."""
    base = seamed_sphere(FAR_CENTRE)
    targets = expressions(base, FAR_CENTRE)
    path = write_blendshapes_glb(tmp_path / "far.glb", base, targets, texture_u8(), "1_neutral")
    got = decode(path)
    vertex_of, _, _ = split_at_seams(base.F, base.F_uv)
    base_error = np.abs(got["V"] - base.V[vertex_of]).max()
    assert GLB_ROUNDTRIP_MM < base_error <= FAR_BASE_F32_MM  # the base itself: float32 metres
    for name, V in targets.items():
        moved = V[vertex_of] != base.V[vertex_of]  # per coordinate
        assert np.abs(got["targets"][name] - V[vertex_of])[moved].max() <= GLB_ROUNDTRIP_MM, name
        # a coordinate the target keeps has delta 0: it is the base as written
        np.testing.assert_array_equal(got["targets"][name][~moved], got["V"][~moved])
