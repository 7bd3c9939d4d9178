"""Markdown reference of :class:`JobSpec`, generated from its JSON schema (docs/spec.md)."""

from __future__ import annotations

import json

from modsat_core.spec.jobspec import JobSpec
from modsat_core.spec.presets import PRESETS


def _type(node: dict, defs: dict) -> str:
    if "$ref" in node:
        return node["$ref"].rsplit("/", 1)[-1]
    if "anyOf" in node:
        return " or ".join(_type(n, defs) for n in node["anyOf"])
    if "enum" in node:
        return " \\| ".join(f"`{v}`" for v in node["enum"])
    if "const" in node:
        return f"`{node['const']}`"
    t = node.get("type", "any")
    if t == "array":
        if "prefixItems" in node:
            return f"[{', '.join(_type(n, defs) for n in node['prefixItems'])}]"
        return f"list of {_type(node.get('items', {}), defs)}"
    return t


def _bounds(node: dict) -> str:
    for branch in node.get("anyOf", []):
        if branch.get("type") != "null":
            node = branch
    parts = []
    for key, sym in (("minimum", ">="), ("exclusiveMinimum", ">"), ("maximum", "<="), ("exclusiveMaximum", "<")):
        if key in node:
            parts.append(f"{sym} {node[key]:g}" if isinstance(node[key], float) else f"{sym} {node[key]}")
    if "maxItems" in node:
        parts.append(f"{node.get('minItems', 0)}-{node['maxItems']} items")
    return ", ".join(parts)


def spec_markdown() -> str:
    schema = JobSpec.model_json_schema()
    defs = schema["$defs"]
    lines = [
        "# JobSpec reference",
        "",
        "Generated from the JSON schema by `modsat schema --markdown`; do not edit by hand.",
        f"Spec version {JobSpec().version}. Unknown keys are rejected; every number is bounded.",
        "",
    ]

    def table(title: str, node: dict) -> None:
        lines.extend(
            [
                f"## `{title}`",
                "",
                node.get("description", "").strip(),
                "",
                "| field | type | default | allowed | meaning |",
                "|---|---|---|---|---|",
            ]
        )
        for name, prop in node["properties"].items():
            default = prop.get("default", "")
            default = json.dumps(default) if default != "" else "(section)"
            desc = prop.get("description", "").replace("\n", " ")
            lines.append(f"| `{name}` | {_type(prop, defs)} | `{default}` | {_bounds(prop)} | {desc} |")
        lines.append("")

    table("JobSpec", schema)
    for name in ("DesignSpace", "ModuleCatalog", "Mission", "RewardSpec", "Training", "GA", "Evaluation", "Diffsim"):
        table(name, defs[name])
    lines.extend(
        [
            "## Presets",
            "",
            "| name | algorithm | grid | env steps | actuator model | torque scale (N m) |",
            "|---|---|---|---|---|---|",
        ]
    )
    for name, spec in PRESETS.items():
        n = spec.design.grid_size
        lines.append(
            f"| `{name}` | {spec.algorithm} | {n}x{n}x{n} | {spec.training.total_env_steps:,} | "
            f"{spec.modules.actuator_model} | {spec.modules.torque_scale_Nm} |"
        )
    return "\n".join(lines) + "\n"
