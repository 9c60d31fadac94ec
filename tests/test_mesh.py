import numpy as np
import pytest

from gpja.errors import InputError
from gpja.mesh import TexturedMesh, read_obj, read_ply, write_obj, write_ply
from tests.tolerances import EXACT_F64, UINT8_STEP


def seamed_cube() -> TexturedMesh:
    """A unit cube: 8 welded vertices, 12 triangles, a UV atlas with seams (14 UVs)."""
    V = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], dtype=np.float64)
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    F = np.array([[a, b, c] for q in quads for a, b, c in ((q[0], q[1], q[2]), (q[0], q[2], q[3]))])
    rng = np.random.default_rng(0)
    UV = rng.random((14, 2))
    F_uv = rng.integers(0, 14, size=F.shape)
    tex = rng.random((16, 16, 3)).astype(np.float32)
    return TexturedMesh(V, F, UV, F_uv, tex)


def test_obj_round_trip_is_lossless(tmp_path):
    mesh = seamed_cube()
    mesh.V = mesh.V + np.random.default_rng(1).normal(scale=1e-3, size=mesh.V.shape) * np.pi
    write_obj(tmp_path / "cube.obj", mesh)
    back = read_obj(tmp_path / "cube.obj")
    np.testing.assert_array_equal(back.V, mesh.V)  # bit-exact, vertex order kept
    np.testing.assert_array_equal(back.F, mesh.F)
    np.testing.assert_array_equal(back.UV, mesh.UV)
    np.testing.assert_array_equal(back.F_uv, mesh.F_uv)
    assert len(back.V) == 8  # seams split UVs, never positions
    assert np.abs(back.texture - mesh.texture).max() <= UINT8_STEP
    assert (tmp_path / "cube.mtl").read_text().strip().endswith("map_Kd texture.png")


def test_obj_can_reference_a_shared_texture(tmp_path):
    mesh = seamed_cube()
    write_obj(tmp_path / "template.obj", mesh)
    mesh.texture = None
    write_obj(tmp_path / "1_neutral.obj", mesh)  # references template's texture.png, writes no image
    back = read_obj(tmp_path / "1_neutral.obj")
    assert back.texture is not None and back.texture.shape == (16, 16, 3)


def test_obj_polygons_negative_indices_and_vertex_colours(tmp_path):
    (tmp_path / "q.obj").write_text(
        "v 0 0 0 1 0 0\nv 1 0 0 1 0 0\nv 1 1 0 1 0 0\nv 0 1 0 1 0 0\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\n"
        "f -4/-4 -3/-3 -2/-2 -1/-1\n")
    m = read_obj(tmp_path / "q.obj")
    np.testing.assert_array_equal(m.F, [[0, 1, 2], [0, 2, 3]])
    np.testing.assert_array_equal(m.F_uv, [[0, 1, 2], [0, 2, 3]])


def test_edge_lengths_analytic():
    m = TexturedMesh(np.array([[0.0, 0, 0], [3, 0, 0], [0, 4, 0]]), np.array([[0, 1, 2]]))
    np.testing.assert_allclose(np.sort(m.edge_lengths()), [3, 4, 5], atol=EXACT_F64)
    np.testing.assert_allclose(m.face_normals(), [[0, 0, 1]], atol=EXACT_F64)


@pytest.mark.parametrize(
    "text, problem",
    [
        ("v 0 0 nan\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", "NaN"),
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 4\n", "out of range"),
        ("# nothing\n", "empty mesh"),
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1/1 2/1 3/1\n", "no 'vt'"),
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 x 3\n", "malformed face"),
    ],
)
def test_obj_bad_input_names_file(tmp_path, text, problem):
    path = tmp_path / "bad.obj"
    path.write_text(text)
    with pytest.raises(InputError, match=problem) as err:
        read_obj(path)
    assert str(path) in str(err.value)


def test_ply_round_trip_exact(tmp_path):
    V = np.random.default_rng(2).normal(scale=80, size=(50, 3))
    F = np.random.default_rng(3).integers(0, 50, size=(70, 3))
    write_ply(tmp_path / "s.ply", V, F)
    V2, F2 = read_ply(tmp_path / "s.ply")
    np.testing.assert_array_equal(V2, V)
    np.testing.assert_array_equal(F2, F)


