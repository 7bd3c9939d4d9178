"""`modsat verify --basilisk`: the same slews in Basilisk and in modsat agree.

Bounds (measured on this machine, docs/verification.md): with the spec's dt = 1/240 s the
two simulators differ along a slew by 0.8-0.9e-7 rad with the PD baseline and 2.7e-7 rad with
the float32 policy, all of it from Basilisk's clock counting integer nanoseconds (dt becomes
4,166,667 ns, so a slew runs 0.33 ns per step slower); with a dt that is a whole number of
nanoseconds they agree to 1.4e-13 rad.
"""

from __future__ import annotations

import json
import shutil
import sys

import numpy as np
import pytest
import torch

from modsat_core.evaluation.monte_carlo import monte_carlo
from modsat_core.sim.morphology import mass_properties
from modsat_core.sim.pd import PDController
from modsat_core.sim.slew import Design
from modsat_core.spec.jobspec import JobSpec
from modsat_core.spec.presets import get_preset
from server import cli

pytestmark = pytest.mark.slow  # flies slews in Basilisk (about a minute)

#: Largest attitude difference (rad) at dt = 1/240 s: measured 9.2e-8 (PD) and 2.7e-7 (policy).
BOUND_RAD = 1e-6
#: ... and with a dt Basilisk's nanosecond clock holds exactly: measured 1.4e-13.
EXACT_CLOCK_BOUND_RAD = 1e-10

CUBE = np.ones((3, 3, 3), dtype=np.int64)
CUBE[1, 1, 1] = 2
ALL_ACTUATORS = np.full((3, 3, 3), 2, dtype=np.int64)  # 27 units: three Basilisk wheel effectors
ASYMMETRIC = np.zeros((3, 3, 3), dtype=np.int64)
for cell, kind in (
    ((0, 0, 0), 1),
    ((1, 0, 0), 2),
    ((2, 0, 0), 1),
    ((2, 1, 0), 1),
    ((2, 2, 0), 1),
    ((2, 2, 1), 2),
    ((1, 2, 1), 1),
):
    ASYMMETRIC[cell] = kind
DESIGNS = {"cube": CUBE, "asymmetric": ASYMMETRIC, "all-actuators": ALL_ACTUATORS}


@pytest.fixture(scope="module")
def verify():
    pytest.importorskip(
        "Basilisk.simulation.reactionWheelStateEffector",
        reason="Basilisk is not installed: pip install -e '.[basilisk]'",
    )
    from modsat_core.verify import run as verify

    return verify


def slew_spec(actuator_model: str = "reaction-wheel", **mission) -> JobSpec:
    """The quick mission (120 control steps) with a residual torque, so every Basilisk
    effector modsat has a twin of is on: wheels, gravity gradient, residual torque."""
    d = get_preset("quick-td3").model_dump(mode="json")
    d["modules"]["actuator_model"] = actuator_model
    d["mission"].update({"residual_torque_Nm": [2e-4, -1e-4, 5e-5], "residual_torque_std_Nm": 1e-4, **mission})
    return JobSpec.model_validate(d)


def test_the_asymmetric_design_has_products_of_inertia():
    I = mass_properties(ASYMMETRIC).inertia_B_kgm2
    assert np.all(np.abs(I[~np.eye(3, dtype=bool)]) > 1e-3)


