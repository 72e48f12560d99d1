"""The documentation site says what the code does: every public name in it, and a site that builds.

Public names are interfaces a plant relies on (configuration keys, commands and their options,
MQTT topics, event types, metric families), so each one the code has must be documented on the
page a user looks it up on, read from the code itself, not from a list kept beside it:

- every configuration key of the models (`gateway/config/`), by its full path, shown in a YAML
  example on some page (an example is what a user copies; the key's comment says what it does),
  and every key of a device file (`gateway/profile/device_files.py`) in the device-file example;
- every command of `invt-gateway` and every option of it, in its section of the Commands page;
- every MQTT topic the `Topics` class makes, and every `bridge/request/<op>`, on the MQTT page;
- every event type (`EventType`) on the Events page;
- every environment variable the package reads (`INVT_GATEWAY_*`, `INVT_BENCH_*`);
- every metric family `/metrics` publishes (`tests/fixtures/metric_families.tsv`, which
  `test_ops_metric_names` holds against a real scrape), in the Operations page's metrics table,
  with each of its labels in its row.

And the site builds with `mkdocs build --strict` (a broken link or anchor fails it), loading no
script, style or font from the internet (a plant network has none). The README's test command is
the one CI runs.
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import re
import shutil
import subprocess
import sys
import types
import typing
from collections.abc import Iterator
from pathlib import Path

import pytest
import yaml
from pydantic import BaseModel

from gateway.cli import build_parser
from gateway.config import GatewayConfig
from gateway.mqtt.kinds import BRIDGE_REQUESTS
from gateway.mqtt.topics import Topics
from gateway.profile.device_files import _DeviceSpec, device_profile
from gateway.store.records import EventType

ROOT = Path(__file__).resolve().parent.parent
DOCS = ROOT / "docs"
PAGES = DOCS / "pages"
METRIC_FAMILIES = Path(__file__).parent / "fixtures" / "metric_families.tsv"
BUILD_TIMEOUT_S = 60


def page(name: str) -> str:
    return (PAGES / name).read_text(encoding="utf-8")


def all_pages() -> dict[str, str]:
    return {path.name: path.read_text(encoding="utf-8") for path in sorted(PAGES.glob("*.md"))}


# --- configuration keys ---------------------------------------------------------------------


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


def config_keys(model: type[BaseModel], prefix: str = "") -> Iterator[str]:
    """Every key of the configuration file, by its path: `buses[].rs485.mode`."""
    for name, field in model.model_fields.items():
        key = field.alias or name
        path = f"{prefix}.{key}" if prefix else key
        yield path
        for inner, suffix in models_in(field.annotation):
            yield from config_keys(inner, path + suffix)


def keys_shown(model: type[BaseModel], value: object, prefix: str = "") -> Iterator[str]:
    """The key paths a YAML example shows, walked beside the models: a key the model lacks (a
    typo in the docs) is not counted."""
    if not isinstance(value, dict):
        return
    for key, inner_value in value.items():
        field = model.model_fields.get(str(key))
        if field is None:
            continue
        path = f"{prefix}.{key}" if prefix else str(key)
        yield path
        for inner, suffix in models_in(field.annotation):
            if suffix.startswith("[]") and isinstance(inner_value, list):
                for item in inner_value:
                    yield from keys_shown(inner, item, path + "[]")
            elif suffix.startswith(".*") and isinstance(inner_value, dict):
                for item in inner_value.values():
                    yield from keys_shown(inner, item, path + ".*")
            elif suffix == "":
                yield from keys_shown(inner, inner_value, path)


def yaml_examples(text: str) -> Iterator[object]:
    for block in re.findall(r"```yaml\n(.*?)```", text, re.DOTALL):
        yield yaml.safe_load(block)


def test_every_configuration_key_is_shown_in_an_example() -> None:
    shown: set[str] = set()
    for text in all_pages().values():
        for example in yaml_examples(text):
            shown |= set(keys_shown(GatewayConfig, example))
    keys = list(config_keys(GatewayConfig))
    assert len(keys) > 100  # the walk found the models' keys, nested ones included
    missing = [key for key in keys if key not in shown]
    assert not missing, f"configuration keys in no YAML example of docs/pages/: {missing}"


def test_the_reference_example_is_a_valid_configuration() -> None:
    """The Configuration reference's full example loads as it is written (every key with its
    default or an example value): a user may copy it."""
    example = next(yaml_examples(page("configuration.md")))
    assert isinstance(example, dict)
    assert set(example) == set(GatewayConfig.model_fields), "the first example shows every section"
    config = GatewayConfig.model_validate(example)
    assert config.buses[0].baudrate == 19200


def test_every_device_file_key_is_in_the_example_and_it_loads() -> None:
    """A device file (a meter's, an I/O module's) is configuration too: its example on the Other
    Modbus devices page shows every key of the device-file model and loads as a device."""
    text = page("devices.md").split("```yaml\n", 1)[1].split("```", 1)[0]
    device = device_profile("file:boiler-meter.yaml", text, "docs/pages/devices.md")
    example = yaml.safe_load(text)
    assert [point.name for point in device.typed_points] == list(example["points"])
    shown = set(keys_shown(_DeviceSpec, example))
    missing = [key for key in config_keys(_DeviceSpec) if key not in shown]
    assert not missing, f"device-file keys not in the example of docs/pages/devices.md: {missing}"


# --- commands and options -------------------------------------------------------------------


def commands(
    parser: argparse.ArgumentParser, path: tuple[str, ...] = ()
) -> Iterator[tuple[tuple[str, ...], list[str]]]:
    """Each command's path (`("params", "restore")`) and its long options."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                options = [
                    option
                    for sub_action in sub._actions
                    for option in sub_action.option_strings
                    if option.startswith("--") and option != "--help"
                ]
                yield (*path, name), options
                yield from commands(sub, (*path, name))


