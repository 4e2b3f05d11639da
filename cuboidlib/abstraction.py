"""The one pipeline that makes a shape's cuboid abstraction, :func:`abstract`: from a mesh or point cloud
file, in any units, or an array, to an :class:`~cuboidlib.results.Abstraction`::

    import cuboidlib
    result = cuboidlib.abstract("my_chair.obj", model="chair")   # a committed network; model=None fits
    result.save("out")                                           # out/my_chair.json, .glb, _segmentation.ply

Every method goes the same way: read and normalise the shape (:func:`cuboidlib.io.load_point_cloud`),
make cuboids and a segmentation (a trained network, Sec. 3, or the per-shape fit of
:mod:`cuboidlib.fitting`), measure the Chamfer distance, and give every cuboid the part most of its points
carry when the input has part labels (Sec. 4.2). The command line's ``fit`` and ``abstract`` are this
function and :meth:`Abstraction.save`. The input is read and the network loaded once; the orientation
check scores its six frames in one network pass (:func:`_network_pass`), and so does ``up="auto"`` its frames
(:func:`_frame_search`, the geometry in :mod:`cuboidlib.frames`).
"""

from __future__ import annotations

import os
import warnings
from pathlib import Path

import numpy as np
import torch

from ._checks import MAX_FIT_STEPS, MAX_SHAPE_POINTS, as_float_tensor, check_coordinates, check_seed, check_size
from .applications import (abstract_shapes, check_latent_statistics, committed_checkpoints, latent_distance,
                           load_trained_model)
from .config import resolve_device, torch_threads
from .fitting import FitConfig, fit_cuboids, tighten_cuboids
from .frames import (AXES, YAWS, candidate_frames, choose_frame, frame_rotation, frame_score, is_axis_frame,
                     mirror_normal, search_frames, turn, yawed_frames)
from .geometry import Cuboids
from .io import PointCloud, load_point_cloud, validate_point_cloud
from .merging import merge_split_cuboids
from .metrics import ChamferConvention, cuboid_chamfer_distance, transfer_part_labels
from .model import CuboidAbstractionNet
from .network_check import (DEFAULT_THRESHOLD, LATENT_THRESHOLDS, NetworkVerdict, committed_networks,
                            latent_distances, network_verdict, verdict_advice, verdict_reasons)
from .normalization import normalize
from .normals import estimate_normals
from .results import Abstraction, AbstractionBatch, result_files

__all__ = ["abstract", "frame_rotation", "candidate_frames", "up_axis_scores", "AXES", "REFINE_LR", "OrientationWarning",
           "ORIENTATION_RATIO", "UPSIDE_DOWN_MARGIN", "FRAME_SCORE", "NetworkFitWarning", "Abstraction", "AbstractionBatch", "result_files"]

#: Learning rate of the cuboid parameters when a network's result is refined (``abstract(refine=...)``):
#: the fit's default 0.01 first moves the network's cuboids away from a good start; 0.003 does not.
REFINE_LR = 0.003

#: How the per-shape fit of ``abstract(shape, None)`` and ``cuboidlib fit`` chooses its number of cuboids
#: (:class:`cuboidlib.fitting.FitConfig`'s ``count``): by the Chamfer distance, so that legs keep their own cuboids
#: (``python benchmarks/bench_fit_count.py``); ``fit_cuboids`` itself keeps the paper's rule.
FIT_COUNT = "chamfer"
#: Steps of the final phase of a refinement on the two-sided distance (:func:`cuboidlib.fitting.tighten_cuboids`).
TIGHTEN_STEPS = 150

#: Steps of the same final phase after the per-shape fit of ``abstract(shape, None)`` (0: none), each on
#: FIT_TIGHTEN_POINTS points and as many surface samples, so that the default fit stays within a few seconds.
FIT_TIGHTEN_STEPS = 100
FIT_TIGHTEN_POINTS = 1024

#: ``abstract(shape, model)`` without ``up`` warns when another up axis gives the network's cuboids a
#: Chamfer distance below this fraction of the +y-up one (measured by ``experiments/orientation_check.py``).
ORIENTATION_RATIO = 0.5

#: How the candidate frames of the orientation check and of ``up="auto"`` are scored: the Chamfer
#: distance with 512 surface samples against at most FRAME_SCORE_POINTS of the input's points, evenly
#: spaced (cheaper than the result's own Chamfer distance, which keeps 4096 samples and every point).
FRAME_SCORE = ChamferConvention(n_samples=512)
FRAME_SCORE_POINTS = 512