def test_ply_own_layout_is_read_as_trimesh_reads_it_and_other_layouts_still_read(tmp_path):
    import trimesh

    from gpja.mesh import _parse_ply_file, _read_own_ply

    V = np.random.default_rng(4).normal(scale=80, size=(40, 3))
    F = np.random.default_rng(5).integers(0, 40, size=(60, 3))
    write_ply(tmp_path / "own.ply", V, F)
    fast = _read_own_ply(tmp_path / "own.ply")
    slow = trimesh.load(tmp_path / "own.ply", file_type="ply", process=False, force="mesh")
    np.testing.assert_array_equal(fast[0], np.asarray(slow.vertices, dtype=np.float64))
    np.testing.assert_array_equal(fast[1], np.asarray(slow.faces, dtype=np.int64))
    # another layout (ASCII, float32) is not this reader's: trimesh reads it
    trimesh.Trimesh(V.astype(np.float32), F, process=False).export(tmp_path / "other.ply", encoding="ascii")
    assert _read_own_ply(tmp_path / "other.ply") is None
    V2, F2 = _parse_ply_file(tmp_path / "other.ply")
    np.testing.assert_allclose(V2, V, atol=1e-4)
    np.testing.assert_array_equal(F2, F)
    # the own layout cut short, or a quad in its face list: errors naming the file
    data = (tmp_path / "own.ply").read_bytes()
    (tmp_path / "short.ply").write_bytes(data[:-7])
    with pytest.raises(InputError, match="short.ply: corrupt PLY"):
        read_ply(tmp_path / "short.ply")
    header_end = data.index(b"end_header\n") + len(b"end_header\n")
    quad = bytearray(data)
    quad[header_end + 24 * len(V)] = 4
    (tmp_path / "quad.ply").write_bytes(bytes(quad))
    with pytest.raises(InputError, match="quad.ply: corrupt PLY: a face"):
        read_ply(tmp_path / "quad.ply")


def test_ply_bad_input(tmp_path):
    (tmp_path / "empty.ply").write_bytes(b"")
    with pytest.raises(InputError, match="empty.ply: scan file is empty"):
        read_ply(tmp_path / "empty.ply")
    (tmp_path / "junk.ply").write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 99\n")
    with pytest.raises(InputError, match="junk.ply"):
        read_ply(tmp_path / "junk.ply")
    with pytest.raises(InputError, match="not found"):
        read_ply(tmp_path / "missing.ply")
    write_ply(tmp_path / "nan.ply", np.array([[0.0, 0, 0], [np.nan, 0, 0], [0, 1, 0]]), np.array([[0, 1, 2]]))
    with pytest.raises(InputError, match="NaN"):
        read_ply(tmp_path / "nan.ply")
    write_ply(tmp_path / "nofaces.ply", np.zeros((0, 3)), np.zeros((0, 3), dtype=int))
    with pytest.raises(InputError, match="empty mesh"):
        read_ply(tmp_path / "nofaces.ply")


def test_regression_obj_text(tmp_path):
    m = TexturedMesh(np.array([[0.1, 0.2, 0.3], [1, 0, 0], [0, 1, 0]]), np.array([[0, 1, 2]]),
                     np.array([[0, 0], [1, 0], [0, 1.0]]), np.array([[0, 1, 2]]))
    write_obj(tmp_path / "t.obj", m, texture_name=None)
    lines = (tmp_path / "t.obj").read_text().splitlines()
    assert lines[1:] == ["v 0.10000000000000001 0.20000000000000001 0.29999999999999999", "v 1 0 0", "v 0 1 0",
                         "vt 0 0", "vt 1 0", "vt 0 1", "f 1/1 2/2 3/3"]


def test_unique_edges_of_two_triangles_and_against_row_unique():
    from gpja.mesh import unique_edges

    edges, face_edge = unique_edges(np.array([[0, 1, 2], [2, 1, 3]]))
    np.testing.assert_array_equal(edges, [[0, 1], [0, 2], [1, 2], [1, 3], [2, 3]])
    np.testing.assert_array_equal(face_edge, [[0, 2, 1], [2, 3, 4]])
    F = np.random.default_rng(0).integers(0, 300, size=(500, 3))
    edges, face_edge = unique_edges(F)
    half = np.sort(np.stack([F, np.roll(F, -1, axis=1)], axis=2).reshape(-1, 2), axis=1)
    ref, inverse = np.unique(half, axis=0, return_inverse=True)
    np.testing.assert_array_equal(edges, ref)
    np.testing.assert_array_equal(face_edge.ravel(), inverse.ravel())