FIELD_TOOLS = ("scan", "read", "write", "params")
"""Their line options are documented once, in the Commands page's "Field tools" section."""


def sections(text: str) -> dict[str, str]:
    """A page's sections by their heading, each up to the next heading of any level."""
    parts = re.split(r"^(#{1,6} .*)$", text, flags=re.MULTILINE)
    return {parts[i].lstrip("#").strip(): parts[i + 1] for i in range(1, len(parts), 2)}


def test_every_command_and_option_is_in_its_section_of_the_commands_page() -> None:
    by_heading = sections(page("commands.md"))
    shared = by_heading["Field tools"]  # the line options the field tools share
    found = list(commands(build_parser()))
    assert len(found) >= 15
    missing = []
    for path, options in found:
        heading = f"invt-gateway {path[0]}"  # `params backup` is documented under `params`
        if heading not in by_heading:
            missing.append(heading)
            continue
        text = by_heading[heading] + (shared if path[0] in FIELD_TOOLS else "")
        missing += [
            f"{' '.join(path)} {option}"
            for option in options
            if not re.search(rf"`[^`]*(?<![\w-]){re.escape(option)}(?![\w-])[^`]*`", text)
        ]
    assert not missing, f"not in their section of docs/pages/commands.md: {missing}"


def test_the_version_option_is_documented() -> None:
    assert "`invt-gateway --version`" in page("commands.md")


# --- MQTT topics and events -------------------------------------------------------------------


def test_every_mqtt_topic_is_in_the_topic_reference() -> None:
    topics = Topics("<base>")
    made = [
        topics.bridge_state,
        topics.bridge_info,
        topics.bridge_event,
        topics.drive_state("<drive>"),
        topics.availability("<drive>"),
        topics.set("<drive>"),
        topics.set_response("<drive>"),
        topics.get("<drive>"),
        topics.bridge_response("<op>"),
        *(topics.bridge_request(request.operation) for request in BRIDGE_REQUESTS),
    ]
    # Every Topics method is called above: a topic added there fails here until it is listed.
    methods = {
        name
        for name, value in vars(Topics).items()
        if not name.startswith("_") and (callable(value) or isinstance(value, property))
    } - {"drive_of", "base"}
    assert methods == {
        "bridge_state",
        "bridge_info",
        "bridge_event",
        "bridge_request",
        "bridge_response",
        "drive_state",
        "availability",
        "set",
        "set_response",
        "get",
    }, "a new topic in Topics: document it and list it here"
    text = page("mqtt.md")
    missing = [topic for topic in made if f"`{topic}`" not in text]
    assert not missing, f"MQTT topics not in docs/pages/mqtt.md: {missing}"


def test_every_event_type_is_in_the_events_page() -> None:
    text = page("events.md")
    missing = [kind.value for kind in EventType if f"`{kind.value}`" not in text]
    assert not missing, f"event types not in docs/pages/events.md: {missing}"


# --- environment variables ---------------------------------------------------------------


def test_every_environment_variable_the_code_names_is_documented() -> None:
    """The variables are named as constants in the code (`ENV_MQTT_PASSWORD = "INVT_..."`):
    every `INVT_GATEWAY_*` and `INVT_BENCH_*` string in the package is one."""
    source = "".join(path.read_text(encoding="utf-8") for path in (ROOT / "gateway").rglob("*.py"))
    variables = set(re.findall(r"[\"'](INVT_(?:GATEWAY|BENCH)_[A-Z_]+)[\"']", source))
    assert {"INVT_GATEWAY_MQTT_PASSWORD", "INVT_GATEWAY_EVENT_LOOP"} <= variables
    documented = "".join(all_pages().values())
    missing = sorted(variable for variable in variables if f"`{variable}" not in documented)
    assert not missing, f"environment variables in no page of docs/pages/: {missing}"


