"""The ``modsat`` command line.

It lives in the top layer because it runs everything: training and benchmarks
(modsat_core), the 3D recordings (web), the service's limits (worker) and the service
(server/cli_service.py: ``serve``, ``worker``, ``view``). Imports stay inside the commands so
that ``modsat presets`` or ``modsat check`` never load torch."""

from __future__ import annotations

import argparse
import errno
import json
import os
import signal
import sys
import time


def _cmd_bench(args: argparse.Namespace) -> int:
    from modsat_core.bench.sim import bench_sim

    report = bench_sim(batch_sizes=tuple(args.batch), min_seconds=args.seconds, dtype=args.dtype)
    if args.json:
        print(json.dumps(report, indent=2))
    else:
        print(f"{report['unit']}, {report['dtype']}, torch {report['torch']}, {report['threads']} threads")
        for name, r in report["results"].items():
            print(f"  {name:>12}: {r['control_steps_per_s']:>12,.0f}   x{r['ratio_to_numpy']:.1f} vs numpy")
    return 0


#: Per-cell rows one `bench update` batch may hold (256 x 1,000: batch 256 on 10x10x10).
MAX_BENCH_CELL_ROWS = 256_000


def _cmd_bench_update(args: argparse.Namespace) -> int:
    from modsat_core.bench.update import bench_update

    if not (
        1 <= args.rounds <= 100
        and 1 <= args.batch_size <= 65536
        and all(2 <= n <= 10 for n in args.grids)
        and all(4 <= h <= 2048 for h in args.hidden)
        and len(args.hidden) <= 4
    ):
        raise SystemExit(
            "modsat bench update: --rounds must be 1 to 100, --batch-size 1 to 65,536, --grids between "
            "2 and 10, --hidden at most 4 sizes of 4 to 2,048"
        )
    if args.batch_size * max(args.grids) ** 3 > MAX_BENCH_CELL_ROWS:
        # The per-module network holds batch x N^3 rows of every layer's activations.
        raise SystemExit(
            f"modsat bench update: --batch-size x N^3 of the largest grid must be at most "
            f"{MAX_BENCH_CELL_ROWS:,} (the per-module network's rows per layer); got "
            f"{args.batch_size * max(args.grids) ** 3:,}"
        )
    report = bench_update(grids=tuple(args.grids), hidden=tuple(args.hidden), batch=args.batch_size, rounds=args.rounds)
    if args.json:
        print(json.dumps(report, indent=2))
    else:
        print(
            f"{report['unit']}, batch {report['batch_size']}, {report['hidden_sizes']}, {report['threads']} thread(s)"
        )
        for grid, r in report["results"].items():
            print(
                f"  {grid}: flat {r['flat_ms']:.1f} ms, per-module {r['per-module_ms']:.1f} ms "
                f"(x{r['per-module_ratio']:.1f}), set {r['set_ms']:.1f} ms (x{r['set_ratio']:.1f}); "
                f"features {r['features_ms']:.1f} ms"
            )
    return 0


def _cmd_bench_learning(args: argparse.Namespace) -> int:
    _set_threads(None)
    from modsat_core.bench.learning import bench_learn, bench_rl_vs_ga

    spec = _load_spec(args)
    if args.out:  # before hours of training, not after
        os.makedirs(args.out, exist_ok=True)
    if args.what == "learn":
        report = bench_learn(spec, args.seeds, args.out, _log)
    else:
        if spec.algorithm != "td3-codesign":
            raise SystemExit("modsat bench rl-vs-ga: give a td3-codesign spec; its GA twin is derived from it")
        report = bench_rl_vs_ga(spec, args.seeds, args.population, args.steps_per_design, args.out, _log)
    _print_report(report, os.path.join(args.out, f"bench-{args.what}.json") if args.out else None)
    return 0


def _cmd_bench_control(args: argparse.Namespace) -> int:
    _set_threads(None)
    from modsat_core.training.td3_control import bench_control

    if args.eval_every < 1:
        raise SystemExit("modsat bench control: --eval-every must be at least 1")
    spec = _load_spec(args)
    if args.out:  # before the training, not after
        if os.path.isdir(args.out):
            raise IsADirectoryError(errno.EISDIR, "Is a directory (--out names the report file)", args.out)
        os.makedirs(os.path.dirname(os.path.abspath(args.out)), exist_ok=True)
    report = bench_control(spec, eval_every=args.eval_every, eval_target=args.eval_target, log=_log)
    _print_report(report, args.out)
    return 0