@pytest.mark.parametrize("faces", [
    "f 1 2 3\nf 1 3 4\n",                       # v
    "f 1/1 2/2 3/3\nf 1/1 3/3 4/4\n",           # v/vt
    "f 1/1/1 2/2/1 3/3/1\nf 1/1/1 3/3/1 4/4/1\n",  # v/vt/vn
    "f -4/-4 -3/-3 -2/-2\nf -4/-4 -2/-2 -1/-1\n",  # negative indices
    "f 1//1 2//1 3//1\nf 1//1 3//1 4//1\n",     # v//vn: the line-by-line parser
    "f 1/1 2/2 3/3 4/4\n",                      # a quad: the line-by-line parser
    "f 1 2 3\nf 1 3 4 2\n",                      # a triangle then a quad
])
def test_obj_fast_and_line_by_line_parsers_agree(tmp_path, faces):
    # identity: whichever parser reads the faces, the mesh is the one the line-by-line parser reads
    import gpja.mesh as M

    text = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nvn 0 0 1\n" + faces
    (tmp_path / "m.obj").write_text(text)
    mesh = read_obj(tmp_path / "m.obj")
    lines = [(i, line) for i, line in enumerate(text.splitlines(), 1) if line.startswith("f ")]
    F, F_uv = M._parse_faces(lines, tmp_path / "m.obj")
    np.testing.assert_array_equal(mesh.F, M._resolve_index(F, 4))
    if F_uv is None:
        assert mesh.F_uv is None
    else:
        np.testing.assert_array_equal(mesh.F_uv, M._resolve_index(F_uv, 4))


def test_obj_fast_parser_leaves_what_it_cannot_read_to_the_line_by_line_one(tmp_path):
    import gpja.mesh as M

    rows = [(1, "v 0 0 0 1"), (2, "v 1 0")]  # ragged: the same count of numbers, other rows
    assert M._parse_numbers(rows, 2, 3, np.float64) is None
    assert M._parse_numbers([(1, "v 0 0 x")], 2, 3, np.float64) is None
    assert M._parse_triangles([(1, "f 1/1 2/2 3/3"), (2, "f 1/1 2/2 3/3 4/4")]) is None
    assert M._parse_triangles([(1, "f 1/1 2/2 3/3"), (2, "f 1/1/1 2 3/3")]) is None  # corners unlike the first one
    np.testing.assert_array_equal(M._parse_numbers([(1, "v 1.5 -2 3e-3")], 2, 3, np.float64), [[1.5, -2, 3e-3]])
    (tmp_path / "r.obj").write_text("v 0 0 0 1\nv 1 0\nv 0 1 0\nf 1 2 3\n")
    with pytest.raises(InputError, match="malformed coordinates"):
        read_obj(tmp_path / "r.obj")


# --- the vectorised OBJ reader (gpja.mesh._scan_obj) against the line-by-line parsers ----------------------------

def _read_line_by_line(path, monkeypatch):
    """read_obj with neither the vectorised scan nor the one-call parsers: every line split and converted alone."""
    import gpja.mesh as M

    with monkeypatch.context() as patch:
        for name in ("_scan_obj", "_parse_numbers", "_parse_triangles"):
            patch.setattr(M, name, lambda *args: None)
        return read_obj(path, load_texture=False)


def _assert_same(a, b):
    for k in ("V", "F", "UV", "F_uv"):
        x, y = getattr(a, k), getattr(b, k)
        assert (x is None) == (y is None), k
        if x is not None:
            assert x.dtype == y.dtype and x.shape == y.shape and x.tobytes() == y.tobytes(), k  # bit for bit


def _fully_vectorised(path) -> bool:
    import gpja.mesh as M

    scan = M._scan_obj(path.read_bytes())
    return scan is not None and scan[3] == ([], [], [])