# --- metrics ----------------------------------------------------------------------------------


def metric_families() -> dict[str, list[str]]:
    """Family name (without `_total`, as the scrape names it) → its labels; the `_created`
    gauges prometheus-client adds beside counters are not families of ours."""
    families = {}
    for line in METRIC_FAMILIES.read_text(encoding="utf-8").splitlines():
        if not line or line.startswith("#"):
            continue
        name, _kind, labels, _help = line.split("\t", 3)
        if not name.endswith("_created"):
            families[name] = [label for label in labels.split(",") if label]
    return families


def test_every_metric_family_and_its_labels_are_in_the_metrics_table() -> None:
    table = sections(page("operations.md"))["Metrics and health"]
    rows = [line for line in table.splitlines() if line.startswith("| `")]
    families = metric_families()
    assert len(families) > 70
    missing = []
    for name, labels in families.items():
        # A counter is named with `_total` as Prometheus shows it; the scrape's family drops it.
        row = next((r for r in rows if re.search(rf"`{re.escape(name)}(_total)?[`{{]", r)), None)
        if row is None:
            missing.append(name)
            continue
        missing += [f"{name} label {label}" for label in labels if label not in row]
    assert not missing, f"not in the metrics table of docs/pages/operations.md: {missing}"


# --- the README -------------------------------------------------------------------------------


def shell_block(text: str, after: str) -> list[str]:
    block = re.search(r"```sh\n(.*?)```", text.split(after, 1)[1], re.DOTALL)
    assert block is not None, f"no ```sh block after {after!r}"
    return block.group(1).strip().splitlines()


def test_the_readme_is_short_and_its_test_command_is_what_ci_runs() -> None:
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    assert len(readme.splitlines()) < 300
    assert shell_block(readme, "## Quick start") == ["bash .ci/demo"]
    assert shell_block(readme, "## Run the tests") == ["bash .ci/test"]
    ci = (ROOT / ".ci" / "run").read_text(encoding="utf-8")
    assert re.search(r"^bash \.ci/test\b", ci, re.MULTILINE), ".ci/run no longer runs .ci/test"


def test_the_readmes_links_into_the_docs_lead_to_pages() -> None:
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    links = re.findall(r"\]\((docs/[^)#]+)(?:#[^)]*)?\)", readme)
    assert len(links) >= 10
    missing = [link for link in links if not (ROOT / link).is_file()]
    assert not missing, missing


# --- the site builds --------------------------------------------------------------------------


def mkdocs_build(config: Path, site: Path) -> subprocess.CompletedProcess[str]:
    if importlib.util.find_spec("mkdocs") is None or importlib.util.find_spec("material") is None:
        pytest.fail(
            "MkDocs or its Material theme is missing: pip install -e '.[docs]' (.ci/test does)"
        )
    return subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "-f", str(config), "-d", str(site)],
        capture_output=True,
        text=True,
        timeout=BUILD_TIMEOUT_S,
        check=False,
        env={**os.environ, "NO_MKDOCS_2_WARNING": "1"},
    )


def test_the_site_builds_strict_and_loads_nothing_from_the_internet(tmp_path: Path) -> None:
    site = tmp_path / "site"
    built = mkdocs_build(DOCS / "mkdocs.yml", site)
    assert built.returncode == 0, built.stderr
    pages = sorted(site.rglob("*.html"))
    assert len(pages) >= len(all_pages())
    external = []
    for html in pages:
        text = html.read_text(encoding="utf-8")
        for tag in re.findall(r"<(?:script|link|img|iframe)\b[^>]*>", text):
            # rel=canonical and the like name an address; only what the browser fetches counts.
            if re.search(r'\b(src|href)="(https?:)?//', tag) and "canonical" not in tag:
                external.append(f"{html.relative_to(site)}: {tag}")
    assert not external, external


def test_a_broken_link_fails_the_build(tmp_path: Path) -> None:
    """The build above would pass whatever --strict checks if it checked nothing: a link to a
    page that isn't there, and one to a heading that isn't, each fail it."""
    for broken in ("[gone](no-such-page.md)", "[gone](mqtt.md#no-such-heading)"):
        copy = tmp_path / broken.split("(")[1].split(".")[0].replace("#", "")
        shutil.copytree(DOCS, copy, ignore=shutil.ignore_patterns("site"))
        with (copy / "pages" / "index.md").open("a", encoding="utf-8") as index:
            index.write(f"\n{broken}\n")
        built = mkdocs_build(copy / "mkdocs.yml", copy / "site")
        assert built.returncode != 0, f"{broken} built"
        assert "no-such" in built.stderr
