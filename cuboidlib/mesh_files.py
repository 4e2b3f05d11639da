"""Reading mesh files: OBJ, OFF and PLY exactly as written, polygons triangulated inside their outlines; STL, GLB
and GLTF through trimesh, after checking that the file is whole.

A file is read exactly as it is written or refused with a ``ValueError`` that names the file, the problem and
what was expected (a face index that is no vertex, a file cut short, a polygon that crosses itself).
"""

from __future__ import annotations

import re
import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh

from .file_tables import (LABEL_NAMES, LINE_END, NUMBER_TOKEN, after_line_end, are_whole, as_labels,
                          check_row_counts, concat_ranges, parse_numbers, ply_vertex_table, read_number_rows, read_ply,
                          strip_comments)
from .files import parse_json, read_file_bytes

__all__ = ["POLYGON_MESH_SUFFIXES", "PolygonMesh", "read_polygon_mesh", "triangulate_polygons", "load_triangle_mesh"]

#: The mesh formats read here (the others go through trimesh).
POLYGON_MESH_SUFFIXES = (".obj", ".off", ".ply")

#: Names of the list of a PLY face's vertex indices.
_FACE_LISTS = ("vertex_indices", "vertex_index")

# -------------------------------------------------------------------------------------- polygon meshes


@dataclass
class PolygonMesh:
    """Vertices and polygons as a file holds them.

    Attributes:
        vertices: (V, 3) float64.
        sizes: (F,) int64, the number of vertices of each polygon (>= 3).
        indices: (sizes.sum(),) int64, the 0-based vertex indices of every polygon, concatenated.
        labels: (F,) int64 per-polygon part labels, or None.
    """

    vertices: np.ndarray
    sizes: np.ndarray
    indices: np.ndarray
    labels: np.ndarray | None = None


def _check_polygons(path, mesh: PolygonMesh) -> PolygonMesh:
    """Refuse polygons of fewer than 3 vertices and indices that are not vertices of the mesh."""
    if mesh.sizes.size and mesh.sizes.min() < 3:
        k = int(np.argmin(mesh.sizes))
        raise ValueError(f"{path}: face {k} has {int(mesh.sizes[k])} vertices; a face needs at least 3")
    v = len(mesh.vertices)
    if mesh.indices.size and not are_whole(mesh.indices.astype(np.float64), 0, v - 1):
        wrong = mesh.indices[(mesh.indices != np.round(mesh.indices)) | (mesh.indices < 0) | (mesh.indices >= v)]
        bad = wrong[0].item()
        raise ValueError(f"{path}: a face refers to vertex {bad:g}, but the mesh has {v} vertices "
                         f"(indices 0 to {v - 1})")
    mesh.indices = mesh.indices.astype(np.int64)
    return mesh


def _ply_mesh(path) -> PolygonMesh:
    _, elements = read_ply(path)
    props = ply_vertex_table(path, elements)
    vertices = np.stack([props[k] for k in "xyz"], axis=1).astype(np.float64)
    strips = next((e for e in elements if e.name == "tristrips" and e.count), None)
    if strips is not None:
        raise ValueError(f"{path}: PLY triangle strips ('tristrips') are not supported; export faces instead")
    face = next((e for e in elements if e.name == "face"), None)
    if face is None or face.count == 0:
        raise ValueError(f"{path}: the PLY file holds no faces; it is a point cloud (read it with read_point_cloud)")
    name = next((k for k in _FACE_LISTS if isinstance(face.data.get(k), tuple)), None)
    if name is None:
        raise ValueError(f"{path}: PLY faces have no vertex index list (expected a list property named "
                         f"{' or '.join(_FACE_LISTS)})")
    sizes, indices = face.data[name]
    label = next((face.data[k] for k in LABEL_NAMES if k in face.data and not isinstance(face.data[k], tuple)), None)
    labels = None if label is None else as_labels(label, f"{path} (face labels)")
    return _check_polygons(path, PolygonMesh(vertices, sizes, indices, labels))


# ----------------------------------------------------------------------------------------------- OBJ

#: OBJ statements that hold no surface geometry (names, groups, materials, smoothing, lines, points).
_OBJ_SKIPPED = frozenset(("o", "g", "s", "usemtl", "mtllib", "maplib", "usemap", "lod", "bevel", "c_interp",
                          "d_interp", "shadow_obj", "trace_obj", "ctech", "stech", "mg", "l", "p"))
