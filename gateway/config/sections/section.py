"""What every section's model shares: an unknown key refused, frozen, each field's docstring its
description; and the check of a file the configuration names."""

from __future__ import annotations

import os

from pydantic import BaseModel, ConfigDict


def readable_file(value: str | None) -> str | None:
    """A file the configuration names must be there and readable: said at load, with the key."""
    if value is not None and not os.access(value, os.R_OK):
        reason = "no such file" if not os.path.exists(value) else "not readable"
        raise ValueError(f"{value}: {reason}")
    return value


class Section(BaseModel):
    # An unknown key is almost always a typo that would silently do nothing: refuse it.
    # The docstring under each field is its description (`Field.description`): the
    # configuration reference (docs/) is generated from it, so it is what a user reads.
    model_config = ConfigDict(extra="forbid", frozen=True, use_attribute_docstrings=True)
