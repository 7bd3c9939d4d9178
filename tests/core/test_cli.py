"""The `modsat` command line, run as a real subprocess."""

import json
import os
import subprocess
import sys

import pytest


def modsat(*args, cwd=None):
    return subprocess.run(
        [sys.executable, "-m", "server.cli", *args], capture_output=True, text=True, timeout=120, cwd=cwd
    )


def test_bench_sim_json_reports_rates_and_ratios():
    r = modsat("bench", "sim", "--json", "--batch", "1", "8", "--seconds", "0.05")
    assert r.returncode == 0, r.stderr
    report = json.loads(r.stdout)
    res = report["results"]
    assert set(res) == {"numpy_1", "torch_1", "torch_8", "slots_8", "slots_32", "slots_128", "slots_900"}
    assert [res[f"slots_{k}"]["slots"] for k in (8, 32, 128, 900)] == [8, 32, 128, 900]
    assert res["numpy_1"]["ratio_to_numpy"] == 1.0
    for v in res.values():
        assert v["control_steps_per_s"] > 0
    assert res["torch_8"]["ratio_to_numpy"] == pytest.approx(
        res["torch_8"]["control_steps_per_s"] / res["numpy_1"]["control_steps_per_s"]
    )


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
    # the REST API's body form, as `POST /api/jobs` takes it
    body = tmp_path / "body.json"
    body.write_text(json.dumps({"preset": "quick", "overrides": {"seed": 3}}))
    assert modsat("check", str(body)).returncode == 0
    body.write_text(json.dumps({"preset": "quick", "overrides": {"seed": -1}}))
    r = modsat("check", str(body))
    assert r.returncode == 2 and "seed: -1 is out of range" in r.stderr
    broken = tmp_path / "broken.json"
    broken.write_bytes(b'{"seed": 3,')
    r = modsat("check", str(broken))
    assert r.returncode == 2 and "is not valid JSON" in r.stderr and "line 1 column 12" in r.stderr
    assert "b'" not in r.stderr and "Traceback" not in r.stderr


def test_bad_flags_get_a_message_not_a_traceback():
    r = modsat("bench", "sim", "--seconds", "-1")
    assert r.returncode == 2 and "--seconds" in r.stderr and "Traceback" not in r.stderr


def test_train_and_eval_commands(tmp_path):
    from ..learning.conftest import tiny_spec

    spec_file = tmp_path / "spec.json"
    spec_file.write_text(tiny_spec().model_dump_json())
    out = tmp_path / "run"
    r = modsat("train", str(spec_file), "--out", str(out), "--steps", "160")
    assert r.returncode == 0, r.stderr
    assert ("policy" in r.stdout and "PD baseline" in r.stdout) or "valid=False" in r.stdout
    names = {p.name for p in out.iterdir()}
    assert {
        "spec.json",
        "curve.json",
        "curve.png",
        "design.json",
        "evaluation.json",
        "trajectories.json",
        "policy.pt",
    } <= names
    assert "checkpoint.pt" not in names  # removed once the run finished
    assert json.loads((out / "spec.json").read_text())["training"]["total_env_steps"] == 160
    r = modsat("eval", str(out), "--episodes", "2", "--json")
    assert r.returncode == 0, r.stderr
    report = json.loads(r.stdout)
    assert report["episodes"] == 2 and report["policy"]["summary"]["episodes"] == 2