def test_obj_vectorised_reader_matches_line_by_line_on_a_random_mesh(tmp_path, monkeypatch):
    rng = np.random.default_rng(7)
    V = rng.normal(scale=60, size=(200, 3))
    V[0], V[1] = [0, 1, -2], V[1] * 1e-9  # words without a dot, with an exponent
    mesh = TexturedMesh(V, rng.integers(0, 200, (300, 3)), rng.random((250, 2)), rng.integers(0, 250, (300, 3)))
    path = tmp_path / "m.obj"
    write_obj(path, mesh, texture_name=None)
    text = path.read_bytes()
    for data in (text, text.replace(b"\n", b"\r\n"), text.rstrip(b"\n"), text.replace(b"\n", b"\r\n").rstrip()):
        path.write_bytes(data)
        fast = read_obj(path)
        assert _fully_vectorised(path)
        _assert_same(fast, _read_line_by_line(path, monkeypatch))
        _assert_same(fast, mesh)


def test_obj_vectorised_reader_skips_what_the_line_loop_skips(tmp_path, monkeypatch):
    # comments, blank lines, vn / o / s / g / usemtl lines between and inside the blocks; v lines not contiguous
    rng = np.random.default_rng(8)
    num = lambda: "%.17g" % rng.normal(scale=30)
    lines = ["# header", "mtllib m.mtl", "o head", f"v {num()} {num()} {num()}", "vn 0 0 1", "",
             f"v {num()}  {num()}\t{num()} ", "# v 9 9 9", " v 9 9 9", "s off", f"vt {num()} {num()}",
             f"v {num()} {num()} {num()}", "g part", f"vt {num()} {num()}", "usemtl skin", f"vt {num()} {num()}",
             "f 1/1 2/2 3/3", "s 1", "", "f  3/3 2/2\t1/1", "vp 1 2", f"v {num()} {num()} {num()}", "f 1/1 3/3 4/2"]
    path = tmp_path / "m.obj"
    path.write_text("\n".join(lines) + "\n")
    fast = read_obj(path, load_texture=False)
    assert _fully_vectorised(path) and len(fast.V) == 4 and len(fast.UV) == 3 and len(fast.F) == 3
    _assert_same(fast, _read_line_by_line(path, monkeypatch))


@pytest.mark.parametrize("v, f, expect_F", [
    ("v 0 0 0 1\nv 1 0 0\nv 1 1 0\nv 0 1 0\n", "f 1 2 3\nf 1 3 4\n", [[0, 1, 2], [0, 2, 3]]),  # one v with a w
    ("v 0 0 0 1 0 0\nv 1 0 0 1 0 0\nv 1 1 0 0 1 0\nv 0 1 0 0 0 1\n", "f 1 2 3\n", [[0, 1, 2]]),  # vertex colours
    ("v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\n", "f 1 2 3\nf 1 2 3 4\n", [[0, 1, 2], [0, 1, 2], [0, 2, 3]]),  # a quad
])
def test_obj_vectorised_reader_leaves_extra_columns_and_polygons_to_the_line_by_line_one(tmp_path, monkeypatch, v, f,
                                                                                         expect_F):
    path = tmp_path / "m.obj"
    path.write_text(v + f)
    mesh = read_obj(path)
    assert not _fully_vectorised(path)
    np.testing.assert_array_equal(mesh.V, [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]])
    np.testing.assert_array_equal(mesh.F, expect_F)
    _assert_same(mesh, _read_line_by_line(path, monkeypatch))


@pytest.mark.parametrize("text, problem", [
    ("# c\nv 0 0 0\nv 1 0 0\nv 0 1 x\nf 1 2 3\n", "malformed coordinates near line 2"),  # the first v line, as before
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 0.5 -\nf 1/1 2/2 3/2\n", "malformed coordinates near line 4"),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nf 1 2 x\n", "line 5: malformed face 'f 1 2 x'"),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nf 1/1 2/1 3/1\nf 1/1/1 2 3/1\n", "line 6: malformed face 'f 1/1/1 2 3/1'"),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nf 1/1 2/ 3/1\n", "line 5: malformed face 'f 1/1 2/ 3/1'"),
])
def test_obj_vectorised_reader_errors_name_the_line(tmp_path, monkeypatch, text, problem):
    # a sign alone ("0.5 -") reads as 0 to np.fromstring's integer parser; corners unlike the first corner
    # ("1/1/1 2 3/1", which the one-call parser used to read as 1/1 1/2 3/1) go to the line-by-line parser
    path = tmp_path / "bad.obj"
    for data in (text, text.replace("\n", "\r\n")):
        path.write_text(data, newline="")
        with pytest.raises(InputError, match=problem) as err:
            read_obj(path)
        assert str(path) in str(err.value)
        with pytest.raises(InputError, match=problem):
            _read_line_by_line(path, monkeypatch)


