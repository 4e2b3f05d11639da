"""Reading and writing the shape files a user brings (meshes, point clouds, dataset layouts) and the samples.

Every format is read into one :class:`PointCloud` through one validation, so a malformed file of any format
fails with the same kind of message, naming the file (``FileNotFoundError`` if missing, else ``ValueError``).
:func:`load_point_cloud` is the entry point of the dataset and the command line: it reads, validates,
subsamples, estimates missing normals and normalises (:mod:`cuboidlib.normalization`), keeping
``(center, scale)`` so results can be written back in the user's coordinates.
"""

from __future__ import annotations

import csv
import json
import os
import re
import sys
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh

from ._checks import MAX_SHAPE_POINTS, check_size
from .files import atomic_path
from .normalization import normalize
from .normals import estimate_normals, orient_normals
from .shapes import CATEGORIES, PART_NAMES, make_shape, plot_shapes

__all__ = [
    "PointCloud",
    "MESH_SUFFIXES",
    "POINT_CLOUD_SUFFIXES",
    "read_point_cloud",
    "write_point_cloud",
    "read_labels",
    "load_mesh_as_point_cloud",
    "load_point_cloud",
    "is_mesh_file",
    "validate_point_cloud",
    "SHAPENET_PART_IDS",
    "shapenet_part_labels",
    "shapenet_part_files",
    "authors_layout_files",
    "write_shape_mesh",
    "write_data_samples",
    "data_sample_files",
]

MESH_SUFFIXES = (".obj", ".ply", ".off", ".stl", ".glb", ".gltf")
POINT_CLOUD_SUFFIXES = (".ply", ".txt", ".pts", ".xyz", ".npy")

#: ShapeNet-part "normal" layout: the 50 global part ids of the three categories used by the
#: paper, in the order of ``PART_NAMES``. Table ids are (top, leg, support); as in the paper
#: (Sec. 4.2) "support" is merged into "leg".
SHAPENET_PART_IDS: dict[str, dict[int, int]] = {
    "airplane": {0: 0, 1: 1, 2: 2, 3: 3},
    "chair": {12: 0, 13: 1, 14: 2, 15: 3},
    "table": {47: 0, 48: 1, 49: 1},
}


@dataclass
class PointCloud:
    """A point cloud with optional normals and labels.

    Attributes:
        points: (N, 3): float32 once normalised (:func:`load_point_cloud`), float64 as read from a file.
        normals: (N, 3) float32 unit normals, or None.
        labels: (N,) int64 part labels, or None.
        center, scale: (3,) float64 and a float, the normalisation applied: the original coordinates
            are ``points * scale + center`` (identity when not normalised).
        source: the file it came from (for messages), or None.
    """

    points: np.ndarray
    normals: np.ndarray | None = None
    labels: np.ndarray | None = None
    center: np.ndarray | None = None
    scale: float = 1.0
    source: str | None = None

    def __post_init__(self):
        if self.center is None:
            self.center = np.zeros(3)

    def __len__(self) -> int:
        return int(self.points.shape[0])


def _check_file(path) -> Path:
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such file")
    if not path.is_file():
        raise ValueError(f"{path}: not a file")
    return path


def validate_point_cloud(points: np.ndarray, normals: np.ndarray | None = None, labels: np.ndarray | None = None,
                         source: str = "point cloud", n_points: int | None = None) -> None:
    """Raise ``ValueError`` naming ``source`` when the arrays are not a usable point cloud.

    Args:
        points: (N, 3), N >= 1, finite, not all identical.
        normals: optional (N, 3), finite, no zero vector.
        labels: optional (N,).
        source: names the cloud in messages (a file name).
        n_points: if given, the least N accepted.
    """
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"{source}: points must have shape (N, 3), got {points.shape}")
    n = points.shape[0]
    if n == 0:
        raise ValueError(f"{source}: contains no points")
    bad = ~np.isfinite(points).all(axis=1)
    if bad.any():
        raise ValueError(f"{source}: {int(bad.sum())} point(s) have NaN or infinite coordinates "
                         f"(first at row {int(np.argmax(bad))}); clean or drop them first")
    if n_points is not None and n < n_points:
        raise ValueError(f"{source}: has only {n} points, fewer than the {n_points} asked for")
    if np.ptp(points, axis=0).max() == 0:
        raise ValueError(f"{source}: all {n} points are identical; the shape is degenerate")
    if normals is not None:
        if normals.shape != points.shape:
            raise ValueError(f"{source}: normals have shape {normals.shape}, expected {points.shape} like the points")
        bad = ~np.isfinite(normals).all(axis=1)
        if bad.any():
            raise ValueError(f"{source}: {int(bad.sum())} normal(s) are NaN or infinite (first at row {int(np.argmax(bad))})")
        zero = np.linalg.norm(normals, axis=1) < 1e-12
        if zero.any():
            raise ValueError(f"{source}: {int(zero.sum())} normal(s) have zero length (first at row "
                             f"{int(np.argmax(zero))}); drop the normals to have them estimated")
    if labels is not None:
        if labels.ndim != 1 or labels.shape[0] != n:
            raise ValueError(f"{source}: {labels.shape[0] if labels.ndim else 0} labels for {n} points; "
                             "expected one label per point")


