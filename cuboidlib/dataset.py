"""The data: a torch ``Dataset`` over procedural collections or files, in-memory shape sets, splits, noise.

One file, because every path to training data ends in the same ShapeSet and splits.

:class:`PointCloudDataset` reads one shape at a time; :class:`ShapeSet` holds many as stacked tensors
(what training and evaluation use); :func:`split_indices` assigns shapes to train / validation / test by
a seeded permutation, and :func:`load_splits` does both for a :class:`DataConfig` (a procedural
collection or a folder of files); :func:`add_noise` and :func:`noisy_splits` jitter the points as the
paper's noise experiment does (Table 4).
"""

from __future__ import annotations

import dataclasses
import math
import os
import warnings
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Callable, Sequence

import numpy as np
import torch

from ._checks import MAX_COLLECTION_POINTS, MAX_SHAPE_POINTS, MAX_SHAPES, check_int, check_seed, check_size
from .config import ConfigDict, derive_seed
from .files import MANIFEST, result_files_in
from .io import (
    MESH_SUFFIXES,
    POINT_CLOUD_SUFFIXES,
    PointCloud,
    authors_layout_files,
    is_mesh_file,
    load_point_cloud,
    shapenet_part_files,
    shapenet_part_labels,
)
from .shapes import (CATEGORIES, GENERATOR_VERSION, PART_NAMES, ShapeCollection, check_generator_version,
                     make_collection)

__all__ = [
    "DataConfig", "DATA_FIELDS", "UNVERSIONED_GENERATOR",
    "PAPER_ROTATIONS_DEG", "PointCloudDataset", "rotate_about_y", "ShapeSet", "split_indices", "load_shapes",
    "load_splits",
    "data_layout",
    "add_noise",
    "noisy_splits",
]

@dataclass
class DataConfig(ConfigDict):
    """Which shapes a run reads and how they are split. :class:`~cuboidlib.train_config.TrainConfig` extends it.

    Args:
        category: procedural category ("chair", "table", "airplane", "animal"); with ``data_dir``, the
            category of a ShapeNet-part or authors' folder, else only a name in logs.
        n_shapes: shapes in the procedural collection (ignored with ``data_dir``).
        n_points: points per shape (paper: 4096); for files a random subset of this size (meshes are
            sampled with this many points).
        data_seed: seed of the collection, or of the subsets drawn from files.
        data_dir: a folder of point-cloud / mesh files to use instead of a procedural collection.
        split_fractions: (train, validation, test) fractions of the shapes, summing to 1.
        split_seed: seed of the permutation that assigns shapes to the splits.
        generator_version: the procedural generator (:data:`cuboidlib.shapes.GENERATOR_VERSIONS`; ignored with
            ``data_dir``). The default is the newest; a config dict or file without the field means
            :data:`UNVERSIONED_GENERATOR` (1), the shapes of every config written before the field, the committed
            networks' among them.
    """

    category: str = "chair"
    n_shapes: int = 512
    n_points: int = 4096
    data_seed: int = 0
    data_dir: str | None = None
    split_fractions: tuple[float, float, float] = (0.7, 0.1, 0.2)
    split_seed: int = 0
    generator_version: int = GENERATOR_VERSION

    @classmethod
    def from_dict(cls, data: dict):
        """As :meth:`ConfigDict.from_dict`, with a missing ``generator_version`` read as :data:`UNVERSIONED_GENERATOR`."""
        if isinstance(data, dict) and "generator_version" not in data:
            data = {**data, "generator_version": UNVERSIONED_GENERATOR}
        return super().from_dict(data)

    def __post_init__(self) -> None:
        name = type(self).__name__
        try:
            self.generator_version = check_generator_version(self.generator_version)
        except ValueError as exc:
            raise ValueError(f"{name}.generator_version: {exc}") from None
        if self.data_dir is None and self.category not in CATEGORIES:
            raise ValueError(f"{name}.category must be one of {CATEGORIES}, got {self.category!r}")
        for key in ("n_shapes", "n_points"):
            check_int(getattr(self, key), f"{name}.{key}", minimum=1)
        check_size(self.n_points, f"{name}.n_points", MAX_SHAPE_POINTS)
        check_size(self.n_shapes, f"{name}.n_shapes", MAX_SHAPES, "shapes")
        if self.data_dir is None:  # a procedural collection is allocated at once
            check_size(self.n_shapes * self.n_points, f"{name}.n_shapes x n_points", MAX_COLLECTION_POINTS)
        for key in ("data_seed", "split_seed"):
            check_int(getattr(self, key), f"{name}.{key}", minimum=0)
            check_seed(getattr(self, key), f"{name}.{key}")
        fractions = self.split_fractions
        if not isinstance(fractions, (list, tuple)) or len(fractions) != 3:
            raise ValueError(f"{name}.split_fractions must be (train, validation, test), got {fractions!r}")
        for k, f in enumerate(fractions):
            if isinstance(f, bool) or not isinstance(f, (int, float)) or not math.isfinite(f):
                raise ValueError(f"{name}.split_fractions[{k}] must be a finite number, got {f!r}")
        self.split_fractions = tuple(float(f) for f in fractions)
        train, val, test = self.split_fractions
        if train <= 0 or val <= 0 or test < 0 or abs(train + val + test - 1) > 1e-6:
            raise ValueError(
                f"{name}.split_fractions must be (train > 0, validation > 0, test >= 0) summing to 1, "
                f"got {fractions!r}"
            )
        if self.data_dir is not None:
            self.data_dir = str(self.data_dir)


