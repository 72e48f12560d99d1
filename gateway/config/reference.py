"""The configuration reference, read from the models themselves: every key of the file by its
path, with its type and allowed values, default, unit and description.

The description is the docstring under the field (pydantic's `use_attribute_docstrings`, set on
`Section`); a key without one is reported by `undocumented`, naming the key and the line of the
model that lacks it. The documentation site's Configuration page is generated from `markdown`
at build time (docs/hooks.py), so it can't drift from what the gateway accepts.
"""

from __future__ import annotations

import ast
import inspect
import re
import textwrap
import types
import typing
from collections.abc import Iterator
from dataclasses import dataclass
from enum import Enum
from functools import cache
from pathlib import Path

import annotated_types
from pydantic import BaseModel
from pydantic.fields import FieldInfo

from gateway.config.schema import GatewayConfig
from gateway.config.sections.values import RegisterRange

UNIT_SUFFIXES = (
    ("_ms", "ms"),
    ("_s", "s"),
    ("_mb", "MB"),
    ("_days", "days"),
    ("_percent", "%"),
)
"""A key's unit is in its name (`timeout_ms`); a field may name another in
`json_schema_extra={"unit": ...}` (`baudrate`: bit/s)."""


@dataclass(frozen=True, slots=True)
class ConfigKey:
    path: str
    """Where the key sits in the file: `buses[].rs485.mode` (`[]` an item of a list, `.*` a
    value of a mapping whose keys the user names)."""
    model: type[BaseModel]
    name: str
    field: FieldInfo

    @property
    def key(self) -> str:
        return self.field.alias or self.name

    @property
    def description(self) -> str:
        return " ".join((self.field.description or "").split())

    @property
    def where(self) -> str:
        """The model's field this key is: `BusConfig.retries
        (gateway/config/sections/buses.py:50)`."""
        file, line = _field_line(self.model, self.name)
        return f"{self.model.__name__}.{self.name} ({file}:{line})"

    @property
    def unit(self) -> str:
        extra = self.field.json_schema_extra
        if isinstance(extra, dict) and isinstance(extra.get("unit"), str):
            return str(extra["unit"])
        for suffix, unit in UNIT_SUFFIXES:
            if self.key.endswith(suffix):
                return unit
        return ""

    @property
    def type_text(self) -> str:
        text = _type_text(self.field.annotation)
        limits = _limits(self.field.metadata)
        return f"{text}, {limits}" if limits else text

    @property
    def default_text(self) -> str:
        if self.field.is_required():
            return "required"
        if self.field.default_factory is not None:
            value = self.field.default_factory()  # type: ignore[call-arg]
        else:
            value = self.field.default
        if isinstance(value, BaseModel):
            return "its keys' defaults"
        return f"`{_yaml_value(value)}`"

    @property
    def section(self) -> type[BaseModel] | None:
        """The model whose keys hang below this one, if any."""
        found = [model for model, _ in models_in(self.field.annotation)]
        return found[0] if found else None


def models_in(annotation: object) -> Iterator[tuple[type[BaseModel], str]]:
    """The models a field's type holds, each with how its keys hang below the field's: `[]` for
    an item of a list, `.*` for a value of a mapping whose keys the user names."""
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        yield annotation, ""
        return
    origin = typing.get_origin(annotation)
    arguments = typing.get_args(annotation)
    if origin in (tuple, list):
        for argument in arguments:
            if argument is not Ellipsis:
                for model, suffix in models_in(argument):
                    yield model, "[]" + suffix
    elif origin is dict:
        for model, suffix in models_in(arguments[1]):
            yield model, ".*" + suffix
    elif origin in (typing.Union, types.UnionType, typing.Annotated):
        for argument in arguments:
            yield from models_in(argument)


def config_keys(model: type[BaseModel] = GatewayConfig, prefix: str = "") -> Iterator[ConfigKey]:
    """Every key of the configuration file, a section's before the keys below it."""
    for name, field in model.model_fields.items():
        key = ConfigKey("", model, name, field)
        path = f"{prefix}.{key.key}" if prefix else key.key
        yield ConfigKey(path, model, name, field)
        for inner, suffix in models_in(field.annotation):
            yield from config_keys(inner, path + suffix)


def undocumented(model: type[BaseModel] = GatewayConfig) -> list[str]:
    """A line per key without a description: the key's path, and the field to give one to."""
    return [
        f"{key.path}: no description; write a docstring under {key.where}"
        for key in config_keys(model)
        if not key.description
    ]


def markdown(model: type[BaseModel] = GatewayConfig, heading: str = "###") -> str:
    """A table per section of the file (the top level, `modbus_tcp`, `buses[]` ...), each
    headed by its path and introduced by the section model's docstring."""
    tables: dict[str, tuple[type[BaseModel], list[ConfigKey]]] = {"": (model, [])}
    for key in config_keys(model):
        parent = key.path.rpartition(".")[0]  # `buses[].rs485.mode` goes in `buses[].rs485`
        tables.setdefault(parent, (key.model, []))[1].append(key)
    out = []
    for path, (section, keys) in tables.items():
        out.append(f"{heading} {f'`{path}`' if path else 'Top level'}\n")
        intro = " ".join((section.__doc__ or "").split())
        if path and intro:
            out.append(f"{intro}\n")
        out.append("| key | type | default | unit | description |")
        out.append("|---|---|---|---|---|")
        for key in keys:
            name = f"`{key.key}`"
            below = [key.path + suffix for _, suffix in models_in(key.field.annotation)]
            if below and below[0] in tables:
                name += f" ([keys]({anchor(below[0])}))"
            out.append(
                f"| {name} | {_cell(key.type_text)} | {_cell(key.default_text)} "
                f"| {key.unit} | {_cell(key.description)} |"
            )
        out.append("")
    return "\n".join(out)


