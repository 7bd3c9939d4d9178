"""Attitude dynamics against conservation laws, an independent integrator and formulas."""

import math

import numpy as np
import pytest
import torch
from scipy.integrate import solve_ivp

from modsat_core.bench.sim import NumpySatellite
from modsat_core.sim import dynamics as dyn
from modsat_core.sim import quaternion as quat

from .conftest import asymmetric_inertia, make_plant, make_state

DT, SKIP, STEPS = 1 / 240, 20, 500  # the paper's integration settings: one episode


def run(state, plant, tau_cmd, steps=STEPS):
    for _ in range(steps):
        state, _ = dyn.control_step(state, plant, tau_cmd, DT, SKIP)
    return state


def test_torque_free_conserves_momentum_and_energy_and_matches_solve_ivp():
    I = asymmetric_inertia()
    q0 = np.array([0.9, 0.1, -0.3, 0.2])
    q0 /= np.linalg.norm(q0)
    w0 = np.array([0.1, -0.08, 0.12])
    plant = make_plant(I, wheels=False)
    s0 = make_state(q0, w0)
    s1 = run(s0, plant, torch.zeros(1, 1, 3, dtype=torch.float64))
    H0, H1 = dyn.angular_momentum_N(s0, plant)[0], dyn.angular_momentum_N(s1, plant)[0]
    E0, E1 = dyn.kinetic_energy(s0, plant)[0], dyn.kinetic_energy(s1, plant)[0]
    assert ((H1 - H0).norm() / H0.norm()).item() < 1e-9
    assert abs((E1 - E0) / E0).item() < 1e-9

    I_inv = np.linalg.inv(I)

    def f(t, y):
        q, w = y[:4], y[4:]
        qd = 0.5 * NumpySatellite.qmul(q, np.concatenate(([0.0], w)))
        return np.concatenate((qd, I_inv @ (-np.cross(w, I @ w))))

    T = STEPS * SKIP * DT
    sol = solve_ivp(f, (0, T), np.concatenate((q0, w0)), method="DOP853", rtol=1e-13, atol=1e-15)
    q_ref = sol.y[:4, -1] / np.linalg.norm(sol.y[:4, -1])
    q_err = quat.multiply(quat.conjugate(torch.tensor(q_ref)), s1.q_BN[0])
    assert quat.error_angle(q_err).item() < 1e-8
    assert np.abs(s1.omega_B[0].numpy() - sol.y[4:, -1]).max() < 1e-9


def test_ideal_mode_is_paper_eq_5():
    """I w' + w x I w = M_c + M_d, with the torque applied directly (no wheel state)."""
    I = asymmetric_inertia()
    plant = make_plant(I, wheels=False, K=2, tau_res=(1e-3, -2e-3, 5e-4))
    s = make_state([1.0, 0, 0, 0], [0.05, 0.02, -0.04], K=2)
    tau_cmd = torch.tensor([[[0.2, -0.1, 0.3], [0.9, 0.0, -1.2]]], dtype=torch.float64)  # 2nd unit clips
    M_c = np.array([0.2 + 0.8, -0.1, 0.3 - 0.8])
    w = s.omega_B[0].numpy()
    wdot = np.linalg.solve(I, M_c + np.array([1e-3, -2e-3, 5e-4]) - np.cross(w, I @ w))
    eps = 1e-6
    s1, tau_c = dyn.physics_step(s, plant, tau_cmd, eps)
    np.testing.assert_allclose(tau_c[0].numpy(), M_c, rtol=1e-12)
    np.testing.assert_allclose((s1.omega_B[0].numpy() - w) / eps, wdot, rtol=1e-5)
    assert torch.all(s1.h_B == 0)


def test_wheels_conserve_total_momentum_under_arbitrary_commands():
    I = asymmetric_inertia()
    plant = make_plant(I, K=3, wheels=True)
    s = make_state([1.0, 0, 0, 0], [0.02, -0.01, 0.03], K=3)
    H0 = dyn.angular_momentum_N(s, plant)[0]
    rng = np.random.default_rng(0)
    for _ in range(STEPS):
        # Units 0 and 1 fight each other (large wheel momenta), unit 2 and the mismatch move
        # the body at realistic rates.
        r = rng.uniform(-1, 1, size=3)
        cmd = np.stack([r, -r + rng.uniform(-0.03, 0.03, 3), rng.uniform(-0.03, 0.03, 3)])
        s, _ = dyn.control_step(s, plant, torch.tensor(cmd).unsqueeze(0), DT, SKIP)
    H1 = dyn.angular_momentum_N(s, plant)[0]
    assert s.h_B.abs().max() > 0.5  # the wheels really took up momentum
    assert s.omega_B.abs().max() > 0.02
    assert (H1 - H0).norm().item() < 1e-12 * s.h_B.abs().max().item()


