"""Training runs: ``train()`` dispatches the spec's ``algorithm`` to one of five learners:

- ``td3-codesign``: TD3 co-design of the shape and its controller (:class:`TD3Run`);
- ``td3-control``: TD3 control of a fixed design (:class:`TD3Run` without its design phase);
- ``ga``: the genetic-algorithm baseline, a TD3 controller per design (:class:`GARun`);
- ``diffsim-control``: the first-order learner, backpropagation through the simulator
  (:class:`DiffsimRun`);
- ``diffsim-codesign``: the first-order learner with a learned design distribution
  (:class:`DiffsimCodesignRun`), or its trade-off front when the objective prices mass
  (:class:`ParetoRun`).

``train(spec, ...)`` is the one entry point (the worker and the CLI call it); its contract
is written in docs/train-interface.md. It does no I/O and never reads the clock: progress,
checkpoints and stopping go through the three callbacks, and the finished run's files come
back as bytes from :meth:`RunResult.artifacts`.

Environment steps are MDP steps: a design step and a control step count one each, per
parallel episode. Learning-curve and final evaluations are not counted. Steps are taken in
batches of ``training.num_envs``; a run never exceeds its budget (it stops before a batch
that would), so it may end up to ``num_envs - 1`` steps short of it.
"""

from __future__ import annotations

import torch

from modsat_core.artefacts import ProgressRecord
from modsat_core.evaluation.run_files import run_files
from modsat_core.spec.jobspec import JobSpec, UnrunnableSpec, is_diffsim
from modsat_core.training.callbacks import CheckpointFn, ProgressFn, StopFn
from modsat_core.training.checkpoint import CHECKPOINT_VERSION, to_device
from modsat_core.training.diffsim import DiffsimRun
from modsat_core.training.diffsim_codesign import DiffsimCodesignRun
from modsat_core.training.diffsim_pareto import ParetoRun
from modsat_core.training.ga import GARun
from modsat_core.training.result import RunResult
from modsat_core.training.td3_trainer import TD3Run


def resolve_device(name: str) -> str:
    """The torch device of ``training.device``: ``auto`` is cuda where torch sees a GPU, else cpu."""
    if name == "auto":
        return "cuda" if torch.cuda.is_available() else "cpu"
    if name == "cuda" and not torch.cuda.is_available():
        raise UnrunnableSpec("training.device is 'cuda' but torch sees no GPU on this machine; use 'auto' or 'cpu'")
    return name


def _noop(*_a, **_k):
    return None


def _never() -> bool:
    return False


def train(
    spec: JobSpec,
    *,
    on_progress: ProgressFn | None = None,
    on_checkpoint: CheckpointFn | None = None,
    should_stop: StopFn | None = None,
    checkpoint: dict | None = None,
) -> RunResult:
    """Run ``spec`` to the end of its env-step budget (or until ``should_stop``).

    See docs/train-interface.md. Resuming from ``checkpoint`` continues the same run.
    """
    on_progress, on_checkpoint, should_stop = on_progress or _noop, on_checkpoint or _noop, should_stop or _never
    if checkpoint is not None and checkpoint.get("version") != CHECKPOINT_VERSION:
        raise ValueError("checkpoint from an incompatible modsat version")
    if spec.algorithm == "ga":
        return GARun(spec, device=resolve_device(spec.training.device)).train(
            on_progress, on_checkpoint, should_stop, checkpoint
        )
    device = resolve_device(spec.training.device)
    run: TD3Run | DiffsimRun
    if spec.algorithm == "diffsim-codesign" and spec.objective.trade_off_prices_s_per_kg:
        run = ParetoRun(spec, device=device)
    elif spec.algorithm == "diffsim-codesign":
        run = DiffsimCodesignRun(spec, device=device)
    else:
        run = DiffsimRun(spec, device=device) if is_diffsim(spec) else TD3Run(spec, device=device)
    if checkpoint is not None:
        run.load_state_dict(to_device(checkpoint["run"], device))

    def wrap(state: dict) -> None:
        on_checkpoint(
            {"version": CHECKPOINT_VERSION, "algorithm": spec.algorithm, "env_steps": state["env_steps"], "run": state}
        )

    stopped = run.run(on_progress, wrap, should_stop)
    if stopped:
        return RunResult(stopped=True, env_steps=run.env_steps, curve=run.curve)

    def evaluating(stage: str | None) -> None:
        on_progress(
            ProgressRecord(
                env_steps=run.env_steps,
                total_env_steps=spec.training.total_env_steps,
                updates=run.updates,
                phase="evaluating",
                stage=stage,
                eval=None,
            ).to_dict()
        )

    evaluating(None)
    if isinstance(run, (ParetoRun, DiffsimCodesignRun)):  # the kept design's (or the front's) flights come first
        run.on_stage = evaluating
    actor, grid, chosen = run.chosen()
    files, summary = run_files(
        spec, run.curve, actor, grid, chosen, on_stage=lambda i, n, what: evaluating(f"{i}/{n}: {what}")
    )
    return RunResult(stopped=False, env_steps=run.env_steps, curve=run.curve, files=files, summary=summary)
