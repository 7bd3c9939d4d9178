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

import io
import warnings
from collections.abc import Callable
from dataclasses import asdict, dataclass

import numpy as np
import torch

from modsat_core.evaluation.run_folder import RunFolder
from modsat_core.grid import ACTUATOR, is_valid
from modsat_core.sim import dynamics as dyn
from modsat_core.sim.mission import EpisodeDraw
from modsat_core.sim.morphology import design_mass_properties
from modsat_core.sim.pd import PDController
from modsat_core.sim.slew import Design, SlewSim
from modsat_core.spec.jobspec import JobSpec, Mission, ModuleCatalog, parse_spec
from modsat_core.verify.basilisk import (
    BASILISK_MISSING,
    DEFAULT_WHEEL_INERTIA_KGM2,
    WheelOptions,
    basilisk_available,
    fly_basilisk,
)
from modsat_core.verify.flight import (
    ControllerFactory,
    attitude_difference_rad,
    evaluation_draws,
    flight_metrics,
    fly_modsat,
    summarize,
)

__all__ = [
    "BASILISK_MISSING",
    "DEFAULT_WHEEL_INERTIA_KGM2",
    "WheelOptions",
    "add_verification",
    "basilisk_available",
    "format_report",
    "verify_run",
]


# ----------------------------------------------------------------------------- the run


@dataclass(frozen=True)
class Run:
    """What verification needs from a run folder."""

    spec: JobSpec
    grid: np.ndarray
    policy: torch.jit.ScriptModule | None
    policy_missing: str | None  # why there is no policy to fly, if there is none

    @classmethod
    def of(cls, run: RunFolder) -> Run:
        """``spec.json``, ``design.json`` and (if present) ``policy_export.pt``."""
        spec, grid = run.spec(), run.design().array
        if not is_valid(grid):
            raise ValueError(f"the design in {run.path}/design.json is not a valid satellite: nothing to fly")
        exported = run.read_optional("policy_export.pt")
        if exported is None:
            why = f"no policy_export.pt in {run.path} (a GA run or an older run): only the PD baseline is verified"
            return cls(spec, grid, None, why)
        with warnings.catch_warnings():  # TorchScript's deprecation notice (see agent.export.export_torchscript)
            warnings.simplefilter("ignore", DeprecationWarning)
            policy = torch.jit.load(io.BytesIO(exported), map_location="cpu")
        return cls(spec, grid, policy.eval(), None)


def takes_last_command(module: torch.jit.ScriptModule) -> bool:
    """Whether an exported controller's ``forward`` takes the last command (``tau_last_B``, a fourth
    input: a policy trained with `training.observe_last_command`; docs/export.md)."""
    schema = module.forward.schema  # type: ignore[attr-defined]  # a ScriptMethod's
    return len(schema.arguments) > 4  # self, q_BT, omega_B, h_B


class ExportedPolicy:
    """The exported TorchScript controller as a :class:`SlewSim` controller.

    Both simulators call it on the same kind of state (a SlewSim holding the state), so the
    policy sees the same inputs in both up to the simulators' differences. One instance flies one
    set of slews from their start (the factory makes one per flight): a controller that takes its
    last command is given the command it returned at the previous call, zeros at the first.
    """

    def __init__(self, module: torch.jit.ScriptModule, tau_max_Nm: float):
        self.module, self.tau_max = module, tau_max_Nm
        self.last_command = takes_last_command(module)
        self.last: torch.Tensor | None = None  # (B, K, 3) N m, the previous call's command

    def __call__(self, sim: SlewSim) -> torch.Tensor:
        # One row at a time: a float32 network's output can depend on the batch size in the
        # last bit, and Basilisk flies one satellite at a time.
        q, w, h = sim.error_quaternion(), sim.state.omega_B, sim.state.h_B
        with torch.no_grad():
            if self.last_command:
                last = torch.zeros_like(h) if self.last is None else self.last
                rows = [self.module(q[i : i + 1], w[i : i + 1], h[i : i + 1], last[i : i + 1]) for i in range(sim.B)]
            else:
                rows = [self.module(q[i : i + 1], w[i : i + 1], h[i : i + 1]) for i in range(sim.B)]
        tau = torch.cat(rows)
        self.last = tau.to(h.dtype)
        return tau.to(sim.dtype) / self.tau_max