def _unit(normals: np.ndarray) -> np.ndarray:
    return (normals / np.linalg.norm(normals, axis=1, keepdims=True)).astype(np.float32)


def _as_labels(values: np.ndarray, source: str, limit: int = 2**62) -> np.ndarray:
    """Labels as int64; whole numbers with |label| < ``limit``, else a ValueError naming ``source``."""
    values = np.asarray(values)
    if values.dtype.kind not in "fiub":
        raise ValueError(f"{source}: labels must be whole numbers, got dtype {values.dtype}")
    if values.dtype.kind == "f":
        if not np.isfinite(values).all() or (values != np.round(values)).any():
            raise ValueError(f"{source}: labels must be whole numbers")
    if values.size and (np.abs(values.astype(np.float64)).max() >= limit):
        raise ValueError(f"{source}: labels must lie in ({-limit}, {limit}); got {values.max()} / {values.min()}")
    return values.astype(np.int64)


# Largest magnitude a float32 coordinate (PLY, .npy) can hold.
_FLOAT32_MAX = float(np.finfo(np.float32).max)


# ----------------------------------------------------------------------------------------- PLY

_PLY_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "i2", "int16": "i2",
    "ushort": "u2", "uint16": "u2", "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}
_NORMAL_NAMES = (("nx", "ny", "nz"), ("normal_x", "normal_y", "normal_z"))
_LABEL_NAMES = ("label", "scalar_label", "part", "class")


def _parse_ply_header(path: Path, data: bytes):
    if not data.startswith(b"ply"):
        raise ValueError(f"{path}: not a PLY file (it does not start with 'ply')")
    end = data.find(b"end_header")
    if end < 0:
        raise ValueError(f"{path}: PLY header has no 'end_header' line")
    body = data.index(b"\n", end) + 1
    fmt, elements = None, []
    expected = {"format": 3, "element": 3, "property": 3}  # tokens of each header line (list: 5)
    for line in data[:end].decode("ascii", errors="replace").splitlines()[1:]:
        tok = line.split()
        if not tok or tok[0] in ("comment", "obj_info"):
            continue
        if tok[0] not in expected:
            raise ValueError(f"{path}: unknown PLY header line {line.strip()!r}")
        wanted = 5 if tok[:2] == ["property", "list"] else expected[tok[0]]
        if len(tok) != wanted:
            raise ValueError(f"{path}: malformed PLY header line {line.strip()!r} (expected {wanted} words)")
        if tok[0] == "format":
            fmt = tok[1]
        elif tok[0] == "element":
            if not tok[2].isdigit():
                raise ValueError(f"{path}: PLY element {tok[1]!r} has count {tok[2]!r}; expected a whole number >= 0")
            elements.append({"name": tok[1], "count": int(tok[2]), "props": []})
        elif tok[0] == "property":
            if not elements:
                raise ValueError(f"{path}: PLY property before any element")
            if tok[1] == "list":
                elements[-1]["props"].append((tok[4], "list", tok[2], tok[3]))
            else:
                if tok[1] not in _PLY_TYPES:
                    raise ValueError(f"{path}: unknown PLY property type {tok[1]!r}")
                elements[-1]["props"].append((tok[2], _PLY_TYPES[tok[1]]))
    if fmt not in ("ascii", "binary_little_endian", "binary_big_endian"):
        raise ValueError(f"{path}: unsupported PLY format {fmt!r}")
    return fmt, elements, body


def _read_ply_vertices(path: Path) -> tuple[dict, int]:
    """The vertex properties of a PLY file as ``{name: (N,) array}`` and its number of faces."""
    data = path.read_bytes()
    fmt, elements, body = _parse_ply_header(path, data)
    n_faces = sum(e["count"] for e in elements if e["name"] == "face")
    names = [e["name"] for e in elements]
    if "vertex" not in names:
        raise ValueError(f"{path}: PLY file has no 'vertex' element")
    vertex = elements[names.index("vertex")]
    before = elements[: names.index("vertex")]
    if any(p[1] == "list" for p in vertex["props"]):
        raise ValueError(f"{path}: PLY vertex element with list properties is not supported")
    if fmt == "ascii":
        lines = data[body:].decode("ascii", errors="replace").splitlines()
        start = sum(e["count"] for e in before)
        rows = lines[start:start + vertex["count"]]
        if len(rows) < vertex["count"]:
            raise ValueError(f"{path}: PLY file is truncated ({len(rows)} of {vertex['count']} vertex rows)")
        table = _ascii_rows(rows, len(vertex["props"]), path, first_line=data[:body].count(b"\n") + start + 1)
        return {p[0]: table[:, i] for i, p in enumerate(vertex["props"])}, n_faces
    if any(p[1] == "list" for e in before for p in e["props"]):
        raise ValueError(f"{path}: binary PLY with list elements before the vertices is not supported")
    order = "<" if fmt == "binary_little_endian" else ">"
    offset = body + sum(e["count"] * np.dtype([(p[0], order + p[1]) for p in e["props"]]).itemsize for e in before)
    dtype = np.dtype([(p[0], order + p[1]) for p in vertex["props"]])
    if offset + vertex["count"] * dtype.itemsize > len(data):
        raise ValueError(f"{path}: PLY file is truncated (expected {vertex['count']} vertices)")
    table = np.frombuffer(data, dtype=dtype, count=vertex["count"], offset=offset)
    return {name: table[name].astype(np.float64) for name in dtype.names}, n_faces