def _cmd_bench_designs(args: argparse.Namespace) -> int:
    _set_threads(None)
    from modsat_core.bench.designs import bench_designs

    for name in ("updates", "pool", "designs", "slews"):
        if getattr(args, name) < 1:
            raise SystemExit(f"modsat bench designs: --{name} must be at least 1")
    if args.out:
        if os.path.isdir(args.out):
            raise IsADirectoryError(errno.EISDIR, "Is a directory (--out names the report file)", args.out)
        os.makedirs(os.path.dirname(os.path.abspath(args.out)), exist_ok=True)
    report = bench_designs(args.seed, args.updates, args.pool, args.designs, args.slews, args.grid_size)
    _print_report(report, args.out)
    return 0


def _cmd_bench_codesign(args: argparse.Namespace) -> int:
    _set_threads(None)
    from modsat_core.bench.codesign import bench_codesign
    from modsat_core.spec.presets import get_preset

    try:  # an unknown preset, or one that does not co-design, is a readable error before any training
        algorithm = get_preset(args.preset).algorithm
    except KeyError as exc:
        raise SystemExit(f"modsat bench codesign: {exc.args[0]}") from None
    if algorithm != "diffsim-codesign":
        raise SystemExit(f"modsat bench codesign: preset {args.preset!r} is {algorithm}, not diffsim-codesign")
    for name in ("designs", "slews"):
        if getattr(args, name) < 1:
            raise SystemExit(f"modsat bench codesign: --{name} must be at least 1")
    if args.out:
        if os.path.isdir(args.out):
            raise IsADirectoryError(errno.EISDIR, "Is a directory (--out names the report file)", args.out)
        os.makedirs(os.path.dirname(os.path.abspath(args.out)), exist_ok=True)
    _print_report(bench_codesign(args.preset, args.seed, args.designs, args.slews), args.out)
    return 0


def _cmd_bench_learners(args: argparse.Namespace) -> int:
    _set_threads(None)
    from modsat_core.bench.learners import DESIGNS, DIFFSIM_STEPS, bench_learners

    unknown = [d for d in args.designs if d not in DESIGNS]
    if unknown:
        raise SystemExit(f"modsat bench learners: unknown design {unknown[0]!r}; known: {', '.join(DESIGNS)}")
    steps = DIFFSIM_STEPS if args.steps is None else args.steps
    if steps < 1:
        raise SystemExit("modsat bench learners: --steps must be at least 1")
    if args.out:
        if os.path.isdir(args.out):
            raise IsADirectoryError(errno.EISDIR, "Is a directory (--out names the report file)", args.out)
        os.makedirs(os.path.dirname(os.path.abspath(args.out)), exist_ok=True)
    rows = bench_learners(args.seeds, args.designs, steps, td3=not args.no_td3, log=lambda r: _log(json.dumps(r)))
    if args.json:
        _print_report(rows, args.out)
    else:
        if args.out:
            with open(args.out, "w") as fh:
                fh.write(json.dumps(rows, indent=2) + "\n")
        for r in rows:
            print(
                f"{r['learner']:8s} {r['design']:15s} seed {r['seed']!s:5s} train {r['train_s']!s:>6s} s  "
                f"success@0.25 {100 * r['success_rate_at_0.25_deg']:5.1f} %  settle {r['median_settling_time_s']} s "
                f"(PD {r['pd_median_settling_time_s']} s)  violations {r['safety_violations']}"
            )
    return 0


def _log(line: str) -> None:
    print(line, file=sys.stderr, flush=True)


def _print_report(report: dict | list, path: str | None) -> None:
    """A benchmark's JSON report on stdout and, if ``path``, in that file."""
    text = json.dumps(report, indent=2)
    if path:
        with open(path, "w") as fh:
            fh.write(text + "\n")
    print(text)


