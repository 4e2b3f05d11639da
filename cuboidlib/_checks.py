"""Input validation shared by every cuboidlib module, called once at a public function's entry.

Each check raises ``ValueError`` (``TypeError`` for a non-array) with a message that names the argument,
what was expected and what was received, so that bad input never becomes a silent wrong answer or a
stack trace from deep inside torch.
"""

from __future__ import annotations

from typing import Sequence

import torch

__all__ = [
    "as_float_tensor",
    "check_shape",
    "check_finite",
    "check_unit_vectors",
    "check_positive",
    "check_same_leading",
    "check_int",
    "check_size",
    "check_seed",
    "check_coordinates",
    "Limit",
    "MAX_SHAPE_POINTS",
    "MAX_SHAPES",
    "MAX_COLLECTION_POINTS",
    "MAX_CUBOIDS",
    "MAX_RESTARTS",
    "MAX_FIT_STEPS",
    "MAX_THREADS",
    "MAX_SEED",
    "MAX_COORDINATE",
    "MAX_NETWORK_WIDTH",
    "MAX_NETWORK_LAYERS",
    "MAX_NETWORK_PARAMETERS",
    "MAX_NEIGHBOURS",
]

# The limits: every path that samples, generates, allocates or repeats something checks its size against one of
# these with check_size before any work (for arrays as for files), so that a size too large is a clear error that
# names its limit, not an allocator failure or an unbounded run. They admit the paper's scale (4,096 points per
# shape, 2,000 shapes, 16 cuboids) with a wide margin. docs/limits.md lists them.


class Limit(int):
    """A limit: an int that knows its name and what it counts, so that every message names the limit it is about.

    Example: ``MAX_CUBOIDS.name == "MAX_CUBOIDS"``, ``MAX_CUBOIDS.unit == "cuboids"``, ``MAX_CUBOIDS + 0 == 64``.
    """

    def __new__(cls, value: int, name: str, unit: str) -> "Limit":
        limit = super().__new__(cls, value)
        limit.name, limit.unit = name, unit
        return limit

    def __reduce__(self):  # copies and pickles are plain ints
        return int, (int(self),)


#: Points per shape: sampled on a mesh, kept of a point cloud or an array (``abstract(..., n_points)``), or a
#: config's n_points; also the bound of normal estimation (cuboidlib.normals.MAX_POINTS, O(N^2)). Sampling an
#: open mesh (normals oriented by visibility) costs most.
MAX_SHAPE_POINTS = Limit(20_000, "MAX_SHAPE_POINTS", "points")
#: Shapes in one collection or one command: a config's n_shapes, ``cuboidlib generate --count``,
#: ``cuboidlib interpolate --steps``, ``cuboidlib samples --per-category``.
MAX_SHAPES = Limit(20_000, "MAX_SHAPES", "shapes")
#: Points in one collection in all (n_shapes x n_points): 2^24, 4,096 shapes of 4,096 points, about 0.5 GB of
#: points, normals and labels.
MAX_COLLECTION_POINTS = Limit(2**24, "MAX_COLLECTION_POINTS", "points")
#: Cuboid slots of the per-shape fit (``FitConfig.num_cuboids``, ``cuboidlib fit --cuboids``) and k-means boxes per
#: shape: the fit's allocation is restarts x points x cuboids numbers, several times over (Adam, gradients).
MAX_CUBOIDS = Limit(64, "MAX_CUBOIDS", "cuboids")
#: Restarts of the per-shape fit (``FitConfig.restarts``, ``cuboidlib fit --restarts``), fitted in one batch: at
#: MAX_SHAPE_POINTS points and MAX_CUBOIDS cuboids about 20 million allocation weights, under 1 GB with Adam.
MAX_RESTARTS = Limit(16, "MAX_RESTARTS", "restarts")
#: Adam steps of one fit or refinement (``FitConfig.steps``, ``--steps``, ``--refine``): time grows with them,
#: about 5 ms a step at 2,048 points and 16 cuboids, so the limit is minutes, not an unbounded run.
MAX_FIT_STEPS = Limit(100_000, "MAX_FIT_STEPS", "steps")
#: Torch threads of one training process (``TrainConfig.num_threads``, ``cuboidlib train --threads``); more threads
#: than cores only slow it down.
MAX_THREADS = Limit(256, "MAX_THREADS", "threads")
#: The largest seed: what torch's generators take as a signed 64-bit integer (numpy's take any).
MAX_SEED = Limit(2**63 - 1, "MAX_SEED", "")
#: The largest coordinate magnitude of a shape to abstract: result files (GLB, PLY) hold float32 coordinates, at
#: most 3.4e38, and cuboids may reach a little beyond the points.
MAX_COORDINATE = 1e38
#: The network's widths, layers and weights (:class:`cuboidlib.model.ModelConfig`), so that a config read from a
#: file cannot ask for an absurd allocation; and its neighbours k.
MAX_NETWORK_WIDTH = Limit(8192, "MAX_NETWORK_WIDTH", "channels")
MAX_NETWORK_LAYERS = Limit(8, "MAX_NETWORK_LAYERS", "layers")
MAX_NETWORK_PARAMETERS = Limit(50_000_000, "MAX_NETWORK_PARAMETERS", "parameters")
MAX_NEIGHBOURS = Limit(1024, "MAX_NEIGHBOURS", "neighbours")


