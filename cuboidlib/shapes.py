"""Procedural, part-labelled shape collections that stand in for the paper's data (Sec. 4).

The paper uses ShapeNet chairs, tables and airplanes and a set of four-legged animals, scored against
part labels (Sec. 4.2). Nothing can be downloaded here, so :func:`make_collection` builds look-alikes:
each shape is a union of analytic solids (:mod:`cuboidlib.solids`) sampled area-uniformly on its outer
surface, with an outward normal and a part label (``PART_NAMES``) per point. Each shape also records
its optional parts (``structure``) and a coarse group for clustering (``structure_id``, an index into
``STRUCTURES``). Shapes are normalised as in :mod:`cuboidlib.normalization`. Shape i of a collection
comes from a generator seeded with (seed, category, i), so a prefix of a larger collection equals the
smaller one; collections are cached as npz, keyed by their arguments and the generator's version.

**Versions.** ``version`` (of :func:`build_parts`, :func:`make_shape`, :func:`make_collection`) picks the
generator, each bit for bit for ever: 1 makes the shapes of the committed chair, table and animal networks; 2,
those of the airplane network, adds what the real meshes of ``benchmarks/real_meshes/`` show and version 1 lacks
(``experiments/transfer_causes.py``): light aircraft and fixed landing gear (:mod:`cuboidlib.shapes_airplane`),
thighs labelled leg, posed tails and wider bodies (:mod:`cuboidlib.shapes_animal`); 3 (:data:`GENERATOR_VERSION`,
the default) is version 2 with the animals' thighs left out. Chairs and tables are the same in every version,
airplanes in versions 2 and 3.
"""

from __future__ import annotations

import math
import os
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Sequence

import numpy as np
import trimesh

from ._checks import MAX_COLLECTION_POINTS, MAX_SHAPE_POINTS, MAX_SHAPES, check_size
from .normalization import normalize
from .shapes_airplane import airplane_v1, airplane_v2
from .shapes_animal import animal_v1, animal_v2, animal_v3
from .shapes_chair import chair
from .shapes_table import table
from .solids import Solid, sample_union_surface

__all__ = [
    "CATEGORIES",
    "PART_NAMES",
    "STRUCTURES",
    "GENERATOR_VERSION",
    "GENERATOR_VERSIONS",
    "check_generator_version",
    "PART_COLORS",
    "Shape",
    "ShapeCollection",
    "build_parts",
    "make_shape",
    "make_collection",
    "default_cache_dir",
    "plot_shapes",
]

CATEGORIES: tuple[str, ...] = ("chair", "table", "airplane", "animal")

# Part labels index these tuples. As in the paper (Sec. 4.2, after BSP-Net) every table support is
# "leg"; an animal's neck is labelled "head".
PART_NAMES: dict[str, tuple[str, ...]] = {
    "chair": ("back", "seat", "leg", "arm"),
    "table": ("top", "leg"),
    "airplane": ("body", "wing", "tail", "engine"),
    "animal": ("body", "head", "leg", "tail"),
}

# Coarse groups for clustering: chair legs type x armrests, table support x top shape (and trestle),
# airplane engine count x T-tail, animal body plan. Every group gets at least ~7 % of a collection.
STRUCTURES: dict[str, tuple[str, ...]] = {
    "chair": ("legs4", "legs4+arms", "pedestal", "pedestal+arms", "sled", "sled+arms"),
    "table": ("legs4-rect", "legs4-round", "pedestal-rect", "pedestal-round", "trestle"),
    "airplane": ("engines0", "engines0+t-tail", "engines2", "engines2+t-tail", "engines4", "engines4+t-tail",
                 "propeller"),  # propeller: light aircraft, generator version 2 only
    "animal": ("standard", "long-neck", "low-long", "stocky"),
}

#: The generators, oldest first. A version's shapes never change; a change of the shapes is a new version.
GENERATOR_VERSIONS: tuple[int, ...] = (1, 2, 3)

#: The default generator: the newest.
GENERATOR_VERSION = GENERATOR_VERSIONS[-1]

#: RGB colours of part labels 0, 1, 2, 3 in figures (and in exported sample meshes).
PART_COLORS: tuple[tuple[float, float, float], ...] = (
    (0.122, 0.467, 0.706),
    (1.000, 0.498, 0.055),
    (0.173, 0.627, 0.173),
    (0.839, 0.153, 0.157),
)

