"""Writing cuboid abstractions to files: JSON, meshes (GLB, OBJ, PLY), segmented point clouds, result folders.

The formats share one module because they share two rules (the reason for its length). Colour: cuboid m is
``PALETTE[m]`` (:mod:`cuboidlib.viz`) everywhere, as in the lessons' figures. Coordinates: shapes are
abstracted in normalised coordinates (bounding box centred at the origin, diagonal 1,
:mod:`cuboidlib.normalization`), and a cuboid goes back to the input's coordinates by

    centre_original = centre * scale + center,   size_original = size * scale,   rotation unchanged

(:func:`denormalize_cuboids`, inverse :func:`normalize_cuboids`).

JSON schema (``format`` "cuboidlib-cuboids", ``version`` 1), the M cuboids of ONE shape::

    {
      "format": "cuboidlib-cuboids",
      "version": 1,
      "source": "chair_0.ply",              # input file name, or null
      "method": {"name": "fit", ...},       # how the cuboids were made (informative), or null
      "convention": {                       # fixed texts that document the fields below
        "center": "...", "quaternion": "...", "rotation_matrix": "...", "size": "...", "units": "..."
      },
      "coordinates": "original",            # or "normalized": the frame of every centre and size
      "normalization": {                    # the input's normalisation (identity if unknown)
        "center": [cx, cy, cz], "scale": s, "rule": "original = normalized * scale + center"
      },
      "num_cuboids": M,                     # cuboid slots, existing or not
      "num_existing": K,
      "chamfer": {"value": 0.0123, "convention": "...", "coordinates": "normalized"},  # optional
      "part_names": ["back", "seat", ...],  # optional: names of the part labels
      "points_file": "chair_0_segmentation.ply",  # optional: the segmented points, same coordinates
      "cuboids": [
        {
          "index": 0,                       # cuboid index m (colour PALETTE[m], mesh node "cuboid_00")
          "exists": true,
          "center": [x, y, z],              # world position of the cuboid's centre
          "quaternion": [w, x, y, z],       # unit, rotates the local axes into the world
          "rotation_matrix": [[...], [...], [...]],  # the same rotation, row-major; columns = local axes
          "size": [lx, ly, lz],             # FULL edge lengths along the local x, y, z axes (2 x half size)
          "part_label": 1,                  # semantic part of the cuboid's points, or null if unknown
          "part_name": "seat"               # only when part_names is given (null if unknown)
        }, ...
      ]
    }

A world point is p = R l + center for a local point l in [-size/2, size/2]^3 (R = rotation_matrix).
Numbers are written with full precision, so :func:`read_cuboids_json` returns exactly the cuboids
written (float32 inputs come back bit for bit).
"""

from __future__ import annotations

import json
import math
import os
import re
from pathlib import Path

import numpy as np
import torch
import trimesh

from .files import LOCK_FILE, MANIFEST, MESH_FORMATS, RESULT_FORMAT, atomic_path, read_json, write_text_atomic
from .geometry import Cuboids, cuboids_to_trimesh
from .metrics import ChamferConvention
from .rotations import quaternion_to_rotation_matrix
from .viz import UNLABELLED, cuboid_color

__all__ = [
    "JSON_FORMAT",
    "JSON_VERSION",
    "COORDINATES",
    "MESH_FORMATS",
    "CONVENTION",
    "palette_rgba",
    "denormalize_cuboids",
    "normalize_cuboids",
    "cuboid_node_name",
    "cuboids_to_dict",
    "cuboids_from_dict",
    "write_cuboids_json",
    "read_cuboids_json",
    "cuboid_scene",
    "write_cuboid_mesh",
    "write_segmented_point_cloud",
    "MANIFEST",
    "read_manifest",
    "write_manifest",
    "prepare_output_folder",
]

JSON_FORMAT = RESULT_FORMAT
JSON_VERSION = 1
COORDINATES = ("original", "normalized")
# MESH_FORMATS, part of this module's names, is defined in cuboidlib.files, which the command line reads
# without importing torch.