def test_obj_decimals_are_read_bit_for_bit():
    # write_obj's 17 digits, exact ties (2^53 + 1, 7e22), long words, exponents, words with no dot: the scan's one
    # numpy call reads each as float() does
    import gpja.mesh as M

    rng = np.random.default_rng(9)
    words = ["%.17g" % x for x in rng.normal(size=1500) * 10.0 ** rng.integers(-6, 6, 1500)]
    words += ["9007199254740993.0", "-9007199254740995", "7e22", "0.1", "-0.0", "-0", "+2.5", "5.", "1.5E+3",
              "123456789012345678901.5", "0.0000000000000000000000000000012", "1e-30", "4.9e-324"]
    words += ["1"] * (-len(words) % 3)
    data = "".join(f"v {a} {b} {c}\n" for a, b, c in zip(words[::3], words[1::3], words[2::3])).encode()
    expect = np.array([float(w) for w in words]).view(np.int64)
    np.testing.assert_array_equal(M._scan_obj(data)[0].ravel().view(np.int64), expect)


def test_obj_text_path_reads_what_the_scan_leaves(tmp_path, monkeypatch):
    # UTF-8 beyond ASCII is scanned unless it holds what str.split cuts at (a no-break space, a vertical tab); the
    # text path reads those as before, and bytes that are not UTF-8 are not a text OBJ file
    import gpja.mesh as M

    path = tmp_path / "m.obj"
    for comment, line, scanned in (("# façade", "v 1 0 0", True), ("#", "v 1 0\u00a00", False),
                                   ("# \x0b", "v 1 0 0", False)):
        path.write_bytes(f"{comment}\nv 0 0 0\n{line}\nv 0 1 0\nf 1 2 3\n".encode())
        assert (M._scan_obj(path.read_bytes()) is not None) == scanned
        _assert_same(read_obj(path), _read_line_by_line(path, monkeypatch))
    path.write_bytes(b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n# \xff\n")
    with pytest.raises(InputError, match="not a text OBJ file"):
        read_obj(path)
    with pytest.raises(InputError, match="mesh file not found"):
        read_obj(tmp_path / "missing.obj")


def test_reading_once_parses_each_file_once_and_hands_out_copies(tmp_path, monkeypatch):
    import gpja.mesh as M

    V, F = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]]), np.array([[0, 1, 2], [0, 3, 1]])
    obj, ply = tmp_path / "m.obj", tmp_path / "s.ply"
    write_obj(obj, TexturedMesh(V, F), texture_name=None)
    write_ply(ply, V, F)
    parsed = []
    for name in ("_parse_obj_file", "_parse_ply_file"):
        real = getattr(M, name)
        monkeypatch.setattr(M, name, lambda *a, real=real, name=name: parsed.append(name) or real(*a))
    with M.reading_once():
        first = read_obj(obj, load_texture=False)
        first.V[0] = 99.0  # a caller changing its copy changes no one else's
        second = read_obj(obj, load_texture=False)
        with M.reading_once():  # a nested block shares the memo
            scans = [read_ply(ply), read_ply(ply)]
        assert read_obj(obj, load_texture=True) is not None  # other options: another read
    assert parsed == ["_parse_obj_file", "_parse_ply_file", "_parse_obj_file"]
    np.testing.assert_array_equal(second.V, V)
    np.testing.assert_array_equal(second.F, F)
    assert scans[0][0] is not scans[1][0]
    np.testing.assert_array_equal(scans[1][0], V)
    # outside a block, and for a file rewritten inside one, the file is parsed again
    read_obj(obj, load_texture=False)
    with M.reading_once():
        read_obj(obj, load_texture=False)
        write_obj(obj, TexturedMesh(V * 2.0, F), texture_name=None)
        np.testing.assert_array_equal(read_obj(obj, load_texture=False).V, V * 2.0)
        with pytest.raises(InputError, match="not found"):
            read_obj(tmp_path / "missing.obj")
    assert parsed[3:] == ["_parse_obj_file"] * 4  # outside; the new block's first; rewritten; missing (its error)
