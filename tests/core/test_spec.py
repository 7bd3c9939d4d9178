"""JobSpec: bounds, unknown keys and readable error messages."""

import json
from pathlib import Path

import pytest

from modsat_core.spec.jobspec import JobSpec, SpecError, Training, parse_spec
from modsat_core.spec.presets import PRESETS, get_preset
from modsat_core.spec.training import REMOVED_KEYS

KEPT = Path(__file__).resolve().parents[1] / "data" / "reproduction"  # the reproduction's kept runs


def messages(data) -> list[str]:
    with pytest.raises(SpecError) as info:
        parse_spec(data)
    return info.value.messages


@pytest.mark.parametrize("n", [0, 1, 11, 100])
def test_grid_size_out_of_range_names_field_value_and_range(n):
    (msg,) = messages({"design": {"grid_size": n}})
    assert msg.startswith("design.grid_size:")
    assert repr(n) in msg
    assert ">= 2" in msg and "<= 10" in msg


def test_negative_module_mass_is_rejected():
    (msg,) = messages({"modules": {"module_mass_kg": -1.0}})
    assert msg.startswith("modules.module_mass_kg: -1.0 is out of range")
    assert "> 0" in msg and "<= 1000" in msg


@pytest.mark.parametrize("field,value", [("slew_min_deg", -5.0), ("slew_max_deg", 181.0), ("slew_max_deg", 720.0)])
def test_slew_range_outside_0_180(field, value):
    (msg,) = messages({"mission": {field: value}})
    assert msg.startswith(f"mission.{field}: {value!r}")
    assert ">= 0" in msg and "<= 180" in msg


def test_slew_min_above_max():
    (msg,) = messages({"mission": {"slew_min_deg": 120, "slew_max_deg": 60}})
    assert "slew_min_deg (120.0) must not exceed slew_max_deg (60.0)" in msg


def test_unknown_keys_are_rejected_and_listed():
    msgs = messages({"desgin": {}, "mission": {"tolerance": 1.0}})
    assert any(m.startswith("desgin: unknown field") and "design" in m for m in msgs)
    assert any(m.startswith("mission.tolerance: unknown field") and "tolerance_deg" in m for m in msgs)


def test_wrong_types_and_literals():
    msgs = messages({"algorithm": "ppo", "seed": "abc"})
    assert any(m.startswith("algorithm: 'ppo' is not allowed") and "td3-codesign" in m for m in msgs)
    assert any(m.startswith("seed:") and "'abc'" in m for m in msgs)


def test_fixed_design_is_checked():
    bad_shape = [[[1, 2], [0, 0]], [[0, 0], [0, 0]]]
    (msg,) = messages({"design": {"grid_size": 3, "fixed_design": bad_shape}})
    assert "3 x 3 x 3" in msg
    disconnected = [[[2, 0], [0, 0]], [[0, 0], [0, 1]]]
    (msg,) = messages({"design": {"grid_size": 2, "fixed_design": disconnected}})
    assert "not face-connected" in msg
    (msg,) = messages({"design": {"grid_size": 2, "fixed_design": [[[2, 12], [0, 0]], [[0, 0], [0, 0]]]}})
    assert msg.startswith("design.fixed_design.0.0.1: 12 is out of range") and "<= 9" in msg
    (msg,) = messages({"design": {"grid_size": 2, "fixed_design": [[[2, 3], [0, 0]], [[0, 0], [0, 0]]]}})
    assert "a wheel unit of type 1" in msg and "modules.wheels lists 1 type" in msg
    no_actuator = [[[1, 1], [0, 0]], [[0, 0], [0, 0]]]
    (msg,) = messages({"design": {"grid_size": 2, "fixed_design": no_actuator}})
    assert "no actuator" in msg


def test_td3_control_needs_a_design():
    (msg,) = messages({"algorithm": "td3-control"})
    assert "fixed_design" in msg


def test_json_text_and_round_trip():
    spec = parse_spec(json.dumps({"seed": 7, "design": {"grid_size": 5}}))
    assert spec.seed == 7 and spec.design.grid_size == 5
    assert parse_spec(spec.model_dump_json()) == spec
    with pytest.raises(SpecError):
        parse_spec("{not json")