#: The generator version of a config written before ``generator_version`` existed: the shapes it was trained on.
UNVERSIONED_GENERATOR = 1

#: The fields of :class:`DataConfig`: two runs with equal values read the same shapes.
DATA_FIELDS: tuple[str, ...] = tuple(f.name for f in fields(DataConfig))

#: The paper's augmentation angles for the animal set (degrees about the up axis), Sec. 4.1.
PAPER_ROTATIONS_DEG: tuple[float, ...] = (-10.0, -5.0, 0.0, 5.0, 10.0)


def rotate_about_y(x: torch.Tensor, angle_deg: float) -> torch.Tensor:
    """Rotate vectors about +y by ``angle_deg`` degrees (right-handed: +z turns towards +x).

    Args:
        x: (..., 3) points or normals.
        angle_deg: the angle in degrees.

    Returns:
        (..., 3) the rotated vectors.
    """
    a = math.radians(angle_deg)
    c, s = math.cos(a), math.sin(a)
    R = torch.tensor([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]], dtype=x.dtype, device=x.device)
    return x @ R.T


class PointCloudDataset(torch.utils.data.Dataset):
    """Shapes from a :class:`~cuboidlib.shapes.ShapeCollection` or from files, one item per shape and angle.

    An item is a dict: "points" and "normals" (N, 3) float32, "labels" (N,) int64 when known, "index"
    (the shape's index in the source) and, for a collection, "structure_id", both int64 scalars, and
    "instances" (N,) int64 when the collection has them. Subsets
    come from a generator seeded by (seed, epoch, item), repeatable whatever the worker order. Files are
    read lazily with :func:`cuboidlib.io.load_point_cloud` and kept in memory.

    Args:
        source: a ShapeCollection, or a sequence of file paths (anything
            :func:`cuboidlib.io.load_point_cloud` reads) or of :class:`~cuboidlib.io.PointCloud`.
        n_points: points per item (a random subset); None keeps every point (files must then all
            have the same size to be batched). For meshes, the number of points sampled on them
            (required).
        augment: repeat every shape once per angle of ``rotations_deg``, points and normals rotated about
            +y (Sec. 4.1: the animal set); the dataset gets len(rotations_deg) times longer.
        rotations_deg: the augmentation angles in degrees (default: the paper's, -10 to 10).
        seed: seed of the subsets (and of mesh sampling).
        label_map: optional function applied to the labels read from files (e.g. ShapeNet-part ids to
            course part indices).
        load_kwargs: extra arguments of :func:`cuboidlib.io.load_point_cloud` for files.
    """

    def __init__(
        self,
        source,
        n_points: int | None = None,
        augment: bool = False,
        rotations_deg: Sequence[float] = PAPER_ROTATIONS_DEG,
        seed: int = 0,
        label_map: Callable[[np.ndarray], np.ndarray] | None = None,
        load_kwargs: dict | None = None,
    ):
        if n_points is not None and n_points < 1:
            raise ValueError(f"n_points must be a positive integer or None, got {n_points}")
        self.rotations = tuple(float(a) for a in rotations_deg) if augment else (0.0,)
        if not self.rotations:
            raise ValueError("rotations_deg must hold at least one angle when augment=True")
        self.n_points, self.seed, self.epoch = n_points, int(seed), 0
        self.label_map = label_map
        self.load_kwargs = dict(load_kwargs or {})
        self.collection: ShapeCollection | None = None
        self._files: list[Path] = []
        self._clouds: dict[int, PointCloud] = {}
        if isinstance(source, ShapeCollection):
            self.collection = source
            if n_points is not None and n_points > source.points.shape[1]:
                raise ValueError(f"n_points={n_points} is more than the {source.points.shape[1]} points per shape "
                                 "of the collection")
            self._n = len(source)
        else:
            items = list(source)
            if not items:
                raise ValueError("source is empty: give a ShapeCollection or at least one file")
            for i, item in enumerate(items):
                if isinstance(item, PointCloud):
                    self._clouds[i] = self._finish(item, i)
                    self._files.append(Path(item.source or f"<point cloud {i}>"))
                elif isinstance(item, (str, os.PathLike)):
                    self._files.append(Path(item))
                else:
                    raise TypeError(f"source item {i} must be a file path or a PointCloud, got {type(item).__name__}")
            self._n = len(items)

    # --------------------------------------------------------------------------- constructors

    @classmethod
    def from_shapenet_part(cls, root: str | os.PathLike, category: str, split: str = "train", **kwargs):
        """Dataset over a ShapeNet-part "normal" folder, labels mapped to the course's parts (table support -> leg).

        Args:
            root, category, split: as in :func:`cuboidlib.io.shapenet_part_files`.
            **kwargs: the other arguments of :class:`PointCloudDataset`.
        """
        files = shapenet_part_files(root, category, split)
        if not files:
            raise ValueError(f"{root}: the {split} split lists no {category!r} shapes")
        return cls(files, label_map=lambda raw: shapenet_part_labels(raw, category), **kwargs)

    @classmethod
    def from_authors_layout(cls, root: str | os.PathLike, category: str, split: str = "train", **kwargs):
        """Dataset over the authors' data layout.

        Args:
            root, category, split: as in :func:`cuboidlib.io.authors_layout_files`.
            **kwargs: the other arguments of :class:`PointCloudDataset`.
        """
        files = authors_layout_files(root, category, split)
        if not files:
            raise ValueError(f"{root}: the {category} {split} list is empty")
        return cls(files, **kwargs)

    # --------------------------------------------------------------------------------- access

    def __len__(self) -> int:
        return self._n * len(self.rotations)

    def set_epoch(self, epoch: int) -> None:
        """Use a new set of random subsets (they depend on ``(seed, epoch, item)``)."""
        self.epoch = int(epoch)

    def _finish(self, pc: PointCloud, i: int) -> PointCloud:
        if pc.normals is None:
            raise ValueError(f"{pc.source or f'point cloud {i}'}: has no normals")
        if pc.labels is not None and self.label_map is not None:
            pc.labels = np.asarray(self.label_map(pc.labels), dtype=np.int64)
        if self.n_points is not None and len(pc) < self.n_points:
            raise ValueError(f"{pc.source or f'point cloud {i}'}: has only {len(pc)} points, fewer than "
                             f"n_points={self.n_points}")
        return pc

    def cloud(self, shape_index: int) -> PointCloud:
        """The full (not subsampled, not rotated) point cloud of shape ``shape_index``."""
        if not 0 <= shape_index < self._n:
            raise IndexError(f"shape index {shape_index} out of range for {self._n} shapes")
        if self.collection is not None:
            c = self.collection
            return PointCloud(c.points[shape_index], c.normals[shape_index], c.labels[shape_index])
        if shape_index not in self._clouds:
            kwargs = {"seed": self.seed, **self.load_kwargs}
            path = self._files[shape_index]
            if is_mesh_file(path):
                kwargs.setdefault("n_points", self.n_points)
            self._clouds[shape_index] = self._finish(load_point_cloud(path, **kwargs), shape_index)
        return self._clouds[shape_index]

    def __getitem__(self, item: int) -> dict:
        if not -len(self) <= item < len(self):
            raise IndexError(f"item {item} out of range for a dataset of {len(self)}")
        item %= len(self)
        shape_index, rot = divmod(item, len(self.rotations))
        pc = self.cloud(shape_index)
        points = torch.as_tensor(np.asarray(pc.points, dtype=np.float32))
        normals = torch.as_tensor(np.asarray(pc.normals, dtype=np.float32))
        labels = None if pc.labels is None else torch.as_tensor(np.asarray(pc.labels, dtype=np.int64))
        instances = None
        if self.collection is not None and self.collection.instances is not None:
            instances = torch.as_tensor(self.collection.instances[shape_index])
        if self.n_points is not None and self.n_points < points.shape[0]:
            g = torch.Generator().manual_seed(int(np.random.SeedSequence([self.seed, self.epoch, item]).generate_state(1)[0]))
            keep = torch.randperm(points.shape[0], generator=g)[: self.n_points]
            points, normals = points[keep], normals[keep]
            labels = None if labels is None else labels[keep]
            instances = None if instances is None else instances[keep]
        angle = self.rotations[rot]
        if angle != 0.0:
            points, normals = rotate_about_y(points, angle), rotate_about_y(normals, angle)
        out = {"points": points, "normals": normals, "index": torch.tensor(shape_index)}
        if labels is not None:
            out["labels"] = labels
        if instances is not None:
            out["instances"] = instances
        if self.collection is not None:
            out["structure_id"] = torch.tensor(int(self.collection.structure_ids[shape_index]))
        return out


