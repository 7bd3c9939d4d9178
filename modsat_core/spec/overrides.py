"""A spec with overrides, the one resolver of both forms that name a preset: the REST API's
``{"preset": NAME, "overrides": {...}}`` (server/submit.py) and ``modsat train --preset NAME
--steps ... --seed ...`` (server/cli/common.py). The overrides are merged into the spec field by
field (nested objects merge, anything else replaces), and the result is validated like a whole
spec."""

from __future__ import annotations

from typing import Any

from modsat_core.spec.jobspec import JobSpec, parse_spec


def merge(base: dict[str, Any], overrides: dict[str, Any]) -> dict[str, Any]:
    """``base`` with ``overrides`` applied: nested dicts merge, other values replace."""
    out = dict(base)
    for k, v in overrides.items():
        out[k] = merge(out[k], v) if isinstance(v, dict) and isinstance(out.get(k), dict) else v
    return out


def with_overrides(spec: JobSpec, overrides: dict[str, Any]) -> JobSpec:
    """``spec`` (a preset, or a spec read from a file) with ``overrides`` merged in, validated
    again (:class:`~modsat_core.spec.jobspec.SpecError` if the result is not a valid spec)."""
    return parse_spec(merge(spec.model_dump(mode="json"), overrides))
