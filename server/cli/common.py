"""What the ``modsat`` commands share: the log line, a benchmark's report, torch's threads, a spec
from ``--preset`` or a file, and the service's limits. The parser (__init__.py), bench.py and
run.py import it; it imports none of them."""

from __future__ import annotations

import argparse
import errno
import json
import os
import sys


def log(line: str) -> None:
    print(line, file=sys.stderr, flush=True)


def prepare_report_path(path: str | None) -> None:
    """Check ``--out`` names a file (not a folder) and make its folder, before any training runs."""
    if path:
        if os.path.isdir(path):
            raise IsADirectoryError(errno.EISDIR, "Is a directory (--out names the report file)", path)
        os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)


def write_report(report: dict | list, path: str | None) -> str:
    """A benchmark's JSON report, written to ``path`` if given; returns its text."""
    text = json.dumps(report, indent=2)
    if path:
        with open(path, "w") as fh:
            fh.write(text + "\n")
    return text


def print_report(report: dict | list, path: str | None) -> None:
    """A benchmark's JSON report on stdout and, if ``path``, in that file."""
    print(write_report(report, path))


def set_threads(n: int | None) -> None:
    """Torch threads of this process: ``--threads``, else MODSAT_TORCH_THREADS, else 1 (on a busy
    machine torch's default of one per core measured about 20x slower); set by
    :func:`modsat_core.training.threads.set_torch_threads`, as the worker's training child does."""
    from modsat_core.training.threads import set_torch_threads

    if n is None:
        raw = os.environ.get("MODSAT_TORCH_THREADS", "").strip() or "1"
        if not raw.isdigit() or not 1 <= int(raw) <= 256:
            raise SystemExit(f"modsat: MODSAT_TORCH_THREADS must be a number from 1 to 256; got {raw!r}")
        n = int(raw)
    if not 1 <= n <= 256:
        raise SystemExit(f"modsat: --threads must be from 1 to 256; got {n}")
    set_torch_threads(n)


def load_spec(args: argparse.Namespace):
    """``--preset NAME`` or a SPEC.json file, with the flags' overrides (``--steps``, ``--device``,
    ``--hidden``, ``--seed``) merged in by the API's resolver (modsat_core.spec.overrides)."""
    from modsat_core.spec.jobspec import parse_spec
    from modsat_core.spec.overrides import with_overrides
    from modsat_core.spec.presets import get_preset

    if (args.preset is None) == (args.spec is None):
        raise SystemExit("modsat train: give either --preset NAME or a SPEC.json file")
    if args.preset is not None:
        spec = get_preset(args.preset)
    else:
        with open(args.spec, "rb") as fh:
            spec = parse_spec(fh.read())
    training = {}
    if args.steps is not None:
        training["total_env_steps"] = args.steps
    if args.device is not None:
        training["device"] = args.device
    if getattr(args, "hidden", None):
        training["hidden_sizes"] = args.hidden
    overrides: dict = {"training": training} if training else {}
    if args.seed is not None:
        overrides["seed"] = args.seed
    return with_overrides(spec, overrides)  # re-validated after the overrides


def _limits():
    """The per-job limits of the MODSAT_* settings (the service's; docs/service.md, "Limits"). On the
    command line the bound on a job's hours applies only where MODSAT_MAX_JOB_HOURS is set: it guards a
    shared service's queue, and a run on one's own machine may take as long as its owner likes."""
    import dataclasses
    import os

    from pydantic import ValidationError

    from worker.settings import WorkerSettings

    try:
        limits = WorkerSettings().limits()
        return limits if os.environ.get("MODSAT_MAX_JOB_HOURS") else dataclasses.replace(limits, max_job_hours=None)
    except ValidationError as exc:
        raise SystemExit(
            f"modsat: bad MODSAT_* setting: {exc.errors()[0]['loc'][0]}: {exc.errors()[0]['msg']}"
        ) from None


def check_limits(spec, command: str) -> None:
    from modsat_core.spec.limits import check

    problems = check(spec, _limits())
    if problems:
        print(
            f"modsat {command}: this spec is over the limits (raise them with the MODSAT_* variables named if "
            "this machine can take it):\n  " + "\n  ".join(m for _, m in problems),
            file=sys.stderr,
        )
        raise SystemExit(2)