#: The generator of each (category, version); chairs and tables are the same in every version.
_GENERATORS: dict[tuple[str, int], Callable[[np.random.Generator], tuple[list[Solid], str, str]]] = {
    ("chair", 1): chair, ("chair", 2): chair, ("chair", 3): chair,
    ("table", 1): table, ("table", 2): table, ("table", 3): table,
    ("airplane", 1): airplane_v1, ("airplane", 2): airplane_v2, ("airplane", 3): airplane_v2,
    ("animal", 1): animal_v1, ("animal", 2): animal_v2, ("animal", 3): animal_v3,
}


# ------------------------------------------------------------------------------- public API


def _check_category(category: str) -> str:
    if category not in PART_NAMES:
        raise ValueError(f"category must be one of {CATEGORIES}, got {category!r}")
    return category


def check_generator_version(version) -> int:
    """The generator version, checked.

    Args:
        version: one of :data:`GENERATOR_VERSIONS`.

    Returns:
        ``version`` as an int.

    Raises:
        ValueError: another value (a bool, a float, an unknown number).
    """
    if isinstance(version, bool) or not isinstance(version, (int, np.integer)) or int(version) not in GENERATOR_VERSIONS:
        raise ValueError(f"generator version must be one of {GENERATOR_VERSIONS} (1: the shapes of the committed chair, "
                         f"table and animal networks; 2: the airplane network's; {GENERATOR_VERSION}: the newest), "
                         f"got {version!r}")
    return int(version)


def _shape_rng(category: str, index: int, seed: int) -> np.random.Generator:
    if seed < 0 or index < 0:
        raise ValueError(f"seed and index must be non-negative integers, got seed={seed}, index={index}")
    return np.random.default_rng([int(seed), CATEGORIES.index(category), int(index)])


def build_parts(category: str, index: int, seed: int = 0,
                version: int = GENERATOR_VERSION) -> tuple[list[Solid], str, int]:
    """The parts of shape ``index`` of a collection, before sampling and normalisation.

    Args:
        category: one of :data:`CATEGORIES`.
        index: the shape's index in the collection, >= 0.
        seed: the collection's seed, >= 0.
        version: the generator, one of :data:`GENERATOR_VERSIONS` (1: the committed networks' shapes).

    Returns:
        ``(solids, structure, structure_id)``: the solids in generator units (metres), each labelled
        with an index into ``PART_NAMES[category]``; the structure string, e.g.
        ``"legs4+stretchers+arms+slatted-back+tilted"``; the coarse group, an index into
        ``STRUCTURES[category]``.
    """
    _check_category(category)
    version = check_generator_version(version)
    solids, structure, coarse = _GENERATORS[category, version](_shape_rng(category, index, seed))
    return solids, structure, STRUCTURES[category].index(coarse)


@dataclass
class Shape:
    """One procedural shape, normalised (see :mod:`cuboidlib.normalization`).

    Attributes:
        category: one of :data:`CATEGORIES`.
        points: (N, 3) float32 surface points.
        normals: (N, 3) float32 outward unit normals.
        labels: (N,) int64 part labels, indices into ``PART_NAMES[category]``.
        structure: string of the optional parts, e.g. ``"pedestal+arms+solid-back"``.
        structure_id: coarse structure, an index into ``STRUCTURES[category]``.
        parts: the analytic solids in normalised coordinates (their union is the shape).
        instances: (N,) int64 the part instance of each point: the index into ``parts`` of the solid it was
            sampled on (a leg, one slat of a back). ``labels == [parts[i].label for i in instances]``.
    """

    category: str
    points: np.ndarray
    normals: np.ndarray
    labels: np.ndarray
    structure: str
    structure_id: int
    parts: list[Solid] = field(repr=False)
    instances: np.ndarray | None = None

    @property
    def part_names(self) -> tuple[str, ...]:
        """The names of the part labels, ``PART_NAMES[category]``."""
        return PART_NAMES[self.category]

    def mesh(self) -> trimesh.Trimesh:
        """The parts' meshes concatenated (not boolean-merged), vertices coloured by part label.

        Returns:
            A ``trimesh.Trimesh`` whose face attribute ``label`` holds each face's part label. (Vertex
            colours, because trimesh exports them without scipy.)
        """
        meshes = [p.mesh() for p in self.parts]
        mesh = trimesh.util.concatenate(meshes)
        vertex_labels = np.concatenate([np.full(len(m.vertices), p.label) for p, m in zip(self.parts, meshes)])
        rgb = np.round(np.array(PART_COLORS)[vertex_labels] * 255).astype(np.uint8)
        mesh.visual.vertex_colors = np.concatenate([rgb, np.full((len(rgb), 1), 255, np.uint8)], axis=1)
        face_labels = np.concatenate([np.full(len(m.faces), p.label) for p, m in zip(self.parts, meshes)])
        mesh.face_attributes["label"] = face_labels.astype(np.int32)
        return mesh