#: The texts of the JSON's "convention" entry.
CONVENTION = {
    "center": "world position of the cuboid centre, in the units given by 'coordinates'",
    "quaternion": "unit quaternion (w, x, y, z), rotates the cuboid's local axes into the world",
    "rotation_matrix": "the same rotation as a row-major 3x3 matrix R; its columns are the local x, y, z "
    "axes in world coordinates; a local point l maps to R l + center",
    "size": "full edge lengths along the local x, y, z axes (twice the half sizes)",
    "units": "'original': the input file's units; 'normalized': bounding box of the input centred at the "
    "origin with diagonal 1 (original = normalized * scale + center)",
}

_QUATERNION_MATRIX_TOL = 1e-5


# ----------------------------------------------------------------------------------------------
# Colours and coordinates
# ----------------------------------------------------------------------------------------------


def _rgb255(hex_color: str) -> list[int]:
    return [int(hex_color[i : i + 2], 16) for i in (1, 3, 5)]


def palette_rgba(m: int) -> np.ndarray:
    """RGBA colours of cuboid indices 0 .. m - 1 (:func:`cuboidlib.viz.cuboid_color`, alpha 255).

    Args:
        m: the number of cuboid indices.

    Returns:
        (m, 4) uint8.
    """
    if isinstance(m, bool) or not isinstance(m, (int, np.integer)) or m < 0:
        raise ValueError(f"m must be a non-negative integer, got {m!r}")
    return np.array([_rgb255(cuboid_color(i)) + [255] for i in range(m)], dtype=np.uint8).reshape(m, 4)


