"""The conventions an exported controller's ``policy_export.onnx`` carries as ONNX ``metadata_props``
(docs/export.md, "What the ONNX file says about itself"), so that the file alone says how to fly it.

Torch-free (``onnx`` only): the export writes the props (:func:`conventions`, :func:`with_metadata`)
and the worker, which knows the job's id, stamps it on the stored file (:func:`stamp_job_id`).
Read them back with ``onnxruntime.InferenceSession(path).get_modelmeta().custom_metadata_map`` or
``{p.key: p.value for p in onnx.load(path).metadata_props}``.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Mapping
from typing import Any

#: Every key the export writes (a reader may rely on them; values are strings).
KEYS = (
    "modsat.version",
    "modsat.job_id",
    "modsat.spec_sha256",
    "modsat.algorithm",
    "modsat.control_dt_s",
    "modsat.torque_scale_Nm",
    "modsat.unit_torque_max_Nm",
    "modsat.wheel_units",
    "modsat.wheel_order",
    "modsat.frames",
    "modsat.inputs",
    "modsat.outputs",
    "modsat.design_grid",
)

WHEEL_ORDER = (
    "unit k is the k-th wheel-unit cell (grid value >= 2) of design_grid in row-major order of grid[i][j][k] "
    "(i slowest, k fastest): numpy.flatnonzero(grid.reshape(-1) >= 2)"
)
FRAMES = (
    "B: body frame, origin at the centre of mass, axes along the grid's i, j, k; T: target frame, inertially "
    "fixed; quaternions scalar first (w, x, y, z), Hamilton product; q_BT = conj(q_TN) * q_BN, attitude of B "
    "relative to T; either sign of q_BT gives the same command; hold each command for control_dt_s"
)
INPUTS = (
    "q_BT (B, 4) float32 error quaternion w,x,y,z, unit; omega_B (B, 3) float32 body rate rad/s in B; "
    "h_B (B, K, 3) float32 momentum of each wheel unit N m s in B (zeros for ideal-torque); B free, K = wheel_units"
)
#: Appended to INPUTS for a controller that observes its last command (`training.observe_last_command`).
LAST_COMMAND_INPUT = (
    "; tau_last_B (B, K, 3) float32 the tau_cmd_B this controller returned at the previous control step, N m "
    "(zeros at a slew's first step): feed its output back, it keeps no memory"
)
OUTPUTS = (
    "tau_cmd_B (B, K, 3) float32 body torque command of each wheel unit, N m in B, each component within "
    "+-unit_torque_max_Nm; the wheel gets -tau (dh_k/dt = -tau_k)"
)


def spec_sha256(spec_json: str | bytes) -> str:
    """SHA-256 of the run's ``spec.json`` as the run writes it (``sha256sum spec.json`` gives the same)."""
    return hashlib.sha256(spec_json.encode() if isinstance(spec_json, str) else spec_json).hexdigest()


def conventions(
    *,
    version: str,
    spec_json: str,
    algorithm: str,
    control_dt_s: float,
    torque_scale_Nm: float,
    unit_torque_max_Nm: list[float],
    grid: list,
    job_id: int | str | None = None,
    last_command: bool = False,
) -> dict[str, str]:
    """The metadata of one exported controller, every value a string (ONNX's ``StringStringEntryProto``)."""
    props: dict[str, Any] = {
        "modsat.version": version,
        "modsat.job_id": "" if job_id is None else str(job_id),
        "modsat.spec_sha256": spec_sha256(spec_json),
        "modsat.algorithm": algorithm,
        "modsat.control_dt_s": repr(float(control_dt_s)),
        "modsat.torque_scale_Nm": repr(float(torque_scale_Nm)),
        "modsat.unit_torque_max_Nm": json.dumps([float(t) for t in unit_torque_max_Nm]),
        "modsat.wheel_units": str(len(unit_torque_max_Nm)),
        "modsat.wheel_order": WHEEL_ORDER,
        "modsat.frames": FRAMES,
        "modsat.inputs": INPUTS + (LAST_COMMAND_INPUT if last_command else ""),
        "modsat.outputs": OUTPUTS,
        "modsat.design_grid": json.dumps(grid, separators=(",", ":")),
    }
    return {k: str(props[k]) for k in KEYS}


def with_metadata(onnx_bytes: bytes, props: Mapping[str, str], doc: str | None = None) -> bytes:
    """``onnx_bytes`` with ``props`` set in its ``metadata_props`` (replacing keys already there)."""
    import onnx

    model = onnx.load_model_from_string(onnx_bytes)
    kept = [p for p in model.metadata_props if p.key not in props]
    del model.metadata_props[:]
    model.metadata_props.extend(kept)
    for key, value in props.items():
        entry = model.metadata_props.add()
        entry.key, entry.value = key, str(value)
    if doc is not None:
        model.doc_string = doc
    return model.SerializeToString()


def read_metadata(onnx_bytes: bytes) -> dict[str, str]:
    import onnx

    return {p.key: p.value for p in onnx.load_model_from_string(onnx_bytes).metadata_props}


def stamp_job_id(files: dict[str, bytes], job_id: int) -> dict[str, bytes]:
    """A finished job's files with ``modsat.job_id`` set in its ONNX export (the run itself cannot
    know the id). A file that does not parse, or a machine without ``onnx``, keeps the file as it is."""
    name = "policy_export.onnx"
    if name not in files:
        return files
    try:
        stamped = with_metadata(files[name], {"modsat.job_id": str(job_id)})
    except Exception:  # an unreadable export is served as written, never lost
        return files
    return {**files, name: stamped}
