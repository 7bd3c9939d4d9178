"""modsat_core.artefacts: the typed records of a run (progress, design.json, evaluation.json,
trajectories.json, curve.json, the evaluation summary) read back what they write, keep the
keys they were given (no nulls for keys a writer left out, unknown keys kept), refuse a file
that does not fit with its name and field, and load no torch."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from modsat_core.artefacts import (
    ArtefactError,
    CurveFile,
    CurvePoint,
    DesignReport,
    EvaluationReport,
    ProgressRecord,
    RunSummary,
    Trajectories,
)

ROOT = Path(__file__).resolve().parents[2]
L_SHAPE = [[[1, 2], [0, 0]], [[1, 0], [0, 0]]]
POINT = {
    "env_steps": 160,
    "updates": 12,
    "valid": True,
    "modules": 3,
    "actuators": 1,
    "mean_return": -80.5,
    "success_rate": 0.5,
    "success_rate_at_0.25_deg": 0.0,
    "success_rate_at_1_deg": 0.5,
    "median_final_error_deg": 0.8,
    "median_slew_time_ratio": None,
}
SUMMARY = {
    "episodes": 4,
    "success_rate": 0.5,
    "safety_violations": 0,
    "mean_return": -70.0,
    "std_return": 2.0,
    "median_final_error_deg": 0.7,
    "median_final_rate_rad_s": 0.001,
    "median_settling_time_s": 20.0,
    "median_slew_time_ratio": 1.7,
    "median_effort_Nms": 0.2,
    "max_peak_rate_rad_s": 0.1,
    "success_rate_at_0.25_deg": 0.25,
    "success_rate_at_1_deg": 0.5,
    "success_rate_at_2_deg": 0.75,
}
EPISODE = {
    "success": True,
    "final_error_deg": 0.2,
    "final_rate_rad_s": 0.0,
    "settling_time_s": None,
    "slew_time_ratio": None,
    "eigenaxis_bound_s": 10.0,
    "slew_angle_deg": 90.0,
    "effort_Nms": 0.1,
    "peak_rate_rad_s": 0.05,
    "safety_violation": False,
    "return": -60.0,
    "duration_s": 1.0,
    "rate_tolerance_rad_s": 0.01,
}


def _slew(T: int = 3) -> dict:
    return {
        "t_s": [0.1 * i for i in range(T)],
        "q_BN": [[1.0, 0.0, 0.0, 0.0]] * T,
        "omega_B": [[0.0] * 3] * T,
        "h_B": [[0.0] * 3] * T,
        "tau_c_B": [[0.0] * 3] * T,
        "error_deg": [1.0] * T,
        "q_TN": [1.0, 0.0, 0.0, 0.0],
        "metrics": EPISODE,
    }


@pytest.mark.parametrize(
    "model,data",
    [
        (CurvePoint, POINT),
        (
            CurvePoint,
            {"env_steps": 96, "mean_return": -3.0, "success_rate": 0.0, "design_return": -5.0, "generation": 1},
        ),
        (
            ProgressRecord,
            {
                "env_steps": 160,
                "total_env_steps": 480,
                "updates": 12,
                "phase": "training",
                "eval": POINT,
                "train_episodes": 8,
                "train_mean_return": -90.0,
                "train_valid_rate": 1.0,
                "train_success_rate": 0.0,
                "critic_loss": 1.5,
                "q": -3.0,
                "elapsed_s": 4.2,
            },
        ),
        (
            ProgressRecord,
            {"env_steps": 480, "total_env_steps": 480, "updates": 40, "phase": "evaluating", "eval": None},
        ),
        (DesignReport, DesignReport.of(L_SHAPE, mass_kg=3.0, principal_inertia_kgm2=[0.01, 0.02, 0.02]).to_dict()),
        (
            EvaluationReport,
            {
                "episodes": 4,
                "seed": 0,
                "design_valid": True,
                "policy": {"summary": SUMMARY, "episodes": [EPISODE]},
                "pd_baseline": {"summary": SUMMARY, "episodes": [EPISODE]},
            },
        ),
        (
            EvaluationReport,
            {
                "episodes": 4,
                "seed": 0,
                "design_valid": False,
                "pd_baseline": None,
                "policy": {
                    "summary": {"episodes": 4, "success_rate": 0.0, "mean_return": -500.0, "std_return": 0.0},
                    "episodes": [],
                },
            },
        ),
        (Trajectories, {"policy": [_slew(3), _slew(5)], "pd_baseline": [_slew(4)]}),
        (CurveFile, {"algorithm": "td3-codesign", "points": [POINT], "best_env_steps": 160}),
        (
            RunSummary,
            {
                "policy": SUMMARY,
                "pd_baseline": None,
                "design": {"grid_size": 2, "valid": True, "modules": 3, "actuators": 1},
                "designs_evaluated": 4,
            },
        ),
        (RunSummary, {"runner": "simulated", "resumed_from": None}),  # a test runner's own summary
    ],
)
def test_a_record_reads_back_exactly_what_was_written(model, data):
    rec = model.parse(json.dumps(data))
    assert rec.to_dict() == data, "same keys (none added as null, unknown ones kept), same values"
    assert model.parse(rec.to_json()) == rec
    assert json.loads(rec.model_dump_json()) == data, "the API's serialisation is the file's"


def test_success_at_a_tolerance_and_keys_named_as_in_the_files():
    s = RunSummary.parse({"policy": SUMMARY}).policy
    assert s is not None and s.success_at(0.25) == 0.25 and s.success_at(1.0) == 0.5 and s.success_at(2) == 0.75
    assert s.success_at(5.0) is None
    # Made from Python names, a record still writes the files' keys.
    p = CurvePoint(env_steps=1, mean_return=0.0, success_rate=0.0, success_rate_at_0_25_deg=0.0)
    assert p.model_dump() == {"env_steps": 1, "mean_return": 0.0, "success_rate": 0.0, "success_rate_at_0.25_deg": 0.0}


def test_a_design_report_is_made_from_its_grid():
    d = DesignReport.of(L_SHAPE)
    assert (d.grid_size, d.valid, d.modules, d.actuators) == (2, True, 3, 1)
    assert next(iter(d.to_dict())) == "grid" and d.types == {"0": "empty", "1": "structure", "2": "actuator"}
    assert "mass_kg" not in d.to_dict() and d.figures().to_dict() == {
        k: v for k, v in d.to_dict().items() if k != "grid"
    }
    assert d.array.shape == (2, 2, 2)
    assert not DesignReport.of([[[1, 0], [0, 0]], [[0, 0], [0, 2]]]).valid


@pytest.mark.parametrize(
    "model,data,message",
    [
        (DesignReport, b"{", r"design.json is not JSON"),
        (
            DesignReport,
            {"grid": [[[1, 2], [0, 0]], [[1, 0], [0, 0]]], "grid_size": 2, "valid": True, "modules": 2, "actuators": 1},
            r"design.json .*modules is 2, the grid has 3",
        ),
        (
            DesignReport,
            {"grid": [[[12]]], "grid_size": 1, "valid": True, "modules": 1, "actuators": 0},
            r"design.json .*0 \(empty\), 1 \(structure\) or 2..9 \(a wheel unit",
        ),
        (DesignReport, {"grid_size": 2}, r"design.json .*grid: Field required"),
        (
            Trajectories,
            {"policy": [{**_slew(3), "omega_B": [[0.0] * 3] * 2}]},
            r"trajectories.json .*policy.0.*omega_B",
        ),
        (Trajectories, {"policy": [{"q_BN": []}]}, r"trajectories.json .*policy.0.t_s: Field required"),
        (
            EvaluationReport,
            {
                "episodes": 4,
                "seed": 0,
                "design_valid": True,
                "policy": {"summary": {"episodes": "many"}},
                "pd_baseline": None,
            },
            r"evaluation.json .*policy.summary.episodes",
        ),
        (ProgressRecord, {"env_steps": "lots"}, r"progress record .*env_steps"),
        (CurveFile, [1, 2], r"curve.json is not a modsat CurveFile"),
    ],
)
def test_a_file_not_in_its_format_is_refused_with_its_name_and_field(model, data, message):
    with pytest.raises(ArtefactError, match=message):
        model.parse(data if isinstance(data, bytes) else json.dumps(data))
    assert issubclass(ArtefactError, ValueError)


def test_the_records_load_no_torch():
    code = (
        "import sys\nimport modsat_core.artefacts as a\n"
        "a.DesignReport.of([[[2]]]).to_json(); a.Trajectories.parse(b'{}')\n"
        "assert 'torch' not in sys.modules, 'torch was imported'\n"
    )
    r = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
