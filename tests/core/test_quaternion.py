"""Quaternion conventions, including the paper's eqs. (2)-(3)."""

import math

import numpy as np
import torch

from modsat_core.sim import quaternion as quat


def rand_q(rng, n=5):
    q = torch.tensor(rng.normal(size=(n, 4)))
    return quat.normalize(q)


def test_rotate_matches_matrix_and_product():
    rng = np.random.default_rng(0)
    q = rand_q(rng)
    v = torch.tensor(rng.normal(size=(5, 3)))
    r1 = quat.rotate(q, v)
    r2 = (quat.to_matrix(q) @ v.unsqueeze(-1)).squeeze(-1)
    pure = torch.cat((torch.zeros(5, 1, dtype=v.dtype), v), -1)
    r3 = quat.multiply(quat.multiply(q, pure), quat.conjugate(q))[:, 1:]
    torch.testing.assert_close(r1, r2, rtol=0, atol=1e-14)
    torch.testing.assert_close(r1, r3, rtol=0, atol=1e-14)
    torch.testing.assert_close(quat.rotate_inverse(q, r1), v, rtol=0, atol=1e-14)


def test_axis_angle_and_error_angle():
    axis = torch.tensor([[0.0, 0.0, 1.0]], dtype=torch.float64)
    q = quat.from_axis_angle(axis, torch.tensor([math.pi / 2], dtype=torch.float64))
    torch.testing.assert_close(
        quat.rotate(q, torch.tensor([[1.0, 0, 0]], dtype=torch.float64)),
        torch.tensor([[0.0, 1.0, 0.0]], dtype=torch.float64),
        atol=1e-15,
        rtol=0,
    )
    for ang in (0.0, 1e-9, 0.3, math.pi - 1e-9, math.pi):
        q = quat.from_axis_angle(axis, torch.tensor([ang], dtype=torch.float64))
        assert abs(quat.error_angle(q).item() - ang) < 1e-12
        assert abs(quat.error_angle(-q).item() - ang) < 1e-12  # q and -q are one rotation


def _cross_matrix(v):
    z = torch.zeros_like(v[:, 0])
    return torch.stack(
        (
            torch.stack((z, -v[:, 2], v[:, 1]), -1),
            torch.stack((v[:, 2], z, -v[:, 0]), -1),
            torch.stack((-v[:, 1], v[:, 0], z), -1),
        ),
        -2,
    )


def test_kinematics_are_paper_eq_2_and_eq_3_with_its_sign_corrected():
    """Paper: dq0/dt = -1/2 qv^T w (eq. 2), dqv/dt = -1/2 (qv^x + q0 E) w (eq. 3, as printed)."""
    rng = np.random.default_rng(1)
    q = rand_q(rng)
    w = torch.tensor(rng.normal(size=(5, 3)))
    q0, qv = q[:, 0], q[:, 1:]
    M = _cross_matrix(qv) + q0[:, None, None] * torch.eye(3, dtype=w.dtype)
    eq3_printed = -0.5 * (M @ w.unsqueeze(-1)).squeeze(-1)
    dq = quat.derivative(q, w)
    torch.testing.assert_close(dq[:, 0], -0.5 * (qv * w).sum(-1), rtol=0, atol=1e-15)  # eq. 2
    torch.testing.assert_close(dq[:, 1:], -eq3_printed, rtol=0, atol=1e-15)  # eq. 3, sign corrected
    # Why the sign must be wrong in print: with it, the norm of q would drift.
    d_norm2_printed = 2 * (q0 * dq[:, 0] + (qv * eq3_printed).sum(-1))
    torch.testing.assert_close(d_norm2_printed, -2 * q0 * (qv * w).sum(-1), rtol=1e-12, atol=1e-15)
    assert d_norm2_printed.abs().max() > 0.1
    torch.testing.assert_close((q * dq).sum(-1), torch.zeros(5, dtype=w.dtype), rtol=0, atol=1e-15)


def test_derivative_is_half_q_times_omega():
    rng = np.random.default_rng(2)
    q = rand_q(rng)
    w = torch.tensor(rng.normal(size=(5, 3)))
    pure = torch.cat((torch.zeros(5, 1, dtype=w.dtype), w), -1)
    torch.testing.assert_close(quat.derivative(q, w), 0.5 * quat.multiply(q, pure), rtol=0, atol=1e-15)


def test_random_axes_are_unit_and_isotropic():
    v = quat.random_axes(np.random.default_rng(3), 20000)
    assert np.allclose(np.linalg.norm(v, axis=1), 1.0)
    assert np.all(np.abs(v.mean(axis=0)) < 0.02)
