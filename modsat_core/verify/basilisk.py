"""The designed satellite in Basilisk: hub, balanced reaction wheels, gravity gradient, a
circular orbit; one slew flown closed loop, one control period at a time. Why Basilisk's
balanced wheels integrate exactly modsat's equations is written in modsat_core/verify/run.py.
Basilisk is optional (``pip install -e '.[basilisk]'``) and imported only when flying.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from modsat_core.grid import ACTUATOR
from modsat_core.sim import dynamics as dyn
from modsat_core.sim.mission import EpisodeDraw
from modsat_core.sim.morphology import design_mass_properties
from modsat_core.sim.slew import Design, SlewSim
from modsat_core.spec.jobspec import Mission, ModuleCatalog
from modsat_core.verify.flight import ControllerFactory, Flight, commanded_torque

BASILISK_MISSING = "modsat verify --basilisk needs Basilisk: pip install -e '.[basilisk]'"
#: Default wheel spin inertia (kg m^2). With ideal wheels it changes nothing (see above);
#: with a speed limit it sets the wheel speed a momentum needs (2 N m s at 1,900 RPM).
DEFAULT_WHEEL_INERTIA_KGM2 = 0.01
#: Wheel units per Basilisk wheel effector: its motor-torque message holds 36 wheels.
UNITS_PER_EFFECTOR = 12


def basilisk_available() -> bool:
    """Whether the Basilisk modules this verification uses can be imported."""
    try:
        from Basilisk.simulation import (  # noqa: F401
            GravityGradientEffector,
            extForceTorque,
            reactionWheelStateEffector,
            spacecraft,
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
        frictions = (("Coulomb friction", self.coulomb_friction_Nm), ("viscous friction", self.viscous_friction_Nms))
        for name, v in frictions:
            if not (math.isfinite(v) and v >= 0):
                raise ValueError(f"--wheel-friction: the {name} must be a number >= 0; got {v}")
        if not (math.isfinite(self.inertia_kgm2) and self.inertia_kgm2 > 0):
            raise ValueError(f"--wheel-inertia must be a positive number of kg m^2; got {self.inertia_kgm2}")

    @property
    def ideal(self) -> bool:
        """True when Basilisk's wheels integrate exactly modsat's equations."""
        return self.speed_max_rpm is None and self.coulomb_friction_Nm == 0 and self.viscous_friction_Nms == 0


# ----------------------------------------------------------------------------- Basilisk


class BasiliskSatellite:
    """The designed satellite in Basilisk, flying one slew, one control period at a time.

    Body frame B: origin at the centre of the grid cell (0, 0, 0), axes along the grid (the
    same axes as modsat's, whose origin is the centre of mass ``r_BcB_B``). Hub: the design's
    mass, centre of mass and full inertia tensor plus ``n_units Js E`` (see the module
    docstring); one Basilisk wheel per body axis per actuator module, in modsat's unit order.
    """

    def __init__(
        self, grid: np.ndarray, mission: Mission, modules: ModuleCatalog, draw: EpisodeDraw, wheels: WheelOptions
    ):
        from Basilisk.architecture import messaging
        from Basilisk.simulation import (
            GravityGradientEffector,
            extForceTorque,
            spacecraft,
        )
        from Basilisk.utilities import SimulationBaseClass, macros

        self.modules, self.wheels_opt = modules, wheels
        mp = design_mass_properties(grid, modules)
        self.unit_positions = (mp.positions_B_m + mp.com_grid_m)[mp.types >= ACTUATOR]  # from B's origin
        self.K = len(self.unit_positions)
        self.has_wheels = modules.actuator_model == "reaction-wheel"
        self.Js = wheels.inertia_kgm2
        self.dt_ns = macros.sec2nano(mission.physics_dt_s)
        self.period_ns = self.dt_ns * mission.frame_skip
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
        r_N, v_N = circular_orbit(mission.orbit_altitude_km, draw.orbit_phase_rad)
        sc.hub.r_CN_NInit = r_N.reshape(3, 1).tolist()
        sc.hub.v_CN_NInit = v_N.reshape(3, 1).tolist()
        self.sim.AddModelToTask(task, sc, 1)
        self.sc = sc

        if mission.gravity_gradient:
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
        self.body_torque: Any = None  # Basilisk's (untyped) ExtForceTorque when there are no wheels
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

        opt, mods = self.wheels_opt, self.modules
        per = UNITS_PER_EFFECTOR
        for g0 in range(0, self.K, per):
            factory = simIncludeRW.rwFactory()
            for k in range(g0, min(g0 + per, self.K)):
                for axis in range(3):
                    kw = dict(
                        RWModel=messaging.BalancedWheels,
                        Js=float(self.Js),
                        u_max=float(mods.torque_scale_Nm),
                        rWB_B=[float(x) for x in self.unit_positions[k]],
                        # Zero absolute wheel momentum at the start: Omega = -g . w.
                        Omega=float(-draw.omega_B[axis] / macros.RPM),
                        label=f"{'xyz'[axis]}{k - g0}",
                    )
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
        cap = self.modules.momentum_capacity_Nms
        return cap / self.Js if cap is not None else -1.0

    def step(self, tau_cmd_B: np.ndarray) -> None:
        """Hold the per-unit body torque command (K, 3) for one control period, then read the state."""
        if self.has_wheels:
            u = -np.asarray(tau_cmd_B, dtype=float)  # the motors' torque on the wheels; Basilisk clips to u_max
            per = UNITS_PER_EFFECTOR
            for g, (_, msg, payload, _) in enumerate(self.rw_groups):
                cmd = u[g * per : (g + 1) * per].reshape(-1)
                payload.motorTorque = cmd.tolist() + [0.0] * (36 - len(cmd))
                msg.write(payload, self.t_ns)
        else:
            tau = np.clip(tau_cmd_B, -self.modules.torque_scale_Nm, self.modules.torque_scale_Nm).sum(0)
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


def fly_basilisk(
    grid: np.ndarray,
    mission: Mission,
    modules: ModuleCatalog,
    draw: EpisodeDraw,
    factory: ControllerFactory,
    wheels: WheelOptions,
) -> Flight:
    """One slew in Basilisk, the controller called at the control rate from the loop.

    The controller sees the Basilisk state through a one-satellite SlewSim that only holds
    it (never steps), so the PD law and the policy run the very code modsat runs.
    """
    sat = BasiliskSatellite(grid, mission, modules, draw, wheels)
    mirror = SlewSim.from_designs([Design.from_grid(grid, modules)], mission, modules, dtype=torch.float64)
    mirror.reset([0], [draw])
    controller = factory(mirror)
    t, q, w = [0.0], [sat.q_BN.copy()], [sat.omega_B.copy()]
    for _ in range(mission.episode_steps):
        mirror.state = dyn.State(
            q_BN=torch.from_numpy(sat.q_BN).unsqueeze(0),
            omega_B=torch.from_numpy(sat.omega_B).unsqueeze(0),
            h_B=torch.from_numpy(sat.h_B).unsqueeze(0),
            t_s=torch.tensor([sat.t_s]),
        )
        with torch.no_grad():
            tau_cmd = commanded_torque(controller(mirror), mirror)[0].numpy()
        sat.step(tau_cmd)
        t.append(sat.t_s)
        q.append(sat.q_BN.copy())
        w.append(sat.omega_B.copy())
        if np.linalg.norm(sat.omega_B) > mission.rate_limit_rad_s:  # a safety violation ends the slew
            break
    return Flight(np.asarray(t), np.asarray(q), np.asarray(w))
