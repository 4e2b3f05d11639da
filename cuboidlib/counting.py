"""How many cuboids a per-shape fit keeps: split and merge by the Chamfer distance (not in the paper).

In the paper a cuboid exists when it holds enough of the points (w_m > eps_ext, Sec. 3.4.3), and the
compactness loss (Eq. 6) pushes the allocation towards few cuboids. Over a training set that finds the parts.
On ONE shape it drops thin parts: a chair leg holds 2-4 % of the points, so one cuboid over two legs, or a
seat cuboid stretched over the legs' tops, costs the sum of Eq. (4) less than the compactness it saves.

This module chooses the count afterwards by the score a user sees, the two-sided Chamfer distance between
the points and the cuboids' surfaces (:func:`cuboidlib.metrics.cuboid_chamfer_distance`). Starting from the
fit's cuboids and its segmentation, it repeats one move at a time:

1. **split** the cuboid whose cut lowers the Chamfer distance most, when it falls by more than
   ``min_gain`` (relative) and a free slot is left;
2. otherwise **merge** the pair of touching cuboids whose union (the tightest box around both point sets)
   raises the Chamfer distance least, when it stays within ``merge_tolerance`` (relative) of the lowest
   distance reached so far (so merges cannot drift upwards one small step at a time). A cut is either 2-means on the cuboid's points or, along
   each of its axes, the plane that leaves the two tightest boxes the smallest total surface; each half gets
   the tightest box around its points, in the parent's rotation.

It stops when neither move is taken. ``merge_tolerance < min_gain``, so a split is never undone by the merge
of its own halves. Every candidate of a round is scored on a fixed subset of the points, with surface samples
drawn from one seed for each, so the choice is deterministic.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from .metrics import ChamferConvention, cuboid_chamfer_distance
from .rotations import quaternion_to_rotation_matrix, rotation_matrix_to_quaternion

__all__ = ["CountConfig", "CountRecord", "choose_count"]


@dataclass(frozen=True)
class CountConfig:
    """Settings of :func:`choose_count`.

    Args:
        min_gain: a split is taken when the Chamfer distance falls by more than this share of it.
        merge_tolerance: a merge is taken when the Chamfer distance rises by at most this share; below
            ``min_gain``.
        min_points: each half of a split holds at least this many points (and 0.5 % of the shape's).
        max_moves: at most this many splits and merges in all.
        search_points: the Chamfer distances of the search use at most this many of the points.
        search_samples: and this many surface samples on the cuboids.
        touch: two cuboids may merge when some point of one lies within this distance of some point of the
            other, in units of the shape's bounding-box diagonal.
        seed: seed of the point subset and the surface samples.
    """

    min_gain: float = 0.02
    merge_tolerance: float = 0.005
    min_points: int = 8
    max_moves: int = 48
    search_points: int = 512
    search_samples: int = 1024
    touch: float = 0.03
    seed: int = 0

    def __post_init__(self) -> None:
        for name in ("min_gain", "merge_tolerance", "touch"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
                    and value >= 0):
                raise ValueError(f"CountConfig.{name} must be a finite non-negative number, got {value!r}")
        if not self.merge_tolerance < self.min_gain < 1:
            raise ValueError(f"CountConfig needs merge_tolerance < min_gain < 1 (else a split and the merge of its "
                             f"halves could repeat), got {self.merge_tolerance!r} and {self.min_gain!r}")
        for name in ("min_points", "max_moves", "search_points", "search_samples", "seed"):
            value = getattr(self, name)
            low = 0 if name in ("seed", "max_moves") else 1
            if isinstance(value, bool) or not isinstance(value, int) or value < low:
                raise ValueError(f"CountConfig.{name} must be an integer >= {low}, got {value!r}")


@dataclass(frozen=True)
class CountRecord:
    """What :func:`choose_count` did to one shape: cuboid counts, moves and the search's Chamfer distances."""

    before: int
    after: int
    splits: int
    merges: int
    chamfer_before: float
    chamfer_after: float

    def to_dict(self) -> dict:
        return {"before": self.before, "after": self.after, "splits": self.splits, "merges": self.merges,
                "chamfer": {"before": round(self.chamfer_before, 7), "after": round(self.chamfer_after, 7)}}


def _tight_box(points: torch.Tensor, R: torch.Tensor, floor: float) -> tuple[torch.Tensor, torch.Tensor]:
    """Centre (3,) and half sizes (3,) of the smallest box with axes R's columns around (n, 3) points."""
    local = points @ R
    lo, hi = local.amin(dim=0), local.amax(dim=0)
    return R @ ((lo + hi) / 2), ((hi - lo) / 2).clamp_min(floor)


def _two_means(local: torch.Tensor, iterations: int = 10) -> torch.Tensor:
    """(n,) bool: 2-means on (n, 3) points, started from the two extremes along their widest axis."""
    axis = int((local.amax(dim=0) - local.amin(dim=0)).argmax())
    centers = torch.stack([local[local[:, axis].argmin()], local[local[:, axis].argmax()]])
    side = torch.zeros(local.shape[0], dtype=torch.bool)
    for _ in range(iterations):
        new = (local - centers[1]).square().sum(-1) < (local - centers[0]).square().sum(-1)
        if new.all() or not new.any():
            break
        if torch.equal(new, side):
            break
        side = new
        centers = torch.stack([local[~side].mean(dim=0), local[side].mean(dim=0)])
    return side


def _box_areas(lo: torch.Tensor, hi: torch.Tensor) -> torch.Tensor:
    """Surface areas (k,) of axis-aligned boxes with corners lo, hi (k, 3)."""
    e = hi - lo
    return 2 * (e[:, 0] * e[:, 1] + e[:, 1] * e[:, 2] + e[:, 2] * e[:, 0])


def _cuts(local: torch.Tensor, least: int) -> list[torch.Tensor]:
    """The candidate cuts of one cuboid's points, (n, 3) in its frame, each an (n,) bool mask whose two sides
    hold at least ``least`` points: 2-means, and per axis the plane across it that leaves the two tightest
    boxes the smallest total surface (a seat's slab and a leg below it; two legs side by side)."""
    cuts = [_two_means(local)]
    n = local.shape[0]
    for axis in range(3):
        order = local[:, axis].argsort()
        ordered = local[order]
        lo_head, hi_head = ordered.cummin(dim=0).values, ordered.cummax(dim=0).values
        lo_tail = ordered.flip(0).cummin(dim=0).values.flip(0)
        hi_tail = ordered.flip(0).cummax(dim=0).values.flip(0)
        at = torch.arange(least, n - least + 1)  # the first index on the far side
        if at.numel() == 0:
            continue
        total = _box_areas(lo_head[at - 1], hi_head[at - 1]) + _box_areas(lo_tail[at], hi_tail[at])
        first = int(at[int(total.argmin())])
        side = torch.zeros(n, dtype=torch.bool)
        side[order[first:]] = True
        cuts.append(side)
    return [c for c in cuts if least <= int(c.sum()) <= n - least]


@dataclass
class _Slots:
    """A shape's M cuboid slots during the search: centres (M, 3), rotations R (M, 3, 3) whose columns are the
    cuboids' axes, half sizes (M, 3) and existence (M,)."""

    centers: torch.Tensor
    R: torch.Tensor
    half_sizes: torch.Tensor
    exists: torch.Tensor

    def copy(self) -> "_Slots":
        return _Slots(self.centers.clone(), self.R.clone(), self.half_sizes.clone(), self.exists.clone())


#: Smallest half size of a cuboid made by a move, in units of the shape's diagonal.
_FLOOR = 0.005


def _merge_moves(points: torch.Tensor, labels: torch.Tensor, slots: _Slots, touch: float) -> list[tuple]:
    """Every merge of two touching cuboids: ``(slots after it, ("merge", kept slot, freed slot))``."""
    used = torch.nonzero(slots.exists).flatten().tolist()
    moves = []
    for i, a in enumerate(used):
        pa = points[labels == a]
        for b in used[i + 1:]:
            pb = points[labels == b]
            if len(pa) == 0 or len(pb) == 0 or float(torch.cdist(pa, pb).min()) > touch:
                continue
            keep, drop = (a, b) if len(pa) >= len(pb) else (b, a)
            after = slots.copy()
            after.centers[keep], after.half_sizes[keep] = _tight_box(torch.cat([pa, pb]), slots.R[keep], _FLOOR)
            after.exists[drop] = False
            moves.append((after, ("merge", keep, drop)))
    return moves


def _split_moves(points: torch.Tensor, labels: torch.Tensor, slots: _Slots, least: int) -> list[tuple]:
    """Every cut of a cuboid into the first free slot: ``(slots after it, ("split", slot, new slot, side))``."""
    free = torch.nonzero(~slots.exists).flatten()
    if len(free) == 0:
        return []
    new, moves = int(free[0]), []
    for a in torch.nonzero(slots.exists).flatten().tolist():
        pa = points[labels == a]
        if len(pa) < 2 * least:
            continue
        for side in _cuts(pa @ slots.R[a], least):
            after = slots.copy()
            after.centers[a], after.half_sizes[a] = _tight_box(pa[~side], slots.R[a], _FLOOR)
            after.centers[new], after.half_sizes[new] = _tight_box(pa[side], slots.R[a], _FLOOR)
            after.R[new], after.exists[new] = slots.R[a], True
            moves.append((after, ("split", a, new, side)))
    return moves


def _relabel(labels: torch.Tensor, move: tuple) -> None:
    """Apply a move's change of the points' slots, in place."""
    if move[0] == "merge":
        labels[labels == move[2]] = move[1]
    else:
        members = torch.nonzero(labels == move[1]).flatten()
        labels[members[move[3]]] = move[2]


def choose_count(points: torch.Tensor, centers: torch.Tensor, quaternions: torch.Tensor, half_sizes: torch.Tensor,
                 exists: torch.Tensor, labels: torch.Tensor, config: CountConfig = CountConfig()):
    """Split and merge one shape's cuboids by the Chamfer distance (see the module docstring).

    Args:
        points: (N, 3) the shape, normalised (bounding-box diagonal 1).
        centers, quaternions, half_sizes: (M, 3), (M, 4) unit (w, x, y, z), (M, 3) the fitted cuboid slots.
        exists: (M,) bool, the slots in use.
        labels: (N,) int64, each point's slot, an existing one.
        config: the moves' thresholds and the search's size.

    Returns:
        ``(centers, quaternions, half_sizes, exists, labels, record)``: the slots after the moves (the same M;
        a split fills a free slot, a merge frees one), each point's slot, and a :class:`CountRecord`.
    """
    if not isinstance(config, CountConfig):
        raise TypeError(f"config must be a CountConfig, got {type(config).__name__}")
    n, m = points.shape[0], centers.shape[0]
    if labels.shape != (n,) or exists.shape != (m,):
        raise ValueError(f"labels must be ({n},) and exists ({m},), got {tuple(labels.shape)} and {tuple(exists.shape)}")
    if n and not bool(exists[labels].all()):
        raise ValueError("every point's label must be an existing slot")
    R = quaternion_to_rotation_matrix(quaternions.to(points.dtype), validate=False)  # (M, 3, 3), columns = axes
    slots, labels = _Slots(centers.clone(), R.clone(), half_sizes.clone(), exists.clone()), labels.clone()
    least = max(config.min_points, math.ceil(0.005 * n))
    subset = points[torch.randperm(n, generator=torch.Generator().manual_seed(config.seed))[:config.search_points]]
    convention = ChamferConvention(n_samples=config.search_samples)

    def score(candidate: _Slots) -> float:
        """The search's Chamfer distance; every candidate draws its samples from the same seed, so that two
        candidates differ by their cuboids rather than by their samples."""
        q = rotation_matrix_to_quaternion(candidate.R, validate=False)
        return float(cuboid_chamfer_distance(subset[None], candidate.centers[None], q[None], candidate.half_sizes[None],
                                             candidate.exists[None], convention,
                                             torch.Generator().manual_seed(config.seed))[0])

    current = before = lowest = score(slots)
    count_before, moves = int(slots.exists.sum()), {"split": 0, "merge": 0}
    while moves["split"] + moves["merge"] < config.max_moves:
        splits = [(score(after), after, move) for after, move in _split_moves(points, labels, slots, least)]
        merges = [(score(after), after, move) for after, move in _merge_moves(points, labels, slots, config.touch)]
        best_split = min(splits, key=lambda x: x[0], default=None)
        best_merge = min(merges, key=lambda x: x[0], default=None)
        if best_split is not None and best_split[0] < current * (1 - config.min_gain):
            chosen = best_split
        elif best_merge is not None and best_merge[0] <= lowest * (1 + config.merge_tolerance):
            chosen = best_merge
        else:
            break
        current, slots, move = chosen
        _relabel(labels, move)
        moves[move[0]] += 1
        lowest = min(lowest, current)
    record = CountRecord(before=count_before, after=int(slots.exists.sum()), splits=moves["split"],
                         merges=moves["merge"], chamfer_before=before, chamfer_after=current)
    quaternions = rotation_matrix_to_quaternion(slots.R, validate=False)
    return slots.centers, quaternions, slots.half_sizes, slots.exists, labels, record
