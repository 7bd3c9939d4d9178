"""The JobSpec and everything about it: its sections and bounds, the presets, the memory limits,
studies, its schema page. Torch-free.

``from modsat_core.spec import JobSpec, parse_spec`` reads the spec's public face from here."""

from modsat_core.spec.jobspec import (
    GA,
    DesignSpace,
    Diffsim,
    Evaluation,
    JobSpec,
    Mission,
    ModuleCatalog,
    RewardSpec,
    SpecError,
    Training,
    UnrunnableSpec,
    format_errors,
    parse_spec,
)

__all__ = [
    "GA",
    "DesignSpace",
    "Diffsim",
    "Evaluation",
    "JobSpec",
    "Mission",
    "ModuleCatalog",
    "RewardSpec",
    "SpecError",
    "Training",
    "UnrunnableSpec",
    "format_errors",
    "parse_spec",
]
