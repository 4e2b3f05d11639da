"""Reading and writing the shape files a user brings (meshes, point clouds, dataset layouts).

Every format is read into one :class:`PointCloud` through one validation, so a malformed file of any format
fails with the same kind of message, naming the file (``FileNotFoundError`` if missing, else ``ValueError``).
:func:`load_point_cloud` is the entry point of the dataset and the command line: it reads, validates,
subsamples, estimates missing normals and normalises (:mod:`cuboidlib.normalization`), keeping
``(center, scale)`` so results can be written back in the user's coordinates. The tables of text and PLY files
are parsed by :mod:`cuboidlib.file_tables`, meshes read by :mod:`cuboidlib.mesh_files`.
"""

from __future__ import annotations

import os
import re
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ._checks import MAX_SHAPE_POINTS, check_size
from .files import atomic_path, check_not_packed, read_file_bytes, read_json
from .file_tables import (LABEL_NAMES, as_labels, parse_ply_header, ply_vertex_table, read_number_rows, read_ply,
                          strip_comments)
from .mesh_files import load_triangle_mesh
from .normalization import normalize
from .normals import estimate_normals, orient_normals

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


# Largest magnitude a float32 coordinate (PLY, .npy) can hold.
_FLOAT32_MAX = float(np.finfo(np.float32).max)


# ----------------------------------------------------------------------------------------- PLY

_NORMAL_NAMES = (("nx", "ny", "nz"), ("normal_x", "normal_y", "normal_z"))


def _read_ply(path: Path) -> PointCloud:
    _, elements = read_ply(path)
    n_faces = sum(e.count for e in elements if e.name == "face")
    if n_faces > 0:
        raise ValueError(f"{path}: has {n_faces} faces, so it is a mesh, not a point cloud; "
                         "use load_mesh_as_point_cloud (or load_point_cloud, which handles both)")
    props = ply_vertex_table(path, elements)
    points = np.stack([props[k] for k in "xyz"], axis=1).astype(np.float64)
    normals = next((np.stack([props[k] for k in names], axis=1).astype(np.float64) for names in _NORMAL_NAMES
                    if all(k in props for k in names)), None)
    label = next((props[k] for k in LABEL_NAMES if k in props), None)
    return PointCloud(points, normals, None if label is None else as_labels(label, str(path)), source=str(path))


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


def _colour_like(values: np.ndarray) -> bool:
    """Whether every value is a colour channel: a whole number in [0, 255], or all values in [0, 1]."""
    if not np.isfinite(values).all():
        return False
    lo, hi = float(values.min()), float(values.max())
    return lo >= 0 and (hi <= 1 or (hi <= 255 and bool(np.all(values == np.round(values)))))


def _pts_intensity_colours(table: np.ndarray, path: Path, normals: str) -> PointCloud:
    """The points of a 7-column ``.pts`` table, x y z intensity r g b, when nothing else can be meant."""
    layout = "a .pts file's 7 columns are x y z intensity r g b"
    if normals == "file":
        raise ValueError(f"{path}: {layout}, so it holds no normals (normals='file' asks for them)")
    looks, _ = _columns_look_like_normals(table[:, 3:6])
    if looks:
        raise ValueError(f"{path}: {layout}, but here columns 4-6 are unit vectors, like normals (x y z nx ny nz "
                         "label?); the reading is ambiguous. Name the file .txt if that is its layout")
    if not _colour_like(table[:, 4:7]):
        _, found = _columns_look_like_normals(table[:, 4:7])
        raise ValueError(f"{path}: {layout}, but here columns 5-7 hold {found.split(',')[0]}, not colours "
                         "(whole numbers in [0, 255] or values in [0, 1]); the layout is unknown")
    return PointCloud(table[:, :3].astype(np.float64), None, None, source=str(path))