@pytest.mark.parametrize(
    "design,model",
    [
        ("cube", "reaction-wheel"),
        ("asymmetric", "reaction-wheel"),
        ("asymmetric", "ideal-torque"),
        ("all-actuators", "reaction-wheel"),
    ],
)
def test_pd_flies_the_same_slews_in_both(verify, design, model):
    spec, grid, n = slew_spec(model), DESIGNS[design], 3 if design == "cube" else 2
    draws = verify.evaluation_draws(spec.mission, spec.evaluation, n)
    c = verify.compare(grid, spec.mission, spec.modules, draws, verify.pd_factory, verify.WheelOptions())
    assert c["same_success"] and c["max_attitude_difference_rad"] < BOUND_RAD
    assert c["modsat"] == pytest.approx(c["basilisk"], rel=1e-4, abs=1e-6)
    for s in c["slews"]:
        assert s["modsat"]["duration_s"] == pytest.approx(s["basilisk"]["duration_s"], rel=1e-6)
    if design != "cube":
        return
    assert c["modsat"]["success_rate"] == 1.0  # the PD baseline lands these slews: a real closed loop
    # The modsat column is modsat's own Monte-Carlo evaluation of the same slews.
    mc = monte_carlo(
        Design.from_grid(grid, spec.modules),
        PDController,
        spec.mission,
        spec.modules,
        episodes=n,
        seed=spec.evaluation.seed,
        dtype=torch.float64,
    )
    for ours, row in zip((s["modsat"] for s in c["slews"]), mc.episodes):
        for key in ("success", "final_error_deg", "settling_time_s", "peak_rate_rad_s", "safety_violation"):
            assert ours[key] == pytest.approx(row[key], rel=1e-12), key


def test_with_a_whole_number_of_nanoseconds_they_agree_to_roundoff(verify):
    spec = slew_spec(physics_dt_s=1 / 250, episode_steps=60)  # 4,000,000 ns exactly
    draws = verify.evaluation_draws(spec.mission, spec.evaluation, 2)
    c = verify.compare(ASYMMETRIC, spec.mission, spec.modules, draws, verify.pd_factory, verify.WheelOptions())
    assert c["max_attitude_difference_rad"] < EXACT_CLOCK_BOUND_RAD


def test_basilisk_wheel_limits_make_another_plant(verify):
    # 100 RPM with Js = 0.01 holds 0.1 N m s, less than the 0.16 N m s the slews need.
    spec = slew_spec()
    limited = verify.WheelOptions(speed_max_rpm=100.0, coulomb_friction_Nm=1e-3, viscous_friction_Nms=1e-4)
    assert not limited.ideal and verify.WheelOptions(inertia_kgm2=0.5).ideal
    draws = verify.evaluation_draws(spec.mission, spec.evaluation, 1)
    c = verify.compare(CUBE, spec.mission, spec.modules, draws, verify.pd_factory, limited)
    assert c["max_attitude_difference_rad"] > 1e-2
    with pytest.raises(ValueError, match="wheel-speed-max"):
        verify.WheelOptions(speed_max_rpm=-1.0)


@pytest.fixture(scope="module")
def trained_run(tmp_path_factory, verify):
    """A short `quick` co-design run, written as `modsat train` writes it.

    Heavy modules (100 kg) so that the barely trained policy, whose torques are mostly
    saturated, turns the satellite slowly enough to fly whole slews (not one step to the
    rate limit): the comparison then covers 120 control steps of closed loop.
    """
    from modsat_core.training.train import train

    d = get_preset("quick-td3").model_dump(mode="json")
    d["modules"]["module_mass_kg"] = 100.0
    d["training"].update(
        total_env_steps=480,
        learning_starts=320,
        hidden_sizes=[32, 32],
        batch_size=32,
        eval_every_steps=10**6,
        eval_episodes=1,
        checkpoint_every_steps=10**6,
        # Without the action penalty and the odd output of `quick`'s recipe: with them the
        # barely trained policy's torques stayed near zero (peak rate 0.0009 rad/s).
        action_l2=0.0,
        odd_control=False,
    )
    d["evaluation"].update(episodes=2, trajectories=0)
    result = train(JobSpec.model_validate(d))
    out = tmp_path_factory.mktemp("quick-run")
    for name, data in result.artifacts().items():
        (out / name).write_bytes(data)
    assert (out / "policy_export.pt").exists()
    return out


def run_cli(argv, capsys) -> tuple[int, str, str]:
    rc = cli.main(argv)
    captured = capsys.readouterr()
    return rc, captured.out, captured.err


