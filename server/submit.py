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

from modsat_core.spec.jobspec import (
    MAX_ERRORS,
    MAX_MESSAGE,
    MAX_QUOTED,
    JobSpec,
    SpecError,
    field_path,
    parse_spec,
    quote,
)
from modsat_core.spec.limits import Limits
from modsat_core.spec.limits import check as check_limits
from modsat_core.spec.overrides import with_overrides
from modsat_core.spec.presets import PRESETS

log = logging.getLogger("modsat.server")


class BadRequest(Exception):
    """The body cannot be read at all (400)."""


class Invalid(Exception):
    """The body was read but is not a valid submission (422). ``errors`` are FastAPI-style."""

    def __init__(self, errors: list[dict[str, Any]], omitted: int = 0):
        self.errors, self.omitted = errors, omitted  # omitted: problems found but not in ``errors``
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


def _short_loc(part: Any) -> Any:
    return part if not isinstance(part, str) or len(part) <= MAX_QUOTED else f"{part[:MAX_QUOTED]}..."


def invalid_response(exc: Invalid) -> JSONResponse:
    """The 422 answer of an :class:`Invalid` submission: FastAPI-style ``detail`` plus ``messages``;
    at most :data:`MAX_ERRORS` problems (and one line counting the rest), each key in a location cut to
    :data:`MAX_QUOTED` characters and each message to :data:`MAX_MESSAGE`: an answer never echoes a
    long request."""
    errors, more = exc.errors[:MAX_ERRORS], max(0, len(exc.errors) - MAX_ERRORS) + exc.omitted
    if more:
        errors.append(_error([], f"... and {more} more problems, not listed", "too_many_errors"))
    detail = [
        {
            **e,
            "loc": [_short_loc(p) for p in e["loc"]],
            "msg": e["msg"] if len(e["msg"]) <= MAX_MESSAGE else f"{e['msg'][:MAX_MESSAGE]}... (cut)",
        }
        for e in errors
    ]
    return JSONResponse({"detail": detail, "messages": [e["msg"] for e in detail]}, status_code=422)


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


class _Repeated(dict):
    """A JSON object that named a key more than once (``repeated`` lists those keys)."""

    repeated: list[str]


def _pairs(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    obj = dict(pairs)
    if len(obj) == len(pairs):
        return obj
    seen: set[str] = set()
    out = _Repeated(obj)
    out.repeated = [k for k, _ in pairs if k in seen or seen.add(k)]  # type: ignore[func-returns-value]
    return out


def _repeated_keys(value: Any) -> list[dict[str, Any]]:
    """422 errors for the keys that an object of ``value`` names twice (JSON leaves it undefined which
    one counts; Python's reader would silently keep the last), at most :data:`MAX_ERRORS`."""
    errors: list[dict[str, Any]] = []
    stack: list[tuple[list[Any], Any]] = [([], value)]
    while stack and len(errors) < MAX_ERRORS:
        loc, v = stack.pop()
        if isinstance(v, _Repeated):
            for key in dict.fromkeys(v.repeated):
                errors.append(
                    _error(
                        [*loc, key],
                        f"{field_path([*loc, key])}: this key is given more than once in the same object (which one "
                        "counts is not guessed); give it once",
                        "duplicate_key",
                    )
                )
        if isinstance(v, dict):
            stack.extend(([*loc, k], x) for k, x in reversed(v.items()))
        elif isinstance(v, list):
            stack.extend(([*loc, i], x) for i, x in reversed(list(enumerate(v))))
    return errors[:MAX_ERRORS]


def decode_json(raw: bytes) -> Any:
    """The JSON value of a request body; :class:`BadRequest` saying what is wrong otherwise, and
    :class:`Invalid` (422) naming a key that an object gives twice."""
    if not raw.strip():
        raise BadRequest('the request body is empty; send a JobSpec or {"preset": NAME} as JSON')
    text = _utf8(raw)
    try:
        value = json.loads(text, object_pairs_hook=_pairs)
    except json.JSONDecodeError as exc:
        raise BadRequest(
            f"the request body is not valid JSON: {exc.msg} at line {exc.lineno} column {exc.colno}"
        ) from None
    except (ValueError, RecursionError) as exc:  # e.g. an integer with too many digits, nesting too deep
        raise BadRequest(f"the request body is not usable JSON: {type(exc).__name__}") from None
    if '"' in text and (repeated := _repeated_keys(value)):
        raise Invalid(repeated)
    return value


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
                        f"{quote(k)}: unknown field next to 'preset'; a preset submission has only "
                        f"'preset' and 'overrides' (put spec fields inside 'overrides')",
                        "extra_forbidden",
                    )
                    for k in extra
                ]
            )
        name, overrides = body["preset"], body.get("overrides", {})
        if not isinstance(name, str) or name not in PRESETS:
            raise Invalid(
                [
                    _error(
                        ["preset"],
                        f"preset: unknown preset {quote(name)}; known: {', '.join(PRESETS)}",
                        "literal_error",
                    )
                ]
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
        raise Invalid([_error(prefix + loc, msg, kind) for loc, msg, kind in errors], exc.omitted) from None
    except (ValueError, TypeError, RecursionError, AttributeError, KeyError, IndexError):
        # A validator's bug must not become a 500, nor show its internal text to the client.
        log.exception("spec validation raised unexpectedly")
        raise Invalid(
            [_error(prefix, "body: the spec could not be validated (a malformed value the checks did not expect)")]
        ) from None
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


def limit_errors(spec: JobSpec, limits: Limits, prefix: list[Any]) -> list[dict[str, Any]]:
    """422 errors of a valid spec over this service's limits (memory, work; docs/service.md)."""
    return [_error([*prefix, *loc], msg, "resource_limit") for loc, msg in check_limits(spec, limits)]


def job_from_body(raw: bytes, limits: Limits) -> JobSpec:
    """A POST /api/jobs body (bytes) as a spec within ``limits``: :class:`BadRequest` or :class:`Invalid`
    otherwise. CPU-bound (~1-10 ms, more for a large invalid body): the routes run it in a thread,
    off the event loop, so that no body delays other requests."""
    body = decode_json(raw)
    spec = spec_from_body(body)
    problems = limit_errors(spec, limits, ["overrides"] if "preset" in body else [])
    if problems:
        raise Invalid(problems)
    return spec
