"""Does a network know this shape? The check behind ``abstract(shape, model, check=True)`` and its
:class:`~cuboidlib.abstraction.NetworkFitWarning`, with the route it advises.

A network is trusted on the shapes its training shapes are like. How far a shape lies from them is the
Mahalanobis distance of its latent code (:func:`cuboidlib.applications.latent_distance`, about sqrt(64) = 8
for a training-like shape). Each committed network has its own threshold (:data:`LATENT_THRESHOLDS`), so a
distance is read relative to it: ``r = distance / threshold``, below 1 inside the network's distribution.

The rule (:func:`network_verdict`): the shape goes to the network with the smallest ``r``. The check is silent
when that is the given network and its ``r`` is at most 1. Otherwise it speaks, and names a route:

* another committed network, when the shape lies nearest to it and inside its threshold (a table given to the
  chair network: ``model="table"``);
* the per-shape fit (``model=None``), when no network has the shape inside its threshold (thin structures,
  other kinds of object).

The thresholds come from one command (``benchmarks/bench_warning.py --calibrate``, rule in
:func:`calibrated_threshold`), to be rerun when the networks are retrained.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from .applications import committed_checkpoints, encode_shapes, latent_distance, load_trained_model
from .model import CuboidAbstractionNet

__all__ = ["LATENT_THRESHOLDS", "DEFAULT_THRESHOLD", "CALIBRATION_MARGIN", "NetworkVerdict", "network_verdict",
           "calibrated_threshold", "committed_networks", "latent_distances", "verdict_reasons", "verdict_advice"]

#: Each committed network's latent-distance threshold, written by
#: ``python benchmarks/bench_warning.py --calibrate --root diegogb=/work/realsrc/diegogb
#: --root flightairmap=/work/realsrc/flightairmap --root quaternius=/work/realsrc/quaternius
#: --root pyvista=data_samples/real/pyvista`` (the rule of :func:`calibrated_threshold`: the validation split
#: and the real in-category meshes of ``benchmarks/real_meshes/``). Rerun it when a network is retrained.
LATENT_THRESHOLDS: dict[str, float] = {"chair": 12.0, "table": 13.1, "airplane": 10.8, "animal": 21.3}

#: The threshold of a network without a calibrated one (a checkpoint of your own): near the committed networks'
#: thresholds for procedural shapes (:data:`LATENT_THRESHOLDS`).
DEFAULT_THRESHOLD = 12.0

#: The calibrated threshold lies this factor above the in-category distances it is measured on.
CALIBRATION_MARGIN = 1.1


@dataclass(frozen=True)
class NetworkVerdict:
    """The check's decision for one shape.

    Attributes:
        given: the name of the network the shape was given to.
        distances: {network name: latent distance of the shape under it}, the given network included.
        thresholds: {network name: its threshold}, same keys.
        speaks: whether the check warns.
        route: when it speaks, the name of the network to use instead, or "fit" for the per-shape fit; else None.
    """

    given: str
    distances: dict[str, float]
    thresholds: dict[str, float]
    speaks: bool
    route: str | None

    def ratio(self, name: str) -> float:
        """``distance / threshold`` of one network: at most 1 inside its distribution."""
        return self.distances[name] / self.thresholds[name]

    def to_dict(self) -> dict:
        """The ``method["network_check"]`` record (rounded for the JSON)."""
        return {"given": self.given, "latent_distance": {k: round(v, 2) for k, v in self.distances.items()},
                "threshold": {k: round(v, 2) for k, v in self.thresholds.items()}, "speaks": self.speaks,
                "route": self.route}

    @classmethod
    def from_dict(cls, record: dict) -> NetworkVerdict:
        """Back from :meth:`to_dict`."""
        return cls(record["given"], dict(record["latent_distance"]), dict(record["threshold"]), record["speaks"],
                   record["route"])


def network_verdict(distances: dict[str, float], thresholds: dict[str, float], given: str) -> NetworkVerdict:
    """Decide whether a network knows a shape, and which route to advise when it does not.

    Args:
        distances: {network name: latent distance of the shape under it}, finite and >= 0; the given
            network and any others to compare with (e.g. the committed networks).
        thresholds: {network name: threshold > 0}, for every key of ``distances``.
        given: the key of the network the shape was given to.

    Returns:
        A :class:`NetworkVerdict`: silent when ``given`` has the smallest ``distance / threshold`` and it is at
        most 1; otherwise speaking, with the route: the network of smallest ratio if that is at most 1, else "fit".
    """
    if not isinstance(distances, dict) or not isinstance(thresholds, dict) or given not in distances:
        raise ValueError(f"network_verdict needs dicts of distances and thresholds holding the given network "
                         f"{given!r}; got distances for {sorted(distances) if isinstance(distances, dict) else distances!r}")
    for name, value in distances.items():
        if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0):
            raise ValueError(f"the latent distance under {name!r} must be a finite number >= 0, got {value!r}")
        limit = thresholds.get(name)
        if not (isinstance(limit, (int, float)) and math.isfinite(limit) and limit > 0):
            raise ValueError(f"the threshold of {name!r} must be a finite number > 0, got {limit!r}")
    ratios = {name: d / thresholds[name] for name, d in distances.items()}
    best = min(ratios, key=lambda name: (ratios[name], name != given))  # a tie keeps the given network
    speaks = best != given or ratios[given] > 1
    route = None if not speaks else (best if best != given and ratios[best] <= 1 else "fit")
    return NetworkVerdict(given, {k: float(v) for k, v in distances.items()},
                          {k: float(thresholds[k]) for k in distances}, speaks, route)


def calibrated_threshold(validation, real=()) -> float:
    """A network's threshold from the latent distances of shapes of its own category.

    :data:`CALIBRATION_MARGIN` times the larger of: the 99th percentile of the validation split's distances,
    and the largest distance of the real in-category meshes once the farthest 1 in 20 (rounded up) are left out.

    Args:
        validation: (S,) latent distances of the network's validation shapes, S >= 1.
        real: (R,) latent distances of real meshes of its category (may be empty).

    Returns:
        The threshold, rounded to 0.1.
    """
    validation, real = np.asarray(validation, dtype=np.float64).ravel(), np.sort(np.asarray(real, dtype=np.float64).ravel())
    if validation.size == 0 or not np.isfinite(validation).all() or not np.isfinite(real).all():
        raise ValueError(f"calibrated_threshold needs finite distances, at least one of validation shapes; got "
                         f"{validation.size} validation and {real.size} real")
    kept = real[:len(real) - math.ceil(0.05 * len(real))]
    level = max(float(np.percentile(validation, 99)), float(kept[-1]) if kept.size else 0.0)
    return round(CALIBRATION_MARGIN * level, 1)


_LOADED: dict[tuple, tuple[CuboidAbstractionNet, dict]] = {}


def committed_networks(device: str = "cpu") -> dict[str, tuple[CuboidAbstractionNet, dict, Path]]:
    """The committed networks that hold latent statistics: {name: (network, its latent statistics, path)},
    each loaded once per process (again when its file changes)."""
    out = {}
    for name, path in committed_checkpoints().items():
        key = (str(path), path.stat().st_mtime_ns, str(device))
        if key not in _LOADED:
            net, state, _ = load_trained_model(path, device)
            _LOADED[key] = (net, state.get("latent_statistics"))
        net, statistics = _LOADED[key]
        if statistics is not None:
            out[name] = (net, statistics, path)
    return out


def latent_distances(points, normals, networks: dict[str, tuple], batch_size: int = 64) -> dict[str, np.ndarray]:
    """The latent distance of shapes under each network.

    Args:
        points, normals: (S, N, 3) shapes as the networks read them (normalised, +y up).
        networks: {name: (network, latent statistics, ...)} (:func:`committed_networks`).
        batch_size: shapes per forward pass.

    Returns:
        {name: (S,) float64 distances}.
    """
    p = torch.as_tensor(np.asarray(points, dtype=np.float32))
    n = torch.as_tensor(np.asarray(normals, dtype=np.float32))
    if p.dim() != 3 or p.shape[-1] != 3 or n.shape != p.shape or p.shape[0] == 0:
        raise ValueError(f"latent_distances needs points and normals of one shape (S, N, 3), S >= 1; got "
                         f"{tuple(p.shape)} and {tuple(n.shape)}")
    out = {}
    for name, (net, statistics, *_) in networks.items():
        device = next(net.parameters()).device
        out[name] = np.concatenate([
            latent_distance(encode_shapes(net, p[s:s + batch_size].to(device), n[s:s + batch_size].to(device)),
                            statistics).numpy() for s in range(0, len(p), batch_size)])
    return out


def verdict_reasons(verdict: NetworkVerdict) -> str:
    """Why the check spoke, in words ("" when it is silent)."""
    if not verdict.speaks:
        return ""
    given = verdict.given

    def under(name: str) -> str:
        return f"{verdict.distances[name]:.1f} under the {name} network, threshold {verdict.thresholds[name]:g}"

    if verdict.route not in (None, "fit"):
        return (f"it lies nearer the {verdict.route} network's training shapes than the {given} network's "
                f"(latent distance {under(verdict.route)}; {under(given)})")
    others = [n for n in verdict.distances if n != given]
    nearest = f"; the nearest other: {under(min(others, key=verdict.ratio))}" if others else ""
    return f"it is unlike the training shapes of every network (latent distance {under(given)}{nearest})"


def verdict_advice(verdict: NetworkVerdict, command_line: bool = False) -> str:
    """What to do instead, in words: the route, as a Python argument or a command-line option."""
    if verdict.route is None:
        return ""
    if verdict.route == "fit":
        return ("the per-shape fit reconstructs such shapes better: `cuboidlib fit` (no network)" if command_line
                else "the per-shape fit reconstructs such shapes better: pass model=None, or fallback=True")
    if command_line:
        return f"the {verdict.route} network fits it: pass --model {verdict.route}"
    return f"the {verdict.route} network fits it: pass model={verdict.route!r}, or fallback=True"
