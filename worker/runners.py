"""What a job runs. The default is ``modsat_core.training.train.train`` (through worker/train_runner.py,
which adds the ``evaluation.viser`` recording to a finished run's files); the others are real runners
that follow the same contract (docs/train-interface.md) for tests and benchmarks of the
queue, without the cost of training:

* ``noop``: returns at once with one small artefact.
* ``simulated``: counts environment steps at ``MODSAT_SIM_STEPS_PER_S`` (default 2000) in
  ticks of ``training.num_envs`` steps, reports progress and learning-curve points, writes
  checkpoints every ``training.checkpoint_every_steps`` and resumes from them, honours
  ``should_stop``. Its artefact ``run.json`` records where it resumed from.
* ``raise``: raises ``RuntimeError`` (the message names the job's seed).

A runner is named by the ``runner`` setting: one of the names above, ``train``, or
``package.module:function`` (the hook for runners outside this package, e.g. the tests';
imported by name). ``train`` and the runners above are plain imports. A runner module may
define ``checkpoint_to_bytes`` and ``checkpoint_from_bytes``; otherwise checkpoints are pickled.
"""

from __future__ import annotations

import importlib
import json
import os
import pickle
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from modsat_core.artefacts import CurvePoint, ProgressRecord

#: The runners of this package by name (``train`` is the default; the others are functions below).
RUNNERS = ("train", "noop", "simulated", "raise")


@dataclass
class Runner:
    """A training function and the (de)serialisers of its checkpoints."""

    train: Callable[..., Any]
    checkpoint_to_bytes: Callable[[dict], bytes]
    checkpoint_from_bytes: Callable[[bytes], dict]


def runner_path(name: str) -> str:
    """Check a runner name: one of :data:`RUNNERS`, or ``package.module:function``."""
    if name not in RUNNERS and ":" not in name:
        raise ValueError(f"unknown runner {name!r}: use one of {', '.join(RUNNERS)} or 'package.module:function'")
    return name


def load_runner(name: str) -> Runner:
    """The runner ``name`` (:func:`runner_path`). ``train`` imports torch: call this in the training child."""
    runner_path(name)
    if name == "train":
        from . import train_runner

        return Runner(train_runner.train, train_runner.checkpoint_to_bytes, train_runner.checkpoint_from_bytes)
    if name in RUNNERS:
        func = {"noop": noop, "simulated": simulated, "raise": raising}[name]
        return Runner(func, checkpoint_to_bytes, checkpoint_from_bytes)
    module_name, func_name = name.split(":", 1)
    module = importlib.import_module(module_name)
    return Runner(
        train=getattr(module, func_name),
        checkpoint_to_bytes=getattr(module, "checkpoint_to_bytes", pickle.dumps),
        checkpoint_from_bytes=getattr(module, "checkpoint_from_bytes", pickle.loads),
    )


@dataclass
class SimpleResult:
    """A :class:`RunResult` look-alike for the test runners."""

    stopped: bool
    env_steps: int
    files: dict[str, bytes] = field(default_factory=dict)
    summary: dict | None = None

    def artifacts(self) -> dict[str, bytes]:
        return dict(self.files)


def checkpoint_to_bytes(ckpt: dict) -> bytes:
    return json.dumps(ckpt).encode()


def checkpoint_from_bytes(data: bytes) -> dict:
    return json.loads(data)


def noop(spec, *, on_progress, on_checkpoint, should_stop, checkpoint=None) -> SimpleResult:
    total = spec.training.total_env_steps
    on_progress(
        ProgressRecord(env_steps=total, total_env_steps=total, updates=0, phase="training", eval=None).to_dict()
    )
    return SimpleResult(False, total, {"result.json": b'{"runner": "noop"}'}, {"runner": "noop"})


def raising(spec, *, on_progress, on_checkpoint, should_stop, checkpoint=None) -> SimpleResult:
    raise RuntimeError(f"simulated training failure (runner 'raise', seed {spec.seed})")


def simulated(spec, *, on_progress, on_checkpoint, should_stop, checkpoint=None) -> SimpleResult:
    t = spec.training
    rate = float(os.environ.get("MODSAT_SIM_STEPS_PER_S", "2000"))
    tick = max(1, t.num_envs)
    env_steps = int(checkpoint["env_steps"]) if checkpoint else 0
    resumed_from = env_steps if checkpoint else None
    next_ckpt = (env_steps // t.checkpoint_every_steps + 1) * t.checkpoint_every_steps
    next_eval = (env_steps // t.eval_every_steps + 1) * t.eval_every_steps
    while env_steps < t.total_env_steps:
        if should_stop():
            on_checkpoint({"env_steps": env_steps, "resumed_from": resumed_from})
            return SimpleResult(True, env_steps)
        time.sleep(tick / rate)
        env_steps = min(t.total_env_steps, env_steps + tick)
        point = None
        if env_steps >= next_eval or env_steps >= t.total_env_steps:
            point = CurvePoint(env_steps=env_steps, mean_return=env_steps / t.total_env_steps, success_rate=0.0)
            next_eval = (env_steps // t.eval_every_steps + 1) * t.eval_every_steps
        on_progress(
            ProgressRecord(
                env_steps=env_steps,
                total_env_steps=t.total_env_steps,
                updates=env_steps // 2,
                phase="training",
                eval=point,
            ).to_dict()
        )
        if env_steps >= next_ckpt and env_steps < t.total_env_steps:
            on_checkpoint({"env_steps": env_steps, "resumed_from": resumed_from})
            next_ckpt = (env_steps // t.checkpoint_every_steps + 1) * t.checkpoint_every_steps
    run = {"runner": "simulated", "env_steps": env_steps, "resumed_from": resumed_from, "pid": os.getpid()}
    return SimpleResult(
        False, env_steps, {"run.json": json.dumps(run).encode()}, {"runner": "simulated", "resumed_from": resumed_from}
    )
