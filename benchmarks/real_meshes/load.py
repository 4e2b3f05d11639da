"""Real, part-labelled meshes made by people, read at run time from the folders they were extracted to.

``manifest.json`` beside this file names every shape: its category, the file under one of the source roots,
its licence and attribution, the rotation ``to_network`` from the file's frame to the networks' frame (+y up,
facing +z) and how each triangle (or point) gets its part. Nothing of the sources is committed here except
the pyvista example meshes (MIT) under ``data_samples/real/``; see ``README.md`` beside this file.

Label methods (``labels.by`` in the manifest):

* ``node``: a glTF node's name (every triangle of the node's mesh), node transforms applied; a skinned mesh
  is taken in its bind pose (the mesh as modelled, placed by its node's transform), not posed by its joints;
* ``group``: an OBJ group (``g``) name;
* ``material``: the name of a glTF primitive's material;
* ``skin_joint``: for a skinned glTF mesh, the part of a triangle is the part whose joints carry the most skin
  weight summed over the triangle's three vertices; a mesh node without skin (a stag's antlers) goes by its
  node name, listed in the same map;
* ``segment_colour``: a separate coloured point cloud (``labels.segments``, a PLY in the same root) gives the
  segments; each sampled point takes the colour of the nearest segment point;
* no ``labels``: an unlabelled shape (``RealShape.labels`` is None).

``labels.map`` maps every name the file holds (node, group, material, joint or ``#rrggbb`` colour) to a part
name of ``cuboidlib.shapes.PART_NAMES[category]`` or to ``"ignore"``: the triangles of an ignored node or
group are dropped before sampling (used for things that are not the object: a blurred-propeller disc, a
ground shadow). A name in the file that the map does not list, or a name in the map that the file does not
hold, makes the shape be skipped with a line saying so: nothing is dropped silently.

Command line::

    python benchmarks/real_meshes/load.py --root diegogb=/work/realsrc/diegogb \\
        --root flightairmap=/work/realsrc/flightairmap --root quaternius=/work/realsrc/quaternius \\
        --root pyvista=data_samples/real --summary --png /tmp/real_png
"""

from __future__ import annotations

import argparse
import base64
import json
import struct
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from cuboidlib.shapes import PART_COLORS, PART_NAMES  # noqa: E402

MANIFEST = HERE / "manifest.json"
IGNORE = "ignore"

__all__ = ["RealShape", "MeshPiece", "read_manifest", "read_pieces", "load_shape", "load_real_shapes", "main"]


@dataclass
class RealShape:
    """One real shape: points in the file's own units and frame; ``to_network @ p`` is in the networks' frame."""

    name: str
    category: str
    points: np.ndarray  # (N, 3) float32
    normals: np.ndarray  # (N, 3) float32, unit face normals
    labels: np.ndarray | None  # (N,) int64 indices into PART_NAMES[category], None when unlabelled
    to_network: np.ndarray  # (3, 3) rotation
    licence: str
    source: str

    @property
    def part_names(self) -> tuple[str, ...]:
        return PART_NAMES[self.category]

    def network_points(self) -> np.ndarray:
        """The points rotated into the networks' frame (+y up, facing +z); units unchanged."""
        return (self.points.astype(np.float64) @ self.to_network.T).astype(np.float32)


@dataclass
class MeshPiece:
    """Triangles of one node / group / primitive, in the file's frame."""

    name: str
    vertices: np.ndarray  # (V, 3) float64
    faces: np.ndarray  # (F, 3) int64
    material: str = ""
    joints: list[str] | None = None  # skin joint names, columns of weights
    weights: np.ndarray | None = None  # (V, len(joints)) skin weights


# ----------------------------------------------------------------------------------------------------------
# glTF 2.0 (own reader: trimesh's loader keeps neither skin weights nor repeated node names)
# ----------------------------------------------------------------------------------------------------------

_COMPONENT = {5120: np.int8, 5121: np.uint8, 5122: np.int16, 5123: np.uint16, 5125: np.uint32, 5126: np.float32}
_WIDTH = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT2": 4, "MAT3": 9, "MAT4": 16}


