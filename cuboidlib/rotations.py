"""Rotations (Sec. 3): unit quaternions (w, x, y, z) and rotation matrices.

A cuboid's rotation r is a unit quaternion; its matrix R = R(r) has the cuboid's local x, y, z axes as columns,
so a local point l maps to the world point R l + t. q and -q are the same rotation;
:func:`standardize_quaternion` picks one sign so that a rotation has one quaternion.
"""

from __future__ import annotations

import torch

from ._checks import as_float_tensor, check_finite, check_unit_vectors

__all__ = [
    "quaternion_to_rotation_matrix",
    "rotation_matrix_to_quaternion",
    "standardize_quaternion",
    "quaternion_multiply",
    "random_quaternions",
]


def quaternion_to_rotation_matrix(q: torch.Tensor, validate: bool = True) -> torch.Tensor:
    """Rotation matrix of a quaternion (w, x, y, z).

    The formula uses 2 / |q|^2, so a quaternion that drifted slightly from unit length still gives
    an exact rotation.

    Args:
        q: (..., 4) quaternions.
        validate: require finite, unit-length quaternions (within 1e-3).

    Returns:
        (..., 3, 3) matrices R whose columns are the local x, y, z axes: a local point l maps to R l + t.
    """
    q = as_float_tensor(q, "quaternions")
    if q.dim() < 1 or q.shape[-1] != 4:
        raise ValueError(f"quaternions must have shape (..., 4) in (w, x, y, z) order, got shape {tuple(q.shape)}")
    if validate:
        check_finite(q, "quaternions")
        check_unit_vectors(q, "quaternions")
    w, x, y, z = q.unbind(-1)
    s = 2.0 / (q * q).sum(-1)
    rows = (
        (1 - s * (y * y + z * z), s * (x * y - w * z), s * (x * z + w * y)),
        (s * (x * y + w * z), 1 - s * (x * x + z * z), s * (y * z - w * x)),
        (s * (x * z - w * y), s * (y * z + w * x), 1 - s * (x * x + y * y)),
    )
    return torch.stack([torch.stack(row, dim=-1) for row in rows], dim=-2)  # (..., 3, 3)


def standardize_quaternion(q: torch.Tensor) -> torch.Tensor:
    """Choose the canonical sign of each quaternion (q and -q are the same rotation).

    Args:
        q: (..., 4) quaternions (w, x, y, z).

    Returns:
        (..., 4): q with w >= 0, or where w == 0 the first non-zero component positive.
    """
    q = as_float_tensor(q, "quaternions")
    nonzero = q.detach() != 0
    first = nonzero.to(torch.uint8).argmax(dim=-1, keepdim=True)  # first non-zero component
    sign = torch.gather(q.detach(), -1, first).sign()
    sign = torch.where(sign == 0, torch.ones_like(sign), sign)
    return q * sign


