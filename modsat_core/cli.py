"""The ``modsat`` command line."""

from __future__ import annotations

import argparse
import json
import sys


def _cmd_bench(args: argparse.Namespace) -> int:
    from .bench import bench_sim

    report = bench_sim(batch_sizes=tuple(args.batch), min_seconds=args.seconds, dtype=args.dtype)
    if args.json:
        print(json.dumps(report, indent=2))
    else:
        print(f"{report['unit']}, {report['dtype']}, torch {report['torch']}, {report['threads']} threads")
        for name, r in report["results"].items():
            print(f"  {name:>12}: {r['control_steps_per_s']:>12,.0f}   x{r['ratio_to_numpy']:.1f} vs numpy")
    return 0


def _cmd_presets(args: argparse.Namespace) -> int:
    from .presets import PRESETS, get_preset

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
    from .spec import JobSpec

    if args.markdown:
        from .specdoc import spec_markdown

        print(spec_markdown(), end="")
    else:
        print(json.dumps(JobSpec.model_json_schema(), indent=2))
    return 0


def _cmd_check(args: argparse.Namespace) -> int:
    from .spec import parse_spec

    with open(args.spec, "rb") as fh:
        spec = parse_spec(fh.read())
    print(f"ok: {spec.algorithm}, {spec.design.grid_size}^3 grid, {spec.training.total_env_steps:,} env steps")
    return 0


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="modsat", description="Co-design of modular satellites and their attitude control.")
    sub = p.add_subparsers(dest="command", required=True)

    b = sub.add_parser("bench", help="benchmarks (not tests): print rates and ratios")
    bsub = b.add_subparsers(dest="what", required=True)
    bs = bsub.add_parser("sim", help="batched simulator vs one-satellite numpy, control steps per second")
    bs.add_argument("--json", action="store_true", help="print the report as JSON")
    bs.add_argument("--batch", type=int, nargs="+", default=[1, 256, 4096], help="batch sizes to time")
    bs.add_argument("--seconds", type=float, default=2.0, help="minimum timing per case")
    bs.add_argument("--dtype", choices=["float32", "float64"], default="float32")
    bs.set_defaults(func=_cmd_bench)

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
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if getattr(args, "seconds", 1.0) <= 0 or any(b < 1 or b > 1_000_000 for b in getattr(args, "batch", [])):
        print("modsat: --seconds must be > 0 and --batch sizes between 1 and 1,000,000", file=sys.stderr)
        return 2
    from .spec import SpecError

    try:
        return args.func(args)
    except SpecError as exc:
        print(f"modsat: {exc}", file=sys.stderr)
        return 2
    except (KeyError, FileNotFoundError, IsADirectoryError) as exc:
        msg = exc.args[0] if isinstance(exc, KeyError) else f"{exc.strerror}: {exc.filename}"
        print(f"modsat: {msg}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
