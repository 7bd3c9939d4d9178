"""The parts catalog (`modules.wheels`, `modules.payload`), the requirements and the flight-condition flag:
masses per part, each wheel unit's own torque and momentum in the simulator, the export, and the
errors a user gets for a catalog or a requirement that cannot be."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from modsat_core.artefacts import ConditionEvaluation, EvaluationSummary, flight_failures
from modsat_core.sim.mission import EpisodeDraw
from modsat_core.sim.morphology import design_mass_properties, mass_properties
from modsat_core.sim.pd import PDController
from modsat_core.sim.slew import Design, SlewSim
from modsat_core.spec.jobspec import JobSpec, SpecError, parse_spec
from modsat_core.spec.parts import WHEEL_LIBRARY, cell_masses, design_mass_kg, design_power_W
from modsat_core.spec.requirements import Requirements, landed_within, verdict
from modsat_core.spec.sections import Mission, ModuleCatalog

STRONG = {"name": "strong", "torque_Nm": 0.01, "momentum_Nms": 0.05, "mass_kg": 0.3, "power_W": 2.0}
WEAK = {"name": "weak", "torque_Nm": 0.004, "momentum_Nms": 0.01, "mass_kg": 0.1, "power_W": 0.5}


def catalog(**kw) -> ModuleCatalog:
    return ModuleCatalog.model_validate({"module_mass_kg": 0.2, "wheels": [STRONG, WEAK], **kw})


def test_without_a_catalog_the_mass_properties_are_the_old_ones():
    rng = np.random.default_rng(0)
    grid = rng.integers(0, 3, size=(3, 3, 3))
    grid[1, 1, 1] = 2
    m = ModuleCatalog(module_mass_kg=1.3)
    old, new = mass_properties(grid, 1.3, 0.1), design_mass_properties(grid, m)
    np.testing.assert_array_equal(old.inertia_B_kgm2, new.inertia_B_kgm2)
    # the per-cell formula agrees with the uniform one when every cell weighs the same
    per_cell = mass_properties(grid, np.where(grid > 0, 1.3, 0.0), 0.1)
    np.testing.assert_allclose(per_cell.inertia_B_kgm2, old.inertia_B_kgm2, rtol=1e-12, atol=1e-15)
    d = Design.from_grid(grid, m)
    assert d.torque_weight is None and d.momentum_weight is None


def test_each_part_weighs_its_own_and_the_inertia_follows():
    m = catalog(payload={"cells": [[0, 0, 0]], "mass_kg": 4.0})
    grid = np.zeros((2, 2, 2), dtype=np.int64)
    grid[0, 0, 0] = 1  # the payload cell
    grid[1, 0, 0] = 2  # a unit of "strong": 0.2 + 3 x 0.3 kg
    grid[0, 1, 0] = 3  # a unit of "weak": 0.2 + 3 x 0.1 kg
    grid[1, 1, 0] = 1  # structure
    masses = cell_masses(grid, m)
    assert masses[0, 0, 0] == 4.0 and masses[1, 1, 0] == 0.2
    assert masses[1, 0, 0] == pytest.approx(1.1) and masses[0, 1, 0] == pytest.approx(0.5)
    assert design_mass_kg(grid, m) == pytest.approx(5.8)
    assert design_power_W(grid, m) == pytest.approx(3 * 2.0 + 3 * 0.5)
    mp = design_mass_properties(grid, m)
    # point masses plus each cube's own a^2/6, about the centre of mass, by hand
    cells = np.argwhere(grid > 0) * 0.1
    w = masses[grid > 0]
    com = (w[:, None] * cells).sum(0) / w.sum()
    r = cells - com
    want = sum(wi * ((ri @ ri + 0.01 / 6) * np.eye(3) - np.outer(ri, ri)) for wi, ri in zip(w, r))
    np.testing.assert_allclose(mp.inertia_B_kgm2, want, rtol=1e-12)
    assert mp.mass_kg == pytest.approx(5.8)


def test_each_wheel_unit_gives_its_own_torque_and_stores_its_own_momentum():
    m = catalog()
    assert m.torque_scale_Nm == 0.01 and m.momentum_capacity_Nms == 0.05  # the strongest wheel's
    grid = np.zeros((3, 3, 3), dtype=np.int64)
    grid[1, 1, :] = [2, 3, 3]
    d = Design.from_grid(grid, m)
    np.testing.assert_allclose(d.slot_weights()[0], [1.0, 0.4, 0.4])
    np.testing.assert_allclose(d.slot_weights()[1], [1.0, 0.2, 0.2])
    mission = Mission(gravity_gradient=False, episode_steps=400)
    sim = SlewSim.from_designs([d], mission, m, dtype=torch.float64)
    # PD's torque box is the units' torques summed: 0.01 + 2 x 0.004 N m per axis
    assert float(sim.plant.box_Nm[0, 0]) == pytest.approx(0.018)
    draw = EpisodeDraw(
        q_BN=np.array([1.0, 0, 0, 0]),
        q_TN=np.array([0.0, 1, 0, 0]),
        omega_B=np.zeros(3),
        tau_residual_B=np.zeros(3),
        orbit_phase_rad=0.0,
    )
    sim.reset([0], [draw])
    for _ in range(300):  # full command on x for 25 s: every unit runs into its own capacity
        sim.step(torch.tensor([[[1.0, 0, 0]] * 3], dtype=torch.float64))
    h = sim.state.h_B[0, :, 0].abs().numpy()
    np.testing.assert_allclose(h, [0.05, 0.01, 0.01], rtol=1e-9)


def test_pd_flies_a_mixed_catalog_design():
    m = catalog()
    grid = np.zeros((3, 3, 3), dtype=np.int64)
    grid[1, 1, :] = [2, 3, 1]
    from modsat_core.evaluation.monte_carlo import monte_carlo

    mission = Mission(slew_min_deg=20, slew_max_deg=40, tolerance_deg=1.0, episode_steps=600)
    mc = monte_carlo(Design.from_grid(grid, m), PDController, mission, m, episodes=4, seed=1, dtype=torch.float64)
    assert all(e["success"] for e in mc.episodes), mc.episodes


def test_the_library_holds_real_wheels_with_their_sources():
    assert len(WHEEL_LIBRARY) >= 3
    for w in WHEEL_LIBRARY.values():
        assert w.torque_Nm > 0 and w.momentum_Nms > 0 and w.mass_kg > 0 and "datasheet" in w.source
    m = ModuleCatalog.model_validate({"wheels": ["bct-rwp015", "nanoavionics-rw0"]})
    assert m.wheels is not None and m.wheels[1].torque_Nm == 0.0032 and m.torque_scale_Nm == 0.004


def _codesign(**sections) -> dict:
    d = {"algorithm": "diffsim-codesign", "design": {"grid_size": 3}, "modules": {"wheels": [STRONG, WEAK]}}
    for k, v in sections.items():
        d[k] = {**d.get(k, {}), **v}
    return d


@pytest.mark.parametrize(
    "data, where, words",
    [
        (_codesign(modules={"wheels": [{**STRONG, "mass_kg": -1.0}]}), "modules.wheels.0.mass_kg", "allowed: > 0"),
        (_codesign(modules={"wheels": [{**STRONG, "torque_Nm": 0.0}]}), "modules.wheels.0.torque_Nm", "allowed: > 0"),
        (_codesign(modules={"wheels": ["no-such-wheel"]}), "modules.wheels", "known: bct-rwp015"),
        (_codesign(modules={"wheels": [STRONG, STRONG]}), "modules.wheels", "repeated: strong"),
        (
            _codesign(modules={"payload": {"cells": [[0, 0, 3]], "mass_kg": 1.0}}),
            "modules.payload.cells",
            "outside the 3^3 grid",
        ),
        (
            _codesign(requirements={"settling_time_s": 20, "mass_budget_kg": 0.5}),
            "requirements.mass_budget_kg",
            "no design can meet it",
        ),
        (
            _codesign(requirements={"settling_time_s": 20, "power_budget_W": 1.0}),
            "requirements.power_budget_W",
            "no design can meet it",
        ),
        (
            {**_codesign(), "algorithm": "td3-codesign"},
            "modules.wheels",
            "first-order learner",
        ),
        (
            _codesign(modules={"wheels": ["bct-rwp015"]}, requirements={"settling_time_s": 20, "power_budget_W": 9}),
            "requirements.power_budget_W",
            "power_W",
        ),
        (
            _codesign(requirements={"settling_time_s": 20, "slew_max_deg": 170}),
            "requirements.slew_max_deg",
            "outside the slews the mission flies",
        ),
        (_codesign(requirements={"settling_time_s": -1}), "requirements.settling_time_s", "allowed: > 0"),
    ],
)
def test_a_bad_catalog_or_requirement_is_refused_naming_it(data, where, words):
    with pytest.raises(SpecError) as err:
        parse_spec(data)
    text = "\n".join(err.value.messages)
    assert where in text and words in text, text


def test_a_payload_named_in_both_places_is_weighed_once():
    """The objective's payload cells and the catalog's, the same cells: the lightest satellite is the payload
    (1 kg) and one unit of the lightest type (1 + 3 x 0.1 kg), 2.3 kg, not the payload counted twice."""
    both = _codesign(
        modules={"payload": {"cells": [[0, 0, 0]], "mass_kg": 1.0}},
        objective={"payload_cells": [[0, 0, 0]]},
        requirements={"settling_time_s": 20, "mass_budget_kg": 3.0},
    )
    assert parse_spec(both).requirements is not None
    both["requirements"]["mass_budget_kg"] = 2.2
    with pytest.raises(SpecError, match=r"lightest satellite the grid can hold \(2.3 kg"):
        parse_spec(both)


def test_old_specs_load_as_they_were():
    spec = JobSpec()
    assert spec.modules.wheels is None and spec.modules.payload is None and spec.requirements is None
    again = parse_spec(_codesign(requirements={"settling_time_s": 20, "mass_budget_kg": 9}))
    assert parse_spec(again.model_dump_json()) == again


def test_the_verdict_names_every_requirement_missed():
    req = Requirements(settling_time_s=10.0, success=0.9, mass_budget_kg=5.0, power_budget_W=4.0)
    ok = verdict(req, 4.0, 3.0, {"nominal": 1.0, "delay-1": 0.95})
    assert ok["meets"] and ok["reasons"] == []
    bad = verdict(req, 6.0, None, {"nominal": 1.0, "delay-1": 0.5})
    assert not bad["meets"] and len(bad["reasons"]) == 3
    assert any("delay-1: 50 %" in r for r in bad["reasons"]) and any("6.00 kg" in r for r in bad["reasons"])
    eps = [
        {"success": True, "settling_time_s": 4.0},
        {"success": True, "settling_time_s": 12.0},
        {"success": False, "settling_time_s": None},
    ]
    assert landed_within(eps, 10.0) == pytest.approx(1 / 3)


def _cond(name: str, policy: float, pd: float) -> ConditionEvaluation:
    def s(rate: float) -> EvaluationSummary:
        return EvaluationSummary.model_validate({"episodes": 100, "success_rate": rate, "mean_return": None})

    return ConditionEvaluation(name=name, changes={}, policy=s(policy), pd_baseline=s(pd))


def test_a_policy_is_flagged_exactly_where_it_fails_a_condition_pd_lands():
    conds = [
        _cond("delay-1", 0.06, 1.0),  # PD lands, the policy does not: flagged
        _cond("weak-wheels", 0.95, 1.0),  # within 90 % of PD's: not flagged
        _cond("large-slews", 0.2, 0.5),  # PD does not land it either: not flagged
        _cond("combined", 0.85, 0.96),  # below 90 % of PD's 96 %: flagged
    ]
    assert [f.name for f in flight_failures(conds)] == ["delay-1", "combined"]
    assert flight_failures([]) == []


def test_a_condition_outside_the_required_slews_is_flown_but_not_judged():
    from modsat_core.spec.evaluation import STANDARD_CONDITIONS
    from modsat_core.spec.requirements import judged

    req = Requirements(settling_time_s=20.0, slew_max_deg=90.0)
    mission = Mission(slew_min_deg=30.0, slew_max_deg=90.0)
    names = [n for n, c in STANDARD_CONDITIONS.items() if judged(c, req, mission)]
    assert "large-slews" not in names and {"delay-1", "small-slews", "combined"} <= set(names)
    assert judged(STANDARD_CONDITIONS["large-slews"], Requirements(settling_time_s=20.0, slew_max_deg=180.0), mission)
