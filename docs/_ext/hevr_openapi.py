"""The endpoint reference of ``hevr serve``, generated at build time from its OpenAPI document
(:func:`hevr.serve.openapi.openapi_document`, what the server answers at
``GET /v1/openapi.json``) and the protocol's models (:mod:`hevr.remote.schema`): written as
Markdown to ``docs/_generated/openapi.md`` (git-ignored), which ``reference/protocol.md``
includes. The document itself is written beside it, as ``openapi.json``, which the page offers
for download.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from sphinx.application import Sphinx

METHODS = ("get", "head", "post", "put", "patch", "delete")


def _cell(text: Any) -> str:
    return " ".join(str(text).split()).replace("|", "\\|")


def _name(ref: str) -> str:
    return ref.rsplit("/", 1)[-1]


def _schema_words(schema: dict) -> str:
    if "$ref" in schema:
        name = _name(schema["$ref"])
        return f"[`{name}`](#schema-{name.lower()})"
    if schema.get("format") == "binary":
        return "bytes"
    return schema.get("type", "")


def _content(content: dict) -> str:
    return "; ".join(f"`{media}`: {_schema_words(body.get('schema', {}))}" for media, body in content.items())


def _operation(path: str, method: str, op: dict, doc: dict, also_head: bool) -> list[str]:
    title = f"`{method.upper()} {path}`" + (" (and `HEAD`)" if also_head else "")
    out = [f"### {title}", "", op.get("summary", "").rstrip(".").capitalize() + ".", ""]
    security = op.get("security", doc.get("security"))
    out += [
        "Asks for no token." if security == [] else "Asks for the bearer token (on a server with a token table).",
        "",
    ]
    params = op.get("parameters", [])
    if params:
        out += ["| parameter | in | accepts | meaning |", "|---|---|---|---|"]
        for p in params:
            accepts = (
                f"`{p['schema']['pattern']}`"
                if "pattern" in p.get("schema", {})
                else p.get("schema", {}).get("type", "")
            )
            out.append(f"| `{p['name']}` | {p['in']} | {_cell(accepts)} | {_cell(p.get('description', ''))} |")
        out.append("")
    body = op.get("requestBody")
    if body:
        out += [f"Body{' (required)' if body.get('required') else ''}: {_content(body['content'])}.", ""]
    out += ["| status | answer | body | headers |", "|---|---|---|---|"]
    for status, answer in op["responses"].items():
        headers = ", ".join(f"`{h}`" for h in answer.get("headers", {}))
        out.append(
            f"| {status} | {_cell(answer.get('description', ''))} | {_content(answer.get('content', {}))} | {headers} |"
        )
    out.append("")
    return out


def openapi_markdown() -> str:
    """The endpoint and schema reference, as Markdown."""
    from hevr.remote import schema
    from hevr.serve.openapi import openapi_document

    doc = openapi_document()
    info = doc["info"]
    out = [
        f"The OpenAPI {doc['openapi']} document of `{info['title']}` {info['version']} "
        f"({{download}}`openapi.json </_generated/openapi.json>`, as the server answers it at "
        f"`GET /v1/openapi.json`), "
        f"in tables.",
        "",
        _cell(info["description"]),
        "",
        "## Endpoints",
        "",
    ]
    for path, item in doc["paths"].items():
        methods = [m for m in METHODS if m in item]
        for method in methods:
            if method == "head" and "get" in item:
                continue  # said with its GET: the same status and headers, no body
            out += _operation(path, method, item[method], doc, also_head=method == "get" and "head" in item)
    out += [
        "## Schemas",
        "",
        "The JSON Schema of each model of `hevr.remote.schema` (the same models check every request "
        "the server receives and every JSON answer the key holder's client reads).",
        "",
    ]
    models = {m.__name__: m for m in schema.MODELS}
    for name, s in doc["components"]["schemas"].items():
        out += [f"(schema-{name.lower()})=", f"### `{name}`", ""]
        if s.get("description"):
            out += [_cell(s["description"]).replace("``", "`"), ""]
        if name in models and s.get("properties"):
            out += [schema.field_table(models[name]), ""]
        elif "oneOf" in s or "anyOf" in s:
            out += [" or ".join(_schema_words(x) for x in s.get("oneOf", s.get("anyOf", []))), ""]
    return "\n".join(out) + "\n"


def _generate(app: Sphinx) -> None:
    from hevr.serve.openapi import openapi_document

    folder = Path(app.srcdir) / "_generated"
    folder.mkdir(exist_ok=True)
    _write(folder / "openapi.md", openapi_markdown())
    _write(folder / "openapi.json", json.dumps(openapi_document(), indent=2) + "\n")


def _write(path: Path, text: str) -> None:
    """Write ``text`` unless the file already holds it (an unchanged file keeps its time: no rebuild)."""
    if not path.exists() or path.read_text(encoding="utf-8") != text:
        path.write_text(text, encoding="utf-8")


def setup(app: Sphinx) -> dict:
    app.connect("builder-inited", _generate)
    return {"version": "1", "parallel_read_safe": True, "parallel_write_safe": True}
