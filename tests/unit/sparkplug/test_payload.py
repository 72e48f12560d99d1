"""Sparkplug B payloads: what we encode reads back with the specification's field numbers and
datatypes; sequence numbers wrap at 255. (What another codec makes of them:
tests/system/test_sparkplug.py, with Eclipse Tahu's JavaScript codec.)"""

from __future__ import annotations

import pytest

from gateway.sparkplug import payload
from gateway.sparkplug import sparkplug_b_pb2 as pb


def test_sequence_numbers_run_0_to_255_then_0() -> None:
    seq = payload.SequenceNumber()
    handed = [seq.next() for _ in range(600)]
    assert handed[:3] == [0, 1, 2]
    assert handed[255:258] == [255, 0, 1]
    assert max(handed) == 255
    assert seq.restart() == 0
    assert seq.next() == 1


@pytest.mark.parametrize(
    ("value", "datatype", "field", "wire"),
    [
        (True, pb.Boolean, "boolean_value", True),
        (-5, pb.Int32, "int_value", 2**32 - 5),
        (65535, pb.Int32, "int_value", 65535),
        (2**40, pb.Int64, "long_value", 2**40),
        (-(2**40), pb.Int64, "long_value", 2**64 - 2**40),
        (50.12, pb.Double, "double_value", 50.12),
        ("running_forward", pb.String, "string_value", "running_forward"),
    ],
)
def test_values_travel_in_their_datatype_field(
    value: payload.Value, datatype: int, field: str, wire: object
) -> None:
    metric = payload.BirthMetric("m", 7, payload.datatype_of(value), value, {"engUnit": "Hz"})
    decoded = pb.Payload.FromString(payload.birth(3, 1_700_000_000_000, [metric]))
    assert decoded.seq == 3
    assert decoded.timestamp == 1_700_000_000_000
    (out,) = decoded.metrics
    assert (out.name, out.alias, out.datatype) == ("m", 7, datatype)
    assert out.WhichOneof("value") == field
    assert getattr(out, field) == wire
    assert list(out.properties.keys) == ["engUnit"]
    assert out.properties.values[0].string_value == "Hz"
    # And back, as a DCMD carrying it would be read.
    (back,) = payload.received(decoded.SerializeToString()).metrics
    assert back.value == value


def test_a_metric_not_read_yet_is_null() -> None:
    metric = payload.BirthMetric("m", 1, payload.DOUBLE, None)
    (out,) = pb.Payload.FromString(payload.birth(0, 1, [metric])).metrics
    assert out.is_null
    assert out.WhichOneof("value") is None


def test_data_by_alias_only_and_death_certificates() -> None:
    data = pb.Payload.FromString(payload.data(9, 5, [payload.DataMetric(4, payload.DOUBLE, 1.5)]))
    (metric,) = data.metrics
    assert not metric.HasField("name")
    # payloads-metric-datatype-not-req: the birth declared it; the value is in its field.
    assert not metric.HasField("datatype")
    assert (metric.alias, metric.double_value, data.seq) == (4, 1.5, 9)
    death = pb.Payload.FromString(payload.node_death(12, 5))
    assert not death.HasField("seq")
    assert [(m.name, m.datatype, m.long_value) for m in death.metrics] == [("bdSeq", pb.Int64, 12)]
    device = pb.Payload.FromString(payload.device_death(10, 5))
    assert (device.seq, len(device.metrics)) == (10, 0)


def test_historical_metrics_carry_their_own_time_and_a_gap_is_null() -> None:
    metrics = [
        payload.HistoricalMetric(4, payload.DOUBLE, 7.3, 1_700_000_000_100),
        payload.HistoricalMetric(4, payload.DOUBLE, 7.4, 1_700_000_000_400),
        payload.HistoricalMetric(5, payload.STRING, None, 1_700_000_000_400),
    ]
    data = pb.Payload.FromString(payload.history(12, 1_700_000_009_000, metrics))
    assert data.seq == 12
    assert [(m.alias, m.timestamp, m.is_historical) for m in data.metrics] == [
        (4, 1_700_000_000_100, True),
        (4, 1_700_000_000_400, True),
        (5, 1_700_000_000_400, True),
    ]
    assert [m.double_value for m in data.metrics[:2]] == [7.3, 7.4]
    assert data.metrics[2].is_null
    assert not any(m.HasField("datatype") or m.HasField("name") for m in data.metrics)


def test_what_is_not_a_payload_is_refused() -> None:
    with pytest.raises(ValueError, match="not a Sparkplug B payload"):
        payload.received(b"\xff\xff\xff")


def test_a_dcmd_that_contradicts_itself_is_refused() -> None:
    wrong_field = pb.Payload(
        metrics=[pb.Payload.Metric(name="set_frequency_hz", datatype=pb.Float, int_value=20)]
    )
    with pytest.raises(ValueError, match="int_value for a Float"):
        payload.received(wrong_field.SerializeToString())
    named = pb.Payload(metrics=[pb.Payload.Metric(name="Xet", datatype=pb.Boolean)])
    not_utf8 = named.SerializeToString().replace(b"Xet", b"\xff\xfet")
    with pytest.raises(ValueError, match="not UTF-8"):
        payload.received(not_utf8)
    widened = pb.Payload(metrics=[pb.Payload.Metric(name="x", datatype=pb.Int32, int_value=7)])
    assert payload.received(widened.SerializeToString()).metrics[0].value == 7
