"""``modsat verify --basilisk``: fly a run's evaluation slews in Basilisk, closed loop.

A learned controller earns a spacecraft engineer's trust when it flies the same slews in
an independent, trusted simulator and the numbers agree with modsat's own evaluation. This
module builds the run's designed satellite in Basilisk (docs/verification.md), flies the
Monte-Carlo evaluation slews (same seeds, same draws) with the run's exported controller
and with the PD baseline, flies the same slews in modsat's :class:`SlewSim` (float64) with
the same controllers, and reports both side by side with the largest attitude difference
between the two simulators along each slew.

How Basilisk's balanced wheels map onto modsat's equations. Basilisk's ``BalancedWheels``
contribute no mass properties: the hub inertia is the whole spacecraft's, the wheel state is
the speed ``Omega`` relative to the body, and the equations are::

    [I_hub - sum Js g g^T] w' = -w x (I_hub w + sum Js Omega g) - sum u g + L
    Js (Omega' + g . w') = u

With ``h = sum Js (g . w + Omega) g`` (the wheels' absolute spin momentum) and
``I_hub = I + sum Js g g^T`` this is exactly modsat's ``I w' = -w x (I w + h) - u + L``,
``h' = u``, for any ``Js``. Each wheel unit is three wheels along the body axes, so
``sum Js g g^T = n_units Js E``: isotropic, which adds nothing to the gravity-gradient torque
Basilisk computes from ``I_hub``. ``Js`` only matters once a wheel-speed limit or friction
is modelled (they act on ``Omega``).

Basilisk is optional (``pip install -e '.[basilisk]'``) and imported only when flying.
"""

from __future__ import annotations

import math
import os
import warnings
from collections.abc import Callable
from dataclasses import asdict, dataclass

import numpy as np
import torch

from . import dynamics as dyn
from . import quaternion as quat
from .evaluate import episode_rngs
from .mission import EpisodeDraw, draw_episode
from .morphology import ACTUATOR, is_valid, mass_properties
from .pd import PDController
from .slew import Design, SlewSim
from .spec import JobSpec, parse_spec

BASILISK_MISSING = "modsat verify --basilisk needs Basilisk: pip install -e '.[basilisk]'"
#: Default wheel spin inertia (kg m^2). With ideal wheels it changes nothing (see above);
#: with a speed limit it sets the wheel speed a momentum needs (2 N m s at 1,900 RPM).
DEFAULT_WHEEL_INERTIA_KGM2 = 0.01
#: Wheel units per Basilisk wheel effector: its motor-torque message holds 36 wheels.
UNITS_PER_EFFECTOR = 12
#: The success tolerances the report always shows, beside the mission's own.
REPORT_TOLERANCES_DEG = (0.25, 1.0)

#: ``controller_factory(sim) -> controller``; ``controller(sim) -> action (B, K, 3) in [-1, 1]``.
ControllerFactory = Callable[[SlewSim], Callable[[SlewSim], torch.Tensor]]


def basilisk_available() -> bool:
    """Whether the Basilisk modules this verification uses can be imported."""
    try:
        from Basilisk.simulation import (  # noqa: F401
            GravityGradientEffector, extForceTorque, reactionWheelStateEffector, spacecraft,
        )
        from Basilisk.utilities import simIncludeGravBody, simIncludeRW  # noqa: F401
    except ImportError:
        return False
    return True


@dataclass(frozen=True)
class WheelOptions:
    """Basilisk's own wheel limits, beyond what modsat models (all off by default).

    With any of them on, the Basilisk plant differs from modsat's on purpose, so the two
    simulators are no longer expected to agree.
    """

    speed_max_rpm: float | None = None
    coulomb_friction_Nm: float = 0.0
    viscous_friction_Nms: float = 0.0
    inertia_kgm2: float = DEFAULT_WHEEL_INERTIA_KGM2

    def __post_init__(self):
        if self.speed_max_rpm is not None and not (math.isfinite(self.speed_max_rpm) and self.speed_max_rpm > 0):
            raise ValueError(f"--wheel-speed-max must be a positive number of RPM; got {self.speed_max_rpm}")
        for name, v in (("Coulomb friction", self.coulomb_friction_Nm), ("viscous friction", self.viscous_friction_Nms)):
            if not (math.isfinite(v) and v >= 0):
                raise ValueError(f"--wheel-friction: the {name} must be a number >= 0; got {v}")
        if not (math.isfinite(self.inertia_kgm2) and self.inertia_kgm2 > 0):
            raise ValueError(f"--wheel-inertia must be a positive number of kg m^2; got {self.inertia_kgm2}")

    @property
    def ideal(self) -> bool:
        """True when Basilisk's wheels integrate exactly modsat's equations."""
        return self.speed_max_rpm is None and self.coulomb_friction_Nm == 0 and self.viscous_friction_Nms == 0


