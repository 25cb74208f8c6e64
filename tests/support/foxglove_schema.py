"""The rules of Foxglove's JSON-schema parser, as a checker of a channel's schema.

``parseJsonSchema`` in foxglove/mcap ``typescript/support`` (Foxglove, Lichtblick)
walks a schema one object at a time: ``"type": "object"`` and a ``properties``
map on each; every property of type boolean, string, number, integer, object
(checked the same way) or array, whose ``items`` is one of those but an array;
anything else (``null``, a list of types, no type) throws. ``oneOf`` it takes
only as numeric constants; ``$ref``, ``$defs``, ``anyOf`` and ``allOf`` it
never follows. ``problems`` lists every place a schema breaks those rules, and
also refuses any of those keywords anywhere, ``oneOf`` included: none of our
channels needs one.
"""

from __future__ import annotations

from typing import Any, Final

SCALARS: Final = ("boolean", "string", "number", "integer")
FORBIDDEN: Final = ("$ref", "$defs", "definitions", "anyOf", "allOf", "oneOf")


def problems(schema: Any) -> list[str]:
    """Every breach of the parser's rules in ``schema`` (empty: Foxglove reads it)."""
    found = [f"{where}: {key}" for where, key in _keywords(schema, "$")]
    found += _object(schema, "$")
    return found


def _keywords(node: Any, where: str) -> list[tuple[str, str]]:
    out: list[tuple[str, str]] = []
    if isinstance(node, dict):
        out += [(where, key) for key in FORBIDDEN if key in node]
        for key, value in node.items():
            if key not in ("enum", "const", "default"):  # values, not schemas
                out += _keywords(value, f"{where}.{key}")
    elif isinstance(node, list):
        for i, value in enumerate(node):
            out += _keywords(value, f"{where}[{i}]")
    return out


def _object(node: Any, where: str) -> list[str]:
    if not isinstance(node, dict) or node.get("type") != "object":
        kind = node.get("type") if isinstance(node, dict) else type(node).__name__
        return [f"{where}: type {kind!r}, the parser wants 'object'"]
    properties = node.get("properties")
    if not isinstance(properties, dict):
        return [f"{where}: an object without properties (the parser reads none)"]
    out: list[str] = []
    for name, field in properties.items():
        out += _field(field, f"{where}.{name}")
    return out


def _field(field: Any, where: str) -> list[str]:
    kind = field.get("type") if isinstance(field, dict) else None
    if kind in SCALARS:
        return []
    if kind == "object":
        return _object(field, where)
    if kind == "array":
        items = field.get("items")
        item_kind = items.get("type") if isinstance(items, dict) else None
        if item_kind in SCALARS:
            return []
        if item_kind == "object":
            return _object(items, f"{where}[]")
        return [f"{where}[]: array items of type {item_kind!r}"]
    return [f"{where}: type {kind!r}"]


_PYTHON_TYPES: Final = {
    "boolean": (bool,),
    "string": (str,),
    "integer": (int,),
    "number": (int, float),
}


def misfits(value: Any, schema: dict[str, Any], where: str = "$") -> list[str]:
    """Where a message breaks its (parser-form) schema: a value of another type, a
    required field absent, a field the schema neither describes nor names as left out
    (its description's "still in every message: a, b.")."""
    kind = schema.get("type")
    if kind in _PYTHON_TYPES:
        ok = isinstance(value, _PYTHON_TYPES[kind]) and not (
            kind != "boolean" and isinstance(value, bool)
        )
        return [] if ok else [f"{where}: {value!r} is not {kind}"]
    if kind == "array":
        if not isinstance(value, list):
            return [f"{where}: {value!r} is not an array"]
        return [
            m for i, v in enumerate(value) for m in misfits(v, schema["items"], f"{where}[{i}]")
        ]
    if not isinstance(value, dict):
        return [f"{where}: {value!r} is not an object"]
    out = [f"{where}.{r}: required, absent" for r in schema.get("required", []) if r not in value]
    described = schema["properties"]
    left_out = schema.get("description", "").partition("still in every message: ")[2]
    named = {n.strip(" .") for n in left_out.split(",")} if left_out else set()
    for key, v in value.items():
        if key in described:
            out += misfits(v, described[key], f"{where}.{key}")
        elif key not in named:
            out.append(f"{where}.{key}: not in the schema")
    return out