def as_float_tensor(x, name: str, dtype: torch.dtype | None = None, device=None) -> torch.Tensor:
    """``x`` as a floating-point tensor; numpy arrays and lists are converted.

    Args:
        x: a tensor or array-like of numbers. Integers become the default float dtype; float tensors keep
            their dtype and gradient history.
        name: the argument's name, for the message.
        dtype, device: convert to these (None: keep).

    Returns:
        The tensor (``x`` itself when it is a float tensor and nothing is converted).

    Raises:
        TypeError: ``x`` is not array-like, or a tensor without values (on the "meta" device).
    """
    if isinstance(x, torch.Tensor):
        if x.is_meta:
            raise TypeError(f"{name} is a tensor on the 'meta' device, which holds a shape but no values; give a "
                            "tensor with values (e.g. on the cpu)")
        t = x
    else:
        try:
            t = torch.as_tensor(x)
        except Exception as exc:  # noqa: BLE001 - re-raised with a clear message
            raise TypeError(f"{name} must be a tensor or array-like of numbers, got {type(x).__name__}") from exc
    if not t.is_floating_point():
        t = t.to(torch.get_default_dtype())
    if dtype is not None or device is not None:
        t = t.to(dtype=dtype or t.dtype, device=device or t.device)
    return t


def _fmt_shape(spec: Sequence) -> str:
    return "(" + ", ".join(str(s) for s in spec) + ")"


def check_shape(t: torch.Tensor, spec: Sequence, name: str) -> dict:
    """Check ``t.shape`` against ``spec`` and return the sizes bound to its symbols.

    Args:
        t: the tensor.
        spec: ints (exact sizes) and strings (symbols such as "B", "N"; a symbol twice must match).
        name: the argument's name, for the message.

    Returns:
        {symbol: size}. Example::

            sizes = check_shape(points, ("B", "N", 3), "points")   # -> {"B": 4, "N": 1024}
    """
    if t.dim() != len(spec):
        raise ValueError(
            f"{name} must have shape {_fmt_shape(spec)} ({len(spec)} dimensions), "
            f"got shape {tuple(t.shape)} ({t.dim()} dimensions)"
        )
    sizes: dict = {}
    for axis, (want, got) in enumerate(zip(spec, t.shape)):
        if isinstance(want, int):
            if got != want:
                raise ValueError(
                    f"{name} must have shape {_fmt_shape(spec)}, got {tuple(t.shape)} "
                    f"(dimension {axis} is {got}, expected {want})"
                )
        else:
            if want in sizes and sizes[want] != got:
                raise ValueError(
                    f"{name} must have shape {_fmt_shape(spec)}, got {tuple(t.shape)} "
                    f"(size {want} is both {sizes[want]} and {got})"
                )
            sizes[want] = got
    return sizes


def check_same_leading(named: dict, sizes: dict, what: str) -> None:
    """Check that the symbolic sizes of several arguments agree.

    Args:
        named: {argument name: the size dict :func:`check_shape` returned for it}.
        sizes: updated in place with every symbol.
        what: the operation's name, for the message.
    """
    for arg, s in named.items():
        for key, value in s.items():
            if key in sizes and sizes[key] != value:
                owner = next((a for a, d in named.items() if d.get(key) == sizes[key]), "another argument")
                raise ValueError(
                    f"{what}: size {key} of {arg} is {value} but {key} of {owner} is {sizes[key]}; "
                    "they must agree"
                )
            sizes[key] = value


def check_finite(t: torch.Tensor, name: str) -> None:
    """Raise if ``t`` holds NaN or infinite values, saying how many and where the first one is."""
    bad = ~torch.isfinite(t.detach())
    if bad.any():
        idx = tuple(int(i) for i in torch.nonzero(bad)[0])
        raise ValueError(
            f"{name} contains {int(bad.sum())} NaN or infinite value(s) (first at index {idx}); "
            "clean or drop those entries first"
        )


