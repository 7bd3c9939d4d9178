"""Issue 46: `modsat eval` says what it flies while it flies (it printed nothing for about a minute),
and `modsat presets` aligns its columns whatever the preset names' lengths."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import torch

from modsat_core.agent.networks import make_actor
from modsat_core.agent.policy_file import policy_bytes
from modsat_core.codesign.features import N_FEATURES
from modsat_core.evaluation.run_files import final_evaluation
from modsat_core.spec.presets import PRESETS
from server.cli.run import presets_table

from .conftest import tiny_spec

MODSAT = str(Path(sys.executable).with_name("modsat"))


def test_modsat_eval_prints_a_line_per_stage_before_its_table(tmp_path):
    spec = tiny_spec(design={"grid_size": 3}, evaluation={"episodes": 2, "trajectories": 1})
    grid = np.ones((3, 3, 3), dtype=np.int64)
    grid[1, 1, 1] = 2
    torch.manual_seed(0)
    actor = make_actor("per-module", N_FEATURES, [16, 16], False).eval()
    (tmp_path / "policy.pt").write_bytes(policy_bytes(actor, grid, spec))
    r = subprocess.run(
        [MODSAT, "eval", str(tmp_path), "--episodes", "2", "--conditions", "delay-1,tumble"],
        capture_output=True,
        text=True,
        timeout=300,
        env={"OMP_NUM_THREADS": "1", "PATH": "/usr/bin:/bin"},
    )
    assert r.returncode == 0, r.stderr
    lines = [ln for ln in r.stderr.splitlines() if ln.startswith("modsat eval: [")]
    assert [ln.split("]")[0][-3:] for ln in lines] == ["1/4", "2/4", "3/4", "4/4"]
    assert "delay-1, tumble" in lines[2]
    assert "done in" in r.stderr and "policy" in r.stdout


def test_the_evaluation_numbers_its_stages_out_of_those_it_runs():
    """The stage numbers are counted, not written down: without flight conditions 2 of 2, with them 4 of 4."""
    grid = np.ones((3, 3, 3), dtype=np.int64)
    grid[1, 1, 1] = 2
    torch.manual_seed(0)
    actor = make_actor("per-module", N_FEATURES, [16, 16], False).eval()
    for conditions, total in (([], 2), (["delay-1"], 4)):
        spec = tiny_spec(
            design={"grid_size": 3}, evaluation={"episodes": 1, "trajectories": 0, "conditions": conditions}
        )
        told: list[tuple[int, int]] = []
        final_evaluation(actor, grid, spec, on_stage=lambda i, n, _what, told=told: told.append((i, n)))
        assert told == [(i, total) for i in range(1, total + 1)]


def test_presets_columns_align_for_every_name_length():
    many = {**PRESETS, "x": PRESETS["quick"], "a-much-longer-preset-name-than-any": PRESETS["paper-5x5x5"]}
    for presets in (PRESETS, many):
        lines = presets_table(presets).splitlines()
        assert len(lines) == len(presets)
        # the algorithm column starts at the same place on every line
        algo = [ln.index(p.algorithm, len(n)) for ln, (n, p) in zip(lines, presets.items(), strict=True)]
        size = [  # where the grid column starts ("3x3x3", "10x10x10")
            ln.index(f"{p.design.grid_size}x{p.design.grid_size}x{p.design.grid_size}", a + len(p.algorithm))
            for ln, a, p in zip(lines, algo, presets.values(), strict=True)
        ]
        assert len(set(algo)) == 1 and len(set(size)) == 1, lines
        assert len({ln.index(" env steps") for ln in lines}) == 1, lines  # the numbers end together