def test_wheel_at_capacity_stops_accelerating_and_momentum_stays_conserved():
    I = np.eye(3) * 0.405
    h_max = 0.05
    plant = make_plant(I, K=2, wheels=True, h_max=h_max)
    s = make_state([1.0, 0, 0, 0], [0.0, 0.0, 0.0], K=2)
    # Unit 0 pushes the body about +x (its wheel goes to -x); unit 1 pushes about -y.
    cmd = torch.tensor([[[0.5, 0.0, 0.0], [0.0, -0.2, 0.0]]], dtype=torch.float64)
    H0 = dyn.angular_momentum_N(s, plant)[0]
    history = []
    for _ in range(12):  # 1 s: unit 0 saturates after 0.1 s, unit 1 after 0.25 s
        s, tau_c = dyn.control_step(s, plant, cmd, DT, SKIP)
        history.append((s.h_B[0].clone(), s.omega_B[0].clone(), tau_c[0].clone()))
    h, w, tau_c = history[-1]
    assert h[0, 0].item() == pytest.approx(-h_max, abs=1e-15)
    assert h[1, 1].item() == pytest.approx(h_max, abs=1e-15)
    assert torch.all(h.abs() <= h_max + 1e-15)
    # Saturated: no more torque, the body rate stops changing.
    assert tau_c.abs().max().item() < 1e-15
    torch.testing.assert_close(history[-2][1], w, rtol=0, atol=1e-15)
    np.testing.assert_allclose(w.numpy(), [h_max / 0.405, -h_max / 0.405, 0.0], atol=1e-9)
    assert (dyn.angular_momentum_N(s, plant)[0] - H0).norm().item() < 1e-14
    # Reversing the command drains the wheel again.
    s, tau_c = dyn.control_step(s, plant, -cmd, DT, SKIP)
    assert s.h_B[0, 0, 0].item() > -h_max + 0.01


def test_gravity_gradient_zero_for_cube_symmetric_body():
    n = dyn.mean_motion_rad_s(500.0)
    rng = np.random.default_rng(1)
    q = quat.normalize(torch.tensor(rng.normal(size=(50, 4))))
    I = torch.eye(3, dtype=torch.float64).expand(50, 3, 3) * 0.405
    tau = dyn.gravity_gradient_B(q, I, torch.tensor(rng.uniform(0, 5000, 50)), n, torch.zeros(50, dtype=torch.float64))
    assert tau.abs().max().item() < 1e-20


def test_gravity_gradient_matches_formula_for_elongated_body():
    # A 5-module rod along body x: I_axial = 5 m a^2/6, I_transverse = that + m a^2 (4+1+0+1+4).
    from modsat_core.sim.morphology import mass_properties

    g = np.zeros((5, 5, 5), dtype=int)
    g[:, 2, 2] = 1
    g[2, 2, 2] = 2
    I = mass_properties(g).inertia_B_kgm2
    I_a, I_t = 5 * 0.01 / 6, 5 * 0.01 / 6 + 0.01 * 10
    np.testing.assert_allclose(np.diag(I), [I_a, I_t, I_t], rtol=1e-12)
    n = dyn.mean_motion_rad_s(500.0)
    assert n == pytest.approx(math.sqrt(3.986004418e14 / (6878.1363e3) ** 3))
    # Radial direction = N x at t=0, phase 0. Rotate the rod by theta about N z (in the orbit
    # plane): classic result |tau| = 3/2 n^2 (I_t - I_a) sin(2 theta), about the orbit normal.
    for theta in (0.0, 0.3, math.pi / 4, 1.2):
        q = quat.from_axis_angle(
            torch.tensor([[0.0, 0.0, 1.0]], dtype=torch.float64), torch.tensor([theta], dtype=torch.float64)
        )
        tau = dyn.gravity_gradient_B(
            q, torch.tensor(I).unsqueeze(0), torch.zeros(1, dtype=torch.float64), n, torch.zeros(1, dtype=torch.float64)
        )[0]
        expected = 1.5 * n**2 * (I_t - I_a) * math.sin(2 * theta)
        assert tau[2].item() == pytest.approx(-expected, abs=1e-18)  # restoring: pulls the rod to radial
        assert abs(tau[0].item()) < 1e-20 and abs(tau[1].item()) < 1e-20
    # And the body-frame formula 3 n^2 r x (I r) at a random attitude and time, in numpy.
    rng = np.random.default_rng(2)
    q = quat.normalize(torch.tensor(rng.normal(size=(1, 4))))
    t, phase = 1234.5, 0.7
    tau = dyn.gravity_gradient_B(
        q,
        torch.tensor(I).unsqueeze(0),
        torch.tensor([t], dtype=torch.float64),
        n,
        torch.tensor([phase], dtype=torch.float64),
    )[0]
    u = n * t + phase
    r_B = NumpySatellite.dcm(q[0].numpy()).T @ np.array([math.cos(u), math.sin(u), 0.0])
    np.testing.assert_allclose(tau.numpy(), 3 * n**2 * np.cross(r_B, I @ r_B), rtol=1e-12, atol=1e-22)