# ----------------------------------------------------------------------------- the run


@dataclass(frozen=True)
class Run:
    """What verification needs from a run directory."""

    spec: JobSpec
    grid: np.ndarray
    policy: torch.jit.ScriptModule | None
    policy_missing: str | None  # why there is no policy to fly, if there is none


def load_run(run_dir: str) -> Run:
    """Read ``spec.json``, ``design.json`` and (if present) ``policy_export.pt``."""
    import json

    with open(os.path.join(run_dir, "spec.json"), "rb") as fh:
        spec = parse_spec(fh.read())
    with open(os.path.join(run_dir, "design.json"), "rb") as fh:
        grid = np.asarray(json.loads(fh.read())["grid"], dtype=np.int64)
    if not is_valid(grid):
        raise ValueError(f"the design in {run_dir}/design.json is not a valid satellite: nothing to fly")
    path = os.path.join(run_dir, "policy_export.pt")
    if not os.path.exists(path):
        return Run(spec, grid, None, f"no policy_export.pt in {run_dir} (a GA run or an older run): "
                                     "only the PD baseline is verified")
    with warnings.catch_warnings():  # TorchScript's deprecation notice (see policy.export_torchscript)
        warnings.simplefilter("ignore", DeprecationWarning)
        policy = torch.jit.load(path, map_location="cpu")
    return Run(spec, grid, policy.eval(), None)


class ExportedPolicy:
    """The exported TorchScript controller as a :class:`SlewSim` controller.

    Both simulators call it on the same kind of state (a SlewSim holding the state), so the
    policy sees the same inputs in both up to the simulators' differences.
    """

    def __init__(self, module: torch.jit.ScriptModule, tau_max_Nm: float):
        self.module, self.tau_max = module, tau_max_Nm

    def __call__(self, sim: SlewSim) -> torch.Tensor:
        # One row at a time: a float32 network's output can depend on the batch size in the
        # last bit, and Basilisk flies one satellite at a time.
        with torch.no_grad():
            rows = [self.module(sim.error_quaternion()[i:i + 1], sim.state.omega_B[i:i + 1],
                                sim.state.h_B[i:i + 1]) for i in range(sim.B)]
        return torch.cat(rows).to(sim.dtype) / self.tau_max


def policy_factory(module: torch.jit.ScriptModule, tau_max_Nm: float) -> ControllerFactory:
    return lambda sim: ExportedPolicy(module, tau_max_Nm)


def pd_factory(sim: SlewSim) -> PDController:
    return PDController(sim)


def evaluation_draws(spec: JobSpec, episodes: int) -> list[EpisodeDraw]:
    """The slews of modsat's final Monte-Carlo evaluation (same seed, same order)."""
    return [draw_episode(r, spec.mission) for r in episode_rngs(spec.evaluation.seed, episodes)]


def commanded_torque(action: torch.Tensor, sim: SlewSim) -> torch.Tensor:
    """Per-unit body torque command (B, K, 3) N m from an action, as :meth:`SlewSim.step` does."""
    a = action.to(sim.dtype).clamp(-1.0, 1.0) * sim.plant.actuator_mask.unsqueeze(-1)
    return a * sim.plant.tau_max_Nm


# ----------------------------------------------------------------------------- histories


@dataclass
class Flight:
    """One slew as flown: the state after every control step (index 0: the start)."""

    t_s: np.ndarray  # (T+1,)
    q_BN: np.ndarray  # (T+1, 4)
    omega_B: np.ndarray  # (T+1, 3)


