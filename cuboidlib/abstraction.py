"""One shape's cuboid abstraction (:class:`Abstraction`) and the one pipeline that makes it (:func:`abstract`).

Three lines take a mesh or point cloud file, in any units, to cuboids written next to it::

    import cuboidlib
    result = cuboidlib.abstract("my_chair.obj", model="chair")   # a committed network; model=None fits
    result.save("out")                                           # out/my_chair.json, .glb, _segmentation.ply

The pipeline is the same for every way of making cuboids: read and normalise the shape
(:func:`cuboidlib.io.load_point_cloud`: bounding box centred, diagonal 1, normals estimated when
missing), make cuboids and a segmentation (a trained network, Sec. 3, or the per-shape fit of
:mod:`cuboidlib.fitting`), measure the Chamfer distance on the normalised shape, and, when the input
has part labels, give every cuboid the part most of its points carry (Sec. 4.2). The result keeps
the normalised cuboids and the normalisation, so it can be written in the input's own coordinates
(the default) or in the normalised ones. The command-line tool's ``fit`` and ``abstract`` are this
function and :meth:`Abstraction.save`.

Why one file: the result types and the pipeline that fills them change together (every field of
:class:`Abstraction` is set by :func:`abstract`, and the frame handling is needed by both).
"""

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
from .geometry import Cuboids, quaternion_multiply, quaternion_to_rotation_matrix, rotation_matrix_to_quaternion
from .metrics import ChamferConvention, cuboid_chamfer_distance, transfer_part_labels

__all__ = ["Abstraction", "AbstractionBatch", "abstract", "result_files", "frame_rotation", "AXES", "REFINE_LR",
           "OrientationWarning", "ORIENTATION_RATIO"]

#: Learning rate of the cuboid parameters when a network's result is refined (``abstract(refine=...)``).
#: The fit's default 0.01 first moves the network's cuboids away from a good start; 0.003 does not
#: (on 16 test chairs, 100 steps: Chamfer 1.57e-3 against 1.86e-3 with 0.01; the network: 2.34e-3).
REFINE_LR = 0.003

#: ``abstract(shape, model)`` without ``up`` warns when another up axis gives the network's cuboids a
#: Chamfer distance below this fraction of the +y-up one (measured by ``experiments/orientation_check.py``).
ORIENTATION_RATIO = 0.5


class OrientationWarning(UserWarning):
    """The input seems to use another up axis than the networks' +y (``abstract`` without ``up``)."""


