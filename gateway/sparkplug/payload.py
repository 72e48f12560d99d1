"""Sparkplug B payloads in and out: metrics to protobuf bytes and back. No I/O.

The wire format is the specification's (`sparkplug_b.proto`, compiled by protoc into the
committed `sparkplug_b_pb2`); this module is the only one that touches the generated classes.

    birth    every metric by name and alias, with its datatype, value and properties
             (NBIRTH, DBIRTH); a metric not read yet goes with `is_null`
    data     changed metrics by alias only, without their datatype (NDATA, DDATA): the birth
             declared it (specification 3.0, `payloads-metric-datatype-not-req`: "The datatype
             SHOULD NOT be included with metric definitions in NDATA, NCMD, DDATA, and DCMD
             messages"); a host decodes the value by the birth's datatype of its alias
    history  metrics polled while the broker was away (DDATA): by alias, `is_historical`, each
             with its own timestamp (when it was polled); a null one marks a gap
    death    NDEATH: the `bdSeq` metric alone; DDEATH: the payload's `seq` alone

A value's datatype follows the value: true/false a Boolean, a whole number an Int32 (Int64
beyond), a number with decimals a Double (a Float would turn 50.12 into 50.119998), text a
String. Signed integers travel as their two's complement in the unsigned fields (specification
3.0, "Payload Metric Datatypes": Int8 to Int32 in `int_value`, Int64 in `long_value`).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Final

from google.protobuf.message import DecodeError

from gateway.sparkplug import sparkplug_b_pb2 as pb

Value = bool | int | float | str

INT32: Final = pb.Int32
INT64: Final = pb.Int64
DOUBLE: Final = pb.Double
BOOLEAN: Final = pb.Boolean
STRING: Final = pb.String
INTEGERS: Final = frozenset(
    {pb.Int8, pb.Int16, pb.Int32, pb.Int64, pb.UInt8, pb.UInt16, pb.UInt32, pb.UInt64}
)
BD_SEQ: Final = "bdSeq"
"""The NBIRTH's and NDEATH's metric that pairs them (specification 3.0)."""


SEQUENCE_MODULO: Final = 256
"""`seq` and `bdSeq` run 0 to 255, then 0 again."""


class SequenceNumber:
    """A Sparkplug sequence number: `seq` of an edge node's messages, `bdSeq` of its CONNECTs."""

    def __init__(self) -> None:
        self.value = -1
        """The last one handed out; -1: none yet."""

    def next(self) -> int:
        self.value = (self.value + 1) % SEQUENCE_MODULO
        return self.value

    def restart(self) -> int:
        """An NBIRTH's: 0, and the next message counts on from it."""
        self.value = 0
        return 0


def datatype_of(value: Value) -> int:
    if isinstance(value, bool):
        return BOOLEAN
    if isinstance(value, int):
        return INT32 if -(2**31) <= value < 2**31 else INT64
    if isinstance(value, float):
        return DOUBLE
    return STRING


@dataclass(frozen=True, slots=True)
class BirthMetric:
    name: str
    alias: int | None
    datatype: int
    value: Value | None
    """None: not read yet (`is_null`)."""
    properties: Mapping[str, Value] = field(default_factory=dict)


@dataclass(frozen=True, slots=True)
class DataMetric:
    alias: int
    datatype: int
    value: Value


@dataclass(frozen=True, slots=True)
class HistoricalMetric:
    alias: int
    datatype: int
    value: Value | None
    """None: nothing known then (a gap the outage buffer could not hold)."""
    timestamp_ms: int


@dataclass(frozen=True, slots=True)
class ReceivedMetric:
    """A metric of an NCMD or DCMD: named, or by the alias our birth gave it."""

    name: str | None
    alias: int | None
    datatype: int
    value: Value | None


@dataclass(frozen=True, slots=True)
class Received:
    timestamp_ms: int | None
    metrics: tuple[ReceivedMetric, ...]


def birth(seq: int, timestamp_ms: int, metrics: Iterable[BirthMetric]) -> bytes:
    payload = pb.Payload(timestamp=timestamp_ms, seq=seq)
    for metric in metrics:
        out = payload.metrics.add(name=metric.name, datatype=metric.datatype)
        out.timestamp = timestamp_ms
        if metric.alias is not None:
            out.alias = metric.alias
        if metric.value is None:
            out.is_null = True
        else:
            _set_value(out, metric.datatype, metric.value)
        if metric.properties:
            _set_properties(out.properties, metric.properties)
    return payload.SerializeToString()


def data(seq: int, timestamp_ms: int, metrics: Sequence[DataMetric]) -> bytes:
    payload = pb.Payload(timestamp=timestamp_ms, seq=seq)
    for metric in metrics:
        # The datatype picks the value's field, and stays off the wire: the birth declared it.
        out = payload.metrics.add(alias=metric.alias)
        out.timestamp = timestamp_ms
        _set_value(out, metric.datatype, metric.value)
    return payload.SerializeToString()