# ----------------------------------------------------------------------------------------------
# Data
# ----------------------------------------------------------------------------------------------


@dataclass
class ShapeSet:
    """Shapes held in memory as stacked tensors.

    Attributes:
        points, normals: (S, N, 3) float32.
        labels: (S, N) int64 part labels, or None.
        indices: (S,) each shape's index in its source (collection or sorted file list).
        part_names: the names of the part labels, or None when unknown.
        num_parts: the number of part labels, or None.
        instances: (S, N) int64 part instances (the solid each point of a procedural shape was sampled on,
            :attr:`cuboidlib.shapes.Shape.instances`), or None.
    """

    points: torch.Tensor
    normals: torch.Tensor
    labels: torch.Tensor | None
    indices: torch.Tensor
    part_names: tuple[str, ...] | None = None
    num_parts: int | None = None
    instances: torch.Tensor | None = None

    def __len__(self) -> int:
        return int(self.points.shape[0])

    def subset(self, index: torch.Tensor) -> "ShapeSet":
        """The shapes at positions ``index`` (a 1-D int64 tensor)."""
        return ShapeSet(
            self.points[index], self.normals[index], None if self.labels is None else self.labels[index],
            self.indices[index], self.part_names, self.num_parts,
            None if self.instances is None else self.instances[index],
        )

    def with_part_names(self, names: Sequence[str], where: str = "part_names") -> "ShapeSet":
        """The shapes with their part labels named: label i is ``names[i]``, and there are ``len(names)`` parts.

        Args:
            names: one name per part label (e.g. ``cuboidlib.shapes.PART_NAMES[category]``).
            where: names the names in the message (e.g. "--part-names").

        Returns:
            A ShapeSet sharing the tensors (itself when the shapes have no labels).

        Raises:
            ValueError: a label has no name (labels above ``len(names) - 1``).
        """
        names = tuple(str(n) for n in names)
        if self.labels is None:
            return self
        top = int(self.labels.max())
        if not names or top >= len(names):
            raise ValueError(f"{where}: the part labels go up to {top}, but {len(names)} name(s) are given "
                             f"({', '.join(names)}); give one name per label, 0 to {top}")
        return dataclasses.replace(self, part_names=names, num_parts=len(names))

    def to(self, device: torch.device | str) -> "ShapeSet":
        """The shapes on ``device`` (``indices`` stay where they are)."""
        return ShapeSet(
            self.points.to(device), self.normals.to(device), None if self.labels is None else self.labels.to(device),
            self.indices, self.part_names, self.num_parts,
            None if self.instances is None else self.instances.to(device),
        )