def test_eval_flies_the_conditions_asked_for(tmp_path):
    """`modsat eval --conditions`: standard names, `none`, a JSON file; a bad one is a readable error."""
    from ..learning.test_diffsim import tiny_diffsim

    spec_file = tmp_path / "spec.json"
    spec_file.write_text(
        tiny_diffsim(evaluation={"episodes": 3, "trajectories": 1, "conditions": []}).model_dump_json()
    )
    out = tmp_path / "run"
    assert modsat("train", str(spec_file), "--out", str(out)).returncode == 0
    assert json.loads((out / "evaluation.json").read_text())["conditions"] == []  # the spec asked for none
    r = modsat("eval", str(out), "--conditions", "delay-1,tumble")
    assert r.returncode == 0, r.stderr
    rows = [ln.split()[0] for ln in r.stdout.splitlines() if ln.startswith("  ") and ln[2] != " "]
    assert rows == ["condition", "nominal", "delay-1", "tumble"], r.stdout
    custom = tmp_path / "conditions.json"
    custom.write_text(json.dumps(["weak-wheels", {"name": "late-3", "delay_steps": 3}]))
    r = modsat("eval", str(out), "--conditions", str(custom), "--json")
    assert r.returncode == 0, r.stderr
    table = json.loads(r.stdout)["conditions"]
    assert [c["name"] for c in table] == ["weak-wheels", "late-3"] and table[1]["changes"] == {"delay_steps": 3}
    assert {"success_rate", "safety_violations"} <= set(table[1]["pd_baseline"])
    r = modsat("eval", str(out), "--conditions", "nope")
    assert r.returncode == 2 and "unknown condition 'nope'" in r.stderr and "delay-1" in r.stderr


def test_train_and_eval_reject_bad_input(tmp_path):
    r = modsat("train", "--preset", "nope", "--out", str(tmp_path / "x"))
    assert r.returncode == 2 and "unknown preset" in r.stderr
    bad = tmp_path / "bad.json"
    bad.write_text('{"design": {"grid_size": 11}}')
    r = modsat("train", str(bad), "--out", str(tmp_path / "y"))
    assert r.returncode == 2 and "design.grid_size" in r.stderr
    r = modsat("eval", str(tmp_path / "missing"))
    assert r.returncode == 2 and "No such file" in r.stderr
    r = modsat("train", "--out", str(tmp_path / "z"))
    assert r.returncode != 0 and "--preset" in r.stderr


def test_bench_learning_rejects_bad_input_before_training(tmp_path):
    a_file = tmp_path / "file"
    a_file.write_text("")
    for args in (
        ["train", "--preset", "quick-td3", "--out", str(a_file)],
        ["bench", "learn", "--preset", "quick-td3", "--out", str(a_file / "sub")],
    ):
        r = modsat(*args)
        assert r.returncode == 2 and str(a_file) in r.stderr and "Traceback" not in r.stderr
    r = modsat("bench", "rl-vs-ga", "--preset", "quick-td3", "--seeds", "0", "-4")
    assert r.returncode == 2 and "seed: -4 is out of range" in r.stderr
    r = modsat("bench", "rl-vs-ga", "--preset", "quick-td3", "--population", "1")
    assert r.returncode == 2 and "ga.population_size" in r.stderr
    r = modsat("bench", "rl-vs-ga", "--preset", "ga-3x3x3")
    assert r.returncode != 0 and "td3-codesign" in r.stderr
    r = modsat("bench", "learners", "--seeds", "0", "-1", "--no-td3")
    assert r.returncode == 2 and "seed: -1 is out of range" in r.stderr and "Traceback" not in r.stderr
    r = modsat("bench", "designs", "--pool", "0")
    assert r.returncode != 0 and "--pool must be at least 1" in r.stderr and "Traceback" not in r.stderr
    r = modsat("bench", "designs", "--seed", "-1", "--updates", "1")
    assert r.returncode == 2 and "seed: -1 is out of range" in r.stderr and "Traceback" not in r.stderr
    r = modsat("bench", "codesign", "--preset", "quick")
    assert r.returncode != 0 and "not diffsim-codesign" in r.stderr and "Traceback" not in r.stderr
    r = modsat("bench", "codesign", "--preset", "nope")
    assert r.returncode != 0 and "unknown preset 'nope'" in r.stderr and "Traceback" not in r.stderr
    r = modsat("bench", "codesign", "--design-batch", "1")
    assert r.returncode == 2 and "diffsim.design_batch: 1 is out of range" in r.stderr and "Traceback" not in r.stderr
    r = modsat("bench", "codesign", "--design-gradient", "exact")
    assert r.returncode == 2 and "invalid choice: 'exact'" in r.stderr and "Traceback" not in r.stderr
    r = modsat("bench", "pareto", "--preset", "diffsim-3x3x3")
    assert r.returncode != 0 and "not a trade-off" in r.stderr and "Traceback" not in r.stderr
    r = modsat("bench", "pareto", "--designs", "0")
    assert r.returncode != 0 and "--designs must be between 1 and 10,000" in r.stderr and "Traceback" not in r.stderr
    r = modsat("bench", "pareto", "--slews", "1000000")
    assert r.returncode != 0 and "--slews must be between 1 and 1,000" in r.stderr and "Traceback" not in r.stderr
    r = modsat("bench", "pareto", "--seeds", "-1")
    assert r.returncode == 2 and "seed: -1 is out of range" in r.stderr and "Traceback" not in r.stderr
    out = str(tmp_path / "study")
    r = modsat("study", "--preset", "quick-td3", "--seeds", "0", "--algorithms", "diffsim-control", "--out", out)
    assert r.returncode == 2 and "design.fixed_design" in r.stderr and "Traceback" not in r.stderr


