"""CSV exports open in a spreadsheet as values, never as formulas (OWASP's rule): text that
begins like a formula is quoted, numbers (negative ones too) stay numbers."""

from __future__ import annotations

import csv
import io

from gateway.console.history import history_csv
from gateway.store.history import Series


def test_history_csv_quotes_formula_text_and_keeps_negative_numbers() -> None:
    shown = Series(
        keys=("output_current_a", "state"),
        times=[1_764_000_000.0, 1_764_000_060.0],
        columns=[[-3.5, 2.0], ['=HYPERLINK("http://x","y")', "@SUM(A1)"]],
        step_s=60.0,
    )
    rows = list(csv.reader(io.StringIO(history_csv(shown))))
    assert rows[1][1:] == ["-3.5", '\'=HYPERLINK("http://x","y")']
    assert rows[2][1:] == ["2", "'@SUM(A1)"]
    assert float(rows[1][1]) == -3.5  # a number a spreadsheet reads as one