def fly_modsat(design: Design, spec: JobSpec, draws: list[EpisodeDraw], factory: ControllerFactory) -> list[Flight]:
    """All slews at once in modsat's simulator (float64); each ends as modsat ends it."""
    m = spec.mission
    B = len(draws)
    sim = SlewSim.from_designs([design] * B, m, spec.modules, dtype=torch.float64)
    sim.reset(list(range(B)), draws)
    controller = factory(sim)
    hist = [(sim.state.t_s.clone(), sim.state.q_BN.clone(), sim.state.omega_B.clone())]
    steps = torch.full((B,), m.episode_steps, dtype=torch.long)
    done = torch.zeros(B, dtype=torch.bool)
    for k in range(1, m.episode_steps + 1):
        with torch.no_grad():
            out = sim.step(controller(sim))
        hist.append((sim.state.t_s.clone(), sim.state.q_BN.clone(), sim.state.omega_B.clone()))
        ended = out.terminated & ~done
        steps[ended] = k
        done |= ended
        if bool(done.all()):
            break
    t, q, w = (torch.stack(x, dim=1).numpy() for x in zip(*hist))
    return [Flight(t[i, : steps[i] + 1], q[i, : steps[i] + 1], w[i, : steps[i] + 1]) for i in range(B)]


# ----------------------------------------------------------------------------- Basilisk