def _normalization(center, scale, b: int, like: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    c = torch.as_tensor(np.asarray(center.detach().cpu() if isinstance(center, torch.Tensor) else center,
                                   dtype=np.float64)).to(like)
    s = torch.as_tensor(np.asarray(scale.detach().cpu() if isinstance(scale, torch.Tensor) else scale,
                                   dtype=np.float64)).to(like)
    if c.shape == (3,):
        c = c.expand(b, 3)
    if s.dim() == 0:
        s = s.expand(b)
    if c.shape != (b, 3) or s.shape != (b,):
        raise ValueError(f"center must have shape (3,) or ({b}, 3) and scale () or ({b},), got "
                         f"{tuple(c.shape)} and {tuple(s.shape)}")
    if not torch.isfinite(c).all() or not torch.isfinite(s).all() or (s <= 0).any():
        raise ValueError("the normalisation needs a finite center and a finite positive scale")
    return c, s


def denormalize_cuboids(cuboids: Cuboids, center, scale) -> Cuboids:
    """Cuboids in normalised coordinates -> the input's original coordinates (module docstring).

    Args:
        cuboids: (B, M) cuboids in normalised coordinates.
        center: (3,) or (B, 3) and scale: () or (B,), positive, as
            :func:`cuboidlib.normalization.normalize` returns them.

    Returns:
        (B, M) cuboids with centres ``c * scale + center`` and half sizes ``s * scale``; quaternions and
        existence unchanged.
    """
    c, s = _normalization(center, scale, cuboids.batch_size, cuboids.centers)
    return Cuboids(cuboids.centers * s[:, None, None] + c[:, None], cuboids.quaternions,
                   cuboids.half_sizes * s[:, None, None], cuboids.exists)


def normalize_cuboids(cuboids: Cuboids, center, scale) -> Cuboids:
    """Inverse of :func:`denormalize_cuboids`: centres ``(c - center) / scale``, half sizes ``s / scale``.

    Args:
        cuboids: (B, M) cuboids in original coordinates.
        center, scale: as for :func:`denormalize_cuboids`.

    Returns:
        (B, M) cuboids in normalised coordinates.
    """
    c, s = _normalization(center, scale, cuboids.batch_size, cuboids.centers)
    return Cuboids((cuboids.centers - c[:, None]) / s[:, None, None], cuboids.quaternions,
                   cuboids.half_sizes / s[:, None, None], cuboids.exists)


def _one_shape(cuboids: Cuboids, index: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """(centers (M, 3), quaternions (M, 4), half_sizes (M, 3), exists (M,)) of shape ``index``, detached."""
    if not isinstance(cuboids, Cuboids):
        raise TypeError(f"cuboids must be a Cuboids batch, got {type(cuboids).__name__}")
    if not -cuboids.batch_size <= index < cuboids.batch_size:
        raise IndexError(f"index {index} is out of range for a batch of {cuboids.batch_size} shapes")
    c = cuboids.detach().to(device="cpu")
    return c.centers[index], c.quaternions[index], c.half_sizes[index], c.existing()[index]


def cuboid_node_name(m: int, num_cuboids: int) -> str:
    """Name of cuboid m in meshes: ``cuboid_07`` (at least two digits, enough for every index < M).

    Args:
        m: the cuboid index.
        num_cuboids: M, the cuboid slots of the shape.

    Returns:
        The node, mesh and material name.
    """
    return f"cuboid_{m:0{max(2, len(str(num_cuboids - 1)))}d}"


# ----------------------------------------------------------------------------------------------
# JSON
# ----------------------------------------------------------------------------------------------


def _floats(x: torch.Tensor) -> list:
    return x.double().tolist()


def cuboids_to_dict(
    cuboids: Cuboids,
    index: int = 0,
    *,
    coordinates: str = "original",
    center=None,
    scale: float = 1.0,
    source: str | None = None,
    method: dict | None = None,
    part_labels=None,
    part_names=None,
    chamfer: float | None = None,
    chamfer_convention: ChamferConvention | None = None,
    points_file: str | None = None,
) -> dict:
    """The JSON document (module docstring) of shape ``index`` of ``cuboids``.

    Args:
        cuboids: (B, M) cuboids, already in ``coordinates``.
        index: the shape to write.
        coordinates: "original" or "normalized", the frame the cuboids are in.
        center, scale: the input's normalisation, (3,) and a positive number (default: identity).
        source: the input file name, or None.
        method: JSON types describing how the cuboids were made, or None.
        part_labels: optional (M,) integers, the part of every cuboid (-1 = unknown).
        part_names: optional names of the part labels.
        chamfer: optional Chamfer distance measured on the normalised shape.
        chamfer_convention: how ``chamfer`` was measured (required with it).
        points_file: optional name of the segmented points file written beside the JSON.

    Returns:
        A dict of JSON types.
    """
    if coordinates not in COORDINATES:
        raise ValueError(f"coordinates must be one of {COORDINATES}, got {coordinates!r}")
    c, q, s, e = _one_shape(cuboids, index)
    m = c.shape[0]
    float64 = torch.zeros((), dtype=torch.float64)
    center_t, scale_t = _normalization(np.zeros(3) if center is None else center, scale, 1, float64)
    labels = None
    if part_labels is not None:
        labels = np.asarray(part_labels.cpu() if isinstance(part_labels, torch.Tensor) else part_labels)
        if labels.shape != (m,) or not np.issubdtype(labels.dtype, np.integer):
            raise ValueError(f"part_labels must be ({m},) integers (-1 = unknown), got shape {labels.shape}, "
                             f"dtype {labels.dtype}")
    names = None if part_names is None else [str(n) for n in part_names]
    if labels is not None and names is not None and labels.max(initial=-1) >= len(names):
        raise ValueError(f"part_labels go up to {labels.max()} but only {len(names)} part_names are given")
    R = quaternion_to_rotation_matrix(q, validate=False)
    items = []
    for i in range(m):
        label = None if labels is None or labels[i] < 0 else int(labels[i])
        item = {
            "index": i,
            "exists": bool(e[i]),
            "center": _floats(c[i]),
            "quaternion": _floats(q[i]),
            "rotation_matrix": _floats(R[i]),
            "size": _floats(2 * s[i]),
            "part_label": label,
        }
        if names is not None:
            item["part_name"] = None if label is None else names[label]
        items.append(item)
    doc = {
        "format": JSON_FORMAT,
        "version": JSON_VERSION,
        "source": source,
        "method": method,
        "convention": dict(CONVENTION),
        "coordinates": coordinates,
        "normalization": {"center": _floats(center_t[0]), "scale": float(scale_t[0]),
                          "rule": "original = normalized * scale + center"},
        "num_cuboids": m,
        "num_existing": int(e.sum()),
    }
    if chamfer is not None:
        if not isinstance(chamfer_convention, ChamferConvention):
            raise ValueError("a chamfer value needs its chamfer_convention (a ChamferConvention)")
        doc["chamfer"] = {"value": float(chamfer), "convention": chamfer_convention.describe(),
                          "coordinates": "normalized"}
    if names is not None:
        doc["part_names"] = names
    if points_file is not None:
        doc["points_file"] = str(points_file)
    doc["cuboids"] = items
    return doc


def write_cuboids_json(path: str | os.PathLike, cuboids: Cuboids, index: int = 0, **kwargs) -> Path:
    """Write shape ``index`` of ``cuboids`` as JSON, atomically.

    Args:
        path: the file to write.
        cuboids, index, **kwargs: as for :func:`cuboids_to_dict`.

    Returns:
        ``path`` as a Path.
    """
    path = Path(path)
    doc = cuboids_to_dict(cuboids, index, **kwargs)
    write_text_atomic(path, _dumps(doc) + "\n")
    return path


def _dumps(doc: dict) -> str:
    """Indented JSON with every list of numbers (a centre, a quaternion, a matrix row) on one line."""
    lists: list[str] = []

    def mark(x):
        if isinstance(x, dict):
            return {k: mark(v) for k, v in x.items()}
        if isinstance(x, list):
            if x and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in x):
                lists.append(json.dumps(x))
                return f"\0{len(lists) - 1}\0"  # a placeholder string, replaced below
            return [mark(v) for v in x]
        return x

    text = json.dumps(mark(doc), indent=1)
    return re.sub(r'"\\u0000(\d+)\\u0000"', lambda m: lists[int(m[1])], text)


def _numbers(value, n: int, what: str) -> list[float]:
    if (not isinstance(value, list) or len(value) != n
            or not all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in value)):
        raise ValueError(f"{what} must be a list of {n} finite numbers, got {value!r}")
    return [float(v) for v in value]