#: ``abstract(shape, model, up="auto")`` warns (:class:`OrientationWarning`) when the best frame with the up
#: reversed scores within this margin of the frame kept (:func:`cuboidlib.frames.frame_score`, log units: about
#: this fraction of the Chamfer distance), measured by ``python benchmarks/bench_rotation.py``.
UPSIDE_DOWN_MARGIN = 0.05


class NetworkFitWarning(UserWarning):
    """``abstract(shape, model, check=True)``: the network does not know this shape (its latent code lies nearer
    another network's training shapes, or far from every network's); the message names the route to take
    instead (:mod:`cuboidlib.network_check`)."""


class OrientationWarning(UserWarning):
    """The input seems to use another up axis than the networks' +y (``abstract`` without ``up``), or
    ``up="auto"`` could hardly tell its up from its down."""


# ----------------------------------------------------------------------------------------------
# Reading the input, once
# ----------------------------------------------------------------------------------------------


def _as_point_cloud(shape, n_points: int, seed: int) -> PointCloud:
    """A normalised PointCloud with unit normals from a file path, a PointCloud or an (N, 3) / (N, 6) array.

    Its ``center`` and ``scale`` map it back to the input's own coordinates: a file's, an array's, or those a
    PointCloud records (:func:`cuboidlib.io.load_point_cloud` normalises and records its file's frame; the two
    normalisations compose).
    """
    if isinstance(shape, (str, os.PathLike)):
        pc = load_point_cloud(shape, n_points, seed, fewer_ok=True)
        _check_frame(pc, str(shape))
        return pc
    if isinstance(shape, PointCloud):
        name = shape.source or "shape"
        given_center = np.asarray(shape.center if shape.center is not None else np.zeros(3), dtype=np.float64)
        given_scale = float(shape.scale)
        if given_center.shape != (3,) or not np.isfinite(given_center).all() or not (
                np.isfinite(given_scale) and given_scale > 0):
            raise ValueError(f"{name}: a PointCloud's center must be 3 finite numbers and its scale a finite positive "
                             f"number (original = points * scale + center), got {shape.center!r} and {shape.scale!r}")
        pc = PointCloud(np.asarray(shape.points, dtype=np.float64), shape.normals, shape.labels, source=shape.source)
    else:
        if isinstance(shape, torch.Tensor):
            array = as_float_tensor(shape, "shape").detach().cpu().double().numpy()  # no data (meta): refused
        else:
            try:
                array = np.asarray(shape, dtype=np.float64)
            except (TypeError, ValueError) as exc:
                raise TypeError(f"shape must be a file path, a PointCloud or an (N, 3) / (N, 6) array of numbers, "
                                f"got {type(shape).__name__}") from exc
        if array.ndim != 2 or array.shape[1] not in (3, 6):
            raise ValueError(f"shape must be a file path, a PointCloud or an (N, 3) / (N, 6) array of points "
                             f"[and normals], got an array of shape {array.shape}")
        name, given_center, given_scale = "shape", np.zeros(3), 1.0
        pc = PointCloud(array[:, :3], array[:, 3:] if array.shape[1] == 6 else None)
    validate_point_cloud(np.asarray(pc.points), pc.normals, pc.labels, pc.source or "shape")
    if n_points < len(pc):
        keep = np.sort(np.random.default_rng(seed).choice(len(pc), n_points, replace=False))
        pc.points = pc.points[keep]
        pc.normals = None if pc.normals is None else pc.normals[keep]
        pc.labels = None if pc.labels is None else pc.labels[keep]
    points, center, scale = normalize(np.asarray(pc.points, dtype=np.float64))
    pc.points = points.astype(np.float32)
    pc.center, pc.scale = given_center + given_scale * center, given_scale * float(scale)  # the input's own frame
    _check_frame(pc, name)
    if pc.normals is None:
        pc.normals = estimate_normals(pc.points, k=min(16, len(pc))).astype(np.float32)
    else:
        n = np.asarray(pc.normals, dtype=np.float64)
        pc.normals = (n / np.linalg.norm(n, axis=1, keepdims=True)).astype(np.float32)
    return pc


def _check_frame(pc: PointCloud, name: str) -> None:
    """Refuse a shape whose coordinates the result files cannot hold (:data:`cuboidlib._checks.MAX_COORDINATE`)."""
    with np.errstate(over="ignore", invalid="ignore"):
        largest = float(np.abs(np.asarray(pc.points, dtype=np.float64) * pc.scale + pc.center).max())
    check_coordinates(largest if np.isfinite(largest) else float("inf"), name)