def _cmd_presets(args: argparse.Namespace) -> int:
    from modsat_core.spec.presets import PRESETS, get_preset

    if args.name:
        print(get_preset(args.name).model_dump_json(indent=2))
    elif args.json:
        print(json.dumps({k: v.model_dump(mode="json") for k, v in PRESETS.items()}, indent=2))
    else:
        for name, spec in PRESETS.items():
            t = spec.training
            n = spec.design.grid_size
            print(f"{name:<12} {spec.algorithm:<13} {n}x{n}x{n}  {t.total_env_steps:>9,} env steps")
    return 0


def _cmd_schema(args: argparse.Namespace) -> int:
    from modsat_core.spec.jobspec import JobSpec

    if args.markdown:
        from modsat_core.spec.doc import spec_markdown

        print(spec_markdown(), end="")
    else:
        print(json.dumps(JobSpec.model_json_schema(), indent=2))
    return 0


def _limits():
    """The per-job limits of the MODSAT_* settings (the service's; docs/service.md, "Limits")."""
    from pydantic import ValidationError

    from worker.settings import WorkerSettings

    try:
        return WorkerSettings().limits()
    except ValidationError as exc:
        raise SystemExit(
            f"modsat: bad MODSAT_* setting: {exc.errors()[0]['loc'][0]}: {exc.errors()[0]['msg']}"
        ) from None


def _check_limits(spec, command: str) -> None:
    from modsat_core.spec.limits import check

    problems = check(spec, _limits())
    if problems:
        print(
            f"modsat {command}: this spec is over the limits (raise them with the MODSAT_* variables named if "
            "this machine can take it):\n  " + "\n  ".join(m for _, m in problems),
            file=sys.stderr,
        )
        raise SystemExit(2)


def _cmd_check(args: argparse.Namespace) -> int:
    from modsat_core.spec.jobspec import parse_spec
    from modsat_core.spec.limits import estimate

    with open(args.spec, "rb") as fh:
        spec = parse_spec(fh.read())
    _check_limits(spec, "check")
    est = estimate(spec)
    print(
        f"ok: {spec.algorithm}, {spec.design.grid_size}^3 grid, {spec.training.total_env_steps:,} env steps, "
        f"about {est.memory_bytes / 2**30:.1f} GiB of memory (replay buffer {est.replay_bytes / 2**30:.2f} GiB)"
    )
    return 0


def _set_threads(n: int | None) -> None:
    """Torch threads of this process: ``--threads``, else MODSAT_TORCH_THREADS, else 1 (on a busy
    machine torch's default of one per core measured about 20x slower)."""

    if n is None:
        raw = os.environ.get("MODSAT_TORCH_THREADS", "").strip() or "1"
        if not raw.isdigit() or not 1 <= int(raw) <= 256:
            raise SystemExit(f"modsat: MODSAT_TORCH_THREADS must be a number from 1 to 256; got {raw!r}")
        n = int(raw)
    if not 1 <= n <= 256:
        raise SystemExit(f"modsat: --threads must be from 1 to 256; got {n}")
    import torch

    torch.set_num_threads(n)


def _load_spec(args: argparse.Namespace):
    from modsat_core.spec.jobspec import parse_spec
    from modsat_core.spec.presets import get_preset

    if (args.preset is None) == (args.spec is None):
        raise SystemExit("modsat train: give either --preset NAME or a SPEC.json file")
    if args.preset is not None:
        spec = get_preset(args.preset)
    else:
        with open(args.spec, "rb") as fh:
            spec = parse_spec(fh.read())
    updates = {}
    if args.steps is not None:
        updates["total_env_steps"] = args.steps
    if args.device is not None:
        updates["device"] = args.device
    if getattr(args, "hidden", None):
        updates["hidden_sizes"] = args.hidden
    if updates:
        spec = spec.model_copy(update={"training": spec.training.model_copy(update=updates)})
    if args.seed is not None:
        spec = spec.model_copy(update={"seed": args.seed})
    return parse_spec(spec.model_dump_json())  # re-validated after the overrides


