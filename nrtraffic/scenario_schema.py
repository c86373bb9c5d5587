"""The scenario file format as a JSON Schema, generated from the dataclasses that declare it.

The sections of :mod:`nrtraffic.scenario` are the one declaration of the format: their fields give
the keys, types and defaults; their ``CHOICES`` the values a string key takes; the comment on a
field's line (or the ``Attributes`` entry of the class docstring) its description. From them come
the JSON Schema (``nrtraffic schema``, committed as ``docs/scenario.schema.json``, which TOML editors
use to check and complete scenario files) and the key reference ``docs/scenario_keys.md``.
The range of every numeric key (``scenario.RANGES``) is the schema's ``minimum`` and ``maximum``
(``exclusiveMinimum`` / ``exclusiveMaximum`` at a bound the key may not take, ``scenario.OPEN``);
further checks stay in the sections' ``validate`` methods, whose messages name the key.
"""

from __future__ import annotations

import dataclasses
import inspect
import json
import re
import typing

from nrtraffic import scenario as S
from nrtraffic.vehicle.params import PRESETS, BicycleParams

SCHEMA_ID = "https://nrtraffic.invalid/scenario.schema.json"
_COMMENT = re.compile(r"^\s+(\w+)\s*:[^#=]*=[^#]*#\s*(.+?)\s*$")
_ATTR = re.compile(r"^\s{4}(\w+(?:\s*,\s*\w+)*)\s*:\s*(.*)$")


def _field_docs(cls) -> dict[str, str]:
    """Description of each field: the comment on its line, else its ``Attributes`` entry."""
    docs: dict[str, str] = {}
    doc = inspect.getdoc(cls) or ""
    if "Attributes" in doc:
        lines = doc.split("Attributes", 1)[1].splitlines()[2:]
        names, text = [], []
        for line in lines + ["end : "]:
            m = _ATTR.match("    " + line) if line and not line.startswith(" ") else None
            if m:
                for n in names:
                    docs[n] = " ".join(text).strip()
                names = [n.strip() for n in m.group(1).split(",")]
                first = m.group(2).strip()
                text = [] if first in ("float", "int", "str", "bool") else [first]  # numpydoc "name : type"
            elif names:
                text.append(line.strip())
    try:
        src = inspect.getsource(cls)
    except (OSError, TypeError):
        src = ""
    for line in src.splitlines():
        m = _COMMENT.match(line)
        if m:
            docs[m.group(1)] = m.group(2)
    return docs


def _json_type(hint) -> dict:
    origin = typing.get_origin(hint)
    if hint is bool:
        return {"type": "boolean"}
    if hint is int:
        return {"type": "integer"}
    if hint is float:
        return {"type": "number"}
    if hint is str:
        return {"type": "string"}
    if origin is tuple:
        args = typing.get_args(hint)
        if args and dataclasses.is_dataclass(args[0]):
            return {"type": "array", "items": _table(args[0], name=_NESTED.get(args[0]))}
        return {"type": "array", "items": {"type": "string"}} if args and args[0] is str else {"type": "array"}
    if hint is tuple:
        return {"type": "array"}
    return {}


_NESTED = {S.DemandFlow: "demand.flows", S.DemandInterval: "demand.intervals"}


def _table(cls, skip=(), name: str | None = None) -> dict:
    hints = typing.get_type_hints(cls)
    ranges = S.RANGES.get(name, {})
    docs = _field_docs(cls)
    choices = getattr(cls, "CHOICES", {})
    props = {}
    for f in dataclasses.fields(cls):
        if f.name in skip:
            continue
        prop = _json_type(hints[f.name])
        if f.default is not dataclasses.MISSING and f.default != ():
            prop["default"] = f.default
        if f.name in choices:
            prop["enum"] = list(choices[f.name])
        if f.name in ranges:
            lo, hi = ranges[f.name]
            side = S.OPEN.get(f"{name}.{f.name}")
            prop["exclusiveMinimum" if side == "min" else "minimum"] = lo
            prop["exclusiveMaximum" if side == "max" else "maximum"] = hi
        if docs.get(f.name):
            prop["description"] = docs[f.name]
        props[f.name] = prop
    return {"type": "object", "description": (inspect.getdoc(cls) or "").split("\n\n")[0],
            "properties": props, "additionalProperties": False}


def json_schema() -> dict:
    """The JSON Schema (draft 2020-12) of a scenario file."""
    sections = {}
    for name, cls in S._SECTIONS.items():
        if cls is S.Vehicle:
            params = _table(BicycleParams)
            params["properties"] = {"preset": {"type": "string", "enum": sorted(PRESETS), "default": "paper",
                                               "description": "named parameter set (vehicle/params.py)"},
                                   **params["properties"]}
            for p in params["properties"].values():
                p.pop("default", None)  # the preset's value
            params["description"] = "a parameter preset and overrides of its fields"
            sections[name] = params
        else:
            sections[name] = _table(cls, name=name)
    sections["approaches"] = {"type": "array", "items": _table(S.Approach, name="approaches")}
    sections["vehicles"] = {"type": "array", "items": _table(S.ListedVehicle, name="vehicles")}
    sections["junctions"] = {"type": "array", "items": _table(S.JunctionSpec, name="junctions")}
    return {
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "$id": SCHEMA_ID,
        "title": "nrtraffic scenario file (scenario.toml)",
        "type": "object",
        "properties": sections,
        "required": ["scenario"],
        "additionalProperties": False,
    }


def schema_text() -> str:
    return json.dumps(json_schema(), indent=1, default=str) + "\n"


def _range(section: str, key: str) -> str:
    """A key's range as :func:`nrtraffic.scenario.range_text` gives it ("" where it has none)."""
    return S.range_text(section, key) if key in S.RANGES.get(section, {}) else ""


def markdown_reference() -> str:
    """Every section and key of the format, with its type, default and meaning."""
    schema = json_schema()
    out = ["# Scenario file keys", "",
           "Generated by `nrtraffic schema --markdown` from the dataclasses of `nrtraffic/scenario.py` (the same "
           "source as [scenario.schema.json](scenario.schema.json)); do not edit by hand.", ""]
    for name, sec in schema["properties"].items():
        array = sec.get("type") == "array"
        table = sec["items"] if array else sec
        out += [f"## `[[{name}]]`" if array else f"## `[{name}]`", "", table.get("description", ""), "",
                "| key | type | default | range | meaning |", "|---|---|---|---|---|"]
        for key, p in table["properties"].items():
            typ = p.get("type", "")
            if "enum" in p:
                typ = " \\| ".join(f'"{v}"' for v in p["enum"])
            default = json.dumps(p["default"], default=str) if "default" in p else ""
            if typ == "array" and "properties" in p.get("items", {}):
                typ = f"array of tables (`[[{name}.{key}]]`, below)"
            out.append(f"| `{key}` | {typ} | {default} | {_range(name, key)} | {p.get('description', '').replace('|', '/')} |")
        out.append("")
        for key, p in table["properties"].items():
            sub = p.get("items", {})
            if p.get("type") == "array" and "properties" in sub:
                out += [f"### `[[{name}.{key}]]`", "", sub.get("description", ""), "",
                        "| key | type | default | range | meaning |", "|---|---|---|---|---|"]
                for k, q in sub["properties"].items():
                    default = json.dumps(q["default"], default=str) if "default" in q else ""
                    out.append(f"| `{k}` | {q.get('type', '')} | {default} | {_range(f'{name}.{key}', k)} | "
                               f"{q.get('description', '').replace('|', '/')} |")
                out.append("")
    return "\n".join(out)
