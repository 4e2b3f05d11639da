"""Per-shape fitting: M cuboids fitted to ONE point cloud by Adam on the paper's losses, without a network.

The free variables of each shape: centres (B, M, 3), quaternions q / |q| (B, M, 4) from free 4-vectors
(starting at the identity, Sec. 3.4.5), half sizes exp(log s) (B, M, 3), and the allocation W, a softmax
over the cuboids of free logits (B, N, M) (Eq. 3 without the network). The loss is the part of Eq. (9)
that needs no network: L_recons (Eq. 4, with the distance of Eq. 5 or the nearest-surface one) +
lambda_compact L_compact (Eq. 6). A cuboid exists at the end when w_m > eps_ext, as the existence targets
are built (Sec. 3.4.3), so a part holding less than eps_ext of the points cannot keep a cuboid of its own.

L_compact defaults to the authors' averaged form, Eq. (6) / M^2: with the literal form and lambda_1 = 0.1
it outweighs L_recons, a mean squared distance, and a fit merges every part into one or two cuboids. The
losses are not convex; ``restarts`` keeps the best of several starts. Shapes are normalised
(:mod:`cuboidlib.normalization`) before the fit and the cuboids mapped back. Lesson 03 and the command
line's ``fit`` use it.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np
import torch
from tqdm import tqdm

from ._checks import (MAX_CUBOIDS, MAX_FIT_STEPS, MAX_RESTARTS, MAX_SHAPE_POINTS, as_float_tensor, check_finite,
                      check_seed, check_shape, check_size, check_unit_vectors)
from .baseline import kmeans
from .config import torch_threads
from .counting import CountConfig, CountRecord, choose_count
from .distance import nearest_surface_distance, point_to_cuboid_distance
from .geometry import Cuboids, sample_cuboid_surfaces
from .losses import (
    LossConfig,
    allocation_portions,
    compactness_loss,
    existence_targets,
    nearest_cuboid_allocation,
    reconstruction_loss,
)
from .neighbors import nearest_indices
from .normalization import normalize
from .results import AbstractionBatch
from .rotations import standardize_quaternion

__all__ = ["FitConfig", "FitResult", "kmeans", "initial_cuboids", "fit_cuboids", "tighten_cuboids"]

DISTANCES = ("normal", "nearest_surface")
INITS = ("kmeans", "random")
COUNTS = ("portion", "chamfer")
#: The settings of :class:`~cuboidlib.losses.LossConfig` that the fit reads.
FIT_LOSS_FIELDS = ("lambda_compact", "compactness_average", "sigma_s", "eps_sps", "eps_ext", "distance", "allocation")
_NETWORK_ONLY = ("chamfer_samples", "centers_from_allocation", "existence_min_points", "lambda_consistency")


@dataclass(frozen=True)
class FitConfig:
    """Settings of :func:`fit_cuboids`.

    Args:
        num_cuboids: M, the cuboid slots (the fit decides how many exist).
        steps: Adam steps.
        lr: learning rate of the centres, quaternions and log half sizes.
        lr_logits: learning rate of the allocation logits.
        init: "kmeans" (k-means++ and Lloyd iterations on the positions) or "random" (centres at M random
            points); both size each cuboid to its cluster. The start depends only on the points,
            num_cuboids, init and seed, so configs that differ in the losses start alike.
        init_sharpness: the initial logits are -init_sharpness * |p - c_m|^2 / D, D the mean squared
            distance of the points to their nearest centre; 0 starts from a uniform W. A soft start lets
            every cuboid feel its neighbours' points, so that the fit can merge cuboids on one part.
        beta2: Adam's second-moment decay; 0.9 (not 0.999) forgets the large first gradients fast, so the
            small late ones that merge over-split parts still move the cuboids.
        normalize: fit in normalised coordinates (bounding box centred, diagonal 1) and map back.
        tol: converged when the mean total loss of the last 10 % of the steps is within this relative
            tolerance of the mean of the 10 % before.
        restarts: fit every shape this many times from different starts, in one batch, and keep the lowest
            final loss.
        seed: seed of the initialisation and of the offsets along the normals (and of the count's search).
        count: how many cuboids exist at the end. "portion" (the paper's rule, Sec. 3.4.3): those holding more
            than eps_ext of the points. "chamfer": from there, split and merge cuboids by the Chamfer distance
            (:func:`cuboidlib.counting.choose_count`), so that thin parts such as legs keep cuboids of their own.
        loss: a :class:`~cuboidlib.losses.LossConfig` or its dict. The fit reads lambda_compact,
            compactness_average (default True here: Eq. (6) / M^2), sigma_s, eps_sps, eps_ext, distance
            ("normal" or "nearest_surface") and allocation ("segmentation", a free softmax W, or
            "nearest_cuboid", P2C-Dis); the settings only a network uses must keep their defaults.
    """

    num_cuboids: int = 16
    steps: int = 300
    lr: float = 0.01
    lr_logits: float = 0.1
    init: str = "kmeans"
    init_sharpness: float = 0.1
    beta2: float = 0.9
    normalize: bool = True
    tol: float = 0.02
    restarts: int = 1
    seed: int = 0
    count: str = "portion"
    loss: LossConfig = field(default_factory=lambda: LossConfig(compactness_average=True))

    def __post_init__(self) -> None:
        if isinstance(self.loss, dict):
            object.__setattr__(self, "loss", LossConfig.from_dict({"compactness_average": True, **self.loss}))
        if not isinstance(self.loss, LossConfig):
            raise TypeError(f"FitConfig.loss must be a LossConfig or a dict, got {type(self.loss).__name__}")
        if self.loss.distance not in DISTANCES:
            raise ValueError(f"FitConfig.loss.distance must be one of {DISTANCES} (the fit has no Chamfer "
                             f"variant), got {self.loss.distance!r}")
        unused = [name for name in _NETWORK_ONLY if getattr(self.loss, name) != getattr(LossConfig(), name)]
        if unused:
            raise ValueError(f"FitConfig.loss sets {unused}, which only training a network uses; the fit "
                             f"reads {FIT_LOSS_FIELDS}")
        if self.count not in COUNTS:
            raise ValueError(f"count must be one of {COUNTS}, got {self.count!r}")
        if self.init not in INITS:
            raise ValueError(f"init must be one of {INITS}, got {self.init!r}")
        for name in ("num_cuboids", "restarts", "seed"):
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or value < (0 if name == "seed" else 1):
                rule = "a non-negative" if name == "seed" else "a positive"
                raise ValueError(f"{name} must be {rule} integer, got {value!r}")
        if not isinstance(self.steps, int) or isinstance(self.steps, bool) or self.steps < 0:
            raise ValueError(f"steps must be a non-negative integer, got {self.steps!r}")
        for name, limit in (("num_cuboids", MAX_CUBOIDS), ("restarts", MAX_RESTARTS), ("steps", MAX_FIT_STEPS)):
            check_size(getattr(self, name), f"FitConfig.{name}", limit, minimum=0 if name == "steps" else 1)
        check_seed(self.seed, "FitConfig.seed")
        for name in ("lr", "lr_logits"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a finite positive number, got {value!r}")
        for name in ("init_sharpness", "tol"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0):
                raise ValueError(f"{name} must be a finite non-negative number, got {value!r}")
        if not (isinstance(self.beta2, (int, float)) and 0 <= self.beta2 < 1):
            raise ValueError(f"beta2 must lie in [0, 1), got {self.beta2!r}")
        if not 0 <= self.loss.eps_ext < 1:
            raise ValueError(f"FitConfig.loss.eps_ext must lie in [0, 1), got {self.loss.eps_ext!r}")

    def replace(self, **changes) -> "FitConfig":
        """A copy with some fields changed (validated again); a ``loss`` dict is merged into the loss settings."""
        loss = changes.pop("loss", {})
        if isinstance(loss, dict):
            loss = LossConfig.from_dict({**self.loss.to_dict(), **loss})
        fields_now = {f: getattr(self, f) for f in self.__dataclass_fields__ if f != "loss"}
        return FitConfig(**{**fields_now, **changes, "loss": loss})


@dataclass(kw_only=True)
class FitResult(AbstractionBatch):
    """What :func:`fit_cuboids` returns: an AbstractionBatch (B = 1 for one (N, 3) cloud) and the fit's record.

    Attributes:
        cuboids: (B, M, ...) the fitted :class:`~cuboidlib.geometry.Cuboids`, input coordinates; ``exists``
            (B, M) is w_m > eps_ext, the largest w_m always existing (a refinement: the start's slots that
            still hold a point).
        labels: (B, N) int64, each point's most allocated EXISTING cuboid.
        W: (B, N, M) the final allocation (softmax of the logits, one-hot for "nearest_cuboid").
        portions: (B, M) w_m = mean_n W_mn.
        initial: (B, M, ...) the cuboids the fit started from, input coordinates.
        history: per-step terms averaged over the batch (of the kept restarts), lists of floats under
            "total", "reconstruction", "compactness" and "existing" (mean count of w_m > eps_ext).
        converged: (B,) bool, see ``FitConfig.tol``.
        count: with ``FitConfig.count == "chamfer"``, one :class:`~cuboidlib.counting.CountRecord` per shape (what
            the count's search did), else None.
        final_loss: (B,) total loss of the returned cuboids and W, without offsets along the normals, in
            the fit's coordinates (normalised ones with ``config.normalize``).
        elapsed_s: wall-clock seconds.
        config: the :class:`FitConfig` used.
    """

    portions: torch.Tensor
    initial: Cuboids
    history: dict[str, list[float]]
    converged: torch.Tensor
    final_loss: torch.Tensor
    elapsed_s: float
    config: FitConfig = field(repr=False)
    count: list[CountRecord] | None = None

    @property
    def exists(self) -> torch.Tensor:
        """(B, M) bool existence mask (the same as ``cuboids.exists``)."""
        return self.cuboids.exists


# ----------------------------------------------------------------------------------------------
# Input checks
# ----------------------------------------------------------------------------------------------


def _check_inputs(points, normals) -> tuple[torch.Tensor, torch.Tensor]:
    """Points and normals as (B, N, 3) float tensors (an (N, 3) cloud gets B = 1), normals unit."""
    p = as_float_tensor(np.asarray(points) if not isinstance(points, torch.Tensor) else points, "points")
    n = as_float_tensor(np.asarray(normals) if not isinstance(normals, torch.Tensor) else normals, "normals")
    p, n = p.detach(), n.detach().to(device=p.device)
    if p.dim() == 2:
        p = p[None]
    if n.dim() == 2:
        n = n[None]
    check_shape(p, ("B", "N", 3), "points (or (N, 3) for one shape)")
    check_shape(n, ("B", "N", 3), "normals (or (N, 3) for one shape)")
    if p.shape != n.shape:
        raise ValueError(f"normals must have the shape of points {tuple(p.shape)}, got {tuple(n.shape)}")
    if p.shape[1] == 0:
        raise ValueError("points is empty (N = 0); a point cloud with at least num_cuboids points is needed")
    check_finite(p, "points")
    check_finite(n, "normals")
    # float16 / bfloat16 lack the range and precision of the optimisation: computed in float32
    dtype = torch.promote_types(torch.promote_types(p.dtype, n.dtype), torch.float32)
    p, n = p.to(dtype), n.to(dtype)
    extent = (p.amax(dim=1) - p.amin(dim=1)).amax(dim=-1)  # (B,)
    if (extent == 0).any():
        raise ValueError(f"points of shape {int(torch.nonzero(extent == 0)[0])} are all identical; "
                         "a degenerate cloud has no cuboid abstraction")
    # Accept normals of any non-zero length (files often store them slightly off unit length):
    # normalise them; zero vectors stay zero and are rejected by the check below.
    n = n / torch.linalg.vector_norm(n, dim=-1, keepdim=True).clamp_min(1e-12)
    check_unit_vectors(n, "normals")
    return p, n


# ----------------------------------------------------------------------------------------------
# Initialisation
# ----------------------------------------------------------------------------------------------


def initial_cuboids(
    points: torch.Tensor, config: FitConfig, generator: torch.Generator | None = None
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """The start of :func:`fit_cuboids` (normally called by it; ``points`` are not checked).

    Centres from k-means or M distinct random points; half sizes sqrt(3) times each cluster's standard
    deviation per axis (a uniform distribution's half extent), at least 1 % of the bounding-box diagonal.

    Args:
        points: (B, N, 3) in the fit's coordinates, N >= num_cuboids.
        config: reads num_cuboids, init and init_sharpness.
        generator: source of the k-means seeds or the random points (None: torch's global one).

    Returns:
        (centers (B, M, 3), quaternions (B, M, 4) identity, half_sizes (B, M, 3), logits (B, N, M)).
    """
    b, n, _ = points.shape
    m = config.num_cuboids
    if config.init == "kmeans":
        labels, centers = kmeans(points, m, iterations=20, generator=generator)
    else:
        pick = torch.stack([torch.randperm(n, generator=generator)[:m] for _ in range(b)]).to(points.device)
        centers = torch.gather(points, 1, pick[..., None].expand(-1, -1, 3))
        labels = torch.cdist(points, centers).argmin(dim=-1)
    one_hot = torch.nn.functional.one_hot(labels, m).to(points.dtype)  # (B, N, M)
    count = one_hot.sum(dim=1).clamp_min(1)[..., None]  # (B, M, 1)
    mean = torch.einsum("bnm,bnc->bmc", one_hot, points) / count
    var = torch.einsum("bnm,bnmc->bmc", one_hot, (points[:, :, None] - mean[:, None]).square()) / count
    diagonal = torch.linalg.vector_norm(points.amax(dim=1) - points.amin(dim=1), dim=-1)  # (B,)
    half_sizes = torch.maximum(math.sqrt(3) * var.sqrt(), 0.01 * diagonal[:, None, None])
    quaternions = torch.zeros(b, m, 4, dtype=points.dtype, device=points.device)
    quaternions[..., 0] = 1
    d2 = torch.cdist(points, centers).square()  # (B, N, M)
    spread = d2.amin(dim=-1).mean(dim=-1).clamp_min(1e-12)[:, None, None]
    logits = -config.init_sharpness * d2 / spread
    return centers, quaternions, half_sizes, logits


# ----------------------------------------------------------------------------------------------
# The fit
# ----------------------------------------------------------------------------------------------


def _converged(totals: torch.Tensor, tol: float) -> torch.Tensor:
    """(B,) bool from the per-step totals (steps, B): last 10 % of steps vs the 10 % before."""
    steps = totals.shape[0]
    window = max(1, steps // 10)
    if steps < 2 * window or steps < 2:
        return torch.zeros(totals.shape[1], dtype=torch.bool)
    last = totals[-window:].mean(dim=0)
    before = totals[-2 * window : -window].mean(dim=0)
    return (last - before).abs() <= tol * last.abs().clamp_min(1e-12)


def fit_cuboids(points, normals, config: FitConfig = FitConfig(), progress: bool = False,
                start: AbstractionBatch | None = None) -> FitResult:
    """Fit ``config.num_cuboids`` cuboids to each point cloud by Adam (see the module docstring).

    The B shapes are fitted independently in one batched optimisation, on the points' device and in their
    float dtype (float32 unless float64 is given); deterministic for a given config.

    Args:
        points: (N, 3) for one shape or (B, N, 3), numpy or torch; N >= num_cuboids.
        normals: the same shape, non-zero (normalised to unit length here).
        config: the settings; with ``restarts`` R > 1 each shape is fitted R times and the lowest final
            loss kept.
        progress: a tqdm bar with the loss terms, and a note on shapes that have not converged.
        start: refinement from an :class:`~cuboidlib.results.AbstractionBatch` of the same B shapes and N
            points (typically a network's, :func:`cuboidlib.applications.abstract_shapes`), in the points'
            coordinates, with ``W`` or ``labels``. Its M slots are kept (``config.num_cuboids`` is ignored,
            ``restarts`` must be 1), the logits start at log W (W clamped at 1e-4), slots absent from the
            start stay empty, and a slot exists at the end when it holds a point, so the cuboid indices,
            and a network's part correspondence, survive.

    Returns:
        A :class:`FitResult`, batch-first.

    Raises:
        FloatingPointError: a loss became NaN or infinite; the message names the step and the shape
            (lower ``lr`` or ``lr_logits``).
    """
    if not isinstance(config, FitConfig):
        raise TypeError(f"config must be a FitConfig, got {type(config).__name__}")
    start_time = time.perf_counter()
    p, nrm = _check_inputs(points, normals)
    b, n, _ = p.shape
    if start is not None:
        _check_start(start, b, n, config)
        config = config.replace(num_cuboids=start.num_segments)
    if n < config.num_cuboids:
        raise ValueError(f"points has N = {n} points per shape, fewer than num_cuboids = {config.num_cuboids}")
    if config.normalize:
        p, center, scale = normalize(p)  # raises on a degenerate cloud (all points identical)
    else:
        diagonal = torch.linalg.vector_norm(p.amax(dim=1) - p.amin(dim=1), dim=-1)
        if (diagonal <= 0).any():
            raise ValueError("points are all identical in some shape: there is no surface to fit cuboids to")
        center, scale = torch.zeros(b, 3, dtype=p.dtype, device=p.device), torch.ones(b, dtype=p.dtype, device=p.device)

    r = config.restarts
    begin = None if start is None else _normalised_start(start, center, scale, p)
    with torch_threads(1 if b * r == 1 else None):  # one shape: one thread (see torch_threads)
        run = _optimise(p.repeat_interleave(r, dim=0), nrm.repeat_interleave(r, dim=0), config, progress, begin)
    # keep, for every shape, the restart with the lowest final loss (rows b * R ... b * R + R - 1)
    best = run["final_loss"].view(b, r).argmin(dim=1) + torch.arange(b, device=p.device) * r
    pick = {key: value[best] for key, value in run.items() if key != "records"}
    records = {key: value[:, best.cpu()] for key, value in run["records"].items()}

    counts = None
    if config.count == "chamfer" and start is None:
        counts = _choose_counts(p, pick, config)
    history = {key: value.mean(dim=1).tolist() for key, value in records.items()}
    converged = _converged(records["total"], config.tol)
    if progress and not bool(converged.all()):
        tqdm.write(
            f"fit_cuboids: {int((~converged).sum())} of {b} shape(s) not converged after {config.steps} steps "
            f"(the loss still changes by more than tol = {config.tol}); consider more steps"
        )
    with torch.no_grad():
        to_input = lambda c, s: (c * scale[:, None, None] + center[:, None], s * scale[:, None, None])  # noqa: E731
        fitted_c, fitted_s = to_input(pick["centers"], pick["half_sizes"])
        init_c, init_s = to_input(pick["initial_centers"], pick["initial_half_sizes"])
    exists = pick["exists"]
    return FitResult(
        cuboids=Cuboids(fitted_c, pick["quaternions"], fitted_s, exists, validate=False),
        labels=pick["W"].masked_fill(~exists[:, None, :], -1.0).argmax(dim=-1),  # (B, N), existing cuboids only
        W=pick["W"],
        portions=pick["portions"],
        initial=Cuboids(init_c, pick["initial_quaternions"], init_s, validate=False),
        history=history,
        converged=converged,
        final_loss=pick["final_loss"],
        elapsed_s=time.perf_counter() - start_time,
        config=config,
        count=counts,
    )


def _choose_counts(p: torch.Tensor, pick: dict, config: FitConfig) -> list[CountRecord]:
    """Split and merge each shape's fitted cuboids by the Chamfer distance, in place in ``pick`` (its cuboids,
    existence, W as the one-hot of the new segmentation, portions); the fit's coordinates."""
    records = []
    count_config = CountConfig(seed=config.seed)
    for i in range(p.shape[0]):
        exists = pick["exists"][i]
        labels = pick["W"][i].masked_fill(~exists[None, :], -1.0).argmax(dim=-1)
        with torch.no_grad():
            c, q, s, e, labels, record = choose_count(p[i], pick["centers"][i], pick["quaternions"][i],
                                                      pick["half_sizes"][i], exists, labels, count_config)
        pick["centers"][i], pick["quaternions"][i], pick["half_sizes"][i], pick["exists"][i] = c, q, s, e
        pick["W"][i] = torch.nn.functional.one_hot(labels, exists.shape[0]).to(pick["W"].dtype)
        pick["portions"][i] = pick["W"][i].mean(dim=0)
        records.append(record)
    return records


def _check_start(start: AbstractionBatch, b: int, n: int, config: FitConfig) -> None:
    if not isinstance(start, AbstractionBatch):
        raise TypeError(f"start must be an AbstractionBatch, got {type(start).__name__}")
    if len(start) != b:
        raise ValueError(f"start holds {len(start)} shape(s) but points holds {b}")
    if start.W is None and start.labels is None:
        raise ValueError("start needs an allocation: its W or its labels")
    allocation = start.W if start.W is not None else start.labels
    if tuple(allocation.shape[:2]) != (b, n):
        raise ValueError(f"start's allocation covers {tuple(allocation.shape[:2])} (shapes, points), "
                         f"the points are {(b, n)}")
    if config.restarts != 1:
        raise ValueError("a refinement starts from one given solution: config.restarts must be 1")


def _normalised_start(start: AbstractionBatch, center: torch.Tensor, scale: torch.Tensor, p: torch.Tensor) -> dict:
    """The start's cuboids in the coordinates the fit works in, its allocation as logits, its existing slots."""
    c = start.cuboids
    like = dict(dtype=p.dtype, device=p.device)
    centers = (c.centers.to(**like) - center[:, None]) / scale[:, None, None]
    half_sizes = (c.half_sizes.to(**like) / scale[:, None, None]).clamp_min(1e-4)
    if start.W is not None:
        W = start.W.to(**like)
    else:
        W = torch.nn.functional.one_hot(start.labels.to(p.device), c.num_cuboids).to(**like)
    allowed = c.exists.to(p.device)
    return {"centers": centers, "quaternions": c.quaternions.to(**like), "half_sizes": half_sizes,
            "logits": W.clamp_min(1e-4).log(), "allowed": allowed}


def _optimise(p: torch.Tensor, nrm: torch.Tensor, config: FitConfig, progress: bool, start: dict | None = None) -> dict:
    """Adam on the free variables of every row of (B, N, 3) normalised points; see :func:`fit_cuboids`.

    ``start``: initial centers, quaternions, half_sizes (B, M, ...), logits (B, N, M) and the slots
    ``allowed`` to hold points (B, M) bool, instead of :func:`initial_cuboids`.
    Returns detached per-row tensors (centers, quaternions, half_sizes, W, portions, exists,
    final_loss, initial_*) and "records": per-step (steps, B) tensors of the loss terms.
    """
    b, n, _ = p.shape
    loss = config.loss
    generator = torch.Generator().manual_seed(config.seed)
    if start is None:
        c0, q0, s0, logits0 = initial_cuboids(p, config, generator)
        blocked = None
    else:
        c0, q0, s0, logits0 = start["centers"], start["quaternions"], start["half_sizes"], start["logits"]
        blocked = ~start["allowed"][:, :, None]  # (B, M, 1): slots that may hold no point
    centers = c0.clone().requires_grad_(True)
    quat_raw = q0.clone().requires_grad_(True)
    log_sizes = s0.log().requires_grad_(True)
    logits = logits0.transpose(1, 2).contiguous().requires_grad_(loss.allocation == "segmentation")  # (B, M, N)
    groups = [{"params": [centers, quat_raw, log_sizes], "lr": config.lr}]
    if loss.allocation == "segmentation":
        groups.append({"params": [logits], "lr": config.lr_logits})
    optimizer = torch.optim.Adam(groups, betas=(0.9, config.beta2))

    def evaluate(offsets: torch.Tensor | None):
        quaternions = quat_raw / torch.linalg.vector_norm(quat_raw, dim=-1, keepdim=True)
        half_sizes = log_sizes.exp()
        if loss.distance == "normal":
            d = point_to_cuboid_distance(
                p, nrm, centers, quaternions, half_sizes, sigma_s=0.0, offsets=offsets, validate=False
            )
        else:
            d = nearest_surface_distance(p, centers, quaternions, half_sizes, validate=False)
        if loss.allocation == "nearest_cuboid":
            W = nearest_cuboid_allocation(d if blocked is None else d.masked_fill(blocked.transpose(1, 2), math.inf))
        else:  # logits are stored (B, M, N): a softmax over a short LAST axis is many times slower on CPU
            free = logits if blocked is None else logits.masked_fill(blocked, -math.inf)
            W = torch.softmax(free, dim=1).transpose(1, 2)
        w = allocation_portions(W)
        recons = reconstruction_loss(W, d)
        compact = compactness_loss(w, loss.eps_sps, average_over_cuboids=loss.compactness_average)
        return recons + loss.lambda_compact * compact, recons, compact, W, w

    sampled = loss.distance == "normal" and loss.sigma_s > 0
    records = {key: torch.empty(config.steps, b, dtype=torch.float64)
               for key in ("total", "reconstruction", "compactness", "existing")}
    bar = tqdm(range(config.steps), desc="fitting cuboids", disable=not progress, leave=False)
    for step in bar:
        offsets = None
        if sampled:
            offsets = loss.sigma_s * torch.randn(b, n, generator=generator, dtype=p.dtype).to(p.device)
        total, recons, compact, W, w = evaluate(offsets)
        if not torch.isfinite(total).all():
            total, recons, compact = total.detach(), recons.detach(), compact.detach()
            bad = int(torch.nonzero(~torch.isfinite(total))[0]) // config.restarts
            raise FloatingPointError(
                f"fit_cuboids diverged at step {step}: the loss of shape {bad} is not finite "
                f"(reconstruction {float(recons.max())}, compactness {float(compact.max())}); lower lr or lr_logits"
            )
        optimizer.zero_grad(set_to_none=True)
        total.sum().backward()  # a sum, so every shape's gradient is independent of the batch size
        optimizer.step()
        existing = (w.detach() > loss.eps_ext).sum(dim=-1)  # (B,)
        for key, value in zip(records, (total, recons, compact, existing)):
            records[key][step] = value.detach().double().cpu()
        if progress and (step % 10 == 0 or step == config.steps - 1):
            bar.set_postfix(loss=f"{float(total.detach().mean()):.4g}", recons=f"{float(recons.detach().mean()):.3g}",
                            cuboids=f"{float(existing.double().mean()):.1f}")
    bar.close()

    with torch.no_grad():
        final_loss, _, _, W, w = evaluate(None)
        if blocked is None:
            exists = existence_targets(w, loss.eps_ext) > 0
        else:  # a refinement keeps the start's slots that still hold a point
            exists = torch.nn.functional.one_hot(W.argmax(dim=-1), W.shape[-1]).any(dim=1) & ~blocked[:, :, 0]
        exists |= w == w.amax(dim=-1, keepdim=True)  # at least one cuboid per shape
        quaternions = standardize_quaternion(quat_raw / torch.linalg.vector_norm(quat_raw, dim=-1, keepdim=True))
    return {
        "centers": centers.detach(), "quaternions": quaternions, "half_sizes": log_sizes.detach().exp(),
        "W": W.contiguous(), "portions": w, "exists": exists, "final_loss": final_loss,
        "initial_centers": c0, "initial_quaternions": q0, "initial_half_sizes": s0, "records": records,
    }


def tighten_cuboids(points, cuboids: Cuboids, steps: int = 150, lr: float = 0.003, n_samples: int = 2048,
                    seed: int = 0, n_points: int | None = None) -> Cuboids:
    """A final phase on the two-sided distance: Adam on the existing cuboids' centres, rotations and sizes,
    minimising the squared-L2 Chamfer distance between the points and fresh surface samples of the cuboids
    at every step (the distance a user sees, not Eq. (4)). The slots, and which of them exist, are kept.

    The learning rate falls linearly to 0, so the last steps average the sampling noise out. Whether the
    result is better than its start is for the caller to measure (one fixed set of samples), see
    :func:`cuboidlib.abstraction.abstract`.

    Args:
        points: (B, N, 3) points, in the cuboids' coordinates (any scale: the step is relative to each
            shape's bounding-box diagonal).
        cuboids: B shapes' M cuboids (centres (B, M, 3), quaternions (B, M, 4), half sizes (B, M, 3),
            exists (B, M)).
        steps: Adam steps (0 returns the cuboids unchanged).
        lr: learning rate of centres and half sizes in units of the diagonal, and of the free quaternions.
        n_samples: surface samples per step.
        seed: seed of the surface samples (and of the point subsets).
        n_points: at most this many of the N points, drawn afresh at every step (None: all of them); fewer
            make each step cheaper (the nearest-neighbour search costs N x n_samples).

    Returns:
        The tightened :class:`~cuboidlib.geometry.Cuboids`, (B, M) slots as given, on the points' device.
    """
    p = as_float_tensor(points, "points")
    check_shape(p, ("B", "N", 3), "points")
    check_finite(p, "points")
    if not isinstance(cuboids, Cuboids):
        raise TypeError(f"cuboids must be a Cuboids, got {type(cuboids).__name__}")
    if cuboids.centers.shape[0] != p.shape[0]:
        raise ValueError(f"cuboids hold {cuboids.centers.shape[0]} shape(s) but points holds {p.shape[0]}")
    if n_points is not None and (isinstance(n_points, bool) or not isinstance(n_points, int) or n_points < 1):
        raise ValueError(f"n_points must be a positive integer or None, got {n_points!r}")
    for name, value in (("steps", steps), ("n_samples", n_samples), ("seed", seed)):
        if isinstance(value, bool) or not isinstance(value, int) or value < (1 if name == "n_samples" else 0):
            raise ValueError(f"{name} must be a {'positive' if name == 'n_samples' else 'non-negative'} integer, "
                             f"got {value!r}")
    check_size(steps, "steps", MAX_FIT_STEPS, minimum=0)
    check_size(n_samples, "n_samples", MAX_SHAPE_POINTS)
    check_seed(seed)
    if not (isinstance(lr, (int, float)) and math.isfinite(lr) and lr > 0):
        raise ValueError(f"lr must be a finite positive number, got {lr!r}")
    return _tighten(p, cuboids, steps, lr, n_samples, seed, n_points)


def _tighten(p: torch.Tensor, cuboids: Cuboids, steps: int, lr: float, n_samples: int, seed: int,
             n_points: int | None = None) -> Cuboids:
    """:func:`tighten_cuboids` after its checks."""
    like = dict(dtype=p.dtype, device=p.device)
    exists = None if cuboids.exists is None else cuboids.exists.to(p.device)
    if steps == 0:
        return Cuboids(cuboids.centers.to(**like), cuboids.quaternions.to(**like), cuboids.half_sizes.to(**like),
                       exists, validate=False)
    scale = torch.linalg.vector_norm(p.amax(dim=1) - p.amin(dim=1), dim=-1).clamp_min(1e-12)[:, None, None]  # (B,1,1)
    centers = (cuboids.centers.to(**like) / scale).clone().requires_grad_(True)
    quat_raw = cuboids.quaternions.to(**like).clone().requires_grad_(True)
    log_sizes = (cuboids.half_sizes.to(**like) / scale).clamp_min(1e-5).log().requires_grad_(True)
    q = p / scale
    optimizer = torch.optim.Adam([centers, quat_raw, log_sizes], lr=lr, betas=(0.9, 0.99))
    schedule = torch.optim.lr_scheduler.LambdaLR(optimizer, lambda k: 1.0 - k / steps)
    generator = torch.Generator(device=p.device).manual_seed(seed)
    for _ in range(steps):
        subset = q
        if n_points is not None and n_points < q.shape[1]:
            subset = q[:, torch.randperm(q.shape[1], generator=generator, device=p.device)[:n_points]]
        quaternions = quat_raw / torch.linalg.vector_norm(quat_raw, dim=-1, keepdim=True)
        samples = sample_cuboid_surfaces(centers, quaternions, log_sizes.exp(), n_samples, exists=exists,
                                         generator=generator, validate=False).points  # (B, n, 3)
        to_samples, to_points = nearest_indices(subset, samples.detach())
        forward = (subset - torch.gather(samples, 1, to_samples[..., None].expand(-1, -1, 3))).square().sum(-1).mean(1)
        backward = (samples - torch.gather(subset, 1, to_points[..., None].expand(-1, -1, 3))).square().sum(-1).mean(1)
        optimizer.zero_grad(set_to_none=True)
        (forward + backward).sum().backward()
        optimizer.step()
        schedule.step()
    with torch.no_grad():
        quaternions = standardize_quaternion(quat_raw / torch.linalg.vector_norm(quat_raw, dim=-1, keepdim=True))
        return Cuboids(centers * scale, quaternions, log_sizes.exp() * scale, exists, validate=False)
