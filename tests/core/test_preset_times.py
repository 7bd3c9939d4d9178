"""The measured time per run of each preset has one source (modsat_core.spec.preset_times): the
README's "What the presets land" table shows the same figures, CPU named, cell for cell."""

from __future__ import annotations

import fnmatch
import re
from pathlib import Path

from modsat_core.spec.preset_times import NOT_MEASURED, PRESET_TIMES, run_time_text
from modsat_core.spec.presets import PRESETS

README = Path(__file__).resolve().parents[2] / "README.md"


def readme_time_cells() -> dict[str, str]:
    """Preset name -> the README table's "time per run (CPU)" cell (a row naming `ga-*` names each
    preset it matches)."""
    text = README.read_text()
    section = text[text.index("## What the presets land") :]
    rows = [ln for ln in section.split("\n## ")[0].splitlines() if ln.startswith("| `")]
    out: dict[str, str] = {}
    for row in rows:
        cells = [c.strip() for c in row.strip().strip("|").split("|")]
        for pattern in re.findall(r"`([^`]+)`", cells[0]):
            names = fnmatch.filter(PRESETS, pattern)
            assert names, f"the README names {pattern!r}, which is no preset"
            for name in names:
                assert name not in out, f"the README has two rows for {name}"
                out[name] = cells[-1]
    return out


def test_the_readmes_time_column_is_the_data_modules():
    cells = readme_time_cells()
    assert set(cells) == set(PRESETS), "every preset has a row"
    assert set(PRESET_TIMES) <= set(PRESETS)
    for name in PRESETS:
        assert cells[name] == run_time_text(name), name


def test_every_figure_names_its_cpu_and_no_preset_borrows_one():
    for name, times in PRESET_TIMES.items():
        assert times and all(t.cpu and t.time and t.cpu not in t.time for t in times), name
    assert run_time_text("paper-3x3x3") == NOT_MEASURED and "paper-3x3x3" not in PRESET_TIMES
    assert run_time_text("cpu-3x3x3") == "42-44 min (AMD EPYC); 46.7 min (Intel Xeon)"
