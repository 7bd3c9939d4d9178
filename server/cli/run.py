"""``modsat presets``, ``schema``, ``check``, ``train``, ``eval`` and ``verify``: a spec, its run and
the run's evaluation; their handlers and their parsers (wired into server/cli/__init__.py by ``add_run_parsers``)."""

from __future__ import annotations

import argparse
import json
import os
import signal
import sys
import time

from .common import check_limits, load_spec, log, set_threads


def presets_table(presets: dict) -> str:
    """One line per preset, every column as wide as its widest entry (names of any length align)."""
    rows = [
        (name, spec.algorithm, "x".join([str(spec.design.grid_size)] * 3), f"{spec.training.total_env_steps:,}")
        for name, spec in presets.items()
    ]
    w = [max(len(r[i]) for r in rows) for i in range(4)] if rows else [0] * 4
    return "\n".join(f"{a:<{w[0]}}  {b:<{w[1]}}  {c:<{w[2]}}  {d:>{w[3]}} env steps" for a, b, c, d in rows)


def _cmd_presets(args: argparse.Namespace) -> int:
    from modsat_core.spec.presets import PRESETS, get_preset

    if args.name:
        print(get_preset(args.name).model_dump_json(indent=2))
    elif args.json:
        print(json.dumps({k: v.model_dump(mode="json") for k, v in PRESETS.items()}, indent=2))
    else:
        print(presets_table(PRESETS))
    return 0


def _cmd_schema(args: argparse.Namespace) -> int:
    from modsat_core.spec.jobspec import JobSpec

    if args.markdown:
        from modsat_core.spec.doc import spec_markdown

        print(spec_markdown(), end="")
    else:
        print(json.dumps(JobSpec.model_json_schema(), indent=2))
    return 0


def _cmd_check(args: argparse.Namespace) -> int:
    from modsat_core.spec.jobspec import SpecError, parse_spec
    from modsat_core.spec.limits import estimate

    with open(args.spec, "rb") as fh:
        raw = fh.read()
    try:
        body = json.loads(raw)
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:  # said as text, not as a bytes repr
        where = f" at line {exc.lineno} column {exc.colno}" if isinstance(exc, json.JSONDecodeError) else ""
        raise SpecError([f"(spec): {args.spec} is not valid JSON: {getattr(exc, 'msg', exc)}{where}"]) from None
    if isinstance(body, dict) and "preset" in body:  # the REST API's form: {"preset": NAME, "overrides": {...}}
        from server.submit import Invalid, spec_from_body

        try:
            spec = spec_from_body(body)
        except Invalid as exc:
            raise SpecError([str(e["msg"]) for e in exc.errors]) from None
    else:
        spec = parse_spec(raw)
    check_limits(spec, "check")
    est = estimate(spec)
    print(
        f"ok: {spec.algorithm}, {spec.design.grid_size}^3 grid, {spec.training.total_env_steps:,} env steps, "
        f"about {est.memory_bytes / 2**30:.1f} GiB of memory (replay buffer {est.replay_bytes / 2**30:.2f} GiB)"
    )
    return 0