#: OBJ statements of free-form curves and surfaces, which cuboidlib does not evaluate.
_OBJ_FREE_FORM = frozenset(("vp", "cstype", "deg", "bmat", "step", "curv", "curv2", "surf", "parm", "trim", "hole",
                            "scrv", "sp", "end", "con"))
_INDEX = re.compile(r"[+-]?\d+")


def _obj_statements(path, data: bytes):
    """``(line number, words)`` of every OBJ statement: comments dropped, continued lines ('\\' at the end) joined."""
    lines = LINE_END.split(data)
    k = 0
    while k < len(lines):
        number, line = k + 1, lines[k].decode("latin-1").split("#", 1)[0].rstrip()
        k += 1
        while line.endswith("\\"):
            if k == len(lines):
                raise ValueError(f"{path}: line {number} ends with a line continuation ('\\') but no line follows; "
                                 "the file is cut off")
            line = line[:-1] + " " + lines[k].decode("latin-1").split("#", 1)[0].rstrip()
            k += 1
        words = line.split()
        if words:
            yield number, words


def _obj_index(path, number: int, words: list[str], token: str, count: int, what: str) -> int:
    """The 0-based index an OBJ reference ``token`` names, ``count`` elements of its kind defined so far."""
    if not _INDEX.fullmatch(token):
        raise ValueError(f"{path}: line {number} ({' '.join(words)!r}): {token!r} is not a {what} index; expected a "
                         "whole number (negative ones count back from the last one defined)")
    i = int(token)
    if i == 0:
        raise ValueError(f"{path}: line {number} ({' '.join(words)!r}) refers to {what} 0, but OBJ {what} indices "
                         "start at 1; the file seems to count from 0. Add 1 to every face index (or export it "
                         "again) so that no vertex is dropped or shifted")
    if i < 0 and count + i < 0:
        raise ValueError(f"{path}: line {number} ({' '.join(words)!r}) refers to {what} {i} (counting back), but "
                         f"only {count} are defined before it")
    return count + i if i < 0 else i - 1


def _obj_face(path, number: int, words: list[str], counts: dict) -> list[int]:
    """The 0-based vertex indices of an OBJ face (references v, v/vt, v//vn or v/vt/vn)."""
    if len(words) < 4:
        raise ValueError(f"{path}: line {number} ({' '.join(words)!r}): a face needs at least 3 vertices, "
                         f"it names {len(words) - 1}")
    face = []
    for ref in words[1:]:
        parts = ref.split("/")
        if len(parts) > 3 or (len(parts) >= 2 and not parts[-1]):
            raise ValueError(f"{path}: line {number} ({' '.join(words)!r}): {ref!r} is not a face reference; "
                             "expected v, v/vt, v//vn or v/vt/vn")
        face.append(_obj_index(path, number, words, parts[0], counts["v"], "vertex"))
        for part, kind, what in zip(parts[1:], ("vt", "vn"), ("texture coordinate", "normal")):
            if part:
                _obj_index(path, number, words, part, counts[kind], what)
    return face


def _obj_vertices(path, rows: list[str], numbers: list[int]) -> np.ndarray:
    """The (V, 3) float64 coordinates of the OBJ vertex rows (each 'x y z'), parsed at once."""
    values = parse_numbers(" ".join(rows).encode("ascii", errors="replace")) if rows else np.zeros(0)
    if values is None or len(values) != 3 * len(rows):
        for row, number in zip(rows, numbers):
            bad = [t for t in row.split() if not NUMBER_TOKEN.fullmatch(t.encode("ascii", errors="replace"))]
            if bad:
                raise ValueError(f"{path}: line {number}: vertex coordinate {bad[0]!r} is not a number")
        raise ValueError(f"{path}: a vertex coordinate is not a number")
    return values.reshape(-1, 3)