def history(seq: int, timestamp_ms: int, metrics: Sequence[HistoricalMetric]) -> bytes:
    """A DDATA of values from before now, in the order given (specification 3.0, "is_historical":
    "a historical value ... acquired from a device or Edge Node" earlier)."""
    payload = pb.Payload(timestamp=timestamp_ms, seq=seq)
    for metric in metrics:
        out = payload.metrics.add(
            alias=metric.alias, timestamp=metric.timestamp_ms, is_historical=True
        )
        if metric.value is None:
            out.is_null = True
        else:
            _set_value(out, metric.datatype, metric.value)
    return payload.SerializeToString()


def node_death(bd_seq: int, timestamp_ms: int) -> bytes:
    payload = pb.Payload(timestamp=timestamp_ms)
    metric = payload.metrics.add(name=BD_SEQ, datatype=INT64, timestamp=timestamp_ms)
    _set_value(metric, INT64, bd_seq)
    return payload.SerializeToString()


def device_death(seq: int, timestamp_ms: int) -> bytes:
    return pb.Payload(timestamp=timestamp_ms, seq=seq).SerializeToString()


def received(data: bytes) -> Received:
    """An NCMD's or DCMD's metrics. Raises ValueError for what isn't a Sparkplug B payload,
    and for one that contradicts itself: a name or text that is not UTF-8 (protobuf's proto2
    strings are bytes then), a value in another field than its datatype's (an `int_value` for
    a Float): the host meant something else than it sent, so none of it is run."""
    try:
        payload = pb.Payload.FromString(data)
    except DecodeError as exc:
        raise ValueError(f"not a Sparkplug B payload: {exc}") from None
    metrics = tuple(_received_metric(metric) for metric in payload.metrics)
    timestamp = payload.timestamp if payload.HasField("timestamp") else None
    return Received(timestamp, metrics)


# -- inside ------------------------------------------------------------------------------------

_FIELD_OF: Final[Mapping[int, str]] = {
    **dict.fromkeys((pb.Int8, pb.Int16, pb.Int32, pb.UInt8, pb.UInt16, pb.UInt32), "int_value"),
    **dict.fromkeys((pb.Int64, pb.UInt64, pb.DateTime), "long_value"),
    pb.Float: "float_value",
    pb.Double: "double_value",
    pb.Boolean: "boolean_value",
    **dict.fromkeys((pb.String, pb.Text, pb.UUID), "string_value"),
}
"""The field a value of each datatype travels in (specification 3.0, "Payload Metric Datatypes");
the datatypes the gateway never takes (DataSet, Bytes, Template ...) are not here."""


def _received_metric(metric: pb.Payload.Metric) -> ReceivedMetric:
    name: object = metric.name if metric.HasField("name") else None
    alias = metric.alias if metric.HasField("alias") else None
    if name is not None and not isinstance(name, str):
        raise ValueError(f"a metric name that is not UTF-8 text ({name!r:.40})")
    label = name if name is not None else f"alias {alias}"
    which = metric.WhichOneof("value")
    expected = _FIELD_OF.get(metric.datatype)
    if not metric.is_null and which is not None and expected is not None and which != expected:
        datatype = pb.DataType.Name(metric.datatype)  # type: ignore[arg-type]  # a known one
        raise ValueError(f"{label}: {which} for a {datatype} (whose value is in {expected})")
    value = None if metric.is_null else _value(metric)
    if isinstance(value, bytes):
        raise ValueError(f"{label}: a text value that is not UTF-8")
    return ReceivedMetric(name, alias, metric.datatype, value)


def _set_value(out: pb.Payload.Metric, datatype: int, value: Value) -> None:
    if datatype == BOOLEAN:
        out.boolean_value = bool(value)
    elif datatype in (pb.Int64, pb.UInt64):
        out.long_value = int(value) & 0xFFFF_FFFF_FFFF_FFFF
    elif datatype in INTEGERS:
        out.int_value = int(value) & 0xFFFF_FFFF
    elif datatype == pb.Float:
        out.float_value = float(value)
    elif datatype == DOUBLE:
        out.double_value = float(value)
    else:
        out.string_value = str(value)


def _value(metric: pb.Payload.Metric) -> Value | None:
    """A received metric's value by its datatype; None for the kinds the gateway never takes."""
    datatype = metric.datatype
    which = metric.WhichOneof("value")
    if which == "boolean_value":
        return metric.boolean_value
    if which == "int_value":
        raw: int = metric.int_value
        signed = datatype in (pb.Int8, pb.Int16, pb.Int32)
        return raw - (1 << 32) if signed and raw >= 1 << 31 else raw
    if which == "long_value":
        raw = metric.long_value
        return raw - (1 << 64) if datatype == pb.Int64 and raw >= 1 << 63 else raw
    if which == "float_value":
        return metric.float_value
    if which == "double_value":
        return metric.double_value
    if which == "string_value":
        return metric.string_value
    return None


def _set_properties(out: pb.Payload.PropertySet, properties: Mapping[str, Value]) -> None:
    for key, value in properties.items():
        out.keys.append(key)
        datatype = datatype_of(value)
        prop = out.values.add(type=datatype)
        if datatype == BOOLEAN:
            prop.boolean_value = bool(value)
        elif datatype == INT32:
            prop.int_value = int(value) & 0xFFFF_FFFF
        elif datatype == INT64:
            prop.long_value = int(value) & 0xFFFF_FFFF_FFFF_FFFF
        elif datatype == DOUBLE:
            prop.double_value = float(value)
        else:
            prop.string_value = str(value)