def _sample_shape(category: str, index: int, seed: int, n_points: int, version: int):
    solids, structure, sid = build_parts(category, index, seed, version)
    rng = np.random.default_rng([int(seed), CATEGORIES.index(category), int(index), 1])  # sampling stream
    p, nn, idx = sample_union_surface(solids, n_points, rng)
    labels = np.array([s.label for s in solids])[idx]
    p, center, scale = normalize(p)
    return solids, structure, sid, p, nn, labels, idx, center, scale


def make_shape(category: str, index: int = 0, n_points: int = 2048, seed: int = 0,
               version: int = GENERATOR_VERSION) -> Shape:
    """Generate shape ``index`` of the collection ``(category, seed)``, with its analytic parts.

    Args:
        category: one of :data:`CATEGORIES`.
        index: the shape's index in the collection.
        n_points: N, points sampled on its surface.
        seed: the collection's seed.
        version: the generator, one of :data:`GENERATOR_VERSIONS`.

    Returns:
        A :class:`Shape` equal to entry ``index`` of ``make_collection(category, n, n_points, seed)``
        for any ``n > index``, plus its parts (for meshes and exact inside/outside tests).
    """
    _check_category(category)
    version = check_generator_version(version)
    n_points = check_size(n_points, "n_points", MAX_SHAPE_POINTS)
    solids, structure, sid, p, nn, labels, instances, center, scale = _sample_shape(category, index, seed, n_points,
                                                                                           version)
    return Shape(
        category=category,
        points=p.astype(np.float32),
        normals=nn.astype(np.float32),
        labels=labels.astype(np.int64),
        structure=structure,
        structure_id=sid,
        parts=[s.mapped(center, scale) for s in solids],
        instances=np.asarray(instances, dtype=np.int64),
    )


