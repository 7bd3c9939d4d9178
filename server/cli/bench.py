"""``modsat bench ...``: sim, update, learn, rl-vs-ga, control, learners, designs, pareto, codesign
(modsat_core.bench) and service (the job service's, server/service_bench.py), their
handlers and their parsers (wired into server/cli/__init__.py by ``add_bench_parsers``)."""

from __future__ import annotations

import argparse
import json
import os
import sys

from .common import load_spec, log, prepare_report_path, print_report, set_threads, write_report


def _cmd_bench(args: argparse.Namespace) -> int:
    from modsat_core.bench.sim import bench_sim

    report = bench_sim(
        batch_sizes=tuple(args.batch), min_seconds=args.seconds, dtype=args.dtype, compiled=args.compiled
    )
    if args.json:
        print(json.dumps(report, indent=2))
    else:
        print(f"{report['unit']}, {report['dtype']}, torch {report['torch']}, {report['threads']} threads")
        for name, r in report["results"].items():
            line = f"  {name:>19}: {r['control_steps_per_s']:>12,.0f}   x{r['ratio_to_numpy']:.1f} vs numpy"
            if "ratio_to_eager" in r:
                line += f"   x{r['ratio_to_eager']:.2f} vs eager, compiled in {r['compile_s']:.0f} s"
            print(line)
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
    set_threads(None)
    from modsat_core.bench.training_runs import bench_learn, bench_rl_vs_ga

    spec = load_spec(args)
    if args.out:  # before hours of training, not after
        os.makedirs(args.out, exist_ok=True)
    if args.what == "learn":
        report = bench_learn(spec, args.seeds, args.out, log)
    else:
        if spec.algorithm != "td3-codesign":
            raise SystemExit("modsat bench rl-vs-ga: give a td3-codesign spec; its GA twin is derived from it")
        report = bench_rl_vs_ga(spec, args.seeds, args.population, args.steps_per_design, args.out, log)
    print_report(report, os.path.join(args.out, f"bench-{args.what}.json") if args.out else None)
    return 0


def _cmd_bench_control(args: argparse.Namespace) -> int:
    set_threads(None)
    from modsat_core.bench.control import bench_control

    if args.eval_every < 1:
        raise SystemExit("modsat bench control: --eval-every must be at least 1")
    spec = load_spec(args)
    prepare_report_path(args.out)  # before the training, not after
    try:
        report = bench_control(spec, eval_every=args.eval_every, eval_target=args.eval_target, log=log)
    except ValueError as exc:  # a spec the flat network cannot follow (TD3Run names the fields)
        raise SystemExit(f"modsat bench control: {exc}") from None
    print_report(report, args.out)
    return 0


def _cmd_bench_designs(args: argparse.Namespace) -> int:
    set_threads(None)
    from modsat_core.bench.designs import bench_designs

    for name in ("updates", "pool", "designs", "slews"):
        if getattr(args, name) < 1:
            raise SystemExit(f"modsat bench designs: --{name} must be at least 1")
    prepare_report_path(args.out)
    report = bench_designs(args.seed, args.updates, args.pool, args.designs, args.slews, args.grid_size)
    print_report(report, args.out)
    return 0


def _cmd_bench_codesign(args: argparse.Namespace) -> int:
    set_threads(None)
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
    prepare_report_path(args.out)
    report = bench_codesign(
        args.preset, args.seed, args.designs, args.slews, args.design_gradient, not args.no_ga, args.design_batch
    )
    print_report(report, args.out)
    return 0


def _cmd_bench_pareto(args: argparse.Namespace) -> int:
    set_threads(None)
    from modsat_core.bench.pareto import bench_pareto
    from modsat_core.spec.presets import get_preset

    try:  # a preset that is not a trade-off is a readable error before any training
        spec = get_preset(args.preset)
    except KeyError as exc:
        raise SystemExit(f"modsat bench pareto: {exc.args[0]}") from None
    if not spec.objective.trade_off_prices_s_per_kg:
        raise SystemExit(
            f"modsat bench pareto: preset {args.preset!r} is not a trade-off (no objective.trade_off_prices_s_per_kg)"
        )
    for name, most in (("designs", 10_000), ("slews", 1_000)):
        if not 1 <= getattr(args, name) <= most:
            raise SystemExit(f"modsat bench pareto: --{name} must be between 1 and {most:,}")
    prepare_report_path(args.out)

    # the seeds so far go to --out after each one: a stopped bench keeps them
    report = bench_pareto(
        args.preset,
        args.seeds,
        args.designs,
        args.slews,
        on_seed=lambda r: write_report(r, args.out),
        ga=not args.no_ga,
    )
    print_report(report, args.out)
    return 0


def _cmd_bench_learners(args: argparse.Namespace) -> int:
    set_threads(None)
    from modsat_core.bench.learners import DESIGNS, DIFFSIM_STEPS, bench_learners

    unknown = [d for d in args.designs if d not in DESIGNS]
    if unknown:
        raise SystemExit(f"modsat bench learners: unknown design {unknown[0]!r}; known: {', '.join(DESIGNS)}")
    steps = DIFFSIM_STEPS if args.steps is None else args.steps
    if steps < 1:
        raise SystemExit("modsat bench learners: --steps must be at least 1")
    prepare_report_path(args.out)
    rows = bench_learners(args.seeds, args.designs, steps, td3=not args.no_td3, log=lambda r: log(json.dumps(r)))
    if args.json:
        print_report(rows, args.out)
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