def _turned_normals(normals: np.ndarray, rotation: np.ndarray) -> np.ndarray:
    """(N, 3) normals in the frame R (no normalisation: directions)."""
    if np.allclose(rotation, np.eye(3)):
        return normals
    return (np.asarray(normals, dtype=np.float64) @ rotation.T).astype(np.float32)


def _load_network(model, device: str):
    """(network, checkpoint dict, path or None) from a name, a path or a loaded network."""
    if isinstance(model, CuboidAbstractionNet):
        return model, {}, None
    return load_trained_model(model, resolve_device(device))


# ----------------------------------------------------------------------------------------------
# One pass: cuboids, segmentation and Chamfer distance of the loaded cloud in given frames
# ----------------------------------------------------------------------------------------------


def _chamfer(points: np.ndarray, cuboids: Cuboids, seed: int, convention: ChamferConvention) -> torch.Tensor:
    """(B,) Chamfer distances of B shapes' cuboids to the same (N, 3) points turned per frame (B, N, 3)."""
    points = torch.as_tensor(points, dtype=cuboids.centers.dtype, device=cuboids.centers.device)
    return cuboid_chamfer_distance(points, cuboids.centers, cuboids.quaternions, cuboids.half_sizes, cuboids.exists,
                                   convention, torch.Generator(device=points.device).manual_seed(seed))


def _network_pass(pc: PointCloud, net, state: dict, rotations: list[np.ndarray], threshold: float,
                  centroids: bool) -> tuple[AbstractionBatch, np.ndarray]:
    """The network's cuboids for the cloud in each frame, in one batch, each turned cloud normalised
    (:func:`cuboidlib.frames.turn`).

    Returns:
        (the batch of F results, the (F, N, 3) points that were fed, one frame per row).
    """
    points = np.stack([turn(pc.points, r)[0] for r in rotations])
    normals = np.stack([_turned_normals(pc.normals, r) for r in rotations])
    return abstract_shapes(net, points, threshold, centers_from_allocation=centroids, normals=normals), points


