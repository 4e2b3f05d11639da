"""The result types of every method that makes cuboids: :class:`AbstractionBatch` (B shapes, as a
network, the per-shape fit or the k-means boxes give them) and :class:`Abstraction` (one shape, in its
own coordinates, ready to save). They sit below every module that returns them."""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from .export import (
    MESH_FORMATS,
    cuboids_from_dict,
    cuboids_to_dict,
    denormalize_cuboids,
    normalize_cuboids,
    write_cuboid_mesh,
    write_cuboids_json,
    write_segmented_point_cloud,
)
from .frames import check_rotation
from .geometry import Cuboids
from .metrics import ChamferConvention
from .rotations import quaternion_multiply, quaternion_to_rotation_matrix, rotation_matrix_to_quaternion
from .viz import plot_cuboids_plotly

__all__ = ["AbstractionBatch", "Abstraction", "result_files"]


@dataclass
class AbstractionBatch:
    """Cuboids and segmentations of B shapes, as every method makes them (network, fit, k-means boxes).

    The batch form of :class:`Abstraction`, in the coordinates the shapes were given in (normalised ones
    for a network). Fields a method does not produce are None.

    Attributes:
        cuboids: :class:`~cuboidlib.geometry.Cuboids` (B, M, ...) with ``exists`` (B, M).
        labels: (B, N) int64, each point's cuboid, always an existing one (the segmentation); None without
            points (shapes decoded from latent codes).
        W: (B, N, M) the soft allocation of the points to the cuboids (Eq. 3), or None.
        exist_probs: (B, M) existence probabilities delta_m, or None.
        z: (B, latent_dim) the network's latent codes, or None.

    Example::

        >>> batch = abstract_shapes(model, points)            # points (B, N, 3), normalised
        >>> batch.num_existing(), batch.labels.shape          # (B,), (B, N)
        >>> one = batch.item(0, points=points[0])             # an Abstraction, ready to save
    """

    cuboids: Cuboids
    labels: torch.Tensor | None = None
    W: torch.Tensor | None = None
    exist_probs: torch.Tensor | None = None
    z: torch.Tensor | None = None

    def __len__(self) -> int:
        return self.cuboids.batch_size

    @property
    def num_segments(self) -> int:
        """M, the number of cuboid slots (segment indices lie in [0, M))."""
        return self.cuboids.num_cuboids

    def num_existing(self) -> torch.Tensor:
        """(B,) int64, the number of existing cuboids of every shape."""
        return self.cuboids.exists.sum(dim=1)

    def item_batch(self, i: int) -> "AbstractionBatch":
        """Shape ``i`` as a batch of one (every field kept)."""
        def one(t):
            return None if t is None else t[i:i + 1]

        c = self.cuboids
        cuboids = Cuboids(c.centers[i:i + 1], c.quaternions[i:i + 1], c.half_sizes[i:i + 1], c.exists[i:i + 1],
                          validate=False)
        return AbstractionBatch(cuboids, one(self.labels), one(self.W), one(self.exist_probs), one(self.z))

    def item(self, i: int, **fields) -> "Abstraction":
        """Shape ``i`` as an :class:`Abstraction` (``fields``: its other fields, e.g. points, center, scale)."""
        c = self.cuboids
        one = Cuboids(c.centers[i:i + 1], c.quaternions[i:i + 1], c.half_sizes[i:i + 1], c.exists[i:i + 1],
                      validate=False).to(device="cpu")
        labels = None if self.labels is None else self.labels[i].cpu().numpy()
        return Abstraction(one, labels=labels, **fields)

    @staticmethod
    def concatenate(parts: "list[AbstractionBatch]") -> "AbstractionBatch":
        """The shapes of several batches in one (a field is kept only if every part has it)."""
        def cat(get):
            values = [get(d) for d in parts]
            return None if any(v is None for v in values) else torch.cat(values)

        cuboids = Cuboids(cat(lambda d: d.cuboids.centers), cat(lambda d: d.cuboids.quaternions),
                          cat(lambda d: d.cuboids.half_sizes), cat(lambda d: d.cuboids.exists), validate=False)
        return AbstractionBatch(cuboids, cat(lambda d: d.labels), cat(lambda d: d.W), cat(lambda d: d.exist_probs),
                                cat(lambda d: d.z))