def test_batched_torch_matches_independent_numpy_implementation():
    """Full model (wheels, gravity gradient, residual torque) vs the numpy reference."""
    I = asymmetric_inertia()
    n = dyn.mean_motion_rad_s(500.0)
    res = np.array([1e-4, -2e-4, 5e-5])
    plant = make_plant(np.stack([I, I]), wheels=True, n=n, tau_res=tuple(res), phase=0.4)
    q0 = np.array([0.8, 0.2, -0.4, 0.4])
    q0 /= np.linalg.norm(q0)
    s = make_state(np.stack([q0, q0]), np.array([[0.05, -0.02, 0.01]] * 2))
    sat = NumpySatellite(I, n, 0.4, res)
    q, w, h, t = q0.copy(), np.array([0.05, -0.02, 0.01]), np.zeros(3), 0.0
    rng = np.random.default_rng(3)
    for _ in range(40):
        cmd = rng.uniform(-0.5, 0.5, size=3)
        s, _ = dyn.control_step(s, plant, torch.tensor(cmd).reshape(1, 1, 3).expand(2, 1, 3), DT, SKIP)
        for _ in range(SKIP):
            q, w, h = sat.rk4(t, q, w, h, cmd, DT)
            t += DT
    np.testing.assert_allclose(s.q_BN[0].numpy(), q, atol=1e-12)
    np.testing.assert_allclose(s.omega_B[1].numpy(), w, atol=1e-12)
    np.testing.assert_allclose(s.h_B[0].sum(0).numpy(), h, atol=1e-12)


def test_float32_default_and_float64_agree_to_float32_precision():
    I = asymmetric_inertia()
    out = {}
    for dt in (torch.float32, torch.float64):
        plant = make_plant(I, wheels=True, dtype=dt)
        s = make_state([1.0, 0, 0, 0], [0.1, 0.0, -0.1], dtype=dt)
        s = run(s, plant, torch.full((1, 1, 3), 0.01, dtype=dt), steps=50)
        out[dt] = s.q_BN[0].double()
    assert (out[torch.float32] - out[torch.float64]).abs().max().item() < 1e-5


@pytest.mark.slow  # compiles the RK4 step (inductor, forward only): a minute or more on a busy 2-core CPU
def test_the_compiled_physics_step_flies_as_the_eager_one():
    """``diffsim.compiled``'s fused step flies the same slew as :func:`physics_step`, to float32 rounding,
    with gravity gradient and the wheels reaching their capacity on the way. Inductor compiles the
    backward pass too (what training runs); it is not compared here, since compiling it would double this
    test's minutes: `modsat bench sim --compiled`'s window rows run it."""
    I = asymmetric_inertia()
    plant = make_plant(I, wheels=True, h_max=1e-3, n=1.1e-3, phase=0.3, dtype=torch.float32)
    tau = torch.tensor([[[0.02, -0.01, 0.015]]])
    out = {}
    with torch.no_grad():
        for name, step in (("eager", dyn.physics_step), ("compiled", dyn.compiled_physics_step())):
            s = make_state([1.0, 0, 0, 0], [0.1, 0.0, -0.1], dtype=torch.float32)
            for _ in range(5):
                s, _ = dyn.control_step(s, plant, tau, DT, 4, step)
            out[name] = (s.q_BN, s.omega_B, s.h_B)
    assert out["eager"][2].abs().max() == pytest.approx(1e-3)  # a wheel at its capacity
    for eager, compiled in zip(out["eager"], out["compiled"], strict=True):
        assert torch.allclose(eager, compiled, rtol=1e-4, atol=1e-6)


def test_without_a_cxx_compiler_the_compiled_step_is_the_eager_one(monkeypatch):
    """Inductor builds C++ kernels: where no compiler is found, a run asking for the fused step flies the
    eager one (with a warning) instead of failing at its first step."""
    monkeypatch.setattr(dyn, "_COMPILED", None)
    monkeypatch.setattr(dyn.shutil, "which", lambda _name: None)
    with pytest.warns(UserWarning, match="no C\\+\\+ compiler"):
        assert dyn.compiled_physics_step() is dyn.physics_step
    assert dyn._COMPILED is None
