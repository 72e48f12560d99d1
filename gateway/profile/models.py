"""The drive models users name (`model:` in the config, `--model`, `--drive ADDR=MODEL`).

Every maker's profiles in one registry: a new maker adds its module's profiles to `_ALL`
(`invt`, `abb`; `generic` for a device of no known maker; each device file of
`data/devices/`, named by its file name, and a site's own as `file:PATH`). A
model is named by its key (`gd30`, `gd300l`, `acs580`, `generic`) in any case, with or without
`-`, `_` or spaces, "Goodrive" for "GD" (`Goodrive30`), or one of its profile's `aliases`.
"""

from __future__ import annotations

from collections.abc import Mapping
from types import MappingProxyType
from typing import Final

from gateway.nearest import nearest
from gateway.profile.abb import ABB_PROFILES, SCAN_QUESTION
from gateway.profile.device_files import FILE_PREFIX, device_file_profile, shipped_devices
from gateway.profile.generic import GENERIC
from gateway.profile.invt import INVT_PROFILES
from gateway.profile.protocol import DriveProfile, Question

_ALL: Final[tuple[DriveProfile, ...]] = (
    *INVT_PROFILES.values(),
    *ABB_PROFILES.values(),
    GENERIC,
    *shipped_devices(),
)

SCAN_QUESTIONS: Final[tuple[Question, ...]] = (SCAN_QUESTION,)
"""How `scan` asks a drive that refuses INVT's identification (2100H-2103H) what it is, maker by
maker, in order."""

PROFILES: Final[Mapping[str, DriveProfile]] = MappingProxyType(
    {profile.key: profile for profile in _ALL}
)


def _normalise(name: str) -> str:
    key = "".join(name.strip().lower().split()).replace("-", "").replace("_", "")
    return "gd" + key.removeprefix("goodrive") if key.startswith("goodrive") else key


_BY_NAME: Final = {
    _normalise(spelled): profile for profile in _ALL for spelled in (profile.key, *profile.aliases)
}


def get_profile(name: str) -> DriveProfile:
    """The profile called `name` ("gd350", "Goodrive30", "GD300-LIFT", "sdm630"), or a site's
    device file (`file:/etc/invt-gateway/devices/mymeter.yaml`, read again each time: a reload
    sees the file's changes); ValueError lists them, or says what is wrong with the file."""
    if name.strip().startswith(FILE_PREFIX):
        return device_file_profile(name)
    try:
        return _BY_NAME[_normalise(name)]
    except KeyError:
        near = nearest(_normalise(name), _BY_NAME)
        suggestion = f" (did you mean {_BY_NAME[near].key}?)" if near else ""
        raise ValueError(
            f"unknown drive profile {name!r}{suggestion}: valid profiles are "
            f"{', '.join(PROFILES)}, or {FILE_PREFIX}PATH for a device file"
        ) from None