def test_cli_json_report_and_the_policy_flies_identically(trained_run, capsys):
    rc, out, _ = run_cli(["verify", str(trained_run), "--basilisk", "--episodes", "2", "--json"], capsys)
    assert rc == 0
    report = json.loads(out)
    assert report["episodes"] == 2 and set(report["controllers"]) == {"policy", "pd_baseline"}
    keys = {
        "success_rate_0_25deg",
        "success_rate_1deg",
        "median_final_error_deg",
        "median_settling_time_s",
        "max_peak_rate_rad_s",
        "safety_violations",
    }
    for name, c in report["controllers"].items():
        assert c["available"], name
        assert keys <= set(c["modsat"]) and set(c["modsat"]) == set(c["basilisk"])
        assert c["max_attitude_difference_rad"] < BOUND_RAD, name
        assert c["median_attitude_difference_rad"] <= c["max_attitude_difference_rad"]
        assert c["same_success"]
    slews = report["controllers"]["policy"]["slews"]
    assert all(s["basilisk"]["duration_s"] > 9.9 for s in slews)  # whole slews, 120 control steps
    assert max(s["basilisk"]["peak_rate_rad_s"] for s in slews) > 0.05  # and the policy did turn the satellite
    plant = report["plant"]
    assert plant["wheel_model"] == "BalancedWheels" and plant["ideal_wheels"] and plant["mass_kg"] > 0


def test_a_run_without_an_exported_policy_still_verifies_the_pd_baseline(verify, trained_run, tmp_path, capsys):
    for name in ("spec.json", "design.json"):
        shutil.copy(trained_run / name, tmp_path / name)
    rc, out, _ = run_cli(["verify", str(tmp_path), "--basilisk", "--episodes", "1", "--json"], capsys)
    assert rc == 0
    report = json.loads(out)
    assert not report["controllers"]["policy"]["available"]
    assert "policy_export.pt" in report["controllers"]["policy"]["reason"]
    assert report["controllers"]["pd_baseline"]["max_attitude_difference_rad"] < BOUND_RAD
    text = verify.format_report(report)  # what the command prints without --json
    assert "policy_export.pt" in text and "pd_baseline" in text and "same successes: yes" in text


def test_without_basilisk_a_message_not_a_traceback(monkeypatch, tmp_path, capsys):
    for name in [m for m in sys.modules if m == "Basilisk" or m.startswith("Basilisk.")] + ["Basilisk"]:
        monkeypatch.setitem(sys.modules, name, None)  # `import Basilisk...` now raises ImportError
    rc, out, err = run_cli(["verify", str(tmp_path), "--basilisk"], capsys)
    assert rc == 2 and out == ""
    assert err.strip() == "modsat verify --basilisk needs Basilisk: pip install -e '.[basilisk]'"


def _files(run_dir, basilisk: bool) -> dict[str, bytes]:
    files = {p.name: p.read_bytes() for p in run_dir.iterdir()}
    spec = json.loads(files["spec.json"])
    spec["evaluation"]["basilisk"] = basilisk
    files["spec.json"] = json.dumps(spec).encode()
    return files


def test_a_run_that_asks_gets_verification_json(trained_run):
    """`evaluation.basilisk`: the worker and `modsat train` add the report to the run's files."""
    from modsat_core.verify.run import ARTIFACT_NAME, add_verification

    files = _files(trained_run, basilisk=False)
    assert not add_verification(files) and ARTIFACT_NAME not in files
    files = _files(trained_run, basilisk=True)
    assert add_verification(files)
    report = json.loads(files[ARTIFACT_NAME])
    assert report["available"] and report["episodes"] == 2
    assert report["controllers"]["policy"]["max_attitude_difference_rad"] < BOUND_RAD


def test_a_run_that_asks_without_basilisk_says_so(monkeypatch, tmp_path):
    from modsat_core.verify import run as v

    monkeypatch.setattr(v, "basilisk_available", lambda: False)
    files = {
        "spec.json": get_preset("quick-td3")
        .model_copy(update={"evaluation": get_preset("quick-td3").evaluation.model_copy(update={"basilisk": True})})
        .model_dump_json()
        .encode()
    }
    assert v.add_verification(files)
    report = json.loads(files[v.ARTIFACT_NAME])
    assert report == {"available": False, "reason": v.BASILISK_MISSING + " (on the machine that trained this run)"}