def _from_columns(table: np.ndarray, path: Path, normals: str = "auto", pts: bool = False) -> PointCloud:
    """A point cloud from the columns of a text or ``.npy`` table.

    Args:
        table: (N, C).
        path: the file, for messages.
        normals: "auto", "file" or "ignore" (:func:`read_point_cloud`).
        pts: the table is a ``.pts`` scan: 4 columns are x y z intensity, 7 are x y z intensity r g b.

    Returns:
        The cloud as stored.
    """
    allowed = (3, 4, 6, 7) if pts else (3, 6, 7)
    if table.ndim != 2 or table.shape[1] not in allowed:
        cols = table.shape[1] if table.ndim == 2 else table.ndim
        expected = ("3 (x y z), 4 (+ intensity), 6 (+ nx ny nz, or r g b) or 7 (+ intensity r g b)" if pts
                    else "3 (x y z), 6 (+ nx ny nz) or 7 (+ label)")
        raise ValueError(f"{path}: expected {expected} columns, got {cols}")
    if pts and table.shape[1] == 7:
        return _pts_intensity_colours(table, path, normals)
    extra = table[:, 3:6] if table.shape[1] >= 6 else None
    looks, found = _columns_look_like_normals(extra) if extra is not None and np.isfinite(extra).all() else (False, "")
    if table.shape[1] == 7 and normals != "file" and not looks:
        raise ValueError(f"{path}: 7 columns are read as x y z nx ny nz label (the ShapeNet-part layout) only when "
                         f"columns 4-6 are unit normals; here they hold {found or 'NaN or infinite values'}, so "
                         "column 7 is not taken for part labels. Name an x y z intensity r g b scan .pts; pass "
                         "normals='file' if columns 4-6 are normals")
    if extra is not None and normals == "ignore":
        extra = None
    elif extra is not None and normals == "auto" and np.isfinite(extra).all() and not looks:
        warnings.warn(f"{path}: columns 4-6 hold {found}; they are not read as normals (normals are "
                      "estimated instead); if they are normals, say so with normals='file'", stacklevel=4)
        extra = None
    labels = as_labels(table[:, 6], str(path)) if table.shape[1] == 7 else None
    return PointCloud(table[:, :3].astype(np.float64), extra, labels, source=str(path))


# Inside a value of a row: a comma between two characters of it (a decimal comma, or a separator without spaces).
_INNER_COMMA = re.compile(rb"[^\s,;],[^\s,;]")
# Values of a row separated by blanks alone.
_BLANK_SEPARATED = re.compile(rb"[^\s,;][ \t]+[^\s,;]")
# A comma with no value before or after it on its line.
_EMPTY_FIELD = re.compile(rb"^[ \t]*,|,[ \t]*,|,[ \t]*\r?$", re.MULTILINE)


def _decimal_marks(path: Path, data: bytes) -> bytes:
    """The text of a point cloud with its separators made spaces and decimal commas made points.

    Read unambiguously: no comma (blanks separate); ';' separates, ',' is decimal (no '.' then); commas
    separate (CSV) when no value holds a comma between blanks; decimal commas when values with one comma
    each are separated by blanks and no '.' appears. Anything else is refused with the cause.

    Args:
        path: the file, for messages.
        data: its text, comments removed.

    Returns:
        The text for :func:`cuboidlib.mesh_files.read_number_rows`.
    """
    if b"," not in data and b";" not in data:
        return data
    if b";" in data:
        if b"," in data and b"." in data:
            raise ValueError(f"{path}: values are separated by ';' and hold both ',' and '.' (thousands separators?); "
                             "the numbers are ambiguous. Write them with one decimal mark and no thousands separator")
        return data.replace(b";", b" ").replace(b",", b".")
    if not (_INNER_COMMA.search(data) and _BLANK_SEPARATED.search(data)):
        empty = _EMPTY_FIELD.search(data)
        if empty:
            line = data.count(b"\n", 0, empty.start()) + 1
            raise ValueError(f"{path}: line {line} has an empty comma-separated field; every row needs all its values")
        return data.replace(b",", b" ")
    if b"." in data:
        raise ValueError(f"{path}: values separated by blanks hold commas, and the file also has '.' (thousands "
                         "separators, or decimal commas mixed with points?); the numbers are ambiguous")
    if re.search(rb",[^\s,]*,|(^|\s),|,(\s|$)", data):
        raise ValueError(f"{path}: rows mix commas between values with commas inside them; the numbers are "
                         "ambiguous. Use blanks, commas or semicolons between values, and one decimal mark")
    return data.replace(b",", b".")


def _pts_rows(path: Path, rows) -> np.ndarray:
    """The rows of a ``.pts`` file that hold points: each count line (a lone whole number) must count the rows
    that follow it up to the next one."""
    counts = np.flatnonzero(rows.widths == 1)
    if not counts.size:
        return np.arange(len(rows))
    if counts[0] != 0:
        raise ValueError(f"{path}: line {int(rows.lines[counts[0]])} holds a single value; a .pts file has one only "
                         "as the count line before its points")
    bounds = np.append(counts, len(rows))
    for k, r in enumerate(counts.tolist()):
        said, follow = float(rows.values[rows.starts[r]]), int(bounds[k + 1] - r - 1)
        if said != follow:
            cut = ": the file is truncated" if follow < said else ""
            raise ValueError(f"{path}: the count line {int(rows.lines[r])} says {said:g} points, but {follow} rows "
                             f"follow it{cut}")
    if not rows.complete:
        raise ValueError(f"{path}: the file ends inside a row (its last line has no line end) although its count "
                         "line declares the rows: it is cut off")
    return np.setdiff1d(np.arange(len(rows)), counts)


