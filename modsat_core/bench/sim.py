"""Simulator benchmark: batched torch simulator vs a one-satellite numpy implementation.

The numpy reference is written the way a single gym env usually is: one satellite,
plain arrays, the same equations (RK4, reaction wheels, gravity gradient) and the same
frame-skip. It is also an independent implementation that the tests compare against.
"""

from __future__ import annotations

import math
import platform
import time

import numpy as np
import torch

from modsat_core.sim.dynamics import mean_motion_rad_s
from modsat_core.sim.gym_envs import reference_design
from modsat_core.sim.mission import draw_episode
from modsat_core.sim.slew import Design, SlewSim
from modsat_core.spec.jobspec import JobSpec


class NumpySatellite:
    """One satellite, numpy float64: state q_BN (4,), omega_B (3,), h_B (3,) total wheel momentum."""

    def __init__(self, I_B: np.ndarray, n_rad_s: float, phase_rad: float, tau_res_B: np.ndarray):
        self.I = np.asarray(I_B, dtype=np.float64)
        self.I_inv = np.linalg.inv(self.I)
        self.n, self.phase, self.tau_res = n_rad_s, phase_rad, np.asarray(tau_res_B, dtype=np.float64)

    @staticmethod
    def qmul(p, q):
        pw, pv, qw, qv = p[0], p[1:], q[0], q[1:]
        return np.concatenate(([pw * qw - pv @ qv], pw * qv + qw * pv + np.cross(pv, qv)))

    def deriv(self, t, q, w, h, tau_c):
        qdot = 0.5 * self.qmul(q, np.concatenate(([0.0], w)))
        tau = tau_c - np.cross(w, self.I @ w + h) + self.tau_res
        if self.n > 0:
            u = self.n * t + self.phase
            r_N = np.array([math.cos(u), math.sin(u), 0.0])
            C_BN = self.dcm(q).T
            r_B = C_BN @ r_N
            tau = tau + 3 * self.n**2 * np.cross(r_B, self.I @ r_B)
        return qdot, self.I_inv @ tau

    @staticmethod
    def dcm(q):
        w, x, y, z = q
        return np.array(
            [
                [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
            ]
        )

    def rk4(self, t, q, w, h, tau_c, dt):
        """One step with constant body torque ``tau_c`` taken from the wheels (h' = -tau_c)."""
        u = -tau_c
        k1q, k1w = self.deriv(t, q, w, h, tau_c)
        k2q, k2w = self.deriv(t + dt / 2, q + dt / 2 * k1q, w + dt / 2 * k1w, h + dt / 2 * u, tau_c)
        k3q, k3w = self.deriv(t + dt / 2, q + dt / 2 * k2q, w + dt / 2 * k2w, h + dt / 2 * u, tau_c)
        k4q, k4w = self.deriv(t + dt, q + dt * k3q, w + dt * k3w, h + dt * u, tau_c)
        q = q + dt / 6 * (k1q + 2 * k2q + 2 * k3q + k4q)
        w = w + dt / 6 * (k1w + 2 * k2w + 2 * k3w + k4w)
        return q / np.linalg.norm(q), w, h + dt * u


def _rate(fn, min_seconds: float) -> tuple[int, float]:
    fn()  # warm-up
    n, t0 = 0, time.perf_counter()
    while True:
        fn()
        n += 1
        elapsed = time.perf_counter() - t0
        if elapsed >= min_seconds:
            return n, elapsed


#: Wheel-unit slots timed at batch 256 (``slots_K`` rows): a co-design run's simulator holds as many slots
#: as the largest design it flies; sized for every free cell of a 10x10x10 grid it held 900.
SLOT_COUNTS = (8, 32, 128, 900)


#: Control steps of one ``compiled`` window row: a first-order training window, the cost of its steps
#: backpropagated (``diffsim.window_steps``' default is 32; fewer keep the bench short).
WINDOW_STEPS = 8


def bench_sim(
    batch_sizes=(1, 256, 4096),
    min_seconds: float = 2.0,
    dtype: str = "float32",
    slot_counts=SLOT_COUNTS,
    compiled: bool = False,
) -> dict:
    """Control steps per second of the batched simulator and of the numpy reference; and of the
    simulator at batch 256 with ``slot_counts`` wheel-unit slots, one of them holding a unit (the cost
    of empty slots). With ``compiled``, the physics step fused by ``torch.compile`` beside the eager
    one at batch 256, in the same run: flying (no gradient) and a training window of
    :data:`WINDOW_STEPS` control steps backpropagated (``window_*`` rows); each compiled row's
    ``compile_s`` is its first call, the compilation (inductor caches it on disk for later processes)."""
    spec = JobSpec()
    mission, modules = spec.mission, spec.modules
    design = Design.from_grid(reference_design(3), modules)
    rng = np.random.default_rng(0)
    draw = draw_episode(rng, mission)
    sat = NumpySatellite(
        design.I_B, mean_motion_rad_s(mission.orbit_altitude_km), draw.orbit_phase_rad, draw.tau_residual_B
    )
    tau_c = np.array([0.01, -0.02, 0.015])
    state = {"t": 0.0, "q": draw.q_BN.copy(), "w": np.zeros(3), "h": np.zeros(3)}

    def numpy_control_step():
        t, q, w, h = state["t"], state["q"], state["w"], state["h"]
        for _ in range(mission.frame_skip):
            q, w, h = sat.rk4(t, q, w, h, tau_c, mission.physics_dt_s)
            t += mission.physics_dt_s
        state.update(t=t, q=q, w=w, h=h)

    n, el = _rate(numpy_control_step, min_seconds)
    results = {"numpy_1": {"batch": 1, "control_steps_per_s": n / el}}
    torch_dtype = {"float32": torch.float32, "float64": torch.float64}[dtype]
    for B in batch_sizes:
        sim = SlewSim.from_designs([design] * B, mission, modules, dtype=torch_dtype)
        sim.reset(list(range(B)), [draw] * B)
        action = torch.full((B, sim.K, 3), 0.01, dtype=torch_dtype)
        n, el = _rate(lambda sim=sim, action=action: sim.step(action), min_seconds)
        results[f"torch_{B}"] = {"batch": B, "control_steps_per_s": B * n / el}
    for K in slot_counts:
        B = 256
        mask = np.zeros((B, K), dtype=bool)
        mask[:, 0] = True
        sim = SlewSim(np.stack([design.I_B] * B), mask, mission, modules, dtype=torch_dtype)
        sim.reset(list(range(B)), [draw] * B)
        action = torch.full((B, K, 3), 0.01, dtype=torch_dtype)
        n, el = _rate(lambda sim=sim, action=action: sim.step(action), min_seconds)
        results[f"slots_{K}"] = {"batch": B, "slots": K, "control_steps_per_s": B * n / el}
    if compiled:
        results.update(_compiled_rows(design, draw, mission, modules, torch_dtype, min_seconds))
    base = results["numpy_1"]["control_steps_per_s"]
    for r in results.values():
        r["ratio_to_numpy"] = r["control_steps_per_s"] / base
    for kind in ("fly", "window"):
        if f"{kind}_256_compiled" in results:
            eager, fused = results[f"{kind}_256_eager"], results[f"{kind}_256_compiled"]
            fused["ratio_to_eager"] = fused["control_steps_per_s"] / eager["control_steps_per_s"]
    return {
        "benchmark": "sim",
        "unit": "control steps per second (each = frame_skip RK4 steps)",
        "frame_skip": mission.frame_skip,
        "dtype": dtype,
        "torch": torch.__version__,
        "threads": torch.get_num_threads(),
        "machine": platform.machine(),
        "results": results,
    }


def _compiled_rows(design, draw, mission, modules, dtype, min_seconds: float) -> dict:
    """The ``fly_256_*`` and ``window_256_*`` rows, eager and compiled (:func:`bench_sim`)."""
    B, rows = 256, {}
    for name in ("eager", "compiled"):
        sim = SlewSim.from_designs([design] * B, mission, modules, dtype=dtype, compiled=name == "compiled")
        sim.reset(list(range(B)), [draw] * B)
        action = torch.full((B, sim.K, 3), 0.01, dtype=dtype)

        def fly(sim=sim, action=action):
            with torch.no_grad():
                sim.step(action)

        def window(sim=sim, action=action):
            a = action.clone().requires_grad_(True)
            cost = sum(sim.step(a).phi_rad.sum() for _ in range(WINDOW_STEPS))
            cost.backward()
            sim.detach()

        for kind, fn, steps in (("fly", fly, 1), ("window", window, WINDOW_STEPS)):
            t0 = time.perf_counter()
            fn()
            first = time.perf_counter() - t0
            n, el = _rate(fn, min_seconds)
            row = {"batch": B, "control_steps_per_s": B * steps * n / el, "first_call_s": first}
            if name == "compiled":
                row["compile_s"] = first
            rows[f"{kind}_256_{name}"] = row
    return rows