class BasiliskSatellite:
    """The designed satellite in Basilisk, flying one slew, one control period at a time.

    Body frame B: origin at the centre of the grid cell (0, 0, 0), axes along the grid (the
    same axes as modsat's, whose origin is the centre of mass ``r_BcB_B``). Hub: the design's
    mass, centre of mass and full inertia tensor plus ``n_units Js E`` (see the module
    docstring); one Basilisk wheel per body axis per actuator module, in modsat's unit order.
    """

    def __init__(self, spec: JobSpec, grid: np.ndarray, draw: EpisodeDraw, wheels: WheelOptions):
        from Basilisk.architecture import messaging
        from Basilisk.simulation import GravityGradientEffector, extForceTorque, spacecraft
        from Basilisk.utilities import SimulationBaseClass, macros

        self.spec, self.wheels_opt = spec, wheels
        m, mods = spec.mission, spec.modules
        mp = mass_properties(grid, mods.module_mass_kg, mods.module_size_m)
        self.unit_positions = (mp.positions_B_m + mp.com_grid_m)[mp.types == ACTUATOR]  # from B's origin
        self.K = len(self.unit_positions)
        self.has_wheels = mods.actuator_model == "reaction-wheel"
        self.Js = wheels.inertia_kgm2
        self.dt_ns = macros.sec2nano(m.physics_dt_s)
        self.period_ns = self.dt_ns * m.frame_skip
        self.t_ns = 0

        self.sim = SimulationBaseClass.SimBaseClass()
        self.sim.SetProgressBar(False)
        task = "dynamics"
        self.sim.CreateNewProcess("modsat").addTask(self.sim.CreateNewTask(task, self.dt_ns))

        sc = spacecraft.Spacecraft()
        sc.ModelTag = "modsat"
        sc.hub.mHub = float(mp.mass_kg)
        sc.hub.r_BcB_B = np.asarray(mp.com_grid_m, dtype=float).reshape(3, 1).tolist()
        hub_I = np.asarray(mp.inertia_B_kgm2, dtype=float)
        if self.has_wheels:
            hub_I = hub_I + self.K * self.Js * np.eye(3)
        sc.hub.IHubPntBc_B = hub_I.tolist()
        sc.hub.sigma_BNInit = _ep_to_mrp(draw.q_BN).reshape(3, 1).tolist()
        sc.hub.omega_BN_BInit = np.asarray(draw.omega_B, dtype=float).reshape(3, 1).tolist()
        r_N, v_N = circular_orbit(m.orbit_altitude_km, draw.orbit_phase_rad)
        sc.hub.r_CN_NInit = r_N.reshape(3, 1).tolist()
        sc.hub.v_CN_NInit = v_N.reshape(3, 1).tolist()
        self.sim.AddModelToTask(task, sc, 1)
        self.sc = sc

        if m.gravity_gradient:
            earth = self._add_gravity(sc)
            gg = GravityGradientEffector.GravityGradientEffector()
            gg.ModelTag = "gravityGradient"
            gg.addPlanetName(earth.planetName)
            sc.addDynamicEffector(gg)
            self.sim.AddModelToTask(task, gg)

        residual = extForceTorque.ExtForceTorque()
        residual.ModelTag = "residualTorque"
        residual.extTorquePntB_B = np.asarray(draw.tau_residual_B, dtype=float).reshape(3, 1).tolist()
        sc.addDynamicEffector(residual)
        self.sim.AddModelToTask(task, residual)

        self.rw_groups: list[tuple] = []  # (effector, command message, payload, wheel count)
        self.body_torque = None
        if self.has_wheels:
            self._add_wheels(sc, task, draw, messaging)
        else:  # the paper's ideal torque: the command acts on the body directly
            self.body_torque = extForceTorque.ExtForceTorque()
            self.body_torque.ModelTag = "controlTorque"
            sc.addDynamicEffector(self.body_torque)
            self.sim.AddModelToTask(task, self.body_torque)
        self.sim.InitializeSimulation()
        self.h_B = np.zeros((self.K, 3))
        self.q_BN, self.omega_B = np.asarray(draw.q_BN, dtype=float), np.asarray(draw.omega_B, dtype=float)

    def _add_gravity(self, sc):
        """Earth as a point mass at the origin, with modsat's gravitational parameter."""
        from Basilisk.utilities import simIncludeGravBody

        factory = simIncludeGravBody.gravBodyFactory()
        earth = factory.createEarth()
        earth.isCentralBody = True
        earth.mu = dyn.MU_EARTH_M3_S2
        factory.addBodiesTo(sc)
        self._gravity = factory  # keeps the bodies alive as long as the simulation
        return earth

    def _add_wheels(self, sc, task, draw: EpisodeDraw, messaging) -> None:
        """Three balanced wheels per unit (x, y, z), ``UNITS_PER_EFFECTOR`` units per effector,
        each effector with its own motor-torque message and its own wheel-speed state."""
        from Basilisk.simulation import reactionWheelStateEffector
        from Basilisk.utilities import macros, simIncludeRW

        opt, mods = self.wheels_opt, self.spec.modules
        per = UNITS_PER_EFFECTOR
        for g0 in range(0, self.K, per):
            factory = simIncludeRW.rwFactory()
            for k in range(g0, min(g0 + per, self.K)):
                for axis in range(3):
                    kw = dict(RWModel=messaging.BalancedWheels, Js=float(self.Js), u_max=float(mods.torque_scale_Nm),
                              rWB_B=[float(x) for x in self.unit_positions[k]],
                              # Zero absolute wheel momentum at the start: Omega = -g . w.
                              Omega=float(-draw.omega_B[axis] / macros.RPM), label=f"{'xyz'[axis]}{k - g0}")
                    if opt.coulomb_friction_Nm > 0:
                        kw.update(useRWfriction=True, fCoulomb=float(opt.coulomb_friction_Nm))
                    if opt.viscous_friction_Nms > 0:
                        kw["cViscous"] = float(opt.viscous_friction_Nms)
                    rw = factory.create("custom", np.eye(3)[axis].tolist(), **kw)
                    rw.Omega_max = self._omega_max_rad_s()
            effector = reactionWheelStateEffector.ReactionWheelStateEffector()
            effector.nameOfReactionWheelOmegasState = f"reactionWheelOmegas{g0 // per}"  # one state per effector
            effector.nameOfReactionWheelThetasState = f"reactionWheelThetas{g0 // per}"
            factory.addToSpacecraft(f"wheels{g0 // per}", effector, sc)
            self.sim.AddModelToTask(task, effector, 2)  # before the spacecraft: reads the command first
            msg = messaging.ArrayMotorTorqueMsg()
            payload = messaging.ArrayMotorTorqueMsgPayload()
            msg.write(payload)
            effector.rwMotorCmdInMsg.subscribeTo(msg)
            self.rw_groups.append((effector, msg, payload, factory.getNumOfDevices()))

    def _omega_max_rad_s(self) -> float:
        """Basilisk's wheel-speed limit: the option, else the spec's capacity over Js, else none."""
        from Basilisk.utilities import macros

        if self.wheels_opt.speed_max_rpm is not None:
            return self.wheels_opt.speed_max_rpm * macros.RPM
        cap = self.spec.modules.momentum_capacity_Nms
        return cap / self.Js if cap is not None else -1.0

    def step(self, tau_cmd_B: np.ndarray) -> None:
        """Hold the per-unit body torque command (K, 3) for one control period, then read the state."""
        if self.has_wheels:
            u = -np.asarray(tau_cmd_B, dtype=float)  # the motors' torque on the wheels; Basilisk clips to u_max
            per = UNITS_PER_EFFECTOR
            for g, (_, msg, payload, _) in enumerate(self.rw_groups):
                cmd = u[g * per:(g + 1) * per].reshape(-1)
                payload.motorTorque = cmd.tolist() + [0.0] * (36 - len(cmd))
                msg.write(payload, self.t_ns)
        else:
            tau = np.clip(tau_cmd_B, -self.spec.modules.torque_scale_Nm, self.spec.modules.torque_scale_Nm).sum(0)
            self.body_torque.extTorquePntB_B = tau.reshape(3, 1).tolist()
        self.t_ns += self.period_ns
        self.sim.ConfigureStopTime(self.t_ns)
        self.sim.ExecuteSimulation()
        self._read_state()

    def _read_state(self) -> None:
        state = self.sc.scStateOutMsg.read()
        self.q_BN = _mrp_to_ep(np.asarray(state.sigma_BN, dtype=float))
        self.omega_B = np.asarray(state.omega_BN_B, dtype=float)
        if self.has_wheels:
            speeds = []
            for effector, _, _, n in self.rw_groups:
                speeds.extend(list(effector.rwSpeedOutMsg.read().wheelSpeeds)[:n])
            Omega = np.asarray(speeds, dtype=float).reshape(self.K, 3)
            self.h_B = self.Js * (Omega + self.omega_B)  # absolute spin momentum, axis by axis

    @property
    def t_s(self) -> float:
        return self.t_ns * 1e-9


