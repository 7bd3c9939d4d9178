"""The example of docs/export.md, run as a user would: numpy and onnxruntime only, in a run's
directory, flying a slew with the run's ONNX export."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

from modsat_core.training.train import train

from .test_diffsim import tiny_diffsim

DOC = Path(__file__).resolve().parents[2] / "docs" / "export.md"


def example() -> str:
    """The page's one Python block."""
    (code,) = re.findall(r"```python\n(.*?)```", DOC.read_text(), flags=re.S)
    return code


def test_the_example_flies_a_slew_with_the_onnx_export(tmp_path):
    code = example()
    assert "modsat" not in code and "torch" not in code
    spec = tiny_diffsim()  # the PD law with a learned correction: it lands, trained or not
    files = train(spec).artifacts()
    for name in ("spec.json", "design.json", "policy_export.onnx"):
        (tmp_path / name).write_bytes(files[name])
    (tmp_path / "fly.py").write_text(code)
    out = subprocess.run([sys.executable, "fly.py"], cwd=tmp_path, capture_output=True, text=True, check=True)
    rows = re.findall(r"t = +([\d.]+) s  error = +([\d.]+) deg  rate = ([\d.]+) rad/s", out.stdout)
    t, error, rate = (list(map(float, col)) for col in zip(*rows))
    assert t[0] == 0.0 and t[-1] == 40.0 and len(rows) == 41, out.stdout
    assert abs(error[0] - 90.0) < 1e-9 and rate[0] == 0.0
    assert error[2] < error[1] < error[0]  # slewing
    # landed and held: within the mission's tolerance, slower than its rate tolerance, to the end
    m = spec.mission
    unsettled = [i for i, (e, w) in enumerate(zip(error, rate)) if e > m.tolerance_deg or w > m.rate_tolerance_rad_s]
    assert unsettled[-1] < 10, out.stdout  # settled within 10 s
    assert error[-1] < 0.01 and rate[-1] < 1e-4, out.stdout
