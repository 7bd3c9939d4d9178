"""modsat_core/spec/limits.py: its constants agree with the code they estimate, the presets fit the
defaults, the issue's over-sized specs do not, and the CLI says so readably."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from modsat_core.spec import limits, parse_spec
from modsat_core.spec.presets import PRESETS, get_preset


def _spec(**sections):
    d = get_preset("quick-td3").model_dump(mode="json")
    for k, v in sections.items():
        d[k] = {**d[k], **v} if isinstance(v, dict) else v
    return parse_spec(d)


def test_constants_agree_with_the_code():
    from modsat_core.agent.networks import SET_CELL_WIDTH
    from modsat_core.codesign.features import N_FEATURES, N_LAST_COMMAND
    from modsat_core.training.replay_layout import replay_buffer_bytes

    assert limits.N_FEATURES == N_FEATURES and limits.SET_CELL_WIDTH == SET_CELL_WIDTH
    assert limits.N_LAST_COMMAND == N_LAST_COMMAND
    for n in (2, 3, 5, 10):  # the buffer is built from the same table: this checks the dtypes' sizes
        for last in (False, True):
            assert limits.transition_bytes(n, last) * 1000 == replay_buffer_bytes(n, 1000, last)


def test_validating_limits_imports_no_torch():
    code = (
        "import sys; from modsat_core.spec import limits; from modsat_core.spec.presets import get_preset; "
        "limits.check(get_preset('paper-5x5x5'), limits.Limits()); print('torch' in sys.modules)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "False"


@pytest.mark.parametrize("name", list(PRESETS))
def test_presets_fit_the_defaults(name):
    assert limits.check(PRESETS[name], limits.Limits()) == []


def test_replay_estimate_is_the_issue_figure():
    # The issue's layout: no last command (quick-td3 observes it since: 2.8 GiB more here)
    training = {"buffer_size": 500_000, "total_env_steps": 1_000_000, "observe_last_command": False}
    big = _spec(design={"grid_size": 10}, training=training)
    est = limits.estimate(big)
    assert est.replay_bytes / 2**30 == pytest.approx(9.36, abs=0.01)  # "9.4 GiB" in the issue
    no_work_bound = limits.Limits(max_job_hours=None)  # a million updates on a 10^3 grid: over the work bound too
    ((loc, msg),) = limits.check(big, no_work_bound)
    assert loc == ("training", "buffer_size") and "9.4 GiB" in msg
    assert limits.check(big, limits.Limits(max_memory_bytes=None, max_job_hours=None)) == []


def test_check_cli_is_readable(tmp_path):
    from server.cli import main

    path = tmp_path / "big.json"
    d = get_preset("quick-td3").model_dump(mode="json")
    d["design"]["grid_size"] = 10
    d["training"].update(buffer_size=500_000, total_env_steps=1_000_000)
    path.write_text(json.dumps(d))
    with pytest.raises(SystemExit) as exc:
        main(["check", str(path)])
    assert exc.value.code == 2
    ok = tmp_path / "ok.json"
    ok.write_text(get_preset("quick-td3").model_dump_json())
    assert main(["check", str(ok)]) == 0


def test_codesign_counts_the_designs_it_flies_at_once():
    """`diffsim-codesign` flies design_batch x design_slews slews at once: too many for the
    service's memory is refused naming `diffsim.design_batch`, not left to run out of memory."""
    d = get_preset("diffsim-3x3x3").model_dump(mode="json")
    assert limits.check(parse_spec(d), limits.Limits()) == []
    est = limits.estimate(parse_spec(d))
    assert est.design_bytes > 0 and est.memory_bytes >= limits.BASE_BYTES + est.update_bytes + est.design_bytes
    d["design"]["grid_size"] = 10
    d["objective"]["payload_cells"] = [[0, 0, 0]]
    d["diffsim"].update(design_batch=4096, design_slews=1000)
    problems = limits.check(parse_spec(d), limits.Limits())
    assert problems and problems[0][0] == ("diffsim", "design_batch"), problems
    assert "designs flown at once" in problems[0][1]


def test_the_relaxed_design_flight_counts_its_graph():
    """The relaxed design gradient keeps a whole episode's graph of `design_slews` slews: the presets
    with it fit, and above the measured peaks (440 MiB: 3x3x3, 16 slews, 500 steps); too many slews
    are refused naming `diffsim.design_slews`."""
    for name in ("diffsim-3x3x3", "diffsim-5x5x5"):
        d = get_preset(name).model_dump(mode="json")
        d["diffsim"]["design_gradient"] = "relaxed"
        assert limits.check(parse_spec(d), limits.Limits()) == [], name
    d = get_preset("diffsim-3x3x3").model_dump(mode="json")
    assert limits.estimate(parse_spec(d)).relaxed_bytes == 0  # the score function keeps no such graph
    d["diffsim"].update(design_gradient="relaxed", design_slews=16)
    assert limits.estimate(parse_spec(d)).relaxed_bytes > 440 * 2**20
    d["diffsim"]["design_slews"] = 1000
    problems = limits.check(parse_spec(d), limits.Limits())
    assert problems and problems[0][0] == ("diffsim", "design_slews"), problems
    assert "the relaxed design flight" in problems[0][1]


def test_flight_conditions_count_in_the_evaluation_s_cost():
    """The final evaluation flies every condition's slews in one batch (episodes x conditions rows),
    policy and PD: a spec the nominal evaluation fits can be refused for its conditions, naming
    `evaluation.episodes` and saying how many conditions it flies."""
    none = limits.estimate(_spec(evaluation={"episodes": 1000, "conditions": []}))
    nine = limits.estimate(_spec(evaluation={"episodes": 1000}))  # the nine standard conditions
    steps = get_preset("quick-td3").mission.episode_steps
    assert nine.evaluation_steps - none.evaluation_steps == 2 * 1000 * 9 * steps
    assert nine.evaluation_bytes == 9 * none.evaluation_bytes
    big = {"episodes": 10_000, "trajectories": 0}
    assert limits.check(_spec(evaluation={**big, "conditions": []}), limits.Limits()) == []
    many = [{"name": f"late-{k}", "delay_steps": 1 + k % 10} for k in range(20)]
    problems = limits.check(_spec(evaluation={**big, "conditions": many}), limits.Limits())
    assert problems and problems[0][0] == ("evaluation", "episodes"), problems
    assert "20 evaluation.conditions" in " ".join(p[1] for p in problems)
