"""A small JSON Schema validator for the score card's schema (pbdyn/benchmark/card.schema.json).

pbdyn does not depend on the jsonschema package, so this module checks the subset of JSON Schema (draft 2020-12)
the card's schema uses: type, properties, required, additionalProperties, items, minItems, maxItems, const, enum,
pattern, minimum and maximum (annotations such as description are ignored). A schema that uses any other keyword is
refused when it is loaded, so the subset cannot silently fall behind the schema. tests/test_input_bounds.py and
tests/test_card_v2.py check that it decides as jsonschema does on real and tampered cards.
"""

from __future__ import annotations

import functools
import json
import math
import re
from pathlib import Path

SCHEMA_FILE = Path(__file__).with_name("card.schema.json")
KEYWORDS = frozenset({"type", "properties", "required", "additionalProperties", "items", "minItems", "maxItems",
                      "const", "enum", "pattern", "minimum", "maximum"})
"""The validating keywords this module implements."""
ANNOTATIONS = frozenset({"$schema", "$id", "title", "description"})
"""Keywords that do not validate."""


class SchemaError(ValueError):
    """A schema that uses a keyword outside KEYWORDS."""


@functools.lru_cache(maxsize=1)
def card_schema() -> dict:
    """The shipped card schema, checked to use only the supported subset."""
    schema = json.loads(SCHEMA_FILE.read_text(encoding="utf-8"))
    check_subset(schema)
    return schema


def check_subset(schema: dict, where: str = "") -> None:
    """SchemaError if ``schema`` (or a schema inside it) uses a keyword this module does not implement."""
    if not isinstance(schema, dict):
        raise SchemaError(f"{where or '<root>'}: a schema must be an object")
    unknown = set(schema) - KEYWORDS - ANNOTATIONS
    if unknown:
        raise SchemaError(f"{where or '<root>'}: unsupported keyword(s) {', '.join(sorted(unknown))}")
    for name, sub in schema.get("properties", {}).items():
        check_subset(sub, f"{where}.{name}")
    for key in ("items", "additionalProperties"):
        if isinstance(schema.get(key), dict):
            check_subset(schema[key], f"{where}[{key}]")


def _is_type(value, name: str) -> bool:
    if name == "null":
        return value is None
    if name == "boolean":
        return isinstance(value, bool)
    if name == "object":
        return isinstance(value, dict)
    if name == "array":
        return isinstance(value, list)
    if name == "string":
        return isinstance(value, str)
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return False
    if name == "number":
        return True
    if name == "integer":
        return isinstance(value, int) or (math.isfinite(value) and value == int(value))
    raise SchemaError(f"unknown type {name!r}")


def _equal(a, b) -> bool:
    """JSON equality: 1 == 1.0, but true is not 1."""
    if isinstance(a, bool) or isinstance(b, bool):
        return isinstance(a, bool) and isinstance(b, bool) and a == b
    if isinstance(a, (int, float)) and isinstance(b, (int, float)):
        return a == b
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(_equal(x, y) for x, y in zip(a, b))
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(_equal(a[k], b[k]) for k in a)
    return type(a) is type(b) and a == b


def _short(value) -> str:
    text = json.dumps(value) if not isinstance(value, (dict, list)) else type(value).__name__
    return text if len(text) <= 60 else text[:57] + "..."


def errors(value, schema: dict, where: str = "") -> list[str]:
    """Every way ``value`` breaks ``schema``, one line each ("<path>: <problem>"); [] if it is valid."""
    here = where or "<card>"
    if "type" in schema:
        names = schema["type"] if isinstance(schema["type"], list) else [schema["type"]]
        if not any(_is_type(value, n) for n in names):
            return [f"{here}: must be of type {' or '.join(names)} (got {_short(value)})"]
    out = []
    if "const" in schema and not _equal(value, schema["const"]):
        out.append(f"{here}: must be {_short(schema['const'])} (got {_short(value)})")
    if "enum" in schema and not any(_equal(value, v) for v in schema["enum"]):
        out.append(f"{here}: must be one of {', '.join(_short(v) for v in schema['enum'])} (got {_short(value)})")
    if "pattern" in schema and isinstance(value, str) and not re.search(schema["pattern"], value):
        out.append(f"{here}: must match {schema['pattern']} (got {_short(value)})")
    if "minimum" in schema and _is_type(value, "number") and not value >= schema["minimum"]:
        out.append(f"{here}: must be >= {schema['minimum']} (got {_short(value)})")
    if "maximum" in schema and _is_type(value, "number") and not value <= schema["maximum"]:
        out.append(f"{here}: must be <= {schema['maximum']} (got {_short(value)})")
    if isinstance(value, list):
        if "minItems" in schema and len(value) < schema["minItems"]:
            out.append(f"{here}: must have at least {schema['minItems']} items (got {len(value)})")
        if "maxItems" in schema and len(value) > schema["maxItems"]:
            out.append(f"{here}: must have at most {schema['maxItems']} items (got {len(value)})")
        if isinstance(schema.get("items"), dict):
            for i, item in enumerate(value):
                out += errors(item, schema["items"], f"{where}[{i}]")
    if isinstance(value, dict):
        for key in schema.get("required", ()):
            if key not in value:
                out.append(f"{here}: misses {key!r}")
        props = schema.get("properties", {})
        extra = schema.get("additionalProperties", True)
        for key, item in value.items():
            sub = f"{where}.{key}" if where else str(key)
            if key in props:
                out += errors(item, props[key], sub)
            elif extra is False:
                out.append(f"{here}: has no field {key!r}")
            elif isinstance(extra, dict):
                out += errors(item, extra, sub)
    return out


def card_errors(card) -> list[str]:
    """Every way ``card`` breaks the shipped card schema (CARD_SCHEMA, pbdyn-card/2: a card of another schema
    version fails at its "schema" field), plus any non-finite number (cards are strict JSON)."""
    from pbdyn.errors import non_finite_path

    out = errors(card, card_schema())
    bad = non_finite_path(card)
    if bad is not None:
        out.append(f"{bad.lstrip('.') or '<card>'}: must be a finite number (cards are strict JSON)")
    return out
