"""The `modsat` command line, run as a real subprocess."""

import json
import os
import subprocess
import sys

import pytest


def modsat(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "modsat_core.cli", *args], capture_output=True, text=True,
                          timeout=120, cwd=cwd)


def test_bench_sim_json_reports_rates_and_ratios():
    r = modsat("bench", "sim", "--json", "--batch", "1", "8", "--seconds", "0.05")
    assert r.returncode == 0, r.stderr
    report = json.loads(r.stdout)
    res = report["results"]
    assert set(res) == {"numpy_1", "torch_1", "torch_8"}
    assert res["numpy_1"]["ratio_to_numpy"] == 1.0
    for v in res.values():
        assert v["control_steps_per_s"] > 0
    assert res["torch_8"]["ratio_to_numpy"] == pytest.approx(
        res["torch_8"]["control_steps_per_s"] / res["numpy_1"]["control_steps_per_s"])


def test_presets_and_schema():
    r = modsat("presets")
    assert r.returncode == 0 and "paper-5x5x5" in r.stdout and "quick" in r.stdout
    r = modsat("presets", "quick")
    assert json.loads(r.stdout)["name"] == "quick"
    r = modsat("presets", "nope")
    assert r.returncode == 2 and "unknown preset 'nope'" in r.stderr and "Traceback" not in r.stderr
    assert "JobSpec" in modsat("schema").stdout


def test_check_reports_readable_errors(tmp_path):
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"design": {"grid_size": 11}, "colour": "red"}))
    r = modsat("check", str(bad))
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert "design.grid_size: 11 is out of range; allowed: >= 2 and <= 10" in r.stderr
    assert "colour: unknown field" in r.stderr
    good = tmp_path / "good.json"
    good.write_text(json.dumps({"seed": 3}))
    assert modsat("check", str(good)).returncode == 0
    r = modsat("check", str(tmp_path / "missing.json"))
    assert r.returncode == 2 and "No such file" in r.stderr


def test_bad_flags_get_a_message_not_a_traceback():
    r = modsat("bench", "sim", "--seconds", "-1")
    assert r.returncode == 2 and "--seconds" in r.stderr and "Traceback" not in r.stderr