def split_indices(n: int, fractions: tuple[float, float, float], seed: int) -> dict[str, torch.Tensor]:
    """Assign ``n`` shapes to "train", "val" and "test" by a seeded permutation.

    Args:
        n: the number of shapes.
        fractions: (train, validation, test): validation gets round(n f_val) shapes (at least 1), test
            round(n f_test) (at least 1 when f_test > 0), train the rest (at least 1).
        seed: the permutation's seed; the same arguments always give the same split.

    Returns:
        {"train", "val", "test": sorted int64 index tensors}.
    """
    _, f_val, f_test = fractions
    n_val = max(1, round(n * f_val))
    n_test = max(1, round(n * f_test)) if f_test > 0 else 0
    n_train = n - n_val - n_test
    if n_train < 1:
        raise ValueError(
            f"{n} shapes are too few for the split fractions {tuple(fractions)}: no training shape is left"
        )
    perm = torch.randperm(n, generator=torch.Generator().manual_seed(derive_seed(seed)))
    parts = torch.split(perm, [n_train, n_val, n_test])
    return {name: part.sort().values for name, part in zip(("train", "val", "test"), parts)}


def _data_files(folder: Path) -> list[Path]:
    if not folder.is_dir():
        raise FileNotFoundError(f"{folder}: no such data folder")
    suffixes = set(MESH_SUFFIXES) | set(POINT_CLOUD_SUFFIXES)
    found = sorted(p for p in folder.rglob("*") if p.is_file() and p.suffix.lower() in suffixes)
    results = {parent: result_files_in(parent) for parent in {p.parent for p in found}}
    files = [p for p in found if p.name not in results[p.parent]]
    if len(files) < len(found):  # cuboidlib's own outputs (meshes of cuboids, segmented points) are not shapes
        warnings.warn(f"{folder}: {len(found) - len(files)} file(s) below it are cuboidlib results (listed in a "
                      f"{MANIFEST} or beside a result JSON, e.g. {[p for p in found if p not in files][0]}); they are "
                      "not read as shapes", stacklevel=4)
    if not files:
        raise ValueError(f"{folder}: holds no point-cloud or mesh file ({', '.join(sorted(suffixes))})"
                         + (" other than cuboidlib results" if found else ""))
    return files