@dataclass
class ShapeCollection:
    """A collection of procedural shapes of one category, as stacked arrays.

    Attributes:
        category: one of :data:`CATEGORIES`.
        points: (S, N, 3) float32, each shape normalised.
        normals: (S, N, 3) float32 outward unit normals.
        labels: (S, N) int64 part labels (indices into ``PART_NAMES[category]``).
        structures: (S,) structure strings.
        structure_ids: (S,) int64 coarse structures (indices into ``STRUCTURES[category]``).
        seed: the collection's seed.
        instances: (S, N) int64 part instances (each point's solid, as in :attr:`Shape.instances`), or None
            for a collection file written without them.
        generator_version: the generator that made it (a file written without it: 1).
    """

    category: str
    points: np.ndarray
    normals: np.ndarray
    labels: np.ndarray
    structures: np.ndarray
    structure_ids: np.ndarray
    seed: int = 0
    instances: np.ndarray | None = None
    generator_version: int = GENERATOR_VERSION

    @property
    def part_names(self) -> tuple[str, ...]:
        """The names of the part labels, ``PART_NAMES[category]``."""
        return PART_NAMES[self.category]

    @property
    def structure_names(self) -> tuple[str, ...]:
        """The names of the coarse structure groups, ``STRUCTURES[category]``."""
        return STRUCTURES[self.category]

    def __len__(self) -> int:
        return int(self.points.shape[0])

    def save(self, path: str | os.PathLike) -> Path:
        """Write the collection to an ``.npz`` file (no pickled objects), atomically.

        Args:
            path: the file to write; missing folders are created.

        Returns:
            The path written.
        """
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        extra = {} if self.instances is None else {"instances": self.instances}
        with tempfile.NamedTemporaryFile(dir=path.parent, suffix=".npz", delete=False) as f:
            np.savez(f, category=np.array(self.category), points=self.points, normals=self.normals,
                     labels=self.labels, structures=np.asarray(self.structures, dtype=str),
                     structure_ids=self.structure_ids, seed=np.array(self.seed),
                     generator_version=np.array(self.generator_version), **extra)
        os.replace(f.name, path)
        return path

    @classmethod
    def load(cls, path: str | os.PathLike) -> "ShapeCollection":
        """Read a collection written by :meth:`save`.

        Args:
            path: an ``.npz`` file.

        Returns:
            The :class:`ShapeCollection`.

        Raises:
            FileNotFoundError: when ``path`` is not a file.
            ValueError: when the file is unreadable or does not hold a valid collection.
        """
        path = Path(path)
        if not path.is_file():
            raise FileNotFoundError(f"{path}: no such collection file")
        try:
            with np.load(path, allow_pickle=False) as z:
                data = {k: z[k] for k in z.files}
        except Exception as exc:  # noqa: BLE001 - re-raised with the file name
            raise ValueError(f"{path}: not a readable collection file ({exc})") from exc
        missing = {"category", "points", "normals", "labels", "structures", "structure_ids"} - set(data)
        if missing:
            raise ValueError(f"{path}: not a shape collection (missing arrays {sorted(missing)})")
        category = str(data["category"])
        if category not in CATEGORIES:
            raise ValueError(f"{path}: unknown category {category!r}; expected one of {CATEGORIES}")
        points, normals, labels = data["points"], data["normals"], data["labels"]
        if points.ndim != 3 or points.shape[-1] != 3 or normals.shape != points.shape:
            raise ValueError(f"{path}: points {points.shape} and normals {normals.shape} must both be (S, N, 3)")
        if labels.shape != points.shape[:2] or data["structures"].shape != points.shape[:1] or \
                data["structure_ids"].shape != points.shape[:1]:
            raise ValueError(f"{path}: labels, structures and structure ids do not match points {points.shape}")
        if points.dtype.kind != "f" or normals.dtype.kind != "f" or labels.dtype.kind not in "iu":
            raise ValueError(f"{path}: points and normals must be floats and labels integers")
        if not (np.isfinite(points).all() and np.isfinite(normals).all()):
            raise ValueError(f"{path}: holds NaN or infinite coordinates")
        if labels.size and (labels.min() < 0 or labels.max() >= len(PART_NAMES[category])):
            raise ValueError(f"{path}: part labels outside 0 .. {len(PART_NAMES[category]) - 1}")
        version = int(data.get("generator_version", 1))
        if version not in GENERATOR_VERSIONS:
            raise ValueError(f"{path}: generator version {version} is not one of {GENERATOR_VERSIONS}")
        instances = data.get("instances")
        if instances is not None:
            if instances.shape != labels.shape or instances.dtype.kind not in "iu" or \
                    (instances.size and instances.min() < 0):
                raise ValueError(f"{path}: instances must be non-negative integers shaped like the labels "
                                 f"{labels.shape}, got {instances.dtype} {instances.shape}")
            instances = instances.astype(np.int64)
        return cls(category=category, points=points, normals=normals, labels=labels.astype(np.int64),
                   structures=data["structures"], structure_ids=data["structure_ids"].astype(np.int64),
                   seed=int(data.get("seed", 0)), instances=instances,
                   generator_version=version)


def default_cache_dir() -> Path:
    """``$CUBOIDLIB_CACHE`` if set, else ``~/.cache/cuboidlib``."""
    env = os.environ.get("CUBOIDLIB_CACHE")
    return Path(env) if env else Path.home() / ".cache" / "cuboidlib"


