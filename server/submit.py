"""Turn a POST /api/jobs body into a :class:`JobSpec`, or into errors a person can act on.

Two body forms (docs/service.md):

* a whole JobSpec, e.g. ``{"algorithm": "td3-codesign", "training": {...}, ...}``;
* a preset with overrides, e.g. ``{"preset": "quick", "overrides": {"seed": 3}}``. The
  overrides are merged into the preset field by field (nested objects merge, anything
  else replaces), and the result is validated like a whole spec
  (:func:`modsat_core.spec.overrides.with_overrides`, which ``modsat train --preset`` uses too).
"""

from __future__ import annotations

import codecs
import json
import logging
from typing import Any

from fastapi import HTTPException
from fastapi.responses import JSONResponse

from modsat_core.spec.jobspec import JobSpec, SpecError, parse_spec
from modsat_core.spec.overrides import with_overrides
from modsat_core.spec.presets import PRESETS

log = logging.getLogger("modsat.server")


class BadRequest(Exception):
    """The body cannot be read at all (400)."""


class Invalid(Exception):
    """The body was read but is not a valid submission (422). ``errors`` are FastAPI-style."""

    def __init__(self, errors: list[dict[str, Any]]):
        self.errors = errors
        super().__init__("; ".join(e["msg"] for e in errors))


def _error(loc: list[Any], msg: str, kind: str = "value_error") -> dict[str, Any]:
    return {"loc": ["body", *loc], "msg": msg, "type": kind}


def json_content_type(content_type: str | None) -> None:
    """415 unless the body is sent as application/json (in UTF-8, the only charset JSON has). Also
    a guard: a page of another site can send text/plain or a form without asking first."""
    ctype, *params = (content_type or "").split(";")
    ctype = ctype.strip().lower()
    if ctype != "application/json":
        raise HTTPException(415, f"send the body as application/json (Content-Type was {ctype[:80] or 'missing'!r})")
    for param in params:
        key, _, value = param.partition("=")
        charset = value.strip().strip('"').lower()
        if key.strip().lower() == "charset" and charset not in ("utf-8", "utf8"):
            raise HTTPException(415, f"send the body as UTF-8 JSON (Content-Type said charset={charset[:40]!r})")


def invalid_response(exc: Invalid) -> JSONResponse:
    """The 422 answer of an :class:`Invalid` submission: FastAPI-style ``detail`` plus ``messages``."""
    return JSONResponse({"detail": exc.errors, "messages": [e["msg"] for e in exc.errors]}, status_code=422)


#: Byte order marks of the encodings that ``json.loads(bytes)`` would otherwise detect and accept.
_BOMS = (
    (codecs.BOM_UTF32_LE, "UTF-32"),  # before UTF-16 LE, whose mark it starts with
    (codecs.BOM_UTF32_BE, "UTF-32"),
    (codecs.BOM_UTF16_LE, "UTF-16"),
    (codecs.BOM_UTF16_BE, "UTF-16"),
)


def _utf8(raw: bytes) -> str:
    """The body as text: UTF-8 only (RFC 8259), a UTF-8 byte order mark tolerated."""
    for bom, name in _BOMS:
        if raw.startswith(bom):
            raise BadRequest(f"the request body is {name} (it starts with a {name} byte order mark); send it as UTF-8")
    if b"\x00" in raw:  # JSON text never holds a NUL byte; UTF-16 or UTF-32 without a mark does
        raise BadRequest("the request body is not UTF-8 text (it holds NUL bytes: UTF-16 or UTF-32?); send it as UTF-8")
    try:
        return raw.removeprefix(codecs.BOM_UTF8).decode("utf-8")
    except UnicodeDecodeError as exc:
        raise BadRequest(
            f"the request body is not UTF-8 text (byte {exc.start} cannot be read); send it as UTF-8"
        ) from None


def decode_json(raw: bytes) -> Any:
    """The JSON value of a request body; :class:`BadRequest` saying what is wrong otherwise."""
    if not raw.strip():
        raise BadRequest('the request body is empty; send a JobSpec or {"preset": NAME} as JSON')
    text = _utf8(raw)
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise BadRequest(
            f"the request body is not valid JSON: {exc.msg} at line {exc.lineno} column {exc.colno}"
        ) from None
    except (ValueError, RecursionError) as exc:  # e.g. an integer with too many digits, nesting too deep
        raise BadRequest(f"the request body is not usable JSON: {type(exc).__name__}") from None


def spec_from_body(body: Any) -> JobSpec:
    """Validate a decoded body; raises :class:`Invalid` with one error per problem."""
    if not isinstance(body, dict):
        raise Invalid(
            [
                _error(
                    [], 'body: expected a JSON object: a JobSpec, or {"preset": NAME, "overrides": {...}}', "dict_type"
                )
            ]
        )
    prefix: list[Any] = []
    if "preset" in body:
        extra = sorted(set(body) - {"preset", "overrides"})
        if extra:
            raise Invalid(
                [
                    _error(
                        [k],
                        f"{k}: unknown field next to 'preset'; a preset submission has only "
                        f"'preset' and 'overrides' (put spec fields inside 'overrides')",
                        "extra_forbidden",
                    )
                    for k in extra
                ]
            )
        name, overrides = body["preset"], body.get("overrides", {})
        if not isinstance(name, str) or name not in PRESETS:
            raise Invalid(
                [_error(["preset"], f"preset: unknown preset {name!r}; known: {', '.join(PRESETS)}", "literal_error")]
            )
        if overrides is None:
            overrides = {}
        if not isinstance(overrides, dict):
            raise Invalid(
                [_error(["overrides"], 'overrides: expected an object of spec fields, e.g. {"seed": 3}', "dict_type")]
            )
        prefix = ["overrides"]
    try:
        spec = with_overrides(PRESETS[name], overrides) if prefix else parse_spec(body)
    except SpecError as exc:
        locs = [list(e.get("loc", ())) for e in exc.errors] or [[] for _ in exc.messages]
        kinds = [str(e.get("type", "value_error")) for e in exc.errors] or ["value_error" for _ in exc.messages]
        if len(locs) != len(exc.messages):
            locs, kinds = [[] for _ in exc.messages], ["value_error" for _ in exc.messages]
        errors = zip(locs, exc.messages, kinds, strict=True)
        raise Invalid([_error(prefix + loc, msg, kind) for loc, msg, kind in errors]) from None
    except (ValueError, TypeError, RecursionError) as exc:  # a validator bug must not become a 500
        log.exception("spec validation raised unexpectedly")
        raise Invalid([_error([], f"body: the spec could not be validated: {exc}")]) from None
    if not prefix and "algorithm" not in body:
        raise Invalid(
            [
                _error(
                    ["algorithm"],
                    'algorithm: a submission names a preset ({"preset": "quick"}, `GET /api/presets` lists them) '
                    "or the algorithm of a whole spec; without either it would be the default 200,000-step "
                    "td3-codesign job",
                    "missing",
                )
            ]
        )
    if spec.name is not None and "\x00" in spec.name:  # stored as a text column: PostgreSQL refuses NUL
        raise Invalid(
            [_error([*prefix, "name"], "name: must not contain the NUL character (\\u0000)", "string_pattern_mismatch")]
        )
    return spec