@dataclass
class AbstractionBatch:
    """Cuboids and segmentations of B shapes, as every method makes them (network, fit, k-means boxes).

    The batch form of :class:`Abstraction`, in the coordinates the shapes were given in (normalised
    ones for a network). Fields that a method does not produce are None.

    cuboids: :class:`~cuboidlib.geometry.Cuboids` (B, M, ...) with ``exists`` (B, M).
    labels: (B, N) long, each point's cuboid, in [0, M) and always an existing one (the
      segmentation), or None when no points were given (shapes decoded from latent codes).
    W: (B, N, M) the soft allocation of the points to the cuboids (Eq. 3), or None.
    exist_probs: (B, M) existence probabilities (the network's delta_m), or None.
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
        """(B,) long, the number of existing cuboids of every shape."""
        return self.cuboids.exists.sum(dim=1)

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
    """The cuboid abstraction of ONE shape. The cuboids are stored in NORMALISED coordinates.

    cuboids: :class:`~cuboidlib.geometry.Cuboids` (1, M, ...) with ``exists``, normalised frame.
    center (3,), scale: the input's normalisation (original = normalized * scale + center).
    points (N, 3), normals (N, 3): the normalised input (or None); labels (N,): cuboid index of every
    point, the segmentation (or None).
    part_labels (M,): semantic part label of each cuboid, -1 unknown (or None); part_names their names.
    chamfer, chamfer_convention: Chamfer distance on the normalised shape and how it was measured.
    source: the input file name; method: a dict of JSON types saying how the cuboids were made.

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
            self.frame = np.asarray(self.frame, dtype=np.float64)
            if self.frame.shape != (3, 3) or not np.allclose(self.frame @ self.frame.T, np.eye(3), atol=1e-6):
                raise ValueError("Abstraction.frame must be a 3 x 3 rotation matrix")

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
        """The cuboids (1, M, ...) in the input's ``"original"`` coordinates or the ``"normalized"`` ones
        (bounding box centred, diagonal 1, in the input's own axes; :attr:`cuboids` holds them in the
        course's frame, +y up, which differs when the input came with another ``up``)."""
        if coordinates not in ("original", "normalized"):
            raise ValueError(f"coordinates must be 'original' or 'normalized', got {coordinates!r}")
        cuboids = self._to_input_axes(self.cuboids)
        return cuboids if coordinates == "normalized" else denormalize_cuboids(cuboids, self.center, self.scale)

    def numpy(self, coordinates: str = "original") -> dict[str, np.ndarray]:
        """The EXISTING cuboids as arrays: ``centers`` (K, 3), ``rotations`` (K, 3, 3) (columns are the
        cuboid's axes), ``sizes`` (K, 3) (full edge lengths), ``index`` (K,) their slot m, and
        ``part_labels`` (K,) (-1 unknown); K = :attr:`num_existing`."""
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
        """The JSON document of the result (schema: :mod:`cuboidlib.export`), cuboids in ``coordinates``."""
        return cuboids_to_dict(
            self.cuboids_in(coordinates), coordinates=coordinates, center=self.center, scale=self.scale,
            source=self.source, method=self.method, part_labels=self.part_labels, part_names=self.part_names,
            chamfer=self.chamfer, chamfer_convention=self.chamfer_convention, points_file=points_file,
        )

    @classmethod
    def from_dict(cls, doc: dict, where: str = "cuboid JSON") -> "Abstraction":
        """Inverse of :meth:`to_dict` (the points are not part of the document: None)."""
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
        """Write ``folder/STEM.json``, the cuboid meshes in ``formats`` (any of glb, obj, ply) and, when
        the result has points, ``folder/STEM_segmentation.ply`` (points coloured and labelled by cuboid).

        Everything is in the input's original coordinates, or in the normalised ones with
        ``normalized=True`` (the JSON records which, and the normalisation either way). STEM defaults
        to the source file's name (else "cuboids"). Returns ``{kind: path}``.
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
        """An interactive plotly figure: the points coloured by cuboid and the translucent cuboids."""
        from .viz import plot_cuboids_plotly

        points = np.zeros((0, 3)) if self.points is None else self._points_in(self.points, coordinates)
        title = kwargs.pop("title", f"{self.source or 'shape'}: {self.num_existing} of {self.cuboids.num_cuboids} "
                           "cuboids")
        names = None
        if self.part_labels is not None and self.part_names:
            names = [self.part_names[k] if 0 <= k < len(self.part_names) else None for k in self.part_labels]
        return plot_cuboids_plotly(points, self.labels, self.cuboids_in(coordinates), max_points=max_points,
                                   title=title, names=names, **kwargs)


def result_files(stem: str, formats=("glb",), points: bool = True) -> dict[str, str]:
    """File names :meth:`Abstraction.save` uses: ``{stem}.json``, ``{stem}.{glb|obj|ply}``,
    ``{stem}.mtl`` with an OBJ, and ``{stem}_segmentation.ply`` for the points."""
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


# ----------------------------------------------------------------------------------------------
# The pipeline
# ----------------------------------------------------------------------------------------------

AXES = {"x": (1, 0, 0), "y": (0, 1, 0), "z": (0, 0, 1), "-x": (-1, 0, 0), "-y": (0, -1, 0), "-z": (0, 0, -1)}


def frame_rotation(up: str = "y", front: str | None = None) -> np.ndarray:
    """The rotation R (3, 3) that takes a shape whose up axis is ``up`` and whose front faces ``front`` into
    the course's frame (+y up, facing +z): ``p_course = R @ p``.

    Axes are "x", "y", "z", "-x", "-y" or "-z". The default front is +z, or -y for a z-up shape (the
    convention of Blender and many CAD exports: z up, the front looking down -y), +y for -z up.
    Example: ``frame_rotation("z")`` maps (0, 0, 1) to (0, 1, 0) and (0, -1, 0) to (0, 0, 1).
    """
    if up not in AXES:
        raise ValueError(f"up must be one of {', '.join(AXES)}, got {up!r}")
    if front is None:
        front = _default_front(up)
    if front not in AXES:
        raise ValueError(f"front must be one of {', '.join(AXES)}, got {front!r}")
    u, f = np.array(AXES[up], dtype=np.float64), np.array(AXES[front], dtype=np.float64)
    if abs(float(u @ f)) > 0.5:
        raise ValueError(f"front {front!r} must be perpendicular to up {up!r}")
    return np.stack([np.cross(u, f), u, f])  # rows: the input axes that become x, y (up) and z (front)



def _as_point_cloud(shape, n_points: int | None, seed: int):
    """A normalised PointCloud with normals from a file path, a PointCloud or an (N, 3) / (N, 6) array."""
    from .io import PointCloud, load_point_cloud, validate_point_cloud
    from .normalization import normalize
    from .normals import estimate_normals

    if isinstance(shape, (str, os.PathLike)):
        return load_point_cloud(shape, n_points, seed, fewer_ok=True)
    if isinstance(shape, PointCloud):
        pc = PointCloud(shape.points, shape.normals, shape.labels, source=shape.source)
    else:
        array = shape.detach().cpu().numpy() if isinstance(shape, torch.Tensor) else np.asarray(shape)
        if array.ndim != 2 or array.shape[1] not in (3, 6):
            raise ValueError(f"shape must be a file path, a PointCloud or an (N, 3) / (N, 6) array of points "
                             f"[and normals], got an array of shape {array.shape}")
        array = array.astype(np.float64)
        pc = PointCloud(array[:, :3], array[:, 3:] if array.shape[1] == 6 else None)
    validate_point_cloud(np.asarray(pc.points), pc.normals, pc.labels, pc.source or "shape")
    if n_points is not None and n_points < len(pc):
        keep = np.sort(np.random.default_rng(seed).choice(len(pc), n_points, replace=False))
        pc.points = pc.points[keep]
        pc.normals = None if pc.normals is None else pc.normals[keep]
        pc.labels = None if pc.labels is None else pc.labels[keep]
    points, center, scale = normalize(np.asarray(pc.points, dtype=np.float64))
    pc.points, pc.center, pc.scale = points.astype(np.float32), center, float(scale)
    if pc.normals is None:
        pc.normals = estimate_normals(pc.points, k=min(16, len(pc))).astype(np.float32)
    else:
        n = np.asarray(pc.normals, dtype=np.float64)
        pc.normals = (n / np.linalg.norm(n, axis=1, keepdims=True)).astype(np.float32)
    return pc


def _turned(pc, rotation: np.ndarray):
    """The normalised cloud in the course's frame. R is a signed permutation of the axes, so the rotated
    cloud is still normalised (bounding box centred, diagonal 1)."""
    if not np.allclose(rotation, np.eye(3)):
        pc.points = (np.asarray(pc.points, dtype=np.float64) @ rotation.T).astype(np.float32)
        pc.normals = (np.asarray(pc.normals, dtype=np.float64) @ rotation.T).astype(np.float32)
    return pc


def _check_part_names(pc, part_names, source) -> None:
    if part_names is not None and pc.labels is not None and len(pc.labels) and int(pc.labels.max()) >= len(part_names):
        raise ValueError(f"{source or 'shape'}: has part labels up to {int(pc.labels.max())} but part_names gives "
                         f"only {len(part_names)} names")


def _default_front(up: str) -> str:
    """+z, or -y for a z-up shape (Blender and many CAD exports), +y for -z up."""
    return {"z": "-y", "-z": "y"}.get(up, "z")


def _by_fitting(shape, n_points, seed, fit_config, rotation, part_names, source, progress):
    """The branch of :func:`abstract` without a network: (point cloud, cuboids, segmentation, method)."""
    from .fitting import FitConfig, fit_cuboids

    config = fit_config if fit_config is not None else FitConfig(seed=seed)
    pc = _turned(_as_point_cloud(shape, 2048 if n_points is None else n_points, seed), rotation)
    _check_part_names(pc, part_names, source)
    if len(pc) < config.num_cuboids:
        raise ValueError(f"{source or 'shape'}: has {len(pc)} points, fewer than the {config.num_cuboids} cuboids")
    fit = fit_cuboids(pc.points, pc.normals, config, progress=progress)
    method = {"name": "fit", "function": "cuboidlib.fitting.fit_cuboids", "num_cuboids": config.num_cuboids,
              "steps": config.steps, "restarts": config.restarts, "seed": config.seed, "points": len(pc),
              "converged": bool(fit.converged[0])}
    return pc, fit.cuboids, fit.labels[0].cpu(), method


def _by_network(shape, model, n_points, seed, threshold, centers, device, rotation, part_names, source):
    """The network branch of :func:`abstract`: (point cloud, cuboids, segmentation, method)."""
    from .applications import abstract_shapes, load_trained_model
    from .model import CuboidAbstractionNet
    from .config import resolve_device

    if isinstance(model, CuboidAbstractionNet):
        net, state, path = model, {}, None
    else:
        net, state, path = load_trained_model(model, resolve_device(device))
    trained_points = state.get("config", {}).get("n_points")
    pc = _as_point_cloud(shape, n_points or (trained_points if isinstance(trained_points, int) else 2048), seed)
    pc = _turned(pc, rotation)
    _check_part_names(pc, part_names, source)
    if len(pc) <= net.config.k:
        raise ValueError(f"{source or 'shape'}: has {len(pc)} points; the network needs more than k = {net.config.k}")
    trained_centroids = bool(state.get("config", {}).get("loss", {}).get("centers_from_allocation", False))
    centroids = trained_centroids if centers == "auto" else centers == "allocation"
    out = abstract_shapes(net, pc.points, threshold, centers_from_allocation=centroids, normals=pc.normals)
    method = {"name": "network", "checkpoint": None if path is None else str(path), "step": state.get("step"),
              "threshold": threshold, "centers": "allocation" if centroids else "predicted", "points": len(pc)}
    return pc, out, method


def _refined(pc, out, steps: int, fit_config, seed: int, progress: bool):
    """Refinement: the per-shape fit started from the network's cuboids and allocation (same slots)."""
    from .fitting import FitConfig, fit_cuboids

    config = (fit_config if fit_config is not None else FitConfig(seed=seed, lr=REFINE_LR)).replace(
        steps=steps, normalize=False)
    points = torch.as_tensor(pc.points, dtype=out.cuboids.centers.dtype, device=out.cuboids.centers.device)[None]
    normals = torch.as_tensor(pc.normals, dtype=points.dtype, device=points.device)[None]
    fit = fit_cuboids(points, normals, config, progress=progress, start=out)
    method = {"refine": {"steps": steps, "function": "cuboidlib.fitting.fit_cuboids(start=network)",
                         "lambda_compact": config.lambda_compact, "seed": config.seed,
                         "converged": bool(fit.converged[0])}}
    return fit, method


