"""CSV cells that a spreadsheet opens as what they are, never as a formula.

Anyone can put text into what the console exports: a name typed at the login is kept in a
failed login's event. A cell that begins with `=`, `+`, `-` or `@` (or a tab or carriage
return, which some spreadsheets skip before looking) is taken as a formula by Excel and
LibreOffice: `=HYPERLINK("http://x","y")` becomes a link. OWASP's rule, followed here: such a
text cell gets a single quote in front, which the spreadsheet shows as text.

Only text is changed: a number stays a number (-3.5 is a value, not a formula), so numeric
columns read as numbers in every spreadsheet.
"""

from __future__ import annotations

from typing import Final

FORMULA_STARTS: Final = ("=", "+", "-", "@", "\t", "\r")


def text_cell(text: str) -> str:
    """`text`, with a quote in front when a spreadsheet would take it as a formula."""
    return "'" + text if text.startswith(FORMULA_STARTS) else text


def cell(value: object) -> object:
    """A value as a CSV cell: None empty, numbers as they are, anything else as safe text."""
    if value is None:
        return ""
    if isinstance(value, int | float) and not isinstance(value, bool):
        return value
    return text_cell(str(value))
