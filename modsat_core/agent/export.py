"""A trained policy's standalone controller in the formats other software loads (docs/export.md).

Every run with a valid design writes the controller of :func:`~modsat_core.agent.policy.exported`,
``forward(q_BT (B, 4), omega_B (B, 3), h_B (B, K, 3)) -> per-unit body torque command (B, K, 3)``
(and a fourth input, ``tau_last_B`` (B, K, 3), the command it returned at the previous control step,
for a TD3 policy that observes its last command: `training.observe_last_command`), in three files:

``policy_export.pt2``
    A ``torch.export`` program (``torch.export.load(path).module()``), batch size dynamic.
``policy_export.onnx``
    The same program in ONNX (opset 20), for onnxruntime and flight software without torch. Its
    ``metadata_props`` carry the conventions (:func:`onnx_metadata`, modsat_core.agent.onnx_meta).
``policy_export.pt``
    TorchScript (``torch.jit.load``), deprecated in torch 2.13 but kept: it is what runs from
    before these formats carry, ``modsat verify`` reads, and any torch since 1.x loads.

A format whose exporter fails (an exporter bug, a torch too old for it) is left out with a
warning naming the format and why; the run's other files are written as ever.
"""

from __future__ import annotations

import io
import logging
import warnings
from collections.abc import Callable

import numpy as np
import torch
from torch import Tensor, nn

import modsat_core
from modsat_core.agent.networks import observes_last_command
from modsat_core.agent.onnx_meta import conventions, with_metadata
from modsat_core.agent.policy import exported
from modsat_core.grid import ACTUATOR
from modsat_core.sim.slew import Design
from modsat_core.spec.jobspec import JobSpec

log = logging.getLogger(__name__)

#: The exported controller's inputs and output, by name (the ONNX graph's names too).
INPUT_NAMES = ("q_BT", "omega_B", "h_B")
#: ... and the fourth input of a policy that observes its last command (`training.observe_last_command`).
LAST_COMMAND_INPUT = "tau_last_B"
OUTPUT_NAME = "tau_cmd_B"
#: ONNX operator set of ``policy_export.onnx``.
ONNX_OPSET = 20


def export_torchscript(actor: nn.Module, grid: np.ndarray, spec: JobSpec) -> bytes:
    """TorchScript bytes of :func:`exported` (load with ``torch.jit.load``)."""
    with warnings.catch_warnings():
        # TorchScript is deprecated in favour of torch.export but still the format that
        # loads with one call (torch.jit.load) in any torch since 1.x; see docs/export.md.
        warnings.simplefilter("ignore", DeprecationWarning)
        module = torch.jit.script(exported(actor, grid, spec).eval())
        buf = io.BytesIO()
        torch.jit.save(module, buf)
    return buf.getvalue()


def input_names(actor: nn.Module) -> tuple[str, ...]:
    """The exported controller's inputs: :data:`INPUT_NAMES`, and :data:`LAST_COMMAND_INPUT` last where
    the actor observes its last command."""
    return (*INPUT_NAMES, LAST_COMMAND_INPUT) if observes_last_command(actor) else INPUT_NAMES


def example_inputs(n_wheels: int, batch: int = 2, last_command: bool = False) -> tuple[Tensor, ...]:
    """Inputs of the exported controller (float32): a unit quaternion, a rate, wheel momenta (and, with
    ``last_command``, a last command).

    ``batch`` >= 2: torch.export fixes a dimension whose example size is 1."""
    gen = torch.Generator().manual_seed(0)
    q = torch.nn.functional.normalize(torch.randn(batch, 4, generator=gen), dim=-1)
    out: tuple[Tensor, ...] = (
        q,
        0.01 * torch.randn(batch, 3, generator=gen),
        0.001 * torch.randn(batch, n_wheels, 3, generator=gen),
    )
    if last_command:
        out = (*out, 0.01 * torch.randn(batch, n_wheels, 3, generator=gen))
    return out


def export_program(actor: nn.Module, grid: np.ndarray, spec: JobSpec) -> torch.export.ExportedProgram:
    """:func:`exported` captured by ``torch.export`` for float32 inputs of any batch size."""
    K = int((np.asarray(grid) >= ACTUATOR).sum())
    batch = torch.export.Dim.DYNAMIC
    names = input_names(actor)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", FutureWarning)  # torch's own pytree deprecations
        return torch.export.export(
            exported(actor, grid, spec).eval(),
            example_inputs(K, last_command=len(names) > len(INPUT_NAMES)),
            dynamic_shapes={name: {0: batch} for name in names},
        )