def cuboids_from_dict(
    doc: dict, where: str = "cuboid JSON", dtype: torch.dtype = torch.float64
) -> tuple[Cuboids, dict]:
    """Parse and check a JSON document of :func:`cuboids_to_dict`.

    Args:
        doc: the parsed JSON.
        where: names the document in messages (a file name).
        dtype: the dtype of the returned cuboids.

    Returns:
        ``(Cuboids (1, M), metadata)`` as :func:`read_cuboids_json`, in the stored coordinates.

    Raises:
        ValueError: naming ``where`` and the entry, for anything malformed.
    """
    if not isinstance(doc, dict) or doc.get("format") != JSON_FORMAT:
        raise ValueError(f"{where}: not a cuboidlib cuboid file (no \"format\": \"{JSON_FORMAT}\")")
    version = doc.get("version")
    if not isinstance(version, int) or version > JSON_VERSION:
        raise ValueError(f"{where}: version {version!r} is not supported (this cuboidlib reads up to {JSON_VERSION})")
    coordinates = doc.get("coordinates")
    if coordinates not in COORDINATES:
        raise ValueError(f"{where}: \"coordinates\" must be one of {COORDINATES}, got {coordinates!r}")
    norm = doc.get("normalization")
    if not isinstance(norm, dict):
        raise ValueError(f"{where}: \"normalization\" must be an object with center and scale")
    center = _numbers(norm.get("center"), 3, f"{where}: normalization.center")
    scale = norm.get("scale")
    if isinstance(scale, bool) or not isinstance(scale, (int, float)) or not math.isfinite(scale) or scale <= 0:
        raise ValueError(f"{where}: normalization.scale must be a positive number, got {scale!r}")
    items = doc.get("cuboids")
    if not isinstance(items, list) or not items:
        raise ValueError(f"{where}: \"cuboids\" must be a non-empty list")
    m = len(items)
    indices = [item.get("index") if isinstance(item, dict) else None for item in items]
    if not all(isinstance(i, int) and not isinstance(i, bool) for i in indices) or sorted(indices) != list(range(m)):
        raise ValueError(f"{where}: the cuboids' \"index\" values must be 0 .. {m - 1}, each once")
    rows = [None] * m
    for item in items:
        i = item["index"]
        what = f"{where}: cuboid {i}"
        if not isinstance(item.get("exists"), bool):
            raise ValueError(f"{what}: \"exists\" must be true or false, got {item.get('exists')!r}")
        size = _numbers(item.get("size"), 3, f"{what}: size")
        if min(size) <= 0:
            raise ValueError(f"{what}: every size must be positive, got {size}")
        label = item.get("part_label")
        if label is not None and (isinstance(label, bool) or not isinstance(label, int) or label < 0):
            raise ValueError(f"{what}: part_label must be a non-negative integer or null, got {label!r}")
        rows[i] = (_numbers(item.get("center"), 3, f"{what}: center"),
                   _numbers(item.get("quaternion"), 4, f"{what}: quaternion"), size, item["exists"],
                   -1 if label is None else label, item.get("rotation_matrix"))
    centers = torch.tensor([r[0] for r in rows], dtype=dtype)[None]
    quaternions = torch.tensor([r[1] for r in rows], dtype=dtype)[None]
    half_sizes = torch.tensor([r[2] for r in rows], dtype=dtype)[None] / 2
    exists = torch.tensor([r[3] for r in rows])[None]
    try:
        cuboids = Cuboids(centers, quaternions, half_sizes, exists)
    except ValueError as exc:
        raise ValueError(f"{where}: {exc}") from exc
    R = quaternion_to_rotation_matrix(cuboids.quaternions[0].double(), validate=False)
    for i, r in enumerate(rows):
        if r[5] is None:
            continue
        if not isinstance(r[5], list) or len(r[5]) != 3:
            raise ValueError(f"{where}: cuboid {i}: rotation_matrix must be 3 rows of 3 numbers")
        matrix = torch.tensor([_numbers(row, 3, f"{where}: cuboid {i}: rotation_matrix row") for row in r[5]],
                              dtype=torch.float64)
        err = float((matrix - R[i]).abs().max())
        if err > _QUATERNION_MATRIX_TOL:
            raise ValueError(f"{where}: cuboid {i}: rotation_matrix and quaternion disagree (by {err:.3g}); "
                             "they must describe the same rotation")
    meta = {k: v for k, v in doc.items() if k != "cuboids"}
    meta["part_labels"] = [r[4] for r in rows]
    meta["normalization"] = {**norm, "center": center, "scale": float(scale)}
    return cuboids, meta


