"""A torch ``Dataset`` over procedural collections or point-cloud / mesh files.

Each item is a dict of tensors: ``"points"`` (N, 3) float32, ``"normals"`` (N, 3) float32,
``"labels"`` (N,) int64 when the part labels are known, ``"index"`` (the shape's index in the
source, int64) and, for procedural collections, ``"structure_id"`` (int64). A ``DataLoader``
stacks them into the batch-first (B, N, 3) tensors the model expects.

* **Subsampling**: with ``n_points`` each item is a random subset of that size, drawn from a
  generator seeded by ``(seed, epoch, item)``, so it is repeatable whatever the worker order;
  :meth:`PointCloudDataset.set_epoch` draws new subsets for a new epoch.
* **Rotation augmentation** (Sec. 4.1: the animal set is augmented by rotations of +-5 and +-10
  degrees about the up axis): with ``augment=True`` every shape appears once per angle of
  ``rotations_deg`` (default ``(-10, -5, 0, 5, 10)``), rotated about the vertical +y axis (points
  and normals alike), so the dataset is ``len(rotations_deg)`` times longer, as in the paper.
* **Files** are read lazily with :func:`cuboidlib.io.load_point_cloud` (normalised with the course
  convention, normals estimated when missing) and kept in memory after the first read.
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Callable, Sequence

import numpy as np
import torch

from .io import (
    PointCloud,
    authors_layout_files,
    is_mesh_file,
    load_point_cloud,
    shapenet_part_files,
    shapenet_part_labels,
)
from .shapes import ShapeCollection

__all__ = ["PAPER_ROTATIONS_DEG", "PointCloudDataset", "rotate_about_y"]

#: The paper's augmentation angles for the animal set (degrees about the up axis), Sec. 4.1.
PAPER_ROTATIONS_DEG: tuple[float, ...] = (-10.0, -5.0, 0.0, 5.0, 10.0)


def rotate_about_y(x: torch.Tensor, angle_deg: float) -> torch.Tensor:
    """Rotate vectors ``x`` (..., 3) by ``angle_deg`` degrees about +y (right-handed: +z towards +x)."""
    a = math.radians(angle_deg)
    c, s = math.cos(a), math.sin(a)
    R = torch.tensor([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]], dtype=x.dtype, device=x.device)
    return x @ R.T


class PointCloudDataset(torch.utils.data.Dataset):
    """Shapes from a :class:`~cuboidlib.shapes.ShapeCollection`, or from files, as tensors.

    Args:
        source: a ShapeCollection, or a sequence of file paths (anything
            :func:`cuboidlib.io.load_point_cloud` reads) or of :class:`~cuboidlib.io.PointCloud`.
        n_points: points per item (a random subset); None keeps every point (files must then all
            have the same size to be batched). For meshes, the number of points sampled on them
            (required).
        augment: repeat every shape once per angle in ``rotations_deg`` (rotation about +y).
        rotations_deg: the augmentation angles in degrees.
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
        """Dataset over a ShapeNet-part "normal" folder (see :func:`cuboidlib.io.shapenet_part_files`),
        labels mapped to the course part names (table support -> leg)."""
        files = shapenet_part_files(root, category, split)
        if not files:
            raise ValueError(f"{root}: the {split} split lists no {category!r} shapes")
        return cls(files, label_map=lambda raw: shapenet_part_labels(raw, category), **kwargs)

    @classmethod
    def from_authors_layout(cls, root: str | os.PathLike, category: str, split: str = "train", **kwargs):
        """Dataset over the authors' layout (see :func:`cuboidlib.io.authors_layout_files`)."""
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
        if self.n_points is not None and self.n_points < points.shape[0]:
            g = torch.Generator().manual_seed(int(np.random.SeedSequence([self.seed, self.epoch, item]).generate_state(1)[0]))
            keep = torch.randperm(points.shape[0], generator=g)[: self.n_points]
            points, normals = points[keep], normals[keep]
            labels = None if labels is None else labels[keep]
        angle = self.rotations[rot]
        if angle != 0.0:
            points, normals = rotate_about_y(points, angle), rotate_about_y(normals, angle)
        out = {"points": points, "normals": normals, "index": torch.tensor(shape_index)}
        if labels is not None:
            out["labels"] = labels
        if self.collection is not None:
            out["structure_id"] = torch.tensor(int(self.collection.structure_ids[shape_index]))
        return out
