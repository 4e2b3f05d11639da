"""The one normalisation convention of cuboidlib: the paper's "unit scale" (Sec. 4.1) made precise.

Axes: +y is up, shapes face +z, x points to the side; augmentation rotates about +y. A shape is
moved so that its axis-aligned bounding box is centred at the origin, then scaled uniformly so that
the box diagonal is 1: ``normalized = (points - center) / scale`` with ``center = (min + max) / 2``
and ``scale = |max - min|``, so it fits in ``[-0.5, 0.5]^3``. Normals do not change. Keep
``(center, scale)`` to write results back in the original coordinates (:func:`denormalize`).
"""

from __future__ import annotations

import numpy as np
import torch

from ._checks import as_float_tensor, check_finite

__all__ = ["normalize", "denormalize", "bounding_box"]

# Diagonals at most this fraction of the largest coordinate magnitude count as "all points identical": below it,
# even float64 (the normalisation's precision, eps 2.2e-16) holds fewer than ~50 steps across the shape. The bound
# is relative only: a shape of size 1e-30 near the origin is a shape, not a point.
_DEGENERATE_RTOL = 1e-14


def _to_tensor(points, name: str) -> tuple[torch.Tensor, bool]:
    is_numpy = not isinstance(points, torch.Tensor)
    t = as_float_tensor(np.asarray(points) if is_numpy else points, name)
    if t.dim() not in (2, 3) or t.shape[-1] != 3:
        raise ValueError(f"{name} must have shape (N, 3) or (B, N, 3), got shape {tuple(t.shape)}")
    return t, is_numpy


def bounding_box(points: torch.Tensor | np.ndarray) -> tuple:
    """Axis-aligned bounding box of a point cloud.

    Args:
        points: (N, 3) or (B, N, 3) tensor or array, at least one point.

    Returns:
        ``(lo, hi)``: the smallest and largest coordinates, each (3,) or (B, 3), of the input's kind.
    """
    t, is_numpy = _to_tensor(points, "points")
    if t.shape[-2] == 0:
        raise ValueError("points is empty (0 points); at least one point is required")
    lo, hi = t.amin(dim=-2), t.amax(dim=-2)
    return (lo.numpy(), hi.numpy()) if is_numpy else (lo, hi)


def normalize(points: torch.Tensor | np.ndarray) -> tuple:
    """Centre the bounding box at the origin and scale its diagonal to length 1.

    Args:
        points: (N, 3) or (B, N, 3) tensor or array; each batch entry is normalised on its own.

    Returns:
        ``(normalized, center, scale)`` with ``normalized = (points - center) / scale``: normalized
        like ``points``, center (3,) or (B, 3), scale () or (B,); of the input's kind and dtype.

    Raises:
        ValueError: on a wrong shape, an empty cloud, NaN/inf values, or all points identical.
    """
    t, is_numpy = _to_tensor(points, "points")
    if t.shape[-2] == 0:
        raise ValueError("points is empty (0 points); at least one point is required")
    check_finite(t, "points")
    wide = t.double()  # float32 coordinates near their limit would overflow in (hi - lo) and the norm
    lo, hi = wide.amin(dim=-2), wide.amax(dim=-2)
    center = (lo + hi) / 2
    extent = hi - lo  # inf only when the box itself exceeds float64
    largest = extent.abs().amax(dim=-1, keepdim=True).clamp_min(torch.finfo(wide.dtype).tiny)
    scale = torch.linalg.vector_norm(extent / largest, dim=-1) * largest[..., 0]  # no overflow in the squares
    magnitude = wide.detach().abs().amax(dim=(-2, -1))
    degenerate = scale <= _DEGENERATE_RTOL * magnitude
    if degenerate.any():
        first = int(torch.nonzero(degenerate.reshape(-1))[0])
        which = "" if t.dim() == 2 else f" (batch entry {first})"
        size, far = float(scale.reshape(-1)[first]), float(magnitude.reshape(-1)[first])
        if size == 0:
            raise ValueError(
                f"points are all identical{which}: the bounding box has zero size, so the shape cannot be "
                "normalised to unit diagonal"
            )
        raise ValueError(
            f"points are all identical{which} to float64 precision: the bounding box diagonal {size:.3g} is at "
            f"most {_DEGENERATE_RTOL:g} of the coordinates' magnitude {far:.3g}, too few digits to normalise; "
            "subtract a nearby origin from the coordinates first"
        )
    if not torch.isfinite(scale.to(t.dtype)).all():
        raise ValueError(
            f"points are too large for {str(t.dtype).replace('torch.', '')}: the bounding-box diagonal "
            f"{float(scale.max()):.3g} cannot be represented; pass float64 coordinates or rescale them"
        )
    normalized = ((wide - center.unsqueeze(-2)) / scale[..., None, None]).to(t.dtype)
    center, scale = center.to(t.dtype), scale.to(t.dtype)
    if is_numpy:
        return normalized.numpy(), center.numpy(), scale.numpy()
    return normalized, center, scale


def denormalize(points: torch.Tensor | np.ndarray, center, scale) -> torch.Tensor | np.ndarray:
    """Map normalised points back to the original coordinates: ``points * scale + center``.

    Args:
        points: (N, 3) or (B, N, 3) normalised points, tensor or array.
        center: (3,) or (B, 3), as returned by :func:`normalize`.
        scale: () or (B,), positive, as returned by :func:`normalize`.

    Returns:
        Points of the shape and kind (numpy or torch) of ``points``.
    """
    t, is_numpy = _to_tensor(points, "points")
    c = as_float_tensor(np.asarray(center) if not isinstance(center, torch.Tensor) else center, "center")
    s = as_float_tensor(np.asarray(scale) if not isinstance(scale, torch.Tensor) else scale, "scale")
    c, s = c.to(dtype=t.dtype, device=t.device), s.to(dtype=t.dtype, device=t.device)
    if c.shape != t.shape[:-2] + (3,):
        raise ValueError(f"center must have shape {tuple(t.shape[:-2]) + (3,)}, got {tuple(c.shape)}")
    if s.shape != t.shape[:-2]:
        raise ValueError(f"scale must have shape {tuple(t.shape[:-2])}, got {tuple(s.shape)}")
    check_finite(t, "points")
    check_finite(c, "center")
    check_finite(s, "scale")
    if (s <= 0).any():
        raise ValueError("scale must be positive (it is the bounding-box diagonal before normalisation)")
    out = t * s[..., None, None] + c.unsqueeze(-2)
    if not torch.isfinite(out).all():
        raise ValueError(
            f"denormalised points overflow {str(t.dtype).replace('torch.', '')} (scale up to "
            f"{float(s.max()):.3g}, |center| up to {float(c.abs().max()):.3g}); pass float64 points"
        )
    return out.numpy() if is_numpy else out
