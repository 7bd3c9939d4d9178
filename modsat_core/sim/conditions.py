"""Flying a controller under flight conditions (:mod:`modsat_core.spec.evaluation`), row by row.

The simulator flies the true satellite; :class:`Flight` stands between it and the controller:

- the controller sees a *measured* state: the attitude turned by a small random rotation (a
  body-frame rotation vector with the row's std per axis, drawn every control step) and the body
  rate plus Gaussian noise; wheel momentum is measured exactly;
- it believes the *model* inertia (the design's), while the simulator flies the true one
  (``inertia_scale`` times the model's, its principal axes turned by ``inertia_rotation_deg``);
- its command reaches the wheels ``delay_steps`` control steps late (zero torque before the first
  command arrives), clipped to the wheel units' box and scaled by ``torque_fraction``.

The initial tumble and the disturbance torque change the slew's draw (:func:`perturb`). With
no row perturbed, :meth:`Flight.act` is ``controller(sim)`` itself. Everything is torch and
differentiable, so the first-order learner trains through it (domain randomisation).
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, fields, replace
from typing import Any

import numpy as np
import torch
from torch import Tensor

from modsat_core.sim import dynamics as dyn
from modsat_core.sim import quaternion as quat
from modsat_core.sim.mission import EpisodeDraw
from modsat_core.sim.slew import SlewSim
from modsat_core.spec.evaluation import Condition, Randomise


@dataclass(frozen=True)
class RowConditions:
    """The conditions of ``n`` rows, numpy (n,) each, in SI units."""

    attitude_noise_rad: np.ndarray
    rate_noise_rad_s: np.ndarray
    delay_steps: np.ndarray  # int
    inertia_scale: np.ndarray
    inertia_rotation_rad: np.ndarray
    torque_fraction: np.ndarray
    tumble_rad_s: np.ndarray
    disturbance_Nm: np.ndarray

    @classmethod
    def of(cls, conditions: list[Condition]) -> RowConditions:
        """One row per condition."""

        def col(f):
            return np.array([f(c) for c in conditions], dtype=np.float64)

        return cls(
            attitude_noise_rad=col(lambda c: c.attitude_noise_deg * quat.DEG),
            rate_noise_rad_s=col(lambda c: c.rate_noise_rad_s),
            delay_steps=np.array([c.delay_steps for c in conditions], dtype=np.int64),
            inertia_scale=col(lambda c: c.inertia_scale),
            inertia_rotation_rad=col(lambda c: c.inertia_rotation_deg * quat.DEG),
            torque_fraction=col(lambda c: c.torque_fraction),
            tumble_rad_s=col(lambda c: c.tumble_rad_s),
            disturbance_Nm=col(lambda c: c.disturbance_Nm),
        )

    @classmethod
    def drawn(cls, r: Randomise, rng: np.random.Generator, n: int) -> RowConditions:
        """``n`` rows drawn uniformly between nominal and ``r`` (domain randomisation), in a fixed
        order of draws."""
        u = rng.uniform(size=(7, n))
        return cls(
            attitude_noise_rad=u[0] * r.attitude_noise_deg * quat.DEG,
            rate_noise_rad_s=u[1] * r.rate_noise_rad_s,
            delay_steps=rng.integers(0, r.delay_steps + 1, size=n),
            inertia_scale=min(r.inertia_scale, 1 / r.inertia_scale) + u[2] * abs(r.inertia_scale - 1 / r.inertia_scale),
            inertia_rotation_rad=u[3] * r.inertia_rotation_deg * quat.DEG,
            torque_fraction=1.0 - u[4] * (1.0 - r.torque_fraction),
            tumble_rad_s=u[5] * r.tumble_rad_s,
            disturbance_Nm=u[6] * r.disturbance_Nm,
        )

    def take(self, idx: np.ndarray) -> RowConditions:
        return RowConditions(**{f.name: getattr(self, f.name)[idx] for f in fields(self)})


@dataclass(frozen=True)
class Axes:
    """The random directions of ``n`` rows' conditions, (n, 3) unit vectors each."""

    inertia: np.ndarray
    tumble: np.ndarray
    disturbance: np.ndarray

    @classmethod
    def draw(cls, rng: np.random.Generator, n: int) -> Axes:
        return cls(*(quat.random_axes(rng, n) for _ in range(3)))


