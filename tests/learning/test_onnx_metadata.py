"""Issue 46: ``policy_export.onnx`` carries its conventions as ``metadata_props`` (docs/export.md, "What
the ONNX file says about itself"), read back with onnxruntime and with onnx; the worker stamps the job id."""

from __future__ import annotations

import contextlib
import hashlib
import io
import json
import os
import re
from pathlib import Path

import numpy as np
import onnx
import onnxruntime as ort
import torch

import modsat_core
from modsat_core.agent.export import export_files
from modsat_core.agent.networks import make_actor
from modsat_core.agent.onnx_meta import KEYS, read_metadata, stamp_job_id
from modsat_core.codesign.features import N_FEATURES

from .conftest import tiny_spec

DOC = Path(__file__).resolve().parents[2] / "docs" / "export.md"


def test_a_runs_onnx_file_says_how_to_fly_it(tmp_path):
    spec = tiny_spec(design={"grid_size": 3})
    grid = np.ones((3, 3, 3), dtype=np.int64)
    grid[0, 1, 1] = grid[1, 1, 1] = grid[2, 0, 2] = 2
    torch.manual_seed(0)
    actor = make_actor("per-module", N_FEATURES, [16, 16], False).eval()
    files = export_files(actor, grid, spec)
    path = tmp_path / "policy_export.onnx"
    path.write_bytes(files["policy_export.onnx"])
    (tmp_path / "spec.json").write_text(spec.model_dump_json(indent=2))  # as a run writes it

    meta = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"]).get_modelmeta().custom_metadata_map
    assert set(KEYS) <= set(meta)
    assert {p.key: p.value for p in onnx.load(str(path)).metadata_props} == meta  # onnx reads the same
    assert float(meta["modsat.control_dt_s"]) == spec.mission.control_dt_s
    assert float(meta["modsat.torque_scale_Nm"]) == spec.modules.torque_scale_Nm == 0.05
    assert json.loads(meta["modsat.unit_torque_max_Nm"]) == [0.05, 0.05, 0.05]
    assert meta["modsat.wheel_units"] == "3"
    assert "row-major" in meta["modsat.wheel_order"] and "q_BT" in meta["modsat.frames"]
    assert meta["modsat.spec_sha256"] == hashlib.sha256((tmp_path / "spec.json").read_bytes()).hexdigest()
    assert meta["modsat.job_id"] == ""  # the run does not know it
    assert meta["modsat.version"] == modsat_core.__version__
    assert meta["modsat.algorithm"] == spec.algorithm
    assert "q_BT (B, 4)" in meta["modsat.inputs"] and "tau_cmd_B (B, K, 3)" in meta["modsat.outputs"]
    assert json.loads(meta["modsat.design_grid"]) == grid.tolist()
    # the metadata does not change the controller: it still runs
    sess = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    q = np.array([[1.0, 0.0, 0.0, 0.0]], np.float32)
    out = sess.run(None, {"q_BT": q, "omega_B": np.zeros((1, 3), np.float32), "h_B": np.zeros((1, 3, 3), np.float32)})
    assert out[0].shape == (1, 3, 3)

    # docs/export.md's block that reads them, run in the run's folder
    (block,) = re.findall(r"```py\n(.*?)```", DOC.read_text(), flags=re.S)
    cwd, printed, scope = os.getcwd(), io.StringIO(), {}
    try:
        os.chdir(tmp_path)
        with contextlib.redirect_stdout(printed):
            exec(block, scope)
    finally:
        os.chdir(cwd)
    assert scope["meta"] == scope["same"] == meta
    assert printed.getvalue().split() == [meta["modsat.control_dt_s"], "0.05"]

    stamped = stamp_job_id(files, 42)
    assert read_metadata(stamped["policy_export.onnx"])["modsat.job_id"] == "42"
    assert {k: v for k, v in read_metadata(stamped["policy_export.onnx"]).items() if k != "modsat.job_id"} == {
        k: v for k, v in meta.items() if k != "modsat.job_id"
    }
    assert stamped["policy_export.pt"] is files["policy_export.pt"]
    assert stamp_job_id({"policy_export.onnx": b"not onnx"}, 1) == {"policy_export.onnx": b"not onnx"}
