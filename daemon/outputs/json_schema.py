"""JSON Schemas that Foxglove's JSON-schema parser takes, made from the payload models.

Foxglove (and Lichtblick, its open-source fork) read a JSON channel's schema
with ``parseJsonSchema`` of foxglove/mcap's ``typescript/support``: one object
at a time, each with ``"type": "object"`` and ``properties``; a property is a
boolean, string, number, integer, object or array, and an array's items are
one of those but an array. It knows no ``$ref``/``$defs``, no ``anyOf``, no
list of types, no ``null``; a schema it cannot read leaves the channel
without its fields in the plot and message-path pickers.

pydantic's schemas of the MQTT payloads use all of those: ``$ref`` for a
nested model, ``anyOf [T, null]`` for ``T | None``, ``additionalProperties``
for a dict, ``prefixItems`` for a tuple. ``foxglove_schema`` rewrites one:
nested models inlined; ``T | None`` as ``T``, left out of ``required`` (the
channels leave null fields out of their messages, so each message fits its
schema); a dict whose keys are known (``keys``, by field name) as an object
of those properties; a tuple of one type as an array of it. A field the parser
cannot describe at all (an array of arrays: the pose's keypoints) is left out
of ``properties`` and named in the schema's description: its values still
travel in every message.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any, Final

from pydantic import BaseModel

SCALARS: Final = ("boolean", "string", "number", "integer")
# What a property keeps of pydantic's schema besides its type (the rest is validation
# the parser ignores, or words that belong to the type that was rewritten).
_KEPT: Final = ("title", "description", "enum", "const", "minimum", "maximum", "format")

Schema = dict[str, Any]


def foxglove_schema(
    model: type[BaseModel], keys: Mapping[str, Sequence[str]] | None = None
) -> Schema:
    """``model``'s JSON Schema in the form Foxglove's parser reads (module docstring).

    ``keys``: for a dict field by name, the keys its messages carry (``probabilities``:
    the action names), so that each is a property a plot can pick."""
    raw = model.model_json_schema()
    defs: dict[str, Schema] = raw.pop("$defs", {})
    return _Flattener(defs, keys or {}).object(raw)


class _Flattener:
    def __init__(self, defs: dict[str, Schema], keys: Mapping[str, Sequence[str]]) -> None:
        self.defs = defs
        self.keys = keys

    def resolve(self, node: Schema) -> Schema:
        """``node`` with its ``$ref`` replaced by what it names (its own keys win)."""
        while "$ref" in node:
            target = self.defs[str(node["$ref"]).rsplit("/", 1)[-1]]
            node = {**target, **{k: v for k, v in node.items() if k != "$ref"}}
        return node

    def non_null(self, node: Schema) -> tuple[Schema, bool]:
        """``T | None`` as ``T``, and whether null was allowed."""
        node = self.resolve(node)
        if "anyOf" in node:
            options = [self.resolve(o) for o in node["anyOf"] if o.get("type") != "null"]
            nullable = len(options) < len(node["anyOf"])
            if len(options) != 1:
                return {}, nullable  # a real union: nothing the parser can type
            rest = {k: v for k, v in node.items() if k not in ("anyOf", "default")}
            return {**options[0], **rest}, nullable
        kind = node.get("type")
        if isinstance(kind, list):
            types = [t for t in kind if t != "null"]
            return ({**node, "type": types[0]} if len(types) == 1 else {}), "null" in kind
        return node, False

    def object(self, node: Schema) -> Schema:
        out: Schema = {k: node[k] for k in ("title", "description") if k in node}
        out["type"] = "object"
        properties: Schema = {}
        required = list(node.get("required", []))
        left_out = []
        for name, raw in node.get("properties", {}).items():
            field, nullable = self.non_null(raw)
            converted = self.field(name, field)
            if converted is None:
                left_out.append(name)
            else:
                properties[name] = converted
            if converted is None or nullable:
                required = [r for r in required if r != name]
        out["properties"] = properties
        if required:
            out["required"] = required
        if left_out:
            note = (
                f"Not described here (Foxglove's schema parser cannot type them), "
                f"still in every message: {', '.join(left_out)}."
            )
            out["description"] = f"{out['description']} {note}" if "description" in out else note
        return out

    def field(self, name: str, node: Schema) -> Schema | None:
        """One property in the parser's form, or None when it has none."""
        kind = node.get("type")
        words: Schema = {k: node[k] for k in _KEPT if k in node}
        if "default" in node and node["default"] is not None:
            words["default"] = node["default"]
        if kind in SCALARS:
            return {**words, "type": kind}
        if kind == "object":
            if "properties" in node:
                return self.object(node)
            values = node.get("additionalProperties")
            known = self.keys.get(name) or node.get("propertyNames", {}).get("enum")
            if not known or not isinstance(values, dict):
                return None  # free keys: nothing to list
            value, _ = self.non_null(values)
            typed = self.field(name, value)
            if typed is None:
                return None
            return {**words, "type": "object", "properties": dict.fromkeys(known, typed)}
        if kind == "array":
            items = node.get("items")
            if items is None:  # a tuple: one type throughout, or nothing to say
                kinds = [self.non_null(i)[0] for i in node.get("prefixItems", [])]
                if not kinds or any(k != kinds[0] for k in kinds):
                    return None
                items = kinds[0]
            item, _ = self.non_null(items)
            item_kind = item.get("type")
            if item_kind in SCALARS:
                typed_item: Schema | None = {"type": item_kind}
            elif item_kind == "object" and "properties" in item:
                typed_item = self.object(item)
            else:
                typed_item = None  # an array of arrays, or of free objects
            return None if typed_item is None else {**words, "type": "array", "items": typed_item}
        return None
