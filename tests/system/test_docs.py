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
import re
import shutil
from collections.abc import Iterator
from pathlib import Path

import pytest
import yaml
from pydantic import BaseModel, ConfigDict

from gateway.cli import build_parser
from gateway.config import GatewayConfig, reference
from gateway.config.reference import models_in
from gateway.mqtt.kinds import BRIDGE_REQUESTS
from gateway.mqtt.topics import Topics
from gateway.profile.addressing import format_register
from gateway.profile.device_files import DEVICE_FILE, _DeviceSpec, device_profile
from gateway.profile.models import PROFILES
from gateway.profile.parameter_tables import sources, table_rows
from gateway.profile.registers import COMMUNICATION_REGISTERS
from gateway.store.records import EventType
from tests.support.site import DOCS, cell_text, mkdocs_build, table_rows_html

ROOT = Path(__file__).resolve().parents[2]
PAGES = DOCS / "pages"
METRIC_FAMILIES = Path(__file__).parents[1] / "fixtures" / "metric_families.tsv"


def page(name: str) -> str:
    return (PAGES / name).read_text(encoding="utf-8")


def all_pages() -> dict[str, str]:
    return {path.name: path.read_text(encoding="utf-8") for path in sorted(PAGES.glob("*.md"))}


# --- configuration keys ---------------------------------------------------------------------


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


@pytest.mark.parametrize("model", [GatewayConfig, DEVICE_FILE], ids=["config", "device-file"])
def test_every_configuration_key_has_a_description(model: type[BaseModel]) -> None:
    """The Configuration and Other Modbus devices pages' tables are generated from the models'
    field docstrings: a key without one would show an empty description. The message names
    each key and the line of the model to write it under."""
    keys = list(reference.config_keys(model))
    assert [key.path for key in keys] == list(config_keys(model))  # the same walk
    missing = reference.undocumented(model)
    assert not missing, "configuration keys without a description:\n" + "\n".join(missing)


class _Spindle(BaseModel):
    model_config = ConfigDict(use_attribute_docstrings=True)
    warmup_s: float = 2.0
    """How long it turns slowly after a start."""
    brake: bool = False


class _Machine(BaseModel):
    model_config = ConfigDict(use_attribute_docstrings=True)
    spindles: tuple[_Spindle, ...] = ()
    """The spindles."""


def test_a_key_without_a_description_is_named_with_the_line_to_fix() -> None:
    line = next(
        number
        for number, text in enumerate(Path(__file__).read_text().splitlines(), 1)
        if text.strip() == "brake: bool = False"
    )
    assert reference.undocumented(_Machine) == [
        f"spindles[].brake: no description; write a docstring under _Spindle.brake "
        f"(tests/system/test_docs.py:{line})"
    ]
    table = reference.markdown(_Machine)
    assert "| `warmup_s` | number | `2` | s | How long it turns slowly after a start. |" in table
    assert "### `spindles[]`" in table


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
        topics.history("<drive>"),
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
        "history",
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


