"""Triangle meshes with a separate UV index, and their files.

``TexturedMesh`` keeps welded positions ``V (n, 3)`` with faces ``F (m, 3)`` and
texture coordinates ``UV (k, 2)`` with their own faces ``F_uv (m, 3)``: a UV seam
splits texture coordinates, never positions (DESIGN.md). UVs follow OBJ's
convention, origin bottom-left, v up.

OBJ I/O is written here rather than taken from trimesh because trimesh gives
every vertex one UV: it splits vertices at UV seams and renumbers them (a seamed
cube's 8 become 31, out of file order; with ``maintain_order`` it keeps the 8
and drops the UV faces), which breaks the topology every method shares, and
because vertex order and float values must survive a round trip bit for bit
(floats are written with 17 significant digits). The reader works on the file's bytes with numpy
(:func:`_scan_obj`): the workflow reads 100K-vertex OBJs dozens of times a run.
PLY scans go through trimesh, which reads every PLY flavour FaceScape and MVS
tools produce.
"""
from __future__ import annotations

import copy
import re
from contextlib import contextmanager
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Callable, Iterator, TypeVar

import numpy as np

from gpja.errors import InputError
from gpja.io import atomic_path, read_image, write_image, write_text


@dataclass(eq=False)
class TexturedMesh:
    """A triangle mesh, optionally with a UV parametrisation and a texture image.

    Attributes:
        V: (n, 3) float64 vertex positions, mm.
        F: (m, 3) int64 vertex indices per triangle (counter-clockwise = outward).
        UV: (k, 2) float64 texture coordinates in [0, 1], origin bottom-left; or None.
        F_uv: (m, 3) int64 indices into ``UV`` per triangle corner; or None.
        texture: (t, t, 3) float32 RGB in [0, 1]; or None.
    """

    V: np.ndarray
    F: np.ndarray
    UV: np.ndarray | None = None
    F_uv: np.ndarray | None = None
    texture: np.ndarray | None = None

    def __post_init__(self) -> None:
        self.V = np.ascontiguousarray(self.V, dtype=np.float64).reshape(-1, 3)
        self.F = np.ascontiguousarray(self.F, dtype=np.int64).reshape(-1, 3)
        if (self.UV is None) != (self.F_uv is None):
            raise ValueError("UV and F_uv must be given together")
        if self.UV is not None:
            self.UV = np.ascontiguousarray(self.UV, dtype=np.float64).reshape(-1, 2)
            self.F_uv = np.ascontiguousarray(self.F_uv, dtype=np.int64).reshape(-1, 3)

    @property
    def has_uv(self) -> bool:
        return self.UV is not None

    def with_vertices(self, V: np.ndarray) -> "TexturedMesh":
        """The same mesh (shared faces, UVs, texture) with new positions ``V (n, 3)``."""
        V = np.asarray(V, dtype=np.float64)
        if V.shape != self.V.shape:
            raise ValueError(f"new vertices have shape {V.shape}, expected {self.V.shape}")
        return replace(self, V=V)

    def validate(self, source: str | Path = "mesh") -> "TexturedMesh":
        """Check the mesh is usable; raise :class:`InputError` naming ``source`` if not.

        Checks: non-empty, finite positions, face indices in range, UV faces
        matching faces one to one with indices in range.
        """
        if len(self.V) == 0 or len(self.F) == 0:
            raise InputError(source, f"empty mesh ({len(self.V)} vertices, {len(self.F)} faces)")
        bad = ~np.isfinite(self.V).all(axis=1)
        if bad.any():
            raise InputError(source, f"{int(bad.sum())} vertices have NaN or infinite coordinates (first: vertex {int(np.argmax(bad))})")
        if self.F.min() < 0 or self.F.max() >= len(self.V):
            raise InputError(source, f"face indices out of range [0, {len(self.V)}) (min {self.F.min()}, max {self.F.max()})")
        if self.has_uv:
            if len(self.F_uv) != len(self.F):
                raise InputError(source, f"{len(self.F_uv)} UV faces for {len(self.F)} faces")
            if len(self.UV) == 0 or self.F_uv.min() < 0 or self.F_uv.max() >= len(self.UV):
                raise InputError(source, "UV face indices out of range")
            if not np.isfinite(self.UV).all():
                raise InputError(source, "texture coordinates contain NaN or infinity")
        return self

    def face_normals(self) -> np.ndarray:
        """(m, 3) float64 unit face normals (zero for degenerate faces)."""
        tri = self.V[self.F]
        n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        norm = np.linalg.norm(n, axis=1, keepdims=True)
        return np.divide(n, norm, out=np.zeros_like(n), where=norm > 0)

    def edge_lengths(self) -> np.ndarray:
        """(e,) float64 length of every undirected edge, mm."""
        edges, _ = unique_edges(self.F)
        return np.linalg.norm(self.V[edges[:, 0]] - self.V[edges[:, 1]], axis=1)