def _mrp_to_ep(sigma: np.ndarray) -> np.ndarray:
    from Basilisk.utilities import RigidBodyKinematics as rbk

    return np.asarray(rbk.MRP2EP(sigma), dtype=float)


def _ep_to_mrp(q: np.ndarray) -> np.ndarray:
    from Basilisk.utilities import RigidBodyKinematics as rbk

    return np.asarray(rbk.EP2MRP(np.asarray(q, dtype=float)), dtype=float)


def circular_orbit(altitude_km: float, phase_rad: float) -> tuple[np.ndarray, np.ndarray]:
    """Position and velocity (N, m and m/s) on modsat's circular orbit in the N x-y plane."""
    r = dyn.R_EARTH_M + altitude_km * 1e3
    v = math.sqrt(dyn.MU_EARTH_M3_S2 / r)
    c, s = math.cos(phase_rad), math.sin(phase_rad)
    return np.array([r * c, r * s, 0.0]), np.array([-v * s, v * c, 0.0])


def fly_basilisk(spec: JobSpec, grid: np.ndarray, draw: EpisodeDraw, factory: ControllerFactory,
                 wheels: WheelOptions) -> Flight:
    """One slew in Basilisk, the controller called at the control rate from the loop.

    The controller sees the Basilisk state through a one-satellite SlewSim that only holds
    it (never steps), so the PD law and the policy run the very code modsat runs.
    """
    m = spec.mission
    sat = BasiliskSatellite(spec, grid, draw, wheels)
    mirror = SlewSim.from_designs([Design.from_grid(grid, spec.modules)], m, spec.modules, dtype=torch.float64)
    mirror.reset([0], [draw])
    controller = factory(mirror)
    t, q, w = [0.0], [sat.q_BN.copy()], [sat.omega_B.copy()]
    for _ in range(m.episode_steps):
        mirror.state = dyn.State(q_BN=torch.from_numpy(sat.q_BN).unsqueeze(0),
                                 omega_B=torch.from_numpy(sat.omega_B).unsqueeze(0),
                                 h_B=torch.from_numpy(sat.h_B).unsqueeze(0), t_s=torch.tensor([sat.t_s]))
        with torch.no_grad():
            tau_cmd = commanded_torque(controller(mirror), mirror)[0].numpy()
        sat.step(tau_cmd)
        t.append(sat.t_s)
        q.append(sat.q_BN.copy())
        w.append(sat.omega_B.copy())
        if np.linalg.norm(sat.omega_B) > m.rate_limit_rad_s:  # a safety violation ends the slew
            break
    return Flight(np.asarray(t), np.asarray(q), np.asarray(w))