def test_presets_are_valid_specs_with_paper_numbers():
    assert set(PRESETS) >= {"paper-3x3x3", "paper-5x5x5", "ga-3x3x3", "ga-5x5x5", "quick", "cpu-3x3x3"}
    for name, spec in PRESETS.items():
        assert parse_spec(spec.model_dump(mode="json")) == spec, name
    p3, p5 = get_preset("paper-3x3x3"), get_preset("paper-5x5x5")
    assert p3.modules.torque_scale_Nm == 0.8 and p5.modules.torque_scale_Nm == 1.5
    assert p5.design.grid_size == 5
    t = p3.training
    assert (
        t.actor_lr,
        t.critic_lr,
        t.batch_size,
        t.buffer_size,
        t.gamma,
        t.tau,
        t.exploration_noise,
        t.train_frequency,
        t.hidden_sizes,
    ) == (3e-4, 3e-3, 512, 500_000, 0.99, 0.005, 0.2, 2, [400, 300])
    m = p3.mission
    assert (m.physics_dt_s, m.frame_skip, m.episode_steps, m.slew_min_deg, m.slew_max_deg) == (
        1 / 240,
        20,
        500,
        30.0,
        150.0,
    )
    assert get_preset("ga-5x5x5").algorithm == "ga"
    with pytest.raises(KeyError, match="known:"):
        get_preset("nope")


def test_every_number_in_the_schema_is_bounded():
    schema = JobSpec.model_json_schema()
    unbounded = []

    def walk(node, path):
        if "$ref" in node:
            walk(schema["$defs"][node["$ref"].rsplit("/", 1)[-1]], path)
            return
        for branch in node.get("anyOf", []):
            walk(branch, path)
        if node.get("type") in ("integer", "number") and "const" not in node:
            has_lo = "minimum" in node or "exclusiveMinimum" in node
            has_hi = "maximum" in node or "exclusiveMaximum" in node
            if not (has_lo and has_hi):
                unbounded.append(path)
        for k, v in node.get("properties", {}).items():
            walk(v, f"{path}.{k}")
        if "items" in node:
            walk(node["items"], path + "[]")
        for i, v in enumerate(node.get("prefixItems", [])):
            walk(v, f"{path}[{i}]")

    walk(schema, "spec")
    assert unbounded == []


def test_docs_spec_md_is_generated_from_the_current_schema():
    from pathlib import Path

    from modsat_core.spec.doc import spec_markdown

    doc = Path(__file__).resolve().parents[2] / "docs" / "spec.md"
    assert doc.read_text() == spec_markdown(), "regenerate with: modsat schema --markdown > docs/spec.md"


def test_exploration_noise_schedule():
    """Constant without a final value; linear from learning_starts to the budget's end."""
    t = Training(total_env_steps=10_000, learning_starts=2_000, exploration_noise=0.1)
    assert t.noise_at(0) == t.noise_at(9_000) == 0.1
    t = t.model_copy(update={"exploration_noise_final": 0.0})
    assert [t.noise_at(s) for s in (0, 2_000, 6_000, 10_000, 20_000)] == pytest.approx([0.1, 0.1, 0.05, 0.0, 0.0])
    assert t.design_exploration_at(6_000) == t.design_exploration  # design exploration keeps its own schedule


def test_a_removed_training_key_at_its_no_op_value_loads_and_is_dropped():
    """Every saved run's spec.json lists every key of its day: the removed ones at their no-op
    values load (the 3x3x3 reproduction's spec is one)."""
    saved = json.loads((KEPT / "3x3x3" / "spec.json").read_text())
    assert {k: saved["training"][k] for k in REMOVED_KEYS} == REMOVED_KEYS
    spec = parse_spec(saved)
    assert not REMOVED_KEYS.keys() & spec.training.model_dump().keys()
    assert spec == parse_spec(
        {**saved, "training": {k: v for k, v in saved["training"].items() if k not in REMOVED_KEYS}}
    )
    assert Training.model_validate(REMOVED_KEYS) == Training()


@pytest.mark.parametrize(
    "key,value,shown",
    [
        ("n_step", 3, "it was 3 here); only its no-op value 1 is accepted"),
        ("n_step", True, "it was true here); only its no-op value 1 is accepted"),
        ("critic_layer_norm", True, "it was true here); only its no-op value false is accepted"),
        ("exploration_noise_min", 0.001, "it was 0.001 here); only its no-op value null is accepted"),
        ("policy_noise_final", 0.01, "it was 0.01 here); only its no-op value null is accepted"),
    ],
)
def test_a_removed_training_key_set_to_anything_else_is_refused_by_name(key, value, shown):
    with pytest.raises(SpecError) as info:
        parse_spec({"training": {key: value}})
    (msg,) = info.value.messages
    assert msg.startswith(f"training.{key}: removed from modsat (") and shown in msg
    assert "docs/lab/2026-12-05-unused-knobs-removed.md" in msg
    (err,) = info.value.errors  # located at the key, as the API's 422 names it
    assert err["loc"] == ("training", key) and err["type"] == "removed_field"