def _obj_mesh(path) -> PolygonMesh:
    counts = {"v": 0, "vt": 0, "vn": 0}
    rows, row_lines, sizes, flat, ahead = [], [], [], [], []
    for number, words in _obj_statements(path, read_file_bytes(path, "an OBJ file")):
        key = words[0]
        if key == "v":
            if len(words) - 1 not in (3, 4, 6, 7):
                raise ValueError(f"{path}: line {number} ({' '.join(words)!r}): a vertex holds x y z (then "
                                 f"optionally w, or r g b); it has {len(words) - 1} values")
            rows.append(" ".join(words[1:4]))
            row_lines.append(number)
            counts["v"] += 1
        elif key in ("vt", "vn"):
            counts[key] += 1
        elif key in ("f", "fo"):
            face = _obj_face(path, number, words, counts)
            if max(face) >= counts["v"]:
                ahead.append((number, words, max(face)))
            sizes.append(len(face))
            flat += face
        elif key in _OBJ_FREE_FORM:
            raise ValueError(f"{path}: line {number}: '{key}' belongs to a free-form curve or surface, which "
                             "cuboidlib does not read; export the model as polygons")
        elif key not in _OBJ_SKIPPED:
            raise ValueError(f"{path}: line {number}: unknown OBJ statement {key!r} (expected v, vt, vn, f, o, g, "
                             "s, usemtl, mtllib, l or p)")
    for number, words, top in ahead:
        if top >= counts["v"]:
            raise ValueError(f"{path}: line {number} ({' '.join(words)!r}) refers to vertex {top + 1}, but the "
                             f"file defines {counts['v']} vertices")
    vertices = _obj_vertices(path, rows, row_lines)
    return PolygonMesh(vertices, np.array(sizes, dtype=np.int64), np.array(flat, dtype=np.int64))


# ----------------------------------------------------------------------------------------------- OFF

_OFF_KEYWORD = re.compile(rb"(ST)?(C)?(N)?(4)?(n)?OFF")


def _next_line(data: bytes, pos: int) -> tuple[bytes, int]:
    """The line starting at ``pos`` (without its end) and the offset of the next one."""
    stop = after_line_end(data, pos)
    return data[pos:stop].rstrip(b"\r\n"), stop


def _off_header(path, data: bytes) -> tuple[bytes, list[bytes], int, int]:
    """The keyword, the counts, the body offset and the number of header lines of an OFF file."""
    pos, line_no, words = 0, 0, []
    while not words and pos < len(data):
        line, pos = _next_line(data, pos)
        line_no, words = line_no + 1, line.split()
    if not words or not _OFF_KEYWORD.fullmatch(words[0]):
        shown = words[0][:20].decode("ascii", errors="replace") if words else ""
        raise ValueError(f"{path}: not an OFF file (its first word is {shown!r}, expected 'OFF')")
    keyword, counts = words[0], words[1:]
    if counts[:1] == [b"BINARY"]:
        raise ValueError(f"{path}: binary OFF files are not supported; save it as ASCII OFF, PLY or OBJ")
    if b"4" in keyword or b"n" in keyword:
        raise ValueError(f"{path}: {keyword.decode()} files hold vertices of other than 3 dimensions; expected OFF")
    while not counts and pos < len(data):
        line, pos = _next_line(data, pos)
        line_no, counts = line_no + 1, line.split()
    if len(counts) not in (2, 3) or not all(re.fullmatch(rb"\d+", c) for c in counts):
        shown = b" ".join(counts).decode("ascii", errors="replace")
        raise ValueError(f"{path}: the OFF counts line reads {shown!r}; expected 'vertices faces edges' "
                         "(whole numbers)")
    return keyword, counts, pos, line_no


def _off_mesh(path) -> PolygonMesh:
    data = strip_comments(read_file_bytes(path, "an OFF file"))
    keyword, counts, body, header_lines = _off_header(path, data)
    nv, nf = int(counts[0]), int(counts[1])
    rows = read_number_rows(path, data, body, header_lines + 1, "OFF body")
    check_row_counts(path, rows, [("vertex", nv), ("face", nf)], "OFF")
    least = 3 + 3 * (b"N" in keyword) + 2 * keyword.startswith(b"ST") + 3 * (b"C" in keyword)
    widths = rows.widths[:nv]
    if nv and (widths.min() < least or widths.max() != widths.min()):
        k = int(np.argmax(widths != widths[0])) if widths.min() >= least else int(np.argmin(widths))
        raise ValueError(f"{path}: OFF vertex rows must all hold the same number of values, at least {least} "
                         f"(x y z ...); line {int(rows.lines[k])} holds {int(widths[k])}, line "
                         f"{int(rows.lines[0])} {int(widths[0])}")
    vertices = rows.values[rows.starts[:nv, None] + np.arange(3)]
    starts, widths = rows.starts[nv:], rows.widths[nv:]
    sizes = rows.values[starts]
    bad = (sizes != np.round(sizes)) | (sizes < 3) | (widths < 1 + sizes) | (widths > 5 + sizes)
    if bad.any():
        k = int(np.argmax(bad))
        raise ValueError(f"{path}: OFF face row at line {int(rows.lines[nv + k])} declares {sizes[k]:g} vertices and "
                         f"holds {int(widths[k])} values; a face row is 'n i1 .. in' (n >= 3), then at most 4 "
                         "colour values")
    sizes = sizes.astype(np.int64)
    indices = rows.values[concat_ranges(starts + 1, sizes)]
    return _check_polygons(path, PolygonMesh(vertices, sizes, indices))