def test_sigterm_stops_train_at_a_checkpoint_that_resumes(tmp_path):
    """A scheduler or `kill` sends SIGTERM: the run stops like Ctrl-C, with a checkpoint."""
    import signal
    import time

    from ..learning.conftest import tiny_spec

    spec_file = tmp_path / "spec.json"
    spec_file.write_text(
        tiny_spec(
            training__total_env_steps=200_000, training__checkpoint_every_steps=160, training__eval_every_steps=100_000
        ).model_dump_json()
    )
    out = tmp_path / "run"
    p = subprocess.Popen(
        [sys.executable, "-m", "server.cli", "train", str(spec_file), "--out", str(out)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, "MODSAT_MAX_CHECKPOINTS": ""},  # a checkpoint every 160 of 200,000 steps: 1,250
    )
    deadline = time.monotonic() + 120
    while not (out / "checkpoint.pt").exists() and time.monotonic() < deadline and p.poll() is None:
        time.sleep(0.2)
    p.send_signal(signal.SIGTERM)
    _, err = p.communicate(timeout=120)
    assert p.returncode == 130, err
    assert "--resume" in err and (out / "checkpoint.pt").exists()


def test_a_closed_pipe_is_silent():
    """`modsat schema | head -c 10`: the reader has left; no 'Broken pipe' message, no traceback."""
    p = subprocess.Popen([sys.executable, "-m", "server.cli", "schema"], stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    p.stdout.close()  # before the 23 kB of schema are written
    err = p.stderr.read().decode()
    assert p.wait(60) == 141, err  # as a shell reports a command ended by SIGPIPE
    assert err == "", err


def test_progress_eta_follows_the_recent_rate():
    import io

    from server.cli import _ProgressBar

    clock = [0.0]
    bar = _ProgressBar(io.StringIO())
    bar.time = lambda: clock[0]
    for t, steps in ((0, 0), (100, 100_000), (200, 200_000), (300, 201_000)):  # the machine got 100x slower
        clock[0] = float(t)
        bar(
            {
                "env_steps": steps,
                "total_env_steps": 300_000,
                "phase": "training",
                "eval": {"mean_return": 1.0, "success_rate": 0.0},
            }
        )
    line = bar.stream.getvalue().splitlines()[-1]
    assert "10 steps/s" in line and "eta 9,900 s" in line, line


def test_progress_says_what_the_final_evaluation_flies():
    """After training no steps/s nor ETA (there are no steps left): the evaluation's stage and its time."""
    import io

    from server.cli import _ProgressBar

    clock = [0.0]
    bar = _ProgressBar(io.StringIO())
    bar.time = lambda: clock[0]
    bar({"env_steps": 100, "total_env_steps": 100, "phase": "training"})
    for t, stage in ((10.0, None), (40.0, "3/4: the policy on 100 slews under each of 9 flight conditions")):
        clock[0] = t
        bar({"env_steps": 100, "total_env_steps": 100, "phase": "evaluating", "stage": stage})
    lines = bar.stream.getvalue().splitlines()
    assert lines[-1] == "final evaluation (30 s): flying 3/4: the policy on 100 slews under each of 9 flight conditions"
    assert "steps/s" not in lines[-1] and "nan" not in bar.stream.getvalue()