class _ProgressBar:
    """One line on a terminal, redrawn in place; a line per evaluation otherwise."""

    def __init__(self, stream=sys.stderr):

        self.stream, self.t0, self.time = stream, time.monotonic(), time.monotonic
        self.tty = stream.isatty()
        self.last_eval = ""
        self.recent: list[tuple[float, int]] = []  # (time, env steps) of the last minute
        self.evaluating: float | None = None  # when the final evaluation started

    def __call__(self, p: dict) -> None:
        done, total = p["env_steps"], max(p["total_env_steps"], 1)
        now = self.time()
        if p.get("phase") == "evaluating":  # training is over: what the final evaluation flies, and since when
            self.evaluating = now if self.evaluating is None else self.evaluating
            what = f"flying {p['stage']}" if p.get("stage") else "the policy and PD on the evaluation's slews"
            line = f"final evaluation ({now - self.evaluating:,.0f} s): {what}"
            self.stream.write(("\r" + line[:160].ljust(160)) if self.tty else line + "\n")
            self.stream.flush()
            return
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
    from modsat_core.verify.run import ARTIFACT_NAME as VERIFICATION
    from worker.train_runner import checkpoint_from_bytes, checkpoint_to_bytes, train  # a job's one code path

    spec = load_spec(args)
    check_limits(spec, "train")
    set_threads(args.threads)
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
    files = result.artifacts()  # with the recording, and verification.json where the spec asks
    if VERIFICATION in files:
        report = json.loads(files[VERIFICATION])
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
    if s.conditions:
        from modsat_core.artefacts import conditions_table

        rows = conditions_table((s.policy, s.pd_baseline), s.conditions)
        print("flight conditions (docs/robustness.md), the same slews:", file=stream)
        widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
        for r in rows:
            line = "  ".join(c.ljust(w) if i == 0 else c.rjust(w) for i, (c, w) in enumerate(zip(r, widths)))
            print("  " + line, file=stream)
        for f in s.flight_failures:
            print(
                f"NOT FLIGHT-READY under {f.name}: the policy lands {100 * f.policy_success:.0f}% of the slews, "
                f"PD {100 * f.pd_success:.0f}% (docs/robustness.md)",
                file=stream,
            )


def _conditions_arg(text: str) -> list:
    """``--conditions``: `all` (the standard ones), `none`, names separated by commas, or a JSON
    file holding a list of conditions (objects or standard names)."""
    from modsat_core.spec.evaluation import STANDARD_CONDITIONS

    if text == "all":
        return list(STANDARD_CONDITIONS)
    if text == "none":
        return []
    if text.endswith(".json"):
        with open(text, encoding="utf-8") as fh:
            items = json.load(fh)
        if not isinstance(items, list):
            raise ValueError(f"{text} must hold a JSON list of conditions")
        return items
    return [name.strip() for name in text.split(",") if name.strip()]


def _cmd_eval(args: argparse.Namespace) -> int:
    set_threads(None)

    from modsat_core.agent.policy_file import load_policy
    from modsat_core.evaluation.run_files import final_evaluation
    from modsat_core.evaluation.run_folder import RunFolder

    actor, grid, spec = load_policy(RunFolder(args.run_dir).read("policy.pt"))
    if grid is None:
        print("modsat: this policy has no design", file=sys.stderr)
        return 2
    if args.conditions is not None:
        try:
            conditions = _conditions_arg(args.conditions)
            evaluation = spec.evaluation.model_validate({**spec.evaluation.model_dump(), "conditions": conditions})
        except (ValueError, OSError) as exc:
            print(f"modsat eval: --conditions: {exc}", file=sys.stderr)
            return 2
        spec = spec.model_copy(update={"evaluation": evaluation})
    t0 = time.monotonic()

    def on_stage(i: int, n: int, what: str) -> None:  # a line per stage: the evaluation takes a minute
        print(f"modsat eval: [{i}/{n}] {time.monotonic() - t0:5.1f} s  flying {what}", file=sys.stderr, flush=True)

    ev = final_evaluation(actor, grid, spec, episodes=args.episodes, on_stage=on_stage)
    print(f"modsat eval: done in {time.monotonic() - t0:.1f} s", file=sys.stderr, flush=True)
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
    set_threads(None)
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
        report = verify_run(args.run_dir, episodes=args.episodes, wheels=wheels, log=log)
    except ValueError as exc:  # a bad option, spec or design: a message, not a traceback
        print(f"modsat verify: {exc}", file=sys.stderr)
        return 2
    print(json.dumps(report, indent=2) if args.json else format_report(report))
    return 0


def add_run_parsers(sub) -> None:
    """Add ``presets``, ``schema``, ``check``, ``train``, ``eval`` and ``verify`` to the ``modsat``
    sub-command parser ``sub``."""
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
    ev.add_argument(
        "--conditions",
        metavar="LIST",
        help="flight conditions to fly besides the nominal slews (docs/robustness.md): `all` (the standard "
        "ones), `none`, names separated by commas (e.g. delay-1,sensor-noise), or a .json file with a list of "
        "conditions; default: the run's evaluation.conditions",
    )
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
