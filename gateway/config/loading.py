"""Reading a file: YAML, the environment's secrets, validation, and every problem reported with
its line and key path (`line 14: drives[1] (fan3).unit_id: ...`), the checks across sections
included even when fields are invalid, so that one run of `check-config` says everything. An
unknown key names the nearest one the section has (`did you mean baudrate?`)."""

from __future__ import annotations

import os
import re
from pathlib import Path
from typing import Annotated, Any, Final, TypeVar, cast, get_args

import yaml
from pydantic import BaseModel, TypeAdapter, ValidationError

from gateway.config.cross_checks import cross_field_problems
from gateway.config.lines import key_lines
from gateway.config.schema import CONFIG_VERSIONS, GatewayConfig
from gateway.config.sections.buses import BusConfig
from gateway.config.sections.drives import DriveConfig
from gateway.config.sections.modbus_tcp import AccessRuleConfig
from gateway.config.sections.mqtt import ENV_MQTT_PASSWORD, ENV_MQTT_USERNAME
from gateway.config.sections.section import Section
from gateway.errors import ConfigError
from gateway.nearest import did_you_mean

S = TypeVar("S", bound=Section)


def load_config(path: str | Path) -> GatewayConfig:
    """Read and validate a YAML file; raise ConfigError listing every problem."""
    source = str(path)
    try:
        text = Path(path).read_text(encoding="utf-8")
    except OSError as exc:
        raise ConfigError([("", f"cannot read the file: {exc.strerror or exc}")], source) from exc
    return parse_config(text, source)


def parse_config(text: str, source: str = "<config>") -> GatewayConfig:
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise ConfigError([("", _yaml_problem(exc))], source) from None
    except RecursionError:  # thousands of nested [ or {: PyYAML recurses once per level
        raise ConfigError([("", "not valid YAML: nested too deeply")], source) from None
    if not isinstance(data, dict):
        raise ConfigError([("", "the file must be a YAML mapping (key: value)")], source)
    version = data.get("version")
    if version is not None and (isinstance(version, bool) or version not in CONFIG_VERSIONS):
        # Checked alone, first: every other complaint about a newer format would be noise.
        readable = ", ".join(map(str, CONFIG_VERSIONS))
        raise ConfigError(
            [("version", f"{version!r} is not a version this gateway reads (it reads {readable})")],
            source,
        )
    data = _apply_environment(data)
    try:
        return GatewayConfig.model_validate(data)
    except ValidationError as exc:
        problems = _problems(exc, data)
        problems += _cross_problems(exc, data, problems)
        raise ConfigError(problems, source, _lines(problems, text, data)) from None


def _yaml_problem(exc: yaml.YAMLError) -> str:
    """'line 12, column 5: not valid YAML: ...' (PyYAML's own text names "<unicode string>")."""
    if not isinstance(exc, yaml.MarkedYAMLError) or exc.problem_mark is None:
        return f"not valid YAML: {exc}"
    mark = exc.problem_mark
    reason = f"line {mark.line + 1}, column {mark.column + 1}: not valid YAML: {exc.problem}"
    if exc.context is not None and exc.context_mark is not None:
        start = exc.context_mark
        reason += f" ({exc.context} at line {start.line + 1}, column {start.column + 1})"
    return reason


def _apply_environment(data: dict[str, Any]) -> dict[str, Any]:
    """The broker's credentials from the environment win over the file's (systemd's
    EnvironmentFile, Docker's --env-file: kept out of a file others may read)."""
    if not isinstance(data.get("mqtt"), dict):
        return data
    mqtt = dict(data["mqtt"])
    for key, variable in (("username", ENV_MQTT_USERNAME), ("password", ENV_MQTT_PASSWORD)):
        value = os.environ.get(variable)
        if value is not None:
            mqtt[key] = value
    return {**data, "mqtt": mqtt}


def _problems(exc: ValidationError, data: dict[str, Any]) -> list[tuple[str, str]]:
    problems: list[tuple[str, str]] = []
    for error in exc.errors():
        path = _key_path(error["loc"], data)
        if error["type"] == "extra_forbidden":
            reason = "unknown key" + _nearest_key(error["loc"])
        elif error["type"] == "missing":
            reason = "required key is missing"
        else:
            reason = str(error["msg"]).removeprefix("Value error, ")
        if path == "" and "\n" in reason:  # cross-field checks carry their own paths
            problems.extend(("", line) for line in reason.splitlines())
        else:
            problems.append((path, reason))
    return problems


def _nearest_key(loc: tuple[int | str, ...]) -> str:
    """ "; did you mean baudrate?" for the unknown key at `loc`, from its section's keys."""
    section: type[BaseModel] | None = GatewayConfig
    for part in loc[:-1]:
        if section is None:
            return ""
        if isinstance(part, str):
            field = section.model_fields.get(part)
            section = None if field is None else _section_in(field.annotation)
    if section is None or not isinstance(loc[-1], str):
        return ""
    return did_you_mean(loc[-1], section.model_fields)


def _section_in(annotation: Any) -> type[BaseModel] | None:
    """The section a field holds: itself, or inside `list[...]`, `... | None`, `Annotated`."""
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return annotation
    for argument in get_args(annotation):
        found = _section_in(argument)
        if found is not None:
            return found
    return None


