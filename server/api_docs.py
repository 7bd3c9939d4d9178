"""``/api/docs``: the API's reference as one HTML page made from the OpenAPI schema, with no script and
nothing from another site (DESIGN.md: no CDN at run time, the API docs included). FastAPI's Swagger UI
loads its scripts from a CDN and is blank offline; this page lists every operation with its parameters
(and their bounds), its body and its answers, and links the schema (``/api/openapi.json``) for tools."""

from __future__ import annotations

import html
import json
from typing import Any

#: The page's own policy (besides the framing one every answer carries): no script, no request out.
CSP = "default-src 'none'; style-src 'unsafe-inline'; img-src 'self'; base-uri 'none'; form-action 'none'"

_STYLE = """
body{font:15px/1.45 system-ui,sans-serif;max-width:980px;margin:2em auto;padding:0 1em;color:#222}
h2{margin-top:2em;border-bottom:1px solid #ccc} h3{margin:1.4em 0 .3em;font-family:monospace;font-size:1.05em}
.m{display:inline-block;min-width:4.2em;font-weight:bold} table{border-collapse:collapse;margin:.3em 0}
td,th{border:1px solid #ddd;padding:2px 8px;text-align:left;vertical-align:top;font-size:.92em}
code{background:#f4f4f4;padding:0 3px} p.d{margin:.2em 0 .5em;white-space:pre-line}
"""

_BOUNDS = (("minimum", ">="), ("exclusiveMinimum", ">"), ("maximum", "<="), ("exclusiveMaximum", "<"))


def _e(text: Any) -> str:
    return html.escape(str(text))


def _type(schema: dict[str, Any]) -> str:
    """A parameter's type and bounds in a few words."""
    if "$ref" in schema:
        return schema["$ref"].rsplit("/", 1)[-1]
    if "anyOf" in schema:
        branches = [_type({**b, **{k: schema[k] for k, _ in _BOUNDS if k in schema}}) for b in schema["anyOf"]]
        return " or ".join(b for b in branches if b != "null")
    if "enum" in schema:
        return " | ".join(str(v) for v in schema["enum"])
    words = [schema.get("type", "any")]
    if schema.get("type") == "array":
        words = [f"list of {_type(schema.get('items', {}))}"]
    words += [f"{sign} {schema[k]}" for k, sign in _BOUNDS if k in schema]
    if "pattern" in schema:
        words.append(f"matching {schema['pattern']}")
    if "default" in schema:
        words.append(f"(default {json.dumps(schema['default'])})")
    return " ".join(words)


def _body(op: dict[str, Any]) -> str:
    content = op.get("requestBody", {}).get("content", {})
    if not content:
        return ""
    media, spec = next(iter(content.items()))
    schema = spec.get("schema", {})
    names = [b.get("$ref", "").rsplit("/", 1)[-1] for b in schema.get("oneOf", [schema])]
    links = " or ".join(f'<a href="#schema-{_e(n)}">{_e(n)}</a>' for n in names if n)
    return f"<p>Body: <code>{_e(media)}</code>, {links or 'JSON'}</p>"


def render(schema: dict[str, Any]) -> str:
    """The reference page of ``schema`` (an OpenAPI document)."""
    info = schema.get("info", {})
    out = [
        "<!doctype html><html lang=en><head><meta charset=utf-8>",
        f"<title>{_e(info.get('title', 'API'))}: API reference</title><style>{_STYLE}</style></head><body>",
        f"<h1>{_e(info.get('title', 'API'))} {_e(info.get('version', ''))}</h1>",
        f"<p class=d>{_e(info.get('description', ''))}</p>",
        '<p>The machine-readable schema: <a href="/api/openapi.json">/api/openapi.json</a> (OpenAPI '
        f"{_e(schema.get('openapi', ''))}). The service\u2019s guide is docs/service.md in the source tree.</p>",
    ]
    for path, ops in schema.get("paths", {}).items():
        for method, op in ops.items():
            out.append(f"<h3><span class=m>{_e(method.upper())}</span> {_e(path)}</h3>")
            text = op.get("description") or op.get("summary") or ""
            out.append(f"<p class=d>{_e(text)}</p>")
            params = op.get("parameters", [])
            if params:
                out.append("<table><tr><th>parameter</th><th>in</th><th>type</th><th>about</th></tr>")
                for p in params:
                    about = p.get("description") or p.get("schema", {}).get("description", "")
                    required = " (required)" if p.get("required") else ""
                    kind = _type(p.get("schema", {}))
                    out.append(
                        f"<tr><td><code>{_e(p['name'])}</code>{required}</td><td>{_e(p.get('in', ''))}</td>"
                        f"<td>{_e(kind)}</td><td>{_e(about)}</td></tr>"
                    )
                out.append("</table>")
            out.append(_body(op))
            answers = ", ".join(
                f"<b>{_e(code)}</b> {_e(r.get('description', ''))}" for code, r in op.get("responses", {}).items()
            )
            out.append(f"<p>Answers: {answers}</p>")
    out.append("<h2>Schemas</h2><p>Each as JSON Schema (the request bodies are closed: unknown fields are 422).</p>")
    for name, sub in schema.get("components", {}).get("schemas", {}).items():
        out.append(f"<details id=schema-{_e(name)}><summary><code>{_e(name)}</code></summary>")
        out.append(f"<pre>{_e(json.dumps(sub, indent=1))}</pre></details>")
    out.append("</body></html>")
    return "\n".join(out)