def quaternion_multiply(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Hamilton product a * b of quaternions (w, x, y, z): the rotation b followed by a.

    Args:
        a: (..., 4) quaternions.
        b: (..., 4) quaternions, broadcast against ``a``.

    Returns:
        (..., 4) products, with R(a * b) = R(a) @ R(b).
    """
    a = as_float_tensor(a, "a")
    b = as_float_tensor(b, "b")
    aw, ax, ay, az = a.unbind(-1)
    bw, bx, by, bz = b.unbind(-1)
    return torch.stack(
        (
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ),
        dim=-1,
    )


def rotation_matrix_to_quaternion(R: torch.Tensor, validate: bool = True, tol: float = 1e-3) -> torch.Tensor:
    """Unit quaternion (w, x, y, z) of a rotation matrix, with the canonical sign of :func:`standardize_quaternion`.

    Each entry uses the best-conditioned of four equivalent formulas: robust for every rotation, half turns included.

    Args:
        R: (..., 3, 3) rotation matrices.
        validate: require finite, orthonormal matrices with determinant +1 (within ``tol``).
        tol: tolerance of those checks.

    Returns:
        (..., 4) unit quaternions q with ``quaternion_to_rotation_matrix(q) == R``.

    Raises:
        ValueError: with ``validate``, for a non-orthonormal matrix or a reflection.
    """
    R = as_float_tensor(R, "R")
    if R.dim() < 2 or R.shape[-2:] != (3, 3):
        raise ValueError(f"R must have shape (..., 3, 3), got shape {tuple(R.shape)}")
    if validate:
        check_finite(R, "R")
        eye = torch.eye(3, dtype=R.dtype, device=R.device)
        err = (R.detach().transpose(-1, -2) @ R.detach() - eye).abs().amax(dim=(-1, -2))
        if (err > tol).any():
            idx = tuple(int(i) for i in torch.nonzero(err > tol)[0])
            raise ValueError(
                f"R must hold rotation matrices (R^T R = I); the matrix at index {idx} is off by "
                f"{float(err[idx]):.3g}"
            )
        det = torch.linalg.det(R.detach())
        if (det < 0).any():
            idx = tuple(int(i) for i in torch.nonzero(det < 0)[0])
            raise ValueError(
                f"R must hold rotations (determinant +1); the matrix at index {idx} has determinant "
                f"{float(det[idx]):.3g} (a reflection, which no quaternion represents)"
            )
    m00, m01, m02 = R[..., 0, 0], R[..., 0, 1], R[..., 0, 2]
    m10, m11, m12 = R[..., 1, 0], R[..., 1, 1], R[..., 1, 2]
    m20, m21, m22 = R[..., 2, 0], R[..., 2, 1], R[..., 2, 2]
    # 4 w^2, 4 x^2, 4 y^2, 4 z^2 from the diagonal; at least one of them is >= 1.
    squares = torch.stack(
        (1 + m00 + m11 + m22, 1 + m00 - m11 - m22, 1 - m00 + m11 - m22, 1 - m00 - m11 + m22), dim=-1
    )
    # Clamping only touches the formulas that are not selected (their root may be tiny or imaginary).
    roots = squares.clamp_min(0.1).sqrt()  # 2|w|, 2|x|, 2|y|, 2|z|
    # Off-diagonal combinations: 4wx, 4wy, 4wz, 4xy, 4xz, 4yz.
    wx, wy, wz = m21 - m12, m02 - m20, m10 - m01
    xy, xz, yz = m01 + m10, m02 + m20, m12 + m21
    r0, r1, r2, r3 = roots.unbind(-1)
    candidates = torch.stack(
        (
            torch.stack((r0 * r0, wx, wy, wz), dim=-1) / (2 * r0)[..., None],
            torch.stack((wx, r1 * r1, xy, xz), dim=-1) / (2 * r1)[..., None],
            torch.stack((wy, xy, r2 * r2, yz), dim=-1) / (2 * r2)[..., None],
            torch.stack((wz, xz, yz, r3 * r3), dim=-1) / (2 * r3)[..., None],
        ),
        dim=-2,
    )  # (..., 4 formulas, 4 components)
    best = torch.nn.functional.one_hot(squares.detach().argmax(dim=-1), 4).to(R.dtype)
    q = (candidates * best[..., None]).sum(dim=-2)
    q = q / q.norm(dim=-1, keepdim=True)
    return standardize_quaternion(q)


def random_quaternions(
    *shape: int,
    generator: torch.Generator | None = None,
    dtype: torch.dtype | None = None,
    device: torch.device | str | None = None,
) -> torch.Tensor:
    """Uniformly random rotations (over SO(3)) as unit quaternions (w, x, y, z) with w >= 0.

    Args:
        *shape: leading shape of the result.
        generator: source of randomness.
        dtype: float dtype; None: torch's default.
        device: device; None: torch's default.

    Returns:
        (*shape, 4) unit quaternions (normalised 4-d Gaussians, uniform on S^3).
    """
    g = torch.randn(*shape, 4, generator=generator, dtype=dtype, device=device)
    return standardize_quaternion(g / g.norm(dim=-1, keepdim=True))