@dataclass
class Abstraction:
    """The cuboid abstraction of ONE shape, stored in NORMALISED coordinates with the normalisation.

    Attributes:
        cuboids: :class:`~cuboidlib.geometry.Cuboids` (1, M, ...) with ``exists``, normalised, course frame.
        center, scale: (3,) and a float, the input's normalisation: original = normalised * scale + center.
        points, normals: (N, 3) the normalised input in the course's frame, or None.
        labels: (N,) each point's cuboid (the segmentation), or None.
        part_labels: (M,) each cuboid's semantic part, -1 unknown, or None; part_names: their names.
        chamfer, chamfer_convention: the Chamfer distance on the normalised shape and how it was measured.
        source: the input file's name; method: a dict of JSON types saying how the cuboids were made.
        frame: (3, 3) the rotation R with p_course = R @ p, any rotation (an axis frame,
            :func:`cuboidlib.frames.frame_rotation`, or the one ``abstract(..., up="auto")`` found), or None for
            the identity.

    Example::

        >>> r = abstract("chair.ply", model="chair")
        >>> r.num_existing, r.numpy()["sizes"].shape      # sizes in the file's units
        (8, (8, 3))
    """

    cuboids: Cuboids
    center: np.ndarray = field(default_factory=lambda: np.zeros(3))
    scale: float = 1.0
    points: np.ndarray | None = None
    normals: np.ndarray | None = None
    labels: np.ndarray | None = None
    part_labels: np.ndarray | None = None
    part_names: tuple[str, ...] | None = None
    chamfer: float | None = None
    chamfer_convention: ChamferConvention | None = None
    source: str | None = None
    method: dict | None = None
    frame: np.ndarray | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.cuboids, Cuboids) or self.cuboids.batch_size != 1:
            raise ValueError("Abstraction.cuboids must be a Cuboids batch holding ONE shape (1, M, ...)")
        if self.frame is not None:
            self.frame = check_rotation(self.frame, "Abstraction.frame")

    def _to_input_axes(self, cuboids: Cuboids) -> Cuboids:
        """Normalised cuboids of the course frame (+y up) -> normalised cuboids in the input's axes."""
        if self.frame is None:
            return cuboids
        back = torch.as_tensor(self.frame.T, dtype=cuboids.centers.dtype)
        q_back = rotation_matrix_to_quaternion(back.double()).to(cuboids.quaternions.dtype)
        return Cuboids(cuboids.centers @ back.T, quaternion_multiply(q_back, cuboids.quaternions),
                       cuboids.half_sizes, cuboids.exists)

    def _points_in(self, values: np.ndarray | None, coordinates: str, is_normal: bool = False) -> np.ndarray | None:
        """The stored points (or normals) in the input's axes, normalised or in its original coordinates."""
        if values is None:
            return None
        out = np.asarray(values, dtype=np.float64)
        if self.frame is not None:
            out = out @ self.frame  # rows: R^T p
        if coordinates == "original" and not is_normal:
            out = out * self.scale + np.asarray(self.center, dtype=np.float64)
        return out

    @property
    def num_existing(self) -> int:
        """How many of the M cuboids exist."""
        return int(self.cuboids.exists.sum())

    def cuboids_in(self, coordinates: str = "original") -> Cuboids:
        """The cuboids in the input's own axes, in its original or its normalised coordinates.

        Args:
            coordinates: "original" or "normalized" (bounding box centred, diagonal 1). :attr:`cuboids`
                holds them in the course's frame, +y up, which differs when the input had another ``up``.

        Returns:
            :class:`~cuboidlib.geometry.Cuboids` (1, M, ...).
        """
        if coordinates not in ("original", "normalized"):
            raise ValueError(f"coordinates must be 'original' or 'normalized', got {coordinates!r}")
        cuboids = self._to_input_axes(self.cuboids)
        return cuboids if coordinates == "normalized" else denormalize_cuboids(cuboids, self.center, self.scale)

    def numpy(self, coordinates: str = "original") -> dict[str, np.ndarray]:
        """The EXISTING cuboids as numpy arrays, K = :attr:`num_existing`.

        Args:
            coordinates: "original" or "normalized", as in :meth:`cuboids_in`.

        Returns:
            A dict: ``centers`` (K, 3), ``rotations`` (K, 3, 3) (columns: the cuboid's axes), ``sizes``
            (K, 3) full edge lengths, ``index`` (K,) their slots m, ``part_labels`` (K,) (-1 unknown).
        """
        c = self.cuboids_in(coordinates)
        keep = c.exists[0].cpu()
        rotations = quaternion_to_rotation_matrix(c.quaternions[0].detach().cpu().double(), validate=False)
        labels = np.full(c.num_cuboids, -1) if self.part_labels is None else np.asarray(self.part_labels)
        return {
            "centers": c.centers[0].detach().cpu().double()[keep].numpy(),
            "rotations": rotations[keep].numpy(),
            "sizes": (2 * c.half_sizes[0].detach().cpu().double()[keep]).numpy(),
            "index": np.nonzero(keep.numpy())[0],
            "part_labels": labels[keep.numpy()],
        }

    def to_dict(self, coordinates: str = "original", points_file: str | None = None) -> dict:
        """The JSON document of the result (schema: :mod:`cuboidlib.export`).

        Args:
            coordinates: the cuboids' coordinates, as in :meth:`cuboids_in`.
            points_file: the name of the segmented point file to refer to, or None.

        Returns:
            A dict of JSON types.
        """
        return cuboids_to_dict(
            self.cuboids_in(coordinates), coordinates=coordinates, center=self.center, scale=self.scale,
            source=self.source, method=self.method, part_labels=self.part_labels, part_names=self.part_names,
            chamfer=self.chamfer, chamfer_convention=self.chamfer_convention, points_file=points_file,
        )

    @classmethod
    def from_dict(cls, doc: dict, where: str = "cuboid JSON") -> "Abstraction":
        """Inverse of :meth:`to_dict`; the points are not in the document (None). ``where`` names it in errors."""
        cuboids, meta = cuboids_from_dict(doc, where)
        center, scale = np.asarray(meta["normalization"]["center"]), float(meta["normalization"]["scale"])
        if meta["coordinates"] == "original":
            cuboids = normalize_cuboids(cuboids, center, scale)
        labels = np.asarray(meta["part_labels"], dtype=np.int64)
        names = meta.get("part_names")
        return cls(cuboids, center, scale, part_labels=None if (labels < 0).all() else labels,
                   part_names=None if names is None else tuple(names), source=meta.get("source"),
                   method=meta.get("method"), chamfer=(meta.get("chamfer") or {}).get("value"))

    def save(self, folder: str | os.PathLike, stem: str | None = None, formats=("glb",),
             normalized: bool = False) -> dict[str, Path]:
        """Write ``STEM.json``, the cuboid meshes and, with points, ``STEM_segmentation.ply`` (points by cuboid).

        Args:
            folder: the output folder.
            stem: the files' stem (default: the source file's name, else "cuboids").
            formats: mesh formats, any of "glb", "obj" (with its .mtl) and "ply".
            normalized: write the normalised coordinates instead of the input's original ones (the JSON
                records which, and the normalisation either way).

        Returns:
            {kind: path} of the files written (:func:`result_files`'s kinds).
        """
        if stem is None:
            stem = Path(self.source).stem if self.source else "cuboids"
        out = Path(folder)
        names = result_files(stem, formats, self.points is not None)
        coordinates = "normalized" if normalized else "original"
        cuboids = self.cuboids_in(coordinates)
        written = {}
        if self.points is not None:
            points = self._points_in(self.points, coordinates)
            labels = self.labels if self.labels is not None else np.full(len(points), -1)
            written["points"] = write_segmented_point_cloud(out / names["points"], points, labels,
                                                            self._points_in(self.normals, coordinates, True))
        written["json"] = write_cuboids_json(
            out / names["json"], cuboids, coordinates=coordinates, center=self.center, scale=self.scale,
            source=self.source, method=self.method, part_labels=self.part_labels, part_names=self.part_names,
            chamfer=self.chamfer, chamfer_convention=self.chamfer_convention, points_file=names.get("points"),
        )
        for fmt in formats:
            written[fmt] = write_cuboid_mesh(out / names[fmt], cuboids)
            if fmt == "obj":
                written["mtl"] = out / names["mtl"]
        return written

    def plot(self, max_points: int = 4000, coordinates: str = "original", **kwargs):
        """An interactive plotly figure: the points coloured by cuboid and the translucent cuboids.

        Args:
            max_points: at most this many points drawn.
            coordinates: "original" or "normalized", as in :meth:`cuboids_in`.
            **kwargs: passed to :func:`cuboidlib.viz.plot_cuboids_plotly` (``title`` has a default).

        Returns:
            A plotly Figure.
        """
        points = np.zeros((0, 3)) if self.points is None else self._points_in(self.points, coordinates)
        title = kwargs.pop("title", f"{self.source or 'shape'}: {self.num_existing} of {self.cuboids.num_cuboids} "
                           "cuboids")
        names = None
        if self.part_labels is not None and self.part_names:
            names = [self.part_names[k] if 0 <= k < len(self.part_names) else None for k in self.part_labels]
        return plot_cuboids_plotly(points, self.labels, self.cuboids_in(coordinates), max_points=max_points,
                                   title=title, names=names, **kwargs)


def result_files(stem: str, formats=("glb",), points: bool = True) -> dict[str, str]:
    """The file names :meth:`Abstraction.save` writes.

    Args:
        stem: the names' stem.
        formats: mesh formats, from :data:`cuboidlib.files.MESH_FORMATS`.
        points: include the segmented point file.

    Returns:
        {kind: name}: "json" ``{stem}.json``, each format ``{stem}.{fmt}``, "mtl" ``{stem}.mtl`` with an
        OBJ, and "points" ``{stem}_segmentation.ply``.
    """
    names = {"json": f"{stem}.json"}
    for fmt in formats:
        if fmt not in MESH_FORMATS:
            raise ValueError(f"unknown mesh format {fmt!r}; expected some of {MESH_FORMATS}")
        names[fmt] = f"{stem}.{fmt}"
        if fmt == "obj":
            names["mtl"] = f"{stem}.mtl"
    if points:
        names["points"] = f"{stem}_segmentation.ply"
    return names