def check_unit_vectors(t: torch.Tensor, name: str, tol: float = 1e-3) -> None:
    """Raise if the last axis of ``t`` is not unit length within ``tol`` (zero vectors named)."""
    norms = torch.linalg.vector_norm(t.detach(), dim=-1)
    if (norms < 1e-12).any():
        idx = tuple(int(i) for i in torch.nonzero(norms < 1e-12)[0])
        raise ValueError(f"{name} contains zero-length vectors (first at index {idx}); unit vectors are required")
    err = (norms - 1).abs()
    if (err > tol).any():
        idx = tuple(int(i) for i in torch.nonzero(err > tol)[0])
        raise ValueError(
            f"{name} must hold unit vectors along the last axis; the vector at index {idx} has "
            f"length {float(norms[idx]):.6g} (normalise it first, e.g. x / x.norm(dim=-1, keepdim=True))"
        )


def check_positive(t: torch.Tensor, name: str, allow_zero: bool = False) -> None:
    """Raise if any entry of ``t`` is negative (or zero unless ``allow_zero``)."""
    bad = (t.detach() < 0) if allow_zero else (t.detach() <= 0)
    if bad.any():
        idx = tuple(int(i) for i in torch.nonzero(bad)[0])
        rule = "non-negative" if allow_zero else "positive"
        raise ValueError(f"{name} must be {rule}; the entry at index {idx} is {float(t.detach()[idx]):.6g}")


def check_int(value, name: str, minimum: int) -> None:
    """An integer (not a bool) of at least ``minimum``, else ValueError naming ``name``."""
    if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
        raise ValueError(f"{name} must be an integer >= {minimum}, got {value!r}")


def check_size(value, name: str, limit: int, unit: str | None = None, minimum: int = 1) -> int:
    """A size to sample, generate, allocate or repeat: a whole number from ``minimum`` to ``limit``, checked before
    any work.

    Args:
        value: the size (an int, or a whole-valued integer type such as numpy's).
        name: the argument's name, for the message.
        limit: the largest accepted, one of the :class:`Limit` constants above (a plain int is named by value).
        unit: what is counted, for the message (default: the limit's unit).
        minimum: the smallest accepted, 1 or 0.

    Returns:
        ``value`` as an int.

    Raises:
        ValueError: not a whole number, below ``minimum`` or above ``limit`` (naming the limit).
    """
    unit = unit or getattr(limit, "unit", "") or "items"
    if isinstance(value, bool) or not hasattr(value, "__index__"):
        raise ValueError(f"{name} must be a whole number of {unit} from {minimum} to {limit:,}, got {value!r}")
    value = int(value.__index__())
    if value < minimum:
        rule = f"a positive number of {unit}" if minimum == 1 else f"at least {minimum} {unit}"
        raise ValueError(f"{name} must be {rule}, got {value}")
    if value > limit:
        where = f" (cuboidlib._checks.{limit.name})" if isinstance(limit, Limit) else ""
        raise ValueError(f"{name} is {value:,} {unit}, above the limit of {limit:,}{where}; the work and memory grow "
                         "with it. Use a smaller size")
    return value


def check_seed(value, name: str = "seed") -> int:
    """A seed: a whole number from 0 to :data:`MAX_SEED` (what torch's generators take).

    Args:
        value: the seed (an int or a numpy integer).
        name: the argument's name, for the message.

    Returns:
        ``value`` as an int.

    Raises:
        ValueError: naming the argument, the range and the value.
    """
    if isinstance(value, bool) or not hasattr(value, "__index__") or not 0 <= int(value.__index__()) <= MAX_SEED:
        raise ValueError(f"{name} must be a whole number from 0 to {MAX_SEED:,} (cuboidlib._checks.MAX_SEED, the "
                         f"largest seed torch's generators take), got {value!r}")
    return int(value.__index__())


def check_coordinates(largest: float, name: str) -> None:
    """Refuse coordinates beyond :data:`MAX_COORDINATE`, which the result files (float32) cannot hold.

    Args:
        largest: the largest absolute coordinate of the shape.
        name: the shape's name, for the message.

    Raises:
        ValueError: naming the shape, its largest coordinate and the limit.
    """
    if not largest <= MAX_COORDINATE:
        raise ValueError(f"{name}: coordinates reach {largest:.3g}, above the limit of {MAX_COORDINATE:.0e} "
                         "(cuboidlib._checks.MAX_COORDINATE): the cuboids could not be written in the result files "
                         "(float32 coordinates, at most 3.4e38). Give the shape in larger units (divide its "
                         "coordinates by a power of ten)")
