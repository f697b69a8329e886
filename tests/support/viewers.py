"""What the viewers people use accept of a JSON schema, as checks over every schema the
SDK writes (MCAP recordings, the live Foxglove server, its services).

* `lichtblick_refuses` ports Lichtblick's ``parseJsonSchema``
  (``packages/mcap-support/src/parseJsonSchema.ts``, lichtblick-suite/lichtblick at
  66adecb, the same as Foxglove Studio's last open-source one): a channel whose schema
  it throws on shows nothing in any panel. Each property has one ``type``, a string,
  among ``boolean``, ``string`` (no ``contentEncoding`` but ``base64``), ``number``,
  ``integer``, ``object`` (read the same way, nested) and ``array`` (whose ``items``
  have one of those types, a string not base64); or a ``oneOf`` of numeric ``const``.
  No list of types, no ``anyOf``, no ``null``, no property without a type.
* `schema_problems` adds what Ajv and JSON Schema itself refuse: an empty ``enum``
  (Ajv: "enum must have non-empty array"), a ``null`` alternative anywhere, and a schema
  that is not valid JSON Schema (2020-12 metaschema, checked by ``jsonschema``).
* `message_problems` validates a message (its JSON text, strict: no NaN, which
  ``JSON.parse`` refuses) against its schema with ``jsonschema``.
"""

from __future__ import annotations

import json
from typing import Any

from jsonschema import Draft202012Validator

__all__ = ["lichtblick_refuses", "message_problems", "schema_problems"]

_SCALARS = ("boolean", "string", "number", "integer")


def lichtblick_refuses(schema: dict[str, Any], name: str = "") -> list[str]:
    """Why Lichtblick's ``parseJsonSchema`` would throw on ``schema`` (empty: it reads
    it), each naming the property's path."""
    problems: list[str] = []

    def fields(node: dict[str, Any], path: str) -> None:
        if node.get("type") != "object":
            problems.append(f'{path or name}: expected "type": "object", got {node.get("type")!r}')
            return
        for field, prop in (node.get("properties") or {}).items():
            where = f"{path}.{field}" if path else field
            if not isinstance(prop, dict):
                problems.append(f"{where}: not an object")
                continue
            if isinstance(prop.get("oneOf"), list):
                if not all(isinstance(a.get("const"), int | float) for a in prop["oneOf"]):
                    problems.append(f"{where}: oneOf alternatives must have number values")
                continue
            kind = prop.get("type")
            if kind in _SCALARS:
                encoding = prop.get("contentEncoding")
                if kind == "string" and encoding not in (None, "base64"):
                    problems.append(f"{where}: unsupported contentEncoding {encoding!r}")
            elif kind == "object":
                fields(prop, where)
            elif kind == "array":
                items = prop.get("items")
                if not isinstance(items, dict):
                    problems.append(f"{where}: an array without items")
                    continue
                item_kind = items.get("type")
                if item_kind == "object":
                    fields(items, where)
                elif item_kind not in _SCALARS:
                    problems.append(f"{where}: unsupported type {item_kind!r} for array item")
                elif item_kind == "string" and items.get("contentEncoding") is not None:
                    problems.append(f"{where}: unsupported contentEncoding for array item")
            else:
                problems.append(f"{where}: unsupported type {kind!r}")

    fields(schema, "")
    return problems


def _walk(node: Any, path: str = "") -> Any:
    """Every subschema of ``node`` with its path."""
    if isinstance(node, dict):
        yield path, node
        for key, value in node.items():
            yield from _walk(value, f"{path}/{key}")
    elif isinstance(node, list):
        for i, value in enumerate(node):
            yield from _walk(value, f"{path}/{i}")


def schema_problems(schema: dict[str, Any], name: str = "") -> list[str]:
    """Everything a viewer or a validator refuses in ``schema``: Lichtblick's rules, an
    empty ``enum``, a ``null`` type or alternative, and what JSON Schema itself
    refuses."""
    problems = lichtblick_refuses(schema, name)
    for path, node in _walk(schema):
        if "enum" in node and not node["enum"]:
            problems.append(f"{name}{path}: empty enum")
        if "enum" in node and None in node["enum"]:
            problems.append(f"{name}{path}: null in enum")
        kind = node.get("type")
        if kind == "null" or (isinstance(kind, list) and "null" in kind):
            problems.append(f"{name}{path}: a null type")
        if isinstance(kind, list):
            problems.append(f"{name}{path}: a list of types {kind}")
        if "anyOf" in node:
            problems.append(f"{name}{path}: anyOf")
    try:
        Draft202012Validator.check_schema(schema)
    except Exception as exc:  # jsonschema's SchemaError: what it says
        problems.append(f"{name}: not a valid JSON schema: {exc}")
    return problems


def message_problems(schema: dict[str, Any], data: bytes | str) -> list[str]:
    """Why the message ``data`` (JSON text) does not match ``schema``: not strict JSON
    (``NaN``, ``Infinity``, which a browser's ``JSON.parse`` refuses), or what
    ``jsonschema`` finds."""

    def refuse(constant: str) -> Any:
        raise ValueError(f"not JSON: {constant}")

    try:
        message = json.loads(data, parse_constant=refuse)
    except ValueError as exc:
        return [str(exc)]
    validator = Draft202012Validator(schema)
    return [
        f"{'.'.join(map(str, e.absolute_path))}: {e.message}"
        for e in validator.iter_errors(message)
    ]