def _ascii_rows(rows: list[str], width: int, path: Path, first_line: int) -> np.ndarray:
    """The (len(rows), width) float64 table of ASCII PLY rows; every row must hold exactly ``width`` numbers.

    Args:
        rows: the vertex lines.
        width: the number of vertex properties.
        path: the file, for messages.
        first_line: the 1-based line number of ``rows[0]`` in the file, for messages.

    Returns:
        The table.
    """
    lengths = np.fromiter((len(r.split()) for r in rows), dtype=np.int64, count=len(rows))
    bad = np.flatnonzero(lengths != width)
    if bad.size:
        k = int(bad[0])
        raise ValueError(f"{path}: {bad.size} ASCII PLY vertex row(s) do not hold the {width} values the header "
                         f"declares (first: line {first_line + k}, vertex {k}, with {int(lengths[k])} values); "
                         "the file is malformed")
    try:
        return np.array(" ".join(rows).split(), dtype=np.float64).reshape(len(rows), width)
    except ValueError as exc:
        raise ValueError(f"{path}: non-numeric value in the ASCII PLY vertex rows ({exc})") from exc


def _read_ply(path: Path) -> PointCloud:
    props, n_faces = _read_ply_vertices(path)
    if n_faces > 0:
        raise ValueError(f"{path}: has {n_faces} faces, so it is a mesh, not a point cloud; "
                         "use load_mesh_as_point_cloud (or load_point_cloud, which handles both)")
    if not all(k in props for k in "xyz"):
        raise ValueError(f"{path}: PLY vertices lack x, y, z properties (found {sorted(props)})")
    points = np.stack([props[k] for k in "xyz"], axis=1)
    normals = next((np.stack([props[k] for k in names], axis=1) for names in _NORMAL_NAMES
                    if all(k in props for k in names)), None)
    label = next((props[k] for k in _LABEL_NAMES if k in props), None)
    return PointCloud(points, normals, None if label is None else _as_labels(label, str(path)), source=str(path))


def _write_ply(path: Path, points, normals, labels, ascii: bool) -> None:
    fields = [("x", "f4"), ("y", "f4"), ("z", "f4")]
    if normals is not None:
        fields += [("nx", "f4"), ("ny", "f4"), ("nz", "f4")]
    if labels is not None:
        fields += [("label", "i4")]
    table = np.empty(len(points), dtype=[(n, "<" + t) for n, t in fields])
    for i, k in enumerate("xyz"):
        table[k] = points[:, i]
    if normals is not None:
        for i, k in enumerate(("nx", "ny", "nz")):
            table[k] = normals[:, i]
    if labels is not None:
        table["label"] = labels
    kind = {"f4": "float", "i4": "int"}
    header = ["ply", f"format {'ascii' if ascii else 'binary_little_endian'} 1.0",
              "comment written by cuboidlib", f"element vertex {len(points)}"]
    header += [f"property {kind[t]} {n}" for n, t in fields] + ["end_header"]
    with open(path, "wb") as f:
        f.write(("\n".join(header) + "\n").encode("ascii"))
        if ascii:
            fmt = " ".join("%d" if t == "i4" else "%.9g" for _, t in fields)  # float32 exact
            np.savetxt(f, np.stack([table[n].astype(np.float64) for n, _ in fields], axis=1), fmt=fmt)
        else:
            f.write(table.tobytes())


# ------------------------------------------------------------------------------- text and npy


#: How far from 1 the length of every row of columns 4-6 may be for them to pass as normals (``normals="auto"``).
_UNIT_TOLERANCE = 0.1


def _columns_look_like_normals(values: np.ndarray) -> tuple[bool, str]:
    """Whether columns 4-6 of a text or ``.npy`` table look like normals, and what they look like instead.

    Args:
        values: (N, 3) float64.

    Returns:
        ``(looks_like_normals, description)``: normals are unit vectors (rows of zeros aside, which
        :func:`validate_point_cloud` reports); the description says what was found otherwise.
    """
    lengths = np.linalg.norm(values, axis=1)
    lengths = lengths[lengths > 0]
    if lengths.size and np.all(np.abs(lengths - 1) <= _UNIT_TOLERANCE):
        return True, "unit vectors"
    lo, hi = float(values.min()), float(values.max())
    whole = bool(np.all(values == np.round(values)))
    if lo >= 0 and hi <= 1:
        return False, "values in [0, 1], like RGB colours, not unit vectors"
    if lo >= 0 and hi <= 255 and whole:
        return False, "whole numbers in [0, 255], like RGB colours, not unit vectors"
    if not lengths.size:
        return False, "only zeros"
    return False, f"vectors of lengths {lengths.min():.3g} to {lengths.max():.3g}, not unit vectors"


