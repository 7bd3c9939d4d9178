"""A study: one spec flown over several seeds and algorithms (RL co-design and its GA twin at the
same env-step budget). The rules a study must meet and its jobs' specs, for ``POST /api/studies``
and ``modsat study`` alike; torch-free."""

from __future__ import annotations

from pydantic import ValidationError

from modsat_core.spec.jobspec import JobSpec, SpecError, format_errors, spec_errors

MAX_SEEDS = 16
ALGORITHMS = ("td3-codesign", "ga", "td3-control", "diffsim-control", "diffsim-codesign")
#: A study's algorithms when it names none: the paper's comparison, RL co-design against the GA.
#: (`td3-control` and `diffsim-control` fly the spec's `design.fixed_design`.)
DEFAULT_ALGORITHMS = ("td3-codesign", "ga")
#: The GA's inner TD3 gets at least this many times its ``learning_starts`` per design, so that it
#: learns on every design (a GA whose inner loop never updates compares RL with random controllers).
GA_MIN_STEPS_PER_LEARNING_START = 2


def seed_problem(seeds: object) -> str | None:
    if (
        not isinstance(seeds, list)
        or not 1 <= len(seeds) <= MAX_SEEDS
        or not all(isinstance(s, int) and not isinstance(s, bool) and 0 <= s < 2**31 for s in seeds)
        or len(set(seeds)) != len(seeds)
    ):
        return f"seeds: 1 to {MAX_SEEDS} distinct integers in [0, 2^31)"
    return None


def algorithm_problem(algorithms: object) -> str | None:
    if (
        not isinstance(algorithms, list)
        or not algorithms
        or not all(isinstance(a, str) for a in algorithms)  # before the set: a dict or list is unhashable
        or len(set(algorithms)) != len(algorithms)
        or not set(algorithms) <= set(ALGORITHMS)
    ):
        return f"algorithms: a non-empty list of distinct names from {', '.join(ALGORITHMS)}"
    return None


def ga_problem(spec: JobSpec) -> str | None:
    """Why the GA twin of ``spec`` would not be a fair comparison, or None."""
    need = GA_MIN_STEPS_PER_LEARNING_START * spec.training.learning_starts
    if spec.ga.steps_per_design < need:
        return (
            f"ga.steps_per_design: {spec.ga.steps_per_design} is under {GA_MIN_STEPS_PER_LEARNING_START} x "
            f"training.learning_starts ({spec.training.learning_starts}): the GA's inner TD3 would hardly "
            f"learn on each design; raise it to at least {need} for a fair GA"
        )
    return None


def study_specs(base: JobSpec, seeds: list[int], algorithms: list[str]) -> list[JobSpec]:
    """One spec per algorithm and seed (algorithms outer): ``base`` with its own seed and algorithm."""
    out = []
    for alg in algorithms:
        try:
            spec = JobSpec.model_validate({**base.model_dump(mode="json"), "algorithm": alg})
        except ValidationError as exc:  # e.g. `td3-control` on a spec without `design.fixed_design`
            raise SpecError([f"{alg}: {m}" for m in format_errors(exc)], spec_errors(exc)) from None
        out += [spec.model_copy(update={"seed": s}) for s in seeds]
    return out


def run_name(spec: JobSpec) -> str:
    """The directory of one run of a local study (``modsat study``)."""
    return f"{spec.algorithm}-seed{spec.seed}"
