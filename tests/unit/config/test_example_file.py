"""config/config.example.yaml: valid, and a full example, documenting every key the gateway reads.

A key added to the configuration without a line in the example fails here, so the file installed
as /etc/invt-gateway/config.yaml never falls behind what the gateway accepts.
"""

from __future__ import annotations

import types
import typing
from pathlib import Path
from typing import Any

import yaml
from pydantic import BaseModel

from gateway.config import GatewayConfig, load_config

EXAMPLE = Path(__file__).resolve().parents[3] / "config" / "config.example.yaml"


def key_paths(model: type[BaseModel], prefix: str = "") -> set[str]:
    """Every key a configuration may hold: "modbus_tcp.port", "drives[].poll[].interval_ms"."""
    paths: set[str] = set()
    for name, field in model.model_fields.items():
        path = f"{prefix}{name}"
        paths.add(path)
        nested, is_list = _section_of(field.annotation)
        if nested is not None:
            paths |= key_paths(nested, f"{path}[]." if is_list else f"{path}.")
    return paths


def _section_of(annotation: Any) -> tuple[type[BaseModel] | None, bool]:
    """The model inside `X`, `X | None`, `tuple[X, ...]` or `tuple[X, ...] | None`."""
    origin = typing.get_origin(annotation)
    if origin in (typing.Union, types.UnionType):
        for argument in typing.get_args(annotation):
            found = _section_of(argument)
            if found[0] is not None:
                return found
        return None, False
    if origin is tuple:
        inner, _ = _section_of(typing.get_args(annotation)[0])
        return inner, True
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return annotation, False
    return None, False


def present(data: Any, prefix: str = "") -> set[str]:
    """The key paths a YAML document uses, list items merged."""
    paths: set[str] = set()
    if isinstance(data, dict):
        for key, value in data.items():
            path = f"{prefix}{key}"
            paths.add(path)
            if isinstance(value, dict):
                paths |= present(value, f"{path}.")
            elif isinstance(value, list):
                for item in value:
                    paths |= present(item, f"{path}[].")
    return paths


def test_example_is_a_valid_configuration() -> None:
    config = load_config(EXAMPLE)
    assert len(config.buses) == 2, "the example shows several lines on one gateway"
    assert config.metrics.enabled
    assert config.mqtt is not None


def test_example_shows_every_key() -> None:
    document = yaml.safe_load(EXAMPLE.read_text(encoding="utf-8"))
    missing = sorted(key_paths(GatewayConfig) - present(document))
    assert not missing, f"config.example.yaml lacks: {', '.join(missing)}"