# ------------------------------------------------------------------------------------- triangulation

#: How far (relative to its size) a vertex of a non-convex polygon may lie from the polygon's plane.
_PLANAR = 1e-2

#: The most vertices of a non-convex polygon that is ear-clipped (the check that it is simple takes memory
#: quadratic in them).
_MAX_EAR_CLIPPED = 1000


def _cross2(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]


def _convex(corners: np.ndarray) -> np.ndarray:
    """Which of the (m, k, 3) polygons are convex and simple seen along their normal (a fan from any vertex fits)."""
    c = corners - corners.mean(axis=1, keepdims=True)
    edges = np.roll(c, -1, axis=1) - c  # edge i runs from vertex i to i + 1
    normal = np.cross(c, np.roll(c, -1, axis=1)).sum(axis=1)  # Newell's normal: twice the area vector
    length = np.linalg.norm(normal, axis=1)
    unit = normal / np.where(length > 0, length, 1.0)[:, None]
    incoming = np.roll(edges, 1, axis=1)
    turn = np.einsum("mkj,mj->mk", np.cross(incoming, edges), unit)  # the turn at each vertex, seen along n
    along_in, along_out = np.einsum("mkj,mj->mk", incoming, unit), np.einsum("mkj,mj->mk", edges, unit)
    dots = (incoming * edges).sum(axis=-1) - along_in * along_out  # the dot product of the projected edges
    scale = np.linalg.norm(incoming, axis=-1) * np.linalg.norm(edges, axis=-1)
    winding = np.arctan2(turn, dots).sum(axis=1)
    return (length > 0) & (turn >= -1e-9 * scale).all(axis=1) & (np.abs(winding - 2 * np.pi) < 1e-6)


def _simple(xy: np.ndarray) -> bool:
    """Whether the closed 2D outline ``xy`` has no two non-adjacent edges that meet."""
    k = len(xy)
    a, b = xy, np.roll(xy, -1, axis=0)
    d1 = _cross2((b - a)[:, None], a[None] - a[:, None])  # [i, j]: side of edge j's start from edge i
    d2 = _cross2((b - a)[:, None], b[None] - a[:, None])
    lo, hi = np.minimum(a, b), np.maximum(a, b)
    boxes = np.all((lo[:, None] <= hi[None]) & (lo[None] <= hi[:, None]), axis=-1)
    meet = (d1 * d2 <= 0) & (d1.T * d2.T <= 0) & boxes
    i, j = np.triu_indices(k, 2)
    adjacent = (j - i == 1) | ((i == 0) & (j == k - 1))
    return not bool(meet[i[~adjacent], j[~adjacent]].any())


def _ear_clip(xy: np.ndarray, eps: float) -> list[tuple[int, int, int]]:
    """Triangles (indices into ``xy``) of the counter-clockwise simple polygon ``xy``, by ear clipping."""
    idx, out = list(range(len(xy))), []
    while len(idx) > 3:
        pts = xy[idx]
        prev, nxt = np.roll(pts, 1, axis=0), np.roll(pts, -1, axis=0)
        turn = _cross2(pts - prev, nxt - pts)
        straight = np.flatnonzero((np.abs(turn) <= eps) & (((pts - prev) * (nxt - pts)).sum(axis=1) >= 0))
        if straight.size:  # a vertex on the line of its neighbours bounds no area
            del idx[int(straight[0])]
            continue
        m = len(idx)
        for t in np.flatnonzero(turn > eps):
            a, b, c = prev[t], pts[t], nxt[t]
            rest = np.delete(pts, [(t - 1) % m, t, (t + 1) % m], axis=0)
            inside = ((_cross2(b - a, rest - a) >= -eps) & (_cross2(c - b, rest - b) >= -eps)
                      & (_cross2(a - c, rest - c) >= -eps))
            if not inside.any():
                out.append((idx[(t - 1) % m], idx[t], idx[(t + 1) % m]))
                del idx[t]
                break
        else:
            return []
    if abs(_cross2(xy[idx[1]] - xy[idx[0]], xy[idx[2]] - xy[idx[0]])) > eps:
        out.append(tuple(idx))
    return out


