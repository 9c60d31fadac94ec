"""Tests of gpja.baselines.external: importing meshes made by other tools."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from gpja.baselines.external import import_mesh
from gpja.data.source import DataSource
from gpja.errors import InputError
from gpja.io import write_image
from gpja.mesh import TexturedMesh, read_obj, write_obj, write_ply
from tests.tolerances import EXACT_F64

SUBJECT, EXPRESSION = "122", "13_lip_funneler"
SIDE_MM = 150.0


def seamed_box() -> TexturedMesh:
    """A 150 mm cube centred at the origin: 8 welded vertices, 12 triangles, a seamed UV atlas, a texture."""
    V = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], dtype=np.float64) * SIDE_MM / 2
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    F = np.array([[a, b, c] for q in quads for a, b, c in ((q[0], q[1], q[2]), (q[0], q[2], q[3]))])
    rng = np.random.default_rng(0)
    UV = rng.random((14, 2))
    F_uv = rng.integers(0, 14, size=F.shape)
    tex = rng.random((8, 8, 3)).astype(np.float32)
    return TexturedMesh(V, F, UV, F_uv, tex)


def rotation(axis: np.ndarray, angle: float) -> np.ndarray:
    """(3, 3) rotation about ``axis`` by ``angle`` radians (Rodrigues)."""
    k = np.asarray(axis, dtype=np.float64) / np.linalg.norm(axis)
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K


S, R, T = 1.3, rotation([1.0, 2.0, 0.5], 0.7), np.array([10.0, -20.0, 5.0])


@pytest.fixture
def external(tmp_path: Path) -> dict:
    """One mesh of another tool in a ``{subject}/{expression}.obj`` layout, plus an output folder."""
    mesh = seamed_box()
    write_obj(tmp_path / "tool" / SUBJECT / f"{EXPRESSION}.obj", mesh, texture_name=f"{EXPRESSION}_tex.png")
    return {"mesh": mesh, "pattern": str(tmp_path / "tool" / "{subject}" / "{expression}.obj"),
            "out": tmp_path / "results" / SUBJECT / "tool" / f"{EXPRESSION}.obj", "root": tmp_path}


def write_transform(root: Path, content) -> str:
    """Write a per-mesh transform JSON; return its pattern."""
    path = root / "transforms" / SUBJECT / f"{EXPRESSION}.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(content if isinstance(content, str) else json.dumps(content))
    return str(root / "transforms" / "{subject}" / "{expression}.json")


def test_identity_round_trip_keeps_everything(external):
    log = import_mesh(external["pattern"], SUBJECT, EXPRESSION, external["out"])
    back = read_obj(external["out"])
    m = external["mesh"]
    for name in ("V", "F", "UV", "F_uv"):
        assert np.array_equal(getattr(back, name), getattr(m, name)), name
    assert back.texture is not None and (external["out"].parent / f"{EXPRESSION}.png").is_file()
    saved = json.loads(external["out"].with_suffix(".json").read_text())
    assert saved == json.loads(json.dumps(log))
    assert log["has_uv"] and log["transform"] is None and log["source"].endswith(f"{SUBJECT}/{EXPRESSION}.obj")


@pytest.mark.parametrize("form", ["scale_R_t", "matrix", "bare_matrix", "facescape"])
def test_known_similarity_moves_vertices_exactly(external, form):
    M = np.eye(4)
    M[:3, :3], M[:3, 3] = S * R, T
    content = {
        "scale_R_t": {"scale": S, "R": R.tolist(), "t": T.tolist()},
        "matrix": {"matrix": M.tolist()},
        "bare_matrix": M.tolist(),
        "facescape": {SUBJECT: {"13": [S, np.c_[R, T].tolist()]}},  # X' = R (s X) + t
    }[form]
    tpattern = write_transform(external["root"], content)
    log = import_mesh(external["pattern"], SUBJECT, EXPRESSION, external["out"], transform_pattern=tpattern)
    back = read_obj(external["out"])
    expected = S * external["mesh"].V @ R.T + T
    assert np.abs(back.V - expected).max() <= EXACT_F64 * SIDE_MM
    assert np.array_equal(back.UV, external["mesh"].UV) and np.array_equal(back.F_uv, external["mesh"].F_uv)
    assert abs(log["transform"]["scale"] - S) <= EXACT_F64


def test_ply_without_uvs_is_written_without_and_logged(external):
    m = external["mesh"]
    write_ply(external["root"] / "nphm" / SUBJECT / f"{EXPRESSION}.ply", m.V, m.F)
    log = import_mesh(str(external["root"] / "nphm" / "{subject}" / "{expression}.ply"), SUBJECT, EXPRESSION,
                      external["out"])
    back = read_obj(external["out"])
    assert not back.has_uv and np.array_equal(back.V, m.V) and np.array_equal(back.F, m.F)
    assert not log["has_uv"] and "photometric metrics will refuse" in log["note"]
    assert not external["out"].with_suffix(".mtl").exists()


def test_shared_texture_is_referenced_relative(external):
    tex = external["root"] / "shared" / "texture.png"
    write_image(tex, np.full((4, 4, 3), 0.5, dtype=np.float32))
    import_mesh(external["pattern"], SUBJECT, EXPRESSION, external["out"], texture=tex)
    assert "map_Kd ../../../shared/texture.png" in external["out"].with_suffix(".mtl").read_text()
    assert not (external["out"].parent / f"{EXPRESSION}.png").exists()
    assert read_obj(external["out"]).texture.shape == (4, 4, 3)


def test_scan_check_accepts_a_matching_mesh_and_refuses_a_far_one(external):
    m = external["mesh"]
    source = DataSource(scans_root=external["root"] / "scans")
    scan = source.scan_file(SUBJECT, EXPRESSION)
    write_ply(scan, m.V, m.F)
    log = import_mesh(external["pattern"], SUBJECT, EXPRESSION, external["out"], source=source)
    assert log["median_scan_gap_mm"] < 1e-6 and log["scan"] == str(scan)
    write_ply(scan, m.V + [0.0, 0.0, 300.0], m.F)
    with pytest.raises(InputError, match="median .* mm from the scan"):
        import_mesh(external["pattern"], SUBJECT, EXPRESSION, external["out"].with_name("x.obj"), source=source)


# --- bad input --------------------------------------------------------------------------------

def expect_error(external, match: str, **kw) -> None:
    """The import fails with ``match`` in the message and writes nothing."""
    pattern = kw.pop("pattern", external["pattern"])
    with pytest.raises(InputError, match=match):
        import_mesh(pattern, SUBJECT, EXPRESSION, external["out"], **kw)
    assert not external["out"].parent.exists() or not any(external["out"].parent.iterdir())


def test_missing_mesh_names_the_path_and_the_pattern(external):
    pattern = str(external["root"] / "nowhere" / "{subject}" / "{expression}.obj")
    expect_error(external, rf"nowhere/{SUBJECT}/{EXPRESSION}\.obj: mesh file not found "
                           rf"\(from pattern '.*nowhere/{{subject}}/{{expression}}\.obj'\)", pattern=pattern)


def test_corrupt_and_nan_meshes_are_refused(external):
    path = Path(external["pattern"].format(subject=SUBJECT, expression=EXPRESSION))
    path.write_bytes(b"\x89PNG\r\n\x1a\n\xff\xfe binary junk")
    expect_error(external, r"13_lip_funneler\.obj: not a text OBJ file")
    path.write_text("v 0 0 0\nv 1 0\nv 0 1 0\nf 1 2 3\n")
    expect_error(external, r"13_lip_funneler\.obj: malformed coordinates")
    path.write_text("v 0 0 0\nv nan 0 0\nv 0 1 0\nf 1 2 3\n")
    expect_error(external, r"13_lip_funneler\.obj: 1 vertices have NaN")
    bad_ply = external["root"] / "tool" / SUBJECT / f"{EXPRESSION}.ply"
    bad_ply.write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 9\nend_header\n\x00")
    expect_error(external, r"13_lip_funneler\.ply: corrupt or unreadable PLY",
                 pattern=external["pattern"].replace(".obj", ".ply"))
    path.with_suffix(".stl").write_text("solid x\n")
    expect_error(external, r"13_lip_funneler\.stl: unsupported mesh format", pattern=external["pattern"].replace(".obj", ".stl"))


def test_mesh_in_metres_is_refused(external):
    tpattern = write_transform(external["root"], {"scale": 0.001, "R": np.eye(3).tolist(), "t": [0, 0, 0]})
    expect_error(external, r"13_lip_funneler\.obj: bounding-box diagonal is 0\.2598", transform_pattern=tpattern)


@pytest.mark.parametrize("content, match", [
    ("{not json", "corrupt JSON"),
    ({"matrix": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0]]}, None),  # 3x4 is fine: the control case
    ({"matrix": [[1, 0.3, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]}, "not a rigid/similarity transform"),
    ({"matrix": [[2, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]}, "not a rigid/similarity transform"),
    ({"matrix": [[-1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]}, "a mirror"),
    ({"matrix": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0.1, 1]]}, "last row"),
    ({"matrix": [[1, 0, 0], [0, 1, 0]]}, "expected a 4x4 or 3x4 matrix"),
    ({"scale": -1.0, "R": np.eye(3).tolist(), "t": [0, 0, 0]}, "scale must be positive"),
    ({"scale": 1.0, "R": [[1, 0], [0, 1]], "t": [0, 0, 0]}, "R must be 3x3"),
    ({"scale": 1.0, "R": np.eye(3).tolist(), "t": [0, "a", 0]}, "malformed transform"),
    ({"scale": float("nan"), "R": np.eye(3).tolist(), "t": [0, 0, 0]}, "NaN or infinite"),
    ({"rotation": 1}, "expected {'matrix': 4x4}"),
    ({SUBJECT: {"1": [1.0, np.eye(4)[:3].tolist()]}}, "no valid \\[scale, Rt\\] entry"),
])
def test_bad_transforms_are_refused(external, content, match):
    tpattern = write_transform(external["root"], content)
    if match is None:
        import_mesh(external["pattern"], SUBJECT, EXPRESSION, external["out"], transform_pattern=tpattern)
        return
    expect_error(external, rf"transforms/{SUBJECT}/{EXPRESSION}\.json: .*{match}", transform_pattern=tpattern)


def test_missing_transform_is_named(external):
    expect_error(external, r"nope/13_lip_funneler\.json: transform file not found \(from pattern",
                 transform_pattern=str(external["root"] / "nope" / "{expression}.json"))


def test_unknown_placeholder_is_refused(external):
    expect_error(external, r"config: path pattern .*{view}", pattern=str(external["root"] / "{view}.obj"))