# ----------------------------------------------------------------------------- metrics


def _error_angles(q_BN: np.ndarray, q_TN: np.ndarray) -> np.ndarray:
    q_e = quat.multiply(quat.conjugate(torch.from_numpy(np.asarray(q_TN, dtype=float))), torch.from_numpy(q_BN))
    return quat.error_angle(q_e).numpy()


def flight_metrics(f: Flight, q_TN: np.ndarray, spec: JobSpec) -> dict:
    """Metrics of one slew as modsat defines them (docs/physics.md, "Mission, reward, metrics")."""
    m = spec.mission
    phi = _error_angles(f.q_BN, q_TN)
    rate = np.linalg.norm(f.omega_B, axis=1)
    violated = bool(rate[-1] > m.rate_limit_rad_s)
    settled_rate = rate[-1] <= m.rate_tolerance_rad_s and not violated
    tol = m.tolerance_deg * quat.DEG
    out_of_tol = np.flatnonzero(phi[1:] > tol)
    success = bool(phi[-1] <= tol and settled_rate)
    row = {
        "success": success,
        "final_error_deg": float(phi[-1] / quat.DEG),
        "final_rate_rad_s": float(rate[-1]),
        "settling_time_s": (float(f.t_s[out_of_tol[-1] + 1]) if len(out_of_tol) else 0.0) if success else None,
        "peak_rate_rad_s": float(rate[1:].max()) if len(rate) > 1 else 0.0,
        "safety_violation": violated,
        "duration_s": float(f.t_s[-1]),
    }
    for tol_deg in REPORT_TOLERANCES_DEG:
        row[f"success_{_tol_key(tol_deg)}"] = bool(phi[-1] <= tol_deg * quat.DEG and settled_rate)
    return row


def _tol_key(tol_deg: float) -> str:
    return f"{tol_deg:g}".replace(".", "_") + "deg"


def summarize(rows: list[dict]) -> dict:
    """The side-by-side figures of one simulator over all slews."""

    def median(key):
        vals = [r[key] for r in rows if r[key] is not None]
        return float(np.median(vals)) if vals else None

    n = len(rows)
    out = {"success_rate": sum(r["success"] for r in rows) / n}
    for tol_deg in REPORT_TOLERANCES_DEG:
        key = _tol_key(tol_deg)
        out[f"success_rate_{key}"] = sum(r[f"success_{key}"] for r in rows) / n
    out.update({
        "median_final_error_deg": median("final_error_deg"),
        "max_final_error_deg": max(r["final_error_deg"] for r in rows),
        "median_settling_time_s": median("settling_time_s"),
        "max_peak_rate_rad_s": max(r["peak_rate_rad_s"] for r in rows),
        "safety_violations": sum(r["safety_violation"] for r in rows),
    })
    return out


def attitude_difference_rad(a: Flight, b: Flight) -> float:
    """Largest angle of ``q_a^-1 q_b`` over the control steps both slews flew."""
    n = min(len(a.q_BN), len(b.q_BN))
    d = quat.multiply(quat.conjugate(torch.from_numpy(a.q_BN[:n])), torch.from_numpy(b.q_BN[:n]))
    return float(quat.error_angle(d).max())


# ----------------------------------------------------------------------------- report


