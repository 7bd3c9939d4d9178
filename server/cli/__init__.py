"""The ``modsat`` command line: its parser and ``main``.

It lives in the top layer because it runs everything: training and benchmarks
(modsat_core), the 3D recordings (web), the service's limits (worker) and the service.
The commands live by family, one module each: bench.py (``bench ...``), run.py
(``presets``, ``schema``, ``check``, ``train``, ``eval``, ``verify``), service.py
(``serve``, ``worker``, ``view``) and study.py (``study``, ``report``), with what
they share in common.py. Imports stay inside the commands so that
``modsat presets`` or ``modsat check`` never load torch. ``python -m server.cli`` runs
``main`` (__main__.py)."""

from __future__ import annotations

import argparse
import os
import sys

from .bench import add_bench_parsers
from .common import check_limits, load_spec
from .run import _ProgressBar, add_run_parsers

__all__ = ["_ProgressBar", "build_parser", "main"]  # _ProgressBar: tests/core/test_cli.py imports it from here


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="modsat", description="Co-design of modular satellites and their attitude control."
    )
    sub = p.add_subparsers(dest="command", required=True)

    add_bench_parsers(sub)
    add_run_parsers(sub)
    _add_service_commands(sub)
    return p


def _add_service_commands(sub) -> None:
    """`serve` and `worker` live with the service (server/, worker/), in the same distribution."""
    from . import service, study

    service.add_commands(sub)
    study.add_commands(sub, load_spec, check_limits)


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if getattr(args, "seconds", 1.0) <= 0 or any(b < 1 or b > 1_000_000 for b in getattr(args, "batch", [])):
        print("modsat: --seconds must be > 0 and --batch sizes between 1 and 1,000,000", file=sys.stderr)
        return 2
    if getattr(args, "episodes", None) is not None and not 1 <= args.episodes <= 10_000:
        print("modsat: --episodes must be between 1 and 10,000", file=sys.stderr)
        return 2
    from modsat_core.artefacts import ArtefactError
    from modsat_core.spec.jobspec import SpecError

    try:
        rc = args.func(args)
        sys.stdout.flush()  # here, where a closed pipe is caught, not at exit
        return rc
    except BrokenPipeError:  # e.g. `modsat presets quick | head`: the reader left; say nothing
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())  # no second error when Python flushes stdout at exit
        return 141
    except (SpecError, ArtefactError) as exc:  # a bad spec; a run folder's file missing or not in its format
        print(f"modsat: {exc}", file=sys.stderr)
        return 2
    except (KeyError, OSError) as exc:  # an unknown preset; a file or directory that cannot be used
        msg = exc.args[0] if isinstance(exc, KeyError) else f"{exc.strerror or exc}: {exc.filename}"
        print(f"modsat: {msg}", file=sys.stderr)
        return 2