def _gltf_document(path: Path) -> tuple[dict, list[bytes]]:
    data = path.read_bytes()
    if data[:4] == b"glTF":
        version = struct.unpack("<I", data[4:8])[0]
        if version != 2:
            raise ValueError(f"{path}: glTF version {version}, only 2 is read")
        offset, doc, chunks = 12, None, []
        while offset + 8 <= len(data):
            length, kind = struct.unpack("<II", data[offset:offset + 8])
            body = data[offset + 8:offset + 8 + length]
            if kind == 0x4E4F534A:
                doc = json.loads(body)
            elif kind == 0x004E4942:
                chunks.append(body)
            offset += 8 + length
        if doc is None:
            raise ValueError(f"{path}: GLB without a JSON chunk")
    else:
        doc, chunks = json.loads(data), []
    if not str(doc.get("asset", {}).get("version", "2")).startswith("2"):
        raise ValueError(f"{path}: glTF version {doc['asset'].get('version')}, only 2 is read")
    buffers = []
    for i, buf in enumerate(doc.get("buffers", [])):
        uri = buf.get("uri")
        if uri is None:
            buffers.append(chunks[0] if chunks else b"")
        elif uri.startswith("data:"):
            buffers.append(base64.b64decode(uri.split(",", 1)[1]))
        else:
            buffers.append((path.parent / uri).read_bytes())
    return doc, buffers


def _accessor(doc: dict, buffers: list[bytes], index: int) -> np.ndarray:
    acc = doc["accessors"][index]
    if "sparse" in acc:
        raise ValueError("sparse glTF accessors are not read")
    dtype, width, count = np.dtype(_COMPONENT[acc["componentType"]]), _WIDTH[acc["type"]], acc["count"]
    if "bufferView" not in acc:
        out = np.zeros((count, width), dtype)
    else:
        view = doc["bufferViews"][acc["bufferView"]]
        raw = buffers[view["buffer"]]
        start = view.get("byteOffset", 0) + acc.get("byteOffset", 0)
        stride = view.get("byteStride") or dtype.itemsize * width
        out = np.ndarray((count, width), dtype, buffer=raw, offset=start, strides=(stride, dtype.itemsize)).copy()
    if acc.get("normalized") and dtype.kind in "iu":
        out = out.astype(np.float64) / np.iinfo(dtype).max
    return out


def _quat_matrix(q) -> np.ndarray:
    x, y, z, w = q
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def _local_matrix(node: dict) -> np.ndarray:
    if "matrix" in node:
        return np.asarray(node["matrix"], dtype=np.float64).reshape(4, 4).T
    m = np.eye(4)
    m[:3, :3] = _quat_matrix(node.get("rotation", [0, 0, 0, 1])) * np.asarray(node.get("scale", [1, 1, 1]))
    m[:3, 3] = node.get("translation", [0, 0, 0])
    return m


def _world_matrices(doc: dict) -> dict[int, np.ndarray]:
    """World matrix of every node reachable from the default scene."""
    nodes = doc.get("nodes", [])
    scenes = doc.get("scenes") or [{"nodes": [i for i in range(len(nodes))
                                              if not any(i in n.get("children", []) for n in nodes)]}]
    world: dict[int, np.ndarray] = {}
    stack = [(i, np.eye(4)) for i in scenes[doc.get("scene", 0)]["nodes"]]
    while stack:
        i, parent = stack.pop()
        world[i] = parent @ _local_matrix(nodes[i])
        stack.extend((c, world[i]) for c in nodes[i].get("children", []))
    return world


def _node_names(doc: dict) -> list[str]:
    """Node names, a repeated name made unique with ``#2``, ``#3``... in node order; unnamed: ``node<i>``."""
    seen: dict[str, int] = {}
    names = []
    for i, node in enumerate(doc.get("nodes", [])):
        name = node.get("name") or f"node{i}"
        seen[name] = seen.get(name, 0) + 1
        names.append(name if seen[name] == 1 else f"{name}#{seen[name]}")
    return names