def _frame_scores(pc, net, state, rotations, threshold, centroids, seed):
    """The network's results for the cloud turned into each frame, scored.

    Returns:
        (the (F,) FRAME_SCORE Chamfer distances, the (F,) latent distances or None without the checkpoint's
        latent statistics, the batch of results, the (F, N, 3) points fed).
    """
    batch, points = _network_pass(pc, net, state, rotations, threshold, centroids)
    step = max(1, -(-points.shape[1] // FRAME_SCORE_POINTS))
    scores = _chamfer(points[:, ::step], batch.cuboids, seed, FRAME_SCORE).cpu().double().numpy()
    latent = None
    if "latent_statistics" in state and batch.z is not None:
        latent = latent_distance(batch.z, state["latent_statistics"]).cpu().double().numpy()
    return scores, latent, batch, points


def _frame_search(pc, net, state, front, threshold, centroids, seed):
    """``up="auto"``: the frame found in one batched pass of the network, two for a shape with two mirror planes
    (:mod:`cuboidlib.frames`).

    Returns:
        (the rotation kept, (its batch row, its points) for :func:`_by_network`, the ``method["up_auto"]`` record).
    """
    mirror = mirror_normal(pc.points, pc.normals) if front is None else None
    candidates = search_frames(pc.points, pc.normals, mirror,
                               None if front is None else np.array(AXES[front], dtype=np.float64))
    chamfer, latent, batch, points = _frame_scores(pc, net, state, [c.rotation for c in candidates], threshold,
                                                   centroids, seed)
    i = choose_frame(candidates, chamfer, latent)
    score = frame_score(chamfer, latent)
    kept, by, frames, ran = candidates[i].rotation, candidates[i].kind, len(candidates), (batch.item_batch(i),
                                                                                          points[i:i + 1])
    flipped = [score[j] for j, c in enumerate(candidates) if c.rotation[1] @ kept[1] < 0]
    chosen = min(score[j] for j, c in enumerate(candidates) if c.variant == candidates[i].variant)
    margin = float(min(flipped) - chosen) if flipped else None  # how much better the orientation kept scored
    kept_chamfer, kept_latent = float(chamfer[i]), None if latent is None else float(latent[i])
    if mirror is not None and mirror.second is not None:  # a square table's mirror planes may be its diagonals
        yawed = yawed_frames(kept)
        chamfer2, latent2, batch2, points2 = _frame_scores(pc, net, state, yawed, threshold, centroids, seed)
        frames += len(yawed)
        score2 = frame_score(chamfer2, latent2)
        j = int(np.argmin(score2))
        if score2[j] < score[i]:
            kept, by, ran = yawed[j], f"{by}, turned {YAWS[j]:g} degrees", (batch2.item_batch(j), points2[j:j + 1])
            kept_chamfer, kept_latent = float(chamfer2[j]), None if latent2 is None else float(latent2[j])
    record = {"chosen": _frame_names(kept), "by": by, "frames": frames, "rotation": np.round(kept, 6).tolist(),
              "chamfer": round(kept_chamfer, 7),
              "latent_distance": None if kept_latent is None else round(kept_latent, 2),
              "upside_down_margin": None if margin is None else round(margin, 4)}
    if mirror is not None:
        record["mirror"] = {"normal": np.round(mirror.normal, 6).tolist(), "error": round(mirror.error, 5),
                            "second": None if mirror.second is None else np.round(mirror.second, 6).tolist()}
    return kept, ran, record


def _upside_down_warning(result: Abstraction) -> None:
    """Warn when ``up="auto"`` could hardly tell up from down (:data:`UPSIDE_DOWN_MARGIN`)."""
    record = result.method["up_auto"]
    margin = record["upside_down_margin"]
    if margin is None or margin >= UPSIDE_DOWN_MARGIN:
        return
    chosen = record["chosen"]
    name = result.source or "the shape"
    warnings.warn(OrientationWarning(
        f"{name}: up='auto' could hardly tell up from down: the network reconstructs it about as well upside down "
        f"(score margin {margin:.3f}, below {UPSIDE_DOWN_MARGIN}); it kept up {chosen['up']}, front "
        f"{chosen['front']} (result.frame): check it, and pass up= and front= if you know them"), stacklevel=4)


def _frame_names(rotation: np.ndarray) -> dict:
    """{"up": ..., "front": ...}: axis names for an axis frame, else the directions in the input's axes."""
    if is_axis_frame(rotation):
        names = {tuple(v): k for k, v in AXES.items()}
        return {"up": names[tuple(int(round(c)) for c in rotation[1])],
                "front": names[tuple(int(round(c)) for c in rotation[2])]}
    return {"up": np.round(rotation[1], 4).tolist(), "front": np.round(rotation[2], 4).tolist()}


def _refined(pc_points, pc_normals, out: AbstractionBatch, steps: int, fit_config, seed: int, progress: bool):
    """Refinement: the per-shape fit started from the network's cuboids and allocation (same slots), then
    :data:`TIGHTEN_STEPS` steps on the two-sided distance (:func:`cuboidlib.fitting.tighten_cuboids`); the
    result's Chamfer distance (the course's convention, the samples of :func:`_result`) is compared with the
    start's, and the start is kept when the refinement did not lower it."""
    config = (fit_config if fit_config is not None else FitConfig(seed=seed, lr=REFINE_LR)).replace(
        steps=steps, normalize=False)
    points = torch.as_tensor(pc_points, dtype=out.cuboids.centers.dtype, device=out.cuboids.centers.device)[None]
    normals = torch.as_tensor(pc_normals, dtype=points.dtype, device=points.device)[None]
    fit = fit_cuboids(points, normals, config, progress=progress, start=out)
    tight = tighten_cuboids(points, fit.cuboids, TIGHTEN_STEPS, seed=seed)
    convention = ChamferConvention()
    before = float(_chamfer(pc_points[None], out.cuboids, seed, convention)[0])
    after = float(_chamfer(pc_points[None], tight, seed, convention)[0])
    kept = after < before
    method = {"refine": {"steps": steps, "function": "cuboidlib.fitting.fit_cuboids(start=network)",
                         "tighten_steps": TIGHTEN_STEPS, "lambda_compact": config.loss.lambda_compact,
                         "seed": config.seed, "converged": bool(fit.converged[0]),
                         "chamfer": {"network": round(before, 7), "refined": round(after, 7)},
                         "kept": "refined" if kept else "network"}}
    if not kept:
        return out, method
    return AbstractionBatch(tight, fit.labels, W=fit.W), method


def _result(pc, cuboids: Cuboids, segmentation: torch.Tensor, points: np.ndarray, rotation: np.ndarray,
            method: dict, part_names, source, seed: int) -> Abstraction:
    """The Abstraction of one shape: its Chamfer distance, its cuboids' part labels and the frame. The turned
    cloud was normalised again in the frame (:func:`cuboidlib.frames.turn`), so the normalisation is composed."""
    convention = ChamferConvention()
    chamfer = float(_chamfer(points[None], cuboids, seed, convention)[0])
    part_labels = None
    if pc.labels is not None and len(pc.labels) and pc.labels.min() >= 0:
        num_parts = max(int(pc.labels.max()) + 1, len(part_names) if part_names else 0)
        part_labels = transfer_part_labels(segmentation[None], torch.as_tensor(pc.labels)[None],
                                           cuboids.num_cuboids, num_parts).numpy()
    identity = np.allclose(rotation, np.eye(3))
    if not identity:
        method.update(_frame_names(rotation))
    _, shift, scale = turn(pc.points, rotation)  # p_course = (R p - shift) / scale
    center = np.asarray(pc.center, dtype=np.float64) + pc.scale * (rotation.T @ shift)
    return Abstraction(cuboids, center, pc.scale * scale, points, _turned_normals(pc.normals, rotation),
                       segmentation.numpy(), part_labels, None if part_names is None else tuple(part_names), chamfer,
                       convention, source=source, method=method, frame=None if identity else rotation)


def _by_network(pc, net, state, path, rotation, threshold, centroids, refine, fit_config, part_names, source,
                seed, progress, merge=None, ran=None) -> Abstraction:
    """The network's result in one frame (a rotation), refined and merged if asked; ``ran``: (batch, points) of
    this frame when the network already ran on it."""
    batch, points = ran if ran is not None else _network_pass(pc, net, state, [rotation], threshold, centroids)
    method = {"name": "network", "checkpoint": None if path is None else str(path), "step": state.get("step"),
              "threshold": threshold, "centers": "allocation" if centroids else "predicted", "points": len(pc)}
    if "latent_statistics" in state and batch.z is not None:  # how far the shape lies from the training shapes
        method["latent_distance"] = round(float(latent_distance(batch.z[:1], state["latent_statistics"])[0]), 2)
    if refine:
        batch, refined = _refined(points[0], _turned_normals(pc.normals, rotation), batch, refine, fit_config, seed, progress)
        method.update(refined)
    if merge is not None:
        before = int(batch.cuboids.existing().sum())
        batch = merge_split_cuboids(batch, max_growth=merge)
        method["merge"] = {"function": "cuboidlib.merging.merge_split_cuboids", "max_growth": merge,
                           "cuboids": {"before": before, "after": int(batch.cuboids.existing().sum())}}
    return _result(pc, batch.cuboids.to(device="cpu"), batch.labels[0].cpu(), points[0], rotation, method,
                   part_names, source, seed)


def _by_fitting(pc, rotation, fit_config, part_names, source, seed, progress) -> Abstraction:
    """The result without a network: the per-shape fit of :mod:`cuboidlib.fitting`."""
    config = fit_config if fit_config is not None else FitConfig(seed=seed, count=FIT_COUNT)
    if len(pc) < config.num_cuboids:
        raise ValueError(f"{source or 'shape'}: has {len(pc)} points, fewer than the {config.num_cuboids} cuboids")
    points, normals = turn(pc.points, rotation)[0], _turned_normals(pc.normals, rotation)
    fit = fit_cuboids(points, normals, config, progress=progress)
    method = {"name": "fit", "function": "cuboidlib.fitting.fit_cuboids", "num_cuboids": config.num_cuboids,
              "steps": config.steps, "restarts": config.restarts, "seed": config.seed, "points": len(pc),
              "converged": bool(fit.converged[0]), "count": config.count}
    if fit.count is not None:
        method["count_search"] = fit.count[0].to_dict()
    cuboids = fit.cuboids
    if FIT_TIGHTEN_STEPS:  # the final phase on the two-sided distance, kept only when it lowers it
        tight = tighten_cuboids(torch.as_tensor(points, dtype=cuboids.centers.dtype)[None], cuboids,
                                FIT_TIGHTEN_STEPS, n_samples=FIT_TIGHTEN_POINTS, seed=seed, n_points=FIT_TIGHTEN_POINTS)
        convention = ChamferConvention()
        before, after = (float(_chamfer(points[None], c, seed, convention)[0]) for c in (cuboids, tight))
        method["tighten"] = {"steps": FIT_TIGHTEN_STEPS, "chamfer": {"fit": round(before, 7), "tightened": round(after, 7)}}
        cuboids = tight if after < before else cuboids
    return _result(pc, cuboids, fit.labels[0].cpu(), points, rotation, method, part_names, source, seed)


def _orientation_warning(result: Abstraction, scores: dict[str, float]) -> None:
    """Record the six up axes' scores; warn when another axis reconstructs the shape much better."""
    best = min(scores, key=scores.get)
    suggested = best if best != "y" and scores[best] < ORIENTATION_RATIO * scores["y"] else None
    result.method["up_check"] = {"chamfer": {u: round(c, 7) for u, c in scores.items()}, "suggested": suggested,
                                 "ratio": ORIENTATION_RATIO}
    if suggested is not None:
        name = result.source or "the shape"
        warnings.warn(OrientationWarning(
            f"{name} looks like it is not +y up: with up {suggested} the network's cuboids reconstruct it "
            f"{scores['y'] / scores[best]:.1f}x better (Chamfer {scores[best]:.3g} against {scores['y']:.3g}); "
            f"pass up={suggested!r} (--up {suggested}) or up='auto', or up='y' if it is upright"), stacklevel=4)  # the caller of abstract()


def _given_name(path) -> tuple[str, float]:
    """The given network's name in the check and its threshold: a committed network's name and calibrated
    threshold (:data:`cuboidlib.network_check.LATENT_THRESHOLDS`), else its file name and the default one."""
    resolved = Path(path).resolve()
    for name, committed in committed_checkpoints().items():
        if committed.resolve() == resolved:
            return name, LATENT_THRESHOLDS.get(name, DEFAULT_THRESHOLD)
    return resolved.name, DEFAULT_THRESHOLD


def _network_check(result: Abstraction, path, device: str) -> NetworkVerdict | None:
    """Whether the network knows the shape (:func:`cuboidlib.network_check.network_verdict`), from its latent
    distance under the given network and under each other committed network; recorded in
    ``method["network_check"]``.

    Returns:
        The verdict, or None when the given network holds no latent statistics (a loaded network, an older
        checkpoint): then the record says the check could not run.
    """
    latent = result.method.get("latent_distance")
    if latent is None or path is None:
        result.method["network_check"] = {"speaks": False, "route": None, "unchecked": (
            "the network carries no latent statistics of its training shapes: pass a committed name or a released "
            "checkpoint file (cuboidlib.release.add_latent_statistics adds them)")}
        return None
    given, threshold = _given_name(path)
    others = {name: v for name, v in committed_networks(resolve_device(device)).items() if name != given}
    others_d = latent_distances(result.points[None], result.normals[None], others)  # rounded as the given one is
    distances = {given: float(latent), **{name: round(float(d[0]), 2) for name, d in others_d.items()}}
    thresholds = {given: threshold, **{name: LATENT_THRESHOLDS.get(name, DEFAULT_THRESHOLD) for name in others}}
    verdict = network_verdict(distances, thresholds, given)
    result.method["network_check"] = verdict.to_dict()
    return verdict


def _network_warning(result: Abstraction, verdict: NetworkVerdict, fell_back: bool) -> None:
    """Warn that the network does not know the shape, with the route (:func:`verdict_advice`) or the one taken."""
    name = result.source or "the shape"
    if not fell_back:
        then = verdict_advice(verdict)
    elif verdict.route == "fit":
        then = "abstract fell back to the per-shape fit (fallback=True)"
    else:
        then = f"abstract used the {verdict.route} network instead (fallback=True)"
    warnings.warn(NetworkFitWarning(f"{name}: {verdict_reasons(verdict)}; {then}"), stacklevel=4)  # the caller of abstract()


def up_axis_scores(shape, model, *, n_points: int | None = None, seed: int = 0, threshold: float = 0.5,
                   centers: str = "auto", device: str = "cpu") -> dict[str, float]:
    """The network's Chamfer distance (:data:`FRAME_SCORE`) with each of the six axes taken as up.

    Args:
        shape, model, n_points, seed, threshold, centers, device: as in :func:`abstract`.

    Returns:
        {"x": ..., "y": ..., "z": ..., "-x": ..., "-y": ..., "-z": ...}: the measurement behind the
        orientation warning.
    """
    _check_sampling(n_points, seed)
    net, state, _ = _load_network(model, device)
    pc = _as_point_cloud(shape, _network_points(n_points, state), seed)
    centroids = _centroids(centers, state)
    scores = _frame_scores(pc, net, state, [frame_rotation(u) for u in AXES], threshold, centroids, seed)[0]
    return dict(zip(AXES, (float(c) for c in scores)))


def _check_sampling(n_points, seed) -> None:
    """The points to keep and the seed, checked before any work, for arrays and PointClouds as for files."""
    check_seed(seed)
    if n_points is not None:
        check_size(n_points, "n_points", MAX_SHAPE_POINTS)


def _network_points(n_points: int | None, state: dict) -> int:
    trained = state.get("config", {}).get("n_points")
    return n_points or (trained if isinstance(trained, int) else 2048)


def _centroids(centers: str, state: dict) -> bool:
    trained = bool(state.get("config", {}).get("loss", {}).get("centers_from_allocation", False))
    return trained if centers == "auto" else centers == "allocation"


# ----------------------------------------------------------------------------------------------
# The public entry
# ----------------------------------------------------------------------------------------------


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
    check: bool = False,
    fallback: bool = False,
    merge: float | None = None,
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
        fit_config: a :class:`~cuboidlib.fitting.FitConfig` for ``model=None`` (default: ``FitConfig`` with the
            count chosen by the Chamfer distance, :data:`FIT_COUNT`).
        part_names: names of the input's part labels, for the JSON.
        device: "cpu", "cuda[:i]" or "auto".
        progress: show the fit's progress bar.
        up, front: the input's up axis and the way its front faces, axis names ("x", "y", "z", "-x", "-y",
            "-z", :func:`frame_rotation`); the networks were trained +y up, facing +z, and the result is
            written back in the input's axes. None (default): +y, and with a network a check of the six up
            axes in the same batch (:func:`up_axis_scores`, scores in ``method["up_check"]``) that warns
            (:class:`OrientationWarning`) when another one reconstructs the shape much better; "y" skips the
            check. "auto" (with a network): the frame is found, in any rotation (:mod:`cuboidlib.frames`: the
            mirror plane, then the ups of the grounds the shape can stand on and of its flat area, about 10-20
            frames scored in one batched pass of the network), and recorded in ``method["up_auto"]``:
            ``chosen`` (axis names for an axis frame, else the up and front as directions in the input's axes),
            ``by`` (what decided it), ``rotation`` (R, also ``result.frame``), ``frames`` (how many were scored).
            With ``front`` given, "auto" turns the shape about that axis only.
        refine: with a network, this many steps of the per-shape fit started from the network's
            cuboids and allocation (``fit_cuboids(start=...)``, default ``FitConfig(lr=REFINE_LR)``):
            tighter cuboids that keep the network's slots, and so its part correspondence. A final phase on
            the two-sided distance (:func:`cuboidlib.fitting.tighten_cuboids`) follows, and the network's own
            cuboids are kept when the refined ones do not have a lower Chamfer distance (recorded in
            ``method["refine"]``): a refinement never makes the result worse.
        check: with a network, check that it knows the shape (:mod:`cuboidlib.network_check`): the shape's latent
            distance under it and under each other committed network, each read against that network's threshold
            (:data:`cuboidlib.network_check.LATENT_THRESHOLDS`); recorded in ``method["network_check"]``. It
            warns (:class:`NetworkFitWarning`) when the shape lies nearer another network's training shapes
            (the message names that network) or beyond every network's threshold (it names the per-shape fit,
            ``model=None``); not when the orientation warning speaks (a shape on its side is turned upright
            first). Off by default (it runs the other networks' encoders), on in ``cuboidlib abstract``. A loaded
            network without its checkpoint carries no latent statistics: the record then says it was not checked.
        fallback: with a network, take the route the check names instead when it speaks: the other network
            (same frame, same options) or the per-shape fit (default FitConfig). It still warns, and the given
            network's record is kept in ``method["fallback"]``.
        merge: with a network, last merge the cuboids that cut one part into pieces
            (:func:`cuboidlib.merging.merge_split_cuboids` with this ``max_growth``, e.g. 0.25; recorded in
            ``method["merge"]``); None (default) keeps the network's cuboids.

    Returns:
        An :class:`~cuboidlib.results.Abstraction` (cuboids normalised, with the normalisation to write
        them back).
    """
    with torch_threads(1):  # one shape: one thread (see cuboidlib.config.torch_threads)
        return _abstract(shape, model, n_points, seed, threshold, centers, fit_config, part_names, device, progress,
                         up, front, refine, check, fallback, merge)


def _abstract(shape, model, n_points, seed, threshold, centers, fit_config, part_names, device, progress, up, front,
              refine, check=True, fallback=False, merge=None) -> Abstraction:
    """:func:`abstract` after its thread count is set."""
    if centers not in ("auto", "predicted", "allocation"):
        raise ValueError(f"centers must be 'auto', 'predicted' or 'allocation', got {centers!r}")
    if isinstance(refine, bool) or not isinstance(refine, int) or refine < 0:
        raise ValueError(f"refine must be a non-negative number of steps, got {refine!r}")
    check_size(refine, "refine", MAX_FIT_STEPS, minimum=0)
    _check_sampling(n_points, seed)
    if not isinstance(check, bool) or not isinstance(fallback, bool):
        raise ValueError(f"check and fallback must be True or False, got {check!r} and {fallback!r}")
    if merge is not None and (isinstance(merge, bool) or not isinstance(merge, (int, float)) or not merge >= 0):
        raise ValueError(f"merge must be None or a growth >= 0, got {merge!r}")
    if model is None and merge is not None:
        raise ValueError("merge acts on a network's cuboids: give a model")
    if model is None and refine:
        raise ValueError("refine starts the fit from a network's cuboids: give a model (model=None fits from scratch)")
    if model is None and up == "auto":
        raise ValueError("up='auto' chooses the frame by the network's reconstruction: give a model")
    _check_frame_options(up, front)
    source = Path(shape).name if isinstance(shape, (str, os.PathLike)) else getattr(shape, "source", None)

    if model is None:
        pc = _as_point_cloud(shape, 2048 if n_points is None else n_points, seed)
        _check_part_names(pc, part_names, source)
        return _by_fitting(pc, frame_rotation("y" if up is None else up, front), fit_config, part_names, source, seed,
                           progress)

    net, state, path = _load_network(model, device)
    if "latent_statistics" in state:
        check_latent_statistics(state["latent_statistics"], net.config.latent_dim, f"{path}: latent_statistics")
    pc = _as_point_cloud(shape, _network_points(n_points, state), seed)
    _check_part_names(pc, part_names, source)
    if len(pc) <= net.config.k:
        raise ValueError(f"{source or 'shape'}: has {len(pc)} points; the network needs more than k = {net.config.k}")
    centroids = _centroids(centers, state)
    one_pass = dict(threshold=threshold, centroids=centroids, refine=refine, fit_config=fit_config,
                    part_names=part_names, source=source, seed=seed, progress=progress, merge=merge)
    if up == "auto":
        rotation, ran, record = _frame_search(pc, net, state, front, threshold, centroids, seed)
        result = _by_network(pc, net, state, path, rotation, **one_pass, ran=ran)
        result.method["up_auto"] = record
        _upside_down_warning(result)
    elif up is not None:
        rotation = frame_rotation(up, front)
        result = _by_network(pc, net, state, path, rotation, **one_pass)
    else:  # +y, and the six up axes scored in the same batch
        rotation = frame_rotation("y", front)
        checked = [frame_rotation(u) for u in AXES]
        scores, _, batch, points = _frame_scores(pc, net, state, checked, threshold, centroids, seed)
        k = next((i for i, r in enumerate(checked) if np.array_equal(r, rotation)), None)
        ran = None if k is None else (batch.item_batch(k), points[k:k + 1])  # the network already ran in this frame
        result = _by_network(pc, net, state, path, rotation, **one_pass, ran=ran)
        _orientation_warning(result, dict(zip(AXES, (float(c) for c in scores))))
    if not (check or fallback):
        return result
    verdict = _network_check(result, path, device)
    if verdict is None or not verdict.speaks:
        return result
    if result.method.get("up_check", {}).get("suggested"):  # the orientation warning comes first: turn it upright
        return result
    result.method["network_check"]["warned"] = True
    if not fallback:
        _network_warning(result, verdict, fell_back=False)
        return result
    record = {"network": {k: v for k, v in result.method.items() if k != "network_check"},
              "network_check": result.method["network_check"]}
    if verdict.route == "fit":
        taken = _by_fitting(pc, rotation, None, part_names, source, seed, progress)
    else:
        net, state, path = _load_network(verdict.route, device)
        taken = _by_network(pc, net, state, path, rotation, **{**one_pass, "centroids": _centroids(centers, state)})
    taken.method["fallback"] = record
    _network_warning(taken, verdict, fell_back=True)
    return taken


def _check_frame_options(up, front) -> None:
    """``up`` and ``front`` of :func:`abstract`, checked before any work."""
    names = ", ".join(repr(a) for a in AXES)
    if up is not None and not (isinstance(up, str) and (up == "auto" or up in AXES)):
        raise ValueError(f"up must be None (+y, checked), 'auto' (searched) or an axis: {names}; got {up!r}")
    if front is not None and not (isinstance(front, str) and front in AXES):
        raise ValueError(f"front must be None or an axis: {names}; got {front!r}")
    if up != "auto":
        frame_rotation("y" if up is None else up, front)  # up and front at right angles


def _check_part_names(pc, part_names, source) -> None:
    if part_names is not None and pc.labels is not None and len(pc.labels) and int(pc.labels.max()) >= len(part_names):
        raise ValueError(f"{source or 'shape'}: has part labels up to {int(pc.labels.max())} but part_names gives "
                         f"only {len(part_names)} names")