def policy_factory(module: torch.jit.ScriptModule, tau_max_Nm: float) -> ControllerFactory:
    return lambda sim: ExportedPolicy(module, tau_max_Nm)


def pd_factory(sim: SlewSim) -> PDController:
    return PDController(sim)


# ----------------------------------------------------------------------------- report


def compare(
    grid: np.ndarray,
    mission: Mission,
    modules: ModuleCatalog,
    draws: list[EpisodeDraw],
    factory: ControllerFactory,
    wheels: WheelOptions,
) -> dict:
    """One controller on the same slews in both simulators, side by side."""
    design = Design.from_grid(grid, modules)
    ours = fly_modsat(design, mission, modules, draws, factory)
    theirs = [fly_basilisk(grid, mission, modules, d, factory, wheels) for d in draws]
    rows_m = [flight_metrics(f, d.q_TN, mission) for f, d in zip(ours, draws)]
    rows_b = [flight_metrics(f, d.q_TN, mission) for f, d in zip(theirs, draws)]
    diffs = [attitude_difference_rad(a, b) for a, b in zip(ours, theirs)]
    return {
        "available": True,
        "modsat": summarize(rows_m),
        "basilisk": summarize(rows_b),
        "max_attitude_difference_rad": max(diffs),
        "median_attitude_difference_rad": float(np.median(diffs)),
        "same_success": [a["success"] for a in rows_m] == [b["success"] for b in rows_b],
        "slews": [
            {"episode": i, "attitude_difference_rad": d, "modsat": a, "basilisk": b}
            for i, (d, a, b) in enumerate(zip(diffs, rows_m, rows_b))
        ],
    }


def plant_report(grid: np.ndarray, mission: Mission, modules: ModuleCatalog, wheels: WheelOptions) -> dict:
    """What the Basilisk model holds, for the report (docs/verification.md)."""
    from Basilisk.utilities import macros

    mp = design_mass_properties(grid, modules)
    n_units = int((np.asarray(grid) >= ACTUATOR).sum())
    has_wheels = modules.actuator_model == "reaction-wheel"
    try:
        from Basilisk import __version__ as bsk_version
    except ImportError:
        bsk_version = None
    return {
        "basilisk_version": bsk_version,
        "integrator": "RK4",
        "physics_dt_s": mission.physics_dt_s,
        "basilisk_dt_ns": macros.sec2nano(mission.physics_dt_s),
        "frame_skip": mission.frame_skip,
        "mass_kg": float(mp.mass_kg),
        "center_of_mass_grid_m": np.asarray(mp.com_grid_m).tolist(),
        "inertia_kgm2": np.asarray(mp.inertia_B_kgm2).tolist(),
        "actuator_model": modules.actuator_model,
        "wheel_units": n_units,
        "wheels": 3 * n_units if has_wheels else 0,
        "wheel_model": "BalancedWheels" if has_wheels else None,
        "hub_inertia_kgm2": (
            np.asarray(mp.inertia_B_kgm2) + (n_units * wheels.inertia_kgm2 if has_wheels else 0.0) * np.eye(3)
        ).tolist(),
        "torque_limit_Nm": modules.torque_scale_Nm,
        "momentum_capacity_Nms": modules.momentum_capacity_Nms,
        "wheel_options": asdict(wheels) if has_wheels else None,
        "ideal_wheels": wheels.ideal,
        "gravity_gradient": mission.gravity_gradient,
        "orbit_altitude_km": mission.orbit_altitude_km,
        "mu_m3_s2": dyn.MU_EARTH_M3_S2,
        "residual_torque_Nm": list(mission.residual_torque_Nm),
        "residual_torque_std_Nm": mission.residual_torque_std_Nm,
    }