def _skin_weights(doc, buffers, prim, skin, n_vertices, n_joints) -> np.ndarray:
    weights = np.zeros((n_vertices, n_joints))
    rows = np.arange(n_vertices)[:, None]
    k = 0
    while f"JOINTS_{k}" in prim["attributes"]:
        j = _accessor(doc, buffers, prim["attributes"][f"JOINTS_{k}"]).astype(np.int64)
        w = _accessor(doc, buffers, prim["attributes"][f"WEIGHTS_{k}"]).astype(np.float64)
        np.add.at(weights, (np.broadcast_to(rows, j.shape), j), w)
        k += 1
    total = weights.sum(1, keepdims=True)
    return np.divide(weights, total, out=np.zeros_like(weights), where=total > 0)


def _primitive_faces(doc, buffers, prim, n_vertices) -> np.ndarray | None:
    mode = prim.get("mode", 4)
    idx = (_accessor(doc, buffers, prim["indices"]).ravel().astype(np.int64) if "indices" in prim
           else np.arange(n_vertices))
    if mode == 4:
        return idx[: len(idx) // 3 * 3].reshape(-1, 3)
    if mode == 5:  # strip
        tri = np.stack([idx[:-2], idx[1:-1], idx[2:]], 1)
        tri[1::2] = tri[1::2][:, [1, 0, 2]]
        return tri
    if mode == 6:  # fan
        return np.stack([np.full(len(idx) - 2, idx[0]), idx[1:-1], idx[2:]], 1)
    return None  # points and lines have no area


def _read_gltf(path: Path) -> list[MeshPiece]:
    doc, buffers = _gltf_document(path)
    world, names = _world_matrices(doc), _node_names(doc)
    materials = [m.get("name") or f"material{i}" for i, m in enumerate(doc.get("materials", []))]
    pieces = []
    for i in sorted(world):
        node = doc["nodes"][i]
        if "mesh" not in node:
            continue
        skin = doc["skins"][node["skin"]] if "skin" in node else None
        joint_names = [names[j] for j in skin["joints"]] if skin else None
        for prim in doc["meshes"][node["mesh"]]["primitives"]:
            pos = _accessor(doc, buffers, prim["attributes"]["POSITION"]).astype(np.float64)
            faces = _primitive_faces(doc, buffers, prim, len(pos))
            if faces is None or len(faces) == 0:
                continue
            weights = None
            if skin is not None and "JOINTS_0" in prim["attributes"]:
                weights = _skin_weights(doc, buffers, prim, skin, len(pos), len(skin["joints"]))
            verts = pos @ world[i][:3, :3].T + world[i][:3, 3]
            material = materials[prim["material"]] if "material" in prim else ""
            pieces.append(MeshPiece(names[i], verts, faces, material,
                                    joint_names if weights is not None else None, weights))
    return pieces


# ----------------------------------------------------------------------------------------------------------
# OBJ / PLY through trimesh
# ----------------------------------------------------------------------------------------------------------


def _read_trimesh(path: Path, groups: bool) -> list[MeshPiece]:
    if groups:
        scene = trimesh.load(str(path), force="scene", split_groups=True, group_material=False,
                             process=False, maintain_order=True)
        pieces = []
        for node in scene.graph.nodes_geometry:
            transform, geom = scene.graph[node]
            mesh = scene.geometry[geom]
            verts = np.asarray(mesh.vertices, np.float64) @ transform[:3, :3].T + transform[:3, 3]
            pieces.append(MeshPiece(str(geom), verts, np.asarray(mesh.faces, np.int64)))
        return pieces
    mesh = trimesh.load(str(path), force="mesh", process=False, maintain_order=True)
    return [MeshPiece("", np.asarray(mesh.vertices, np.float64), np.asarray(mesh.faces, np.int64))]


def read_pieces(path: str | Path, by: str | None = None) -> list[MeshPiece]:
    """The triangles of a mesh file as named pieces (glTF nodes, OBJ groups, or one unnamed piece)."""
    path = Path(path)
    if path.suffix.lower() in (".glb", ".gltf"):
        return _read_gltf(path)
    return _read_trimesh(path, groups=(by == "group"))


# ----------------------------------------------------------------------------------------------------------
# Labels and sampling
# ----------------------------------------------------------------------------------------------------------


class MappingError(ValueError):
    """A manifest's label map does not match the file (a name unlisted, or listed but absent)."""


def _check_names(found: set[str], mapping: dict, what: str, category: str) -> None:
    missing = sorted(found - set(mapping))
    stale = sorted(set(mapping) - found)
    bad = sorted({v for v in mapping.values() if v != IGNORE and v not in PART_NAMES[category]})
    if missing:
        raise MappingError(f"{len(missing)} {what} not in the label map: {missing[:8]}")
    if stale:
        raise MappingError(f"{len(stale)} {what} of the label map not in the file: {stale[:8]}")
    if bad:
        raise MappingError(f"parts not of {category}: {bad}")


def _triangle_parts(pieces: list[MeshPiece], labels: dict | None, category: str):
    """Concatenated (vertices, faces) without ignored pieces, and a part index per face (or -1 / None)."""
    by = labels.get("by") if labels else None
    part_index = {p: i for i, p in enumerate(PART_NAMES[category])}
    if by in ("node", "group", "material"):
        key = (lambda p: p.material) if by == "material" else (lambda p: p.name)
        _check_names({key(p) for p in pieces}, labels["map"], f"{by}s", category)
    if by == "skin_joint":
        names = {j for p in pieces for j in (p.joints or [])} | {p.name for p in pieces if p.weights is None}
        if all(p.weights is None for p in pieces):
            raise MappingError("skin_joint labels on a mesh without skin weights")
        _check_names(names, labels["map"], "joints and unskinned nodes", category)
    verts, faces, parts, offset = [], [], [], 0
    for piece in pieces:
        if by in ("node", "group", "material"):
            part = labels["map"][piece.material if by == "material" else piece.name]
            if part == IGNORE:
                continue
            face_part = np.full(len(piece.faces), part_index[part])
        elif by == "skin_joint" and piece.weights is not None:
            face_part = _skin_face_parts(piece, labels["map"], part_index)
        elif by == "skin_joint":
            part = labels["map"][piece.name]
            if part == IGNORE:
                continue
            face_part = np.full(len(piece.faces), part_index[part])
        else:
            face_part = np.full(len(piece.faces), -1)
        verts.append(piece.vertices)
        faces.append(piece.faces + offset)
        parts.append(face_part)
        offset += len(piece.vertices)
    if not faces:
        raise MappingError("no triangles left")
    return np.concatenate(verts), np.concatenate(faces), np.concatenate(parts)


def _skin_face_parts(piece: MeshPiece, mapping: dict, part_index: dict) -> np.ndarray:
    columns = np.zeros((len(piece.joints), len(part_index)))
    for j, name in enumerate(piece.joints):
        if mapping[name] != IGNORE:
            columns[j, part_index[mapping[name]]] = 1.0
    vertex_parts = piece.weights @ columns  # (V, P) weight per part
    face_weight = vertex_parts[piece.faces].sum(1)  # (F, P)
    return np.argmax(face_weight, 1)


def sample_triangles(vertices: np.ndarray, faces: np.ndarray, n_points: int, seed: int):
    """Area-weighted uniform samples on every triangle: (points, unit face normals, face index)."""
    tri = vertices[faces]
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    area = np.linalg.norm(cross, axis=1)
    if not area.sum() > 0:
        raise MappingError("the mesh has no area")
    rng = np.random.default_rng(seed)
    face = rng.choice(len(faces), size=n_points, p=area / area.sum())
    u, v = rng.random(n_points), rng.random(n_points)
    flip = u + v > 1
    u[flip], v[flip] = 1 - u[flip], 1 - v[flip]
    t = tri[face]
    points = t[:, 0] + u[:, None] * (t[:, 1] - t[:, 0]) + v[:, None] * (t[:, 2] - t[:, 0])
    normals = cross[face] / area[face, None]
    return points, normals, face


def _nearest(queries: np.ndarray, points: np.ndarray, chunk: int = 256) -> np.ndarray:
    out = np.empty(len(queries), np.int64)
    sq = (points ** 2).sum(1)
    for s in range(0, len(queries), chunk):
        q = queries[s:s + chunk]
        out[s:s + chunk] = np.argmin(sq[None] - 2 * q @ points.T, 1)
    return out


def _segment_labels(points: np.ndarray, segments: Path, labels: dict, category: str) -> np.ndarray:
    cloud = trimesh.load(str(segments), process=False)
    colours = np.asarray(cloud.colors)[:, :3] if getattr(cloud, "colors", None) is not None else None
    if colours is None or len(colours) != len(cloud.vertices):
        raise MappingError(f"{segments.name} has no vertex colours")
    hexes = np.array([f"#{r:02x}{g:02x}{b:02x}" for r, g, b in colours])
    _check_names(set(hexes), labels["map"], "segment colours", category)
    nearest = _nearest(points, np.asarray(cloud.vertices, np.float64))
    part_index = {p: i for i, p in enumerate(PART_NAMES[category])}
    part_of = {h: part_index.get(p, -1) for h, p in labels["map"].items()}
    out = np.array([part_of[h] for h in hexes[nearest]], np.int64)
    if (out < 0).any():
        raise MappingError("segment colours mapped to 'ignore' are not supported")
    return out


def load_shape(entry: dict, root: Path, n_points: int = 2048, seed: int = 0) -> RealShape:
    """One manifest entry, its files under ``root``."""
    category, labels = entry["category"], entry.get("labels")
    path = root / entry["source"]["path"]
    if not path.is_file():
        raise FileNotFoundError(f"{path} missing")
    pieces = read_pieces(path, labels.get("by") if labels else None)
    by = labels.get("by") if labels else None
    verts, faces, face_part = _triangle_parts(pieces, labels if by != "segment_colour" else None, category)
    points, normals, face = sample_triangles(verts, faces, n_points, seed)
    if by == "segment_colour":
        seg = root / labels["segments"]
        if not seg.is_file():
            raise FileNotFoundError(f"{seg} missing")
        point_labels = _segment_labels(points, seg, labels, category)
    elif by is None:
        point_labels = None
    else:
        point_labels = face_part[face].astype(np.int64)
    rot = np.asarray(entry["to_network"], dtype=np.float64)
    if rot.shape != (3, 3) or not np.allclose(rot @ rot.T, np.eye(3), atol=1e-6) or np.linalg.det(rot) < 0:
        raise MappingError(f"to_network is not a rotation: {entry['to_network']}")
    src = entry["source"]
    where = (f"{src['repo']}@{src['commit'][:12]}:{src['path']}" if "repo" in src
             else f"{src['package']}=={src['version']}:{src['path']}")
    return RealShape(entry["id"], category, points.astype(np.float32), normals.astype(np.float32),
                     point_labels, rot, entry["licence"], where)


def read_manifest(path: str | Path = MANIFEST) -> dict:
    return json.loads(Path(path).read_text())


def load_real_shapes(roots: dict[str, Path], n_points: int = 2048, seed: int = 0,
                     manifest: str | Path | dict = MANIFEST,
                     categories: tuple[str, ...] | None = None) -> tuple[list[RealShape], list[str]]:
    """The manifest's shapes whose root is given and whose files are there, and one line per shape skipped."""
    data = manifest if isinstance(manifest, dict) else read_manifest(manifest)
    shapes, skipped = [], []
    for entry in data["shapes"]:
        if categories and entry["category"] not in categories:
            continue
        root = roots.get(entry["root"])
        if root is None:
            skipped.append(f"{entry['id']}: no root '{entry['root']}' given")
            continue
        try:
            shapes.append(load_shape(entry, Path(root), n_points, seed))
        except (OSError, ValueError, KeyError) as exc:
            skipped.append(f"{entry['id']}: {exc}")
    return shapes, skipped


# ----------------------------------------------------------------------------------------------------------
# Command line
# ----------------------------------------------------------------------------------------------------------


def summary_lines(shapes: list[RealShape]) -> list[str]:
    lines = []
    for category in PART_NAMES:
        group = [s for s in shapes if s.category == category]
        if not group:
            continue
        labelled = [s for s in group if s.labels is not None]
        line = f"{category:9s} {len(group):3d} shapes ({len(labelled)} labelled)"
        if labelled:
            counts = np.bincount(np.concatenate([s.labels for s in labelled]), minlength=len(PART_NAMES[category]))
            shares = counts / counts.sum()
            line += "  " + "  ".join(f"{p} {100 * f:.1f}%" for p, f in zip(PART_NAMES[category], shares))
            present = [sum(int((s.labels == i).any()) for s in labelled) for i in range(len(PART_NAMES[category]))]
            line += "   in shapes: " + " ".join(f"{p} {n}" for p, n in zip(PART_NAMES[category], present))
        lines.append(line)
    return lines


def write_png(shape: RealShape, folder: Path) -> Path:
    """Three views in the networks' frame (front: x-y, side: z-y with the front to the right, top: x-z)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    p = shape.network_points()
    colours = (np.array(PART_COLORS)[shape.labels] if shape.labels is not None
               else np.full((len(p), 3), 0.4))
    fig, axes = plt.subplots(1, 3, figsize=(10.5, 3.8))
    views = [("front (x right, y up)", 0, 1, False), ("side (z = front to the right, y up)", 2, 1, False),
             ("top (x right, z = front down)", 0, 2, True)]
    order = np.argsort(p[:, 2])  # draw the back first in the front view
    for ax, (title, a, b, flip) in zip(axes, views):
        o = order if a == 0 and b == 1 else np.argsort(-p[:, 0]) if a == 2 else np.argsort(p[:, 1])
        ax.scatter(p[o, a], p[o, b], c=colours[o], s=3, linewidths=0)
        ax.set_title(title, fontsize=8)
        ax.set_aspect("equal")
        if flip:
            ax.invert_yaxis()
        ax.tick_params(labelsize=6)
    names = shape.part_names if shape.labels is not None else ()
    handles = [plt.Line2D([], [], marker="o", ls="", color=PART_COLORS[i], label=n) for i, n in enumerate(names)]
    if handles:
        fig.legend(handles=handles, loc="lower center", ncol=len(handles), fontsize=8)
    fig.suptitle(f"{shape.name} ({shape.category}) {shape.licence}", fontsize=9)
    folder.mkdir(parents=True, exist_ok=True)
    out = folder / f"{shape.name}.png"
    fig.savefig(out, dpi=80)
    plt.close(fig)
    return out


def _parse_roots(items: list[str]) -> dict[str, Path]:
    roots = {}
    for item in items:
        name, sep, path = item.partition("=")
        if not sep or not name:
            raise SystemExit(f"--root takes NAME=PATH, got {item!r}")
        roots[name] = Path(path)
    return roots


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--root", action="append", default=[], metavar="NAME=PATH",
                        help="where a source's files were extracted (repeatable); NAME as in the manifest's roots")
    parser.add_argument("--manifest", type=Path, default=MANIFEST)
    parser.add_argument("--points", type=int, default=2048)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--only", nargs="*", default=None, help="these shape ids only")
    parser.add_argument("--summary", action="store_true", help="shapes per category and their part shares")
    parser.add_argument("--png", type=Path, default=None, metavar="DIR", help="one picture per shape, by part")
    args = parser.parse_args(argv)
    data = read_manifest(args.manifest)
    if args.only:
        data = dict(data, shapes=[e for e in data["shapes"] if e["id"] in set(args.only)])
    shapes, skipped = load_real_shapes(_parse_roots(args.root), args.points, args.seed, data)
    for line in skipped:
        print(f"skipped {line}")
    if args.summary or not args.png:
        for line in summary_lines(shapes):
            print(line)
    if args.png:
        for shape in shapes:
            write_png(shape, args.png)
        print(f"{len(shapes)} pictures in {args.png}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