def data_layout(folder: str | os.PathLike, category: str) -> str:
    """The layout of a data folder.

    Args:
        folder: the folder.
        category: the category whose file lists the authors' layout would hold.

    Returns:
        "shapenet-part" (``synsetoffset2category.txt`` at its root), "authors" (``<category>_train`` or
        ``_test`` ``.npy`` / ``.txt`` at its root) or "files" (every mesh and point cloud file below it).
    """
    folder = Path(folder)
    if (folder / "synsetoffset2category.txt").is_file():
        return "shapenet-part"
    if _authors_splits(folder, category):
        return "authors"
    return "files"


def _authors_splits(folder: Path, category: str) -> list[str]:
    """The splits ("train", "test") whose file list the authors' layout holds in ``folder``."""
    return [s for s in ("train", "test") if any((folder / f"{category}_{s}{x}").is_file() for x in (".npy", ".txt"))]


def _folder_dataset(folder: Path, category: str, n_points: int, seed: int) -> tuple[PointCloudDataset, tuple | None]:
    """The dataset of a data folder in any of the layouts of :func:`data_layout`, and its part names.

    The published splits of a data set are joined (ShapeNet-part: train, val and test; the authors'
    data: train and test), so that :func:`split_indices` splits them as it splits everything else.
    """
    if not folder.is_dir():
        raise FileNotFoundError(f"{folder}: no such data folder")
    layout = data_layout(folder, category)
    if layout == "shapenet-part":
        files = [f for split in ("train", "val", "test") for f in shapenet_part_files(folder, category, split)]
        if not files:
            raise ValueError(f"{folder}: the ShapeNet-part lists hold no {category!r} shape")
        dataset = PointCloudDataset(files, n_points=n_points, seed=seed,
                                    label_map=lambda raw: shapenet_part_labels(raw, category))
        return dataset, PART_NAMES[category]
    if layout == "authors":
        files = [f for split in _authors_splits(folder, category) for f in authors_layout_files(folder, category, split)]
        if not files:
            raise ValueError(f"{folder}: the {category} file lists are empty")
        return PointCloudDataset(files, n_points=n_points, seed=seed), None
    return PointCloudDataset(_data_files(folder), n_points=n_points, seed=seed), None