class _ProgressBar:
    """One line on a terminal, redrawn in place; a line per evaluation otherwise."""

    def __init__(self, stream=sys.stderr):

        self.stream, self.t0, self.time = stream, time.monotonic(), time.monotonic
        self.tty = stream.isatty()
        self.last_eval = ""
        self.recent: list[tuple[float, int]] = []  # (time, env steps) of the last minute

    def __call__(self, p: dict) -> None:
        done, total = p["env_steps"], max(p["total_env_steps"], 1)
        now = self.time()
        # The rate of the last minute, not since the start: a resumed run starts at its
        # checkpoint, and the machine's load changes (the ETA once read 105 s, then 2,533 s).
        self.recent.append((now, done))
        while len(self.recent) > 2 and now - self.recent[1][0] >= 60.0:
            self.recent.pop(0)  # keep one point at least a minute old (or the oldest) as the anchor
        t_old, s_old = self.recent[0]
        rate = (done - s_old) / (now - t_old) if now > t_old else 0.0
        eta = (total - done) / rate if rate > 0 else float("nan")
        if p.get("eval"):
            e = p["eval"]
            self.last_eval = f"eval return {e['mean_return']:.1f}, success {100 * e['success_rate']:.0f}%"
        width = 24
        fill = int(width * min(done / total, 1.0))
        line = (
            f"[{'#' * fill}{'.' * (width - fill)}] {done:,}/{total:,} steps  {rate:,.0f} steps/s  "
            f"eta {eta:,.0f} s  {p.get('phase', '')}  {self.last_eval}"
        )
        if self.tty:
            self.stream.write("\r" + line[:160].ljust(160))
        elif p.get("eval") or p.get("phase") == "evaluating":
            self.stream.write(line + "\n")
        self.stream.flush()

    def close(self) -> None:
        if self.tty:
            self.stream.write("\n")


def _cmd_train(args: argparse.Namespace) -> int:

    from modsat_core.training.checkpoint import checkpoint_from_bytes, checkpoint_to_bytes
    from modsat_core.training.train import train

    spec = _load_spec(args)
    _check_limits(spec, "train")
    _set_threads(args.threads)
    out = args.out
    os.makedirs(out, exist_ok=True)
    ckpt_path = os.path.join(out, "checkpoint.pt")
    checkpoint = None
    if args.resume and os.path.exists(ckpt_path):
        with open(ckpt_path, "rb") as ckpt_fh:
            checkpoint = checkpoint_from_bytes(ckpt_fh.read())
        print(f"resuming from {ckpt_path} at {checkpoint['env_steps']:,} env steps", file=sys.stderr)
    stop = {"flag": False}

    def on_sigint(*_):
        stop["flag"] = True  # the training checkpoints and returns

    def save_ckpt(ck: dict) -> None:
        tmp = ckpt_path + ".tmp"
        with open(tmp, "wb") as fh:
            fh.write(checkpoint_to_bytes(ck))
        os.replace(tmp, ckpt_path)

    # Ctrl-C and SIGTERM (a scheduler, `kill`) both stop at a checkpoint that --resume continues.
    old = {sig: signal.signal(sig, on_sigint) for sig in (signal.SIGINT, signal.SIGTERM)}
    bar = _ProgressBar()
    try:
        result = train(
            spec, on_progress=bar, on_checkpoint=save_ckpt, should_stop=lambda: stop["flag"], checkpoint=checkpoint
        )
    finally:
        for sig, handler in old.items():
            signal.signal(sig, handler)
        bar.close()
    if result.stopped:
        print(
            f"stopped at {result.env_steps:,} env steps; continue with: modsat train ... --out {out} --resume",
            file=sys.stderr,
        )
        return 130
    from modsat_core.verify.run import add_verification
    from web.recording import (
        add_recording,  # the 3D replay, evaluation.viser (docs/viewer.md)
    )

    files = result.artifacts()
    add_recording(files)
    if add_verification(files):
        report = json.loads(files["verification.json"])
        print(
            "modsat train: "
            + (
                "the evaluation slews were flown in Basilisk too: verification.json"
                if report["available"]
                else f"no Basilisk verification: {report['reason']}"
            ),
            file=sys.stderr,
        )
    for name, data in files.items():
        with open(os.path.join(out, name), "wb") as fh:
            fh.write(data)
    if os.path.exists(ckpt_path):
        os.remove(ckpt_path)
    _print_evaluation(result.summary, sys.stdout)
    print(f"outputs in {out}/: {', '.join(sorted(files))}")
    return 0


