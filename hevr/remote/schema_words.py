"""A JSON Schema in words, and a pydantic model's refusal as one line ``field: expected X, got Y``:
what every refused request and answer of the protocol (:mod:`hevr.remote.schema`'s models) says.
Generic: any pydantic model's schema is derived from the model itself (:func:`_defs`).

>>> expected({"type": "array", "minItems": 3, "maxItems": 3, "items": {"type": "number"}})
'an array of 3 items, each a number'
"""

from __future__ import annotations

import json
from functools import cache
from typing import Any

from pydantic import BaseModel, ValidationError
from pydantic.json_schema import GenerateJsonSchema, models_json_schema

from ..errors import ParameterError

__all__ = ["check", "expected", "message"]


class _NoTitles(GenerateJsonSchema):
    """JSON Schema without pydantic's generated field titles ("Focal Point")."""

    def field_title_should_be_set(self, schema: Any) -> bool:
        return False


@cache
def _defs(model: type[BaseModel]) -> dict[str, dict[str, Any]]:
    """The JSON Schema of ``model`` and of every model it refers to, by name (references
    ``#/$defs/NAME``): what :func:`message` walks, derived from the model itself, so that any model
    :func:`check` is given (``RenderOptions`` included) has its schema.

    >>> class Point(BaseModel):
    ...     x: int
    >>> sorted(_defs(Point))
    ['Point']
    """
    _, doc = models_json_schema([(model, "validation")], ref_template="#/$defs/{model}", schema_generator=_NoTitles)
    return doc["$defs"]


def check(model: type[BaseModel], data: Any, name: str = "request") -> Any:
    """``data`` validated by ``model``; a :class:`hevr.ParameterError` naming the field otherwise
    (``name``: what the whole object is called)."""
    try:
        return model.model_validate(data)
    except ValidationError as exc:
        raise ParameterError(message(exc, model, name)) from None


def _show(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 80 else text[:77] + "..."


def _deref(s: dict[str, Any], defs: dict[str, Any] | None = None) -> dict[str, Any]:
    """``s``, or the schema its ``$ref`` names in ``defs`` (followed to the end)."""
    while "$ref" in s:
        s = (defs or {})[s["$ref"].rsplit("/", 1)[1]]
    return s


def _walk(model: type[BaseModel], loc: tuple[int | str, ...]) -> tuple[str, dict[str, Any], dict[str, Any], bool]:
    """(the field's path, the schema of the field, the schema of the node the error is at,
    whether the walk stopped at a union's member) of a pydantic error location in ``model``."""
    defs = _defs(model)
    node = field = defs[model.__name__]
    path = ""
    for part in loc:
        node = _deref(node, defs)
        options = node.get("oneOf") or node.get("anyOf")
        if options and isinstance(part, str) and {"$ref": f"#/$defs/{part}"} in options:
            node = defs[part]  # a tagged member: the same field
        elif isinstance(part, int) and "items" in node:
            node = field = node["items"]
            path += f"[{part}]"
        elif isinstance(part, str) and part in node.get("properties", {}):
            node = field = node["properties"][part]
            path += f".{part}" if path else part
        else:  # inside an untagged union (its members' names): the field as a whole
            return path, field, field, True
    return path, field, _deref(node, defs), False


def _number(x: Any) -> str:
    return str(x) if isinstance(x, int) else f"{x:g}"


def expected(s: dict[str, Any], defs: dict[str, Any] | None = None) -> str:
    """What a JSON Schema accepts, in words (``defs``: the schemas its references name, as
    ``hevr.remote.schema.components("#/$defs/{model}")`` gives the protocol's).

    >>> expected({"type": "integer", "minimum": 0, "maximum": 8})
    'an integer in [0, 8]'
    >>> expected({"anyOf": [{"type": "number", "exclusiveMinimum": 0}, {"type": "null"}]})
    'a number > 0 or null'
    """
    s = _deref(s, defs)
    if "const" in s:
        return json.dumps(s["const"])
    if "enum" in s:
        return "one of " + ", ".join(map(str, s["enum"]))
    options = s.get("oneOf") or s.get("anyOf")
    if options:
        return " or ".join(expected(o, defs) for o in options)
    kind = s.get("type")
    if kind in ("integer", "number"):
        lo = (
            f"[{_number(s['minimum'])}"
            if "minimum" in s
            else f"({_number(s['exclusiveMinimum'])}"
            if "exclusiveMinimum" in s
            else None
        )
        hi = (
            f"{_number(s['maximum'])}]"
            if "maximum" in s
            else f"{_number(s['exclusiveMaximum'])})"
            if "exclusiveMaximum" in s
            else None
        )
        what = "an integer" if kind == "integer" else "a number"
        if lo and hi:
            return f"{what} in {lo}, {hi}"
        if lo:
            return f"{what} {'>=' if lo[0] == '[' else '>'} {lo[1:]}"
        return f"{what} {'<=' if hi[-1] == ']' else '<'} {hi[:-1]}" if hi else what
    if kind == "array":
        lo, hi = s.get("minItems", 0), s.get("maxItems")
        count = f"{lo}" if lo == hi else f"{lo} to {hi}" if hi is not None else f"at least {lo}"
        return f"an array of {count} items, each {expected(s.get('items', {}), defs)}"
    if kind == "string":
        return s.get("description") or (f"a string matching {s['pattern']}" if "pattern" in s else "a string")
    if kind == "object":
        return f"a {s['title']} object" if "title" in s else "a JSON object"
    words = {"boolean": "true or false", "null": "null"}
    return words.get(kind, "a JSON value") if isinstance(kind, str) else "a JSON value"


def message(exc: ValidationError, model: type[BaseModel], name: str) -> str:
    """The one-line message of a pydantic error of ``model`` (any model: its schema is derived
    from it): unknown fields first, then missing ones, then the first field refused, each as
    ``field: expected X, got Y``.

    >>> from typing import Annotated
    >>> from pydantic import Field
    >>> class Options(BaseModel):
    ...     step: Annotated[float, Field(gt=0, le=1e6)] = 1.0
    >>> try:
    ...     Options.model_validate({"step": -1.0})
    ... except ValidationError as exc:
    ...     message(exc, Options, "request")
    'step: expected a number in (0, 1e+06], got -1.0'
    """
    errors = exc.errors(include_url=False)
    for kind in ("extra_forbidden", "missing"):
        found = [e for e in errors if e["type"] == kind]
        if found:
            where = min((_walk(model, e["loc"][:-1]) for e in found), key=lambda w: w[0].count("."))
            names = sorted(str(e["loc"][-1]) for e in found if _walk(model, e["loc"][:-1])[0] == where[0])
            node = where[2]
            if kind == "extra_forbidden":
                return (
                    f"{where[0] or name}: expected only the fields {sorted(node.get('properties', {}))}, "
                    f"got extra fields {names}"
                )
            return f"{where[0] or name}: expected the fields {sorted(node.get('required', []))}, missing {names}"
    e = errors[0]
    path, field, node, _ = _walk(model, e["loc"])
    return f"{path or name}: expected {expected(field if path else node, _defs(model))}, got {_show(e['input'])}"
