"""`modsat report`: the curves, the table and the designs of saved runs (issue 15's figure),
from real tiny runs of both methods, through the real command line."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from modsat_core.artefacts import ArtefactError, DesignReport
from modsat_core.evaluation.run_files import design_report
from modsat_core.evaluation.run_folder import RunFolder
from modsat_core.evaluation.study_report import held_curves, saved_run, symmetry
from modsat_core.grid import ACTUATOR, STRUCTURE

from .conftest import tiny_spec

PNG = b"\x89PNG\r\n\x1a\n"


def _write(run_dir, files: dict[str, bytes]) -> None:
    run_dir.mkdir(parents=True)
    for name, data in files.items():
        (run_dir / name).write_bytes(data)


def test_study_runs_every_seed_and_method_then_reports(study_dir, tmp_path):
    out, stdout = study_dir
    assert sorted(p.name for p in out.iterdir()) == [
        "ga-seed0",
        "ga-seed1",
        "report",
        "td3-codesign-seed0",
        "td3-codesign-seed1",
    ]
    for d in ("ga-seed0", "td3-codesign-seed1"):
        spec = json.loads((out / d / "spec.json").read_text())
        assert (spec["algorithm"], spec["seed"]) == (d.split("-seed")[0], int(d[-1]))
    report = json.loads((out / "report" / "study.json").read_text())
    assert report["algorithms"]["GA"]["finished"] == report["algorithms"]["RL co-design"]["finished"] == 2
    assert "| RL co-design | 0, 1 |" in stdout
    # Run again: the finished runs are kept, not trained again.
    r = modsat("study", str(out.parent / "spec.json"), "--seeds", "0", "1", "--out", str(out))
    assert r.returncode == 0 and r.stdout.count("finished earlier, kept") == 4, r.stdout + r.stderr
    unfair = tmp_path / "unfair.json"
    unfair.write_text(tiny_spec(ga={"steps_per_design": 64}).model_dump_json())  # learning_starts 96
    r = modsat("study", str(unfair), "--seeds", "0", "0", "--out", str(tmp_path / "s"))
    assert r.returncode == 2 and "seeds: 1 to 16 distinct" in r.stderr and "ga.steps_per_design: 64" in r.stderr
    assert "Traceback" not in r.stderr and not (tmp_path / "s").exists()


@pytest.fixture(scope="module")
def study_dir(tmp_path_factory):
    """`modsat study` of the tiny mission: two seeds of RL co-design and of the GA, two at a time."""
    root = tmp_path_factory.mktemp("study")
    spec = tiny_spec(ga={"population_size": 2, "steps_per_design": 192})  # twice learning_starts
    (root / "spec.json").write_text(spec.model_dump_json())
    r = modsat("study", str(root / "spec.json"), "--seeds", "0", "1", "--out", str(root / "out"), "--jobs", "2")
    assert r.returncode == 0, r.stdout + r.stderr
    return root / "out", r.stdout


@pytest.fixture(scope="module")
def runs(study_dir):
    return {(a, s): study_dir[0] / f"{a}-seed{s}" for a in ("td3-codesign", "ga") for s in (0, 1)}


def modsat(*args):
    return subprocess.run([sys.executable, "-m", "server.cli", *args], capture_output=True, text=True, timeout=300)


def test_report_of_both_methods_over_seeds(runs, tmp_path):
    out = tmp_path / "report"
    r = modsat("report", *map(str, runs.values()), "--out", str(out))
    assert r.returncode == 0, r.stderr
    result = json.loads((out / "study.json").read_text())
    assert result["grid_size"] == 2
    assert list(result["algorithms"]) == ["RL co-design", "GA"]
    for label, algorithm in (("RL co-design", "td3-codesign"), ("GA", "ga")):
        a = result["algorithms"][label]
        assert a["seeds"] == [0, 1]
        # The table's figures are the runs' own final evaluations, mean and std over the seeds.
        finals = [json.loads((runs[(algorithm, s)] / "evaluation.json").read_text()) for s in (0, 1)]
        returns = [f["policy"]["summary"]["mean_return"] for f in finals]
        assert a["policy"]["return"]["mean"] == pytest.approx(np.mean(returns))
        assert a["policy"]["return"]["std"] == pytest.approx(np.std(returns, ddof=1))
        pd = [f["pd_baseline"]["summary"]["success_rate_at_1_deg"] for f in finals if f["pd_baseline"]]
        assert a["pd_on_designs"]["success_1"]["n"] == len(pd)
        # Each seed's curve held from point to point, averaged where both seeds have one.
        curves = [json.loads((runs[(algorithm, s)] / "curve.json").read_text())["points"] for s in (0, 1)]
        c = a["curves"]["mean_return"]
        assert c["env_steps"][0] == max(p[0]["env_steps"] for p in curves)
        x = c["env_steps"][-1]
        held = [[p["mean_return"] for p in pts if p["env_steps"] <= x][-1] for pts in curves]
        assert c["mean"][-1] == pytest.approx(np.mean(held)) and c["std"][-1] == pytest.approx(np.std(held, ddof=1))
        # The flight conditions (docs/robustness.md): nominal, then each condition every finished run
        # with a valid design flew, mean over those runs.
        valid = [f for f in finals if f["pd_baseline"]]
        names = [c["name"] for c in valid[0]["conditions"]] if valid else []
        assert list(a["conditions"]) == (["nominal", *names] if names else [])
        for name in names:
            rates = [next(c for c in f["conditions"] if c["name"] == name)["policy"]["success_rate"] for f in valid]
            assert a["conditions"][name]["policy"]["success"]["mean"] == pytest.approx(np.mean(rates))
        for d in a["designs"]:
            assert (out / d["png"]).read_bytes().startswith(PNG)
            assert 0 <= d["mirror_planes"] <= 3
    assert (out / "curves.png").read_bytes().startswith(PNG)
    table = (out / "table.md").read_text()
    assert table == r.stdout.split("wrote ")[0]
    assert "| RL co-design | 0, 1 |" in table and "| GA | 0, 1 |" in table
    flown = [label for label, a in result["algorithms"].items() if a["conditions"]]
    assert flown, "no run of the study flew a valid design: the conditions' table is untested"
    assert "Flight conditions" in table and f"| {flown[0]} | delay-1 |" in table


def test_report_refuses_what_is_not_one_study(runs, tmp_path):
    other = tmp_path / "other"
    spec = json.loads((runs[("ga", 1)] / "spec.json").read_text())
    spec["mission"]["tolerance_deg"] = 0.25
    _write(other, {n: (runs[("ga", 1)] / n).read_bytes() for n in ("curve.json", "design.json", "evaluation.json")})
    (other / "spec.json").write_text(json.dumps(spec))
    r = modsat("report", str(runs[("ga", 0)]), str(other), "--out", str(tmp_path / "x"))
    assert r.returncode == 2 and "differ in spec.mission" in r.stderr and "Traceback" not in r.stderr
    (other / "curve.json").unlink()
    r = modsat("report", str(other), "--out", str(tmp_path / "y"))
    assert r.returncode == 2 and "no curve.json" in r.stderr and "Traceback" not in r.stderr
    (other / "curve.json").write_text("{not json")
    with pytest.raises(ArtefactError, match=r"curve\.json"):
        saved_run(RunFolder(other))
    assert not (tmp_path / "x").exists() and not (tmp_path / "y").exists()


def test_symmetry_numbers():
    spec = tiny_spec(design={"grid_size": 3})
    size = spec.modules.module_size_m
    cube = np.full((3, 3, 3), STRUCTURE)
    cube[1, 1, 1] = ACTUATOR
    s = symmetry(design_report(cube, spec), size)
    assert s == {
        "modules": 27,
        "actuators": 1,
        "mirror_planes": 3,
        "products_of_inertia_ratio": pytest.approx(0.0, abs=1e-12),
        "com_offset_modules": pytest.approx(0.0, abs=1e-12),
    }
    ell = np.zeros((3, 3, 3), dtype=int)  # an L in one plane: no mirror plane, products of inertia
    ell[0, 0, 0] = ACTUATOR
    ell[1, 0, 0] = ell[0, 1, 0] = STRUCTURE
    s = symmetry(design_report(ell, spec), size)
    assert s["mirror_planes"] == 0 and s["products_of_inertia_ratio"] > 0.05
    # The centre of mass (1/3, 1/3, 0) module edges from the corner; the grid centre is at (1, 1, 1).
    assert s["com_offset_modules"] == pytest.approx(np.linalg.norm([2 / 3, 2 / 3, 1.0]))
    rod = np.zeros((3, 3, 3), dtype=int)  # along the middle row, the actuator at one end
    rod[:, 1, 1] = STRUCTURE
    rod[0, 1, 1] = ACTUATOR
    assert symmetry(design_report(rod, spec), size)["mirror_planes"] == 2  # not about x: the types differ
    assert symmetry(DesignReport.of(rod), size).keys() == {"modules", "actuators", "mirror_planes"}


def test_held_curves_wait_for_every_seed(runs):
    a, b = saved_run(RunFolder(runs[("ga", 0)])), saved_run(RunFolder(runs[("ga", 1)]))
    c = held_curves([a, b], "mean_return")
    first = max(a.curve.points[0].env_steps, b.curve.points[0].env_steps)
    assert c["env_steps"][0] == first and c["env_steps"] == sorted(set(c["env_steps"]))
    assert len(c["mean"]) == len(c["std"]) == len(c["env_steps"])


def test_a_figure_some_runs_lack_says_how_many_runs_it_is_over():
    """A run that landed no slew has no median slew time: the table says over how many runs the
    figure is, instead of a mean ± 0 that reads like every seed agreeing."""
    from modsat_core.evaluation.study_report import _mean_std, _pm

    assert _pm(_mean_std([3.93, None]), fmt="{:.2f}") == "3.93 ± 0.00 (1 of 2 runs)"
    assert _pm(_mean_std([1.0, 3.0])) == "2.0 ± 1.4"
    assert _pm(_mean_std([None, None])) == "-"