def _cmd_bench_service(args: argparse.Namespace) -> int:
    what = args.what_service or ["api", "queue"]
    if what == ["threads"]:
        if not all(1 <= n <= 256 for n in args.threads) or not 0 <= args.busy <= 64:
            print("modsat bench service: --threads from 1 to 256, --busy from 0 to 64", file=sys.stderr)
            return 2
    elif set(what) - {"api", "queue"}:
        print("modsat bench service: what to measure: api and/or queue, or threads alone", file=sys.stderr)
        return 2
    from server.service_bench import bench_service, bench_threads

    if what == ["threads"]:
        report = {"machine": {"cpus": os.cpu_count()}, "threads": bench_threads(args.threads, args.busy)}
    else:
        report = bench_service(
            what,
            db=args.db,
            pg=args.pg,
            jobs=args.jobs,
            clients=args.clients,
            requests=args.requests,
            workers=args.workers,
            quiet=args.json,
        )
    print(json.dumps(report, indent=2))
    return 0


def _add_service_parser(bsub) -> None:
    bsv = bsub.add_parser(
        "service",
        help="the job service: API latency and queue throughput on SQLite and PostgreSQL, or torch threads (JSON)",
    )
    bsv.add_argument("what_service", nargs="*", metavar="what", help="api and/or queue (default: both), or threads")
    bsv.add_argument(
        "--threads",
        type=int,
        nargs="+",
        default=[1, 2],
        help="threads: MODSAT_TORCH_THREADS values to compare (default 1 2)",
    )
    bsv.add_argument("--busy", type=int, default=1, help="threads: other CPU-bound processes meanwhile (default 1)")
    bsv.add_argument("--db", nargs="+", choices=["sqlite", "postgresql"], default=["sqlite", "postgresql"])
    bsv.add_argument(
        "--pg",
        metavar="URL",
        help="admin URL of a PostgreSQL server (a database is created and dropped; default MODSAT_BENCH_PG_URL, "
        "else postgresql://postgres@127.0.0.1:5432/postgres)",
    )
    bsv.add_argument("--jobs", type=int, default=1000)
    bsv.add_argument("--clients", type=int, default=50)
    bsv.add_argument("--requests", type=int, default=3000)
    bsv.add_argument("--workers", type=int, default=4)
    bsv.add_argument("--json", action="store_true", help="print only the JSON report")
    bsv.set_defaults(func=_cmd_bench_service)


def add_bench_parsers(sub) -> None:
    """Add ``bench`` and its sub-commands to the ``modsat`` sub-command parser ``sub``."""
    b = sub.add_parser("bench", help="benchmarks (not tests): print rates and ratios")
    bsub = b.add_subparsers(dest="what", required=True)
    bs = bsub.add_parser("sim", help="batched simulator vs one-satellite numpy, control steps per second")
    bs.add_argument("--json", action="store_true", help="print the report as JSON")
    bs.add_argument("--batch", type=int, nargs="+", default=[1, 256, 4096], help="batch sizes to time")
    bs.add_argument("--seconds", type=float, default=2.0, help="minimum timing per case")
    bs.add_argument("--dtype", choices=["float32", "float64"], default="float32")
    bs.add_argument(
        "--compiled",
        action="store_true",
        help="also the physics step fused by torch.compile beside the eager one, batch 256 (compiles for minutes)",
    )
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

    bp = bsub.add_parser(
        "pareto",
        help="the trade-off run's front against NSGA-II's, random designs' and a GA's with a controller per design",
    )
    bp.add_argument("--preset", default="trade-off-3x3x3", help="a trade-off preset (default trade-off-3x3x3)")
    bp.add_argument("--seeds", type=int, nargs="+", default=[0], help="seeds (default 0)")
    bp.add_argument("--designs", type=int, default=100, help="random designs (default 100)")
    bp.add_argument("--slews", type=int, default=32, help="bench slews each design flies (default 32)")
    bp.add_argument(
        "--no-ga", action="store_true", help="leave out the GA with a controller per design (the paper's method)"
    )
    bp.add_argument("--json", action="store_true", help="accepted for symmetry: the report is JSON")
    bp.add_argument("--out", help="also write the JSON report to this file")
    bp.set_defaults(func=_cmd_bench_pareto, threads=None)

    bcd = bsub.add_parser(
        "codesign",
        help="diffsim-codesign's kept design against the initial cube and random designs (JSON)",
    )
    bcd.add_argument("--preset", default="diffsim-3x3x3", help="a diffsim-codesign preset (default diffsim-3x3x3)")
    bcd.add_argument("--seed", type=int, default=0, help="seed (default 0)")
    bcd.add_argument("--designs", type=int, default=100, help="random designs (default 100)")
    bcd.add_argument("--slews", type=int, default=16, help="slews each design flies (default 16)")
    bcd.add_argument(
        "--design-gradient",
        choices=["score-function", "relaxed"],
        default=None,
        help="override the preset's diffsim.design_gradient (docs/diffsim.md compares them)",
    )
    bcd.add_argument(
        "--design-batch", type=int, default=None, help="override the preset's diffsim.design_batch (draws per update)"
    )
    bcd.add_argument("--no-ga", action="store_true", help="leave out the GA row (halves the bench's time)")
    bcd.add_argument("--out", help="also write the JSON report to this file")
    bcd.set_defaults(func=_cmd_bench_codesign, threads=None)

    _add_service_parser(bsub)
