"""The function-parameter tables as shipped: every row well-formed and sourced, every series
covered, and the loader's checks refusing a malformed row by file, line and column."""

from __future__ import annotations

import csv
import io
from importlib import resources

import pytest

from gateway.errors import TableError
from gateway.profile import get_profile
from gateway.profile.invt import INVT_PROFILES as PROFILES  # the series with manual tables
from gateway.profile.parameter_tables import COLUMNS, read_rows, series_table, sources

HEADER = ",".join(COLUMNS)


def shipped_tables() -> list[str]:
    return [t["file"] for t in sources()["tables"].values() if "file" in t]


@pytest.mark.parametrize("file", shipped_tables())
def test_each_shipped_row_is_well_formed(file: str) -> None:
    text = resources.files("gateway.profile").joinpath("data", file).read_text(encoding="utf-8")
    records = list(csv.DictReader(io.StringIO(text)))
    codes = [record["code"] for record in records]
    assert codes == sorted(set(codes)), "codes unique and in order"
    rows = read_rows(text, file)  # raises on a default outside its range, a bad mark...
    assert len(rows) == len(records)
    for row in rows:
        assert row.description
        assert row.group.startswith("P")
        assert row.minimum <= row.number(row.default) <= row.maximum, row.name
        assert all(row.minimum <= value <= row.maximum for value, _ in row.choices), row.name


@pytest.mark.parametrize("key", sorted(PROFILES))
def test_every_series_has_a_sourced_table_whose_bounds_exist(key: str) -> None:
    table = get_profile(key).parameter_table
    assert table.rows, key
    for row in table.rows:
        assert row.source, f"{key} {row.name}: no source"
        assert row.group in table.sources
        for bound in (row.minimum_from, row.maximum_from):
            assert bound is None or table.named(bound) is not None, f"{key} {row.name}: {bound}"


@pytest.mark.parametrize("key", sorted(PROFILES))
def test_the_defaults_keep_the_bounds_they_name(key: str) -> None:
    """A drive at its factory settings (a simulated one too) breaks none of its own ranges."""
    table = get_profile(key).parameter_table
    for row in table.rows:
        low, high = table.named(row.minimum_from or ""), table.named(row.maximum_from or "")
        if low is not None:
            assert low.number(low.default) <= row.number(row.default), f"{key} {row.name}"
        if high is not None:
            assert row.number(row.default) <= high.number(high.default), f"{key} {row.name}"


def test_the_goodrive200a_table_is_the_manuals_whole_and_confirmed() -> None:
    table = series_table("gd200a")
    assert len(table.rows) == 425
    assert table.unconfirmed_groups == ()
    groups = sorted({row.group for row in table.rows})
    assert groups == [f"P{n:02d}" for n in (*range(12), 13, 14, 17, 24)]
    speed_mode = table.named("P00.00")
    assert speed_mode is not None
    assert speed_mode.choice(2) == "SVPWM (V/F) control"
    assert speed_mode.locked_while_running
    assert "pages 34-40" in speed_mode.source
    torque = table.named("P03.12")
    assert torque is not None
    assert torque.signed
    assert (torque.number(0xF448), torque.word(-3000)) == (-3000, 0xF448)


def test_a_series_without_its_own_table_says_which_groups_are_borrowed() -> None:
    table = series_table("gd350")
    p00_11 = table.named("P00.11")
    assert p00_11 is not None
    assert p00_11.confirmed
    carrier = table.named("P00.14")
    assert carrier is not None
    assert not carrier.confirmed
    assert "unconfirmed for gd350" in table.sources["P00"]
    assert "P05" in table.unconfirmed_groups


@pytest.mark.parametrize(
    ("row", "complaint"),
    [
        ("P00.01,Run,,0,0,2,3,○,,,,", "default 3 outside the range"),
        ("P00.01,Run,,0,0,2,0,x,,,,", "change: 'x' is none of"),
        ("P00.01,Run,Hz,2,0,1.234,0,○,,,,", "maximum: 1.234 has more than 2 decimals"),
        ("P00.01,Run,,0,0,2,0,○,0: a|0: b,,,", "a value is listed twice"),
        ("P00.01,Run,,0,-1,0xFFFF,0,○,,,,", "does not fit one register"),
        ("X00.01,Run,,0,0,2,0,○,,,,", "code:"),
    ],
)
def test_a_malformed_row_is_named(row: str, complaint: str) -> None:
    with pytest.raises(TableError, match=rf"t\.csv:2: .*{complaint}"):
        read_rows(f"{HEADER}\n{row}\n", "t.csv")


def test_codes_out_of_order_are_refused() -> None:
    text = f"{HEADER}\nP00.02,B,,0,0,1,0,○,,,,\nP00.01,A,,0,0,1,0,○,,,,\n"
    with pytest.raises(TableError, match=r"t\.csv:3: P00\.01 is not after P00\.02"):
        read_rows(text, "t.csv")


def test_a_parameter_is_found_by_its_number_as_the_manual_or_the_wire_writes_it() -> None:
    table = series_table("gd200a")
    for spelled in ("P00.03", "p0.3", "0003H", "0x0003", " P00.03 "):
        assert [row.name for row in table.find(spelled)] == ["P00.03"], spelled
    assert table.find("P99.99") == ()
    assert table.find("") == ()


def test_a_parameter_is_found_by_the_words_of_its_name_in_any_order() -> None:
    table = series_table("gd200a")
    found = [row.name for row in table.find("time ACC")]
    assert found[:2] == ["P00.11", "P01.06"]
    assert all("acc" in row.description.lower() for row in table.find("time ACC"))
    # Words that happen to be hex with an H ("each", "ach") are words, not addresses.
    assert all("each" in row.description.lower() for row in table.find("each"))


def test_the_range_says_its_unit_and_the_parameters_bounding_it() -> None:
    table = series_table("gd200a")
    limit = table.named("P00.04")
    assert limit is not None
    assert limit.range_text() == "0.00 ... 400.00 Hz, within P00.05 ... P00.03"
    p0510 = table.named("P05.10")
    assert p0510 is not None
    assert p0510.range_text().startswith("0x0000 ... ")
    assert table.groups[-2:] == ("P17", "P24")
