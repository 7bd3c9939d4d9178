"""``modsat study`` (a study run locally: one spec over seeds and algorithms, then its report) and
``modsat report`` (the figure, the table and the designs of saved runs); wired into server/cli/__init__.py."""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import time
from typing import IO


def add_commands(sub, load_spec, check_limits) -> None:
    """``load_spec`` and ``check_limits``: `modsat train`'s (server/cli/common.py), passed in, not imported back."""
    s = sub.add_parser(
        "study",
        help="run one spec over several seeds, RL co-design and its GA twin, here; then write their report",
        description="Trains every (algorithm, seed) of the study with `modsat train` (one torch thread each, at "
        "most --jobs at once) into OUT/ALGORITHM-seedN, then writes `modsat report` of them to OUT/report. "
        "Run it again after a stop: finished runs are kept and stopped ones resume from their checkpoints.",
    )
    s.add_argument("spec", nargs="?", help="a JobSpec JSON file (or use --preset)")
    s.add_argument("--preset", help="a named preset (see `modsat presets`)")
    s.add_argument("--seeds", type=int, nargs="+", required=True, metavar="SEED")
    s.add_argument(
        "--algorithms", nargs="+", metavar="ALGORITHM", help="default td3-codesign ga (modsat_core.spec.study)"
    )
    s.add_argument("--out", required=True, metavar="DIR")
    s.add_argument("--jobs", type=int, default=1, help="runs at once (default 1; at most one per core)")
    s.set_defaults(func=_cmd_study, steps=None, device=None, seed=None, load_spec=load_spec, check_limits=check_limits)

    r = sub.add_parser(
        "report",
        help="the learning curves (mean +/- std over seeds), the table and the designs of saved runs",
        description="Compare finished runs of one mission (e.g. RL co-design and the GA over several seeds): "
        "writes study.json, table.md, curves.png and designs/*.png to --out. Each RUN_DIR is a directory "
        "written by `modsat train --out`.",
    )
    r.add_argument("run_dirs", nargs="+", metavar="RUN_DIR", help="finished runs, all of the same mission")
    r.add_argument("--out", required=True, metavar="DIR", help="directory to write the report to (created)")
    r.set_defaults(func=_cmd_report)


def _write_report(run_dirs: list[str], out: str) -> int:
    from modsat_core.artefacts import ArtefactError
    from modsat_core.evaluation.run_folder import RunFolder
    from modsat_core.evaluation.study_report import report_files, saved_run

    try:
        runs = [saved_run(RunFolder(d)) for d in dict.fromkeys(os.path.normpath(d) for d in run_dirs)]
        files, _ = report_files(runs)
    except ArtefactError as exc:
        print(f"modsat: {exc}", file=sys.stderr)
        return 2
    for name, data in files.items():
        path = os.path.join(out, name)
        os.makedirs(os.path.dirname(path), exist_ok=True)
        with open(path, "wb") as fh:
            fh.write(data)
    sys.stdout.write(files["table.md"].decode())
    print(f"wrote {len(files)} files to {out}")
    return 0


def _cmd_report(args: argparse.Namespace) -> int:
    return _write_report(args.run_dirs, args.out)


def _cmd_study(args: argparse.Namespace) -> int:
    from modsat_core.spec.study import (
        DEFAULT_ALGORITHMS,
        algorithm_problem,
        ga_problem,
        run_name,
        seed_problem,
        study_specs,
    )

    if args.algorithms is None:
        args.algorithms = list(DEFAULT_ALGORITHMS)
    base = args.load_spec(args)
    problems = [p for p in (seed_problem(args.seeds), algorithm_problem(args.algorithms)) if p]
    if "ga" in args.algorithms and (p := ga_problem(base)):
        problems.append(p)
    if not 1 <= args.jobs <= 64:
        problems.append("--jobs: between 1 and 64")
    if problems:
        print("modsat study: " + "\n  ".join(problems), file=sys.stderr)
        return 2
    specs = study_specs(base, args.seeds, args.algorithms)
    for spec in specs[:: len(args.seeds)]:
        args.check_limits(spec, "study")
    os.makedirs(args.out, exist_ok=True)
    todo, dirs = [], []
    for spec in specs:
        d = os.path.join(args.out, run_name(spec))
        dirs.append(d)
        if os.path.exists(os.path.join(d, "evaluation.json")):
            print(f"{d}: finished earlier, kept")
            continue
        os.makedirs(d, exist_ok=True)
        with open(os.path.join(d, "study-spec.json"), "w") as fh:
            json.dump(spec.model_dump(mode="json"), fh, indent=1)
        todo.append(d)
    failed = _run_all(todo, args.jobs)
    if failed:
        print(
            f"modsat study: {len(failed)} run(s) failed or stopped: {', '.join(failed)} (see their train.log; "
            "run the same command again to resume)",
            file=sys.stderr,
        )
        return 1
    return _write_report(dirs, os.path.join(args.out, "report"))


def _finished(d: str) -> bool:
    return os.path.exists(os.path.join(d, "evaluation.json"))


def _die_with_parent() -> None:
    """In the child, before exec: on Linux, SIGTERM it when `modsat study` dies, even by SIGKILL (the run
    then checkpoints and exits, and `--resume` continues it); elsewhere, nothing."""
    if sys.platform.startswith("linux"):
        import ctypes

        ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG = 1


def _run_all(todo: list[str], jobs: int) -> list[str]:
    """Train each directory's study-spec.json in its own process, at most ``jobs`` at once; returns
    the directories that did not finish (failed, or stopped by Ctrl-C / SIGTERM at a checkpoint)."""
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    running: dict[str, tuple[subprocess.Popen, IO[bytes]]] = {}
    queue = list(todo)
    stop = {"flag": False}

    def on_signal(*_):
        stop["flag"] = True

    old = {sig: signal.signal(sig, on_signal) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        while queue or running:
            while queue and len(running) < jobs and not stop["flag"]:
                d = queue.pop(0)
                log = open(os.path.join(d, "train.log"), "ab")  # closed when the run ends
                spec = os.path.join(d, "study-spec.json")
                cmd = [sys.executable, "-m", "server.cli", "train", spec, "--out", d, "--resume", "--threads", "1"]
                proc = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, env=env, preexec_fn=_die_with_parent)
                running[d] = (proc, log)
                print(f"{d}: training (pid {proc.pid})", flush=True)
            if stop["flag"] and not stop.get("sent"):
                queue.clear()
                for proc, _ in running.values():
                    proc.send_signal(signal.SIGINT)  # each run checkpoints and exits; --resume continues it
                stop["sent"] = True
            for d, (proc, fh) in list(running.items()):
                if proc.poll() is not None:
                    fh.close()
                    del running[d]
                    print(f"{d}: {'finished' if _finished(d) else f'exit {proc.returncode}'}", flush=True)
            time.sleep(0.5)
    finally:
        for sig, handler in old.items():
            signal.signal(sig, handler)
    return [d for d in todo if not _finished(d)]