def compare(spec: JobSpec, grid: np.ndarray, draws: list[EpisodeDraw], factory: ControllerFactory,
            wheels: WheelOptions) -> dict:
    """One controller on the same slews in both simulators, side by side."""
    design = Design.from_grid(grid, spec.modules)
    ours = fly_modsat(design, spec, draws, factory)
    theirs = [fly_basilisk(spec, grid, d, factory, wheels) for d in draws]
    rows_m = [flight_metrics(f, d.q_TN, spec) for f, d in zip(ours, draws)]
    rows_b = [flight_metrics(f, d.q_TN, spec) for f, d in zip(theirs, draws)]
    diffs = [attitude_difference_rad(a, b) for a, b in zip(ours, theirs)]
    return {
        "available": True,
        "modsat": summarize(rows_m),
        "basilisk": summarize(rows_b),
        "max_attitude_difference_rad": max(diffs),
        "median_attitude_difference_rad": float(np.median(diffs)),
        "same_success": [a["success"] for a in rows_m] == [b["success"] for b in rows_b],
        "slews": [{"episode": i, "attitude_difference_rad": d, "modsat": a, "basilisk": b}
                  for i, (d, a, b) in enumerate(zip(diffs, rows_m, rows_b))],
    }


def plant_report(spec: JobSpec, grid: np.ndarray, wheels: WheelOptions) -> dict:
    """What the Basilisk model holds, for the report (docs/verification.md)."""
    from Basilisk.utilities import macros

    m, mods = spec.mission, spec.modules
    mp = mass_properties(grid, mods.module_mass_kg, mods.module_size_m)
    n_units = int((np.asarray(grid) == ACTUATOR).sum())
    has_wheels = mods.actuator_model == "reaction-wheel"
    try:
        from Basilisk import __version__ as bsk_version
    except ImportError:
        bsk_version = None
    return {
        "basilisk_version": bsk_version,
        "integrator": "RK4",
        "physics_dt_s": m.physics_dt_s,
        "basilisk_dt_ns": macros.sec2nano(m.physics_dt_s),
        "frame_skip": m.frame_skip,
        "mass_kg": float(mp.mass_kg),
        "center_of_mass_grid_m": np.asarray(mp.com_grid_m).tolist(),
        "inertia_kgm2": np.asarray(mp.inertia_B_kgm2).tolist(),
        "actuator_model": mods.actuator_model,
        "wheel_units": n_units,
        "wheels": 3 * n_units if has_wheels else 0,
        "wheel_model": "BalancedWheels" if has_wheels else None,
        "hub_inertia_kgm2": (np.asarray(mp.inertia_B_kgm2) + (n_units * wheels.inertia_kgm2 if has_wheels else 0.0)
                             * np.eye(3)).tolist(),
        "torque_limit_Nm": mods.torque_scale_Nm,
        "momentum_capacity_Nms": mods.momentum_capacity_Nms,
        "wheel_options": asdict(wheels) if has_wheels else None,
        "ideal_wheels": wheels.ideal,
        "gravity_gradient": m.gravity_gradient,
        "orbit_altitude_km": m.orbit_altitude_km,
        "mu_m3_s2": dyn.MU_EARTH_M3_S2,
        "residual_torque_Nm": list(m.residual_torque_Nm),
        "residual_torque_std_Nm": m.residual_torque_std_Nm,
    }


def verify_run(run_dir: str, episodes: int | None = None, wheels: WheelOptions | None = None,
               log: Callable[[str], None] | None = None) -> dict:
    """Fly the run's evaluation slews in Basilisk and in modsat; the report ``--json`` prints."""
    wheels = wheels or WheelOptions()
    log = log or (lambda _line: None)
    run = load_run(run_dir)
    spec = run.spec
    if spec.modules.actuator_model != "reaction-wheel" and wheels != WheelOptions():
        raise ValueError("the run's actuator model is ideal-torque: there are no wheels for the wheel options")
    n = episodes or spec.evaluation.episodes
    draws = evaluation_draws(spec, n)
    if run.policy is not None:
        log(f"policy: {n} slews in modsat and in Basilisk")
        policy = compare(spec, run.grid, draws, policy_factory(run.policy, spec.modules.torque_scale_Nm), wheels)
    else:
        policy = {"available": False, "reason": run.policy_missing}
        log(f"policy: {run.policy_missing}")
    log(f"PD baseline: {n} slews in modsat and in Basilisk")
    pd = compare(spec, run.grid, draws, pd_factory, wheels)
    return {
        "episodes": n,
        "seed": spec.evaluation.seed,
        "tolerance_deg": spec.mission.tolerance_deg,
        "controllers": {"policy": policy, "pd_baseline": pd},
        "plant": plant_report(spec, run.grid, wheels),
    }