def load_shapes(config: DataConfig, progress: bool = False) -> ShapeSet:
    """All shapes of the configured source as one :class:`ShapeSet`, before splitting.

    Args:
        config: the procedural collection of ``config.category``, or the folder ``config.data_dir``: a
            ShapeNet-part root, the authors' layout or any folder of mesh / point cloud files
            (:func:`data_layout`; for the first two ``config.category`` picks the category).
        progress: show the progress of making a procedural collection.

    Returns:
        The :class:`ShapeSet`, points (S, N, 3).
    """

    if config.data_dir is None:
        collection = make_collection(config.category, config.n_shapes, config.n_points, config.data_seed,
                                     progress=progress, version=config.generator_version)
        dataset = PointCloudDataset(collection)
        part_names = PART_NAMES[config.category]
    else:
        dataset, part_names = _folder_dataset(Path(config.data_dir), config.category, config.n_points,
                                              config.data_seed)
    items = [dataset[i] for i in range(len(dataset))]
    sizes = {int(item["points"].shape[0]) for item in items}
    if len(sizes) > 1:
        raise ValueError(f"the shapes have different numbers of points {sorted(sizes)}; set n_points to batch them")
    has_labels = all("labels" in item for item in items)
    labels = torch.stack([item["labels"] for item in items]) if has_labels else None
    num_parts = None
    if labels is not None:
        num_parts = len(part_names) if part_names is not None else int(labels.max()) + 1
        if labels.min() < 0 or labels.max() >= num_parts:
            raise ValueError(
                f"part labels must lie in [0, {num_parts}), got [{int(labels.min())}, {int(labels.max())}]"
            )
    has_instances = all("instances" in item for item in items)
    return ShapeSet(
        torch.stack([item["points"] for item in items]),
        torch.stack([item["normals"] for item in items]),
        labels,
        torch.stack([item["index"] for item in items]),
        part_names,
        num_parts,
        torch.stack([item["instances"] for item in items]) if has_instances else None,
    )


def load_splits(config: DataConfig, progress: bool = False) -> dict[str, ShapeSet]:
    """The "train", "val" and "test" shapes of a configuration: :func:`load_shapes`, then :func:`split_indices`.

    Args:
        config, progress: as in :func:`load_shapes`.

    Returns:
        {"train", "val", "test": :class:`ShapeSet`}.
    """
    shapes = load_shapes(config, progress)
    return {name: shapes.subset(idx) for name, idx in split_indices(len(shapes), config.split_fractions,
                                                                    config.split_seed).items()}


# ----------------------------------------------------------------------------------------------
# Input noise (Table 4 of the paper)
# ----------------------------------------------------------------------------------------------


def add_noise(points: torch.Tensor, sigma_n: float, seed: int) -> torch.Tensor:
    """Input noise of Table 4: ``points + sigma_n * e``, e ~ N(0, I_3) drawn independently per point.

    Each coordinate gets standard deviation sigma_n (variance sigma_n^2, as in the paper); for a fixed seed
    the noise levels differ only by the factor sigma_n. The normals stay those of the clean surface.

    Args:
        points: (..., 3) float tensor.
        sigma_n: the standard deviation, finite and >= 0.
        seed: seed of e; the same seed gives the same jitter.

    Returns:
        (..., 3) a new tensor.
    """
    if not isinstance(points, torch.Tensor) or not points.is_floating_point() or points.shape[-1:] != (3,):
        raise ValueError(f"points must be a float tensor of shape (..., 3), got {getattr(points, 'shape', points)!r}")
    if not (isinstance(sigma_n, (int, float)) and math.isfinite(sigma_n) and sigma_n >= 0):
        raise ValueError(f"sigma_n must be a finite non-negative number, got {sigma_n!r}")
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
    generator = torch.Generator().manual_seed(seed)
    e = torch.randn(points.shape, generator=generator, dtype=points.dtype)
    return points + sigma_n * e.to(points.device)


def _noise_seed(data_seed: int, split: str) -> int:
    return int(np.random.SeedSequence([data_seed, ("train", "val", "test").index(split), 5]).generate_state(1)[0])


def noisy_splits(splits: dict[str, ShapeSet], sigma_n: float, data_seed: int) -> dict[str, ShapeSet]:
    """Every split with :func:`add_noise` on its points; normals, labels and indices unchanged.

    The noise is drawn once, so every epoch sees the same noisy clouds.

    Args:
        splits: {name: ShapeSet}, names among "train", "val" and "test".
        sigma_n: as in :func:`add_noise`.
        data_seed: the seed each split's noise seed is derived from.

    Returns:
        {name: ShapeSet} with noisy points.
    """
    return {name: dataclasses.replace(s, points=add_noise(s.points, sigma_n, _noise_seed(data_seed, name)))
            for name, s in splits.items()}