def candidate_frames(front: str | None = None) -> list[tuple[str, str]]:
    """Every (up, front) pair of axes at right angles (24), or the 6 ups with ``front`` fixed where possible."""
    pairs = [(u, f) for u in AXES for f in AXES if abs(int(np.dot(AXES[u], AXES[f]))) == 0]
    return [(u, f) for u, f in pairs if front is None or f == front]


def _best_frame(shape, model, front, refine: int, **options) -> Abstraction:
    """``abstract(up="auto")``: the network's result in every candidate frame, the one with the lowest
    Chamfer distance kept (then refined, if asked); ``method["up_auto"]`` records every candidate's score."""
    if model is None:
        raise ValueError("up='auto' chooses the frame by the network's reconstruction: give a model")
    frames = candidate_frames(front)
    if not frames:
        raise ValueError(f"front {front!r} is not an axis")
    scores = {(u, f): abstract(shape, model, up=u, front=f, **options).chamfer for u, f in frames}
    up, front = min(scores, key=scores.get)
    result = abstract(shape, model, up=up, front=front, refine=refine, **options)
    result.method["up_auto"] = {"chosen": {"up": up, "front": front},
                                "chamfer": {f"{u} {f}": round(c, 7) for (u, f), c in scores.items()}}
    return result


def _up_axis_results(shape, model, **options) -> dict[str, Abstraction]:
    """The network's result with each of the six axes taken as up (default fronts), keyed by the axis."""
    return {u: abstract(shape, model, up=u, **options) for u in AXES}