def _triangulate_one(corners: np.ndarray, source: str, face: int) -> np.ndarray:
    """Triangles (indices into ``corners``) of a polygon that is not convex, or refused with the reason."""
    k = len(corners)
    if k > _MAX_EAR_CLIPPED:
        raise ValueError(f"{source}: face {face} has {k} vertices and is not convex; cuboidlib triangulates such faces "
                         f"of at most {_MAX_EAR_CLIPPED} vertices. Triangulate it in your modeller")
    c = corners - corners.mean(axis=0)
    size = float(np.linalg.norm(np.ptp(c, axis=0)))
    normal = np.cross(c, np.roll(c, -1, axis=0)).sum(axis=0)
    area = float(np.linalg.norm(normal)) / 2
    fan = np.stack([np.zeros(k - 2, dtype=np.int64), np.arange(1, k - 1), np.arange(2, k)], axis=1)
    if area <= 1e-12 * size**2:
        spread = np.linalg.norm(np.cross(c[fan[:, 1]] - c[fan[:, 0]], c[fan[:, 2]] - c[fan[:, 0]]), axis=1).sum()
        if spread <= 1e-12 * size**2:
            return fan  # every vertex on one line: no area to sample
        raise ValueError(f"{source}: face {face} ({k} vertices) crosses itself (its outline encloses no net area); "
                         "fix or remove it")
    unit = normal / (2 * area)
    if np.abs(c @ unit).max() > _PLANAR * size:
        raise ValueError(f"{source}: face {face} ({k} vertices) is neither convex nor planar (its vertices lie up to "
                         f"{np.abs(c @ unit).max() / size:.2g} of its size off its plane), so it has no one surface; "
                         "triangulate it in your modeller")
    u = np.cross(unit, np.eye(3)[int(np.argmin(np.abs(unit)))])
    u /= np.linalg.norm(u)
    xy = np.stack([c @ u, c @ np.cross(unit, u)], axis=1)  # counter-clockwise: (u, n x u, n) is right-handed
    triangles = _ear_clip(xy, 1e-12 * size**2) if _simple(xy) else []
    if not triangles:
        raise ValueError(f"{source}: face {face} ({k} vertices) crosses or touches itself, so it cannot be "
                         "triangulated inside its outline; fix or remove it")
    return np.array(triangles, dtype=np.int64)


def triangulate_polygons(vertices: np.ndarray, sizes: np.ndarray, indices: np.ndarray,
                         source: str = "mesh") -> tuple[np.ndarray, np.ndarray]:
    """Triangulate polygons inside their outlines.

    Convex polygons (seen along their normal) are fanned from their first vertex; the others, if planar (within
    1 % of their size) and simple, are ear-clipped in their plane, so that every triangle lies inside the polygon.

    Args:
        vertices: (V, 3).
        sizes: (F,) vertex counts, each >= 3.
        indices: (sizes.sum(),) vertex indices of the polygons, concatenated.
        source: names the mesh in messages.

    Returns:
        ``(triangles, polygon)``: (T, 3) int64 vertex indices and (T,) int64 the polygon of each triangle, in the
        order of the polygons.

    Raises:
        ValueError: a polygon crosses itself, or is neither convex nor planar.
    """
    sizes = np.asarray(sizes, dtype=np.int64)
    offsets = np.cumsum(sizes) - sizes
    triangles, owners = [np.zeros((0, 3), dtype=np.int64)], [np.zeros(0, dtype=np.int64)]
    for k in np.unique(sizes).tolist():
        which = np.flatnonzero(sizes == k)
        poly = indices[offsets[which, None] + np.arange(k)]
        if k == 3:
            triangles.append(poly)
            owners.append(which)
            continue
        convex = _convex(vertices[poly])
        fan = np.stack([np.repeat(poly[convex, :1], k - 2, axis=1), poly[convex, 1:-1], poly[convex, 2:]], axis=2)
        triangles.append(fan.reshape(-1, 3))
        owners.append(np.repeat(which[convex], k - 2))
        for j in np.flatnonzero(~convex):
            local = _triangulate_one(vertices[poly[j]], source, int(which[j]))
            triangles.append(poly[j][local])
            owners.append(np.full(len(local), which[j], dtype=np.int64))
    owner = np.concatenate(owners)
    order = np.argsort(owner, kind="stable")
    return np.concatenate(triangles)[order], owner[order]