def program_bytes(program: torch.export.ExportedProgram) -> bytes:
    """``policy_export.pt2``: the program as ``torch.export.save`` writes it."""
    buf = io.BytesIO()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", FutureWarning)
        torch.export.save(program, buf)
    return buf.getvalue()


def onnx_bytes(program: torch.export.ExportedProgram, names: tuple[str, ...] = INPUT_NAMES) -> bytes:
    """``policy_export.onnx``: the program translated by torch's exporter (needs ``onnxscript``), its
    inputs named ``names``."""
    onnx_logger = logging.getLogger("torch.onnx")
    level = onnx_logger.level
    onnx_logger.setLevel(logging.ERROR)  # it lists every optional operator library it skips (torchvision)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", FutureWarning)
            onnx_program = torch.onnx.export(
                program,
                dynamo=True,
                input_names=list(names),
                output_names=[OUTPUT_NAME],
                opset_version=ONNX_OPSET,
                verbose=False,
            )
    finally:
        onnx_logger.setLevel(level)
    if onnx_program is None:  # only the legacy (TorchScript) exporter returns None
        raise RuntimeError("torch.onnx.export returned no program")
    return onnx_program.model_proto.SerializeToString()


def _onnx_with_metadata(data: bytes, grid: np.ndarray, spec: JobSpec, doc: str, last_command: bool = False) -> bytes:
    """The ONNX file with its conventions as metadata, or without them (said on stderr) where they cannot
    be worked out: the controller is worth shipping either way."""
    try:
        return with_metadata(data, onnx_metadata(grid, spec, last_command=last_command), doc)
    except Exception as exc:
        _left_out("policy_export.onnx's metadata", exc)
        return data


def onnx_metadata(
    grid: np.ndarray, spec: JobSpec, job_id: int | None = None, last_command: bool = False
) -> dict[str, str]:
    """The ONNX file's ``metadata_props``: control step, torque scale, wheel order and frames, the
    hash of the run's ``spec.json``, the job id (empty where the run does not know it: the worker stamps
    it), modsat's version, the input and output layout (``last_command``: with ``tau_last_B``) and the
    design (docs/export.md)."""
    torque_max = spec.modules.torque_scale_Nm * Design.from_grid(grid, spec.modules).slot_weights()[0]
    return conventions(
        version=modsat_core.__version__,
        spec_json=spec.model_dump_json(indent=2),  # the bytes of the run's spec.json
        algorithm=spec.algorithm,
        control_dt_s=spec.mission.control_dt_s,
        torque_scale_Nm=spec.modules.torque_scale_Nm,
        unit_torque_max_Nm=[float(t) for t in torque_max],
        grid=np.asarray(grid).tolist(),
        job_id=job_id,
        last_command=last_command,
    )


def export_files(actor: nn.Module, grid: np.ndarray, spec: JobSpec) -> dict[str, bytes]:
    """The standalone controller's files of a run (the module docstring): those that could be
    written. An exporter that fails is reported (a warning) and its file left out: a finished run
    is never lost to an exporter (torch.export and the ONNX translation raise many kinds of errors)."""
    files = {"policy_export.pt": export_torchscript(actor, grid, spec)}
    try:
        program = export_program(actor, grid, spec)
    except Exception as exc:
        _left_out("policy_export.pt2 and policy_export.onnx", exc)
        return files
    names = input_names(actor)
    last = len(names) > len(INPUT_NAMES)
    doc = f"modsat attitude controller: {OUTPUT_NAME} = controller({', '.join(names)}); see metadata_props"
    writers: dict[str, Callable[[torch.export.ExportedProgram], bytes]] = {
        "policy_export.pt2": program_bytes,
        "policy_export.onnx": lambda p: _onnx_with_metadata(onnx_bytes(p, names), grid, spec, doc, last),
    }
    for name, write in writers.items():
        try:
            files[name] = write(program)
        except Exception as exc:
            _left_out(name, exc)
    return files


def _left_out(what: str, exc: Exception) -> None:
    hint = " (install onnxscript: pip install onnx onnxscript)" if isinstance(exc, ImportError) else ""
    log.warning("%s left out of the run's files: %s: %s%s", what, type(exc).__name__, exc, hint)