def verify_run(
    run_dir: str | RunFolder,
    episodes: int | None = None,
    wheels: WheelOptions | None = None,
    log: Callable[[str], None] | None = None,
) -> dict:
    """Fly the run's evaluation slews in Basilisk and in modsat; the report ``--json`` prints.
    ``run_dir``: the run's directory, or its files (:class:`RunFolder`)."""
    wheels = wheels or WheelOptions()
    log = log or (lambda _line: None)
    run = Run.of(run_dir if isinstance(run_dir, RunFolder) else RunFolder(run_dir))
    spec = run.spec
    if spec.modules.actuator_model != "reaction-wheel" and wheels != WheelOptions():
        raise ValueError("the run's actuator model is ideal-torque: there are no wheels for the wheel options")
    if spec.modules.wheels and len(spec.modules.wheels) > 1:
        raise ValueError(
            "the run's parts catalog has several wheel types; the Basilisk comparison flies one wheel unit type "
            "(docs/verification.md)"
        )
    n = episodes or spec.evaluation.episodes
    draws = evaluation_draws(spec.mission, spec.evaluation, n)
    mission, modules = spec.mission, spec.modules
    if run.policy is not None:
        log(f"policy: {n} slews in modsat and in Basilisk")
        policy = compare(run.grid, mission, modules, draws, policy_factory(run.policy, modules.torque_scale_Nm), wheels)
    else:
        policy = {"available": False, "reason": run.policy_missing}
        log(f"policy: {run.policy_missing}")
    log(f"PD baseline: {n} slews in modsat and in Basilisk")
    pd = compare(run.grid, mission, modules, draws, pd_factory, wheels)
    return {
        "episodes": n,
        "seed": spec.evaluation.seed,
        "tolerance_deg": spec.mission.tolerance_deg,
        "controllers": {"policy": policy, "pd_baseline": pd},
        "plant": plant_report(run.grid, mission, modules, wheels),
    }


def format_report(report: dict) -> str:
    """The report as a table for people."""
    p = report["plant"]
    lines = [
        f"{report['episodes']} evaluation slews (seed {report['seed']}), modsat SlewSim float64 vs Basilisk "
        f"{p['basilisk_version']} ({p['integrator']}, dt {p['basilisk_dt_ns']} ns, control every "
        f"{p['frame_skip']} steps)",
        f"plant: {p['mass_kg']:g} kg, {p['wheel_units']} wheel unit(s), {p['actuator_model']}, gravity gradient "
        f"{'on' if p['gravity_gradient'] else 'off'}"
        + ("" if p["ideal_wheels"] else "; Basilisk wheel limits on: agreement not expected"),
        f"{'':<12} {'simulator':<9} {'@tol':>6} {'@0.25deg':>8} {'@1deg':>6} {'error deg':>10} "
        f"{'settle s':>8} {'peak rad/s':>10} {'unsafe':>6}   (success rates; medians; max peak rate)",
    ]
    for name, c in report["controllers"].items():
        if not c["available"]:
            lines.append(f"{name:<12} {c['reason']}")
            continue
        for sim in ("modsat", "basilisk"):
            s = c[sim]
            settle = s["median_settling_time_s"]
            lines.append(
                f"{name if sim == 'modsat' else '':<12} {sim:<9} {100 * s['success_rate']:>5.0f}% "
                f"{100 * s['success_rate_0_25deg']:>7.0f}% {100 * s['success_rate_1deg']:>5.0f}% "
                f"{s['median_final_error_deg']:>10.4f} {'-' if settle is None else f'{settle:.3f}':>8} "
                f"{s['max_peak_rate_rad_s']:>10.3f} {s['safety_violations']:>6}"
            )
        lines.append(
            f"{'':<12} attitude difference modsat vs Basilisk: max {c['max_attitude_difference_rad']:.2e} "
            f"rad, median {c['median_attitude_difference_rad']:.2e} rad; same successes: "
            f"{'yes' if c['same_success'] else 'NO'}"
        )
    return "\n".join(lines)


#: The artefact a run whose spec asks for ``evaluation.basilisk`` gets (worker and ``modsat train``).
ARTIFACT_NAME = "verification.json"


def add_verification(files: dict[str, bytes]) -> bool:
    """Add ``verification.json`` to a finished run's ``files`` if its spec asks for it
    (``evaluation.basilisk``): the report of :func:`verify_run`, or, where Basilisk is not
    installed, ``{"available": false, "reason": ...}``. The training itself never fails
    because of it: an error becomes the report's reason. Returns whether it was asked for."""
    import json

    spec = parse_spec(files["spec.json"])
    if not spec.evaluation.basilisk:
        return False
    if not basilisk_available():
        report: dict = {"available": False, "reason": BASILISK_MISSING + " (on the machine that trained this run)"}
    else:
        try:
            report = {"available": True, **verify_run(RunFolder("the run's files", files))}
        except Exception as exc:  # the run's own results must still be stored
            report = {"available": False, "reason": f"verification failed: {type(exc).__name__}: {exc}"}
    files[ARTIFACT_NAME] = json.dumps(report, indent=1).encode()
    return True