# -------------------------------------------------------------------------------------------- any mesh

_READERS = {".obj": _obj_mesh, ".off": _off_mesh, ".ply": _ply_mesh}


def read_polygon_mesh(path: str | Path) -> PolygonMesh:
    """Read an OBJ, OFF or PLY mesh exactly as the file holds it.

    OBJ: v (x y z, optionally w or r g b), f with references v, v/vt, v//vn or v/vt/vn (negative ones count back
    from the last vertex defined), any number of objects and groups, comments, '\\' line continuations; free-form
    geometry and unknown statements are refused. OFF: [ST][C][N]OFF with counts, '#' comments. PLY: ASCII or
    binary, a face list 'vertex_indices' and an optional per-face 'label'. Line ends LF, CRLF or CR; a UTF-8
    byte order mark is skipped; compressed files are refused.

    Args:
        path: the file; its suffix (.obj, .off, .ply) chooses the reader.

    Returns:
        The vertices and polygons (labels from a PLY face property named as in ``LABEL_NAMES``).

    Raises:
        ValueError: anything the file holds that cannot be read exactly: truncated or malformed content, a face
            index that is no vertex, a face of fewer than 3 vertices.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in _READERS:
        raise ValueError(f"{path}: not a polygon mesh file read here ({suffix!r}; expected one of "
                         f"{', '.join(POLYGON_MESH_SUFFIXES)})")
    return _READERS[suffix](path)


# ------------------------------------------------------------------------------- STL, GLB, GLTF


def _check_glb(path: Path, data: bytes) -> None:
    """Refuse a GLB file whose header, chunks or buffers claim more bytes than the file holds."""
    if len(data) < 20:
        raise ValueError(f"{path}: unreadable mesh: an empty or truncated GLB file ({len(data)} bytes; a GLB has a 12-byte header "
                         "and at least one chunk)")
    magic, version, length = struct.unpack_from("<4sII", data)
    if magic != b"glTF":
        raise ValueError(f"{path}: unreadable mesh: not a GLB file (it does not start with 'glTF')")
    if length != len(data):
        raise ValueError(f"{path}: unreadable mesh: the GLB header declares {length:,} bytes but the file has {len(data):,}; "
                         "it is truncated or damaged")
    offset, chunks = 12, {}
    while offset + 8 <= length:
        size, kind = struct.unpack_from("<I4s", data, offset)
        if offset + 8 + size > length:
            raise ValueError(f"{path}: unreadable mesh: a GLB chunk declares {size:,} bytes, beyond the end of the file "
                             f"({length:,} bytes); it is truncated or damaged")
        chunks.setdefault(kind, data[offset + 8:offset + 8 + size])
        offset += 8 + size
    try:
        doc = parse_json(chunks.get(b"JSON", b""), f"{path}: the GLB's JSON chunk")
    except ValueError as exc:
        raise ValueError(f"{path}: unreadable mesh: the GLB's JSON chunk is missing or unreadable ({exc})") from exc
    binary = len(chunks.get(b"BIN\x00", b""))
    for k, buffer in enumerate(doc.get("buffers", []) if isinstance(doc, dict) else []):
        claimed = buffer.get("byteLength") if isinstance(buffer, dict) else None
        if isinstance(buffer, dict) and "uri" not in buffer and (not isinstance(claimed, int) or claimed > binary):
            raise ValueError(f"{path}: unreadable mesh: GLB buffer {k} claims {claimed!r} bytes but the file's binary chunk holds "
                             f"{binary:,}; it is damaged")


def _check_stl(path: Path, data: bytes) -> None:
    """Refuse an STL file cut short: binary, shorter or longer than its triangle count says; ASCII, without its
    closing 'endsolid' line."""
    if len(data) >= 84 and 84 + 50 * struct.unpack_from("<I", data, 80)[0] == len(data):
        return  # binary, complete (its 80-byte header may start with 'solid' too)
    if data.lstrip().startswith(b"solid"):
        last = data.rstrip().rsplit(b"\n", 1)[-1].strip()
        if not last.startswith(b"endsolid"):
            raise ValueError(f"{path}: unreadable mesh: the ASCII STL file does not end with an 'endsolid' line; it is "
                             "truncated")
        return
    count = struct.unpack_from("<I", data, 80)[0] if len(data) >= 84 else None
    declared = f"its header declares {count:,} triangles ({84 + 50 * count:,} bytes)" if count is not None else (
        "a binary STL file has at least 84 bytes")
    raise ValueError(f"{path}: unreadable mesh: {declared}, but the file has {len(data):,} bytes; it is truncated or "
                     "damaged")


def _trimesh_scene_mesh(path: Path) -> trimesh.Trimesh:
    """A mesh file trimesh reads (STL, GLB, GLTF) as one mesh, every node's transform baked in."""
    try:
        loaded = trimesh.load(str(path), process=False)
    except Exception as exc:  # noqa: BLE001 - re-raised with the file name
        raise ValueError(f"{path}: unreadable mesh ({type(exc).__name__}: {exc})") from exc
    if isinstance(loaded, trimesh.Scene):
        vertices, faces, count = [], [], 0
        for node in loaded.graph.nodes_geometry:
            transform, name = loaded.graph[node]
            geom = loaded.geometry.get(name)
            if isinstance(geom, trimesh.Trimesh) and len(geom.faces):
                vertices.append(trimesh.transform_points(geom.vertices, transform))
                faces.append(geom.faces + count)
                count += len(geom.vertices)
        if not faces:
            raise ValueError(f"{path}: the mesh is empty (the file holds no triangles)")
        loaded = trimesh.Trimesh(np.concatenate(vertices), np.concatenate(faces), process=False)
    if not isinstance(loaded, trimesh.Trimesh):
        raise ValueError(f"{path}: contains no faces ({type(loaded).__name__}); for a point cloud use read_point_cloud")
    return loaded