def up_axis_scores(shape, model, **options) -> dict[str, float]:
    """The Chamfer distance of the network's cuboids with each of the six axes taken as up (default
    fronts), {"y": ..., "-y": ..., "x": ..., ...}: the measurement behind the orientation warning."""
    return {u: result.chamfer for u, result in _up_axis_results(shape, model, **options).items()}


def _checked_orientation(shape, model, front, refine: int, **options) -> Abstraction:
    """``abstract`` without ``up``: +y up, with a warning when another up axis fits the network much better
    (its Chamfer distance below ``ORIENTATION_RATIO`` times the +y one); ``method["up_check"]`` keeps the scores."""
    import warnings

    results = _up_axis_results(shape, model, **options)
    scores = {u: r.chamfer for u, r in results.items()}
    best = min(scores, key=scores.get)
    if refine == 0 and front in (None, _default_front("y")):
        result = results["y"]  # the check's own +y pass is the answer
    else:
        result = abstract(shape, model, up="y", front=front, refine=refine, **options)
    suggested = best if best != "y" and scores[best] < ORIENTATION_RATIO * scores["y"] else None
    result.method["up_check"] = {"chamfer": {u: round(c, 7) for u, c in scores.items()}, "suggested": suggested,
                                 "ratio": ORIENTATION_RATIO}
    if suggested is not None:
        name = result.source or "the shape"
        warnings.warn(OrientationWarning(
            f"{name} looks like it is not +y up: with up {suggested} the network's cuboids reconstruct it "
            f"{scores['y'] / scores[best]:.1f}x better (Chamfer {scores[best]:.3g} against {scores['y']:.3g}); "
            f"pass up={suggested!r} (--up {suggested}) or up='auto', or up='y' if it is upright"), stacklevel=3)
    return result


