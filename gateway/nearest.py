"""The nearest of the names a user could have meant, for "did you mean ...?" (a key of the
configuration, a drive model): one rule for every place that suggests one."""

from __future__ import annotations

import difflib
from collections.abc import Iterable

CUTOFF = 0.6
"""difflib's similarity ratio a name needs to be suggested: `baudrat` → `baudrate` (0.93),
`modle` → `model` (0.8), `gd35O` → `gd350` (0.8); `timeout` is not `retries`."""


LOOKALIKES = str.maketrans("oil", "011")
"""Letters typed for the digits they look like (`gd35O` for `gd350`): a name that differs from
the typed one only so is the one meant, before any nearer by spelling (`gd35`)."""


def nearest(typed: str, names: Iterable[str]) -> str | None:
    """The name of `names` nearest to `typed` (letter case aside), or None when none is near."""
    by_folded = {name.casefold(): name for name in names}
    folded = typed.casefold()
    alike = [name for key, name in by_folded.items() if _alike(key) == _alike(folded)]
    if alike:
        return alike[0]
    found = difflib.get_close_matches(folded, by_folded, n=1, cutoff=CUTOFF)
    return by_folded[found[0]] if found else None


def _alike(name: str) -> str:
    return name.translate(LOOKALIKES)


def did_you_mean(typed: str, names: Iterable[str]) -> str:
    """ "; did you mean baudrate?" to follow a reason, or "" when no name is near."""
    found = nearest(typed, names)
    return f"; did you mean {found}?" if found else ""