def format_report(report: dict) -> str:
    """The report as a table for people."""
    p = report["plant"]
    lines = [f"{report['episodes']} evaluation slews (seed {report['seed']}), modsat SlewSim float64 vs Basilisk "
             f"{p['basilisk_version']} ({p['integrator']}, dt {p['basilisk_dt_ns']} ns, control every "
             f"{p['frame_skip']} steps)",
             f"plant: {p['mass_kg']:g} kg, {p['wheel_units']} wheel unit(s), {p['actuator_model']}, gravity gradient "
             f"{'on' if p['gravity_gradient'] else 'off'}" + ("" if p["ideal_wheels"] else
                                                                "; Basilisk wheel limits on: agreement not expected"),
             f"{'':<12} {'simulator':<9} {'@tol':>6} {'@0.25deg':>8} {'@1deg':>6} {'error deg':>10} "
             f"{'settle s':>8} {'peak rad/s':>10} {'unsafe':>6}   (success rates; medians; max peak rate)"]
    for name, c in report["controllers"].items():
        if not c["available"]:
            lines.append(f"{name:<12} {c['reason']}")
            continue
        for sim in ("modsat", "basilisk"):
            s = c[sim]
            settle = s["median_settling_time_s"]
            lines.append(f"{name if sim == 'modsat' else '':<12} {sim:<9} {100 * s['success_rate']:>5.0f}% "
                         f"{100 * s['success_rate_0_25deg']:>7.0f}% {100 * s['success_rate_1deg']:>5.0f}% "
                         f"{s['median_final_error_deg']:>10.4f} {'-' if settle is None else f'{settle:.3f}':>8} "
                         f"{s['max_peak_rate_rad_s']:>10.3f} {s['safety_violations']:>6}")
        lines.append(f"{'':<12} attitude difference modsat vs Basilisk: max {c['max_attitude_difference_rad']:.2e} "
                     f"rad, median {c['median_attitude_difference_rad']:.2e} rad; same successes: "
                     f"{'yes' if c['same_success'] else 'NO'}")
    return "\n".join(lines)


#: The artefact a run whose spec asks for ``evaluation.basilisk`` gets (worker and ``modsat train``).
ARTIFACT_NAME = "verification.json"


def add_verification(files: dict[str, bytes]) -> bool:
    """Add ``verification.json`` to a finished run's ``files`` if its spec asks for it
    (``evaluation.basilisk``): the report of :func:`verify_run`, or, where Basilisk is not
    installed, ``{"available": false, "reason": ...}``. The training itself never fails
    because of it: an error becomes the report's reason. Returns whether it was asked for."""
    import json
    import tempfile

    spec = parse_spec(files["spec.json"])
    if not spec.evaluation.basilisk:
        return False
    if not basilisk_available():
        report: dict = {"available": False, "reason": BASILISK_MISSING + " (on the machine that trained this run)"}
    else:
        try:
            with tempfile.TemporaryDirectory(prefix="modsat-verify-") as tmp:
                for name in ("spec.json", "design.json", "policy_export.pt"):
                    if name in files:
                        with open(os.path.join(tmp, name), "wb") as fh:
                            fh.write(files[name])
                report = {"available": True, **verify_run(tmp)}
        except Exception as exc:  # noqa: BLE001 - the run's own results must still be stored
            report = {"available": False, "reason": f"verification failed: {type(exc).__name__}: {exc}"}
    files[ARTIFACT_NAME] = json.dumps(report, indent=1).encode()
    return True