def make_collection(
    category: str,
    n_shapes: int,
    n_points: int = 2048,
    seed: int = 0,
    cache_dir: str | os.PathLike | None = None,
    use_cache: bool = True,
    progress: bool = False,
    version: int = GENERATOR_VERSION,
) -> ShapeCollection:
    """Generate (or load from the cache) ``n_shapes`` shapes of ``category`` with ``n_points`` each.

    Args:
        category: "chair", "table", "airplane" or "animal".
        n_shapes: S, the number of shapes.
        n_points: N, points per shape.
        seed: the collection's seed (shape i's generator is seeded with ``(seed, category, i)``).
        cache_dir: cache folder; None: :func:`default_cache_dir`. The file name encodes
            ``(category, n_shapes, n_points, seed, version)``.
        use_cache: read and write the cache; False always generates and writes nothing.
        progress: show a tqdm progress bar while generating.
        version: the generator, one of :data:`GENERATOR_VERSIONS` (1: the committed networks' shapes).

    Returns:
        A :class:`ShapeCollection`: points (S, N, 3) and normals (S, N, 3) float32, labels and instances
        (S, N) int64.
    """
    _check_category(category)
    version = check_generator_version(version)
    n_shapes = check_size(n_shapes, "n_shapes", MAX_SHAPES, "shapes")
    n_points = check_size(n_points, "n_points", MAX_SHAPE_POINTS)
    check_size(n_shapes * n_points, f"n_shapes x n_points ({n_shapes:,} x {n_points:,})", MAX_COLLECTION_POINTS)
    cache_file = None
    if use_cache:
        cache_dir = Path(cache_dir) if cache_dir is not None else default_cache_dir()
        cache_file = cache_dir / f"{category}_S{n_shapes}_N{n_points}_seed{seed}_v{version}.npz"
        if cache_file.is_file():
            try:
                cached = ShapeCollection.load(cache_file)
                if (cached.category, cached.points.shape, cached.seed, cached.generator_version) == \
                        (category, (n_shapes, n_points, 3), seed, version) \
                        and cached.instances is not None:
                    return cached
            except ValueError:
                pass  # unreadable, invalid, mismatched or instance-less cache entry: regenerate and overwrite it
    points = np.empty((n_shapes, n_points, 3), np.float32)
    normals = np.empty((n_shapes, n_points, 3), np.float32)
    labels = np.empty((n_shapes, n_points), np.int64)
    instances = np.empty((n_shapes, n_points), np.int64)
    structures, ids = [], np.empty(n_shapes, np.int64)
    indices = range(n_shapes)
    if progress:
        from tqdm.auto import tqdm

        indices = tqdm(indices, desc=f"{category} shapes")
    for i in indices:
        _, structure, sid, p, nn, lab, inst, _, _ = _sample_shape(category, i, seed, n_points, version)
        points[i], normals[i], labels[i], instances[i] = p, nn, lab, inst
        structures.append(structure)
        ids[i] = sid
    coll = ShapeCollection(category, points, normals, labels, np.array(structures, dtype=str), ids, seed, instances,
                           version)
    if cache_file is not None:
        coll.save(cache_file)
    return coll


def plot_shapes(shapes: Sequence, titles: Sequence[str] | None = None, ncols: int = 3, point_size: float = 2.0,
                figsize_per_plot: float = 2.6):
    """Matplotlib figure of part-labelled point clouds: one 3D scatter per shape, +y up, front (+z) to the viewer.

    Args:
        shapes: :class:`Shape` objects or ``(points (N, 3), labels (N,), category)`` tuples.
        titles: optional title per shape.
        ncols: subplots per row.
        point_size: marker size.
        figsize_per_plot: inches per subplot side.

    Returns:
        The ``matplotlib.figure.Figure``, a legend naming the parts at each run of one category.
    """
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D

    items = [(s.points, s.labels, s.category) if isinstance(s, Shape) else s for s in shapes]
    nrows = max(1, math.ceil(len(items) / ncols))
    fig = plt.figure(figsize=(figsize_per_plot * ncols, figsize_per_plot * nrows))
    previous = None
    for k, (pts, lab, cat) in enumerate(items):
        ax = fig.add_subplot(nrows, ncols, k + 1, projection="3d", proj_type="ortho")
        pts, lab = np.asarray(pts), np.asarray(lab)
        ax.scatter(pts[:, 0], -pts[:, 2], pts[:, 1], c=np.array(PART_COLORS)[lab], s=point_size, linewidths=0)
        half = float(np.abs(pts).max())
        for setter in (ax.set_xlim, ax.set_ylim, ax.set_zlim):
            setter(-half, half)
        ax.set_box_aspect((1, 1, 1), zoom=1.25)
        ax.view_init(elev=20, azim=-60)
        ax.set_axis_off()
        if titles is not None:
            ax.set_title(titles[k], fontsize=7)
        if cat != previous:  # one legend per run of shapes of the same category
            handles = [Line2D([], [], marker="o", ls="", color=PART_COLORS[i], label=name)
                       for i, name in enumerate(PART_NAMES[cat])]
            ax.legend(handles=handles, loc="upper left", fontsize=6, frameon=False, handletextpad=0.1,
                      borderaxespad=0.0)
        previous = cat
    fig.subplots_adjust(left=0.0, right=1.0, bottom=0.0, top=0.95, wspace=0.0, hspace=0.1)
    return fig
