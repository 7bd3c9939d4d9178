"""`modsat bench update`: the per-update cost of each network (mechanics, on tiny sizes)."""

from __future__ import annotations

import json

import pytest

from modsat_core.bench.update import bench_update
from server.cli import main


def test_report_has_every_network_and_its_ratio_to_flat_per_grid():
    r = bench_update(grids=(2, 3), hidden=(16, 16), batch=8, rounds=1)
    assert r["threads"] == 1 and r["batch_size"] == 8 and r["hidden_sizes"] == [16, 16]
    assert set(r["results"]) == {"2x2x2", "3x3x3"}
    for grid, row in r["results"].items():
        for net in ("flat", "per-module", "set"):
            assert row[f"{net}_ms"] > 0
        for net in ("per-module", "set"):
            assert row[f"{net}_ratio"] == pytest.approx(row[f"{net}_ms"] / row["flat_ms"], rel=0.02, abs=0.01)
        assert row["cells"] == int(grid[0]) ** 3


def test_cli_prints_json_and_rejects_bad_sizes(capsys):
    assert (
        main(["bench", "update", "--json", "--grids", "2", "--hidden", "8", "8", "--batch-size", "4", "--rounds", "1"])
        == 0
    )
    out = json.loads(capsys.readouterr().out)
    assert set(out["results"]["2x2x2"]) >= {"flat_ms", "per-module_ms", "set_ms", "set_ratio", "per-module_ratio"}
    with pytest.raises(SystemExit, match="--grids between"):
        main(["bench", "update", "--grids", "11"])
    with pytest.raises(SystemExit, match="at most 256,000"):  # would hold 65,536,000 cell rows per layer
        main(["bench", "update", "--grids", "10", "--batch-size", "65536"])