def true_inertia(I_model: np.ndarray, rows: RowConditions, axes: Axes) -> np.ndarray:
    """(n, 3, 3): ``s R I R^T``, the model inertia scaled and its axes turned about ``axes.inertia``."""
    q = quat.axis_angle_np(axes.inertia, rows.inertia_rotation_rad)
    R = quat.to_matrix(torch.from_numpy(q)).numpy()
    return rows.inertia_scale[:, None, None] * (R @ I_model @ np.swapaxes(R, -1, -2))


def perturb(
    I_model: np.ndarray, draws: list[EpisodeDraw], rows: RowConditions, axes: Axes
) -> tuple[np.ndarray, list[EpisodeDraw]]:
    """What rows flown under ``rows`` really are: their true inertia (:func:`true_inertia`) and their
    slews ``draws`` starting with the tumble about ``axes.tumble`` and with the disturbance torque
    about ``axes.disturbance`` added to their own."""
    out = [
        replace(
            d,
            omega_B=d.omega_B + rows.tumble_rad_s[k] * axes.tumble[k],
            tau_residual_B=d.tau_residual_B + rows.disturbance_Nm[k] * axes.disturbance[k],
        )
        for k, d in enumerate(draws)
    ]
    return true_inertia(I_model, rows, axes), out


def _small_rotation(v: Tensor) -> Tensor:
    """The unit quaternion (..., 4) of the rotation vector ``v`` (..., 3)."""
    angle = v.norm(dim=-1, keepdim=True)
    half = 0.5 * angle
    # sin(x/2)/x -> 1/2 at 0: the rotation of a zero vector is the identity, with no NaN
    k = torch.where(angle > 1e-12, torch.sin(half) / angle.clamp(min=1e-12), torch.full_like(angle, 0.5))
    return torch.cat((torch.cos(half), k * v), dim=-1)