def abstract(
    shape,
    model=None,
    *,
    n_points: int | None = None,
    seed: int = 0,
    threshold: float = 0.5,
    centers: str = "auto",
    fit_config=None,
    part_names=None,
    device: str = "cpu",
    progress: bool = False,
    up: str | None = None,
    front: str | None = None,
    refine: int = 0,
) -> Abstraction:
    """Cuboid abstraction and segmentation of one shape, in its own coordinates.

    Args:
        shape: a mesh or point cloud file (any format :func:`cuboidlib.io.load_point_cloud` reads), a
            :class:`~cuboidlib.io.PointCloud`, or an (N, 3) / (N, 6) array of points [and normals],
            in any units and position; it is normalised first, and normals are estimated when missing.
        model: a trained network: a committed name ("chair", "table", "airplane", "animal"), a
            checkpoint file or run folder, or a loaded ``CuboidAbstractionNet``; None fits cuboids to
            this shape alone (:func:`cuboidlib.fitting.fit_cuboids`, no network, no part consistency).
        n_points: points sampled on a mesh or kept of a larger cloud (default: the network's training
            size, 2048 for the fit).
        seed: seed of the sampling, the fit and the Chamfer samples.
        threshold: existence probability above which a network's cuboid exists.
        centers: network cuboid centres: "predicted", "allocation" (centroids of the points) or "auto"
            (what the network was trained with).
        fit_config: a :class:`~cuboidlib.fitting.FitConfig` for ``model=None`` (default: the course's).
        part_names: names of the input's part labels, for the JSON.
        device: "cpu", "cuda[:i]" or "auto".
        progress: show the fit's progress bar.
        up, front: the input's up axis and the direction its front faces (:func:`frame_rotation`); the
            networks were trained on +y up, facing +z. The result is written back in the input's axes.
            ``up=None`` (default) is +y; with a network it also runs the network with each of the six
            axes as up (:func:`up_axis_scores`, a few tenths of a second) and warns
            (:class:`OrientationWarning`) when another one reconstructs the shape much better;
            ``method["up_check"]`` keeps the scores. Give ``up="y"`` to skip the check.
            ``up="auto"`` (with a network) tries the 24 frames (with ``front`` given, the 4 ups at right
            angles to it) and keeps the one whose cuboids reconstruct the shape best (lowest Chamfer
            distance); ``method["up_auto"]`` says which it chose and every frame's score. The choice is
            only as good as the network on that input: keep ``n_points`` at the network's training size
            (with 256 points an upright chair was reconstructed better upside down).
        refine: with a network, this many steps of the per-shape fit started from the network's
            cuboids and allocation (``fit_cuboids(start=...)``; settings from ``fit_config``, default
            ``FitConfig(lr=REFINE_LR)``): tighter cuboids on this shape that keep the network's cuboid
            slots, and so its part correspondence. 100 steps take about a second on a CPU.

    Returns an :class:`Abstraction` (cuboids normalised, with the normalisation to write them back).
    """
    if up == "auto":
        return _best_frame(shape, model, front, refine=refine, n_points=n_points, seed=seed, threshold=threshold,
                           centers=centers, fit_config=fit_config, part_names=part_names, device=device,
                           progress=progress)
    if up is None and model is not None:
        return _checked_orientation(shape, model, front, refine=refine, n_points=n_points, seed=seed,
                                    threshold=threshold, centers=centers, fit_config=fit_config,
                                    part_names=part_names, device=device, progress=progress)
    up = "y" if up is None else up
    if centers not in ("auto", "predicted", "allocation"):
        raise ValueError(f"centers must be 'auto', 'predicted' or 'allocation', got {centers!r}")
    if isinstance(refine, bool) or not isinstance(refine, int) or refine < 0:
        raise ValueError(f"refine must be a non-negative number of steps, got {refine!r}")
    if refine and model is None:
        raise ValueError("refine starts the fit from a network's cuboids: give a model (model=None fits from scratch)")
    rotation = frame_rotation(up, front)
    source = Path(shape).name if isinstance(shape, (str, os.PathLike)) else getattr(shape, "source", None)
    if model is None:
        pc, cuboids, segmentation, method = _by_fitting(shape, n_points, seed, fit_config, rotation, part_names,
                                                        source, progress)
    else:
        pc, out, method = _by_network(shape, model, n_points, seed, threshold, centers, device, rotation,
                                      part_names, source)
        if refine:
            out, refined = _refined(pc, out, refine, fit_config, seed, progress)
            method.update(refined)
        cuboids, segmentation = out.cuboids.to(device="cpu"), out.labels[0].cpu()
    convention = ChamferConvention()
    points = torch.as_tensor(pc.points, dtype=cuboids.centers.dtype)[None]
    chamfer = float(cuboid_chamfer_distance(
        points, cuboids.centers, cuboids.quaternions, cuboids.half_sizes, cuboids.exists, convention,
        torch.Generator().manual_seed(seed),
    )[0])
    part_labels = None
    if pc.labels is not None and len(pc.labels) and pc.labels.min() >= 0:
        num_parts = max(int(pc.labels.max()) + 1, len(part_names) if part_names else 0)
        part_labels = transfer_part_labels(segmentation[None], torch.as_tensor(pc.labels)[None],
                                           cuboids.num_cuboids, num_parts).numpy()
    identity = np.allclose(rotation, np.eye(3))
    if not identity:
        method.update(up=up, front=front or _default_front(up))
    return Abstraction(
        cuboids, pc.center, pc.scale, pc.points, pc.normals, segmentation.numpy(), part_labels,
        None if part_names is None else tuple(part_names), chamfer, convention, source=source, method=method,
        frame=None if identity else rotation,
    )
