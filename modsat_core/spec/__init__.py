"""The JobSpec and everything about it: its sections and bounds, the presets, the memory limits,
studies, its schema page. Torch-free.

``from modsat_core.spec import JobSpec, parse_spec`` reads the spec's public face from here."""

from modsat_core.spec import jobspec
from modsat_core.spec.jobspec import *  # noqa: F403 (the spec's public face: jobspec.__all__, listed once)

__all__ = jobspec.__all__