def anchor(path: str) -> str:
    """The id MkDocs's toc gives the heading `` `path` ``: symbols dropped, lower case."""
    slug = re.sub(r"[^\w\s-]", "", path).strip().lower()
    return "#" + re.sub(r"[-\s]+", "-", slug)


def _cell(text: str) -> str:
    return text.replace("|", "\\|")


def _type_text(annotation: object) -> str:
    origin = typing.get_origin(annotation)
    arguments = typing.get_args(annotation)
    if origin in (typing.Union, types.UnionType):
        options = [_type_text(a) for a in arguments if a is not type(None)]
        text = " or ".join(options)
        return f"{text} or `null`" if type(None) in arguments else text
    if origin is typing.Annotated:
        limits = _limits([m for a in arguments[1:] for m in _metadata(a)])
        inner = _type_text(arguments[0])
        return f"{inner} {limits}" if limits else inner
    if origin is typing.Literal:
        return " or ".join(f"`{_yaml_value(a)}`" for a in arguments)
    if origin in (tuple, list):
        return f"list of {_type_text(arguments[0])}"
    if origin is dict:
        return f"map of {_type_text(arguments[0])} → {_type_text(arguments[1])}"
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return "section"
    if isinstance(annotation, type) and issubclass(annotation, Enum):
        return " or ".join(f"`{member.value}`" for member in annotation)
    names = {
        bool: "boolean",
        int: "integer",
        float: "number",
        str: "text",
        RegisterRange: "register or range",
    }
    if isinstance(annotation, type) and annotation in names:
        return names[annotation]
    return str(annotation)


def _metadata(item: object) -> list[object]:
    return list(item.metadata) if isinstance(item, FieldInfo) else [item]


def _limits(metadata: list[object]) -> str:
    low = high = ""
    parts = []
    for item in metadata:
        if isinstance(item, annotated_types.Ge):
            low = f"{_number(item.ge)}"
        elif isinstance(item, annotated_types.Gt):
            low = f"above {_number(item.gt)}"
        elif isinstance(item, annotated_types.Le):
            high = f"{_number(item.le)}"
        elif isinstance(item, annotated_types.Lt):
            high = f"below {_number(item.lt)}"
        elif isinstance(item, annotated_types.MinLen) and item.min_length > 1:
            parts.append(f"at least {item.min_length} characters")
        elif isinstance(item, annotated_types.MaxLen):
            parts.append(f"at most {item.max_length} characters")
        elif getattr(item, "pattern", None):
            parts.append(f"matching `{item.pattern}`")  # type: ignore[attr-defined]
        elif isinstance(item, annotated_types.MinLen):
            parts.append("not empty")
    if low and high:
        bounds = f"{low}..{high}" if not low.startswith("above") else f"{low}, at most {high}"
        parts.insert(0, bounds.replace("..below ", ", below "))
    elif low:
        parts.insert(0, low if low.startswith("above") else f"at least {low}")
    elif high:
        parts.insert(0, high if high.startswith("below") else f"at most {high}")
    return ", ".join(parts)


def _number(value: object) -> str:
    if isinstance(value, float) and value.is_integer():
        return str(int(value))
    return str(value)


def _yaml_value(value: object) -> str:
    if isinstance(value, Enum):
        return _yaml_value(value.value)
    if value == "":
        return '""'
    if value is None:
        return "null"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return _number(value)
    if isinstance(value, tuple | list):
        return "[" + ", ".join(_yaml_value(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{k}: {_yaml_value(v)}" for k, v in value.items()) + "}"
    return str(value)


@cache
def _field_line(model: type[BaseModel], name: str) -> tuple[str, int]:
    """The file and line where `model` (or the base it inherits the field from) declares
    `name`, for a message that sends the reader straight there."""
    for cls in model.__mro__:
        if not (isinstance(cls, type) and issubclass(cls, BaseModel)):
            continue
        try:
            lines, first = inspect.getsourcelines(cls)
            file = inspect.getsourcefile(cls) or "?"
        except (OSError, TypeError):
            continue
        tree = ast.parse(textwrap.dedent("".join(lines)))
        for node in ast.walk(tree):
            if (
                isinstance(node, ast.AnnAssign)
                and isinstance(node.target, ast.Name)
                and node.target.id == name
            ):
                return _shown(file), first + node.lineno - 1
    return "?", 0


def _shown(file: str) -> str:
    """A path from the repository's top when the package is run from a checkout."""
    path = Path(file).resolve()
    top = Path(__file__).resolve().parents[2]
    return str(path.relative_to(top)) if path.is_relative_to(top) else str(path)


__all__ = ["ConfigKey", "anchor", "config_keys", "markdown", "models_in", "undocumented"]