def _from_columns(table: np.ndarray, path: Path, normals: str = "auto") -> PointCloud:
    if table.ndim != 2 or table.shape[1] not in (3, 6, 7):
        cols = table.shape[1] if table.ndim == 2 else table.ndim
        raise ValueError(f"{path}: expected 3 (x y z), 6 (+ nx ny nz) or 7 (+ label) columns, got {cols}")
    extra = table[:, 3:6] if table.shape[1] >= 6 else None
    if extra is not None and normals == "ignore":
        extra = None
    elif extra is not None and normals == "auto" and np.isfinite(extra).all():
        looks, found = _columns_look_like_normals(extra)
        if not looks:
            warnings.warn(f"{path}: columns 4-6 hold {found}; they are not read as normals (normals are "
                          "estimated instead); if they are normals, say so with normals='file'", stacklevel=4)
            extra = None
    labels = _as_labels(table[:, 6], str(path)) if table.shape[1] == 7 else None
    return PointCloud(table[:, :3].astype(np.float64), extra, labels, source=str(path))


def _read_text(path: Path, normals: str) -> PointCloud:
    # numpy's C parser, one pass over the lines (commas read as spaces, '#' starts a comment)
    with open(path, encoding="utf-8", errors="replace") as f, warnings.catch_warnings():
        warnings.filterwarnings("ignore", "loadtxt: input contained no data")  # reported below, with the file
        try:
            table = np.loadtxt((line.replace(",", " ") for line in f), dtype=np.float64, comments="#", ndmin=2)
        except ValueError as exc:
            detail = str(exc).split(";")[0]  # numpy's own hint after ';' is about its arguments
            problem = "rows have different numbers of columns" if "columns changed" in detail else "non-numeric value"
            raise ValueError(f"{path}: {problem} ({detail})") from exc
    if table.size == 0:
        raise ValueError(f"{path}: contains no points")
    return _from_columns(table, path, normals)


def _read_npy(path: Path, normals: str) -> PointCloud:
    try:
        table = np.load(path, allow_pickle=False)
    except Exception as exc:  # noqa: BLE001 - re-raised with the file name
        raise ValueError(f"{path}: not a readable NumPy array file ({exc})") from exc
    if table.dtype.kind not in "fiu":
        raise ValueError(f"{path}: expected a numeric array, got dtype {table.dtype}")
    if table.size == 0:
        raise ValueError(f"{path}: contains no points")
    return _from_columns(table.astype(np.float64), path, normals)


def read_point_cloud(path: str | os.PathLike, normals: str = "auto") -> PointCloud:
    """Read a point cloud file as stored (no normalisation, no estimation of normals).

    Args:
        path: by suffix, ``.ply`` (ASCII or binary; vertex properties x, y, z, optional nx, ny, nz and
            label), ``.txt``/``.pts``/``.xyz`` (whitespace or comma separated rows ``x y z [nx ny nz
            [label]]``, the ShapeNet-part "normal" layout) or ``.npy`` ((N, 3), (N, 6) as the authors'
            released data, or (N, 7)).
        normals: what columns 4-6 of a text or ``.npy`` file are: ``"auto"`` (normals when every row is a
            unit vector; otherwise, e.g. RGB colours, they are dropped with a warning that says what they
            hold), ``"file"`` (normals, whatever they hold) or ``"ignore"`` (dropped). A PLY file names its
            normals (nx, ny, nz), so they are always read.

    Returns:
        A :class:`PointCloud`: float64 points (the coordinates as stored: normalise before casting to
        float32, so that coordinates far from the origin keep their precision), unit float32 normals or
        None, int64 labels or None.

    Raises:
        FileNotFoundError: the file does not exist.
        ValueError: unknown suffix, unreadable or malformed content, no points, NaN/inf values,
            all points identical, zero normals.
    """
    path = _check_file(path)
    if normals not in ("auto", "file", "ignore"):
        raise ValueError(f"normals must be 'auto', 'file' or 'ignore', got {normals!r}")
    suffix = path.suffix.lower()
    if suffix == ".ply":
        pc = _read_ply(path)
    elif suffix in (".txt", ".pts", ".xyz"):
        pc = _read_text(path, normals)
    elif suffix == ".npy":
        pc = _read_npy(path, normals)
    else:
        raise ValueError(f"{path}: unknown point cloud format {suffix!r}; expected one of {POINT_CLOUD_SUFFIXES}")
    validate_point_cloud(pc.points, pc.normals, pc.labels, str(path))
    if np.abs(pc.points).max() > _FLOAT32_MAX:
        raise ValueError(f"{path}: coordinates up to {np.abs(pc.points).max():.3g} exceed the float32 range "
                         "cuboidlib reads points in; rescale the file")
    pc.points = pc.points.astype(np.float64)
    if pc.normals is not None:
        pc.normals = _unit(pc.normals)
    return pc


def read_labels(path: str | os.PathLike) -> np.ndarray:
    """Read a label file with one integer per line (e.g. ShapeNet-part ``.seg``).

    Args:
        path: the label file.

    Returns:
        (N,) int64.
    """
    path = _check_file(path)
    tokens = path.read_text(errors="replace").split()
    try:
        values = np.array(tokens, dtype=np.float64)
    except ValueError as exc:
        raise ValueError(f"{path}: label file holds a non-numeric value ({exc})") from exc
    return _as_labels(values, str(path))


