"""Telemetry keys as OPC UA values: each key's DataType, its EngineeringUnits, and a polled
value as a DataValue. No I/O.

A key's DataType comes from what the gateway knows of it: a device file's point by its kind
(u16 is UInt16, f32 Float, a scaled integer Double, an enumeration its words, a String), an INVT
or ABB drive's words by the table below, a running value (a frequency, a current) Double. A key
the tables don't know is BaseDataType: any value goes, typed by what it holds.

Units are UNECE Recommendation 20 common codes, as OPC UA Part 8 asks (`EUInformation`: the
namespace of UN/CEFACT, the code packed into `UnitId`, the symbol as its display name).
"""

from __future__ import annotations

import datetime
from collections.abc import Mapping
from typing import Final

from asyncua import ua

from gateway.profile import DriveProfile
from gateway.profile.point_types import Kind, TypedPoint
from gateway.profile.registers import RUNNING_VALUES
from gateway.profile.states import RunState
from gateway.profile.telemetry import TelemetryValue

UNECE_NAMESPACE: Final = "http://www.opcfoundation.org/UA/units/un/cefact"
UNECE_CODES: Final[Mapping[str, tuple[str, str]]] = {
    "Hz": ("HTZ", "hertz"),
    "kHz": ("KHZ", "kilohertz"),
    "V": ("VLT", "volt"),
    "A": ("AMP", "ampere"),
    "mA": ("4K", "milliampere"),
    "W": ("WTT", "watt"),
    "kW": ("KWT", "kilowatt"),
    "kWh": ("KWH", "kilowatt hour"),
    "MWh": ("MWH", "megawatt hour"),
    "°C": ("CEL", "degree Celsius"),
    "rpm": ("RPM", "revolutions per minute"),
    "%": ("P1", "percent"),
    "s": ("SEC", "second"),
    "ms": ("C26", "millisecond"),
    "min": ("MIN", "minute"),
    "h": ("HUR", "hour"),
    "Ω": ("OHM", "ohm"),
    "Nm": ("NU", "newton metre"),
    "bar": ("BAR", "bar"),
    "kPa": ("KPA", "kilopascal"),
    "Pa": ("PAL", "pascal"),
    "m³/h": ("MQH", "cubic metre per hour"),
    "l/min": ("L2", "litre per minute"),
}
"""The units the profiles, the parameter tables and the shipped device files use, by their
symbol there (a table's "s (or min)", "Hz/s" or "kWh x 1000" has no EngineeringUnits)."""

WORDS: Final[Mapping[str, ua.VariantType]] = {
    "state": ua.VariantType.String,
    "command_source": ua.VariantType.String,
    "fault_name": ua.VariantType.String,
    "fault_description": ua.VariantType.String,
    "ready": ua.VariantType.Boolean,
    "overload_pre_alarm": ua.VariantType.Boolean,
    "warning": ua.VariantType.Boolean,
    "at_setpoint": ua.VariantType.Boolean,
    "state_word_1": ua.VariantType.UInt16,
    "state_word_2": ua.VariantType.UInt16,
    "status_word": ua.VariantType.UInt16,
    "fault_code": ua.VariantType.UInt16,
    "input_terminals": ua.VariantType.UInt16,
    "output_terminals": ua.VariantType.UInt16,
    "reference_1": ua.VariantType.Int16,
    "reference_2": ua.VariantType.Int16,
}
"""The decoded words of the drives' profiles, by telemetry key."""

KINDS: Final[Mapping[Kind, ua.VariantType]] = {
    Kind.U16: ua.VariantType.UInt16,
    Kind.S16: ua.VariantType.Int16,
    Kind.U32: ua.VariantType.UInt32,
    Kind.S32: ua.VariantType.Int32,
    Kind.U64: ua.VariantType.UInt64,
    Kind.S64: ua.VariantType.Int64,
    Kind.F32: ua.VariantType.Float,
    Kind.F64: ua.VariantType.Double,
    Kind.STRING: ua.VariantType.String,
    Kind.ENUM: ua.VariantType.String,
    Kind.BIT: ua.VariantType.Boolean,
    Kind.BOOL: ua.VariantType.Boolean,
}
RUN_STATES: Final = ("unknown", *(state.name.lower() for state in RunState))
"""The `run_state` variable's EnumStrings: a drive's `state` word at the index of its number in
INVT's state word 1 (1 running_forward ... 6 pre_exciting); 0 a word not among them. An ABB
drive's states are the same words."""
ANY: Final = ua.VariantType.Variant
"""BaseDataType: a key the tables don't know."""
RUNNING_KEYS: Final = frozenset(running.key for running in RUNNING_VALUES)


def variant_type(profile: DriveProfile, key: str) -> ua.VariantType:
    point = _point(profile, key)
    if point is not None:
        scaled = point.scale != 1.0 or point.offset != 0.0 or point.decimals is not None
        if scaled and point.kind not in (Kind.STRING, Kind.ENUM, Kind.BIT, Kind.BOOL):
            return ua.VariantType.Double
        return KINDS[point.kind]
    if key in WORDS:
        return WORDS[key]
    if key in RUNNING_KEYS or key.startswith("actual_value_"):
        return ua.VariantType.Double
    return ANY


def run_state(state: TelemetryValue) -> int:
    """The `run_state` value of a drive's `state` word (its index in `RUN_STATES`)."""
    return RUN_STATES.index(state) if state in RUN_STATES else 0


def engineering_units(symbol: str) -> ua.EUInformation | None:
    """The UNECE unit of `symbol`; None for a unitless key or a symbol not in the table."""
    known = UNECE_CODES.get(symbol)
    if known is None:
        return None
    code, description = known
    unit_id = 0
    for character in code:  # Part 8: the code's characters packed into an Int32, left to right
        unit_id = unit_id << 8 | ord(character)
    return ua.EUInformation(
        NamespaceUri=UNECE_NAMESPACE,
        UnitId=unit_id,
        DisplayName=ua.LocalizedText(symbol),
        Description=ua.LocalizedText(description),
    )


def data_value(
    kind: ua.VariantType, value: TelemetryValue, read_at: datetime.datetime
) -> ua.DataValue:
    """A polled value, Good, stamped with when it was read; BadTypeMismatch when the value
    can't be held by the key's type (a profile that changed its mind)."""
    try:
        variant = _variant(kind, value)
    except (TypeError, ValueError, OverflowError):
        return status_value(ua.StatusCodes.BadTypeMismatch, read_at)
    return ua.DataValue(variant, SourceTimestamp=read_at, ServerTimestamp=read_at)


def status_value(code: int, at: datetime.datetime) -> ua.DataValue:
    """No value, only why (BadCommunicationError: the drive is offline)."""
    return ua.DataValue(StatusCode=ua.StatusCode(code), SourceTimestamp=at, ServerTimestamp=at)


def _variant(kind: ua.VariantType, value: TelemetryValue) -> ua.Variant:
    if kind is ANY:
        return ua.Variant(value)
    if kind is ua.VariantType.String:
        return ua.Variant(str(value), kind)
    if kind is ua.VariantType.Boolean:
        return ua.Variant(bool(value), kind)
    if kind in (ua.VariantType.Float, ua.VariantType.Double):
        return ua.Variant(float(value), kind)
    if isinstance(value, str):
        raise TypeError(f"{value!r} is no number")
    return ua.Variant(int(value), kind)


def _point(profile: DriveProfile, key: str) -> TypedPoint | None:
    for point in profile.typed_points:
        if point.name == key:
            return point
    return None
