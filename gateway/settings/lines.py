"""The lines and the drives on them: bus settings, RS-485 direction control, each drive's
settings (its route's numbers, profile and poll groups)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

from gateway.bus import Bus, BusSettings
from gateway.bus.direction import DirectionControl, DirectionMode
from gateway.bus.line import LineSettings
from gateway.bus.line_share import LineShares
from gateway.config import BusConfig, DriveConfig, Rs485Config
from gateway.modbus.timing import CharacterFormat
from gateway.profile import DriveProfile, PollGroup
from gateway.profile.limit_alarms import point_limits
from gateway.profile.point_types import Limit
from gateway.profile.ram_writes import ram_write_address
from gateway.routing import Route


def bus_settings(config: BusConfig) -> BusSettings:
    char_format = CharacterFormat(config.baudrate, config.parity, config.stopbits, config.bytesize)
    gap_s = char_format.t35_s if config.gap_ms is None else config.gap_ms / 1000
    return BusSettings(
        name=config.name,
        line=LineSettings(
            port=config.port,
            char_format=char_format,
            gap_s=gap_s,
            char_timeout_s=config.char_timeout_ms / 1000,
            drain_s=config.drain_ms / 1000,
            turnaround_s=config.turnaround_ms / 1000,
            echo=config.echo,
            direction=direction_control(config.rs485),
            name=config.name,
        ),
        timeout_s=config.timeout_ms / 1000,
        retries=config.retries,
        queue_size=config.queue_size,
        offline_after=config.offline_after,
        probe_max_s=config.probe_max_s,
        shares=LineShares(config.write_share, config.broadcast_share, config.poll_share),
    )


def direction_control(config: Rs485Config | None) -> DirectionControl | None:
    if config is None:
        return None
    return DirectionControl(
        mode=DirectionMode(config.mode),
        rts_level_for_tx=config.rts_level_for_tx == "high",
        delay_before_tx_s=config.delay_before_tx_ms / 1000,
        delay_after_tx_s=config.delay_after_tx_ms / 1000,
    )


@dataclass(frozen=True, slots=True)
class DriveSettings:
    """One drive as the router, the poller, MQTT, metrics and the console need it."""

    name: str
    bus: str
    address: int
    unit_id: int
    """The Modbus-TCP unit id SCADA uses (the address unless configured)."""
    model: str
    profile: DriveProfile
    """The model's profile with this drive's corrections applied."""
    timeout_s: float | None
    retries: int | None
    max_words: int | None
    """Requests over this many words are split; None: never split."""
    ram_writes: bool
    """Parameter writes go to the RAM-only address (asked for, and the model has one)."""
    cache_max_age_s: float | None
    poll_groups: tuple[PollGroup, ...]
    """The configured groups, or the profile's."""
    asks_for_polls: bool
    """Configured poll groups or a cache age: polled even without MQTT or the console."""
    alarms: Mapping[str, Limit] = field(default_factory=dict)
    """Limit alarms: a drive's on its telemetry keys (`drives[].alarms`), a device's on its
    points (its device file's `high`/`low`)."""


def drive_settings(config: DriveConfig) -> DriveSettings:
    profile = config.profile()
    split = profile.split_by_default if config.split is None else config.split
    if config.poll is not None:
        groups = tuple(
            PollGroup(g.name, g.start, g.count, g.interval_ms / 1000) for g in config.poll
        )
    else:
        groups = profile.poll_groups
    return DriveSettings(
        name=config.name,
        bus=config.bus,
        address=config.address,
        unit_id=config.effective_unit_id,
        model=config.model,
        profile=profile,
        timeout_s=None if config.timeout_ms is None else config.timeout_ms / 1000,
        retries=config.retries,
        max_words=profile.max_words if split else None,
        ram_writes=config.ram_writes and profile.ram_writes_supported,
        cache_max_age_s=None if config.cache_max_age_ms is None else config.cache_max_age_ms / 1000,
        poll_groups=groups,
        asks_for_polls=config.poll is not None or config.cache_max_age_ms is not None,
        alarms=point_limits(profile.typed_points)
        if profile.typed_points
        else {
            key: Limit(a.high, a.low, a.hysteresis, a.delay_ms / 1000)
            for key, a in config.alarms.items()
        },
    )


def drive_route(drive: DriveSettings, bus: Bus) -> Route:
    return Route(
        unit_id=drive.unit_id,
        drive=drive.name,
        bus=bus,
        address=drive.address,
        timeout_s=drive.timeout_s,
        retries=drive.retries,
        max_words=drive.max_words,
        ram_address=ram_write_address if drive.ram_writes else None,
        cache_max_age_s=drive.cache_max_age_s,
    )