def load_triangle_mesh(path: str | Path) -> tuple[trimesh.Trimesh, np.ndarray | None]:
    """Read a mesh file as triangles: OBJ, OFF and PLY by :func:`read_polygon_mesh` and
    :func:`triangulate_polygons`; STL, GLB and GLTF by trimesh (every node's transform baked in), once the file is
    found whole.

    Args:
        path: an existing mesh file.

    Returns:
        ``(mesh, labels)``: the unprocessed trimesh (vertices as the file holds them) and the (T,) int64 part
        label of each triangle, from a PLY face property named as in ``LABEL_NAMES``, or None.

    Raises:
        ValueError: unreadable, truncated or empty, a face index that is no vertex, NaN or infinite
            coordinates, no surface area.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    labels = None
    if suffix in POLYGON_MESH_SUFFIXES:
        polygons = read_polygon_mesh(path)
        if not len(polygons.sizes):
            raise ValueError(f"{path}: the mesh is empty (the file holds no faces)")
        if not np.isfinite(polygons.vertices).all():
            raise ValueError(f"{path}: the mesh has NaN or infinite vertex coordinates")
        triangles, owner = triangulate_polygons(polygons.vertices, polygons.sizes, polygons.indices, str(path))
        labels = None if polygons.labels is None else polygons.labels[owner]
        loaded = trimesh.Trimesh(polygons.vertices, triangles, process=False)
    else:
        data = read_file_bytes(path, f"a {suffix} mesh")
        if suffix == ".glb":
            _check_glb(path, data)
        elif suffix == ".stl":
            _check_stl(path, data)
        loaded = _trimesh_scene_mesh(path)
    if len(loaded.faces) == 0:
        raise ValueError(f"{path}: the mesh is empty (the file holds no triangles)")
    faces = np.asarray(loaded.faces)
    if faces.min() < 0 or faces.max() >= len(loaded.vertices):
        bad = faces.max() if faces.max() >= len(loaded.vertices) else faces.min()
        raise ValueError(f"{path}: a face refers to vertex {bad}, but the mesh has {len(loaded.vertices)} vertices")
    if not np.isfinite(loaded.vertices).all():
        raise ValueError(f"{path}: the mesh has NaN or infinite vertex coordinates")
    if loaded.area <= 0:
        raise ValueError(f"{path}: the mesh has zero surface area (all triangles are degenerate)")
    return loaded, labels