def write_point_cloud(path: str | os.PathLike, points, normals=None, labels=None, ascii: bool = False) -> Path:
    """Write a point cloud atomically, in the format of the file suffix.

    ``.ply``: float x, y, z, nx, ny, nz and an int ``label`` property; ``.txt``: rows ``x y z [nx ny nz
    [label]]``; ``.npy``: an (N, 3), (N, 6) or (N, 7) float32 array. Labels in ``.txt`` and ``.npy`` need
    normals (the column layout).

    Args:
        path: a ``.ply``, ``.txt`` or ``.npy`` file.
        points: (N, 3).
        normals: optional (N, 3).
        labels: optional (N,) integers.
        ascii: write a ``.ply`` as ASCII instead of binary little-endian.

    Returns:
        ``path`` as a Path.
    """
    path = Path(path)
    points = np.asarray(points, dtype=np.float64)
    normals = None if normals is None else np.asarray(normals, dtype=np.float64)
    labels = None if labels is None else np.asarray(labels)
    source = f"{path} (writing)"
    validate_point_cloud(points, normals, labels, source)
    suffix = path.suffix.lower()
    if suffix not in (".ply", ".txt", ".npy"):
        raise ValueError(f"{path}: unknown point cloud format {suffix!r}; write .ply, .txt or .npy")
    if suffix != ".txt" and np.abs(points).max() > _FLOAT32_MAX:
        raise ValueError(f"{source}: coordinates up to {np.abs(points).max():.3g} do not fit the float32 of "
                         f"{suffix} files; rescale them or write .txt")
    if labels is not None:  # PLY stores int32 labels, .npy float32 (whole numbers exact below 2^24)
        labels = _as_labels(labels, source, limit={".ply": 2**31, ".npy": 2**24}.get(suffix, 2**62))
    if suffix == ".ply":
        with atomic_path(path) as tmp:
            _write_ply(tmp, points, normals, labels, ascii)
        return path
    if labels is not None and normals is None:
        raise ValueError(f"{path}: the {suffix} layout stores labels in column 7, after normals; give normals too")
    cols = [points] + ([normals] if normals is not None else []) + ([labels[:, None]] if labels is not None else [])
    table = np.concatenate(cols, axis=1)
    with atomic_path(path) as tmp:
        if suffix == ".npy":
            np.save(tmp, table.astype(np.float32))
        else:
            # 9 significant digits: every float32 value reads back exactly, at any magnitude
            fmt = ["%.9g"] * (table.shape[1] - (labels is not None)) + (["%d"] if labels is not None else [])
            np.savetxt(tmp, table, fmt=fmt)
    return path


# --------------------------------------------------------------------------------------- meshes


# A face line of an OBJ file with a vertex index 0 (OBJ counts from 1; trimesh would silently shift such a file).
_OBJ_ZERO_INDEX = re.compile(rb"(?m)^[ \t]*f[ \t][^\n]*?(?<=[ \t])0(?=[/ \t\r\n]|$)")


def _check_obj_indices(path: Path) -> None:
    """Refuse an OBJ file whose faces use vertex index 0 (a 0-based file): OBJ indices start at 1."""
    data = path.read_bytes()
    found = _OBJ_ZERO_INDEX.search(data)
    if found:
        line = data.count(b"\n", 0, found.start()) + 1
        end = data.find(b"\n", found.start())
        text = data[found.start():end if end >= 0 else len(data)].decode(errors="replace").strip()
        raise ValueError(f"{path}: line {line} ({text!r}) refers to vertex "
                         "0, but OBJ vertex indices start at 1; the file seems to count from 0. Add 1 to every face "
                         "index (or export it again) so that no vertex is dropped or shifted")