_LAST_STEP: Final = re.compile(r"(?:\.[^.\[]+|\[\d+\](?: \([^)]*\))?)$")
"""The last step of a key path: `.unit_id`, or `[1] (fan3)`."""


def _lines(problems: list[tuple[str, str]], text: str, data: Any) -> list[int | None]:
    """Each problem's line in the file: its key's, or (a missing key) its item's."""
    by_path = {_key_path(loc, data): line for loc, line in key_lines(text).items()}
    found: list[int | None] = []
    for path, reason in problems:
        # A cross-field problem carries its path in its reason: "drives[1] (fan3).bus: ...".
        where = path or reason.split(": ", 1)[0]
        while where and where not in by_path:
            shorter = _LAST_STEP.sub("", where)
            where = "" if shorter == where else shorter  # a top-level key: no line
        found.append(by_path.get(where))
    return found


def _key_path(loc: tuple[int | str, ...], data: Any) -> str:
    """('drives', 1, 'unit_id') -> 'drives[1] (fan3).unit_id': the index and the item's name."""
    path = ""
    node = data
    for part in loc:
        if isinstance(part, int):
            path += f"[{part}]"
            node = node[part] if isinstance(node, list) and part < len(node) else None
            if isinstance(node, dict) and isinstance(node.get("name"), str):
                path += f" ({node['name']})"
        else:
            path += f".{part}" if path else str(part)
            node = node.get(part) if isinstance(node, dict) else None
    return path


class _Unreadable(str):
    """A value the file doesn't give in a usable form, for the cross-field checks: shown as "?"
    (a string, so it joins and formats), equal only to itself (never a duplicate of anything),
    empty when iterated, sorted last."""

    __slots__ = ()
    __eq__ = object.__eq__
    __ne__ = object.__ne__
    __hash__ = object.__hash__

    def __new__(cls) -> _Unreadable:
        return super().__new__(cls, "?")

    def __iter__(self) -> Any:
        return iter(())

    def __bool__(self) -> bool:
        return False

    def __lt__(self, other: object) -> bool:
        return False

    def __gt__(self, other: object) -> bool:
        return not isinstance(other, _Unreadable)

    def __repr__(self) -> str:
        return "?"


def _cross_problems(
    exc: ValidationError, data: dict[str, Any], reported: list[tuple[str, str]]
) -> list[tuple[str, str]]:
    """The cross-field checks (duplicates, undefined buses...) on a file with invalid fields.

    pydantic runs the model validator only once every field is valid, so a duplicate unit id
    would show up only after the other mistakes were fixed. Here the same checks run on what the
    file says, each invalid or missing field taken as unreadable, so one run reports everything.
    A cross-field problem about a key already reported is left out.
    """
    failed = {tuple(error["loc"]) for error in exc.errors()}
    if failed == {()}:
        return []  # every field was valid: these checks ran in the model, and are reported
    modbus_tcp = data.get("modbus_tcp")
    problems = cross_field_problems(
        _construct_all(BusConfig, data.get("buses"), ("buses",), failed),
        _construct_all(DriveConfig, data.get("drives"), ("drives",), failed),
        _construct_all(
            AccessRuleConfig,
            modbus_tcp.get("access") if isinstance(modbus_tcp, dict) else None,
            ("modbus_tcp", "access"),
            failed,
        ),
    )
    paths = {path for path, _ in reported if path}
    if not isinstance(data.get("buses"), list):
        paths.add("buses")  # no bus to check a drive's `bus` against: that's the problem
    return [("", line) for line in problems if not _about(line.split(": ", 1)[0], paths)]


def _about(path: str, reported: set[str]) -> bool:
    """A cross-field problem at `path` follows from a problem already reported."""
    return path in reported or ("buses" in reported and path.endswith(".bus"))


def _construct_all(
    model: type[S], items: object, loc: tuple[str, ...], failed: set[tuple[Any, ...]]
) -> tuple[S, ...]:
    if not isinstance(items, list):
        return ()
    return tuple(_construct(model, item, (*loc, index), failed) for index, item in enumerate(items))


def _construct(
    model: type[S], item: object, loc: tuple[Any, ...], failed: set[tuple[Any, ...]]
) -> S:
    """One item with each valid field as the model reads it and each other one unreadable."""
    raw = item if isinstance(item, dict) else {}
    values: dict[str, Any] = {}
    for name, field in model.model_fields.items():
        where = (*loc, name)
        if any(f[: len(where)] == where for f in failed) or (
            name not in raw and field.is_required()
        ):
            values[name] = _Unreadable()  # the field, or something inside it, is invalid
        elif name in raw:
            # The field passed validation: read it the same way ("5" is 5, a list a tuple).
            field_type = cast("type[Any]", Annotated[field.annotation, field])
            adapter: TypeAdapter[Any] = TypeAdapter(field_type)
            try:
                values[name] = adapter.validate_python(raw[name])
            except ValidationError:
                values[name] = _Unreadable()
    return cast("S", model.model_construct(**values))  # pydantic types it as the base class