class Flight:
    """A :class:`SlewSim` whose rows fly under conditions; see the module docstring.

    ``max_delay``: the most control steps of delay any row will have (the command history kept).
    ``seed``: the measurement noise's stream (a torch generator of its own, so that two controllers
    flown with the same seed meet the same noise)."""

    def __init__(self, sim: SlewSim, max_delay: int = 0, seed: int = 0):
        self.sim = sim
        B, K = sim.B, sim.K
        kw: dict[str, Any] = dict(dtype=sim.dtype, device=sim.device)
        self.I_model: Tensor | None = None  # None: the controller knows the inertia the sim flies
        self.attitude_noise = torch.zeros(B, **kw)
        self.rate_noise = torch.zeros(B, **kw)
        self.delay = torch.zeros(B, dtype=torch.long, device=sim.device)
        self.fraction = torch.ones(B, **kw)
        self.history = torch.zeros(max_delay, B, K, 3, **kw)
        self.generator = torch.Generator(device=sim.device)
        self.generator.manual_seed(seed)
        self._model: tuple[dyn.Plant, dyn.Plant] | None = None  # (the sim's plant, the model's)
        self.noisy = self.weakened = False

    # ------------------------------------------------------------------ rows
    def set_rows(self, idx: Tensor, rows: RowConditions, I_model: Tensor | None = None) -> None:
        """Rows ``idx`` fly under ``rows`` from now on; the model inertia is ``I_model`` (b, 3, 3) or,
        if None, the sim's current one for those rows (the sim must already fly the true inertia)."""
        kw: dict[str, Any] = dict(dtype=self.sim.dtype, device=self.sim.device)
        idx = idx.to(self.sim.device)
        if I_model is None:
            I_model = self.sim.plant.I_B[idx]
        base = self.sim.plant.I_B if self.I_model is None else self.I_model
        self.I_model = _put(base.detach(), idx, I_model.to(**kw))
        self.attitude_noise = _put(self.attitude_noise, idx, torch.as_tensor(rows.attitude_noise_rad, **kw))
        self.rate_noise = _put(self.rate_noise, idx, torch.as_tensor(rows.rate_noise_rad_s, **kw))
        delay = torch.as_tensor(rows.delay_steps, dtype=torch.long, device=self.sim.device)
        if delay.numel() and int(delay.max()) > self.history.shape[0]:
            raise ValueError(f"a delay of {int(delay.max())} steps; this flight keeps {self.history.shape[0]}")
        self.delay = _put(self.delay, idx, delay)
        self.fraction = _put(self.fraction, idx, torch.as_tensor(rows.torque_fraction, **kw))
        self._flags()

    def randomise(
        self, idx: Tensor, r: Randomise, rng: np.random.Generator, I_model: np.ndarray, draws: list[EpisodeDraw]
    ) -> list[EpisodeDraw]:
        """Rows ``idx``, about to start the slews ``draws`` on designs of inertia ``I_model`` (b, 3, 3),
        fly under conditions drawn from ``r`` with ``rng`` (domain randomisation): the sim flies their
        true inertia (on its current wheel units), the controller knows ``I_model``. Returns the draws
        with the tumble and the disturbance (the caller resets the sim on them)."""
        n = len(idx)
        rows, axes = RowConditions.drawn(r, rng, n), Axes.draw(rng, n)
        I_true, draws = perturb(I_model, draws, rows, axes)
        dev = self.sim.device
        self.sim.set_plants(idx.to(dev), torch.as_tensor(I_true).to(dev), self.sim.plant.actuator_mask[idx.to(dev)])
        self.set_rows(idx, rows, torch.as_tensor(I_model))
        return draws

    def _flags(self) -> None:
        self._model = None
        self.noisy = bool((self.attitude_noise > 0).any() or (self.rate_noise > 0).any())
        self.weakened = bool((self.fraction < 1.0).any())

    def grow_slots(self, K: int) -> None:
        """The sim's wheel-unit slots grown to ``K`` (:meth:`SlewSim.grow_slots`), no command on its way
        to the new ones."""
        pad = K - self.sim.K
        if pad <= 0:
            return
        self.sim.grow_slots(K)
        h = self.history
        self.history = torch.cat([h, h.new_zeros(h.shape[0], h.shape[1], pad, 3)], dim=2)
        self._model = None

    def reset_rows(self, idx: Tensor) -> None:
        """New slews on rows ``idx``: no command is on its way to their wheels."""
        if self.history.shape[0]:
            h = self.history.clone()
            h[:, idx.to(self.sim.device)] = 0.0
            self.history = h

    # ------------------------------------------------------------------ what the controller sees
    def model_plant(self) -> dyn.Plant:
        """The sim's plant with the inertia the controller believes."""
        plant = self.sim.plant
        if self.I_model is None:
            return plant
        if self._model is None or self._model[0] is not plant:
            same = bool(torch.equal(self.I_model, plant.I_B))
            model = plant if same else replace(plant, I_B=self.I_model, I_B_inv=torch.linalg.inv(self.I_model))
            self._model = (plant, model)
        return self._model[1]

    def view(self, measured: bool = True) -> SlewSim:
        """The sim as the controller sees it: measured state (``measured``: a fresh draw of the noise;
        else the true state), model inertia; the sim itself when neither differs."""
        plant = self.model_plant()
        noisy = self.noisy and measured
        if plant is self.sim.plant and not noisy:
            return self.sim
        view = copy.copy(self.sim)
        view.plant = plant
        if noisy:
            st = self.sim.state
            B, dt = self.sim.B, self.sim.dtype
            g = self.generator
            e_att = torch.randn(B, 3, generator=g, dtype=dt, device=self.sim.device) * self.attitude_noise[:, None]
            e_rate = torch.randn(B, 3, generator=g, dtype=dt, device=self.sim.device) * self.rate_noise[:, None]
            q_meas = quat.multiply(st.q_BN, _small_rotation(e_att))
            view.state = dyn.State(q_meas, st.omega_B + e_rate, st.h_B, st.t_s)
        return view

    # ------------------------------------------------------------------ what reaches the wheels
    def act(self, controller) -> Tensor:
        """The action (B, K, 3) the wheels get this step from ``controller(view) -> command``."""
        return self.apply(controller(self.view()))

    def apply(self, a: Tensor) -> Tensor:
        """What reaches the wheels of the command ``a`` (B, K, 3) given now: a delayed row gets the
        command of ``delay`` steps ago, a weakened one its fraction of it."""
        if self.history.shape[0]:
            past = torch.cat(
                (a.to(self.history.dtype).unsqueeze(0), self.history), dim=0
            )  # past[d]: commanded d steps ago
            a = past[self.delay, torch.arange(self.sim.B, device=self.sim.device)]
            self.history = past[:-1]
        if self.weakened:
            a = a.to(self.sim.dtype).clamp(-1.0, 1.0) * self.fraction[:, None, None]
        return a

    def step(self, controller):
        """One control step of the sim with ``controller`` in the loop under the rows' conditions."""
        return self.sim.step(self.act(controller))

    # ------------------------------------------------------------------ the first-order learner
    def detach(self) -> None:
        self.sim.detach()
        self.history = self.history.detach()

    def state_dict(self) -> dict:
        """What :meth:`load_state_dict` needs (with the sim's :meth:`~SlewSim.flight_state`) to go on
        exactly: the rows' conditions, the commands on their way, the noise stream and the true inertia."""
        return {
            "I_true": self.sim.plant.I_B.detach().cpu().clone(),
            "I_model": None if self.I_model is None else self.I_model.detach().cpu().clone(),
            "attitude_noise": self.attitude_noise.cpu().clone(),
            "rate_noise": self.rate_noise.cpu().clone(),
            "delay": self.delay.cpu().clone(),
            "fraction": self.fraction.cpu().clone(),
            "history": self.history.detach().cpu().clone(),
            "generator": self.generator.get_state(),
        }

    def load_state_dict(self, d: dict) -> None:
        kw: dict[str, Any] = dict(dtype=self.sim.dtype, device=self.sim.device)
        p = self.sim.plant
        self.sim.set_plants(torch.arange(self.sim.B, device=self.sim.device), d["I_true"].to(**kw), p.actuator_mask)
        self.I_model = None if d["I_model"] is None else d["I_model"].to(**kw)
        self.attitude_noise, self.rate_noise = d["attitude_noise"].to(**kw), d["rate_noise"].to(**kw)
        self.delay = d["delay"].to(self.sim.device)
        self.fraction = d["fraction"].to(**kw)
        self.history = d["history"].to(**kw)
        self.generator.set_state(d["generator"])
        self._flags()


def _put(x: Tensor, idx: Tensor, value: Tensor) -> Tensor:
    out = x.clone()
    out[idx] = value
    return out


def max_delay(conditions: list[Condition]) -> int:
    return max((c.delay_steps for c in conditions), default=0)


def condition_mission_range(mission, c: Condition):
    """The mission whose slews condition ``c`` draws (its slew range, else the mission's)."""
    lo = mission.slew_min_deg if c.slew_min_deg is None else c.slew_min_deg
    hi = mission.slew_max_deg if c.slew_max_deg is None else c.slew_max_deg
    if (lo, hi) == (mission.slew_min_deg, mission.slew_max_deg):
        return mission
    if lo > hi:
        raise ValueError(f"condition {c.name!r}: slews {lo}-{hi} deg are an empty range")
    return mission.model_copy(update={"slew_min_deg": lo, "slew_max_deg": hi})