def read_cuboids_json(
    path: str | os.PathLike, coordinates: str | None = None, dtype: torch.dtype = torch.float64
) -> tuple[Cuboids, dict]:
    """Read a file of :func:`write_cuboids_json` back.

    Args:
        path: the JSON file.
        coordinates: None keeps the stored frame; "original" or "normalized" converts with the stored
            normalisation (and updates ``metadata["coordinates"]``).
        dtype: the dtype of the returned cuboids.

    Returns:
        ``(cuboids, metadata)``: (1, M) Cuboids, and every top-level entry but "cuboids" plus
        ``part_labels``, a list of M ints (-1 = unknown).

    Raises:
        FileNotFoundError: no such file.
        ValueError: naming the file and the entry, for anything malformed (wrong lengths, NaN, non-unit
            quaternions, non-positive sizes, a rotation matrix that contradicts its quaternion, ...).
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such file")
    doc = read_json(path)
    cuboids, meta = cuboids_from_dict(doc, str(path), dtype)
    if coordinates is not None and coordinates != meta["coordinates"]:
        if coordinates not in COORDINATES:
            raise ValueError(f"coordinates must be None or one of {COORDINATES}, got {coordinates!r}")
        convert = denormalize_cuboids if coordinates == "original" else normalize_cuboids
        cuboids = convert(cuboids, meta["normalization"]["center"], meta["normalization"]["scale"])
        meta["coordinates"] = coordinates
    return cuboids, meta


# ----------------------------------------------------------------------------------------------
# Meshes
# ----------------------------------------------------------------------------------------------


def _existing_meshes(cuboids: Cuboids, index: int) -> list[tuple[int, trimesh.Trimesh]]:
    """(cuboid index, mesh with 8 vertices, 12 triangles, palette face colours) of every existing cuboid."""
    c, q, s, e = _one_shape(cuboids, index)
    keep = torch.nonzero(e)[:, 0].tolist()
    if not keep:
        raise ValueError(f"shape {index} has no existing cuboid; there is nothing to write")
    meshes = cuboids_to_trimesh(c, q, s, e, colors=palette_rgba(c.shape[0]), split=True)
    return list(zip(keep, meshes))


def cuboid_scene(cuboids: Cuboids, index: int = 0) -> trimesh.Scene:
    """A trimesh scene of the existing cuboids of one shape, as :func:`write_cuboid_mesh` writes to GLB.

    Args:
        cuboids: (B, M) cuboids.
        index: the shape.

    Returns:
        A scene with one node per existing cuboid, named like its mesh and its PBR material
        (:func:`cuboid_node_name`; base colour = palette colour).
    """
    m = cuboids.num_cuboids
    scene = trimesh.Scene()
    for i, mesh in _existing_meshes(cuboids, index):
        name = cuboid_node_name(i, m)
        material = trimesh.visual.material.PBRMaterial(
            name=name, baseColorFactor=palette_rgba(m)[i], metallicFactor=0.0, roughnessFactor=1.0
        )
        mesh.visual = trimesh.visual.TextureVisuals(material=material)
        scene.add_geometry(mesh, node_name=name, geom_name=name)
    return scene


def _write_obj(path: Path, cuboids: Cuboids, index: int) -> None:
    m = cuboids.num_cuboids
    mtl = path.with_suffix(".mtl")
    colors = palette_rgba(m)
    obj_lines = ["# cuboids written by cuboidlib: one object per existing cuboid, material = palette colour",
                 f"mtllib {mtl.name}"]
    mtl_lines = ["# palette colours of the cuboids (cuboidlib.viz.PALETTE)"]
    offset = 1
    for i, mesh in _existing_meshes(cuboids, index):
        name = cuboid_node_name(i, m)
        obj_lines += [f"o {name}", f"usemtl {name}"]
        obj_lines += ["v {:.9g} {:.9g} {:.9g}".format(*v) for v in mesh.vertices]
        obj_lines += ["f {} {} {}".format(*(f + offset)) for f in mesh.faces]
        offset += len(mesh.vertices)
        r, g, b = (colors[i, :3] / 255).tolist()
        mtl_lines += [f"newmtl {name}", f"Kd {r:.6f} {g:.6f} {b:.6f}", "Ka 0 0 0", "Ks 0 0 0", "d 1", "illum 1"]
    write_text_atomic(mtl, "\n".join(mtl_lines) + "\n")
    write_text_atomic(path, "\n".join(obj_lines) + "\n")


def write_cuboid_mesh(path: str | os.PathLike, cuboids: Cuboids, index: int = 0) -> Path:
    """Write the existing cuboids of shape ``index`` as a mesh (8 corners, 12 outward triangles each).

    The format follows the suffix. GLB: one node, mesh and PBR material per cuboid, named
    ``cuboid_07`` (:func:`cuboid_node_name`), base colour = palette colour (sRGB values). OBJ: one object
    and material per cuboid, in the ``.mtl`` written beside it (``Kd`` = palette colour). PLY (binary):
    palette-coloured vertices and an int ``cuboid`` property per face.

    Args:
        path: a ``.glb``, ``.obj`` or ``.ply`` file.
        cuboids: (B, M) cuboids.
        index: the shape to write.

    Returns:
        ``path`` as a Path.
    """
    path = Path(path)
    kind = path.suffix.lower().lstrip(".")
    if kind not in MESH_FORMATS:
        raise ValueError(f"{path}: unknown mesh format {path.suffix!r}; expected one of "
                         f"{', '.join('.' + f for f in MESH_FORMATS)}")
    if kind == "glb":
        with atomic_path(path) as tmp:
            cuboid_scene(cuboids, index).export(str(tmp), file_type="glb")
    elif kind == "obj":
        _write_obj(path, cuboids, index)
    else:
        parts = _existing_meshes(cuboids, index)
        vertices = np.concatenate([mesh.vertices for _, mesh in parts])
        faces = np.concatenate([mesh.faces + 8 * k for k, (_, mesh) in enumerate(parts)])  # (12 K, 3)
        kept = [i for i, _ in parts]
        mesh = trimesh.Trimesh(vertices, faces, process=False)
        # one colour per cuboid on its own 8 vertices (vertex colours export without extra dependencies)
        colors = np.repeat(palette_rgba(cuboids.num_cuboids)[kept], 8, axis=0)  # (8 K, 4)
        mesh.visual = trimesh.visual.ColorVisuals(mesh, vertex_colors=colors)
        mesh.face_attributes["cuboid"] = np.repeat(kept, 12).astype(np.int32)
        with atomic_path(path) as tmp:
            mesh.export(str(tmp), file_type="ply", encoding="binary")
    return path


# ----------------------------------------------------------------------------------------------
# Segmented point clouds
# ----------------------------------------------------------------------------------------------


def _numpy(x) -> np.ndarray:
    return x.detach().cpu().numpy() if isinstance(x, torch.Tensor) else np.asarray(x)


def write_segmented_point_cloud(path: str | os.PathLike, points, labels, normals=None) -> Path:
    """Write points coloured by their cuboid as a binary PLY.

    Vertex properties: float ``x y z`` (and ``nx ny nz``), uchar ``red green blue`` (the palette colour of
    the point's cuboid, grey for -1) and int ``label``; :func:`cuboidlib.io.read_point_cloud` reads it back.

    Args:
        path: a ``.ply`` file.
        points: (N, 3), N >= 1, finite.
        labels: (N,) integers, the cuboid index of every point (-1 = none).
        normals: optional (N, 3).

    Returns:
        ``path`` as a Path.
    """
    path = Path(path)
    if path.suffix.lower() != ".ply":
        raise ValueError(f"{path}: segmented point clouds are written as .ply")
    p = _numpy(points).astype(np.float64)
    lab = _numpy(labels)
    if p.ndim != 2 or p.shape[1] != 3 or len(p) == 0:
        raise ValueError(f"points must have shape (N, 3) with N >= 1, got {p.shape}")
    if not np.isfinite(p).all():
        raise ValueError("points contain NaN or infinite values")
    if np.abs(p).max() > np.finfo(np.float32).max:
        raise ValueError(f"points up to {np.abs(p).max():.3g} do not fit the PLY file's float32; rescale them")
    if (lab.shape != (len(p),) or not np.issubdtype(lab.dtype, np.integer) or (lab < -1).any()
            or (lab >= 2**31).any()):
        raise ValueError(f"labels must be ({len(p)},) integers in [-1, 2^31) (cuboid indices), got shape "
                         f"{lab.shape}, dtype {lab.dtype}" + (f", largest {lab.max()}" if lab.size else ""))
    fields = [("x", "<f4"), ("y", "<f4"), ("z", "<f4")]
    n = None if normals is None else _numpy(normals).astype(np.float64)
    if n is not None:
        if n.shape != p.shape or not np.isfinite(n).all():
            raise ValueError(f"normals must be finite with the shape of points {p.shape}, got {n.shape}")
        fields += [("nx", "<f4"), ("ny", "<f4"), ("nz", "<f4")]
    fields += [("red", "u1"), ("green", "u1"), ("blue", "u1"), ("label", "<i4")]
    table = np.empty(len(p), dtype=fields)
    for k, name in enumerate("xyz"):
        table[name] = p[:, k]
        if n is not None:
            table["n" + name] = n[:, k]
    used, which = np.unique(lab[lab >= 0], return_inverse=True)  # colour only the labels present
    colors = np.array([_rgb255(cuboid_color(int(u))) for u in used], dtype=np.uint8).reshape(-1, 3)
    rgb = np.empty((len(p), 3), np.uint8)
    rgb[lab >= 0] = colors[which]
    rgb[lab < 0] = _rgb255(UNLABELLED)
    for k, name in enumerate(("red", "green", "blue")):
        table[name] = rgb[:, k]
    table["label"] = lab
    kind = {"<f4": "float", "u1": "uchar", "<i4": "int"}
    header = ["ply", "format binary_little_endian 1.0",
              "comment written by cuboidlib: points coloured by cuboid, label = cuboid index",
              f"element vertex {len(p)}"] + [f"property {kind[t]} {name}" for name, t in fields] + ["end_header"]
    with atomic_path(path) as tmp, open(tmp, "wb") as f:
        f.write(("\n".join(header) + "\n").encode("ascii"))
        f.write(table.tobytes())
    return path


# ----------------------------------------------------------------------------------------------
# Output folders: refuse to mix runs, and a manifest of what each run wrote
# ----------------------------------------------------------------------------------------------

# MANIFEST (cuboidlib.files): the file name of a results folder's manifest.


def read_manifest(folder: str | os.PathLike) -> dict | None:
    """The manifest of the run that wrote ``folder``.

    Args:
        folder: a results folder.

    Returns:
        The manifest dict (``command``, ``complete``, ``files``), or None if there is none or it is unreadable.
    """
    path = Path(folder) / MANIFEST
    try:
        doc = read_json(path)
    except (OSError, ValueError):
        return None
    files = doc.get("files") if isinstance(doc, dict) else None
    if not isinstance(files, list) or not all(isinstance(f, str) and "/" not in f and f not in ("", ".", "..")
                                               for f in files):
        return None
    return doc


def write_manifest(folder: str | os.PathLike, files, command: str | None = None, complete: bool = True) -> Path:
    """Record the files a run wrote in ``folder`` and whether the run completed.

    Args:
        folder: the results folder.
        files: the paths written there (only their names are kept).
        command: the command line of the run, or None.
        complete: whether the run finished.

    Returns:
        The path of the manifest file.
    """
    names = sorted({Path(f).name for f in files})
    doc = {"format": "cuboidlib-manifest", "command": command, "complete": bool(complete), "files": names}
    return write_text_atomic(Path(folder) / MANIFEST, json.dumps(doc, indent=1) + "\n")


def prepare_output_folder(folder: str | os.PathLike, overwrite: bool = False) -> Path:
    """Make ``folder`` ready for a new run's results without mixing them with an earlier run's.

    A folder with files but no manifest is refused even with ``overwrite``: nothing says which files are stale.

    Args:
        folder: the results folder; created if missing.
        overwrite: remove the files the earlier run listed in its manifest (never any other file).

    Returns:
        ``folder`` as a Path.

    Raises:
        ValueError: the folder holds files and ``overwrite`` is False, or it holds no manifest.
    """
    folder = Path(folder)
    if folder.exists() and not folder.is_dir():
        raise ValueError(f"{folder}: exists and is not a folder")
    present = sorted(p.name for p in folder.iterdir() if p.name != LOCK_FILE) if folder.is_dir() else []
    if not present:
        folder.mkdir(parents=True, exist_ok=True)
        return folder
    manifest = read_manifest(folder)
    if not overwrite:
        raise ValueError(f"{folder}: already holds {len(present)} file(s) ({', '.join(present[:3])}"
                         f"{', ...' if len(present) > 3 else ''}); choose another folder, or overwrite "
                         "the earlier results (--overwrite)")
    if manifest is None:
        raise ValueError(f"{folder}: holds files that no cuboidlib run recorded (no {MANIFEST}); "
                         "choose another folder")
    for name in manifest["files"] + [MANIFEST]:
        (folder / name).unlink(missing_ok=True)
    return folder