@pytest.fixture(scope="module")
def site(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The site as `mkdocs build --strict` makes it, once for the tests that read it."""
    site = tmp_path_factory.mktemp("docs") / "site"
    built = mkdocs_build(DOCS / "mkdocs.yml", site)
    assert built.returncode == 0, built.stderr
    return site


def test_the_site_builds_strict_and_loads_nothing_from_the_internet(site: Path) -> None:
    pages = sorted(site.rglob("*.html"))
    assert len(pages) >= len(all_pages())
    external = []
    for built_page in pages:
        text = built_page.read_text(encoding="utf-8")
        for tag in re.findall(r"<(?:script|link|img|iframe)\b[^>]*>", text):
            # rel=canonical and the like name an address; only what the browser fetches counts.
            if re.search(r'\b(src|href)="(https?:)?//', tag) and "canonical" not in tag:
                external.append(f"{built_page.relative_to(site)}: {tag}")
    assert not external, external


def built_sections(site: Path, name: str) -> dict[str, str]:
    """A built page's sections by their heading's id (level 2 and 3), as HTML."""
    text = (site / name / "index.html").read_text(encoding="utf-8")
    assert "<!-- generated" not in text  # every generated part was put in
    return dict(re.findall(r'<h[23] id="([^"]+)".*?</h[23]>(.*?)(?=<h[23] |$)', text, re.S))


@pytest.mark.parametrize(
    ("model", "name"), [(GatewayConfig, "configuration"), (DEVICE_FILE, "devices")]
)
def test_the_reference_pages_have_every_key_with_its_description(
    site: Path, model: type[BaseModel], name: str
) -> None:
    """Under its section's heading, each key has a row that carries its description."""
    by_id = built_sections(site, name)
    missing = []
    keys = list(reference.config_keys(model))
    assert len(keys) > 30
    for key in keys:
        section = by_id.get(reference.anchor(key.path.rpartition(".")[0] or "Top level")[1:], "")
        row = re.search(rf"<td><code>{re.escape(key.key)}</code>.*?</tr>", section, re.S)
        text = cell_text(row.group(0)) if row else ""
        if key.description.replace("`", "") not in " ".join(text.split()):
            missing.append(key.path)
    assert not missing, f"no row with its description on the built {name} page: {missing}"


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


# --- drives and parameters, generated from the profiles -------------------------------------


def test_the_drives_page_has_every_model_register_and_fault(site: Path) -> None:
    """Every model `model:` takes, with its 2103H code; every communication register; every
    code of every fault table a model uses, with its keypad code and words."""
    text = (site / "drives" / "index.html").read_text(encoding="utf-8")
    rows = table_rows_html(text)
    by_first = {row[0]: row for row in rows if row}
    assert len(PROFILES) >= 15
    for key, profile in PROFILES.items():
        row = next((r for r in rows if r[0].split(" ")[0] == key), None)
        assert row is not None, f"model {key} not in the models table"
        for code in profile.identification:
            assert format_register(code) in row[2], (key, row)
    for register in COMMUNICATION_REGISTERS:
        row = by_first.get(format_register(register.address))
        assert row is not None, register.name
        assert row[1] == register.name
    by_id = built_sections(site, "drives")
    for profile in PROFILES.values():
        table = profile.faults
        if not table.entries:
            continue
        section = next(
            (
                html
                for id_, html in by_id.items()
                if id_.endswith("fault-table") and f"<code>{profile.key}</code>" in html
            ),
            None,
        )
        assert section is not None, f"no fault table names {profile.key}"
        shown = {row[0]: row for row in table_rows_html(section)}
        for code, (short, words) in table.entries.items():
            assert shown.get(str(code)) == [str(code), short, words], (profile.key, code)


def test_the_parameters_page_has_every_row_of_every_table_with_its_source(site: Path) -> None:
    by_id = built_sections(site, "parameters")
    tables = sources()["tables"]
    assert {"common", "gd200a"} <= set(tables)
    for name, described in tables.items():
        intro = cell_text(by_id[f"table-{name}"])
        assert " ".join(described["document"].split()) in " ".join(intro.split())
        rows = table_rows(name)
        for parameter in rows:
            section = by_id[f"{name}-{parameter.group.lower()}"]
            if described.get("groups"):
                assert described["groups"][parameter.group] in cell_text(section)
            row = next((r for r in table_rows_html(section) if r[0] == parameter.name), None)
            assert row is not None, f"{name} {parameter.name} not on the page"
            assert row[1] == " ".join(parameter.description.split())
            default = "depends on model" if not parameter.default_known else None
            assert default is None or row[3] == default
    # The GD200A manual's P00.03, as the CSV has it.
    p0003 = next(r for r in table_rows_html(by_id["gd200a-p00"]) if r[0] == "P00.03")
    assert p0003[2:5] == ["0.00 ... 400.00 Hz, at least P00.04", "50.00 Hz", "stopped only"]
    bar_code = next(r for r in table_rows_html(by_id["gd200a-p07"]) if r[0] == "P07.21")
    assert "set by the factory: the drive's bar code, never restored" in bar_code[5]


def test_every_parameter_table_file_is_described_in_the_sources() -> None:
    """The page lists the tables `parameter_sources.yaml` names: a CSV table dropped beside it
    without its entry (its document, its groups' pages) would be on no page and in no series."""
    data = ROOT / "gateway" / "profile" / "data"
    named = {t["file"] for t in sources()["tables"].values() if "file" in t}
    files = {path.name for path in data.glob("*.csv")}
    assert files, "no parameter table in gateway/profile/data/"
    assert files <= named, f"tables in no entry of parameter_sources.yaml: {files - named}"


def test_the_benchmark_page_shows_a_run_the_bench_wrote_with_todays_columns() -> None:
    """docs/bench/run.md comes from `bench --page`, not a hand: its table has the columns the
    bench prints now (a column added to the bench means running it again for the page)."""
    from gateway.instruments.bench.page import WRITTEN_BY
    from gateway.instruments.bench.report import header

    run = (DOCS / "bench" / "run.md").read_text(encoding="utf-8")
    assert run.startswith(WRITTEN_BY)
    assert f"```text\n{header()}\n" in run
    assert "<!-- generated: benchmark-run -->" in page("benchmark.md")