def _print_evaluation(summary: dict, stream) -> None:
    from modsat_core.artefacts import RunSummary
    from modsat_core.grid import describe

    s = RunSummary.parse(summary)
    d = s.design
    print(f"design: {describe(d.modules, d.actuators)}, valid={d.valid}" if d else "design: none", file=stream)
    print(
        f"{'':<12} {'episodes':>8} {'success':>8} {'@0.25deg':>9} {'@1deg':>7} {'return':>16} {'slew/bound':>10}",
        file=stream,
    )
    for name, ev in (("policy", s.policy), ("PD baseline", s.pd_baseline)):
        if ev is None:
            continue

        def pct(value: float | None) -> str:
            return "-" if value is None else f"{100 * value:.0f}%"

        ratio, ret = ev.median_slew_time_ratio, ev.mean_return
        print(
            f"{name:<12} {ev.episodes:>8} {pct(ev.success_rate):>8} {pct(ev.success_at(0.25)):>9} "
            f"{pct(ev.success_at(1.0)):>7} {'-' if ret is None else f'{ret:.1f}':>8} +/- {ev.std_return or 0:<5.1f} "
            f"{'-' if ratio is None else f'{ratio:.2f}':>10}",
            file=stream,
        )


def _cmd_eval(args: argparse.Namespace) -> int:
    _set_threads(None)

    from modsat_core.agent.policy_file import load_policy
    from modsat_core.evaluation.run_files import final_evaluation
    from modsat_core.evaluation.run_folder import RunFolder

    actor, grid, spec = load_policy(RunFolder(args.run_dir).read("policy.pt"))
    if grid is None:
        print("modsat: this policy has no design", file=sys.stderr)
        return 2
    ev = final_evaluation(actor, grid, spec, episodes=args.episodes)
    ev.pop("trajectories")
    if args.json:
        ev["policy"].pop("episodes", None)
        if ev["pd_baseline"]:
            ev["pd_baseline"].pop("episodes", None)
        print(json.dumps(ev, indent=2))
    else:
        from modsat_core.artefacts import EvaluationReport
        from modsat_core.evaluation.run_files import design_report, run_summary

        summary = run_summary(EvaluationReport.model_validate(ev), design_report(grid, spec))
        _print_evaluation(summary.to_dict(), sys.stdout)
    return 0