def _read_text(path: Path, normals: str) -> PointCloud:
    data = strip_comments(read_file_bytes(path, f"a {path.suffix} point cloud"))
    rows = read_number_rows(path, _decimal_marks(path, data), what="rows")
    if not len(rows):
        raise ValueError(f"{path}: contains no points")
    pts = path.suffix.lower() == ".pts"
    keep = _pts_rows(path, rows) if pts else np.arange(len(rows))
    if not keep.size:
        raise ValueError(f"{path}: contains no points")
    widths = rows.widths[keep]
    if np.any(widths != widths[0]):
        k = int(np.argmax(widths != widths[0]))
        hint = " (a point count? only .pts files have count lines)" if widths[0] == 1 else ""
        raise ValueError(f"{path}: rows have different numbers of columns (line {int(rows.lines[keep[k]])} holds "
                         f"{int(widths[k])} values, line {int(rows.lines[keep[0]])} {int(widths[0])}{hint})")
    w = int(widths[0])
    if keep.size == len(rows):
        table = rows.values.reshape(-1, w)
    else:
        table = rows.values[rows.starts[keep, None] + np.arange(w)]
    return _from_columns(table, path, normals, pts)


def _read_npy(path: Path, normals: str) -> PointCloud:
    with open(path, "rb") as f:
        check_not_packed(path, f.read(8), "a NumPy .npy array")
    try:
        table = np.load(path, allow_pickle=False)
    except Exception as exc:  # noqa: BLE001 - re-raised with the file name
        raise ValueError(f"{path}: not a readable NumPy array file ({exc})") from exc
    if not isinstance(table, np.ndarray) or table.dtype.kind not in "fiu":
        raise ValueError(f"{path}: expected a numeric array, got {getattr(table, 'dtype', type(table).__name__)}")
    if table.size == 0:
        raise ValueError(f"{path}: contains no points")
    return _from_columns(table.astype(np.float64), path, normals)


def read_point_cloud(path: str | os.PathLike, normals: str = "auto") -> PointCloud:
    """Read a point cloud file as stored (no normalisation, no estimation of normals).

    Args:
        path: by suffix, ``.ply`` (ASCII or binary; vertex properties x, y, z, optional nx, ny, nz and
            label), ``.txt``/``.xyz`` (rows ``x y z [nx ny nz [label]]``, the ShapeNet-part "normal" layout;
            the label column is read only when columns 4-6 are unit normals, or ``normals="file"``), ``.pts``
            (a scan: rows ``x y z``, ``x y z intensity``, ``x y z`` + 3 columns as in ``.txt``, or ``x y z
            intensity r g b``, each block of rows optionally after a line that counts them) or ``.npy``
            ((N, 3), (N, 6) as the authors' released data, or (N, 7)). Text values are separated by blanks,
            commas or semicolons, with decimal points or (where nothing else can be meant) decimal commas;
            '#' starts a comment.
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
        ValueError: unknown suffix, unreadable, malformed, truncated, compressed or ambiguous content, no
            points, NaN/inf values, all points identical, zero normals.
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
    rows = read_number_rows(path, read_file_bytes(path, "a label file"), what="label file")
    return as_labels(rows.values, str(path))


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
        labels = as_labels(labels, source, limit={".ply": 2**31, ".npy": 2**24}.get(suffix, 2**62))
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


def load_mesh_as_point_cloud(path: str | os.PathLike, n_points: int, seed: int = 0,
                             orient: str = "auto") -> PointCloud:
    """Sample ``n_points`` points area-uniformly on a mesh file, with the normals of their faces.

    Args:
        path: a mesh: OBJ, OFF or PLY with faces (read by :func:`cuboidlib.mesh_files.read_polygon_mesh`, polygons
            triangulated inside their outlines), STL, GLB or GLTF (read by trimesh).
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
    mesh, face_labels = load_triangle_mesh(path)
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
    labels = None if face_labels is None else face_labels[face]
    return PointCloud(points, normals.astype(np.float32), labels, source=str(path))


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
        _, elements, _, _ = parse_ply_header(path, read_file_bytes(path, "a PLY file"))
        return sum(e.count for e in elements if e.name == "face") > 0
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
    for line in read_file_bytes(cat_file, "a text file").decode("utf-8", errors="replace").splitlines():
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
        entries = read_json(list_file)
        if not isinstance(entries, list):
            raise ValueError(f"{list_file}: a split list must hold a JSON list of names, got {type(entries).__name__}")
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
        text = read_file_bytes(txt, "a text file").decode("utf-8", errors="replace")
        names = [ln.strip() for ln in text.splitlines() if ln.strip()]
    else:
        raise FileNotFoundError(f"{npy}: no such file list (nor {txt.name})")
    files = [root / category / (n if Path(n).suffix else n + ".npy") for n in names]
    missing = [f for f in files if not f.is_file()]
    if missing:
        raise FileNotFoundError(f"{missing[0]}: listed in the {split} split but missing "
                                f"({len(missing)} listed file(s) missing)")
    return files
