"""docs/reproduction.md's table is the report of the runs kept for it (tests/data/reproduction/): redrawn
from their files, it must come out the same, and the page must show it (a rerun or an edit of either
shows up here)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from modsat_core.evaluation.run_folder import RunFolder
from modsat_core.evaluation.study_report import saved_run, study, table_markdown

ROOT = Path(__file__).resolve().parents[2]
DOCS = ROOT / "docs"
KEPT = ROOT / "tests" / "data" / "reproduction"


@pytest.mark.parametrize(("grid", "seeds"), [("3x3x3", 3), ("5x5x5", 3)])
def test_the_reproduction_table_is_the_report_of_the_kept_runs(grid, seeds):
    root = KEPT / grid
    runs = [saved_run(RunFolder(p)) for p in sorted((root / "runs").iterdir())]
    result = study(runs)
    assert {label: a["finished"] for label, a in result["algorithms"].items()} == {"RL co-design": seeds, "GA": seeds}
    table = table_markdown(result)
    assert table == (root / "report" / "table.md").read_text()
    assert table in (DOCS / "reproduction.md").read_text()
    kept = json.loads((root / "report" / "study.json").read_text())
    for label, a in result["algorithms"].items():
        assert kept["algorithms"][label]["policy"] == a["policy"]
        assert kept["algorithms"][label]["curves"] == a["curves"]
