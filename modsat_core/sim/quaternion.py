"""Batched quaternion algebra in torch.

Convention (the same as viser and Basilisk's Euler parameters ``beta_BN``): scalar-first
``wxyz``, Hamilton product, and ``q_BN`` is the attitude of frame B relative to frame N,
so that a vector's components map as ``v_N = q_BN (x) v_B (x) conj(q_BN)``. With this
convention the kinematics are ``dq_BN/dt = 1/2 q_BN (x) [0, omega_B]``.

In components this is the paper's eq. (2), ``dq0/dt = -1/2 qv^T omega``, and eq. (3) with
its sign corrected, ``dqv/dt = +1/2 (qv^x + q0 E) omega`` (Wie's form). As printed, eq. (3)
does not preserve the quaternion norm (``d|q|^2/dt = -2 q0 qv.omega``), so it cannot hold
for any convention; ``tests/core/test_quaternion.py`` shows both facts.

All functions take tensors of shape ``(..., 4)`` / ``(..., 3)`` and broadcast.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from torch import Tensor


def multiply(p: Tensor, q: Tensor) -> Tensor:
    """Hamilton product ``p (x) q``; shapes (..., 4)."""
    pw, px, py, pz = p.unbind(-1)
    qw, qx, qy, qz = q.unbind(-1)
    return torch.stack(
        (
            pw * qw - px * qx - py * qy - pz * qz,
            pw * qx + px * qw + py * qz - pz * qy,
            pw * qy - px * qz + py * qw + pz * qx,
            pw * qz + px * qy - py * qx + pz * qw,
        ),
        dim=-1,
    )


def conjugate(q: Tensor) -> Tensor:
    """Inverse rotation of a unit quaternion; shape (..., 4)."""
    return torch.cat((q[..., :1], -q[..., 1:]), dim=-1)


def normalize(q: Tensor) -> Tensor:
    return q / q.norm(dim=-1, keepdim=True)


def rotate(q_AB: Tensor, v_B: Tensor) -> Tensor:
    """Components in A of a vector given in B: ``v_A = q_AB (x) v_B (x) conj(q_AB)``.

    Shapes: q (..., 4), v (..., 3) -> (..., 3). Uses the Rodrigues form (no 4-vector products).
    """
    w = q_AB[..., :1]
    u = q_AB[..., 1:]
    t = 2.0 * torch.cross(u, v_B, dim=-1)
    return v_B + w * t + torch.cross(u, t, dim=-1)


def rotate_inverse(q_AB: Tensor, v_A: Tensor) -> Tensor:
    """Components in B of a vector given in A (rotation by ``conj(q_AB)``)."""
    return rotate(conjugate(q_AB), v_A)


def to_matrix(q_AB: Tensor) -> Tensor:
    """Direction-cosine matrix ``C_AB`` with ``v_A = C_AB v_B``; shape (..., 3, 3)."""
    w, x, y, z = q_AB.unbind(-1)
    return torch.stack(
        (
            torch.stack((1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)), -1),
            torch.stack((2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)), -1),
            torch.stack((2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)), -1),
        ),
        dim=-2,
    )


def from_axis_angle(axis: Tensor, angle_rad: Tensor) -> Tensor:
    """Rotation by ``angle_rad`` (...,) about the unit ``axis`` (..., 3)."""
    half = 0.5 * angle_rad.unsqueeze(-1)
    return torch.cat((torch.cos(half), axis * torch.sin(half)), dim=-1)


def error_angle(q_e: Tensor) -> Tensor:
    """Rotation angle in [0, pi] of an error quaternion (shortest way); shape (...,)."""
    # atan2 of the vector and scalar parts is accurate near 0 and pi, unlike acos.
    return 2.0 * torch.atan2(q_e[..., 1:].norm(dim=-1), q_e[..., 0].abs())


def canonical(q: Tensor) -> Tensor:
    """The representative with a non-negative scalar part (q and -q are the same rotation)."""
    sign = torch.where(q[..., :1] < 0, -1.0, 1.0).to(q.dtype)
    return q * sign


def derivative(q_BN: Tensor, omega_B: Tensor) -> Tensor:
    """Kinematics ``dq/dt = 1/2 q (x) [0, omega_B]``; q (..., 4), omega (..., 3) rad/s."""
    w = q_BN[..., :1]
    v = q_BN[..., 1:]
    dw = -0.5 * (v * omega_B).sum(-1, keepdim=True)
    dv = 0.5 * (w * omega_B + torch.cross(v, omega_B, dim=-1))
    return torch.cat((dw, dv), dim=-1)


def random_axes(rng: np.random.Generator, n: int) -> np.ndarray:
    """``n`` unit vectors uniform on the sphere, shape (n, 3), float64."""
    v = rng.normal(size=(n, 3))
    norm = np.linalg.norm(v, axis=1, keepdims=True)
    # A zero draw has probability zero; guard anyway so no NaN can leave this function.
    v = np.where(norm > 1e-12, v / np.maximum(norm, 1e-12), np.array([1.0, 0.0, 0.0]))
    return v


def axis_angle_np(axis: np.ndarray, angle_rad: np.ndarray) -> np.ndarray:
    """numpy twin of :func:`from_axis_angle`, used where samples are drawn with numpy RNGs."""
    half = 0.5 * np.asarray(angle_rad)[..., None]
    return np.concatenate((np.cos(half), axis * np.sin(half)), axis=-1)


DEG = math.pi / 180.0