def _check_glb(path: Path) -> None:
    """Refuse a GLB file whose header, chunks or buffers claim more bytes than the file holds."""
    import struct

    data = path.read_bytes()
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
        doc = json.loads(chunks.get(b"JSON", b"").decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ValueError(f"{path}: unreadable mesh: the GLB's JSON chunk is missing or unreadable ({exc})") from exc
    binary = len(chunks.get(b"BIN\x00", b""))
    for k, buffer in enumerate(doc.get("buffers", []) if isinstance(doc, dict) else []):
        claimed = buffer.get("byteLength") if isinstance(buffer, dict) else None
        if isinstance(buffer, dict) and "uri" not in buffer and (not isinstance(claimed, int) or claimed > binary):
            raise ValueError(f"{path}: unreadable mesh: GLB buffer {k} claims {claimed!r} bytes but the file's binary chunk holds "
                             f"{binary:,}; it is damaged")


def _load_mesh(path: Path) -> trimesh.Trimesh:
    if path.suffix.lower() == ".obj":
        _check_obj_indices(path)
    if path.suffix.lower() == ".glb":
        _check_glb(path)
    try:
        loaded = trimesh.load(str(path), process=False)
    except Exception as exc:  # noqa: BLE001 - re-raised with the file name
        raise ValueError(f"{path}: unreadable mesh ({type(exc).__name__}: {exc})") from exc
    if isinstance(loaded, trimesh.Scene):  # e.g. GLB: bake every node's transform into one mesh
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
    return loaded


def load_mesh_as_point_cloud(path: str | os.PathLike, n_points: int, seed: int = 0,
                             orient: str = "auto") -> PointCloud:
    """Sample ``n_points`` points area-uniformly on a mesh file, with the normals of their faces.

    Args:
        path: any mesh trimesh reads (OBJ, PLY with faces, OFF, STL, GLB/GLTF).
        n_points: number of points N, from 1 to ``cuboidlib._checks.MAX_SHAPE_POINTS``.
        seed: seed of the sampling.
        orient: ``"auto"``: for a watertight mesh with consistent winding, trust the winding (flipped
            as a whole if the enclosed volume is negative), otherwise orient the sampled normals
            outward with :func:`cuboidlib.normals.orient_normals`; ``"winding"``: always trust
            the face winding; ``"visibility"``: always re-orient.

    Returns:
        A :class:`PointCloud` in the file's coordinates (not normalised; float64 points, so that a mesh far
        from the origin keeps its precision until it is normalised), float32 normals; its labels are those of
        the sampled faces when the file is a PLY mesh with a per-face ``label`` property (as
        :func:`write_shape_mesh` writes), otherwise None.
    """
    path = _check_file(path)
    n_points = check_size(n_points, "n_points", MAX_SHAPE_POINTS)
    if orient not in ("auto", "winding", "visibility"):
        raise ValueError(f"orient must be 'auto', 'winding' or 'visibility', got {orient!r}")
    mesh = _load_mesh(path)
    rng = np.random.default_rng(seed)
    areas = mesh.area_faces
    cdf = np.cumsum(areas)
    face = np.minimum(np.searchsorted(cdf, rng.random(n_points) * cdf[-1], side="right"), len(areas) - 1)
    tri = mesh.vertices[mesh.faces[face]]
    r1, r2 = np.sqrt(rng.random(n_points)), rng.random(n_points)
    points = (1 - r1)[:, None] * tri[:, 0] + (r1 * (1 - r2))[:, None] * tri[:, 1] + (r1 * r2)[:, None] * tri[:, 2]
    normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    closed = mesh.is_watertight and mesh.is_winding_consistent
    if orient == "visibility" or (orient == "auto" and not closed):
        normals = orient_normals(points, normals)
    elif closed and mesh.volume < 0:
        normals = -normals
    validate_point_cloud(points, normals, None, str(path))
    face_labels = _ply_face_labels(mesh)
    labels = None if face_labels is None else face_labels[face]
    return PointCloud(points, normals.astype(np.float32), labels, source=str(path))


def _ply_face_labels(mesh: trimesh.Trimesh) -> np.ndarray | None:
    """Per-face ``label`` of a PLY mesh (as :func:`write_shape_mesh` writes), if there is one."""
    try:
        labels = np.asarray(mesh.metadata["_ply_raw"]["face"]["data"]["label"]).reshape(-1)
    except (KeyError, ValueError, TypeError, IndexError):
        return None
    return labels.astype(np.int64) if len(labels) == len(mesh.faces) else None


def is_mesh_file(path: str | os.PathLike) -> bool:
    """Whether ``path`` is a mesh file (OBJ, OFF, STL, GLB/GLTF, or a PLY file with faces).

    Args:
        path: an existing file.

    Returns:
        True for a mesh, False otherwise.
    """
    path = _check_file(path)
    suffix = path.suffix.lower()
    if suffix == ".ply":
        return _read_ply_vertices(path)[1] > 0
    return suffix in MESH_SUFFIXES


def load_point_cloud(
    path: str | os.PathLike,
    n_points: int | None = None,
    seed: int = 0,
    normalize_shape: bool = True,
    normals: str = "auto",
    labels_path: str | os.PathLike | None = None,
    k: int = 16,
    fewer_ok: bool = False,
) -> PointCloud:
    """Read any supported file as a validated, normalised point cloud with normals.

    Args:
        path: a point cloud (``.ply`` without faces, ``.txt``, ``.pts``, ``.xyz``, ``.npy``) or a mesh
            (``.obj``, ``.off``, ``.stl``, ``.glb``, ``.gltf``, ``.ply`` with faces).
        n_points: for meshes, the number of points to sample (required); for point clouds, a random
            subset of this size is kept (an error if the file has fewer points). At most
            ``cuboidlib._checks.MAX_SHAPE_POINTS``, checked before the file is read.
        seed: seed of the sampling / subsampling.
        normalize_shape: apply the course normalisation (bounding-box centre to the origin, diagonal
            1) and record ``(center, scale)``.
        normals: ``"auto"`` (use the file's normals, estimate them when missing; columns 4-6 of a text or
            ``.npy`` file count as normals only when they are unit vectors, see :func:`read_point_cloud`),
            ``"estimate"`` (always estimate) or ``"file"`` (require them in the file, and take columns 4-6 as
            normals whatever they hold).
        labels_path: an optional separate label file (one integer per point, e.g. ``.seg``).
        k: neighbours for normal estimation.
        fewer_ok: for point clouds with fewer than ``n_points`` points, keep them all instead of
            raising.

    Returns:
        A :class:`PointCloud` with float32 points and normals; its ``center`` and ``scale`` map it back to the
        file's coordinates (normalised in float64 before the points are cast to float32).
    """
    path = _check_file(path)
    if normals not in ("auto", "estimate", "file"):
        raise ValueError(f"normals must be 'auto', 'estimate' or 'file', got {normals!r}")
    if n_points is not None:
        n_points = check_size(n_points, "n_points", MAX_SHAPE_POINTS)
    is_mesh = is_mesh_file(path)
    if is_mesh:
        if n_points is None:
            raise ValueError(f"{path}: is a mesh; give n_points to say how many points to sample")
        pc = load_mesh_as_point_cloud(path, n_points, seed)
    else:
        pc = read_point_cloud(path, normals={"auto": "auto", "file": "file", "estimate": "ignore"}[normals])
    if labels_path is not None:
        pc.labels = read_labels(labels_path)
        validate_point_cloud(pc.points, None, pc.labels, f"{path} with labels {labels_path}")
    if normals == "file" and pc.normals is None:
        raise ValueError(f"{path}: has no normals (and normals='file' forbids estimating them)")
    if n_points is not None and not is_mesh:
        if fewer_ok:
            n_points = min(n_points, len(pc))
        validate_point_cloud(pc.points, None, None, str(path), n_points=n_points)
        if n_points < len(pc):
            keep = np.sort(np.random.default_rng(seed).choice(len(pc), n_points, replace=False))
            pc.points = pc.points[keep]
            pc.normals = None if pc.normals is None else pc.normals[keep]
            pc.labels = None if pc.labels is None else pc.labels[keep]
    wide = pc.points.astype(np.float64)
    if normalize_shape:  # in float64, then cast: map coordinates (1e6 and more) keep their precision
        pc.points, pc.center, scale = normalize(wide)
        pc.points, pc.scale = pc.points.astype(np.float32), float(scale)
    else:
        pc.points = wide.astype(np.float32)
        lost = float(np.abs(pc.points - wide).max()) / float(np.linalg.norm(np.ptp(wide, axis=0)))
        if lost > 1e-4:
            warnings.warn(f"{path}: in float32 the coordinates move by up to {lost:.2g} of the shape's size (they lie "
                          "far from the origin); normalise the shape (normalize_shape=True) to keep its detail",
                          stacklevel=2)
    if pc.normals is None or normals == "estimate":
        if len(pc) < 3:
            raise ValueError(f"{path}: needs at least 3 points to estimate normals, has {len(pc)}")
        pc.normals = estimate_normals(pc.points, k=min(k, len(pc))).astype(np.float32)
    return pc


# ---------------------------------------------------------------------------- dataset layouts


def shapenet_part_labels(raw: np.ndarray, category: str, numbering: str = "global") -> np.ndarray:
    """Map ShapeNet-part part ids to indices into ``PART_NAMES[category]`` (table support -> leg, Sec. 4.2).

    Args:
        raw: integer part ids, any shape.
        category: "airplane", "chair" or "table".
        numbering: "global", the 0-49 ids of the "normal" layout's 7th column, or "one-based", the
            per-category 1..K ids of the original ``.seg`` files.

    Returns:
        int64 labels of the shape of ``raw``.
    """
    if category not in SHAPENET_PART_IDS:
        raise ValueError(f"ShapeNet-part labels are known for {tuple(SHAPENET_PART_IDS)}, not {category!r}")
    ids = SHAPENET_PART_IDS[category]
    if numbering == "one-based":
        first = min(ids)
        ids = {k - first + 1: v for k, v in ids.items()}
    elif numbering != "global":
        raise ValueError(f"numbering must be 'global' or 'one-based', got {numbering!r}")
    raw = np.asarray(raw)
    unknown = sorted(set(np.unique(raw).tolist()) - set(ids))
    if unknown:
        raise ValueError(f"labels {unknown[:5]} are not {numbering} ShapeNet-part ids of {category!r} "
                         f"(expected {sorted(ids)})")
    lut = np.zeros(max(ids) + 1, dtype=np.int64)
    for k, v in ids.items():
        lut[k] = v
    return lut[raw]


def shapenet_part_files(root: str | os.PathLike, category: str, split: str = "train") -> list[Path]:
    """Files of ``category`` in a ShapeNet-part "normal" folder for one split.

    Args:
        root: the folder, holding ``synsetoffset2category.txt`` (lines ``Chair 03001627``),
            ``train_test_split/shuffled_<split>_file_list.json`` (entries ``shape_data/<synset>/<id>``) and
            ``<synset>/<id>.txt``.
        category: a category name of ``synsetoffset2category.txt``, any case.
        split: "train", "val", "test" or "trainval".

    Returns:
        The listed ``.txt`` files, in the order of the split lists.
    """
    root = Path(root)
    cat_file = _check_file(root / "synsetoffset2category.txt")
    synsets = {}
    for line in cat_file.read_text().splitlines():
        tok = line.split()
        if len(tok) >= 2:
            synsets[tok[0].lower()] = tok[1]
    if category.lower() not in synsets:
        raise ValueError(f"{cat_file}: no category {category!r} (it lists {sorted(synsets)})")
    synset = synsets[category.lower()]
    splits = ("train", "val") if split == "trainval" else (split,)
    files = []
    for s in splits:
        if s not in ("train", "val", "test"):
            raise ValueError(f"split must be 'train', 'val', 'test' or 'trainval', got {split!r}")
        list_file = _check_file(root / "train_test_split" / f"shuffled_{s}_file_list.json")
        try:
            entries = json.loads(list_file.read_text())
        except json.JSONDecodeError as exc:
            raise ValueError(f"{list_file}: not valid JSON ({exc})") from exc
        for entry in entries:
            parts = str(entry).split("/")
            if len(parts) >= 2 and parts[-2] == synset:
                files.append(root / synset / f"{parts[-1]}.txt")
    missing = [f for f in files if not f.is_file()]
    if missing:
        raise FileNotFoundError(f"{missing[0]}: listed in the {split} split but missing "
                                f"({len(missing)} listed file(s) missing)")
    return files


def authors_layout_files(root: str | os.PathLike, category: str, split: str = "train") -> list[Path]:
    """Files of one split in the layout of the authors' released data.

    Args:
        root: the folder, holding ``<category>_<split>.npy`` (an array of file names) or
            ``<category>_<split>.txt`` (one name per line), and ``<category>/<name>`` files of (N, 6)
            arrays (xyz + normal); a name without suffix gets ``.npy``.
        category: the category's folder name.
        split: the split's name in the list file names.

    Returns:
        The listed files, in the order of the list.
    """
    root = Path(root)
    npy, txt = root / f"{category}_{split}.npy", root / f"{category}_{split}.txt"
    if npy.is_file():
        try:
            names = [str(n) for n in np.load(npy, allow_pickle=False).ravel()]
        except ValueError as exc:
            raise ValueError(f"{npy}: the file list must be an array of strings saved without pickle ({exc})") from exc
    elif txt.is_file():
        names = [ln.strip() for ln in txt.read_text().splitlines() if ln.strip()]
    else:
        raise FileNotFoundError(f"{npy}: no such file list (nor {txt.name})")
    files = [root / category / (n if Path(n).suffix else n + ".npy") for n in names]
    missing = [f for f in files if not f.is_file()]
    if missing:
        raise FileNotFoundError(f"{missing[0]}: listed in the {split} split but missing "
                                f"({len(missing)} listed file(s) missing)")
    return files


# --------------------------------------------------------------------------------- data_samples


def write_shape_mesh(path: str | os.PathLike, shape) -> Path:
    """Write a :class:`cuboidlib.shapes.Shape` as a binary PLY mesh.

    The parts' meshes are concatenated (not boolean-merged), vertices coloured by part (``PART_COLORS``),
    with an int ``label`` per face, which :func:`load_mesh_as_point_cloud` carries to the sampled points.

    Args:
        path: the ``.ply`` file.
        shape: the procedural shape.

    Returns:
        ``path`` as a Path.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    shape.mesh().export(str(path), file_type="ply", encoding="binary")
    return path


def _sample_name(category: str, i: int) -> str:
    return f"{category}_{i}"


def data_sample_files(out_dir: str | os.PathLike, n_per_category: int = 3, figure: bool = True) -> list[Path]:
    """The files :func:`write_data_samples` writes, so that a caller can check them before any work.

    Args:
        out_dir, n_per_category, figure: as in :func:`write_data_samples`.

    Returns:
        Their paths: the meshes, the point clouds, ``index.csv`` and (with ``figure``) ``samples.png``.
    """
    out = Path(out_dir)
    names = [_sample_name(c, i) for c in CATEGORIES for i in range(n_per_category)]
    return ([out / "meshes" / f"{n}.ply" for n in names] + [out / "points" / f"{n}.ply" for n in names]
            + [out / "index.csv"] + ([out / "samples.png"] if figure else []))


def write_data_samples(out_dir: str | os.PathLike, n_per_category: int = 3, n_points: int = 2048,
                       seed: int = 0, figure: bool = True) -> list[Path]:
    """Write the course's sample files (the committed ``data_samples/`` folder).

    Per category, the first shapes of collection ``seed`` whose coarse structure is not taken yet:
    ``meshes/<category>_<i>.ply`` (:func:`write_shape_mesh`), ``points/<category>_<i>.ply`` (points with
    normals and labels), then ``index.csv`` (files, category, collection index, structure, part names) and
    ``samples.png`` (a part-coloured scatter of every sample).

    Args:
        out_dir: the folder to write.
        n_per_category: shapes per category.
        n_points: points per shape.
        seed: the procedural collection.
        figure: also write ``samples.png``.

    Returns:
        The paths written.
    """
    out = Path(out_dir)
    written, rows, chosen = [], [], []
    for category in CATEGORIES:
        seen, index, found = set(), 0, 0
        while found < n_per_category:
            shape = make_shape(category, index, n_points, seed)
            if shape.structure_id not in seen or index >= 50 * n_per_category:
                seen.add(shape.structure_id)
                name = _sample_name(category, found)
                written.append(write_shape_mesh(out / "meshes" / f"{name}.ply", shape))
                written.append(write_point_cloud(out / "points" / f"{name}.ply", shape.points, shape.normals,
                                                 shape.labels))
                rows.append([f"points/{name}.ply", f"meshes/{name}.ply", category, index, shape.structure,
                             shape.structure_id, " ".join(PART_NAMES[category])])
                chosen.append(shape)
                found += 1
            index += 1
    index_file = out / "index.csv"
    with open(index_file, "w", newline="") as f:
        w = csv.writer(f, lineterminator="\n")
        w.writerow(["points", "mesh", "category", "collection_index", "structure", "structure_id", "part_names"])
        w.writerows(rows)
    written.append(index_file)
    if figure:
        import matplotlib

        if "matplotlib.pyplot" not in sys.modules:
            matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig = plot_shapes(chosen, titles=[s.structure for s in chosen], ncols=n_per_category, point_size=1.5)
        fig.savefig(out / "samples.png", dpi=90)
        plt.close(fig)
        written.append(out / "samples.png")
    return written