def _cmd_verify(args: argparse.Namespace) -> int:
    _set_threads(None)
    from modsat_core.verify.run import (
        BASILISK_MISSING,
        DEFAULT_WHEEL_INERTIA_KGM2,
        WheelOptions,
        basilisk_available,
        format_report,
        verify_run,
    )

    if not args.basilisk:
        print("modsat verify: name the simulator to fly the slews in: --basilisk", file=sys.stderr)
        return 2
    if not basilisk_available():
        print(BASILISK_MISSING, file=sys.stderr)
        return 2
    coulomb, viscous = args.wheel_friction or (0.0, 0.0)
    inertia = DEFAULT_WHEEL_INERTIA_KGM2 if args.wheel_inertia is None else args.wheel_inertia
    try:
        wheels = WheelOptions(
            speed_max_rpm=args.wheel_speed_max,
            coulomb_friction_Nm=coulomb,
            viscous_friction_Nms=viscous,
            inertia_kgm2=inertia,
        )
        report = verify_run(args.run_dir, episodes=args.episodes, wheels=wheels, log=_log)
    except ValueError as exc:  # a bad option, spec or design: a message, not a traceback
        print(f"modsat verify: {exc}", file=sys.stderr)
        return 2
    print(json.dumps(report, indent=2) if args.json else format_report(report))
    return 0


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="modsat", description="Co-design of modular satellites and their attitude control."
    )
    sub = p.add_subparsers(dest="command", required=True)

    b = sub.add_parser("bench", help="benchmarks (not tests): print rates and ratios")
    bsub = b.add_subparsers(dest="what", required=True)
    bs = bsub.add_parser("sim", help="batched simulator vs one-satellite numpy, control steps per second")
    bs.add_argument("--json", action="store_true", help="print the report as JSON")
    bs.add_argument("--batch", type=int, nargs="+", default=[1, 256, 4096], help="batch sizes to time")
    bs.add_argument("--seconds", type=float, default=2.0, help="minimum timing per case")
    bs.add_argument("--dtype", choices=["float32", "float64"], default="float32")
    bs.set_defaults(func=_cmd_bench)
    bu = bsub.add_parser("update", help="milliseconds per TD3 update: flat, per-module and set networks, one thread")
    bu.add_argument("--json", action="store_true", help="print the report as JSON")
    bu.add_argument("--grids", type=int, nargs="+", default=[3, 5], help="grid sizes N (default 3 5)")
    bu.add_argument("--hidden", type=int, nargs="+", default=[256, 256], help="wide layers (default 256 256)")
    bu.add_argument("--batch-size", type=int, default=256, help="transitions per update (default 256)")
    bu.add_argument("--rounds", type=int, default=5, help="timed rounds, networks taking turns (default 5)")
    bu.set_defaults(func=_cmd_bench_update)
    for what, text in (
        ("learn", "train a spec over several seeds: wall time, success at 0.25/1 deg, PD comparison"),
        ("rl-vs-ga", "RL co-design vs the GA baseline at the same env-step budget, several seeds"),
    ):
        bl = bsub.add_parser(what, help=text)
        bl.add_argument("spec", nargs="?", help="a JobSpec JSON file (or use --preset)")
        bl.add_argument("--preset", help="a named preset (see `modsat presets`)")
        bl.add_argument("--steps", type=int, help="override training.total_env_steps")
        bl.add_argument("--device", choices=["auto", "cpu", "cuda"], help="override training.device")
        bl.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2], help="seeds to run (default 0 1 2)")
        bl.add_argument("--out", help="also write each run's outputs and the JSON report here")
        if what == "rl-vs-ga":
            bl.add_argument("--population", type=int, default=6, help="GA population size (default 6)")
            bl.add_argument(
                "--steps-per-design",
                type=int,
                default=10_000,
                help="GA: TD3 env steps per evaluated design (default 10,000)",
            )
        bl.set_defaults(func=_cmd_bench_learning, seed=None)

    bc = bsub.add_parser(
        "control",
        help="flat-MLP TD3 flying one fixed design on a spec's mission: is the mission learnable, at what cost",
    )
    bc.add_argument("spec", nargs="?", help="a JobSpec JSON file (or use --preset)")
    bc.add_argument("--preset", help="a named preset (see `modsat presets`)")
    bc.add_argument("--steps", type=int, help="override training.total_env_steps")
    bc.add_argument("--seed", type=int, help="override the seed")
    bc.add_argument("--hidden", type=int, nargs="+", help="hidden layer sizes (default: training.hidden_sizes)")
    bc.add_argument("--eval-every", type=int, default=5_000, help="env steps between evaluations (default 5,000)")
    bc.add_argument(
        "--eval-target", action="store_true", help="also evaluate the target actor (the Polyak average of the actor)"
    )
    bc.add_argument("--out", help="also write the JSON report to this file")
    bc.set_defaults(func=_cmd_bench_control, device=None)

    bl2 = bsub.add_parser(
        "learners",
        help="diffsim (first-order), TD3 at the same wall time, and PD on the same designs and 100 slews",
    )
    bl2.add_argument("--json", action="store_true", help="print the rows as a JSON list")
    bl2.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4], help="seeds (default 0 1 2 3 4)")
    bl2.add_argument(
        "--designs", nargs="+", default=["cube", "three-actuator"], help="designs (default cube three-actuator)"
    )
    bl2.add_argument("--steps", type=int, help="diffsim env steps per run (default 120 updates: 983,040)")
    bl2.add_argument("--no-td3", action="store_true", help="leave out the TD3 rows")
    bl2.add_argument("--out", help="also write the rows (JSON) to this file")
    bl2.set_defaults(func=_cmd_bench_learners, threads=None)

    bd = bsub.add_parser(
        "designs",
        help="a design-conditioned diffsim controller and PD on held-out random designs (JSON)",
    )
    bd.add_argument("--seed", type=int, default=0, help="seed (default 0)")
    bd.add_argument("--grid-size", type=int, choices=(3, 5), default=3, help="3 (cpu-3x3x3) or 5 (paper-5x5x5)")
    bd.add_argument("--updates", type=int, default=240, help="training updates (default 240)")
    bd.add_argument("--pool", type=int, default=330, help="random training designs (default 330)")
    bd.add_argument("--designs", type=int, default=100, help="held-out designs (default 100)")
    bd.add_argument("--slews", type=int, default=32, help="slews per held-out design (default 32)")
    bd.add_argument("--out", help="also write the JSON report to this file")
    bd.set_defaults(func=_cmd_bench_designs, threads=None)

    bcd = bsub.add_parser(
        "codesign",
        help="diffsim-codesign's kept design against the initial cube and random designs (JSON)",
    )
    bcd.add_argument("--preset", default="diffsim-3x3x3", help="a diffsim-codesign preset (default diffsim-3x3x3)")
    bcd.add_argument("--seed", type=int, default=0, help="seed (default 0)")
    bcd.add_argument("--designs", type=int, default=100, help="random designs (default 100)")
    bcd.add_argument("--slews", type=int, default=16, help="slews each design flies (default 16)")
    bcd.add_argument("--out", help="also write the JSON report to this file")
    bcd.set_defaults(func=_cmd_bench_codesign, threads=None)

    pr = sub.add_parser("presets", help="list the named presets, or print one as JSON")
    pr.add_argument("name", nargs="?")
    pr.add_argument("--json", action="store_true")
    pr.set_defaults(func=_cmd_presets)

    sc = sub.add_parser("schema", help="print the JSON schema of JobSpec")
    sc.add_argument("--markdown", action="store_true", help="the reference tables of docs/spec.md instead")
    sc.set_defaults(func=_cmd_schema)

    ck = sub.add_parser("check", help="validate a spec file (JSON)")
    ck.add_argument("spec")
    ck.set_defaults(func=_cmd_check)

    tr = sub.add_parser("train", help="train a co-design (or GA / control-only) run and write its outputs")
    tr.add_argument("spec", nargs="?", help="a JobSpec JSON file (or use --preset)")
    tr.add_argument("--preset", help="a named preset (see `modsat presets`)")
    tr.add_argument("--out", required=True, help="output directory")
    tr.add_argument("--steps", type=int, help="override training.total_env_steps")
    tr.add_argument("--seed", type=int, help="override the seed")
    tr.add_argument("--device", choices=["auto", "cpu", "cuda"], help="override training.device")
    tr.add_argument("--resume", action="store_true", help="continue from OUT/checkpoint.pt (after Ctrl-C)")
    tr.add_argument(
        "--threads",
        type=int,
        help="torch threads (default: MODSAT_TORCH_THREADS, else 1; one per training process is fastest "
        "on a busy machine)",
    )
    tr.set_defaults(func=_cmd_train)

    ev = sub.add_parser("eval", help="Monte-Carlo evaluation of a trained run (policy and PD baseline)")
    ev.add_argument("run_dir", help="a directory written by `modsat train`")
    ev.add_argument("--episodes", type=int, help="number of seeded slews (default: the spec's)")
    ev.add_argument("--json", action="store_true")
    ev.set_defaults(func=_cmd_eval)

    vf = sub.add_parser(
        "verify",
        help="fly a run's evaluation slews in Basilisk beside modsat's simulator and compare (docs/verification.md)",
    )
    vf.add_argument("run_dir", help="a directory written by `modsat train`")
    vf.add_argument(
        "--basilisk",
        action="store_true",
        help="fly them in Basilisk (needs the optional extra: pip install -e '.[basilisk]')",
    )
    vf.add_argument("--episodes", type=int, help="number of seeded slews (default: the spec's)")
    vf.add_argument("--json", action="store_true")
    vf.add_argument(
        "--wheel-speed-max",
        type=float,
        metavar="RPM",
        help="Basilisk's wheel-speed limit (a less ideal plant: agreement no longer expected)",
    )
    vf.add_argument(
        "--wheel-friction",
        type=float,
        nargs=2,
        metavar=("COULOMB_NM", "VISCOUS_NMS"),
        help="Basilisk's wheel friction: Coulomb torque (N m) and viscous coefficient (N m s/rad)",
    )
    vf.add_argument(
        "--wheel-inertia",
        type=float,
        metavar="KGM2",
        help="wheel spin inertia Js (default 0.01; alone it changes nothing, with a speed limit it does)",
    )
    vf.set_defaults(func=_cmd_verify)

    _add_service_commands(sub)
    return p


def _add_service_commands(sub) -> None:
    """`serve` and `worker` live with the service (server/, worker/), in the same distribution."""
    from . import cli_service, cli_study

    cli_service.add_commands(sub)
    cli_study.add_commands(sub, _load_spec, _check_limits)


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


if __name__ == "__main__":
    sys.exit(main())