def unique_edges(F: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Undirected edges of a triangle index array.

    Args:
        F: (m, 3) int corner indices.
    Returns:
        edges: (e, 2) int64 sorted vertex pairs, in lexicographic order.
        face_edge: (m, 3) int64 edge id of each face's edge k = (corner k, corner k+1).
    """
    F = np.asarray(F, dtype=np.int64).reshape(-1, 3)
    a, b = F, np.roll(F, -1, axis=1)
    n = int(F.max()) + 1 if F.size else 1
    # one int64 key per undirected edge, ordered as the (low, high) rows are: a 1-D unique is
    # several times faster than np.unique(axis=0) on rows
    key, inverse = np.unique((np.minimum(a, b) * n + np.maximum(a, b)).ravel(), return_inverse=True)
    return np.stack([key // n, key % n], axis=1), inverse.reshape(-1, 3)


def check_vertex_prefix(n_registered: int, n_template: int, source: str | Path) -> None:
    """Raise :class:`InputError` if a registered mesh has fewer vertices than its template.

    Registrations keep the template's vertices first and in order (refinement appends the new ones), so
    vertex ``i < n_template`` of a registered mesh is template vertex ``i``: the correspondence metric and a
    registration started from another one (``gpja.register.pipeline.start_from``) rely on it.
    """
    if n_registered < n_template:
        raise InputError(source, f"{n_registered} vertices, fewer than the template's {n_template}: "
                                 "not a registration of this template (its vertices must come first, in order)")


# --- OBJ + MTL + PNG ----------------------------------------------------------------------

def _format_rows(row_format: str, rows: np.ndarray) -> str:
    """Every row of ``rows (k, c)`` through the %-format ``row_format`` (c fields), as one string: one C-level
    formatting call, the text ``np.savetxt`` writes with that format (a Python call per row, 3x slower)."""
    return (row_format * len(rows)) % tuple(rows.ravel().tolist())


def write_obj(path: str | Path, mesh: TexturedMesh, texture_name: str | None = "texture.png") -> None:
    """Write a mesh as OBJ (+ MTL referencing ``texture_name``, + the PNG if the mesh has one).

    With ``texture_name`` set and ``mesh.texture`` None, the MTL references an
    existing (shared) texture next to the OBJ without writing it. All files are
    written atomically.
    """
    path = Path(path)
    mesh.validate(path)
    mtl_name = path.with_suffix(".mtl").name
    with atomic_path(path) as tmp, open(tmp, "w", encoding="ascii") as fh:
        fh.write("# gpja TexturedMesh: welded positions, separate UV faces\n")
        if texture_name is not None:
            fh.write(f"mtllib {mtl_name}\nusemtl material0\n")
        fh.write(_format_rows("v %.17g %.17g %.17g\n", mesh.V))
        if mesh.has_uv:
            fh.write(_format_rows("vt %.17g %.17g\n", mesh.UV))
            corners = np.stack([mesh.F + 1, mesh.F_uv + 1], axis=2).reshape(-1, 6)
            fh.write(_format_rows("f %d/%d %d/%d %d/%d\n", corners))
        else:
            fh.write(_format_rows("f %d %d %d\n", mesh.F + 1))
    if texture_name is not None:
        write_text(path.with_suffix(".mtl"),
                   f"newmtl material0\nKa 1 1 1\nKd 1 1 1\nKs 0 0 0\nillum 1\nmap_Kd {texture_name}\n")
        if mesh.texture is not None:
            write_image(path.parent / texture_name, mesh.texture)


def _parse_faces(lines: list[str], path: Path) -> tuple[np.ndarray, np.ndarray | None]:
    """Parse ``f`` lines (any polygon, fan-triangulated) into vertex and UV faces."""
    fv: list[list[int]] = []
    ft: list[list[int]] = []
    has_vt = None
    for lineno, line in lines:
        corners = line.split()[1:]
        if len(corners) < 3:
            raise InputError(path, f"line {lineno}: face with fewer than 3 corners")
        try:
            parts = [c.split("/") for c in corners]
            v = [int(p[0]) for p in parts]
            t = [int(p[1]) for p in parts] if len(parts[0]) > 1 and parts[0][1] else None
        except (ValueError, IndexError):
            raise InputError(path, f"line {lineno}: malformed face {line.strip()!r}") from None
        if has_vt is None:
            has_vt = t is not None
        elif has_vt != (t is not None):
            raise InputError(path, f"line {lineno}: some faces have texture indices and some do not")
        for k in range(1, len(v) - 1):
            fv.append([v[0], v[k], v[k + 1]])
            if t is not None:
                ft.append([t[0], t[k], t[k + 1]])
    return np.array(fv, dtype=np.int64).reshape(-1, 3), (np.array(ft, dtype=np.int64).reshape(-1, 3) if has_vt else None)


def _fromstring(body: str | bytes, dtype, count: int) -> np.ndarray | None:
    """The whitespace-separated numbers of ``body`` parsed by numpy in one call; None unless there are ``count``."""
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # older numpy warns where newer raises, at a malformed token
        try:
            values = np.fromstring(body, dtype=dtype, sep=" ")
        except ValueError:
            return None
    return values if values.size == count else None


def _parse_numbers(rows: list[tuple[int, str]], skip: int, per_row: int, dtype) -> np.ndarray | None:
    """The numbers of ``rows`` (``(lineno, line)``, each line's first ``skip`` characters dropped) parsed by numpy in
    one call, as ``(len(rows), per_row)``; None when the rows do not hold exactly ``per_row`` numbers each (the
    caller's line-by-line parser then reads them and names what is wrong).

    Why not line by line: a registered mesh's OBJ has about 400K lines, and splitting and converting each in
    Python took 3 s of every 100K-vertex read (half of a metrics job); numpy's C parser takes a tenth of that.
    """
    if not rows:
        return np.zeros((0, per_row), dtype=dtype)
    if dtype is np.float64 and any(len(line.split()) != per_row + 1 for _, line in rows):
        return None  # extra columns (vertex colours, a w) or missing ones
    body = " ".join(line[skip:] for _, line in rows)
    if dtype is not np.float64:
        body = body.replace("/", " ")
    values = _fromstring(body, dtype, len(rows) * per_row)
    return None if values is None else values.reshape(len(rows), per_row)


def _parse_triangles(lines: list[tuple[int, str]]) -> tuple[np.ndarray, np.ndarray | None] | None:
    """:func:`_parse_faces` for the common case, in one numpy call: every ``f`` line a triangle whose corners all
    read ``v``, ``v/vt`` or ``v/vt/vn`` like the first line's first corner. None otherwise (the line-by-line parser
    decides)."""
    if not lines:
        return None
    corners = lines[0][1].split()[1:]
    parts = corners[0].count("/") + 1 if corners else 0  # v, v/vt or v/vt/vn, as the first corner reads
    if not 1 <= parts <= 3:
        return None
    k = parts - 1
    for _, line in lines:  # three corners of k slashes each (the third has what the first two leave), no empty index
        c = line.split()
        if len(c) != 4 or line.count("/") != 3 * k or c[1].count("/") != k or c[2].count("/") != k or "//" in line:
            return None
    values = _parse_numbers(lines, 2, 3 * parts, np.int64)
    if values is None:
        return None
    corners = values.reshape(len(lines), 3, parts)
    return corners[:, :, 0].copy(), (corners[:, :, 1].copy() if parts > 1 else None)


_UNICODE_SPACE = re.compile("[\x85\xa0\u1680\u2000-\u200a\u2028\u2029\u202f\u205f\u3000]")  # str.isspace, past ASCII


def _ends_in_digit(seg: np.ndarray) -> bool:
    i = len(seg) - 1
    while i >= 0 and seg[i] <= 32:
        i -= 1
    return i >= 0 and 48 <= seg[i] <= 57


def _scan_obj(data: bytes):
    """:func:`read_obj`'s line loop and one-call parsers, vectorised over the file's bytes.

    Returns ``(V, UV, faces, (v_rows, vt_rows, f_rows), mtllib)``: ``V``, ``UV`` the ``v``, ``vt`` numbers and
    ``faces`` the ``(F, F_uv)`` of the ``f`` lines, each None where its kind is absent or some line of it is not as
    :func:`_parse_numbers` / :func:`_parse_triangles` read it, whose ``(lineno, line)`` rows then come instead for
    them and the line-by-line parsers. None for bytes that are not UTF-8 or hold what Python's ``split`` or
    ``splitlines`` cut at and numpy does not (control characters but tab, CR, LF; Unicode spaces): the text path
    reads those.

    Why: the line loop and the per-line checks took three quarters of a 100K-vertex read (0.8 of 1.1 s). Here numpy
    finds the lines, and in one kind's lines, gathered, the words (a byte above space after one at or below it, where
    ``str.split`` starts one): the lines hold n words each if there are n per line in all and words i n and
    i n + n - 1 lie in line i. Faces read like their first corner if every corner holds as many slashes, none at its
    start; one call then reads all the numbers, and reads fewer where an index is empty or a sign apart from its
    digits.
    """
    if not data.isascii():
        try:
            if _UNICODE_SPACE.search(data.decode("utf-8")):
                return None
        except UnicodeDecodeError:
            return None
    a = np.frombuffer(data, dtype=np.uint8)
    n = len(a)
    nl = np.flatnonzero(a == 10)
    control = np.count_nonzero(a < 32)
    if control != len(nl):
        cr = data.count(b"\r")
        if control != len(nl) + cr + data.count(b"\t"):
            return None
        if cr:  # universal newlines, as Path.read_text reads them
            return _scan_obj(data.replace(b"\r\n", b"\n").replace(b"\r", b"\n"))
    ends = np.append(nl, n)  # of each line, as str.splitlines cuts them
    starts = np.concatenate(([0], nl + 1))
    if starts[-1] == n:  # a final newline ends the last line, it starts none
        ends, starts = ends[:-1], starts[:-1]
    head = np.lib.stride_tricks.as_strided(a, shape=(max(n - 2, 0), 3), strides=(1, 1))[np.minimum(starts, n - 3)] \
        if n >= 3 else np.zeros((len(starts), 3), dtype=np.uint8)
    for i in np.flatnonzero(starts > n - 3).tolist():  # the last line or two, of two bytes or fewer
        head[i] = np.frombuffer((data[starts[i]:] + b"\n\n\n")[:3], dtype=np.uint8)
    b0, b1, b2 = head.T  # a line's first three bytes, or its newline after fewer
    is_v, is_vt, is_f = (b0 == 118) & (b1 == 32), (b0 == 118) & (b1 == 116) & (b2 == 32), (b0 == 102) & (b1 == 32)

    def rows(idx: np.ndarray) -> list[tuple[int, str]]:
        return [(i + 1, data[s:e].decode()) for i, s, e in zip(idx.tolist(), starts[idx].tolist(), ends[idx].tolist())]

    def segment(idx: np.ndarray, skip: int) -> tuple[bytearray, np.ndarray, np.ndarray, np.ndarray]:
        """Lines idx as one bytearray (runs of consecutive lines, each ended by a newline) with their keyword
        blanked, its numpy view, and their starts and ends in it."""
        brk = np.flatnonzero(np.diff(idx) != 1) + 1
        lo, hi = starts[idx[np.r_[0, brk]]], ends[idx[np.r_[brk - 1, len(idx) - 1]]]
        view = memoryview(data)
        text = bytearray(b"\n").join([view[s:e] for s, e in zip(lo.tolist(), hi.tolist())] + [b""])
        seg = np.frombuffer(text, dtype=np.uint8)
        run = np.zeros(len(idx), dtype=np.int64)
        run[brk] = 1
        shift = (np.cumsum(hi - lo + 1) - (hi - lo + 1) - lo)[np.cumsum(run)]
        ls, le = starts[idx] + shift, ends[idx] + shift
        for k in range(skip - 1):
            seg[ls + k] = 32
        return text, seg, ls, le

    def words(ls: np.ndarray, le: np.ndarray, at: np.ndarray, per_line: int) -> bool:
        return len(at) == len(ls) * per_line and \
            bool(((at[::per_line] >= ls) & (at[per_line - 1::per_line] < le)).all())

    def floats(idx: np.ndarray, skip: int, per_row: int) -> tuple[np.ndarray | None, list]:
        if len(idx) == 0:
            return None, []
        _, seg, ls, le = segment(idx, skip)
        blank = seg <= 32
        word = ~blank
        start = np.flatnonzero(word[1:] & blank[:-1]) + 1  # seg[0] is a blanked keyword
        if words(ls, le, start, per_row):
            values = _fromstring(seg.tobytes(), np.float64, len(idx) * per_row)
            if values is not None:
                return values.reshape(-1, per_row), []
        return None, rows(idx)

    V, v_rows = floats(np.flatnonzero(is_v), 2, 3)
    UV, vt_rows = floats(np.flatnonzero(is_vt), 3, 2)
    idx, faces, f_rows = np.flatnonzero(is_f), None, []
    if len(idx):
        corners = data[starts[idx[0]]:ends[idx[0]]].decode().split()[1:]
        parts = corners[0].count("/") + 1 if corners else 0  # v, v/vt or v/vt/vn, as the first corner reads
        if 1 <= parts <= 3:
            _, seg, ls, le = segment(idx, 2)
            blank = seg <= 32
            start = np.flatnonzero(~blank[1:] & blank[:-1]) + 1
            slash = np.flatnonzero(seg == 47)
            if words(ls, le, start, 3) and len(slash) == len(start) * (parts - 1):
                at = slash.reshape(len(start), parts - 1)  # each corner's slashes, none at its start
                if (parts == 1 or ((at[:, 0] > start) & (at[:, -1] < np.append(start[1:], len(seg)))).all()) \
                        and _ends_in_digit(seg):  # np.fromstring reads a sign alone at the end as 0
                    seg[slash] = 32
                    # an empty index ("1//2", "1/") or a sign apart from its digits reads fewer numbers
                    values = _fromstring(seg.tobytes(), np.int64, 3 * len(idx) * parts)
                    if values is not None:
                        corners = values.reshape(len(idx), 3, parts)
                        faces = corners[:, :, 0].copy(), (corners[:, :, 1].copy() if parts > 1 else None)
        if faces is None:
            f_rows = rows(idx)
    mtllib = None
    for i in np.flatnonzero(b0 == 109).tolist():
        if data.startswith(b"mtllib ", starts[i]):
            mtllib = data[starts[i]:ends[i]].decode().split(maxsplit=1)[1].strip()
            break
    return V, UV, faces, (v_rows, vt_rows, f_rows), mtllib


def _resolve_index(idx: np.ndarray, count: int) -> np.ndarray:
    """OBJ indices are 1-based; negative ones count back from the end."""
    return np.where(idx < 0, count + idx, idx - 1) if (idx < 0).any() else idx - 1


#: what :func:`reading_once` remembers: (kind, resolved path, size, modification time, options) -> the first
#: read's result; None outside it, where every read parses its file
_READ_ONCE: dict | None = None
_Read = TypeVar("_Read")


@contextmanager
def reading_once() -> Iterator[None]:
    """Within the block, :func:`read_obj` and :func:`read_ply` parse each file once.

    A later read of the same file (the same resolved path, size and modification time, the same options)
    returns a deep copy of the first read's result, so every caller gets arrays of its own, exactly as
    from the file. A metrics job reads its mesh four times and the scans twice each (one family after
    another, each from the paths: ``gpja.metrics.evaluate``). Nested blocks share the outermost memo,
    which is dropped when it ends.
    """
    global _READ_ONCE
    outer = _READ_ONCE
    if outer is None:
        _READ_ONCE = {}
    try:
        yield
    finally:
        _READ_ONCE = outer


def _remembered(kind: str, path: Path, options: tuple, read: Callable[[], _Read]) -> _Read:
    """``read()``, or inside :func:`reading_once` a copy of its first result for this file."""
    if _READ_ONCE is None:
        return read()
    try:
        stat = path.stat()
    except OSError:
        return read()  # missing or unreadable: the reader says so
    key = (kind, str(path.resolve()), stat.st_size, stat.st_mtime_ns, options)
    if key not in _READ_ONCE:
        _READ_ONCE[key] = read()
    return copy.deepcopy(_READ_ONCE[key])


def read_obj(path: str | Path, load_texture: bool = True) -> TexturedMesh:
    """Read an OBJ (triangles or polygons; ``v``, ``vt``, ``f``, ``mtllib``/``map_Kd``).

    Lines are recognised by their first characters exactly (``v ``, ``vt ``, ``f ``, ``mtllib ``); ``vn``, comments,
    groups and the rest are skipped. :func:`_scan_obj` reads the file's bytes; the text path below is what it
    vectorises, and reads what it leaves. Inside :func:`reading_once` a file is parsed once.

    Raises:
        InputError: missing file, malformed lines, out-of-range indices, NaN
        coordinates, empty mesh, or a referenced texture that cannot be read.
    """
    path = Path(path)
    return _remembered("obj", path, (load_texture,), lambda: _parse_obj_file(path, load_texture))


def _parse_obj_file(path: Path, load_texture: bool) -> TexturedMesh:
    """:func:`read_obj`'s reading, every time it is called."""
    if not path.is_file():
        raise InputError(path, "mesh file not found")
    data = path.read_bytes()
    scan = _scan_obj(data)
    if scan is not None:
        V, UV, faces, (v_rows, vt_rows, f_lines), mtllib = scan
    else:
        try:
            text = data.decode("utf-8")
        except UnicodeDecodeError:
            raise InputError(path, "not a text OBJ file") from None
        V = UV = faces = mtllib = None
        v_rows, vt_rows, f_lines = [], [], []
        for lineno, line in enumerate(text.replace("\r\n", "\n").replace("\r", "\n").splitlines(), 1):
            if line.startswith("v "):
                v_rows.append((lineno, line))
            elif line.startswith("vt "):
                vt_rows.append((lineno, line))
            elif line.startswith("f "):
                f_lines.append((lineno, line))
            elif line.startswith("mtllib ") and mtllib is None:
                mtllib = line.split(maxsplit=1)[1].strip()

    def floats(rows, n, skip):
        fast = _parse_numbers(rows, skip, n, np.float64)
        if fast is not None:
            return fast
        try:  # extra columns (vertex colours, a w), or something malformed: line by line
            return np.array([r.split()[1:n + 1] for _, r in rows], dtype=np.float64).reshape(-1, n)
        except ValueError:
            raise InputError(path, f"malformed coordinates near line {rows[0][0] if rows else 0}") from None

    if V is None:
        V = floats(v_rows, 3, 2)
    if UV is None and vt_rows:
        UV = floats(vt_rows, 2, 3)
    F, F_uv = faces or _parse_triangles(f_lines) or _parse_faces(f_lines, path)
    F = _resolve_index(F, len(V))
    if F_uv is not None:
        if UV is None:
            raise InputError(path, "faces reference texture coordinates but the file has no 'vt' lines")
        F_uv = _resolve_index(F_uv, len(UV))
    else:
        UV = None
    texture = None
    if load_texture and mtllib is not None:
        tex_path = _texture_from_mtl(path.parent / mtllib)
        if tex_path is not None:
            texture = read_image(tex_path)
    return TexturedMesh(V=V, F=F, UV=UV, F_uv=F_uv, texture=texture).validate(path)


def referenced_texture(path: str | Path) -> Path | None:
    """The texture image an OBJ's material library (its first ``mtllib``) references, or None."""
    path = Path(path)
    if not path.is_file():
        raise InputError(path, "mesh file not found")
    for line in path.read_text(encoding="utf-8", errors="replace").splitlines():
        if line.startswith("mtllib "):
            return _texture_from_mtl(path.parent / line.split(maxsplit=1)[1].strip())
    return None


def _texture_from_mtl(mtl: Path) -> Path | None:
    """The first ``map_Kd`` image of an MTL file, or None."""
    if not mtl.is_file():
        raise InputError(mtl, "material file referenced by the OBJ not found")
    for line in mtl.read_text(encoding="utf-8", errors="replace").splitlines():
        if line.strip().startswith("map_Kd"):
            return mtl.parent / line.strip().split()[-1]
    return None


# --- PLY scans ----------------------------------------------------------------------------

def read_ply(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """Read a triangle-mesh PLY (ascii or binary), e.g. a raw scan.

    Returns:
        V: (n, 3) float64 positions (file units).
        F: (m, 3) int64 faces.
    Raises:
        InputError: missing, unreadable, empty, or with NaN / out-of-range values.

    Inside :func:`reading_once` a file is parsed once.
    """
    path = Path(path)
    return _remembered("ply", path, (), lambda: _parse_ply_file(path))


def _parse_ply_file(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """:func:`read_ply`'s reading, every time it is called."""
    if not path.is_file():
        raise InputError(path, "scan file not found")
    if path.stat().st_size == 0:
        raise InputError(path, "scan file is empty (0 bytes)")
    fast = _read_own_ply(path)
    if fast is not None:
        V, F = fast
    else:
        import trimesh

        try:
            loaded = trimesh.load(path, file_type="ply", process=False, force="mesh")
        except Exception as err:  # trimesh raises many types for corrupt files
            raise InputError(path, f"corrupt or unreadable PLY ({type(err).__name__}: {err})") from None
        V = np.asarray(getattr(loaded, "vertices", np.zeros((0, 3))), dtype=np.float64)
        F = np.asarray(getattr(loaded, "faces", np.zeros((0, 3))), dtype=np.int64)
    TexturedMesh(V, F).validate(path)
    return V, F


#: The header :func:`write_ply` writes, up to its two counts (``_read_own_ply``).
_OWN_PLY_HEADER = re.compile(
    rb"ply\nformat binary_little_endian 1\.0\n(?:comment [^\n]*\n)*element vertex (\d+)\n"
    rb"property double x\nproperty double y\nproperty double z\n"
    rb"element face (\d+)\nproperty list uchar int vertex_indices\nend_header\n")


def _read_own_ply(path: Path) -> tuple[np.ndarray, np.ndarray] | None:
    """The PLY layout :func:`write_ply` writes, read with numpy; None for any other file (trimesh reads those).

    Written here rather than left to trimesh because every job of a run reads the synthetic scans, which are in
    this one layout: 0.02 s against trimesh's 0.28 s a 200K-vertex scan, and no 0.4 s trimesh import, in about
    110 jobs of the default run. The arrays are trimesh's to the bit (``tests/test_mesh.py``).

    Raises:
        InputError: the header is this layout's but the file is shorter or longer than its counts say, or a
            face is not a triangle.
    """
    with open(path, "rb") as fh:
        head = fh.read(4096)
        match = _OWN_PLY_HEADER.match(head)
        if match is None:
            return None
        n_vertices, n_faces = int(match.group(1)), int(match.group(2))
        fh.seek(match.end())
        body = fh.read()
    face_dtype = np.dtype([("n", "u1"), ("idx", "<i4", (3,))])
    expected = 24 * n_vertices + face_dtype.itemsize * n_faces
    if len(body) != expected:
        raise InputError(path, f"corrupt PLY: {len(body)} bytes of data where its header's {n_vertices} vertices "
                               f"and {n_faces} triangles need {expected}")
    V = np.frombuffer(body, dtype="<f8", count=3 * n_vertices).reshape(-1, 3).astype(np.float64)
    faces = np.frombuffer(body, dtype=face_dtype, count=n_faces, offset=24 * n_vertices)
    if n_faces and (faces["n"] != 3).any():
        raise InputError(path, "corrupt PLY: a face of the vertex_indices list is not a triangle")
    return V, faces["idx"].astype(np.int64)


def write_ply(path: str | Path, V: np.ndarray, F: np.ndarray) -> None:
    """Write positions ``V (n, 3)`` and faces ``F (m, 3)`` as binary PLY, atomically.

    Positions are stored as float64 (trimesh's exporter writes float32, which
    would lose the ground-truth precision synthetic scans need).
    """
    V = np.ascontiguousarray(V, dtype="<f8").reshape(-1, 3)
    F = np.asarray(F, dtype=np.int64).reshape(-1, 3)
    header = ("ply\nformat binary_little_endian 1.0\ncomment written by gpja\n"
              f"element vertex {len(V)}\nproperty double x\nproperty double y\nproperty double z\n"
              f"element face {len(F)}\nproperty list uchar int vertex_indices\nend_header\n")
    faces = np.empty(len(F), dtype=[("n", "u1"), ("idx", "<i4", (3,))])
    faces["n"] = 3
    faces["idx"] = F
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        fh.write(header.encode("ascii"))
        fh.write(V.tobytes())
        fh.write(faces.tobytes())
